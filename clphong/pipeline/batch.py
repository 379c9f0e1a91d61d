"""Batch relighting: frame sequences × light rigs → one output per frame per rig.

Sequences
---------
An input is a frame pattern or a folder:

* ``shot/gbuf.####.exr``: each ``#`` is one digit of zero padding
  (``####`` → ``0001``; longer numbers are written in full);
* ``shot/gbuf.%04d.exr`` (printf style; ``%d`` for no padding);
* ``shot/`` (a folder): every ``*.exr`` in it (hidden files aside) is a frame,
  numbered by the digits at the end of its own file stem (``gbuf.0012.exr``
  is frame 12). A file without such a number (``notes.exr``), or two files
  with the same number (two sequences in one folder), is an error naming the
  file(s), never a silent renumbering: give a pattern to pick one sequence;
* a single file: a one-frame sequence.

Without ``frames=`` the frames are those found on disk. With it (a
:class:`~clphong.pipeline.frames.FrameRange` such as ``1-240x2``) the frames on
disk that are in the range are relit, and the range's frames without a file are
counted (:attr:`BatchPlan.missing`; the CLI says how many and exits 1), never
listed one by one: a range of 10⁹ frames costs what the files on disk cost.

Outputs
-------
Each frame and rig is delivered as any combination of a scene-linear EXR, SDR
PNG/TIFF, HDR PQ PNG/JPEG XL and a contact sheet, all from one shading
through :func:`clphong.deliver.outputs.render_outputs` (the output step of
``clphong render``), with the rig's :class:`~clphong.deliver.outputs.OutputOptions`
(its scene's ``[render]`` colour settings, overridable). Each kind has an
output template: a path with the fields ``{frame}`` (an int: use
``{frame:04d}``), ``{rig}``, ``{stem}`` (input file name without extension)
and ``{name}`` (``{stem}`` without its frame number), which may use ``####``
or ``%04d`` for the frame. Folders are created as needed. Each file is written
to a temporary name in its folder and renamed into place, so an output path
either holds a complete image or does not exist; an interrupted run leaves
no partial file. A frame and rig is complete when all its files exist: a
rerun with ``skip_existing`` skips those and writes the missing files of the
others (temporary files left by a killed run are removed first).

Execution
---------
``jobs=1`` relights in this process with its stages overlapped: the next frame
is read in a thread while the current one shades and the previous one is
written (at most one frame read ahead and one being written; frames are written
and reported in order; OpenImageIO and the OpenCL queue release the GIL).
``jobs=N`` runs N worker processes; a worker that dies (killed, crashed) has
the temporary files of its frame removed and that frame retried once on
another worker, then reported failed. ``scheduler=ADDRESS`` sends each frame as
a task to a Dask distributed cluster (:mod:`clphong.pipeline.distributed`). Every
worker builds its :class:`~clphong.pipeline.relighter.Relighter` per rig once and reuses it.
One bad frame never stops a batch: its failure is recorded with the reason,
the others complete, and :attr:`BatchResult.failed` lists them.
"""

from __future__ import annotations

import collections
import os
import queue
import signal
import statistics
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

from ..core.errors import ClphongError
from ..core.signals import clear_pending, raise_pending, signal_name, terminating_signals
from ..deliver.outputs import OutputPaths, check_extensions
from ..io.atomic import remove_live_temporaries
from .distributed import CONNECT_TIMEOUT_S, run_on_dask
from .frames import (
    _check_template,
    _first_missing,
    _range_size,
    _short_frames,
    expand_sequence,
    format_output,
    parse_frame_range,
)
from .jobs import (
    BatchError,
    Interrupted,
    Job,
    Outcome,
    Rig,
    failed_outcomes,
    load_job,
    relight_job,
    shade_job,
)
from .paths import (
    check_output_folder,
    check_rig_name,
    remove_job_temporaries,
    remove_stale_temporaries,
    stale_temporaries,
)
from .pool import run_pool
from .relighter import cached_relighter

__all__ = ["BatchError", "Rig", "Job", "Outcome", "BatchPlan", "BatchResult", "Interrupted",
           "parse_frame_range", "expand_sequence", "format_output", "plan_batch", "run_batch",
           "relight_job", "stale_temporaries", "remove_stale_temporaries", "failed_outcomes"]


# --------------------------------------------------------------------------- plan

