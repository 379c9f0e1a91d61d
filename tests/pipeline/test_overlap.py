"""The one-process batch overlaps reading, shading and writing of consecutive frames.

Frame i+1 is read while frame i shades and frame i-1 is written; frames are
written one at a time and in order, reported in order, with at most one frame
read ahead; the outputs are those of a sequential run, byte for byte; a bad
frame fails alone; an interrupt leaves no temporary file. The overlap is proved
with instrumented stages (events each stage waits for), never with timings:
each probe also runs on the sequential path (``overlap=False``), where it must
see no overlap, so a probe that could not fail would show up there.
"""

from __future__ import annotations

import collections
import os
import signal
import threading
import time

import numpy as np
import pytest
from conftest import RIG_SCENE, random_gbuffer, read_rgb

import clphong
import clphong.deliver.outputs as outputs_mod
from clphong.console.cli import main
from clphong.device.renderer import Renderer
from clphong.io.atomic import atomic_path
from clphong.pipeline import batch
from clphong.pipeline.batch import Rig, plan_batch, run_batch
from clphong.pipeline.relighter import RelighterSpec

H, W = 12, 16
FRAMES = 6

SCENE = RIG_SCENE


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    from clphong.io.gbuffer import write_gbuffer

    root = tmp_path_factory.mktemp("overlap")
    (root / "seq").mkdir()
    rng = np.random.default_rng(14)
    for f in range(1, FRAMES + 1):
        g = random_gbuffer(rng, H, W)
        write_gbuffer(root / "seq" / f"shot.{f:04d}.exr", g.position, g.normal, g.albedo,
                      coverage=g.coverage)
    (root / "key.toml").write_text(SCENE.format(x=3.0))
    (root / "fill.toml").write_text(SCENE.format(x=-3.0))
    return root


def _rigs(root, names=("key", "fill")):
    return [Rig(n, clphong.load_scene(root / f"{n}.toml")) for n in names]


def _specs(rigs):
    from clphong.deliver.outputs import OutputOptions

    return {r.name: RelighterSpec(scene=r.scene, output=OutputOptions().for_scene(r.scene))
            for r in rigs}


def _plan(root, out, rigs, *, sdr=True, frames=None):
    return plan_batch(str(root / "seq" / "shot.####.exr"), rigs, str(out / "{rig}" / "{name}.####.exr"),
                      sdr=[str(out / "{rig}" / "{name}.####.png")] if sdr else (), frames=frames)


def _frame_of(path) -> int:
    return int(os.path.basename(str(path)).split(".")[1])


def _shaded_frame(gbuffer) -> int:
    return _frame_of(gbuffer.sources["position"].split(":")[0])


def _no_temporaries(folder):
    left = [p for p in folder.rglob("*") if p.name.startswith(".") and ".tmp-" in p.name]
    assert not left, left


def _without_datetime(data: bytes) -> bytes:
    """An EXR's bytes with the value of its ``capDate`` header attribute (the wall clock
    at writing, which OpenImageIO stores) blanked; other files as they are."""
    key = b"capDate\x00string\x00"
    at = data.find(key)
    if at < 0:
        return data
    start = at + len(key)
    n = int.from_bytes(data[start:start + 4], "little")
    return data[:start + 4] + b"\x00" * n + data[start + 4 + n:]


# ---------------------------------------------------------------- the same files, in order


