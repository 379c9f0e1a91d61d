"""A batch's pool of worker processes (``clphong relight --jobs N``).

:func:`run_pool` hands each spawned worker its jobs over the worker's own pipe
and so always knows which jobs a worker holds; a worker that dies has its job
retried once elsewhere and is replaced (:class:`_Pool`). A worker
(:func:`_worker_main`) relights each job it is sent with its own cached
relighters (:func:`clphong.pipeline.jobs.relight_job`).
"""

from __future__ import annotations

import collections
import os
import signal
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from ..core.memory import ENV_VAR, memory_budget
from ..core.signals import raise_pending, signal_name, terminating_signals
from ..io.atomic import remove_live_temporaries
from .jobs import Interrupted, Job, failed_outcomes, relight_job
from .paths import remove_job_temporaries

__all__ = ["run_pool", "worker_environment"]


def worker_environment(n: int) -> dict[str, str]:
    """What each of ``n`` pool workers sets in its environment (where not set
    already): its share of the cores for PoCL, and its share of the memory this
    process may use (clphong.device.bands), so that n workers together plan within it."""
    env = {"POCL_CPU_MAX_CU_NUM": str(max(1, (os.cpu_count() or 1) // n))}
    budget = memory_budget().bytes
    if budget is not None and ENV_VAR not in os.environ:
        env[ENV_VAR] = str(max(1, budget // n))
    return env


def _worker_main(conn, specs, env: dict[str, str]) -> None:  # pragma: no cover - subprocess
    """A pool worker: relight the jobs that arrive on ``conn`` until a None (or the batch process is gone).

    Replies ``(index, outcomes, warnings)`` per job; the warnings (say, non-finite
    inputs) are shown by the batch process, as in a one-process batch. SIGTERM
    or SIGINT end the worker with exit status 128 + the signal number, after
    removing the temporary file of a write in flight.
    """
    for key, value in env.items():      # N workers share the machine: worker_environment
        os.environ.setdefault(key, value)
    for sig in terminating_signals():
        signal.signal(sig, Interrupted.handler)
    try:
        while True:
            try:
                item = conn.recv()
            except (EOFError, OSError):       # the batch process was killed: do not run on orphaned
                return
            if item is None:
                return
            index, job = item
            with warnings.catch_warnings(record=True) as caught:
                outcomes = relight_job(job, specs)
            raise_pending()                   # a signal C code swallowed: this job is retried
            shown = [(w.category, str(w.message), w.filename, w.lineno) for w in caught]
            try:
                try:
                    conn.send((index, outcomes, shown))
                except (AttributeError, TypeError, ValueError):     # a warning class that cannot be pickled
                    conn.send((index, outcomes, [(UserWarning, *w[1:]) for w in shown]))
            except OSError:                   # the batch process is gone
                return
    except KeyboardInterrupt as exc:
        remove_live_temporaries()     # a write the interrupt caught before its own cleanup could
        sys.exit(128 + int(getattr(exc, "signum", signal.SIGINT)))
    finally:
        # Nothing is being written any more: a late SIGTERM may simply end the process.
        for sig in terminating_signals():
            signal.signal(sig, signal.SIG_DFL)


def _death(exitcode: int | None) -> str:
    """How a worker process ended, for messages: 'killed by SIGKILL', 'SIGTERM, exit code 143'."""
    if exitcode is not None and exitcode < 0:
        try:
            return f"killed by {signal_name(-exitcode)}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    if exitcode is not None and exitcode > 128:
        try:
            return f"{signal_name(exitcode - 128)}, exit code {exitcode}"
        except ValueError:
            pass
    return f"exit code {exitcode}"


@dataclass
class _Worker:
    proc: object
    conn: object
    held: list[int] = field(default_factory=list)   # indices of the jobs sent to it, oldest (running) first


#: Jobs sent ahead to a pool worker (the one it runs and the next), so that it never waits for work.
_AHEAD = 2


class _Pool:
    """The worker processes of one batch, and the jobs each one holds (see :func:`run_pool`)."""

    def __init__(self, jobs: Sequence[Job], specs: dict, n: int, on_outcomes: Callable,
                 on_retry: Callable[[Job, str], None] | None):
        import multiprocessing as mp

        self.ctx = mp.get_context("spawn")
        self.jobs, self.specs, self.n = jobs, specs, n
        self.on_outcomes, self.on_retry = on_outcomes, on_retry
        self.env = worker_environment(n)
        self.pending = collections.deque(range(len(jobs)))
        self.undone = set(range(len(jobs)))
        self.first_death: dict[int, str] = {}    # job index -> how its first worker died
        self.workers: dict[int, _Worker] = {}    # by process sentinel
        self.registry: dict = {}                 # warnings shown (as a module's __warningregistry__)
        # Each death charges a try to a job (two each), so this many workers is ample; a limit all
        # the same, so that workers that die before taking any job cannot be replaced forever.
        self.spawns_left = n + 2 * len(jobs)

    def spawn(self):
        self.spawns_left -= 1
        here, there = self.ctx.Pipe()
        p = self.ctx.Process(target=_worker_main, args=(there, self.specs, self.env), daemon=True)
        p.start()
        there.close()                            # so that this end reads EOF once the worker is gone
        self.workers[p.sentinel] = _Worker(p, here)

    def fill(self):
        """Spawn workers up to ``n`` while jobs wait, and feed each one."""
        while self.pending and len(self.workers) < self.n and self.spawns_left > 0:
            self.spawn()
        for w in self.workers.values():
            self.feed(w)

    def finish(self, i, outcomes):
        if i in self.undone:
            self.undone.discard(i)
            self.on_outcomes(outcomes)

    def feed(self, w):
        # One job ahead while there are enough for every worker: near the end a
        # worker holding two frames would leave another idle.
        pending = self.pending
        while pending and (not w.held or (len(w.held) < _AHEAD
                                          and len(pending) >= len(self.workers))):
            i = pending.popleft()
            try:
                w.conn.send((i, self.jobs[i]))
            except OSError:                      # it is dying: its sentinel says so next
                pending.appendleft(i)
                return
            w.held.append(i)

    def receive(self, w) -> bool:
        """Take every reply ``w`` has sent; False once its pipe is closed (it has ended)."""
        while True:
            try:
                if not w.conn.poll():
                    return True
                i, outcomes, shown = w.conn.recv()
            except (EOFError, OSError):
                return False
            if i in w.held:
                w.held.remove(i)
            for category, message, filename, lineno in shown:
                warnings.warn_explicit(message, category, filename, lineno, registry=self.registry)
            self.finish(i, outcomes)

    def bury(self, w):
        del self.workers[w.proc.sentinel]
        w.proc.join()
        w.conn.close()
        how = _death(w.proc.exitcode)
        for i in w.held:
            remove_job_temporaries(self.jobs[i])
        if w.held:
            i, rest = w.held[0], w.held[1:]
            if i in self.first_death:
                self.finish(i, failed_outcomes(self.jobs[i], f"worker process died twice running "
                                                             f"it ({self.first_death[i]}, then {how})"))
            else:
                self.first_death[i] = how
                if self.on_retry is not None:
                    self.on_retry(self.jobs[i], f"worker process died ({how})")
                rest = [i, *rest]
            self.pending.extendleft(reversed(rest))

    def close(self, finished: bool):
        """End the workers: told to exit when every job is done, else SIGTERM (each unwinds and
        removes its temporary file), then SIGKILL after 10 s."""
        procs = [w.proc for w in self.workers.values()]
        if finished:
            for w in self.workers.values():
                try:
                    w.conn.send(None)
                except OSError:
                    pass
            for p in procs:
                p.join(10)
        for p in procs:
            if p.is_alive():
                p.terminate()
        deadline = time.monotonic() + 10
        for p in procs:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join()
        for w in self.workers.values():
            w.conn.close()


def run_pool(jobs: Sequence[Job], specs: dict, n: int, on_outcomes: Callable,
              on_retry: Callable[[Job, str], None] | None = None) -> None:
    """N worker processes (spawned: OpenCL and threads do not survive fork).

    This process hands each worker its jobs over the worker's own pipe, so it
    always knows which jobs a worker holds. A worker that ends while holding
    jobs, whatever its exit status, has died: the temporary files of those
    jobs' outputs are removed, the job it was running is retried once on
    another worker (``on_retry`` is told) and fails the second time, the
    others are sent to other workers, and a new worker replaces it.
    """
    from multiprocessing.connection import wait

    pool = _Pool(jobs, specs, max(1, min(n, len(jobs))), on_outcomes, on_retry)
    finished = False
    try:
        pool.fill()
        while pool.undone:
            workers = pool.workers
            if not workers:                      # safety net: never wait on no one
                for i in sorted(pool.undone):
                    pool.finish(i, failed_outcomes(jobs[i], "no worker process left to run it"))
                break
            ready = set(wait([w.conn for w in workers.values()] + list(workers), timeout=1.0))
            for w in list(workers.values()):
                if w.conn in ready or w.proc.sentinel in ready:
                    if not pool.receive(w) or w.proc.sentinel in ready:
                        pool.receive(w)          # what it sent before it ended
                        pool.bury(w)
            pool.fill()
        finished = True
    finally:
        pool.close(finished)