@dataclass
class BatchPlan:
    """The jobs to run, and what already exists.

    ``skipped``: (frame, rig, OutputPaths) of each complete frame and rig
    (every file exists); ``kept``: (frame, rig, path) of existing files of an
    incomplete one (its job writes only the missing files).
    """

    jobs: list[Job]
    skipped: list[tuple[int, str, OutputPaths]] = field(default_factory=list)
    kept: list[tuple[int, str, str]] = field(default_factory=list)
    #: Frames of ``frames=`` with no file on disk (counted, never listed), and the first few.
    missing: int = 0
    missing_first: list[int] = field(default_factory=list)
    frames_text: str = ""

    def missing_line(self) -> str:
        """``3 frame(s) of --frames 1-10 have no file (first: 5, 6, 7)``, or ''."""
        if not self.missing:
            return ""
        first = ", ".join(map(str, self.missing_first))
        more = ", ..." if self.missing > len(self.missing_first) else ""
        return (f"{self.missing} frame(s) of --frames {self.frames_text} have no file "
                f"(first: {first}{more})")

    @property
    def outputs(self) -> int:
        """Frames × rigs to deliver (the unit of progress and of the summary)."""
        return sum(len(j.outputs) for j in self.jobs)

    @property
    def files(self) -> int:
        """Files to write."""
        return sum(len(p) for j in self.jobs for _, p in j.outputs)