def test_overlapped_outputs_are_byte_identical_to_a_sequential_run(shot, tmp_path):
    rigs = _rigs(shot)
    specs = _specs(rigs)
    runs = {}
    for name, overlap in (("overlap", True), ("sequential", False)):
        out = tmp_path / name
        result = run_batch(_plan(shot, out, rigs), specs, overlap=overlap)
        assert len(result.written) == 2 * FRAMES and not result.failed
        runs[name] = out
    # ... and the API, one frame after the other, is the same again
    ref = tmp_path / "api"
    for rig in rigs:
        r = clphong.Relighter(rig.scene)
        (ref / rig.name).mkdir(parents=True)
        for f in range(1, FRAMES + 1):
            r.relight(str(shot / "seq" / f"shot.{f:04d}.exr"),
                      out=str(ref / rig.name / f"shot.{f:04d}.exr"),
                      sdr=str(ref / rig.name / f"shot.{f:04d}.png"))
    names = sorted(p.relative_to(ref) for p in ref.rglob("*.*"))
    assert len(names) == 4 * FRAMES
    for out in runs.values():
        assert sorted(p.relative_to(out) for p in out.rglob("*.*")) == names
        for n in names:
            a, b = (out / n).read_bytes(), (ref / n).read_bytes()
            if n.suffix == ".exr":
                assert b"capDate\x00string\x00" in a
            assert _without_datetime(a) == _without_datetime(b), n
        _no_temporaries(out)


def test_frames_are_reported_and_written_in_order_one_at_a_time(shot, tmp_path, monkeypatch):
    """Even frames shade slowly, so frames finish shading out of order; they are still
    written one at a time in frame order, and reported in frame order."""
    original_render, original_write = Renderer.render, outputs_mod.write_output
    writing, log, lock = [], [], threading.Lock()

    def render(self, gbuffer, **kw):
        if _shaded_frame(gbuffer) % 2 == 0:
            time.sleep(0.05)
        return original_render(self, gbuffer, **kw)

    def write_output(rgb, path, options=None, **kw):
        with lock:
            writing.append(path)
            log.append(("start", _frame_of(path), len(writing)))
        time.sleep(0.01)
        try:
            return original_write(rgb, path, options, **kw)
        finally:
            with lock:
                writing.remove(path)

    monkeypatch.setattr(Renderer, "render", render)
    monkeypatch.setattr(outputs_mod, "write_output", write_output)
    rigs = _rigs(shot, ("key",))
    reported = []
    result = run_batch(_plan(shot, tmp_path, rigs, sdr=False), _specs(rigs),
                       on_outcome=lambda o: reported.append(o.frame))
    assert reported == list(range(1, FRAMES + 1))
    assert [o.frame for o in result.outcomes] == reported
    assert [f for _, f, _ in log] == list(range(1, FRAMES + 1))
    assert max(n for _, _, n in log) == 1, log            # never two frames written at once


# ---------------------------------------------------------------- the overlap itself


class _Probe:
    """Events per (stage, frame): set when that stage of that frame has started."""

    def __init__(self, patience: float):
        self.patience = patience
        self._events = collections.defaultdict(threading.Event)
        self._lock = threading.Lock()
        self.seen: dict[tuple[str, int], bool] = {}

    def started(self, stage, frame):
        with self._lock:
            ev = self._events[(stage, frame)]
        ev.set()

    def meanwhile(self, stage, frame) -> bool:
        """Wait (while the caller's stage runs) for ``stage`` of ``frame`` to start."""
        with self._lock:
            ev = self._events[(stage, frame)]
        return ev.wait(self.patience)


@pytest.mark.parametrize("overlap", [True, False], ids=["overlapped", "sequential"])
def test_reading_frame_i_plus_1_overlaps_shading_frame_i(shot, tmp_path, monkeypatch, overlap):
    """Shading frame i waits for the reading of frame i+1 to start, and reading frame i+1
    waits for the shading of frame i to start: both are then running at once."""
    probe = _Probe(patience=10.0 if overlap else 0.2)
    original_load, original_render = batch.load_job, Renderer.render

    def load_job(job, channels):
        probe.started("read", job.frame)
        if job.frame > 1:
            probe.seen[("read", job.frame)] = probe.meanwhile("shade", job.frame - 1)
        return original_load(job, channels)

    def render(self, gbuffer, **kw):
        f = _shaded_frame(gbuffer)
        probe.started("shade", f)
        if f < FRAMES:
            probe.seen[("shade", f)] = probe.meanwhile("read", f + 1)
        return original_render(self, gbuffer, **kw)

    monkeypatch.setattr(batch, "load_job", load_job)
    monkeypatch.setattr(Renderer, "render", render)
    rigs = _rigs(shot, ("key",))
    result = run_batch(_plan(shot, tmp_path, rigs, sdr=False), _specs(rigs), overlap=overlap)
    assert len(result.written) == FRAMES
    shading = [probe.seen[("shade", f)] for f in range(1, FRAMES)]
    assert shading == [overlap] * (FRAMES - 1), probe.seen


