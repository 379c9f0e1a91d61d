"""Tests of clphong.deliver.outputs: the EXR's A and layers, straight alpha in the display
outputs, and the albedo's colour space."""

from __future__ import annotations

import warnings

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import GBUFFERS

from clphong.color import ocio as color
from clphong.color.ocio import ColorError
from clphong.deliver.outputs import (
    OutputOptions,
    OutputPaths,
    _load_config,
    check_outputs,
    convert_albedo,
    render_outputs,
)
from clphong.device.renderer import Renderer
from clphong.io.gbuffer import read_gbuffer
from clphong.model.scene import load_scene

BLENDER = GBUFFERS / "blender"


def _channels(path):
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)     # as stored: OpenImageIO would premultiply a PNG
    inp = oiio.ImageInput.open(str(path), config)
    spec = inp.spec()
    px = np.asarray(inp.read_image(oiio.FLOAT))
    inp.close()
    return {n: px[..., k] for k, n in enumerate(spec.channelnames)}


@pytest.fixture(scope="module")
def blender():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(BLENDER / "spheres.toml")
    return scene, read_gbuffer(BLENDER / "cycles-5.0.exr")


def test_exr_has_coverage_and_every_layer(blender, tmp_path):
    scene, gb = blender
    r = Renderer(scene, aovs=("diffuse", "specular"))
    options = OutputOptions().for_scene(scene)
    res, _ = render_outputs(r, gb, options, OutputPaths(exr=str(tmp_path / "o.exr")))
    ch = _channels(tmp_path / "o.exr")
    assert set(ch) == {"R", "G", "B", "A", *(f"{n}.{c}" for n in ("key", "fill", "diffuse", "specular")
                                             for c in "RGB")}
    assert np.array_equal(ch["A"], gb.coverage)                   # Blender's Combined.A
    for k, c in enumerate("RGB"):
        assert np.array_equal(ch[c], res.image[..., k])
        assert np.array_equal(ch[f"key.{c}"], res.layers["key"][..., k])


def test_straight_alpha_png_is_the_unpremultiplied_colour(blender, tmp_path):
    """--alpha: A = coverage, RGB the display encoding of S = beauty/α (not of α·S)."""
    scene, gb = blender
    options = OutputOptions(alpha=True, dither=False, bits=16).for_scene(scene)
    res, _ = render_outputs(Renderer(scene), gb, options, OutputPaths(sdr=str(tmp_path / "s.png")))
    ch = _channels(tmp_path / "s.png")
    a = gb.coverage
    assert np.abs(ch["A"] - a).max() <= 0.5 / 65535 + 1e-7
    opaque, _ = render_outputs(Renderer(scene), gb, OutputOptions(dither=False, bits=16).for_scene(scene),
                               OutputPaths(sdr=str(tmp_path / "o.png")))
    flat = _channels(tmp_path / "o.png")
    edge = (a > 0.2) & (a < 0.8)
    full = a == 1
    # where covered, both show the same colour; at edges the straight one is brighter
    assert np.array_equal(ch["R"][full], flat["R"][full])
    assert (ch["R"][edge] >= flat["R"][edge]).all() and (ch["R"][edge] > flat["R"][edge]).any()


def test_albedo_space_converts_with_ocio_as_colour_science_does():
    """sRGB-encoded albedo to linear Rec.709 and to ACEScg, against colour-science's sRGB
    decoding and Bradford-adapted matrix. Tolerance: OCIO's CPU processor evaluates the
    power with a fast approximation (~1e-5 relative) and its config's matrices are given
    to ~6 digits, so 1e-4 of the largest value."""
    colour = pytest.importorskip("colour")
    gb = read_gbuffer(GBUFFERS / "spheres.exr")
    cfg = _load_config(None)
    want = colour.cctf_decoding(gb.albedo.astype(np.float64), "sRGB")
    got = convert_albedo(gb, cfg, "sRGB Encoded Rec.709 (sRGB)", color.working_space("lin_rec709"))
    assert np.abs(got.albedo - want).max() <= 1e-4 * want.max()
    M = colour.matrix_RGB_to_RGB(colour.RGB_COLOURSPACES["sRGB"], colour.RGB_COLOURSPACES["ACEScg"],
                                 "Bradford")
    got = convert_albedo(gb, cfg, "sRGB Encoded Rec.709 (sRGB)", color.working_space("acescg"))
    assert np.abs(got.albedo - want @ M.T).max() <= 1e-4 * want.max()
    # the working space itself: nothing converted
    same = convert_albedo(gb, cfg, "Linear Rec.709 (sRGB)", color.working_space("lin_rec709"))
    assert same is gb


def test_unknown_albedo_space_is_one_line_before_any_work(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(GBUFFERS / "spheres.toml")
    options = OutputOptions(albedo_space="sRGB Textur").for_scene(scene)
    with pytest.raises(ColorError) as info:
        check_outputs(options, OutputPaths(exr=str(tmp_path / "x.exr")), warn=False)
    msg = str(info.value)
    assert msg.startswith("--albedo-space: 'sRGB Textur' is not a colour space") and "\n" not in msg


@pytest.mark.parametrize("kw, needle", [
    (dict(bits=16), "JPEG holds 8 bits per channel"),
    (dict(alpha=True), "JPEG cannot hold an alpha channel (--alpha)"),
    (dict(display="Display P3 - Display"), "a JPEG cannot be tagged with the colour space"),
])
def test_jpeg_limits_are_checked_before_any_work(kw, needle, tmp_path):
    """Before shading, so neither the -o EXR nor anything else is written first."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(GBUFFERS / "spheres.toml")
    from clphong.core.errors import OutputError
    options = OutputOptions(**kw).for_scene(scene)
    jpg = str(tmp_path / "x.jpg")
    with pytest.raises(OutputError) as info:
        check_outputs(options, OutputPaths(exr=str(tmp_path / "x.exr"), sdr=jpg), warn=False)
    assert str(info.value).startswith(f"{jpg}: ") and needle in str(info.value)