def plan_batch(sequence: str, rigs: Sequence[Rig], template: str | None = None, *,
               sdr: Sequence[str] = (), hdr: Sequence[str] = (), contact_sheet: Sequence[str] = (),
               frames: Sequence[int] | None = None, skip_existing: bool = False) -> BatchPlan:
    """Expand the sequence, name every output, and drop those that exist (with ``skip_existing``).

    Parameters
    ----------
    sequence : str
        Frame pattern or folder (see the module docstring).
    rigs : sequence of Rig
    template : str, optional
        Template of the scene-linear EXR of each frame and rig.
    sdr, hdr, contact_sheet : sequence of str
        Templates of the SDR (``.png``/``.tif``), HDR (``.png``/``.jxl``) and
        contact-sheet files of each frame and rig (a single string is one template).
    frames : FrameRange or sequence of int, optional
        The frames to relight among those on disk; those with no file are counted
        in :attr:`BatchPlan.missing`.
    skip_existing : bool
        Skip a frame and rig whose files all exist; write only the missing
        files of one whose files partly exist.

    Raises
    ------
    BatchError
        No output template, a template with a bad field or extension, two
        outputs with the same path (a template without ``{rig}`` for several
        rigs, or without a frame for several frames), or an output that would
        overwrite an input.
    """
    if not rigs:
        raise BatchError("no light rig given; pass at least one scene file with --rig")
    for r in rigs:
        check_rig_name(r.name)
    names = [r.name for r in rigs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise BatchError(f"rig name {sorted(dup)[0]!r} is used twice; name rigs with --rig NAME=SCENE.toml")
    templates = OutputPaths(exr=template, sdr=sdr, hdr=hdr, contact_sheet=contact_sheet)
    if not templates:
        raise BatchError("no output template given; give -o OUT.####.exr, --sdr OUT.####.png, "
                         "--hdr OUT.####.png or --contact-sheet OUT.####.png")
    for t in templates.files:
        _check_template(t)
    try:
        check_extensions(templates)
    except ClphongError as exc:
        raise BatchError(f"output template {exc}") from None
    pairs = expand_sequence(sequence, frames)
    owner: dict[str, tuple[int, str]] = {}
    inputs = {os.path.abspath(p): f for f, p in pairs}
    plan = BatchPlan([])
    if frames is not None:
        plan.missing = _range_size(frames) - len(pairs)
        if plan.missing:
            plan.missing_first = _first_missing(frames, [f for f, _ in pairs])
        plan.frames_text = _short_frames(frames)
    for frame, src in pairs:
        outs = []
        for rig in rigs:
            def name(kind, tmpl):
                return format_output(tmpl, frame=frame, rig=rig.name, source=src)

            paths = templates.map(name)
            for path, tmpl in zip(paths.files, templates.files):
                key = os.path.abspath(path)
                if key in owner:
                    f0, r0 = owner[key]
                    raise BatchError(f"output template {tmpl!r} gives {path} for both frame {f0} rig "
                                     f"{r0!r} and frame {frame} rig {rig.name!r}; add {{rig}} or #### "
                                     "to it (or give each output kind its own name)")
                owner[key] = (frame, rig.name)
                if key in inputs:
                    raise BatchError(f"{path}: output would overwrite the input of frame {inputs[key]}; "
                                     "choose another output template")
            if skip_existing:
                exist = [p for p in paths.files if os.path.isfile(p)]
                if len(exist) == len(paths):
                    plan.skipped.append((frame, rig.name, paths))
                    continue
                plan.kept.extend((frame, rig.name, p) for p in exist)
                paths = paths.only(p for p in paths.files if p not in exist)
            outs.append((rig.name, paths))
        if outs:
            plan.jobs.append(Job(frame, src, tuple(outs)))
    for folder in sorted({os.path.dirname(p) for _, paths in
                          ((r, ps) for job in plan.jobs for r, ps in job.outputs) for p in paths.files}):
        check_output_folder(folder)
    return plan


# --------------------------------------------------------------------------- running


@dataclass
class BatchResult:
    outcomes: list[Outcome]
    skipped: int
    seconds: float
    stale_removed: int = 0
    interrupted: int | None = None          # the signal number, if interrupted
    #: (frame, source, reason) of each frame retried because its worker process died.
    retried: list[tuple[int, str, str]] = field(default_factory=list)

    @property
    def written(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.ok]

    @property
    def failed(self) -> list[Outcome]:
        return [o for o in self.outcomes if not o.ok]

    def stage_seconds(self) -> dict[str, float]:
        """Median seconds per output written of each stage the outcomes timed: ``"read"``
        (the frame's G-buffer), ``"shade"`` and ``"write"`` (every file of the output).
        Overlapped (one process), the slowest of them bounds the rate; {} when none was timed."""
        out = {}
        for stage in STAGES:
            times = [o.stages[stage] for o in self.written if stage in o.stages]
            if times:
                out[stage] = statistics.median(times)
        return out

    def summary(self) -> list[str]:
        """Lines for stderr: totals, retries, then one line per failed frame with the reasons.

        The counts and the rate are of outputs: one per frame and rig (each
        with all its files), the unit of the progress bar too.
        """
        n_ok, n_bad = len(self.written), len(self.failed)
        rate = n_ok / self.seconds if self.seconds > 0 else 0.0
        head = (f"{n_ok} written, {self.skipped} skipped (exist), {n_bad} failed "
                f"in {self.seconds:.1f} s ({rate:.2f} outputs/s)")
        stages = self.stage_seconds()
        if stages:
            head += "; median s/output: " + ", ".join(f"{k} {v:.2f}" for k, v in stages.items())
        if self.stale_removed:
            head += f"; removed {self.stale_removed} temporary file(s) of an interrupted run"
        lines = [head]
        if self.interrupted:
            name = signal_name(self.interrupted)
            lines.append(f"interrupted by {name}: no partial files were left; rerun with "
                         "--skip-existing to finish")
        for frame, src, reason in self.retried:
            lines.append(f"retried frame {frame} ({src}) on another worker: {reason}")
        by_frame: dict[tuple[int, str], list[Outcome]] = {}
        for o in self.failed:
            by_frame.setdefault((o.frame, o.source), []).append(o)
        if by_frame:
            lines.append(f"failed: {n_bad} output(s) of {len(by_frame)} frame(s):")
        listed = []
        for (frame, src), outs in sorted(by_frame.items()):
            reasons = {o.error for o in outs}
            rigs = ", ".join(o.rig for o in outs)
            if len(reasons) == 1:
                listed.append(f"  frame {frame} ({src}) [{rigs}]: {reasons.pop()}")
            else:
                for o in outs:
                    listed.append(f"  frame {frame} ({src}) [{o.rig}]: {o.error}")
        if len(listed) > MAX_FAILURES_LISTED:
            more = len(listed) - MAX_FAILURES_LISTED
            listed = listed[:MAX_FAILURES_LISTED] + [f"  ... and {more} more"]
        return lines + listed


#: The stages whose median time per output the batch summary gives (:meth:`BatchResult.stage_seconds`).
STAGES = ("read", "shade", "write")

#: Failure lines of a batch summary listed in full; the rest are counted ("... and N more").
MAX_FAILURES_LISTED = 20


class _Signals:
    """Turn SIGINT and every catchable terminating signal (SIGTERM, SIGHUP, SIGUSR2, ...:
    :func:`clphong.core.signals.terminating_signals`) into :class:`Interrupted` in the
    main thread while active."""

    def __init__(self):
        self.old = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, *terminating_signals()):
                self.old[sig] = signal.signal(sig, Interrupted.handler)
        return self

    def __exit__(self, *exc):
        for sig, handler in self.old.items():
            signal.signal(sig, handler)
        return False