@pytest.mark.parametrize("overlap", [True, False], ids=["overlapped", "sequential"])
def test_writing_frame_i_minus_1_overlaps_shading_frame_i(shot, tmp_path, monkeypatch, overlap):
    probe = _Probe(patience=10.0 if overlap else 0.2)
    original_write, original_render = outputs_mod.write_output, Renderer.render

    def write_output(rgb, path, options=None, **kw):
        f = _frame_of(path)
        if f < FRAMES:
            probe.seen[("write", f)] = probe.meanwhile("shade", f + 1)
        return original_write(rgb, path, options, **kw)

    def render(self, gbuffer, **kw):
        probe.started("shade", _shaded_frame(gbuffer))
        return original_render(self, gbuffer, **kw)

    monkeypatch.setattr(outputs_mod, "write_output", write_output)
    monkeypatch.setattr(Renderer, "render", render)
    rigs = _rigs(shot, ("key",))
    result = run_batch(_plan(shot, tmp_path, rigs, sdr=False), _specs(rigs), overlap=overlap)
    assert len(result.written) == FRAMES
    assert [probe.seen[("write", f)] for f in range(1, FRAMES)] == [overlap] * (FRAMES - 1), probe.seen


def test_at_most_one_frame_is_read_ahead(shot, tmp_path, monkeypatch):
    """When reading frame f starts, frame f-3 is written: frames in memory are f (read),
    f-1 (shading) and f-2 (written). Shading is slow and reading fast, so a reader that
    ran further ahead would be caught."""
    original_load, original_render, original_write = batch.load_job, Renderer.render, outputs_mod.write_output
    written, early, lock = set(), [], threading.Lock()

    def load_job(job, channels):
        with lock:
            if any(f not in written for f in range(1, job.frame - 2)):
                early.append((job.frame, sorted(written)))
        return original_load(job, channels)

    def render(self, gbuffer, **kw):
        time.sleep(0.05)
        return original_render(self, gbuffer, **kw)

    def write_output(rgb, path, options=None, **kw):
        original_write(rgb, path, options, **kw)
        with lock:
            written.add(_frame_of(path))

    monkeypatch.setattr(batch, "load_job", load_job)
    monkeypatch.setattr(Renderer, "render", render)
    monkeypatch.setattr(outputs_mod, "write_output", write_output)
    rigs = _rigs(shot, ("key",))
    result = run_batch(_plan(shot, tmp_path, rigs, sdr=False), _specs(rigs))
    assert len(result.written) == FRAMES
    assert not early, early


def test_stage_times_are_in_the_outcomes_and_the_summary(shot, tmp_path):
    rigs = _rigs(shot, ("key",))
    result = run_batch(_plan(shot, tmp_path, rigs), _specs(rigs))
    for o in result.written:
        assert set(o.stages) == {"read", "shade", "wait", "write"}, o.stages
        assert all(v >= 0 for v in o.stages.values())
    stages = result.stage_seconds()
    assert list(stages) == ["read", "shade", "write"]
    assert "; median s/output: read " in result.summary()[0]


# ---------------------------------------------------------------- failures


