"""A cached render writes nothing into PoCL's kernel cache (issue 14).

PoCL 3.0 wrote on every run: an empty ``tempfile_*`` at device start (its SIGFPE
handler) and, on every build from source, the source and its 1.1 MB preprocessed
text, so that a cached render under ``ulimit -f 1000`` died of SIGABRT ("LLVM
ERROR: IO failure on output stream"). These run the README's command in
subprocesses, each cache its own ``POCL_CACHE_DIR``.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys

import pytest
from conftest import GBUFFERS

pty = pytest.importorskip("pty")
resource = pytest.importorskip("resource")

SPHERES = [str(GBUFFERS / "spheres.toml"), str(GBUFFERS / "spheres.exr")]
LIMIT_KIB = 1000          # ulimit -f 1000 (the spheres output is 0.66 MB)


@pytest.fixture(scope="module", autouse=True)
def _pocl_only():
    from clphong.device.selection import get_runtime

    if not get_runtime().is_pocl:
        pytest.skip("PoCL's kernel cache: the default device is not PoCL's")


def _env(cache):
    env = dict(os.environ, POCL_CACHE_DIR=str(cache))
    env.pop("POCL_SIGFPE_HANDLER", None)      # clphong must set what it needs itself
    return env


def _render(cache, out, *, fsize_kib=None, stderr=subprocess.PIPE):
    """``clphong render`` of the spheres sample with its own cache; the result."""
    def limit():
        _, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize_kib * 1024, hard))

    return subprocess.run([sys.executable, "-m", "clphong", "render", *SPHERES, "-o", str(out)],
                          env=_env(cache), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                          stderr=stderr, text=True, timeout=600,
                          preexec_fn=limit if fsize_kib else None)


def _render_on_tty(cache, out):
    """The same with stderr on a pseudo-terminal: (exit code, what it printed there)."""
    master, slave = pty.openpty()
    try:
        r = _render(cache, out, stderr=slave)
    finally:
        os.close(slave)
    text = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:            # EIO: the terminal's other end is closed and drained
            break
        if not chunk:
            break
        text += chunk
    os.close(master)
    return r.returncode, text.decode(errors="replace").replace("\r\n", "\n")


def _snapshot(cache):
    """Every file and folder under ``cache``: its size and modification time."""
    return {str(p.relative_to(cache)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(cache.rglob("*"))}


def _assert_unchanged(before, after):
    assert sorted(after) == sorted(before), (
        f"new: {sorted(set(after) - set(before))}, gone: {sorted(set(before) - set(after))}")
    # PoCL truncates the empty last_accessed of each program it builds (LRU pruning):
    # a new time, no new file and no data.
    changed = [p for p in before if before[p] != after[p] and not p.endswith("last_accessed")]
    assert not changed, f"rewritten: {changed}"


@pytest.fixture(scope="module")
def warm(tmp_path_factory):
    """A kernel cache after one (cold) render, and its snapshot."""
    root = tmp_path_factory.mktemp("pocl-warm")
    cache = root / "cache"
    r = _render(cache, root / "cold.exr")
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", "a compile with stderr not a terminal must print nothing"
    return cache, _snapshot(cache)


def test_a_cached_render_adds_no_file(warm, tmp_path):
    cache, before = warm
    r = _render(cache, tmp_path / "warm.exr")
    assert r.returncode == 0, r.stderr
    _assert_unchanged(before, _snapshot(cache))


def test_a_cached_render_survives_ulimit_f_1000(warm, tmp_path):
    cache, before = warm
    r = _render(cache, tmp_path / "limited.exr", fsize_kib=LIMIT_KIB)
    assert r.returncode == 0, f"exit {r.returncode}: {r.stderr[-2000:]}"
    assert r.stderr == ""
    assert (tmp_path / "limited.exr").stat().st_size > 0
    _assert_unchanged(before, _snapshot(cache))


def test_a_cached_render_on_a_terminal_says_nothing(warm, tmp_path):
    cache, _ = warm
    code, text = _render_on_tty(cache, tmp_path / "tty.exr")
    assert code == 0, text
    assert text == ""


def test_a_first_compile_on_a_terminal_says_one_line(tmp_path):
    code, text = _render_on_tty(tmp_path / "cache", tmp_path / "first.exr")
    assert code == 0, text
    lines = text.splitlines()
    assert len(lines) == 1, text
    assert lines[0].startswith("clphong: compiling shade.cl for this scene (first run"), text


def test_an_uncached_build_under_ulimit_is_a_one_line_error(tmp_path):
    cache = tmp_path / "cache"
    r = _render(cache, tmp_path / "x.exr", fsize_kib=LIMIT_KIB)
    assert r.returncode == 1, f"exit {r.returncode} (-6: SIGABRT): {r.stderr[-2000:]}"
    assert r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith("clphong: error: ") and str(cache) in r.stderr, r.stderr
    assert "ulimit -f" in r.stderr and "POCL_CACHE_DIR" in r.stderr
    assert not (tmp_path / "x.exr").exists()


class _Stream(io.StringIO):
    def __init__(self, tty):
        super().__init__()
        self._tty = tty

    def isatty(self):
        return self._tty


def test_notice_on_tty_writes_only_to_a_terminal():
    from clphong.device.runtime import notice_on_tty

    tty, pipe = _Stream(True), _Stream(False)
    notice_on_tty("clphong: compiling x.cl", tty)
    notice_on_tty("clphong: compiling x.cl", pipe)
    assert tty.getvalue() == "clphong: compiling x.cl\n"
    assert pipe.getvalue() == ""


def test_the_notice_comes_from_a_compile_not_from_a_cache(monkeypatch, tmp_path):
    """In process: a compile calls the hook; the same program again (in-process
    cache) and the same program from clphong's binary do not."""
    from clphong.device import runtime, selection

    rt = selection.get_runtime()
    said = []
    monkeypatch.setattr(runtime, "compile_notice", said.append)
    monkeypatch.setattr(runtime, "COMPILE_NOTICE_AFTER_S", 0.0)
    monkeypatch.setattr(rt, "_programs", {})
    # clphong's binaries in an empty folder (PoCL keeps the folder it started with)
    monkeypatch.setenv("POCL_CACHE_DIR", str(tmp_path))
    defines = {"LANES": 1, "CHAINS": 1}
    compiled = rt.compiled
    rt.program("peak.cl", defines)
    assert rt.compiled == compiled + 1
    assert said == ["clphong: compiling peak.cl (first run; cached afterwards)\u2026"]
    rt.program("peak.cl", defines)
    monkeypatch.setattr(rt, "_programs", {})
    rt.program("peak.cl", defines)                 # from clphong/*.poclbin
    assert rt.compiled == compiled + 1
    assert len(said) == 1
    assert len(list((tmp_path / "clphong").glob("peak-*.poclbin"))) == 1


