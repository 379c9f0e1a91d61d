"""Colour management and outputs: OCIO configs, working spaces, display encodings
against colour-science, written files' metadata, the CLI and the scene keys.

Tolerances:
* OCIO matrices: OCIO composes its matrices in double and applies them in float
  (3 products, 2 sums, one rounding of each coefficient): |err| ≤ 6u·Σ_j|M_ij·x_j|.
* OCIO transfer functions: OCIO's CPU renderer evaluates pow with its SSE
  polynomial approximation (src/OpenColorIO/SSE.h, "~15 bits of mantissa
  precision"): relative 2^-15, doubled, 2^-14. PQ's outer exponent m2 = 78.84
  would amplify a 2^-15 error of the inner power 79-fold; OCIO evaluates the
  ST 2084 fixed function in float with std::pow (≤ 1 ulp), whose condition
  bound 4·m2·u = 1.9e-5 is inside the same 2^-14.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import GBUFFERS

from clphong.color import ocio as color
from clphong.console.cli import main
from clphong.core.errors import ClphongError, OutputError

colour = pytest.importorskip("colour")
U = 2.0 ** -24
OCIO_REL = 2.0 ** -14
SPHERES = [str(GBUFFERS / "spheres.toml"), str(GBUFFERS / "spheres.exr")]
REC709, ACESCG = color.WORKING_SPACES["lin_rec709"], color.WORKING_SPACES["acescg"]


@pytest.fixture(scope="module")
def cfg():
    return color.load_config(color.DEFAULT_CONFIG)


def attrs(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    d = {a.name: a.value for a in spec.extra_attribs}
    pixels = inp.read_image(oiio.FLOAT)
    fmt = str(spec.format)
    inp.close()
    return d, pixels, fmt


def png_chunks(path) -> list[str]:
    """The chunk types of a PNG, in order (OpenImageIO reports no sRGB/gAMA flag of its own)."""
    import struct

    raw = open(path, "rb").read()
    assert raw[:8] == b"\x89PNG\r\n\x1a\n"
    pos, out = 8, []
    while pos < len(raw):
        n, = struct.unpack(">I", raw[pos:pos + 4])
        out.append(raw[pos + 4:pos + 8].decode("latin-1"))
        pos += 12 + n
    return out


#: How OpenImageIO 3 reads back the colour space of an sRGB display-encoded file: the
#: PNG sRGB chunk and the TIFF EXIF ColorSpace = 1 both come back as its interop ID
#: 'srgb_rec709_scene' (sRGB-encoded Rec.709), whatever name was written.
SRGB_READ_BACK = "srgb_rec709_scene"
#: Chunks that would tell a PNG reader "sRGB" / "this gamma": never in a PQ or P3 file.
SRGB_CHUNKS = {"sRGB", "gAMA", "cHRM", "iCCP"}


def check_srgb_tags(path):
    """An sRGB display-encoded SDR file as clphong writes it: exact tags per format."""
    a = attrs(path)[0]
    assert a["oiio:ColorSpace"] == SRGB_READ_BACK, a
    if str(path).endswith(".png"):
        assert tuple(a["CICP"]) == color.SRGB_CICP
        chunks = png_chunks(path)
        assert chunks.index("cICP") < chunks.index("IDAT") and "sRGB" in chunks
    else:
        assert "CICP" not in a and a["Exif:ColorSpace"] == 1, a


def check_pq_tags(path):
    a = attrs(path)[0]
    assert a["oiio:ColorSpace"] == "pq_rec2020_display" and tuple(a["CICP"]) == color.PQ_CICP, a
    assert "Exif:ColorSpace" not in a
    if str(path).endswith(".png"):
        assert not SRGB_CHUNKS & set(png_chunks(path)), png_chunks(path)


# ------------------------------------------------------------------ configs

def test_default_config_has_the_aces2_sdr_and_hdr_views(cfg):
    assert color.HDR_VIEW in cfg.views(color.HDR_DISPLAY)
    assert any("SDR" in v for v in cfg.views(cfg.default_display()))


def test_missing_config_file_is_an_error(tmp_path):
    with pytest.raises(color.ColorError, match="does not exist"):
        color.load_config(tmp_path / "nope.ocio")


def test_config_that_does_not_parse_is_an_error_not_a_silent_fallback(tmp_path):
    bad = tmp_path / "bad.ocio"
    bad.write_text("ocio_profile_version: [\n")
    with pytest.raises(color.ColorError) as info:
        color.load_config(bad)
    assert "does not load" in str(info.value) and str(bad) in str(info.value)
    # OpenImageIO itself would have carried on with its minimal built-in config:
    assert oiio.ColorConfig(str(bad)).configname() == "built-in"


def test_unknown_builtin_config_and_ocio_env(tmp_path, monkeypatch):
    with pytest.raises(color.ColorError, match="does not load"):
        color.load_config("ocio://no-such-config")
    monkeypatch.setenv("OCIO", str(tmp_path / "missing.ocio"))
    with pytest.raises(color.ColorError, match=r"\$OCIO"):
        color.load_config()
    monkeypatch.setenv("OCIO", "ocio://cg-config-latest")
    assert color.load_config().path == "ocio://cg-config-latest"


def test_bad_display_view_look_list_the_valid_ones(cfg):
    with pytest.raises(color.ColorError, match="'sRGB - Display'"):
        cfg.check_display_view("sRGB", None)
    with pytest.raises(color.ColorError, match="Un-tone-mapped"):
        cfg.check_display_view(None, "ACES 2.0 SDR")
    with pytest.raises(color.ColorError, match="ACES 1.3 Reference Gamut Compression"):
        cfg.check_display_view(None, None, "gamut")


def test_unknown_working_space_lists_the_valid_ones():
    with pytest.raises(color.ColorError, match="'lin_rec709', 'acescg'"):
        color.working_space("srgb")


# ------------------------------------------------------------------ against colour-science

def test_rec709_acescg_matrix_is_bradford_adapted_as_colour_science_computes(cfg):
    # 'ITU-R BT.709' derives its matrix from the primaries; colour's 'sRGB' uses the
    # standard's 4-decimal matrix, which differs from OCIO's by 7e-5.
    want = colour.RGB_to_RGB(np.eye(3), "ITU-R BT.709", "ACEScg",
                             chromatic_adaptation_transform="Bradford").T
    got = cfg.matrix(cfg.space_name(REC709), cfg.space_name(ACESCG))
    assert np.all(np.abs(got - want) <= 6 * U * np.abs(want).sum(axis=1, keepdims=True))
    back = cfg.working_to_rec709(ACESCG)
    assert np.allclose(back @ want, np.eye(3), atol=2e-6)


def test_untagged_buffer_would_be_read_as_acescg(cfg):
    """The pitfall: OIIO's untagged default is the scene_linear role (ACEScg here)."""
    assert cfg.oiio.getColorSpaceNameByRole("scene_linear") == "ACEScg"
    x = np.array([[[0.8, 0.2, 0.1]]], np.float32)
    tagged = cfg.display_view(x, REC709, None, "Un-tone-mapped")
    untagged = oiio.ImageBufAlgo.ociodisplay(oiio.ImageBuf(x), "sRGB - Display",
                                             "Un-tone-mapped").get_pixels(oiio.FLOAT)
    assert np.max(np.abs(tagged - untagged)) > 0.05
    want = colour.models.eotf_inverse_sRGB(x.astype(np.float64))     # all above the toe
    assert np.all(np.abs(tagged - want) <= OCIO_REL * want + 4 * U)


