"""Frames as tasks on a Dask distributed cluster (``clphong relight --scheduler ADDRESS``).

Dask is an optional extra (``pip install "clphong[dask]"``) and is imported
only here, only when a scheduler is given; local batches never import it.

Each frame (with all its rigs) is one task, :func:`clphong.pipeline.batch.relight_job`.
The task carries the rigs' :class:`~clphong.pipeline.relighter.RelighterSpec` (the validated
scenes and options, a few kB); on each worker process
:func:`clphong.pipeline.relighter.cached_relighter` builds and compiles the relighter on the
first task and reuses it for every later one. Workers read the G-buffers and
write the outputs themselves, so inputs and outputs must be on storage that
every worker sees under the same paths (the usual farm file server).

A farm runs ``dask scheduler`` on one host and ``dask worker tcp://HOST:8786``
on each render node (with ``--nworkers 1 --nthreads 1``: PoCL already uses
every core of a node), then::

    clphong relight shot/gbuf.####.exr --rig key.toml -o out/{rig}.####.exr \\
        --scheduler tcp://HOST:8786
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from ..core.errors import ClphongError
from ..model.options import check_number
from .jobs import Job, Outcome, failed_outcomes, relight_job

__all__ = ["run_on_dask", "SchedulerError"]


class SchedulerError(ClphongError):
    """The Dask scheduler cannot be reached, or Dask is not installed."""


#: Seconds to connect to a scheduler and hear its handshake (``--scheduler-timeout``).
CONNECT_TIMEOUT_S = 20.0


def _probe(address: str, timeout: float) -> None:
    """Connect to a ``tcp://`` scheduler address and wait for the first bytes of its
    handshake (a Dask scheduler writes its own at once), all within ``timeout`` seconds.

    Dask's own client waits without limit for a peer that accepts the connection and
    never speaks, and reported an unroutable address as "out of memory" then a
    traceback 40 s later: this check runs first, so each case is one line naming
    the address and the cause. Other schemes (tls://, inproc://) are left to Dask."""
    import socket
    import time
    from urllib.parse import urlsplit

    if "://" in address and not address.startswith("tcp://"):
        return
    try:
        parts = urlsplit(address if "://" in address else f"tcp://{address}")
        host, port = parts.hostname, parts.port or 8786
    except ValueError as exc:
        raise SchedulerError(f"Dask scheduler address {address!r}: {exc}") from None
    if not host:
        raise SchedulerError(f"Dask scheduler address {address!r}: no host; write tcp://HOST:PORT")
    deadline = time.monotonic() + timeout
    stage = "connect"
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            stage = "handshake"
            sock.settimeout(max(deadline - time.monotonic(), 0.001))
            first = sock.recv(1)
    except socket.timeout:
        cause = (f"no answer to the connection in {timeout:g} s (an unroutable or filtered "
                 "address?)" if stage == "connect" else
                 f"it accepted the connection but sent nothing in {timeout:g} s (not a Dask "
                 "scheduler, or a hung one)")
        raise SchedulerError(f"cannot connect to the Dask scheduler at {address}: {cause}; check "
                             "the address, or raise --scheduler-timeout") from None
    except OSError as exc:
        raise SchedulerError(f"cannot connect to the Dask scheduler at {address}: "
                             f"{exc.strerror or exc}") from None
    if not first:
        raise SchedulerError(f"the Dask scheduler at {address} closed the connection without a "
                             "handshake (not a Dask scheduler?)")


def _client(scheduler, timeout: float = CONNECT_TIMEOUT_S):
    try:
        from distributed import Client
    except ImportError:
        raise SchedulerError("--scheduler needs Dask: pip install 'clphong[dask]' "
                             "(dask[distributed])") from None
    if not isinstance(scheduler, str):
        return scheduler, False                      # a Client the caller owns
    _probe(scheduler, timeout)
    try:
        return Client(scheduler, timeout=f"{timeout}s", set_as_default=False), True
    except (OSError, TimeoutError, ValueError) as exc:
        raise SchedulerError(f"cannot connect to the Dask scheduler at {scheduler}: "
                             f"{' '.join(str(exc).split())}") from None


def run_on_dask(jobs: Sequence[Job], specs: dict, scheduler, on_outcomes: Callable[[list[Outcome]], None],
                *, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Run every job as a task on a Dask cluster; report outcomes as tasks finish.

    Parameters
    ----------
    jobs : sequence of Job
    specs : dict of str to RelighterSpec
    scheduler : str or distributed.Client
        Scheduler address (``tcp://host:8786``) or an existing client.
    on_outcomes : callable
        Called with the outcomes of each finished job.
    timeout : float
        Seconds to connect to the scheduler and hear its handshake; then a
        :class:`SchedulerError` naming the address and the cause.

    Notes
    -----
    A task that raises (a worker lost, a bug) is reported as failed outcomes
    for its frame; the other tasks carry on. On an interrupt the pending
    tasks are cancelled and a client we opened is closed.
    """
    timeout = check_number(timeout, "--scheduler-timeout", SchedulerError)   # as the CLI says it
    client, owned = _client(scheduler, timeout)     # first: it explains a missing Dask
    futures = {}
    try:
        from distributed import as_completed

        # Scatter the specs once (broadcast), rather than pickling them into every task.
        [specs_f] = client.scatter([specs], broadcast=True, hash=False)
        for job in jobs:
            fut = client.submit(relight_job, job, specs_f, pure=False,
                                key=f"clphong-frame-{job.frame}-{id(job):x}")
            futures[fut] = job
        for fut in as_completed(list(futures), loop=client.loop):
            job = futures[fut]
            try:
                outs = fut.result()
            except Exception as exc:  # noqa: BLE001 - a lost worker must not stop the batch
                reason = f"Dask task failed: {type(exc).__name__}: {' '.join(str(exc).split())}"
                outs = failed_outcomes(job, reason)
            on_outcomes(outs)
            fut.release()
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending)
        if owned:
            client.close()
