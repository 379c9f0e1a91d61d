"""One job of a batch: a frame of the sequence, with every rig's outputs.

A :class:`Job` is read once (:func:`load_job`), then shaded and written once per
rig (:func:`shade_job`); :func:`relight_job` does both with this process's
cached relighters and is the entry point of pool workers and Dask tasks. A
failure is an :class:`Outcome`, never an exception, so the other frames of a
batch still complete. Each outcome carries the seconds of its stages (read,
shade, write), which the batch summary reports.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

from ..core.errors import ClphongError
from ..core.signals import raised
from ..deliver.outputs import OutputPaths
from ..io.gbuffer import read_gbuffer
from .relighter import cached_relighter, deliver_staged

__all__ = ["BatchError", "Interrupted", "Rig", "Job", "Outcome", "failed_outcomes", "load_job",
           "shade_job", "relight_job"]


class BatchError(ClphongError):
    """A batch cannot start: a bad sequence pattern, frame range, rig or output template."""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived during a batch; ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum

    @classmethod
    def handler(cls, signum, frame):
        """A signal handler that raises :class:`Interrupted` for ``signum`` (recorded:
        :func:`clphong.core.signals.raise_pending`)."""
        raise raised(cls(signum))


@dataclass(frozen=True)
class Rig:
    """A named light rig: a scene (camera, material, lights)."""

    name: str
    scene: object


@dataclass(frozen=True)
class Job:
    """One input frame and, per rig, the files still to write for it: (rig name, OutputPaths)."""

    frame: int
    source: str
    outputs: tuple[tuple[str, OutputPaths], ...]


@dataclass
class Outcome:
    """What happened to the outputs of one frame and rig.

    ``path`` is the first of its files (the EXR, if any); ``paths`` all of them.
    ``stages``: seconds of its stages, those that ran: ``"read"`` (the frame's
    G-buffer, shared by its rigs), ``"shade"``, ``"wait"`` (shaded, waiting for
    its turn to write) and ``"write"`` (every file).
    """

    frame: int
    source: str
    rig: str
    path: str
    ok: bool
    error: str | None = None
    seconds: float = 0.0
    paths: tuple[str, ...] = ()
    stages: dict = field(default_factory=dict, compare=False)


def _outcome(job: Job, rig: str, paths: OutputPaths, ok: bool, error: str | None = None,
             seconds: float = 0.0, stages: dict | None = None) -> Outcome:
    files = paths.files
    return Outcome(job.frame, job.source, rig, files[0] if files else "", ok, error, seconds, files,
                   dict(stages or {}))


def failed_outcomes(job: Job, reason: str) -> list[Outcome]:
    """Every output of ``job`` failed for ``reason`` (a worker died, a task was lost)."""
    return [_outcome(job, rig, paths, False, reason) for rig, paths in job.outputs]


def _reason(exc: BaseException) -> str:
    if isinstance(exc, ClphongError):
        text = str(exc)
    else:   # an unexpected failure still gets one line, with its type
        text = f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())


def load_job(job: Job, channels) -> object:
    """Read a job's G-buffer; return it, or the exception that reading raised."""
    try:
        return read_gbuffer(job.source, channels=channels)
    except Exception as exc:  # noqa: BLE001 - a bad frame must not stop the batch
        return exc


def shade_job(job: Job, gbuffer, relighters: dict, *, read_seconds: float | None = None,
              before_write=None, parallel: bool = False) -> list[Outcome]:
    """Shade and write every output of a job; a failure is recorded, not raised.

    Parameters
    ----------
    job : Job
    gbuffer : GBuffer or BaseException
        What :func:`load_job` returned (an exception fails every output of the job).
    relighters : dict of str to Relighter
    read_seconds : float, optional
        How long reading the G-buffer took (recorded in each outcome's ``stages``).
    before_write : callable, optional
        Called once per rig, after its shading and before its first file is written
        (:func:`clphong.pipeline.relighter.deliver_staged`). Only an exception that is
        not an ``Exception`` (an interrupt, a batch stopping) escapes from here: the
        outputs not yet written are then not written.
    parallel : bool
        Write each output's EXR in a thread of its own beside its display files
        (:func:`~clphong.pipeline.relighter.deliver_staged`).
    """
    outcomes = []
    read = {} if read_seconds is None else {"read": read_seconds}
    for rig, paths in job.outputs:
        t0 = time.perf_counter()
        if isinstance(gbuffer, BaseException):
            outcomes.append(_outcome(job, rig, paths, False, _reason(gbuffer), stages=read))
            continue
        try:
            for folder in {os.path.dirname(os.path.abspath(p)) for p in paths.files}:
                os.makedirs(folder, exist_ok=True)
            _, stages = deliver_staged(relighters[rig], gbuffer, paths, source=job.source,
                                       before_write=before_write, parallel=parallel)
            outcomes.append(_outcome(job, rig, paths, True, seconds=time.perf_counter() - t0,
                                     stages={**read, **stages}))
        except Exception as exc:  # noqa: BLE001
            outcomes.append(_outcome(job, rig, paths, False, _reason(exc), time.perf_counter() - t0,
                                     stages=read))
    return outcomes


def relight_job(job: Job, specs: dict) -> list[Outcome]:
    """Read, shade and write one job with this process's cached relighters (worker entry point)."""
    relighters = {}
    for rig, spec in specs.items():
        try:
            relighters[rig] = cached_relighter(spec)
        except Exception as exc:  # noqa: BLE001 - e.g. no OpenCL device on this worker
            return failed_outcomes(job, _reason(exc))
    channels = next(iter(specs.values())).channels if specs else ()
    t0 = time.perf_counter()
    gbuffer = load_job(job, dict(channels) or None)
    return shade_job(job, gbuffer, relighters, read_seconds=time.perf_counter() - t0)