def srgb_toe_slope(a=0.055, g=2.4):
    """Slope of the linear toe that makes the sRGB curve C1-continuous (OCIO's
    MonCurve/ExponentWithLinear); IEC 61966-2-1 rounds it to 12.92."""
    return ((1 + a) ** g * (g - 1) ** (g - 1)) / (a ** (g - 1) * g ** g)


def test_sdr_view_encoding_matches_colour_science_srgb(cfg):
    x = np.geomspace(1e-4, 1.0, 300).reshape(1, 100, 3).astype(np.float32)
    got = cfg.display_view(x, REC709, "sRGB - Display", "Un-tone-mapped")
    want = colour.models.eotf_inverse_sRGB(x.astype(np.float64))
    # Below the break OCIO's toe slope is the exact 12.9232..., not the standard's 12.92.
    toe = np.where(x <= 0.0031308, srgb_toe_slope() / 12.92 - 1, 0.0)
    assert np.all(np.abs(got - want) <= (OCIO_REL + toe) * want + 4 * U)
    assert np.any(np.abs(got - want) > OCIO_REL * want + 4 * U)   # the toe difference is real


def test_hdr_pq_encoding_matches_colour_science_in_absolute_nits(cfg):
    """OCIO's display-linear 1.0 is 100 nits; the PQ code of Rec.2020 light L nits is
    colour's eotf_inverse_ST2084(L)."""
    x = np.geomspace(1e-3, 10.0, 300).reshape(1, 100, 3).astype(np.float32)
    got = cfg.display_view(x, REC709, color.HDR_DISPLAY, "Un-tone-mapped")
    M = colour.RGB_to_RGB(np.eye(3), "ITU-R BT.709", "ITU-R BT.2020").T   # same white: no CAT
    nits = 100.0 * np.einsum("ij,...j->...i", M, x.astype(np.float64))
    want = colour.models.eotf_inverse_ST2084(nits)
    assert np.all(np.abs(got - want) <= OCIO_REL * want + 8 * U)
    # 100 nits (the SDR white) lands on PQ code 0.508 (ST 2084 table).
    assert abs(float(colour.models.eotf_inverse_ST2084(100.0)) - 0.5081) < 1e-4


