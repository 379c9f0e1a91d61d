"""Output paths of a batch, checked before any frame runs, and the temporary files a
killed run left beside them (removed only when their writer is gone:
:func:`clphong.io.atomic.writer_gone`)."""

from __future__ import annotations

import glob
import os
import re

from ..io.atomic import writer_gone, written_here
from .jobs import BatchError


def check_rig_name(name: str) -> str:
    """A rig name is one path component of printable characters: it names output folders
    and files through ``{rig}`` (``../../x`` made folders outside the output tree)."""
    bad = (not name or name in (".", "..") or "/" in name or os.sep in name
           or (os.altsep is not None and os.altsep in name)
           or not all(ch.isprintable() for ch in name))
    if bad:
        shown = name.encode("unicode_escape").decode("ascii")
        if len(shown) > 200:
            shown = shown[:200] + "…"
        raise BatchError(f"rig name '{shown}': a rig name must be one folder or file name of "
                         "printable characters (no '/', not '.' or '..'); name the rig with "
                         "--rig NAME=SCENE.toml")
    return name


def check_output_folder(folder: str) -> None:
    """Before any frame runs: ``folder`` (as written, not normalised) can be made and then
    reached by the system. Relight makes missing output folders, but never one just to
    step back out of it: ``missing/..`` passed every check and then failed every frame's
    write ("No such file or directory"), because the system needs ``missing`` to exist
    to resolve ``..``; and no part may be a regular file."""
    parts = [p for p in folder.split(os.sep) if p]
    path = os.sep if folder.startswith(os.sep) else ""
    missing = None
    for part in parts:
        path = os.path.join(path, part) if path else part
        if part == ".." and missing is not None:
            raise BatchError(f"output folder {folder}: {missing} does not exist, so '..' after it "
                             "cannot be resolved; write the folder without it, or create "
                             f"{missing} first")
        if missing is None and os.path.lexists(path) and not os.path.isdir(path):
            raise BatchError(f"output folder {folder}: {path} is a file, not a folder; "
                             "choose another output folder")
        if missing is None and not os.path.lexists(path):
            missing = path


def stale_temporaries(path: str) -> list[str]:
    """Temporary files that :func:`clphong.io.atomic.atomic_path` left for ``path`` (a killed
    run): ``.NAME.tmp-XXXXXXXX.EXT``, and ``….EXT.born``, the name a temporary file has for
    the moment before it takes its own (a SIGKILL there left one behind)."""
    folder = os.path.dirname(os.path.abspath(path))
    stem, ext = os.path.splitext(os.path.basename(path))
    rx = re.compile(r"^\." + re.escape(stem) + r"\.tmp-[0-9a-f]{8}" + re.escape(ext) + r"(\.born)?$")
    pattern = os.path.join(glob.escape(folder), "." + glob.escape(stem) + ".tmp-*" + glob.escape(ext))
    return [p for pat in (pattern, pattern + ".born")
            for p in glob.glob(pat, include_hidden=True) if rx.match(os.path.basename(p))]


def remove_stale_temporaries(files, *, own: bool = False) -> list[str]:
    """Remove :func:`stale_temporaries` of each of ``files`` whose writer is gone
    (:func:`clphong.io.atomic.writer_gone`: a live run's file is locked, and left alone),
    and with ``own`` those of this process's own writes in flight (a stopping batch
    gives up on them); the ones removed."""
    removed = []
    for path in files:
        for tmp in stale_temporaries(path):
            if not (writer_gone(tmp) or (own and written_here(tmp))):
                continue
            try:
                os.remove(tmp)
                removed.append(tmp)
            except OSError:
                pass
    return removed


def remove_job_temporaries(job, *, own: bool = False) -> int:
    """Remove the temporary files a killed run left for the outputs of ``job`` (a
    :class:`~clphong.pipeline.jobs.Job`; with ``own``,
    this process's own writes in flight too); return how many."""
    return len(remove_stale_temporaries((p for _, paths in job.outputs for p in paths.files), own=own))
