"""clphong inspect and clphong diff."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import random_gbuffer

from clphong.console.cli import main
from clphong.core.errors import OutputError
from clphong.io.atomic import write_exr
from clphong.io.gbuffer import write_gbuffer
from clphong.io.inspection import diff_images, inspect_file


def _read(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp, oiio.geterror()
    spec = inp.spec()
    px = np.asarray(inp.read_image(oiio.FLOAT))
    inp.close()
    return spec, px


@pytest.fixture
def gbuffer_file(tmp_path):
    """A generic G-buffer with planted NaN, Inf and negative values and a camera."""
    rng = np.random.default_rng(4)
    g = random_gbuffer(rng, 24, 32)
    C = g.albedo.copy()
    C[0, 0, 0] = np.nan
    C[1, 2, 0] = np.nan
    C[3, 4, 1] = np.inf
    C[5, 6, 2] = -np.inf
    C[7, 8, 2] = -0.5
    M = np.eye(4)
    M[3, :3] = (-1.0, -2.0, -6.0)          # row vectors: eye at (1, 2, 6)
    path = tmp_path / "g.exr"
    write_gbuffer(path, g.position, g.normal, C, coverage=g.coverage, attributes={"worldToCamera": M})
    return path, g, C


def test_inspect_report(gbuffer_file):
    path, g, C = gbuffer_file
    rep = inspect_file(path)
    part = rep["parts"][0]
    assert part["data_window"] == [0, 0, 32, 24]
    names = [c["name"] for c in part["channels"]]
    assert {"P.X", "N.Y", "albedo.B", "A"} <= set(names)
    assert all(c["type"] == "float" for c in part["channels"])
    stats = {s["name"]: s for s in part["stats"]}
    assert (stats["albedo.R"]["nan"], stats["albedo.G"]["inf"], stats["albedo.B"]["inf"]) == (2, 1, 1)
    # negatives counted independently from the array that was written
    for i, ch in enumerate("RGB"):
        assert stats[f"albedo.{ch}"]["negative"] == int((C[..., i] < 0).sum())
    assert stats["P.X"]["negative"] == int((g.position[..., 0] < 0).sum())
    assert np.allclose(part["camera"]["eye_y_up"], (1.0, 2.0, 6.0), rtol=0, atol=1e-6)
    assert rep["gbuffer"]["convention"] == "generic"


def test_inspect_cli_text_and_json(gbuffer_file, capsys):
    path, _, _ = gbuffer_file
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "G-buffer: generic convention, 32x24" in out
    assert "totals: 2 NaN, 2 Inf" in out
    assert "camera: worldToCamera" in out and "eye (1, 2, 6)" in out
    assert main(["inspect", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["gbuffer"]["convention"] == "generic"
    assert main(["inspect", str(path.parent / "missing.exr")]) == 1
    assert "clphong: error:" in capsys.readouterr().err


def test_inspect_plain_image_is_not_a_gbuffer(tmp_path, capsys):
    write_exr(tmp_path / "rgb.exr", np.ones((4, 5, 3), np.float32), pixel_type="half")
    assert main(["inspect", str(tmp_path / "rgb.exr")]) == 0
    out = capsys.readouterr().out
    assert "R                        half" in out
    assert "G-buffer: not usable:" in out and "camera: no worldToCamera attribute" in out


# ---------------------------------------------------------------- diff


@pytest.fixture
def pair(tmp_path):
    rng = np.random.default_rng(8)
    A = rng.uniform(0.05, 4.0, (24, 32, 3)).astype(np.float32)
    B = A.copy()
    B[10, 20, 1] *= np.float32(1.001)      # one value 0.1 % off
    write_exr(tmp_path / "a.exr", A)
    write_exr(tmp_path / "b.exr", B)
    return tmp_path, A, B


def test_identical_images_match_by_every_metric(pair):
    d, A, _ = pair
    for metric, tol in (("max-rel", 0.0), ("mean-abs", 0.0), ("psnr", 1000.0), ("flip", 0.0)):
        assert main(["diff", str(d / "a.exr"), str(d / "a.exr"), "--metric", metric, "--tol", str(tol)]) == 0


def test_max_rel_and_mean_abs_values(pair, capsys):
    d, A, B = pair
    # Independent float64 computation from the stored float32 values.
    rel = abs(float(B[10, 20, 1]) - float(A[10, 20, 1])) / float(A[10, 20, 1])
    r = diff_images(d / "a.exr", d / "b.exr", metric="max-rel", tol=1.0)
    assert r.value == pytest.approx(rel, rel=1e-12) and r.worst == (20, 10, "G")
    assert main(["diff", str(d / "a.exr"), str(d / "b.exr"), "--metric", "max-rel", "--tol", "2e-3"]) == 0
    assert main(["diff", str(d / "a.exr"), str(d / "b.exr"), "--metric", "max-rel", "--tol", "5e-4"]) == 1
    assert "worst at pixel (20, 10) channel G" in capsys.readouterr().out
    mean_abs = abs(float(B[10, 20, 1]) - float(A[10, 20, 1])) / A.size
    assert diff_images(d / "a.exr", d / "b.exr", metric="mean-abs", tol=1).value == pytest.approx(mean_abs, rel=1e-12)


def test_psnr_closed_form(pair):
    d, A, B = pair
    err = float(B[10, 20, 1]) - float(A[10, 20, 1])
    mse = err * err / A.size
    want = 10 * math.log10(float(A.max()) ** 2 / mse)
    r = diff_images(d / "a.exr", d / "b.exr", metric="psnr", tol=want - 0.01)
    assert r.value == pytest.approx(want, rel=1e-12) and r.match
    assert not diff_images(d / "a.exr", d / "b.exr", metric="psnr", tol=want + 0.01).match


def test_flip_and_heatmaps(pair):
    d, A, _ = pair
    C = A * np.float32(1.5)                # a visible change everywhere
    write_exr(d / "c.exr", C)
    r = diff_images(d / "a.exr", d / "c.exr", metric="flip", tol=1.0, heatmap=d / "heat.exr")
    spec, heat = _read(d / "heat.exr")
    assert list(spec.channelnames) == ["Y"] and heat.shape == (24, 32, 1)
    assert 0 < r.value <= 1 and r.value == pytest.approx(float(heat.mean()), rel=1e-5)
    assert main(["diff", str(d / "a.exr"), str(d / "c.exr"), "--metric", "flip", "--tol", str(r.value / 2),
                 "--heatmap", str(d / "heat.png")]) == 1
    spec, png = _read(d / "heat.png")
    assert spec.nchannels == 3 and png.shape == (24, 32, 3)


def test_differences_and_trouble(pair, tmp_path, capsys):
    d, A, _ = pair
    write_exr(d / "small.exr", A[:12])
    assert main(["diff", str(d / "a.exr"), str(d / "small.exr"), "--tol", "1"]) == 1
    assert "32x24 but" in capsys.readouterr().out
    N = A.copy()
    N[0, 0, 0] = np.nan
    write_exr(d / "nan.exr", N)
    r = diff_images(d / "a.exr", d / "nan.exr", metric="mean-abs", tol=1e9)
    assert not r.match and r.nonfinite_mismatches == 1
    assert diff_images(d / "nan.exr", d / "nan.exr", metric="max-rel", tol=0).match   # same NaN: equal
    assert main(["diff", str(d / "a.exr"), str(d / "nope.exr"), "--tol", "1"]) == 2
    assert "clphong: error:" in capsys.readouterr().err


@pytest.mark.parametrize("which", ["a", "b"])
def test_heatmap_never_overwrites_an_input(pair, capsys, which):
    d, _, _ = pair
    target = d / f"{which}.exr"
    before = target.read_bytes()
    assert main(["diff", str(d / "a.exr"), str(d / "b.exr"), "--tol", "1",
                 "--heatmap", str(target)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("clphong: error: ") and err.count("\n") == 1, err
    assert f"{target}: the heat map would overwrite the input {target}" in err
    assert target.read_bytes() == before
    with pytest.raises(OutputError, match="would overwrite the input"):
        diff_images(d / "a.exr", d / "b.exr", tol=1, heatmap=d / "." / f"{which}.exr")
    assert sorted(p.name for p in d.iterdir()) == ["a.exr", "b.exr"]


@pytest.mark.parametrize("option, value, why", [
    ("--floor", "inf", "got inf"), ("--floor", "nan", "got nan"), ("--floor", "-1", "got -1.0"),
    ("--floor", "0", "got 0.0"), ("--peak", "inf", "got inf"), ("--peak", "0", "got 0.0"),
])
def test_diff_limits_that_would_make_everything_match_are_refused(pair, tmp_path, capsys, option,
                                                                  value, why):
    """--floor inf (or --peak inf) let an all-black image "match" a lit one, exit 0; nan, -1
    and 0 went in without a word. Each is refused at the door with the registry's one
    line (model.options.NUMBERS), from the CLI (exit 2) and the API alike."""
    d, A, _ = pair
    write_exr(d / "black.exr", np.zeros_like(A))
    metric = "max-rel" if option == "--floor" else "psnr"
    tol = "1e-3" if metric == "max-rel" else "40"
    assert main(["diff", str(d / "a.exr"), str(d / "black.exr"), "--metric", metric, "--tol", tol,
                 option, value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{option}: expected a finite number > 0, {why}" in err, err
    with pytest.raises(ValueError, match=f"{option}: expected a finite number > 0"):
        diff_images(d / "a.exr", d / "black.exr", metric=metric, tol=float(tol),
                    **{option[2:]: float(value)})
    # a sound limit still tells the images apart
    assert main(["diff", str(d / "a.exr"), str(d / "black.exr"), "--metric", metric, "--tol", tol,
                 option, "1e-3"]) == 1