#: Frames shaded or written at once in one process: one shading while the one before it is written.
_IN_FLIGHT = 2
#: Seconds a stopping one-process batch waits for the frames in flight (at most a frame being
#: read, one being shaded and one being written) before it removes their temporary files.
_STOP_WAIT = 30.0


class _Stopped(BaseException):
    """The batch is stopping (an interrupt, an error): a frame not yet writing is abandoned."""


class _Frame:
    """One frame in flight in a one-process batch: shaded in a thread of its own, then
    written once the frame before it is done (or the batch stops: ``stop`` is set)."""

    def __init__(self, job, gbuffer, read_seconds, previous, relighters, stop: threading.Event):
        self.job, self.previous, self.relighters, self.stop = job, previous, relighters, stop
        self.done = threading.Event()        # written (or failed), and so is every frame before
        self.outcomes, self.error = None, None
        self.thread = threading.Thread(target=self.run, args=(gbuffer, read_seconds),
                                       name=f"clphong-frame-{job.frame}", daemon=True)

    def wait_previous(self, abandon: bool):
        prev = self.previous
        while prev is not None and not prev.done.wait(0.1):
            if self.stop.is_set():
                break
        if abandon and self.stop.is_set():
            raise _Stopped
        self.previous = None                 # no chain of finished frames kept alive

    def run(self, gbuffer, read_seconds):
        try:
            self.outcomes = shade_job(self.job, gbuffer, self.relighters,
                                      read_seconds=read_seconds,
                                      before_write=lambda: self.wait_previous(abandon=True),
                                      parallel=True)
        except _Stopped:
            pass
        except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
            self.error = exc
        finally:
            del gbuffer
            try:
                self.wait_previous(abandon=False)
            finally:
                self.done.set()


def _run_inline(jobs: Sequence[Job], specs: dict, on_outcomes: Callable, *,
                overlap: bool = True) -> None:
    """One process: reading, shading and writing of consecutive frames overlap.

    A reader thread reads frame i+1 while frame i shades and frame i-1 is
    written. Each frame is shaded, then written, by a thread of its own, at most
    :data:`_IN_FLIGHT` (2) at a time, and a frame starts writing only once every
    frame before it is written (:func:`~clphong.pipeline.relighter.deliver_staged`'s
    seam): frames are written one at a time, in order, and reported in order,
    from this (the main) thread. So at most one frame is read ahead, one shaded
    and one written; OpenImageIO and the OpenCL queue release the GIL. A frame's
    EXR is written in a thread beside its display files (SDR/HDR/contact sheet):
    with ``--sdr`` the single-threaded PNG encoder is otherwise the slowest stage.

    An interrupt (SIGINT/SIGTERM turned into :class:`Interrupted` in this thread)
    or any other exception here stops the batch: no further frame is read or
    shaded, a frame still shading is abandoned before its first file, and the
    frame being written is given up to :data:`_STOP_WAIT` seconds to finish (each
    file appears whole, or not at all); the temporary files of the frames in
    flight are then removed.

    With ``overlap=False`` each frame is read, shaded and written in turn, in
    this thread (where an interrupt unwinds through
    :func:`clphong.io.atomic.atomic_path`, which removes the temporary file).
    """
    relighters = {rig: cached_relighter(spec) for rig, spec in specs.items()}
    channels = dict(next(iter(specs.values())).channels) or None
    if not overlap:
        for job in jobs:
            t0 = time.perf_counter()
            gbuffer = load_job(job, channels)
            on_outcomes(shade_job(job, gbuffer, relighters, read_seconds=time.perf_counter() - t0))
            del gbuffer
            raise_pending()                      # a signal C code swallowed stops the batch here
        return

    stop = threading.Event()
    slot = threading.Semaphore(1)          # frames read and not yet taken: at most one
    ahead: queue.SimpleQueue = queue.SimpleQueue()

    def reader():
        for job in jobs:
            while not slot.acquire(timeout=0.1):
                if stop.is_set():
                    return
            if stop.is_set():
                return
            t0 = time.perf_counter()
            gbuffer = load_job(job, channels)
            ahead.put((job, gbuffer, time.perf_counter() - t0))
            del gbuffer

    def take():
        while True:
            try:
                return ahead.get(timeout=0.1)
            except queue.Empty:
                if not t.is_alive() and ahead.empty():
                    raise RuntimeError("the frame reader thread stopped unexpectedly") from None

    def report(frame):
        while not frame.done.wait(0.1):          # a timeout, so that signals are handled here
            pass
        frame.thread.join()
        if frame.error is not None:
            raise frame.error
        on_outcomes(frame.outcomes)
        raise_pending()                          # a signal C code swallowed stops the batch here

    inflight: collections.deque = collections.deque()
    previous = None
    t = threading.Thread(target=reader, name="clphong-reader", daemon=True)
    t.start()
    try:
        for _ in jobs:
            while len(inflight) >= _IN_FLIGHT:
                report(inflight[0])
                inflight.popleft()
            job, gbuffer, read_seconds = take()
            slot.release()                       # the reader starts on the next frame
            previous = _Frame(job, gbuffer, read_seconds, previous, relighters, stop)
            del gbuffer
            inflight.append(previous)
            previous.thread.start()
        while inflight:
            report(inflight[0])
            inflight.popleft()
    finally:
        stop.set()
        _stop_threads([t, *(f.thread for f in inflight)], [f.job for f in inflight])