def test_a_bad_frame_fails_alone_with_one_line_and_exit_1(shot, tmp_path, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    for f in range(1, FRAMES + 1):
        src = shot / "seq" / f"shot.{f:04d}.exr"
        data = src.read_bytes()
        (seq / src.name).write_bytes(data[:300] if f == 3 else data)
    out = tmp_path / "out"
    (out / "key").mkdir(parents=True)
    (out / "key" / "shot.0004.exr").mkdir()           # frame 4's EXR cannot be written,
    (out / "key" / "shot.0005.png").mkdir()           # frame 5's SDR neither
    args = ["relight", str(seq / "shot.####.exr"), "--rig", str(shot / "key.toml"),
            "-o", str(out / "{rig}" / "{name}.####.exr"), "--sdr", str(out / "{rig}" / "{name}.####.png")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert f"{FRAMES - 3} written, 0 skipped (exist), 3 failed" in err
    lines = [ln for ln in err.splitlines() if ln.startswith("  frame ")]
    assert [int(ln.split()[1]) for ln in lines] == [3, 4, 5], err
    assert "shot.0003.exr" in lines[0] and "is a directory" in lines[1] and "shot.0005.png" in lines[2]
    assert "out/key/shot.0004.exr" in lines[1] and "out/key/shot.0005.png" in lines[2]
    for f in (1, 2, 6):
        assert (out / "key" / f"shot.{f:04d}.exr").is_file() and (out / "key" / f"shot.{f:04d}.png").is_file()
    assert not (out / "key" / "shot.0003.exr").exists() and not (out / "key" / "shot.0003.png").exists()
    _no_temporaries(out)


# ---------------------------------------------------------------- interrupts


def _interrupt_at(frame, monkeypatch, *, then):
    """Patch write_output: writing ``frame`` sends this process SIGTERM, then calls ``then``."""
    original = outputs_mod.write_output

    def write_output(rgb, path, options=None, **kw):
        if _frame_of(path) == frame:
            os.kill(os.getpid(), signal.SIGTERM)
            return then(original, rgb, path, options, **kw)
        return original(rgb, path, options, **kw)

    monkeypatch.setattr(outputs_mod, "write_output", write_output)


def test_sigterm_while_a_frame_is_written_stops_cleanly(shot, tmp_path, monkeypatch):
    """The frame being written when SIGTERM lands is finished (whole); the frame shading
    then is abandoned before its first file; nothing else is read, shaded or written."""
    def finish_slowly(original, rgb, path, options, **kw):
        time.sleep(0.3)                               # the batch is stopping meanwhile
        return original(rgb, path, options, **kw)

    _interrupt_at(3, monkeypatch, then=finish_slowly)
    rigs = _rigs(shot, ("key",))
    out = tmp_path / "out"
    result = run_batch(_plan(shot, out, rigs, sdr=False), _specs(rigs))
    assert result.interrupted == signal.SIGTERM
    # frame 2 is done when frame 3 writes; the signal may land before it is reported
    assert [o.frame for o in result.outcomes] in ([1], [1, 2])
    files = sorted(p.name for p in (out / "key").iterdir())
    assert files == ["shot.0001.exr", "shot.0002.exr", "shot.0003.exr"]
    expected = clphong.Relighter(rigs[0].scene).relight(str(shot / "seq" / "shot.0003.exr"))
    assert np.array_equal(read_rgb(out / "key" / "shot.0003.exr"), expected)
    _no_temporaries(out)


def test_a_write_hung_past_the_stop_wait_leaves_no_temporary(shot, tmp_path, monkeypatch):
    """A write that does not finish within _STOP_WAIT: its temporary file is removed when
    the batch returns, and the write, once it ends, cannot put a file in place."""
    monkeypatch.setattr(batch, "_STOP_WAIT", 0.2)
    released, ended = threading.Event(), threading.Event()

    def hang(original, rgb, path, options, **kw):
        try:
            with atomic_path(path) as tmp:
                with open(tmp, "wb") as f:
                    f.write(b"half an image")
                released.wait(10)
        finally:
            ended.set()

    _interrupt_at(2, monkeypatch, then=hang)
    rigs = _rigs(shot, ("key",))
    out = tmp_path / "out"
    result = run_batch(_plan(shot, out, rigs, sdr=False), _specs(rigs))
    assert result.interrupted == signal.SIGTERM
    _no_temporaries(out)
    released.set()
    assert ended.wait(10)
    assert sorted(p.name for p in (out / "key").iterdir()) == ["shot.0001.exr"]
    _no_temporaries(out)
