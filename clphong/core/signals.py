"""Which signals clphong turns into a clean stop (temporary outputs removed, exit 128 + N).

Every signal whose default action ends the process and that a Python handler can
safely take (signal(7)): without a handler it would end clphong in the middle of a
write and leave the hidden temporary file behind. Not in the list, and why:

* SIGKILL and SIGSTOP cannot be caught;
* SIGINT is Python's KeyboardInterrupt already;
* SIGPIPE and SIGXFSZ are ignored by Python, so a closed pipe or the file-size limit
  is an error (BrokenPipeError, exit 141; EFBIG, a failed write) instead;
* SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT, SIGTRAP and SIGSYS report a crash (or a
  debugger) in the process itself, where no Python code can run safely. A crash
  can leave a temporary file, which the next run of the same output removes.
"""

from __future__ import annotations

import contextlib
import signal
import threading

#: The asynchronous terminating signals by name (those this platform has are used).
TERMINATING = ("SIGTERM", "SIGHUP", "SIGQUIT", "SIGUSR1", "SIGUSR2", "SIGALRM", "SIGVTALRM",
               "SIGPROF", "SIGXCPU", "SIGIO", "SIGPWR", "SIGSTKFLT")


def terminating_signals() -> list[int]:
    """The signals of :data:`TERMINATING` on this platform, then the real-time signals
    (SIGRTMIN..SIGRTMAX), whose default action also ends the process. Left out: a
    signal ignored (SIG_IGN: ``nohup`` ignores SIGHUP, and it stays ignored) or
    handled by C code (a library's own handler, which Python reports as None)."""
    out = [getattr(signal, name) for name in TERMINATING if hasattr(signal, name)]
    if hasattr(signal, "SIGRTMIN") and hasattr(signal, "SIGRTMAX"):
        out += list(range(signal.SIGRTMIN, signal.SIGRTMAX + 1))
    return [sig for sig in dict.fromkeys(out)
            if signal.getsignal(sig) not in (None, signal.SIG_IGN)]


def signal_name(signum: int) -> str:
    """``SIGTERM``; ``SIGRTMIN+3`` for a real-time signal."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        rtmin = getattr(signal, "SIGRTMIN", None)
        return f"SIGRTMIN+{signum - rtmin}" if rtmin is not None else f"signal {signum}"


#: The exception a signal handler of clphong's raised last, until someone acts on it.
_pending: BaseException | None = None


def raised(exc: BaseException) -> BaseException:
    """What a signal handler raises, recorded first (see :func:`raise_pending`)."""
    global _pending
    _pending = exc
    return exc


def clear_pending() -> None:
    """The signal was acted on (the batch stops, the worker exits): nothing to raise again."""
    global _pending
    _pending = None


def raise_pending() -> None:
    """Raise again a signal's exception that C code swallowed; nothing if none (or not in
    the main thread, where handlers run).

    A Python signal handler runs at the main thread's next bytecode, which may be in
    Python code that C code called: a ``__getattr__`` that pyopencl probes with
    ``PyObject_HasAttr``, which clears every exception, was seen to drop a SIGTERM that
    way, and the worker ran on as if no signal had come. The handlers record what they
    raise (:func:`raised`); the checkpoints (between frames, before an output replaces
    its file) call this.
    """
    global _pending
    if _pending is None or threading.current_thread() is not threading.main_thread():
        return
    exc, _pending = _pending, None
    raise exc


class Terminated(KeyboardInterrupt):
    """A terminating signal (SIGTERM, SIGHUP, SIGQUIT, ...), raised like Ctrl-C so that
    every cleanup (temporary outputs) runs; the CLI exits 128 + its number."""

    def __init__(self, signum: int = 15, name: str = "SIGTERM"):
        super().__init__(name)
        self.signum, self.name = signum, name


@contextlib.contextmanager
def signals_as_interrupt():
    """Turn every catchable terminating signal (:func:`terminating_signals`) into
    :class:`Terminated` while the block runs (main thread only; elsewhere nothing), and
    record Ctrl-C's KeyboardInterrupt as they are recorded (:func:`raise_pending`).

    Their default actions end the process at once (SIGQUIT with a core dump),
    which would leave a half-written temporary output (``.NAME.tmp-XXXX.exr``)
    behind.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _raise(signum, frame):
        raise raised(Terminated(signum, signal_name(signum)))

    def _interrupt(signum, frame):
        raise raised(KeyboardInterrupt())

    previous = {}
    try:
        for sig in terminating_signals():
            previous[sig] = signal.signal(sig, _raise)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            previous[signal.SIGINT] = signal.signal(signal.SIGINT, _interrupt)    # Ctrl-C, recorded
    except (ValueError, OSError):          # no signals here (e.g. an embedded interpreter)
        for sig, old in previous.items():
            signal.signal(sig, old)
        yield
        return
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
        clear_pending()
