"""Compiling where an abort cannot kill the caller: a child process that builds kernels.

LLVM answers some code generation bugs with abort() (PoCL 3.0 on Zen 4: ``LLVM
ERROR: Cannot select``), which no exception handler survives. clphong therefore
compiles every new kernel variant in a child process that stays alive for the
parent's lifetime (``python -m clphong.device.buildchild --device P:D``): the parent
sends one JSON request a line (entry file, build options, where to write the
binary), the child compiles in-process and writes the program's binary
(CL_PROGRAM_BINARIES), and the parent loads that binary in-process, as it loads a
cached one. A child that dies is reported as :class:`VariantCrash` with the
signal and LLVM's last line, and the next request starts a new child.

:func:`run_child` runs a one-shot child module the same way (the self-test).
"""

from __future__ import annotations

import atexit
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import threading

from ..core.errors import DeviceError

#: Set in every child's environment: a child compiles in-process and self-tests nothing.
CHILD_ENV = "CLPHONG_OPENCL_CHILD"


class VariantCrash(DeviceError):
    """A child building or testing a kernel variant died (a signal, or no answer).
    ``transient``: it was interrupted or timed out, which says nothing of the variant."""

    transient = False


#: Signals that end a child from outside (a user's ^C, a job's kill): not the variant's fault.
_OUTSIDE = {-signal.SIGINT, -signal.SIGTERM, -signal.SIGKILL, -signal.SIGHUP}


def _crash(message: str, returncode: int | None) -> VariantCrash:
    exc = VariantCrash(message)
    exc.transient = returncode is None or returncode in _OUTSIDE
    return exc


def in_child() -> bool:
    return os.environ.get(CHILD_ENV) == "1"


#: Intel's CPU runtime re-vectorises kernels across work-items by a heuristic
#: (CL_CONFIG_CPU_VECTORIZER_MODE=0), which halved the fast path at 16 lanes on Zen 5
#: (0.76 against 1.52 GPLE/s, 1080p x 256 lights, measured side by side): clphong's lane
#: kernels are vectorised by hand, so its compiling children keep the explicit vectors
#: (mode 1; the same speed at 1 lane). A user's own setting is kept. PoCL ignores it.
#: Kernels written one scalar work-item at a time (kernels/node_bound.cl: the tree's
#: bounds and cut, in double) are the other way round: the runtime's own vectoriser
#: across work-items runs them 2-4× faster (its heuristic, mode 0: node_terms 25 against
#: 6 M pairs/s, tile_cut 1.1 against 2.5 s a 1080p frame on Ice Lake), so they compile
#: in a child of that mode (``implicit``). Intel's runtime reads the mode once, when a
#: process starts: hence a child per mode. PyOpenCL's binary cache does not see the
#: mode, so the runtime adds it to such a program's options (Runtime.program).
INTEL_VECTORIZER_ENV = "CL_CONFIG_CPU_VECTORIZER_MODE"
INTEL_VECTORIZER_MODE = "1"
INTEL_IMPLICIT_MODE = "0"
#: The kernel files of that kind.
IMPLICIT_VECTOR_KERNELS = frozenset({"node_bound.cl"})


def intel_vectorizer_mode(implicit: bool = False) -> str:
    """The mode Intel's runtime compiles clphong's kernels with (part of the binary key):
    the user's own setting, else mode 1, or 0 for a kernel vectorised by the runtime
    (``implicit``)."""
    return os.environ.get(INTEL_VECTORIZER_ENV,
                          INTEL_IMPLICIT_MODE if implicit else INTEL_VECTORIZER_MODE)


def _child_env(mode: str | None = None) -> dict:
    env = dict(os.environ)
    env[CHILD_ENV] = "1"
    env[INTEL_VECTORIZER_ENV] = intel_vectorizer_mode() if mode is None else mode
    return env


def death(returncode: int, stderr: str) -> str:
    """How a child ended, in words: ``SIGABRT (LLVM ERROR: Cannot select ...)``."""
    if returncode < 0:
        try:
            how = signal.Signals(-returncode).name
        except ValueError:
            how = f"signal {-returncode}"
    else:
        how = f"exit status {returncode}"
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    llvm = [ln for ln in lines if "LLVM ERROR" in ln or "error" in ln.lower()]
    last = (llvm or lines or [""])[-1]
    return f"{how} ({last[:200]})" if last else how