# ------------------------------------------------------------------ written files

def test_exr_has_chromaticities_colorspace_and_no_stale_interop_id(tmp_path):
    from clphong.deliver.writers import write_scene_linear
    from clphong.io.atomic import write_exr

    rgb = np.random.default_rng(0).uniform(0, 4, (8, 12, 3)).astype(np.float32)
    for ws, ptype, comp in ((ACESCG, "half", "piz"), (REC709, "float", "zip")):
        p = tmp_path / f"{ws.name}.exr"
        write_scene_linear(p, rgb, ws, pixel_type=ptype, compression=comp)
        a, px, fmt = attrs(p)
        assert np.allclose(a["chromaticities"], ws.chromaticities, atol=1e-7)
        assert a["oiio:ColorSpace"] == ws.interop_id
        assert a["colorInteropID"] == ws.interop_id
        assert a["compression"] == comp and fmt == ptype
    # A header copied from an ACEScg file onto Rec.709 pixels: the stale ID is dropped.
    p = tmp_path / "converted.exr"
    write_exr(p, rgb, attributes={"colorInteropID": "lin_ap1_scene",
                                  "oiio:ColorSpace": "lin_rec709_scene"})
    assert attrs(p)[0]["colorInteropID"] == "lin_rec709_scene"


@pytest.mark.parametrize("ext,bits", [(".png", 8), (".png", 16), (".tif", 8), (".tif", 16)])
def test_sdr_files_bit_depth_tags_and_values(tmp_path, ext, bits):
    from clphong.deliver.writers import write_sdr

    x = np.tile(np.linspace(0, 1, 64, dtype=np.float32)[None, :, None], (16, 1, 3))
    p = tmp_path / f"s{ext}"
    write_sdr(p, x, bits=bits, colorspace="srgb_rec709_display", cicp=color.SRGB_CICP)
    a, px, fmt = attrs(p)
    assert fmt == ("uint8" if bits == 8 else "uint16")
    check_srgb_tags(p)
    lsb = 1 / (2 ** bits - 1)
    # 8-bit is dithered (±½ LSB noise before rounding: |err| < 1 LSB); 16-bit is rounded.
    assert np.max(np.abs(px - x)) <= (1.0 if bits == 8 else 0.5) * lsb + 1e-6