def _stop_threads(threads, jobs: Sequence[Job], wait: float | None = None) -> None:
    """Wait (up to ``wait`` seconds, default :data:`_STOP_WAIT`) for the threads of a stopping
    batch, then remove the temporary files of ``jobs``. A second interrupt ends the wait
    early (the files are still removed) and is re-raised."""
    deadline = time.monotonic() + (_STOP_WAIT if wait is None else wait)
    again = None
    try:
        for th in threads:
            while th.is_alive() and time.monotonic() < deadline:
                try:
                    th.join(min(0.1, max(0.0, deadline - time.monotonic())))
                except KeyboardInterrupt as exc:
                    again, deadline = exc, 0.0
    finally:
        for job in jobs:
            remove_job_temporaries(job, own=True)
    if again is not None:
        raise again


def run_batch(plan: BatchPlan, specs: dict, *, jobs: int = 1, scheduler: str | None = None,
              progress: bool = False, on_outcome: Callable[[Outcome], None] | None = None,
              overlap: bool = True, scheduler_timeout: float = CONNECT_TIMEOUT_S) -> BatchResult:
    """Run a plan; never raises for a bad frame.

    Parameters
    ----------
    plan : BatchPlan
    specs : dict of str to clphong.pipeline.relighter.RelighterSpec
        One per rig name.
    jobs : int
        Local worker processes (1: in this process, reading, shading and writing
        consecutive frames at once).
    scheduler : str, optional
        Address of a Dask distributed scheduler (``tcp://host:8786``), or a
        ``distributed.Client``; frames then run as tasks on its workers.
    scheduler_timeout : float
        Seconds to connect to ``scheduler`` and hear its handshake (20).
    progress : bool
        Show a tqdm progress bar on stderr: outputs (frames × rigs) done, outputs/s and ETA.
    overlap : bool
        With ``jobs=1``: overlap the stages of consecutive frames (default); False:
        read, shade and write each frame in turn (for comparison).

    Returns
    -------
    BatchResult
        With ``interrupted`` set when SIGINT/SIGTERM stopped it.
    """
    t0 = time.perf_counter()
    stale = sum(remove_job_temporaries(job) for job in plan.jobs)
    outcomes: list[Outcome] = []
    retried: list[tuple[int, str, str]] = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=plan.outputs, unit="output", file=sys.stderr, dynamic_ncols=True,
                   smoothing=0.1, disable=None)

    def collect(outs: Iterable[Outcome]):
        for o in outs:
            outcomes.append(o)
            if on_outcome is not None:
                on_outcome(o)
            if bar is not None:
                bar.update(1)
                if not o.ok:
                    bar.set_postfix_str(f"{len([x for x in outcomes if not x.ok])} failed", refresh=False)

    interrupted = None
    try:
        with _Signals():
            if not plan.jobs:
                pass
            elif scheduler is not None:
                run_on_dask(plan.jobs, specs, scheduler, collect, timeout=scheduler_timeout)
            elif jobs <= 1:
                _run_inline(plan.jobs, specs, collect, overlap=overlap)
            else:
                run_pool(plan.jobs, specs, jobs, collect,
                          on_retry=lambda job, why: retried.append((job.frame, job.source, why)))
    except Interrupted as exc:
        interrupted = exc.signum
    except KeyboardInterrupt:
        interrupted = signal.SIGINT
    finally:
        clear_pending()
        if interrupted is not None:
            remove_live_temporaries()   # a write (inline mode) the interrupt caught before its own cleanup could
        if bar is not None:
            bar.close()
    return BatchResult(outcomes, skipped=len(plan.skipped), seconds=time.perf_counter() - t0,
                       stale_removed=stale, interrupted=interrupted, retried=retried)
