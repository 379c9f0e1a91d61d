"""Coverage-guided fuzzing of clphong's file readers with atheris (libFuzzer).

Not collected by pytest (the name does not start with ``test_``). Run a long
campaign, for example::

    pip install atheris            # or: pip install ".[fuzz]"
    mkdir -p corpus/gbuffer corpus/scene
    python tests/fuzz_atheris.py --seed-corpus corpus          # writes seeds
    python tests/fuzz_atheris.py gbuffer corpus/gbuffer -max_total_time=3600
    python tests/fuzz_atheris.py scene corpus/scene -max_total_time=3600 -dict=tests/scene.dict

The first argument picks the target (``gbuffer``: ``read_gbuffer`` of the
bytes as an EXR file; ``scene``: ``load_scene`` of the bytes as a TOML file);
the rest are passed to libFuzzer (``-runs=N``, ``-max_len=N``, ``-jobs=N``,
``-max_total_time=S``, a corpus folder, a crash file to reproduce). See
docs/fuzzing.md.

The property is the one of tests/test_fuzz.py: only ClphongError subclasses
may escape, each with a one-line message. Any other exception is reported by
atheris as a crash, with the input saved as ``crash-<sha1>``.
"""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
import warnings

import atheris

with atheris.instrument_imports():
    import clphong.core.memory  # noqa: F401 - the memory checks the reader calls
    import clphong.io.gbuffer
    import clphong.model.scene

from clphong.core.errors import ClphongError  # noqa: E402

# A mutated header may claim a huge image: the reader must refuse it, not allocate it.
os.environ.setdefault("CLPHONG_MAX_MEMORY", "64M")
_DIR = tempfile.mkdtemp(prefix="clphong-atheris-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
atexit.register(shutil.rmtree, _DIR, True)


def _check(fn, data: bytes, suffix: str) -> None:
    path = os.path.join(_DIR, "input" + suffix)
    with open(path, "wb") as fh:
        fh.write(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            fn(path)
        except ClphongError as exc:
            if "\n" in str(exc):
                raise AssertionError(f"message spans lines: {str(exc)!r}") from exc


def fuzz_gbuffer(data: bytes) -> None:
    _check(clphong.io.gbuffer.read_gbuffer, data, ".exr")


def fuzz_scene(data: bytes) -> None:
    _check(clphong.model.scene.load_scene, data, ".toml")


TARGETS = {"gbuffer": fuzz_gbuffer, "scene": fuzz_scene}


def write_seed_corpus(folder: str) -> None:
    """Valid G-buffers and scenes (the seeds of tests/test_fuzz.py) as corpus files."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import test_fuzz

    for sub in ("gbuffer", "scene"):
        os.makedirs(os.path.join(folder, sub), exist_ok=True)
    for name, data in test_fuzz.SEEDS.items():
        with open(os.path.join(folder, "gbuffer", name + ".exr"), "wb") as fh:
            fh.write(data)
    with open(os.path.join(folder, "scene", "valid.toml"), "w") as fh:
        fh.write(test_fuzz._VALID_TEXT)
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for sample in ("spheres.toml", "ortho.toml"):
        src = os.path.join(repo, "gbuffers", sample)
        if os.path.exists(src):
            with open(src, "rb") as fi, open(os.path.join(folder, "scene", sample), "wb") as fo:
                fo.write(fi.read())
    print(f"seed corpus written to {folder}/gbuffer and {folder}/scene")


def main(argv: list[str]) -> None:
    if len(argv) >= 3 and argv[1] == "--seed-corpus":
        write_seed_corpus(argv[2])
        return
    if len(argv) < 2 or argv[1] not in TARGETS:
        sys.exit(f"usage: {argv[0]} gbuffer|scene [libFuzzer options and corpus folders]\n"
                 f"       {argv[0]} --seed-corpus FOLDER")
    target = TARGETS[argv[1]]
    atheris.Setup([argv[0], *argv[2:]], target)
    atheris.Fuzz()


if __name__ == "__main__":
    main(sys.argv)