def test_dither_removes_banding_before_8_bit_quantisation(tmp_path):
    from clphong.deliver.writers import write_sdr

    x = np.tile(np.linspace(0.2, 0.21, 256, dtype=np.float32)[None, :, None], (64, 1, 3))
    err = {}
    for dither in (False, True):
        p = tmp_path / f"d{dither}.png"
        write_sdr(p, x, bits=8, dither=dither)
        px = attrs(p)[1]
        err[dither] = np.max(np.abs(px.mean(axis=0) - x[0])) * 255   # column means, in LSB
    # Rounding: a column is off by up to ½ LSB; dithered, 64 samples average it out
    # (σ of the mean ≈ 0.29/√64 LSB ≈ 0.04; 0.25 is > 5σ).
    assert err[False] > 0.4 and err[True] < 0.25


@pytest.mark.parametrize("ext", [".png", ".jxl"])
def test_hdr_files_carry_cicp_9_16_0_1(tmp_path, ext):
    from clphong.deliver.writers import jpegxl_available, write_hdr

    if ext == ".jxl" and not jpegxl_available():
        pytest.skip("no JPEG XL in this OpenImageIO")
    x = np.random.default_rng(1).uniform(0, 1, (8, 8, 3)).astype(np.float32)
    p = tmp_path / f"h{ext}"
    write_hdr(p, x)
    a, px, fmt = attrs(p)
    assert tuple(a["CICP"]) == (9, 16, 0, 1) and fmt == "uint16"
    check_pq_tags(p)
    assert np.max(np.abs(px - x)) <= 0.5 / 65535 + 1e-6            # lossless 16-bit
    if ext == ".png":
        raw = p.read_bytes()
        i = raw.find(b"cICP")
        assert i > 0 and raw[i + 4:i + 8] == bytes([9, 16, 0, 1])


def test_writers_reject_wrong_extensions(tmp_path):
    from clphong.deliver.writers import write_hdr, write_sdr

    with pytest.raises(OutputError, match=r"\.png or \.tif"):
        write_sdr(tmp_path / "a.bmp", np.zeros((2, 2, 3)))
    with pytest.raises(OutputError, match=r"\.png or \.jxl"):
        write_hdr(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ CLI, end to end

def test_render_every_kind_in_one_run(tmp_path):
    out = {k: tmp_path / n for k, n in (("exr", "a.exr"), ("sdr", "a.png"), ("tif", "a.tif"),
                                        ("hdr", "a_pq.png"), ("sheet", "sheet.png"))}
    rc = main(["render", *SPHERES, "-o", str(out["exr"]), "--sdr", str(out["sdr"]),
               "--sdr", str(out["tif"]), "--bits", "16", "--hdr", str(out["hdr"]),
               "--contact-sheet", str(out["sheet"]), "--tonemap", "pbr-neutral",
               "--exposure", "0.5", "--working-space", "acescg", "--exr-type", "half",
               "--exr-compression", "piz"])
    assert rc == 0
    a = attrs(out["exr"])[0]
    assert a["oiio:ColorSpace"] == "lin_ap1_scene" and a["colorInteropID"] == "lin_ap1_scene"
    assert a["compression"] == "piz" and "CICP" not in a
    assert np.allclose(a["chromaticities"], ACESCG.chromaticities, atol=1e-7)
    assert attrs(out["sdr"])[2] == "uint16" and attrs(out["tif"])[2] == "uint16"
    for kind in ("sdr", "tif", "sheet"):
        check_srgb_tags(out[kind])
    check_pq_tags(out["hdr"])
    assert attrs(out["sheet"])[1].shape[1] > 4 * 300


def test_render_sdr_alone_matches_the_fused_reference(tmp_path):
    import clphong
    from clphong.device.display import DisplayTransform

    p = tmp_path / "agx.png"
    assert main(["render", *SPHERES, "--sdr", str(p), "--bits", "16", "--tonemap", "agx"]) == 0
    rgb = clphong.render(clphong.load_scene(SPHERES[0]), clphong.read_gbuffer(SPHERES[1]))
    want = DisplayTransform("agx").reference(rgb)
    # 16-bit rounding (½ LSB) plus the kernel's bound (< 1e-4 for AgX, see test_tonemap).
    assert np.max(np.abs(attrs(p)[1] - want)) <= 0.5 / 65535 + 3e-4


def test_render_ocio_view_and_errors(tmp_path, capsys):
    p = tmp_path / "v.png"
    tif = tmp_path / "v.tif"
    assert main(["render", *SPHERES, "--sdr", str(p), "--sdr", str(tif),
                 "--view", "ACES 2.0 - SDR 100 nits (Rec.709)",
                 "--look", "ACES 1.3 Reference Gamut Compression"]) == 0
    check_srgb_tags(p)
    check_srgb_tags(tif)          # the view's display is sRGB: a TIFF can say so
    bad = tmp_path / "bad.png"
    for args, words in ((["--tonemap", "filmic"], "valid: 'none'"),
                        (["--view", "Nope"], "views:"),
                        (["--ocio-config", str(tmp_path / "x.ocio")], "x.ocio"),
                        (["--tonemap", "agx", "--view", "Un-tone-mapped"], "both tone-map")):
        capsys.readouterr()
        assert main(["render", *SPHERES, "--sdr", str(bad), "--hdr", str(tmp_path / "h.png"), *args]) == 1
        err = capsys.readouterr().err
        assert err.startswith("clphong: error: ") and words in err and err.count("\n") == 1
    assert not bad.exists() and not (tmp_path / "h.png").exists()


def test_render_without_any_output_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["render", *SPHERES])
    assert info.value.code == 2


