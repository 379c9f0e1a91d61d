"""Batch relighting: sequences, ranges, templates, failures, resume after a kill."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import RIG_SCENE, patch_everywhere, random_gbuffer, read_rgb

from clphong.console.cli import main
from clphong.pipeline.batch import (
    BatchError,
    BatchPlan,
    BatchResult,
    Outcome,
    Rig,
    expand_sequence,
    format_output,
    parse_frame_range,
    plan_batch,
    run_batch,
)
from clphong.pipeline.frames import FrameRange
from clphong.pipeline.relighter import RelighterSpec

H, W = 24, 32

SCENE = RIG_SCENE


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    """24 frames of 32x24 G-buffers, two rig scene files, and the expected images.

    The expected image of each frame and rig is rendered independently, one
    frame at a time through clphong.render (itself held against the float64
    reference by tests/device/test_renderer.py); a batch must reproduce it bit for bit,
    because it runs the same kernel on the same data.
    """
    import clphong
    from clphong.io.gbuffer import write_gbuffer

    root = tmp_path_factory.mktemp("shot")
    (root / "seq").mkdir()
    rng = np.random.default_rng(6)
    frames = {}
    for f in range(1, 25):
        g = random_gbuffer(rng, H, W)
        write_gbuffer(root / "seq" / f"shot.{f:04d}.exr", g.position, g.normal, g.albedo,
                      coverage=g.coverage)
        frames[f] = clphong.read_gbuffer(root / "seq" / f"shot.{f:04d}.exr")
    (root / "key.toml").write_text(SCENE.format(x=3.0))
    (root / "fill.toml").write_text(SCENE.format(x=-3.0))
    expected = {}
    for rig in ("key", "fill"):
        scene = clphong.load_scene(root / f"{rig}.toml")
        r = clphong.Renderer(scene)
        for f, g in frames.items():
            expected[(f, rig)] = r.render(g).image
    return root, expected


def _args(root, out, *extra):
    return ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
            "--rig", str(root / "fill.toml"), "-o", str(out / "{rig}" / "{name}.####.exr"), *extra]


def _check_outputs(out, expected, frames=range(1, 25)):
    for f in frames:
        for rig in ("key", "fill"):
            px = read_rgb(out / rig / f"shot.{f:04d}.exr")
            assert np.array_equal(px, expected[(f, rig)]), (f, rig)


def _no_temporaries(folder):
    left = [p for p in folder.rglob("*") if p.name.startswith(".") and ".tmp-" in p.name]
    assert not left, left


# ---------------------------------------------------------------- names and ranges


def test_frame_range_forms():
    assert parse_frame_range("1-240x2")[:3] == [1, 3, 5] and parse_frame_range("1-240x2")[-1] == 239
    assert len(parse_frame_range("1-240x2")) == 120
    assert parse_frame_range("5") == [5]
    assert parse_frame_range("1-3, 10, 2-4") == [1, 2, 3, 10, 4]
    for bad in ("", "a-b", "5-1", "1-10x0", "1--"):
        with pytest.raises(BatchError):
            parse_frame_range(bad)


def test_output_template_fields():
    src = "in/shot_v2.0012.exr"
    assert format_output("o/{rig}/{name}.####.exr", frame=12, rig="key", source=src) == "o/key/shot_v2.0012.exr"
    assert format_output("o/{stem}.{rig}.exr", frame=12, rig="k", source=src) == "o/shot_v2.0012.k.exr"
    assert format_output("o/x.%06d.exr", frame=12, rig="k", source=src) == "o/x.000012.exr"
    assert format_output("o/x.{frame:03d}.exr", frame=12345, rig="k", source=src) == "o/x.12345.exr"


def test_sequence_patterns_and_folder_agree(shot):
    root, _ = shot
    a = expand_sequence(str(root / "seq" / "shot.####.exr"))
    b = expand_sequence(str(root / "seq" / "shot.%04d.exr"))
    c = expand_sequence(str(root / "seq"))
    assert a == b == c and [f for f, _ in a] == list(range(1, 25))
    # '#' padding must match exactly: shot.0001.exr is not frame 1 of shot.##.exr
    with pytest.raises(BatchError, match="no files match the pattern in frames 1"):
        expand_sequence(str(root / "seq" / "shot.##.exr"), [1])
    with pytest.raises(BatchError, match="no files match"):
        expand_sequence(str(root / "seq" / "shot.##.exr"))
    # a range keeps the frames on disk that are in it, never listing the range
    rng = FrameRange.parse("3-1000000000x3")
    assert [f for f, _ in expand_sequence(str(root / "seq" / "shot.####.exr"), rng)] == list(range(3, 25, 3))


def test_folder_frames_are_numbered_by_their_own_names(shot, tmp_path, capsys):
    """A stray un-numbered EXR, or a second sequence, in a folder is a one-line error naming the
    file(s), never a silent renumbering of the shot (which made --frames 10-12 select nothing)."""
    root, expected = shot
    seq = tmp_path / "seq"
    seq.mkdir()
    for f in (10, 11, 12):
        (seq / f"gbuf.{f:04d}.exr").write_bytes((root / "seq" / f"shot.{f - 9:04d}.exr").read_bytes())
    notes = seq / "zz_notes.exr"
    notes.write_bytes((root / "seq" / "shot.0004.exr").read_bytes())
    out = tmp_path / "out"
    args = ["relight", str(seq), "--rig", str(root / "key.toml"), "--frames", "10-12",
            "-o", str(out / "{rig}.####.exr")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err == (f"clphong: error: {notes}: no frame number at the end of its name, and every .exr "
                   "in a sequence folder is a frame; move it out, or give a pattern such as "
                   f"{seq / 'gbuf.####.exr'}\n"), err
    assert not out.exists()
    with pytest.raises(BatchError, match="zz_notes.exr: no frame number"):
        expand_sequence(str(seq))                 # without --frames as well
    # Two sequences in one folder: both files of the repeated frame are named.
    notes.rename(seq / "other.11.exr")
    with pytest.raises(BatchError) as info:
        expand_sequence(str(seq), [10, 11, 12])
    assert str(info.value).startswith(f"{seq / 'gbuf.0011.exr'} and {seq / 'other.11.exr'} are both "
                                      "frame 11 (two sequences in one folder?)")
    assert "\n" not in str(info.value)
    (seq / "other.11.exr").unlink()
    # A clean folder: the frames are the numbers in the names, as with the pattern.
    assert expand_sequence(str(seq)) == expand_sequence(str(seq / "gbuf.####.exr"))
    assert main(args) == 0
    assert sorted(p.name for p in out.iterdir()) == ["key.0010.exr", "key.0011.exr", "key.0012.exr"]
    for f in (10, 11, 12):
        assert np.array_equal(read_rgb(out / f"key.{f:04d}.exr"), expected[(f - 9, "key")]), f


def test_colliding_outputs_are_refused(shot):
    import clphong

    root, _ = shot
    rigs = [Rig("key", clphong.load_scene(root / "key.toml")), Rig("fill", clphong.load_scene(root / "fill.toml"))]
    with pytest.raises(BatchError, match="add {rig}"):
        plan_batch(str(root / "seq"), rigs, str(root / "o" / "{name}.####.exr"))
    with pytest.raises(BatchError, match="overwrite the input"):
        plan_batch(str(root / "seq" / "shot.####.exr"), rigs[:1], str(root / "seq" / "{stem}.exr"))


# ---------------------------------------------------------------- whole batches


@pytest.mark.parametrize("jobs", [1, 2])
def test_batch_20_frames_two_rigs(shot, tmp_path, jobs, capsys):
    root, expected = shot
    out = tmp_path / "out"
    assert main(_args(root, out, "--jobs", str(jobs), "--frames", "1-24")) == 0
    _check_outputs(out, expected)
    assert sorted(p.name for p in (out / "key").iterdir()) == [f"shot.{f:04d}.exr" for f in range(1, 25)]
    _no_temporaries(out)
    err = capsys.readouterr().err
    assert "48 written, 0 skipped (exist), 0 failed" in err


def test_frame_step_and_dry_run(shot, tmp_path, capsys):
    root, expected = shot
    out = tmp_path / "out"
    assert main(_args(root, out, "--frames", "2-24x10", "--dry-run")) == 0
    listed = capsys.readouterr().out.splitlines()
    assert len(listed) == 6 and all(line.startswith("write") for line in listed)
    assert not out.exists()                           # a dry run writes nothing
    assert main(_args(root, out, "--frames", "2-24x10")) == 0
    assert sorted(p.name for p in (out / "fill").iterdir()) == ["shot.0002.exr", "shot.0012.exr", "shot.0022.exr"]
    _check_outputs(out, expected, frames=(2, 12, 22))


def test_three_corrupt_frames_do_not_stop_the_batch(shot, tmp_path, capsys):
    root, expected = shot
    seq = tmp_path / "seq"
    seq.mkdir()
    bad = {5: "truncated", 11: "not an exr", 17: "no normals"}
    for f in range(1, 25):
        src = root / "seq" / f"shot.{f:04d}.exr"
        if f == 5:
            (seq / src.name).write_bytes(src.read_bytes()[:300])
        elif f == 11:
            (seq / src.name).write_text("this is not an image\n")
        elif f == 17:
            from clphong.io.atomic import write_exr
            write_exr(seq / src.name, np.zeros((H, W, 3), np.float32), channel_names=("P.X", "P.Y", "P.Z"))
        else:
            (seq / src.name).write_bytes(src.read_bytes())
    out = tmp_path / "out"
    args = ["relight", str(seq / "shot.####.exr"), "--rig", str(root / "key.toml"), "--rig",
            str(root / "fill.toml"), "-o", str(out / "{rig}" / "{name}.####.exr")]
    assert main(args) == 1
    err = capsys.readouterr().err
    good = [f for f in range(1, 25) if f not in bad]
    _check_outputs(out, expected, frames=good)
    for f in bad:
        assert not (out / "key" / f"shot.{f:04d}.exr").exists()
    assert "42 written, 0 skipped (exist), 6 failed" in err
    assert "failed: 6 output(s) of 3 frame(s):" in err
    lines = [ln for ln in err.splitlines() if ln.startswith("  frame ")]
    assert [int(ln.split()[1]) for ln in lines] == sorted(bad)
    assert "no normal, albedo channels found" in lines[2] and "[key, fill]" in lines[2]
    _no_temporaries(out)
    # Rerun with resume: only the 3 bad frames are tried again, and fail again.
    assert main(args + ["--skip-existing"]) == 1
    assert "0 written, 42 skipped (exist), 6 failed" in capsys.readouterr().err


# ---------------------------------------------------------------- interrupted runs


def _start(root, out, jobs=1):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-m", "clphong", *_args(root, out, "--jobs", str(jobs))]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)


def _wait_for_outputs(proc, out, n, timeout=60):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if out.exists() and sum(1 for p in out.rglob("shot.*.exr")) >= n:
            return
        if proc.poll() is not None:
            pytest.fail(f"batch ended (rc {proc.returncode}) before it could be interrupted: "
                        f"{proc.stderr.read()}")
        time.sleep(0.005)
    pytest.fail("no outputs appeared")


@pytest.mark.parametrize("sig, jobs", [(signal.SIGTERM, 1), (signal.SIGINT, 1), (signal.SIGTERM, 2),
                                       (signal.SIGKILL, 1), (signal.SIGUSR2, 1), (signal.SIGALRM, 2)],
                         ids=["SIGTERM", "SIGINT", "SIGTERM-jobs2", "SIGKILL", "SIGUSR2",
                              "SIGALRM-jobs2"])
def test_resume_after_killed_run(shot, tmp_path, sig, jobs, capsys):
    root, expected = shot
    out = tmp_path / "out"
    proc = _start(root, out, jobs)
    _wait_for_outputs(proc, out, 4)
    proc.send_signal(sig)
    rc = proc.wait(timeout=60)
    stderr = proc.stderr.read()
    written = sorted(out.rglob("shot.*.exr"))
    assert 4 <= len(written) < 48, "the kill should land mid-batch"
    # Every output that exists under its final name is complete and correct.
    for p in written:
        f = int(p.name.split(".")[1])
        assert np.array_equal(read_rgb(p), expected[(f, p.parent.name)]), p
    if sig == signal.SIGKILL:
        assert rc == -signal.SIGKILL
    else:
        assert rc == 128 + sig, stderr
        assert f"interrupted by {signal.Signals(sig).name}" in stderr
        _no_temporaries(out)          # the handler removed the temporary file of the write in flight
    # Resume: only the rest is relit; the result is the complete, correct batch.
    assert main(_args(root, out, "--skip-existing")) == 0
    err = capsys.readouterr().err
    assert f"{48 - len(written)} written, {len(written)} skipped (exist), 0 failed" in err
    _check_outputs(out, expected)
    _no_temporaries(out)              # temporaries a SIGKILL left behind are cleaned up too


# ---------------------------------------------------------------- a pool worker dies


@dataclasses.dataclass(frozen=True)
class _FaultySpec(RelighterSpec):
    """A rig whose worker process sends itself ``fault_signal`` (0: exits with status 0) while it
    writes frame ``fault_frame`` (a temporary file of it exists then): every time, or with
    ``fault_marker`` only while that file does not exist (it is created first), i.e. once."""

    fault_frame: int = 0
    fault_signal: int = int(signal.SIGKILL)
    fault_marker: str = ""
    #: instead: send SIGTERM to itself where its exception is swallowed, as C code that
    #: clears errors does (pyopencl probing a __getattr__ with PyObject_HasAttr), then go on
    fault_swallow: bool = False

    def build(self):
        return _FaultyRelighter(super().build(), self)


class _FaultyRelighter:
    def __init__(self, inner, spec):
        self.inner, self.spec = inner, spec

    def deliver(self, gbuffer, paths, **kw):
        from clphong.io.atomic import atomic_path

        spec = self.spec
        if (os.path.basename(kw["source"]) == f"shot.{spec.fault_frame:04d}.exr"
                and not (spec.fault_marker and os.path.exists(spec.fault_marker))):
            if spec.fault_marker:
                open(spec.fault_marker, "x").close()
            if spec.fault_swallow:
                try:
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(60)                # the handler raises here...
                except KeyboardInterrupt:
                    pass                          # ...and the exception is dropped
                return self.inner.deliver(gbuffer, paths, **kw)
            with atomic_path(paths.files[0]) as tmp:
                with open(tmp, "wb") as f:
                    f.write(b"half an image")
                if not spec.fault_signal:
                    os._exit(0)                   # a clean exit, holding a frame
                os.kill(os.getpid(), spec.fault_signal)
                time.sleep(60)                    # the signal ends this first
        return self.inner.deliver(gbuffer, paths, **kw)


class _Hung(Exception):
    pass


@contextlib.contextmanager
def _deadline(seconds):
    """Raise _Hung in the main thread after ``seconds`` (the pool's workers are then stopped)."""
    def hung(signum, frame):
        raise _Hung(f"the batch did not end within {seconds} s")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _faulty_batch(root, out, frames, **fault):
    import clphong

    scene = clphong.load_scene(root / "key.toml")
    plan = plan_batch(str(root / "seq" / "shot.####.exr"), [Rig("key", scene)],
                      str(out / "{rig}" / "{name}.####.exr"), frames=frames)
    with _deadline(120):
        return run_batch(plan, {"key": _FaultySpec(scene=scene, **fault)}, jobs=2)


@pytest.mark.parametrize("sig, how", [(signal.SIGKILL, "killed by SIGKILL"),
                                      (signal.SIGTERM, "SIGTERM, exit code 143"),
                                      (0, "exit code 0")],
                         ids=["SIGKILL", "SIGTERM", "exit-0"])
def test_a_worker_that_dies_mid_frame_is_replaced_and_the_frame_retried(shot, tmp_path, sig, how):
    root, expected = shot
    out = tmp_path / "out"
    marker = tmp_path / "died"
    result = _faulty_batch(root, out, range(1, 9), fault_frame=3, fault_signal=int(sig),
                           fault_marker=str(marker))
    assert marker.exists(), "the worker was not made to die"
    assert result.interrupted is None and not result.failed
    assert sorted(o.frame for o in result.written) == list(range(1, 9))      # every frame delivered
    for f in range(1, 9):
        assert np.array_equal(read_rgb(out / "key" / f"shot.{f:04d}.exr"), expected[(f, "key")]), f
    _no_temporaries(out)          # the dying worker's temporary file (SIGKILL: left) is removed
    src = str(root / "seq" / "shot.0003.exr")
    assert result.retried == [(3, src, f"worker process died ({how})")]
    lines = result.summary()
    assert lines[0].startswith("8 written, 0 skipped (exist), 0 failed in ")
    assert lines[1:] == [f"retried frame 3 ({src}) on another worker: worker process died ({how})"]


def test_a_signal_whose_exception_c_code_swallowed_still_ends_the_worker(shot, tmp_path):
    """A SIGTERM whose Interrupted is dropped (C code clearing errors) is raised again before
    the frame's output is put in place: the worker ends (exit 143) and the frame is retried,
    where it had run on as if no signal had come."""
    root, expected = shot
    out = tmp_path / "out"
    marker = tmp_path / "swallowed"
    result = _faulty_batch(root, out, range(1, 7), fault_frame=3, fault_swallow=True,
                           fault_marker=str(marker))
    assert marker.exists()
    assert result.interrupted is None and not result.failed
    for f in range(1, 7):
        assert np.array_equal(read_rgb(out / "key" / f"shot.{f:04d}.exr"), expected[(f, "key")]), f
    _no_temporaries(out)
    assert result.retried == [(3, str(root / "seq" / "shot.0003.exr"),
                               "worker process died (SIGTERM, exit code 143)")]


def test_a_swallowed_signal_stops_a_one_process_batch_before_the_frames_file(shot, tmp_path):
    import clphong

    root, _ = shot
    out = tmp_path / "out"
    scene = clphong.load_scene(root / "key.toml")
    plan = plan_batch(str(root / "seq" / "shot.####.exr"), [Rig("key", scene)],
                      str(out / "{rig}" / "{name}.####.exr"), frames=range(1, 6))
    with _deadline(120):
        result = run_batch(plan, {"key": _FaultySpec(scene=scene, fault_frame=3, fault_swallow=True)},
                           jobs=1, overlap=False)
    assert result.interrupted == signal.SIGTERM
    assert sorted(o.frame for o in result.written) == [1, 2]
    assert sorted(p.name for p in (out / "key").iterdir()) == ["shot.0001.exr", "shot.0002.exr"]
    _no_temporaries(out)


def test_a_frame_that_kills_every_worker_fails_after_one_retry(shot, tmp_path):
    root, expected = shot
    out = tmp_path / "out"
    result = _faulty_batch(root, out, range(1, 7), fault_frame=3)        # dies on every try
    assert result.interrupted is None
    assert sorted(o.frame for o in result.written) == [1, 2, 4, 5, 6]
    for f in (1, 2, 4, 5, 6):
        assert np.array_equal(read_rgb(out / "key" / f"shot.{f:04d}.exr"), expected[(f, "key")]), f
    assert not (out / "key" / "shot.0003.exr").exists()
    _no_temporaries(out)
    src = str(root / "seq" / "shot.0003.exr")
    lines = result.summary()
    assert lines[0].startswith("5 written, 0 skipped (exist), 1 failed in ")
    assert lines[1:] == [
        f"retried frame 3 ({src}) on another worker: worker process died (killed by SIGKILL)",
        "failed: 1 output(s) of 1 frame(s):",
        f"  frame 3 ({src}) [key]: worker process died twice running it (killed by SIGKILL, "
        "then killed by SIGKILL)"]


def _pool_workers(pid):
    """Pids of the spawned multiprocessing workers among the children of process ``pid``."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in cmd:
            found.append(int(entry))
    return sorted(found)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_killing_one_pool_worker_neither_hangs_nor_loses_a_frame(shot, tmp_path, sig):
    """clphong relight --jobs 2, one worker killed from outside mid-batch (an OOM kill, an admin)."""
    root, expected = shot
    out = tmp_path / "out"
    proc = _start(root, out, jobs=2)
    _wait_for_outputs(proc, out, 4)
    workers = _pool_workers(proc.pid)
    assert len(workers) == 2, workers
    os.kill(workers[0], sig)
    try:
        rc = proc.wait(timeout=120)
    except subprocess.TimeoutExpired:
        for pid in _pool_workers(proc.pid):
            os.kill(pid, signal.SIGKILL)
        proc.kill()
        pytest.fail("the batch hung after one of its workers was killed")
    stderr = proc.stderr.read()
    assert rc == 0, stderr
    assert "clphong relight: 48 written, 0 skipped (exist), 0 failed" in stderr
    # SIGTERM: the worker unwinds (exit 143), or, if the signal reaches it while it is still
    # starting (importing, before its handler is installed; seen under load), it ends by
    # the signal's default action; both are reported as what they were
    hows = (["killed by SIGKILL"] if sig == signal.SIGKILL
            else ["SIGTERM, exit code 143", "killed by SIGTERM"])
    assert any(f"on another worker: worker process died ({how})" in stderr for how in hows), stderr
    _check_outputs(out, expected)
    _no_temporaries(out)


def test_pool_workers_warnings_are_the_one_line_warnings_of_one_process(shot, tmp_path, capfd):
    """Warnings raised in --jobs workers (non-finite inputs) reach stderr as 'clphong: warning:'
    lines, as with --jobs 1, not as raw two-line Python warnings from the workers."""
    import clphong
    from clphong.io.gbuffer import write_gbuffer

    root, _ = shot
    seq = tmp_path / "seq"
    seq.mkdir()
    for f in range(1, 5):
        src = root / "seq" / f"shot.{f:04d}.exr"
        g = clphong.read_gbuffer(src)
        P = g.position.copy()
        for y, x in np.argwhere(g.coverage > 0)[: f - 1]:     # frame f: f - 1 NaN positions
            P[y, x, 1] = np.nan
        write_gbuffer(seq / src.name, P, g.normal, g.albedo, coverage=g.coverage)
    warned = {}
    for jobs in (1, 2):
        args = ["relight", str(seq / "shot.####.exr"), "--rig", str(root / "key.toml"), "--rig",
                str(root / "fill.toml"), "-o", str(tmp_path / f"out{jobs}" / "{rig}.####.exr"),
                "--jobs", str(jobs), "--quiet"]
        assert main(args) == 0
        err = capfd.readouterr().err
        assert "InputWarning" not in err and "warnings.warn" not in err, err
        warned[jobs] = sorted(ln for ln in err.splitlines() if ln.startswith("clphong: warning: "))
    assert warned[2] == warned[1] and len(warned[1]) == 3, warned
    assert all("non-finite G-buffer values left unshaded as background" in ln for ln in warned[1])


def test_summary_and_progress_count_outputs_not_frames(monkeypatch):
    """One output per frame and rig: 2 frames x 2 rigs in 2 s is 2 outputs/s (1 frame/s)."""
    import tqdm

    outcomes = [Outcome(f, f"in.{f}.exr", rig, f"o.{rig}.{f}.exr", ok=True)
                for f in (1, 2) for rig in ("key", "fill")]
    assert BatchResult(outcomes, skipped=0, seconds=2.0).summary() == [
        "4 written, 0 skipped (exist), 0 failed in 2.0 s (2.00 outputs/s)"]
    bars = []

    class Bar:
        def __init__(self, **kw):
            bars.append(kw)

        def close(self):
            pass

    monkeypatch.setattr(tqdm, "tqdm", Bar)
    run_batch(BatchPlan([]), {}, progress=True)   # nothing to run: only the bar is looked at
    assert bars and bars[0]["unit"] == "output", bars


# ---------------------------------------------------------------- every output kind


ACES_RENDER = """
[render]
working_space = "acescg"
tonemap = "agx"
exposure = 0.5
"""


def _attrs(path):
    """(header attributes, pixel type name) of an image file."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp, oiio.geterror()
    spec = inp.spec()
    inp.close()
    return {a.name: a.value for a in spec.extra_attribs}, str(spec.format)


@pytest.fixture(scope="module")
def aces_rig(shot):
    """The key rig, delivered in ACEScg with AgX at +0.5 EV by its [render] table."""
    root, _ = shot
    path = root / "key_aces.toml"
    path.write_text(SCENE.format(x=3.0) + ACES_RENDER)
    return path


def _kinds_args(root, rig, out, *extra):
    return ["relight", str(root / "seq" / "shot.####.exr"), "--rig", f"key={rig}",
            "--rig", str(root / "fill.toml"), "-o", str(out / "{rig}" / "{name}.####.exr"),
            "--sdr", str(out / "{rig}" / "png" / "{name}.####.png"),
            "--hdr", str(out / "{rig}" / "hdr" / "{name}.####.png"), *extra]


@pytest.mark.parametrize("jobs", [1, 2])
def test_every_output_kind_per_frame_per_rig(shot, aces_rig, tmp_path, jobs, capsys):
    root, expected = shot
    out = tmp_path / "out"
    assert main(_kinds_args(root, aces_rig, out, "--frames", "1-4", "--jobs", str(jobs))) == 0
    assert "8 written, 0 skipped (exist), 0 failed" in capsys.readouterr().err
    # The working space changes the tags, not the scene-linear values.
    _check_outputs(out, expected, frames=range(1, 5))
    for f in range(1, 5):
        a, fmt = _attrs(out / "key" / f"shot.{f:04d}.exr")
        assert a["oiio:ColorSpace"] == "lin_ap1_scene" and fmt == "float"
        assert np.allclose(a["chromaticities"], (0.713, 0.293, 0.165, 0.830, 0.128, 0.044,
                                                 0.32168, 0.33767), atol=1e-6)
        a, _ = _attrs(out / "fill" / f"shot.{f:04d}.exr")
        assert a["oiio:ColorSpace"] == "lin_rec709_scene"
        assert np.allclose(a["chromaticities"], (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290),
                           atol=1e-6)
        for rig in ("key", "fill"):
            a, fmt = _attrs(out / rig / "png" / f"shot.{f:04d}.png")
            assert fmt == "uint8" and tuple(a["CICP"]) == (1, 13, 0, 1)
            a, fmt = _attrs(out / rig / "hdr" / f"shot.{f:04d}.png")
            assert fmt == "uint16" and tuple(a["CICP"]) == (9, 16, 0, 1)
    _no_temporaries(out)
    # One frame through 'clphong render' with the same scene gives the same bytes: the
    # ACEScg rig's AgX at +0.5 EV from its [render] table, the fill rig's defaults.
    for rig, scene in (("key", aces_rig), ("fill", root / "fill.toml")):
        ref = tmp_path / f"ref_{rig}.png"
        hdr = tmp_path / f"ref_{rig}_pq.png"
        assert main(["render", str(scene), str(root / "seq" / "shot.0003.exr"), "--sdr", str(ref),
                     "--hdr", str(hdr)]) == 0
        assert (out / rig / "png" / "shot.0003.png").read_bytes() == ref.read_bytes(), rig
        assert (out / rig / "hdr" / "shot.0003.png").read_bytes() == hdr.read_bytes(), rig
    # ... and the scene's tone mapping was applied (it differs from the default).
    assert (out / "key" / "png" / "shot.0003.png").read_bytes() != _render_png(
        root / "key.toml", root, tmp_path / "plain.png")


def _render_png(scene, root, path, *options, frame=3):
    assert main(["render", str(scene), str(root / "seq" / f"shot.{frame:04d}.exr"),
                 "--sdr", str(path), *options]) == 0
    return path.read_bytes()


def test_command_line_overrides_each_rigs_render_table(shot, aces_rig, tmp_path, capsys):
    root, _ = shot
    out = tmp_path / "out"
    opts = ["--tonemap", "hable", "--white", "6", "--exposure", "-1", "--bits", "16",
            "--working-space", "lin_rec709", "--exr-type", "half", "--exr-compression", "piz"]
    args = ["relight", str(root / "seq" / "shot.####.exr"), "--rig", f"key={aces_rig}",
            "--frames", "3", "-o", str(out / "{rig}.####.exr"),
            "--sdr", str(out / "{rig}.####.png"), "--sdr", str(out / "{rig}.####.tif"), *opts]
    assert main(args) == 0
    ref = _render_png(aces_rig, root, tmp_path / "ref.png", *opts)
    assert (out / "key.0003.png").read_bytes() == ref
    _render_png(aces_rig, root, tmp_path / "ref.tif", *opts)
    # (TIFF headers carry the time of writing: compare pixels and the other tags.)
    assert np.array_equal(read_rgb(out / "key.0003.tif"), read_rgb(tmp_path / "ref.tif"))
    ta, tb = (_attrs(p)[0] for p in (out / "key.0003.tif", tmp_path / "ref.tif"))
    assert ta.pop("DateTime", None) and tb.pop("DateTime", None) and ta == tb
    assert _attrs(out / "key.0003.png")[1] == "uint16"
    a, fmt = _attrs(out / "key.0003.exr")
    assert fmt == "half" and a["compression"] == "piz" and a["oiio:ColorSpace"] == "lin_rec709_scene"
    # Each override matters: without them the scene's AgX +0.5 EV gives another image.
    assert (out / "key.0003.png").read_bytes() != _render_png(aces_rig, root, tmp_path / "s.png",
                                                              "--bits", "16")


def test_dry_run_lists_every_file_and_resume_writes_only_the_missing_ones(shot, tmp_path, capsys):
    root, _ = shot
    out = tmp_path / "out"
    args = _kinds_args(root, root / "key.toml", out, "--frames", "1-2")
    assert main(args + ["--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 * 2 * 3 and all(ln.startswith("write  frame ") for ln in lines)
    assert sum(ln.endswith(".png") and "/hdr/" in ln for ln in lines) == 4
    assert not out.exists()
    assert main(args) == 0
    capsys.readouterr()
    png = out / "key" / "png" / "shot.0002.png"
    exr = out / "key" / "shot.0002.exr"
    good, exr_stat = png.read_bytes(), exr.stat()
    png.unlink()                         # frame 2 of rig key is no longer complete
    assert main(args + ["--skip-existing", "--dry-run"]) == 0
    res = capsys.readouterr()
    assert [ln for ln in res.out.splitlines() if ln.startswith("write")] == [
        f"write  frame 2 [key] {root / 'seq' / 'shot.0002.exr'} -> {png}"]
    assert "1 file(s) to write for 1 frame(s) x rig(s), 3 skipped" in res.err
    assert main(args + ["--skip-existing"]) == 0
    assert "1 written, 3 skipped (exist), 0 failed" in capsys.readouterr().err
    assert png.read_bytes() == good
    assert exr.stat().st_mtime_ns == exr_stat.st_mtime_ns and exr.stat().st_ino == exr_stat.st_ino
    _no_temporaries(out)


def test_failed_frames_leave_no_output_of_any_kind(shot, tmp_path, capsys):
    root, expected = shot
    seq = tmp_path / "seq"
    seq.mkdir()
    for f in (1, 2, 3):
        src = root / "seq" / f"shot.{f:04d}.exr"
        (seq / src.name).write_bytes(src.read_bytes()[:300] if f == 2 else src.read_bytes())
    out = tmp_path / "out"
    args = ["relight", str(seq / "shot.####.exr"), "--rig", str(root / "key.toml"),
            "-o", str(out / "{name}.####.exr"), "--sdr", str(out / "{name}.####.png"),
            "--hdr", str(out / "{name}.pq.####.png")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "2 written, 0 skipped (exist), 1 failed" in err
    assert "failed: 1 output(s) of 1 frame(s):" in err and "  frame 2 (" in err
    assert sorted(p.name for p in out.iterdir()) == [
        "shot.0001.exr", "shot.0001.png", "shot.0003.exr", "shot.0003.png",
        "shot.pq.0001.png", "shot.pq.0003.png"]
    _no_temporaries(out)


@pytest.mark.parametrize("extra, words", [
    (["--view", "Nope"], "rig 'key_aces' ("),
    (["--tonemap", "filmic"], "valid: 'none'"),
    (["--hdr", "out/{rig}.####.jpg"], "output template out/{rig}.####.jpg: a HDR output must end in"),
    (["--sdr", "out/same.png"], "add {rig} or ####"),
])
def test_output_option_errors_are_one_line_before_any_work(shot, aces_rig, tmp_path, capsys,
                                                           extra, words):
    root, _ = shot
    extra = [x.replace("out/", str(tmp_path / "out") + "/") for x in extra]
    words = words.replace("out/", str(tmp_path / "out") + "/")
    args = ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(aces_rig),
            "-o", str(tmp_path / "out" / "{rig}.####.exr"), *extra]
    if "--view" in extra:
        args += ["--tonemap", "none", "--sdr", str(tmp_path / "out" / "{rig}.####.png")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith("clphong: error: ") and words in err and err.count("\n") == 1, err
    if "--view" in extra:
        assert "key_aces.toml" in err and "views:" in err
    assert not (tmp_path / "out").exists()


def test_relight_without_any_output_is_a_usage_error(shot, capsys):
    root, _ = shot
    with pytest.raises(SystemExit) as info:
        main(["relight", str(root / "seq"), "--rig", str(root / "key.toml")])
    assert info.value.code == 2
    assert "at least one output template" in capsys.readouterr().err


def test_resume_after_sigterm_with_sdr_outputs(shot, tmp_path, capsys):
    """A run killed mid-batch, resumed: every EXR and PNG is that of an uninterrupted run."""
    root, expected = shot
    ref = tmp_path / "ref"
    sdr = lambda out: ["--sdr", str(out / "{rig}" / "png" / "{name}.####.png")]  # noqa: E731
    assert main(_args(root, ref, *sdr(ref))) == 0
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "clphong", *_args(root, out, *sdr(out))],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    _wait_for_outputs(proc, out, 4)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 128 + signal.SIGTERM
    _no_temporaries(out)
    pngs = sorted(out.rglob("*.png"))
    assert len(pngs) < 48, "the kill should land mid-batch"
    for p in pngs:                       # what exists is complete
        assert p.read_bytes() == (ref / p.relative_to(out)).read_bytes(), p
    capsys.readouterr()
    assert main(_args(root, out, *sdr(out), "--skip-existing")) == 0
    assert "0 failed" in capsys.readouterr().err
    _check_outputs(out, expected)
    for p in sorted(ref.rglob("*.png")):
        assert p.read_bytes() == (out / p.relative_to(ref)).read_bytes(), p
    assert len(list(out.rglob("*.png"))) == 48
    _no_temporaries(out)


def test_exr_template_with_another_extension_fails_once_before_any_frame(shot, tmp_path, capsys,
                                                                         monkeypatch):
    """-o out/{rig}.####.png: one line naming the template, exit 1, before any frame runs
    (not one 'give a name ending in .exr' per frame)."""
    import clphong.pipeline.batch

    def no_frames(*a, **k):
        raise AssertionError("frames ran before the templates were checked")

    patch_everywhere(monkeypatch, clphong.pipeline.batch, "run_batch", no_frames)
    root, _ = shot
    out = tmp_path / "out"
    tmpl = str(out / "{rig}.####.png")
    assert main(["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
                 "-o", tmpl]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err == f"clphong: error: output template {tmpl}: a scene-linear output must end in .exr\n"
    assert not out.exists()


def test_failure_summary_lists_at_most_20_then_counts_the_rest():
    from clphong.pipeline.batch import MAX_FAILURES_LISTED, BatchResult, Outcome

    outcomes = [Outcome(f, f"in.{f:04d}.exr", "key", f"out.{f:04d}.exr", ok=False, error="bad frame")
                for f in range(1, 101)]
    outcomes.append(Outcome(101, "in.0101.exr", "key", "out.0101.exr", ok=True))
    lines = BatchResult(outcomes, skipped=0, seconds=1.0).summary()
    assert lines[0].startswith("1 written, 0 skipped (exist), 100 failed")
    assert lines[1] == "failed: 100 output(s) of 100 frame(s):"
    frames = [ln for ln in lines if ln.startswith("  frame ")]
    assert len(frames) == MAX_FAILURES_LISTED == 20
    assert frames[0].startswith("  frame 1 (in.0001.exr) [key]: bad frame")
    assert lines[-1] == "  ... and 80 more"
    # at the limit, nothing is elided
    lines = BatchResult(outcomes[:20], skipped=0, seconds=1.0).summary()
    assert len([ln for ln in lines if ln.startswith("  frame ")]) == 20
    assert not any("more" in ln for ln in lines)


def test_relight_help_shows_percent_patterns_once(capsys):
    with pytest.raises(SystemExit) as info:
        main(["relight", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "P.%04d.exr" in out and "%%" not in out


# ---------------------------------------------------------------- renderer options


def _recording_run_batch(monkeypatch):
    """Wrap clphong.pipeline.batch.run_batch to keep the RelighterSpecs the command built."""
    import clphong.pipeline.batch

    seen = []
    real = clphong.pipeline.batch.run_batch

    def record(plan, specs, **kw):
        seen.append(specs)
        return real(plan, specs, **kw)

    patch_everywhere(monkeypatch, clphong.pipeline.batch, "run_batch", record)
    return seen


def _as_worker_builds(spec):
    """The relighter a worker builds: from the spec after pickling (spawn pools, Dask)."""
    import pickle

    again = pickle.loads(pickle.dumps(spec))
    assert again == spec and hash(again) == hash(spec)
    return again.build()


@pytest.mark.parametrize("path, jobs", [("float", 1), ("float", 2), ("fast", 2)])
def test_relight_path_float_equals_render_path_float(shot, tmp_path, path, jobs, capsys, monkeypatch):
    root, expected = shot
    seen = _recording_run_batch(monkeypatch)
    out = tmp_path / "out"
    assert main(_args(root, out, "--frames", "1-4", "--path", path, "--jobs", str(jobs))) == 0
    differs = False
    for f in range(1, 5):
        for rig in ("key", "fill"):
            single = tmp_path / f"render.{rig}.{f}.exr"
            assert main(["render", str(root / f"{rig}.toml"), str(root / "seq" / f"shot.{f:04d}.exr"),
                         "-o", str(single), "--path", path]) == 0
            batch = read_rgb(out / rig / f"shot.{f:04d}.exr")
            assert np.array_equal(batch, read_rgb(single)), (f, rig)      # bit-identical
            differs |= not np.array_equal(batch, expected[(f, rig)])   # expected: accurate path
    assert differs, f"--path {path} gave the accurate path's images: the option did not reach the kernel"
    [specs] = seen
    for spec in specs.values():
        assert spec.path == path
        r = _as_worker_builds(spec)
        assert r.renderer.fp64_directions is False and r.renderer.path == path
        defines = r.renderer.plan_for(()).defines
        assert defines["DIRECTIONS_FP64"] == 0
        assert defines["POW_FP32"] == (path == "fast")


MANY_LIGHTS_HEAD = """\
[camera]
type = "orthographic"
direction = [0.0, 0.0, -1.0]
[material]
model = "phong"
k_a = 0.0
k_d = 0.7
k_s = 0.3
h = 24.0
"""


@pytest.fixture(scope="module")
def culled_shot(tmp_path_factory):
    """4 frames of a 96x48 wavy surface and a rig of 60 small-reach point lights (culling prunes)."""
    from conftest import heightfield, point_lights

    from clphong.io.gbuffer import write_gbuffer

    root = tmp_path_factory.mktemp("culled")
    (root / "seq").mkdir()
    rng = np.random.default_rng(11)
    for f in range(1, 5):
        g = heightfield(rng, h=48, w=96, bumps=0.1 * f)
        write_gbuffer(root / "seq" / f"wave.{f:04d}.exr", g.position, g.normal, g.albedo,
                      coverage=g.coverage)
    text = [MANY_LIGHTS_HEAD]
    for light in point_lights(rng, 60, extent=(9.5, 4.7)):
        text.append("[[light]]\ntype = \"point\"\n"
                    f"position = [{', '.join(f'{x:.6f}' for x in light['position'])}]\n"
                    f"color = [{', '.join(f'{x:.6f}' for x in light['color'])}]\n"
                    f"intensity = {light['intensity']:.6f}\n"
                    f"attenuation = [{', '.join(f'{x:.1f}' for x in light['attenuation'])}]\n")
    (root / "many.toml").write_text("\n".join(text))
    return root


def test_relight_max_error_equals_render_max_error(culled_shot, tmp_path, capsys, monkeypatch):
    import clphong

    root = culled_shot
    seen = _recording_run_batch(monkeypatch)
    out = tmp_path / "out"
    cull = ["--max-error", "1e-3", "--reference-white", "2"]
    assert main(["relight", str(root / "seq" / "wave.####.exr"), "--rig", str(root / "many.toml"),
                 "-o", str(out / "{rig}.####.exr"), "--jobs", "2", *cull]) == 0
    for f in range(1, 5):
        single = tmp_path / f"render.{f}.exr"
        assert main(["render", str(root / "many.toml"), str(root / "seq" / f"wave.{f:04d}.exr"),
                     "-o", str(single), *cull]) == 0
        assert np.array_equal(read_rgb(out / f"many.{f:04d}.exr"), read_rgb(single)), f
    [specs] = seen
    spec = specs["many"]
    assert (spec.max_error, spec.reference_white) == (1e-3, 2.0)
    r = _as_worker_builds(spec)
    assert r.renderer.max_error == pytest.approx(2e-3)          # absolute: eps x reference white
    # The rig really is culled (so equal images are not just brute force twice).
    rgb = r.relight(str(root / "seq" / "wave.0001.exr"))
    result = r.renderer.render(r.read(str(root / "seq" / "wave.0001.exr")))
    assert np.array_equal(result.image, rgb)
    assert result.plan.defines["CULLING"] == 1
    assert result.cull.kept_fraction < 0.8, result.cull
    brute = clphong.Relighter(str(root / "many.toml")).relight(str(root / "seq" / "wave.0001.exr"))
    assert not np.array_equal(rgb, brute)
    assert np.array_equal(rgb, read_rgb(out / "many.0001.exr"))


def test_nonfinite_error_fails_only_the_nan_frame(shot, tmp_path, capsys):
    import clphong
    from clphong.io.gbuffer import write_gbuffer

    root, expected = shot
    seq = tmp_path / "seq"
    seq.mkdir()
    for f in range(1, 5):
        src = root / "seq" / f"shot.{f:04d}.exr"
        if f == 3:
            g = clphong.read_gbuffer(src)
            P = g.position.copy()
            y, x = np.argwhere(g.coverage > 0)[0]
            P[y, x, 1] = np.nan
            write_gbuffer(seq / src.name, P, g.normal, g.albedo, coverage=g.coverage)
        else:
            (seq / src.name).write_bytes(src.read_bytes())
    out = tmp_path / "out"
    args = ["relight", str(seq / "shot.####.exr"), "--rig", str(root / "key.toml"), "--rig",
            str(root / "fill.toml"), "-o", str(out / "{rig}" / "{name}.####.exr")]
    assert main(args + ["--nonfinite", "error", "--jobs", "2"]) == 1
    err = capsys.readouterr().err
    _check_outputs(out, expected, frames=(1, 2, 4))
    assert not (out / "key" / "shot.0003.exr").exists() and not (out / "fill" / "shot.0003.exr").exists()
    assert "6 written, 0 skipped (exist), 2 failed" in err
    [line] = [ln for ln in err.splitlines() if ln.startswith("  frame ")]
    assert line.startswith(f"  frame 3 ({seq / 'shot.0003.exr'}) [key, fill]: non-finite"), line
    assert "P.X,P.Y,P.Z: 1 pixel(s)" in line                   # the buffer, and the count
    _no_temporaries(out)
    # The default policy shades the frame, that pixel as background.
    assert main(args + ["--skip-existing"]) == 0
    assert "2 written, 6 skipped (exist), 0 failed" in capsys.readouterr().err


@pytest.mark.parametrize("option, fragment", [
    (["--max-error", "-1"], "--max-error: expected a finite number ≥ 0, got -1.0"),
    (["--max-error", "nan"], "--max-error: expected a finite number ≥ 0, got nan"),
    (["--max-error", "1e-3", "--reference-white", "0"], "--reference-white: expected a finite number > 0, got 0.0"),
    (["--reference-white", "-2"], "--reference-white: expected a finite number > 0, got -2.0"),
])
@pytest.mark.parametrize("command", ["relight", "render"])
def test_bad_renderer_options_are_one_line_before_any_frame(shot, tmp_path, capsys, monkeypatch,
                                                            option, fragment, command):
    import clphong.io.gbuffer

    def no_frames(*a, **k):
        raise AssertionError("a frame was read before the options were checked")

    patch_everywhere(monkeypatch, clphong.io.gbuffer, "read_gbuffer", no_frames)
    root, _ = shot
    out = tmp_path / "out"
    if command == "relight":
        args = _args(root, out, *option)
    else:
        args = ["render", str(root / "key.toml"), str(root / "seq" / "shot.0001.exr"),
                "-o", str(out / "x.exr"), *option]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err == f"clphong: error: {fragment}" + err[len(f"clphong: error: {fragment}"):]
    assert err.count("\n") == 1, err
    assert not out.exists()


def test_render_and_relight_share_the_renderer_options():
    """One definition: the same flags, choices, defaults and help in both parsers."""
    from clphong.console.cli import _build_parser

    parser = _build_parser()
    subs = next(a for a in parser._actions if a.dest == "command").choices
    flags = ("--nonfinite", "--max-error", "--reference-white", "--path")

    def options(name):
        acts = {s: a for a in subs[name]._actions for s in a.option_strings}
        return {f: (acts[f].choices, acts[f].default, acts[f].help, acts[f].type) for f in flags}

    assert options("render") == options("relight")


def test_pool_workers_share_the_cores_and_the_memory(monkeypatch):
    """Each of N workers plans within 1/N of the memory this process may use (it would
    otherwise budget against the same available memory as the others) and uses 1/N of
    the cores; a CLPHONG_MAX_MEMORY the user set is each worker's own."""
    from clphong.core.memory import MemoryBudget
    from clphong.pipeline import pool

    monkeypatch.delenv("CLPHONG_MAX_MEMORY", raising=False)
    monkeypatch.setattr(pool, "memory_budget", lambda: MemoryBudget(8 * 2 ** 30, "test"))
    monkeypatch.setattr(pool.os, "cpu_count", lambda: 8)
    assert pool.worker_environment(2) == {"POCL_CPU_MAX_CU_NUM": "4",
                                          "CLPHONG_MAX_MEMORY": str(4 * 2 ** 30)}
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "1G")
    assert "CLPHONG_MAX_MEMORY" not in pool.worker_environment(2)
    monkeypatch.setattr(pool, "memory_budget", lambda: MemoryBudget(None, "no limit"))
    monkeypatch.delenv("CLPHONG_MAX_MEMORY")
    assert pool.worker_environment(3) == {"POCL_CPU_MAX_CU_NUM": "2"}


@pytest.mark.parametrize("tty,quiet", [(True, False), (True, True), (False, False)],
                         ids=["terminal", "quiet", "not-a-terminal"])
def test_progress_bar_on_a_terminal_only_and_not_with_quiet(shot, tmp_path, capsys, monkeypatch,
                                                            tty, quiet):
    """tqdm's bar (outputs done of the total, outputs/s and ETA) on a terminal; none with
    --quiet (which also drops the totals) or when stderr is not a terminal."""
    root, _ = shot
    monkeypatch.setattr(sys.stderr, "isatty", lambda: tty)
    argv = _args(root, tmp_path, "--frames", "1-3", *(["--quiet"] if quiet else []))
    assert main(argv) == 0
    err = capsys.readouterr().err
    shows_bar = "6/6" in err and "output/s" in err
    assert shows_bar == (tty and not quiet), err
    assert ("6 written" in err) == (not quiet), err


def test_a_range_far_beyond_the_shot_answers_at_once_and_counts_the_missing(shot, tmp_path, capsys):
    """relight --frames 1-1000000000 on a short shot was killed by the out-of-memory killer
    after 100 s (1-1000000 took 1 GB and 100 s even with --dry-run): the frames on disk in
    the range are relit, the rest counted in one line, exit 1, in well under a second of
    planning."""
    import time

    root, expected = shot
    out = tmp_path / "out"
    args = ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
            "-o", str(out / "{rig}.####.exr"), "--frames", "20-1000000000"]
    t0 = time.perf_counter()
    assert main(args + ["--dry-run"]) == 0
    assert time.perf_counter() - t0 < 1.0
    err = capsys.readouterr().err
    assert "5 file(s) to write for 5 frame(s) x rig(s)" in err
    assert "999999976 frame(s) of --frames 20-1000000000 have no file (first: 25, 26, 27, 28, 29, ...)" in err
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "5 written, 0 skipped (exist), 0 failed" in err and "999999976 frame(s)" in err
    for f in range(20, 25):
        assert np.array_equal(read_rgb(out / f"key.{f:04d}.exr"), expected[(f, "key")])
