"""Real Blender renders (gbuffers/blender/, made by its make_fixtures.py with bpy 5.0.1 and
4.5.15, Cycles, 1024 samples): read in every layout, relit with their own lights, and held
against the float64 reference and against Blender's own Combined pass, to its noise."""

from __future__ import annotations

import warnings

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import GBUFFERS, check_against_reference

from clphong.device.renderer import Renderer
from clphong.io.gbuffer import read_gbuffer
from clphong.model.scene import load_scene

DIR = GBUFFERS / "blender"
FILES = ("cycles-5.0.exr", "cycles-5.0-interleaved.exr", "cycles-4.5.exr")


def _passes(name):
    """{channel: (H, W) array} of every part of a fixture, read with OpenImageIO alone."""
    inp = oiio.ImageInput.open(str(DIR / name))
    out, sub = {}, 0
    while inp.seek_subimage(sub, 0):
        s = inp.spec()
        px = np.asarray(inp.read_image(sub, 0, 0, s.nchannels, "float")).reshape(s.height, s.width, -1)
        out.update({c: px[..., k] for k, c in enumerate(s.channelnames)})
        sub += 1
    inp.close()
    return out


def _rgb(p, layer):
    return np.stack([p[f"ViewLayer.{layer}.{c}"] for c in "RGB"], -1).astype(np.float64)


@pytest.fixture(scope="module")
def scene():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_scene(DIR / "spheres.toml")


def _interior(gb):
    """Fully covered pixels whose 3×3 neighbourhood is covered and of one albedo (no object
    boundary inside the pixel filter), where Blender's filtered passes are one surface's."""
    a, alb = gb.coverage, gb.albedo
    h, w = a.shape
    ok = np.zeros((h, w), bool)
    for y in range(1, h - 1):
        for x in range(1, w - 1):
            ok[y, x] = (a[y - 1:y + 2, x - 1:x + 2] == 1).all() and \
                np.abs(alb[y - 1:y + 2, x - 1:x + 2] - alb[y, x]).max() < 1e-4
    return ok


@pytest.mark.parametrize("name", FILES)
def test_every_layout_reads_as_blender(name):
    gb = read_gbuffer(DIR / name)
    assert gb.convention == "blender" and gb.coverage is not None
    diffuse = "DiffCol" if "4.5" in name else "Diffuse Color"
    assert gb.sources["albedo"].startswith(f"{DIR / name}: ViewLayer.{diffuse}.R")
    if name == "cycles-5.0.exr":                        # multi-part: the part is named
        assert "(part " in gb.sources["position"]
    counts = gb.attributes["clphong:coverage"]
    assert counts["partial"] > 0 and counts["edge_background"] == 0
    assert counts["edge_positions"] > 0                 # Blender's first-sample (0, 0, 0) positions


def test_multipart_and_interleaved_are_the_same_buffers():
    a, b = read_gbuffer(DIR / FILES[0]), read_gbuffer(DIR / FILES[1])
    for key in ("position", "normal", "albedo", "coverage"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key


@pytest.mark.parametrize("name", FILES)
def test_relit_fixture_matches_the_float64_reference(name, scene):
    check_against_reference(scene, read_gbuffer(DIR / name))


def test_relit_fixture_matches_blenders_combined_to_its_noise(scene):
    """The 5.0 and 4.5 files are two independent renders of one scene (Position is
    bit-identical): their difference measures Cycles' noise, √2·σ per pixel. clphong against
    the 5.0 Combined must be within that noise (a wrong convention, e.g. a missing π, is off
    by a factor); the groups likewise against Combined_key and Combined_fill."""
    gb = read_gbuffer(DIR / FILES[0])
    p50, p45 = _passes(FILES[0]), _passes(FILES[2])
    res = Renderer(scene).render(gb)
    m = _interior(gb)
    for layer, mine in (("Combined", res.image), *((f"Combined_{g}", res.layers[g]) for g in ("key", "fill"))):
        c50, c45 = _rgb(p50, layer), _rgb(p45, layer)
        lit = m & (c50.max(-1) > 1e-3 * c50.max())
        noise = np.abs(c50 - c45)[lit].mean() / np.sqrt(2)            # E|X − Y|/√2: one render's
        err = np.abs(mine.astype(np.float64) - c50)[lit].mean()
        assert err <= 1.5 * noise, (layer, err, noise)
        # the mean ratio, within 3σ of a mean of noise: σ ≈ 1.25·E|e| (normal noise), about
        # one independent value per 3×3 pixels (Blender's 1.5-pixel filter spreads each
        # sample over its neighbours), the three channels of a pixel not independent
        bias = mine[lit].astype(np.float64).sum() / c50[lit].sum()
        sigma_mean = 1.25 * noise / c50[lit].mean() / np.sqrt(lit.sum() / 9)
        assert abs(bias - 1) <= 3 * sigma_mean, (layer, bias, sigma_mean)
    # the groups add up to the beauty, and alpha is Blender's
    assert np.abs(res.layers["key"] + res.layers["fill"] - res.image).max() < 1e-6
    assert np.array_equal(np.asarray(gb.coverage), p50["ViewLayer.Combined.A"])


def test_edge_pixels_are_shaded_on_a_surface(scene):
    """Partly covered pixels: un-premultiplied albedo, a stand-in position for Blender's
    background first sample; premultiplied by α they match Combined far better than shading
    them at the world origin (the position Blender wrote), which was 0.117 against 0.033."""
    gb = read_gbuffer(DIR / FILES[0])
    raw = read_gbuffer(DIR / FILES[0], premultiplied=False)
    c50 = _rgb(_passes(FILES[0]), "Combined")
    a = gb.coverage
    edge = (a > 0) & (a < 1) & (c50.max(-1) > 1e-3 * c50.max())
    ours = Renderer(scene).render(gb).image
    rel = np.abs(ours - c50).max(-1)[edge] / c50.max(-1)[edge]
    assert np.median(rel) < 0.05
    # un-premultiplying matters: without it the edges are darker by α
    naive = Renderer(scene).render(raw).image
    rel_naive = np.abs(naive - c50).max(-1)[edge] / c50.max(-1)[edge]
    assert np.median(rel) < np.median(rel_naive)


def test_blender_file_without_coverage_warns_in_one_line(tmp_path):
    """The Combined part (coverage) removed from the 5.0 file: read, with one warning."""
    from clphong.core.errors import InputWarning

    inp = oiio.ImageInput.open(str(DIR / FILES[0]))
    specs, pixels, sub = [], [], 0
    while inp.seek_subimage(sub, 0):
        s = inp.spec()
        if s.get_string_attribute("name") != "ViewLayer.Combined":
            specs.append(s)
            pixels.append(np.asarray(inp.read_image(sub, 0, 0, s.nchannels, "float")))
        sub += 1
    inp.close()
    path = str(tmp_path / "no-alpha.exr")
    out = oiio.ImageOutput.create(path)
    assert out.open(path, specs)
    for k, px in enumerate(pixels):
        if k:
            assert out.open(path, specs[k], "AppendSubimage")
        assert out.write_image(px)
    assert out.close()
    with pytest.warns(InputWarning) as record:
        gb = read_gbuffer(path)
    assert gb.coverage is None and len(record) == 1
    msg = str(record[0].message)
    assert msg.startswith(f"{path}: no coverage channel") and "\n" not in msg