def test_displays_command_lists_displays_views_looks_and_operators():
    r = subprocess.run([sys.executable, "-m", "clphong", "displays"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    for word in ("'sRGB - Display'  (default)", color.HDR_VIEW, "looks:", "agx", "acescg"):
        assert word in r.stdout


# ------------------------------------------------------------------ scene keys

def _scene(render):
    from clphong.model.scene import parse_scene

    return parse_scene({"camera": {"type": "perspective", "position": [0, 0, 5]},
                        "material": {"model": "phong", "k_a": 0, "k_d": 0.5, "k_s": 0, "h": 1},
                        "render": render}, "s.toml")


def test_scene_colour_keys_parse_and_round_trip():
    from clphong.model.scene import parse_scene

    s = _scene({"working_space": "acescg", "exposure": -1.5, "tonemap": "Uncharted2",
                "white_point": 8, "view": "Un-tone-mapped"})
    c = s.color
    assert (c.working_space, c.exposure, c.tonemap, c.white_point, c.view) == \
        ("acescg", -1.5, "hable", 8.0, "Un-tone-mapped")
    assert parse_scene(s.to_dict(), "s.toml") == s


@pytest.mark.parametrize("render,key,words", [
    ({"tonemap": "aces2"}, "render.tonemap", "valid: 'none'"),
    ({"tonemap": 3}, "render.tonemap", "expected a string"),
    ({"working_space": "rec709"}, "render.working_space", "'lin_rec709', 'acescg'"),
    ({"exposure": "1"}, "render.exposure", "expected a number"),
    ({"exposure": 1000}, "render.exposure", "out of range"),
    ({"white_point": 0}, "render.white_point", "must be > 0"),
    ({"view": ""}, "render.view", "non-empty string"),
    ({"exposur": 1}, "render.exposur", "did you mean 'exposure'"),
])
def test_scene_colour_key_errors_name_file_and_key(render, key, words):
    from clphong.core.errors import SceneError

    with pytest.raises(SceneError) as info:
        _scene(render)
    assert str(info.value).startswith(f"s.toml: {key}: ") and words in str(info.value)
    assert isinstance(info.value, ClphongError)


# ------------------------------------------------------------------ one rule, checked up front

def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("clphong: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("outputs", [["--sdr", "a.png"], ["--hdr", "a.png"],
                                     ["--sdr", "a.png", "--view", "Un-tone-mapped"],
                                     ["--contact-sheet", "a.png"]])
@pytest.mark.parametrize("ev", ["2000", "200", "-200", "100.5"])
def test_exposure_has_the_scene_keys_range_on_every_output(outputs, ev, tmp_path, capsys):
    """Every display path refuses |EV| > 100, as the scene key does: no OverflowError
    traceback, no all-zero PQ image, no black SDR written with exit 0."""
    outputs = [str(tmp_path / a) if a.endswith(".png") else a for a in outputs]
    assert main(["render", *SPHERES, *outputs, "--exposure", ev]) == 1
    err = _one_line_error(capsys)
    assert f"--exposure {float(ev):g} stops is out of range" in err and "-100..100" in err, err
    assert list(tmp_path.iterdir()) == []
    from clphong.core.errors import SceneError

    with pytest.raises(SceneError, match="out of range"):      # the same rule in the scene
        _scene({"exposure": float(ev)})


def test_exposure_at_the_limit_is_a_picture_on_every_output(tmp_path):
    for ev in (100, -100):
        _scene({"exposure": ev})                                # the scene takes it too
        sdr, hdr = tmp_path / f"s{ev}.png", tmp_path / f"h{ev}.png"
        assert main(["render", *SPHERES, "--sdr", str(sdr), "--hdr", str(hdr),
                     "--exposure", str(ev)]) == 0
        for p in (sdr, hdr):
            px = attrs(p)[1]
            assert np.isfinite(px).all()
            assert (px.max() > 0.5) if ev > 0 else (px.max() == 0), (p, px.max())


def test_exposure_out_of_range_through_the_api_is_a_tonemap_error(cfg):
    from clphong.core.errors import ToneMapError
    from clphong.deliver.outputs import OutputOptions
    from clphong.device.display import DisplayTransform
    from clphong.model.options import MAX_EXPOSURE

    x = np.ones((1, 1, 3), np.float32)
    for ev in (2000.0, -200.0, float("inf")):
        with pytest.raises(ToneMapError):
            DisplayTransform("agx", exposure=ev)
        with pytest.raises(ToneMapError):
            cfg.display_view(x, REC709, color.HDR_DISPLAY, color.HDR_VIEW, exposure=ev)
        with pytest.raises(ToneMapError, match="exposure"):
            OutputOptions(exposure=ev).checked()
    assert MAX_EXPOSURE == 100
    DisplayTransform("agx", exposure=-MAX_EXPOSURE)


@pytest.mark.parametrize("args, words", [
    (["--sdr", "T/a.png", "--tonemap", "agx", "--ocio-config", "T/broken.ocio"], "does not load"),
    (["--sdr", "T/a.png", "--tonemap", "agx", "--ocio-config", "T/missing.ocio"], "missing.ocio"),
    (["-o", "T/a.exr", "--ocio-config", "T/broken.ocio"], "does not load"),
    (["--hdr", "T/a.png", "--view", "Nope"], "views: "),
    (["--contact-sheet", "T/a.png", "--display", "Nope"], "displays: "),
    (["-o", "T/a.exr", "--look", "Nope"], "looks: "),
    (["-o", "T/a.exr", "--hdr-view", "Nope"], "views: "),
])
def test_colour_options_are_checked_even_when_no_output_uses_them(args, words, tmp_path, capsys):
    """A bad config, display, view or look is an error, never silently ignored."""
    (tmp_path / "broken.ocio").write_text("ocio_profile_version: [\n")
    args = [a.replace("T/", f"{tmp_path}/") for a in args]
    assert main(["render", *SPHERES, *args]) == 1
    err = _one_line_error(capsys)
    assert words in err, err
    assert [p.name for p in tmp_path.iterdir()] == ["broken.ocio"]


def test_tonemap_and_view_conflict_names_the_scene_key_it_came_from(tmp_path, capsys):
    scene = tmp_path / "agx.toml"
    scene.write_text((GBUFFERS / "spheres.toml").read_text() + '\n[render]\ntonemap = "agx"\n')
    out = tmp_path / "v.png"
    assert main(["render", str(scene), SPHERES[1], "--sdr", str(out), "--view", "Un-tone-mapped"]) == 1
    err = _one_line_error(capsys)
    assert f"'agx' (the scene key render.tonemap in {scene})" in err and "(--view)" in err, err
    assert "--tonemap" not in err
    assert not out.exists()
    # given on the command line, it is named so
    assert main(["render", *SPHERES, "--sdr", str(out), "--tonemap", "agx", "--view",
                 "Un-tone-mapped"]) == 1
    assert "'agx' (--tonemap)" in _one_line_error(capsys)


def test_contact_sheet_shows_the_views_of_the_display_given(tmp_path):
    import clphong
    from clphong.deliver.contact import write_contact_sheet
    from clphong.deliver.outputs import _load_config

    display = "Display P3 - Display"
    sheet = tmp_path / "sheet.png"
    assert main(["render", *SPHERES, "--contact-sheet", str(sheet), "--display", display]) == 0
    rgb = clphong.render(clphong.load_scene(SPHERES[0]), clphong.read_gbuffer(SPHERES[1]))
    cfg = _load_config(None)
    want, default = tmp_path / "want.png", tmp_path / "default.png"
    write_contact_sheet(want, rgb, REC709, cfg, display=display)
    write_contact_sheet(default, rgb, REC709, cfg)
    assert np.array_equal(attrs(sheet)[1], attrs(want)[1])
    assert not np.array_equal(attrs(sheet)[1], attrs(default)[1])


def test_display_p3_png_is_tagged_p3_and_a_p3_tiff_is_refused(tmp_path, capsys):
    """TIFF has no cICP and OpenImageIO's TIFF writer records only sRGB (EXIF ColorSpace):
    a P3 TIFF would carry no colour space at all, so it is refused up front."""
    display = "Display P3 - Display"
    png, tif = tmp_path / "p3.png", tmp_path / "p3.tif"
    assert main(["render", *SPHERES, "--sdr", str(png), "--display", display]) == 0
    a = attrs(png)[0]
    assert a["oiio:ColorSpace"] == "srgb_p3d65_scene" and tuple(a["CICP"]) == (12, 13, 0, 1), a
    assert not SRGB_CHUNKS & set(png_chunks(png)), png_chunks(png)
    for sdr in ([tif], [png, tif]):
        capsys.readouterr()
        assert main(["render", *SPHERES, *[x for p in sdr for x in ("--sdr", str(p))],
                     "--display", display]) == 1
        err = _one_line_error(capsys)
        assert f"{tif}: a TIFF cannot be tagged with the colour space 'srgb_p3d65_display'" in err, err
    assert not tif.exists()


def test_contact_sheet_for_a_p3_display_is_p3_throughout_and_tagged_so(tmp_path, capsys):
    """The operator tiles (sRGB-encoded by the kernel) are converted to the display's
    colour space by OCIO, and the sheet is tagged with it; a TIFF sheet there is refused."""
    import clphong
    from clphong.deliver.contact import TILE_WIDTH, contact_sheet
    from clphong.deliver.outputs import _load_config

    p3 = "Display P3 - Display"
    sheet = tmp_path / "sheet.png"
    assert main(["render", *SPHERES, "--contact-sheet", str(sheet), "--display", p3]) == 0
    a = attrs(sheet)[0]
    assert a["oiio:ColorSpace"] == "srgb_p3d65_scene" and tuple(a["CICP"]) == (12, 13, 0, 1), a
    rgb = clphong.render(clphong.load_scene(SPHERES[0]), clphong.read_gbuffer(SPHERES[1]))
    cfg = _load_config(None)
    srgb, _ = contact_sheet(rgb, REC709, cfg, operators=["agx"], views=[])
    conv, _ = contact_sheet(rgb, REC709, cfg, operators=["agx"], views=[], display=p3)
    want = cfg.convert(srgb, "sRGB - Display", "Display P3 - Display")
    tile = (slice(4, 4 + 100), slice(4, 4 + TILE_WIDTH))        # below the label, inside the tile
    assert not np.allclose(conv[tile], srgb[tile], atol=1e-3)
    assert np.allclose(conv[tile], np.clip(want[tile], 0, 1), atol=1e-5)
    capsys.readouterr()
    assert main(["render", *SPHERES, "--contact-sheet", str(tmp_path / "s.tif"),
                 "--display", p3]) == 1
    assert "a TIFF cannot be tagged" in capsys.readouterr().err
