"""clphong's disk cache: its folder, and a store of small files with limits and cleanup.

The folder is ``$CLPHONG_CACHE_DIR``, else ``$XDG_CACHE_HOME/clphong``, else
``~/.cache/clphong``. It holds the host's description (``host/``), the self-test
verdicts (``selftest/``), non-PoCL kernel binaries (``bin/``), Intel's ICD folder
(``icd-*``) and the environment maps' conversions (``environment/``, through
:class:`Store`).

A :class:`Store` writes each entry atomically (a temporary file, then a rename: a
reader never sees half a file), skips writing where the disk is nearly full or the
folder cannot be written (the next process only recomputes), and keeps at most
``keep`` entries, removing the least recently used.
"""

from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path

__all__ = ["cache_dir", "Store", "CACHE_MIN_FREE"]

#: Free space below which a cache folder is taken for full (as for PoCL's kernel cache).
CACHE_MIN_FREE = 4 << 20


def cache_dir() -> Path:
    """clphong's cache folder: ``$CLPHONG_CACHE_DIR``, else ``$XDG_CACHE_HOME/clphong``,
    else ``~/.cache/clphong``."""
    if os.environ.get("CLPHONG_CACHE_DIR"):
        return Path(os.environ["CLPHONG_CACHE_DIR"])
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]) / "clphong"
    return Path.home() / ".cache" / "clphong"


class Store:
    """Files ``NAME.SUFFIX`` in ``cache_dir()/sub``, at most ``keep`` of them."""

    def __init__(self, sub: str, suffix: str, keep: int):
        self.sub, self.suffix, self.keep = sub, suffix, int(keep)

    @property
    def folder(self) -> Path:
        return cache_dir() / self.sub

    def path(self, name: str) -> Path:
        return self.folder / f"{name}{self.suffix}"

    def get(self, name: str) -> Path | None:
        """The entry's path if it exists (its time is touched: recently used), else None."""
        p = self.path(name)
        try:
            os.utime(p)
        except OSError:
            return None
        return p

    def put(self, name: str, write) -> bool:
        """Write an entry with ``write(file object)``, atomically; whether it was kept."""
        folder = self.folder
        try:
            folder.mkdir(parents=True, exist_ok=True)
            if shutil.disk_usage(folder).free < CACHE_MIN_FREE:
                return False
        except OSError:
            return False
        final = self.path(name)
        tmp = final.with_name(f".{final.name}.{os.getpid()}-{threading.get_ident()}.tmp")
        try:
            with open(tmp, "wb") as f:
                write(f)
            os.replace(tmp, final)
        except OSError:
            try:
                tmp.unlink()
            except OSError:
                pass
            return False
        self._clean()
        return True

    def _clean(self) -> None:
        """Remove the least recently used entries beyond ``keep``."""
        try:
            entries = [(p.stat().st_mtime, p) for p in self.folder.glob(f"*{self.suffix}")
                       if not p.name.startswith(".")]
        except OSError:
            return
        entries.sort()
        for _, p in entries[:max(len(entries) - self.keep, 0)]:
            try:
                p.unlink()
            except OSError:
                pass