def run_child(module: str, args: list[str], *, timeout: float, what: str) -> str:
    """Run ``python -m module args`` as a child and return its stdout; a child killed by
    a signal, timed out or failing raises :class:`VariantCrash` naming ``what``."""
    try:
        done = subprocess.run([sys.executable, "-m", module, *args], env=_child_env(),
                              stdin=subprocess.DEVNULL, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        raise _crash(f"{what}: no answer in {timeout:.0f} s", None) from None
    if done.returncode != 0:
        raise _crash(f"{what}: the child process ended by {death(done.returncode, done.stderr)}",
                     done.returncode)
    return done.stdout


#: A kernel variant compiles in 0.2-30 s; no answer in this long is a hung compiler.
BUILD_TIMEOUT_S = 600.0


class BuildChild:
    """One long-lived child compiling for one device; :meth:`build` is serialised."""

    #: The child's module (``python -m``); a test points it at one that aborts.
    module = "clphong.device.buildchild"

    def __init__(self, selector: str, mode: str | None = None):
        self.selector = selector
        self.mode = mode                       # Intel's vectoriser mode (None: the default)
        self._proc: subprocess.Popen | None = None
        self._err = None
        self._lock = threading.Lock()

    def _start(self) -> subprocess.Popen:
        self._err = tempfile.TemporaryFile(mode="w+")
        self._proc = subprocess.Popen(
            [sys.executable, "-m", self.module, "--device", self.selector],
            env=_child_env(self.mode), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=self._err,
            text=True, bufsize=1)
        return self._proc

    def build(self, entry_file: str, opts: list[str], out: str, what: str) -> None:
        """Compile ``entry_file`` with ``opts`` in the child, its binary written to ``out``.
        A build error raises :class:`DeviceError` with the compiler's first error line."""
        with self._lock:
            if self._proc is not None and self._proc.poll() is not None:
                self._reap()                   # a child that ended since the last build
            proc = self._proc or self._start()
            try:
                proc.stdin.write(json.dumps({"entry": entry_file, "opts": opts, "out": out}) + "\n")
                proc.stdin.flush()
                ready, _, _ = select.select([proc.stdout], [], [], BUILD_TIMEOUT_S)
                if not ready:                  # a compiler that hangs: end it, say so
                    proc.kill()
                    self._reap()
                    raise _crash(f"{what}: the compiler gave no answer in {BUILD_TIMEOUT_S:.0f} s",
                                 None)
                line = proc.stdout.readline()
            except (BrokenPipeError, OSError):
                line = ""
            if not line:
                rc, stderr = self._reap()
                raise _crash(f"{what}: the compiler's process ended by {death(rc, stderr)}", rc)
            answer = json.loads(line)
            if answer.get("error"):
                raise DeviceError(answer["error"])

    def _reap(self) -> tuple[int, str]:
        """Wait for the ended (or killed) child, close its pipes; (return code, its stderr)."""
        proc, self._proc = self._proc, None
        rc = proc.wait()
        stderr = ""
        for stream in (proc.stdin, proc.stdout):
            try:
                stream.close()
            except OSError:
                pass
        if self._err is not None:
            self._err.seek(0)
            stderr = self._err.read()
            self._err.close()
            self._err = None
        return rc, stderr

    def close(self) -> None:
        if self._proc is None:
            return
        try:
            self._proc.stdin.close()           # the child's loop ends at end of input
            self._proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            self._proc.kill()
        self._reap()


_CHILDREN: dict[tuple, BuildChild] = {}


def build_child(selector: str, mode: str | None = None) -> BuildChild:
    """The compiling child for ``selector`` whose Intel vectoriser mode is ``mode``
    (None: :func:`intel_vectorizer_mode`'s default)."""
    child = _CHILDREN.get((selector, mode))
    if child is None:
        child = _CHILDREN[(selector, mode)] = BuildChild(selector, mode)
    return child


@atexit.register
def _close_children() -> None:
    for child in list(_CHILDREN.values()):
        child.close()