def test_a_full_or_unwritable_cache_folder_is_named_with_the_remedy(monkeypatch, tmp_path):
    """A build that fails where PoCL's cache folder is full or read-only says so, with
    the folder and POCL_CACHE_DIR, not "failed to build ... install PoCL"."""
    import shutil
    from collections import namedtuple

    import pyopencl as cl

    from clphong.core.errors import DeviceError
    from clphong.device import runtime, selection

    try:
        rt = selection.get_runtime("pocl")     # PoCL's, whichever device is the default
    except DeviceError:
        pytest.skip("PoCL's cache only, and no PoCL device is present")
    monkeypatch.setenv("POCL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(rt, "_programs", {})

    def fail(self, *a, **k):
        raise cl.RuntimeError("clBuildProgram failed: BUILD_PROGRAM_FAILURE")

    monkeypatch.setattr(cl.Program, "build", fail)
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(1 << 30, (1 << 30) - 1024, 1024))
    # the compiling child's side (Runtime.compile_to): its DeviceError's text is what
    # the parent raises (isolate.BuildChild.build), so it is the user's message
    with pytest.raises(DeviceError) as info:
        rt._compile("peak.cl", rt.build_options({"LANES": 8, "CHAINS": 8, "UNIQUE": 12345}))
    msg = str(info.value)
    assert str(tmp_path / "cache") in msg and "is full (1 KiB free)" in msg
    assert "POCL_CACHE_DIR" in msg and "install" not in msg
    assert runtime.cache_problem(tmp_path) is None or "full" in runtime.cache_problem(tmp_path)
    (tmp_path / "file").write_text("x")
    monkeypatch.undo()
    assert "is not a folder" in runtime.cache_problem(tmp_path / "file" / "kcache")
