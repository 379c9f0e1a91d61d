"""Batch relighting: sequences, ranges, templates, failures, resume after a kill."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from clphong.batch import (BatchError, expand_sequence, format_output, parse_frame_range,
                           plan_batch, Rig)
from clphong.cli import main

from conftest import random_gbuffer

H, W = 24, 32

SCENE = """\
[camera]
type = "perspective"
position = [0.0, 2.0, 6.0]
[material]
model = "phong"
k_a = 0.1
k_d = 0.7
k_s = 0.2
h = 32.0
[[light]]
type = "point"
position = [{x}, 5.0, 4.0]
intensity = 20.0
[[light]]
type = "ambient"
"""


def _read(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp, oiio.geterror()
    px = inp.read_image(oiio.FLOAT)
    inp.close()
    return np.asarray(px)


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    """24 frames of 32x24 G-buffers, two rig scene files, and the expected images.

    The expected image of each frame and rig is rendered independently, one
    frame at a time through clphong.render (itself held against the float64
    reference by test_kernels.py); a batch must reproduce it bit for bit,
    because it runs the same kernel on the same data.
    """
    import clphong
    from clphong.gbuffer import write_gbuffer

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
            expected[(f, rig)] = r.render(g)
    return root, expected


def _args(root, out, *extra):
    return ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
            "--rig", str(root / "fill.toml"), "-o", str(out / "{rig}" / "{name}.####.exr"), *extra]


def _check_outputs(out, expected, frames=range(1, 25)):
    for f in frames:
        for rig in ("key", "fill"):
            px = _read(out / rig / f"shot.{f:04d}.exr")
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
    # '#' padding must match exactly: shot.01.exr is not frame 1 of shot.####.exr
    assert [f for f, _ in expand_sequence(str(root / "seq" / "shot.##.exr"), [1])] == [1]
    with pytest.raises(BatchError, match="no files match"):
        expand_sequence(str(root / "seq" / "shot.##.exr"))


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
            from clphong.output import write_exr
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
                                       (signal.SIGKILL, 1)],
                         ids=["SIGTERM", "SIGINT", "SIGTERM-jobs2", "SIGKILL"])
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
        assert np.array_equal(_read(p), expected[(f, p.parent.name)]), p
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
