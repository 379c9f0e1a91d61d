"""clphong.deliver.writers: every EXR compression and its levels, JPEG SDR output,
straight alpha in the display outputs, and ``clphong --version``.

Tolerances, each derived where it is used:

* Lossless EXR compressions (none, rle, zips, zip, piz, htj2k256, htj2k32):
  bit-identical; at half, identical to numpy's float16 rounding (OpenImageIO and
  numpy both round float to half to nearest even).
* pxr24: float is rounded to 24 bits (sign, 8 exponent and 15 mantissa bits):
  |err| ≤ 2^-16·|x| (half an ulp of a 16-bit significand); half and uint are kept.
* b44/b44a: half channels only (float channels are stored as they are). OpenEXR's
  ``pack()`` (OpenEXRCore/internal_b44.c) stores each 4x4 block's distances to the
  block maximum, in ordered half bit patterns, rounded to multiples of 2^s, s the
  smallest shift whose running differences fit 6 bits. With R the block's range,
  s ≤ s* = the smallest s with round(R / 2^s) ≤ 31 (then every rounded distance is
  in 0..31, so every difference fits), and with the maximum kept exact the error of
  a value is ≤ 2^(s*-1) bit patterns, 0 when s* = 0 (a flat or gentle block).
* dwaa/dwab: lossy DCT quantisation with no closed bound; see the test.
* 8-bit display output: dithered colour ≤ 1 LSB, rounded 16-bit ≤ ½ LSB; alpha is
  never dithered, so ≤ ½ LSB at any depth and exact on a code value.
* JPEG: see :func:`test_jpeg_sdr_is_8_bit_quality_95_dithered_and_tagged_srgb`.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import GBUFFERS, REPO

from clphong.color import ocio as color
from clphong.console.cli import main
from clphong.core.errors import OutputError
from clphong.deliver.writers import (
    EXR_BASE_COMPRESSIONS,
    HTJ2K_COMPRESSIONS,
    check_compression,
    exr_compressions,
    jpegxl_available,
    write_hdr,
    write_scene_linear,
    write_sdr,
)
from clphong.io.atomic import write_exr

REC709 = color.WORKING_SPACES["lin_rec709"]
SPHERES = [str(GBUFFERS / "spheres.toml"), str(GBUFFERS / "spheres.exr")]
LOSSLESS = ("none", "rle", "zips", "zip", "piz") + HTJ2K_COMPRESSIONS
LOSSY = ("pxr24", "b44", "b44a", "dwaa", "dwab")


def _read(path, *, unassociated: bool = False, fmt=oiio.FLOAT):
    """(attributes, pixels, spec) of an image; ``unassociated`` reads alpha as stored."""
    config = oiio.ImageSpec()
    if unassociated:
        config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    px = inp.read_image(fmt)
    assert px is not None, inp.geterror()
    inp.close()
    return {a.name: a.value for a in spec.extra_attribs}, np.asarray(px), spec


def _wide(h=32, w=40, seed=0):
    """Signed values over many binades (lossless checks)."""
    rng = np.random.default_rng(seed)
    return (rng.standard_normal((h, w, 3)) * 10.0 ** rng.integers(-3, 4, (h, w, 3))).astype(np.float32)


def _smooth(h=32, w=40):
    """A positive, smooth image (h, w multiples of 4: whole B44 blocks) with a flat corner."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    x = np.stack([xx / w, yy / h, 0.5 + 0.3 * np.sin(xx / 5.0 + yy / 7.0)], -1) * 1.5 + 0.05
    x[:8, :8] = 0.75                                   # flat 4x4 blocks: B44A's 3-byte case
    return x.astype(np.float32)


def _exr(tmp_path, x, compression, pixel_type="float", name=None):
    p = tmp_path / f"{name or compression.replace(':', '_')}_{pixel_type}.exr"
    write_scene_linear(p, x, REC709, pixel_type=pixel_type, compression=compression)
    return _read(p)[:2] + (p,)


# ------------------------------------------------------------------ the list and the probe

def test_exr_compressions_are_the_ten_of_openexr_3_and_the_htj2k_ones_this_build_writes(tmp_path):
    names = exr_compressions()
    assert names[:10] == EXR_BASE_COMPRESSIONS
    assert set(names[10:]) <= set(HTJ2K_COMPRESSIONS)
    # Independently of the probe: OpenImageIO writes zip, silently, for a name it lacks,
    # so an HTJ2K name is listed exactly when a file written with it says so.
    for name in HTJ2K_COMPRESSIONS:
        p = tmp_path / f"{name}.exr"
        write_exr(p, np.ones((4, 4, 3), np.float32), compression=name)
        written = _read(p)[0]["compression"]
        assert (written == name) == (name in names), (name, written, names)


# ------------------------------------------------------------------ round trips

@pytest.mark.parametrize("pixel_type", ["float", "half"])
@pytest.mark.parametrize("name", LOSSLESS)
def test_lossless_compressions_round_trip_bit_exact(tmp_path, name, pixel_type):
    if name not in exr_compressions():
        pytest.skip(f"this OpenImageIO/OpenEXR does not write {name}")
    x = _wide()
    a, px, _ = _exr(tmp_path, x, name, pixel_type)
    assert a["compression"] == name
    want = x if pixel_type == "float" else x.astype(np.float16).astype(np.float32)
    assert np.array_equal(px, want)


def test_pxr24_rounds_float_to_24_bits_and_keeps_half_exact(tmp_path):
    x = _wide()
    a, px, _ = _exr(tmp_path, x, "pxr24", "float")
    assert a["compression"] == "pxr24"
    err = np.abs(px - x)
    assert np.all(err <= 2.0 ** -16 * np.abs(x)), np.max(err / np.abs(x))
    assert err.max() > 0                               # it did drop the low 8 bits
    a, px, _ = _exr(tmp_path, x, "pxr24", "half")
    assert np.array_equal(px, x.astype(np.float16).astype(np.float32))


def _b44_bound(bits: np.ndarray) -> np.ndarray:
    """Per-value bound (in half bit patterns) of B44 on positive half ``bits`` (H, W, 3),
    from the block range R: 2^(s*-1), s* the smallest shift with round(R / 2^s) ≤ 31."""
    h, w, c = bits.shape
    blocks = bits.reshape(h // 4, 4, w // 4, 4, c).transpose(0, 2, 4, 1, 3).reshape(h // 4, w // 4, c, 16)
    R = blocks.max(-1) - blocks.min(-1)
    s = np.zeros_like(R)
    while True:
        wide = np.floor(R / 2.0 ** s + 0.5) > 31
        if not wide.any():
            break
        s += wide
    bound = np.where(s > 0, 2.0 ** (s - 1), 0.0)                       # (h/4, w/4, c)
    return np.repeat(np.repeat(bound, 4, axis=0), 4, axis=1)


@pytest.mark.parametrize("name", ["b44", "b44a"])
def test_b44_is_within_its_block_bound_on_half_and_stores_float_unchanged(tmp_path, name):
    x = _smooth()
    rng = np.random.default_rng(3)
    x[16:, 20:] *= rng.uniform(0.5, 1.5, x[16:, 20:].shape).astype(np.float32)  # rough blocks too
    a, px, _ = _exr(tmp_path, x, name, "half")
    assert a["compression"] == name
    # positive values: the ordered bit patterns of pack() differ as the raw ones do
    want = x.astype(np.float16).view(np.uint16).astype(np.int64)
    got = px.astype(np.float16).view(np.uint16).astype(np.int64)
    err, bound = np.abs(got - want), _b44_bound(want)
    assert np.all(err <= bound), np.max(err - bound)
    assert err.max() > 0                               # lossy on the rough blocks
    assert np.all(err[:8, :8] == 0)                    # a flat block is exact
    a, px, _ = _exr(tmp_path, x, name, "float")
    assert a["compression"] == name and np.array_equal(px, x)


@pytest.mark.parametrize("name", ["dwaa", "dwab"])
def test_dwa_is_lossy_but_close_and_records_its_level(tmp_path, name):
    """DWA quantises 8x8 DCT coefficients after a perceptual (log-like) transfer; no closed
    bound. Level 45, OpenEXR's default, is meant to be visually lossless: on a smooth image
    the mean relative error must stay under 1 % (about the Weber fraction of a just
    noticeable difference), the worst pixel under 10 %. A larger level quantises harder."""
    x = _smooth()
    errors = {}
    for level in (None, 45, 300):
        comp = name if level is None else f"{name}:{level}"
        a, px, _ = _exr(tmp_path, x, comp, "float")
        assert a["compression"] == name and np.all(np.isfinite(px))
        if level is not None:
            assert a["openexr:dwaCompressionLevel"] == float(level)
        errors[level] = px
    rel = np.abs(errors[45] - x) / x
    assert rel.mean() < 0.01 and rel.max() < 0.10, (rel.mean(), rel.max())
    assert rel.max() > 0                                               # lossy
    assert np.array_equal(errors[None], errors[45])                    # the default is 45
    assert np.abs(errors[300] - x).mean() > np.abs(errors[45] - x).mean()


@pytest.mark.parametrize("name", ["zip", "zips"])
def test_zip_levels_change_the_size_not_the_pixels(tmp_path, name):
    """OpenEXR does not record the zlib level in the file: its effect is the size. On a
    smooth half image level 1 compresses less than the default 4, and 9 more."""
    x = _smooth()
    sizes, pixels = {}, {}
    for comp in (f"{name}:1", name, f"{name}:9"):
        a, px, p = _exr(tmp_path, x, comp, "half")
        assert a["compression"] == name
        sizes[comp], pixels[comp] = os.path.getsize(p), px
    assert sizes[f"{name}:1"] > sizes[name] > sizes[f"{name}:9"], sizes
    assert all(np.array_equal(px, pixels[name]) for px in pixels.values())


# ------------------------------------------------------------------ validation

@pytest.mark.parametrize("value, want", [("zip", "zip"), ("zip:9", "zip:9"), ("zip:09", "zip:9"),
                                         ("zips:1", "zips:1"), ("dwaa:45", "dwaa:45"),
                                         ("dwab:300", "dwab:300"), ("none", "none"),
                                         ("b44a", "b44a")])
def test_check_compression_returns_what_openimageio_takes(value, want):
    assert check_compression(value, "out.exr") == want


@pytest.mark.parametrize("value, words", [
    ("bogus", "must be one of"), ("ZIP", "must be one of"), ("", "must be one of"),
    (None, "must be one of"), (3, "must be one of"),
    ("zip:0", "the level of zip must be 1 to 9, not '0'"),
    ("zips:10", "the level of zips must be 1 to 9, not '10'"),
    ("zip:", "the level of zip must be 1 to 9, not ''"),
    ("dwaa:0", "the level of dwaa must be a whole number ≥ 1"),
    ("dwab:-1", "the level of dwab must be a whole number ≥ 1"),
    ("dwaa:45.5", "the level of dwaa must be a whole number ≥ 1"),
    ("dwaa:99999999999", "the level of dwaa must be a whole number ≥ 1"),
    ("piz:3", "piz takes no level"), ("b44:2", "b44 takes no level"),
])
def test_bad_compression_names_and_levels_are_one_line_errors_listing_the_valid_ones(value, words):
    with pytest.raises(OutputError) as info:
        check_compression(value, "--exr-compression")
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("--exr-compression: EXR compression"), msg
    assert words in msg, msg
    assert all(n in msg for n in exr_compressions()) and "dwaa/dwab:LEVEL" in msg, msg


def test_write_scene_linear_refuses_a_bad_compression_and_writes_nothing(tmp_path):
    p = tmp_path / "x.exr"
    with pytest.raises(OutputError, match=rf"^{p}: EXR compression 'zip:10'"):
        write_scene_linear(p, np.zeros((2, 2, 3), np.float32), REC709, compression="zip:10")
    assert not list(tmp_path.iterdir())


def test_cli_writes_the_compression_and_level_given(tmp_path):
    out = tmp_path / "o.exr"
    assert main(["render", *SPHERES, "-o", str(out), "--exr-compression", "dwab:90"]) == 0
    a = _read(out)[0]
    assert a["compression"] == "dwab" and a["openexr:dwaCompressionLevel"] == 90.0


@pytest.mark.parametrize("value, words", [("zip:10", "the level of zip must be 1 to 9"),
                                          ("lzw", "must be one of none, rle")])
def test_cli_bad_compression_is_a_one_line_usage_error(tmp_path, capsys, value, words):
    with pytest.raises(SystemExit) as e:
        main(["render", *SPHERES, "-o", str(tmp_path / "o.exr"), "--exr-compression", value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("clphong render: error: argument --exr-compression: EXR compression")
    assert err.count("\n") == 1 and words in err and err.endswith("(see clphong render --help)\n"), err
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ JPEG

#: ITU-T T.81 Annex K, tables K.1 (luminance) and K.2 (chrominance), in natural order.
K1 = [16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55,
      14, 13, 16, 24, 40, 57, 69, 56, 14, 17, 22, 29, 51, 87, 80, 62,
      18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
      49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99]
K2 = [17, 18, 24, 47, 99, 99, 99, 99, 18, 21, 26, 66, 99, 99, 99, 99,
      24, 26, 56, 99, 99, 99, 99, 99, 47, 66, 99, 99, 99, 99, 99, 99] + [99] * 32
#: The zigzag order of a DQT segment: entry k is natural-order coefficient ZIGZAG[k] (T.81 fig. A.6).
ZIGZAG = [0, 1, 8, 16, 9, 2, 3, 10, 17, 24, 32, 25, 18, 11, 4, 5, 12, 19, 26, 33, 40, 48,
          41, 34, 27, 20, 13, 6, 7, 14, 21, 28, 35, 42, 49, 56, 57, 50, 43, 36, 29, 22,
          15, 23, 30, 37, 44, 51, 58, 59, 52, 45, 38, 31, 39, 46, 53, 60, 61, 54, 47, 55,
          62, 63]


def ijg_table(base, quality: int) -> np.ndarray:
    """libjpeg's jpeg_set_quality: scale 200 - 2q (q ≥ 50) or 5000 / q, in percent,
    rounded, clamped to 1..255 (baseline)."""
    scale = 200 - 2 * quality if quality >= 50 else 5000 // quality
    return np.clip((np.asarray(base) * scale + 50) // 100, 1, 255)


def jpeg_tables(path) -> dict[int, np.ndarray]:
    """The quantisation tables of a baseline JPEG (DQT segments), in natural order."""
    raw, i, tables = Path(path).read_bytes(), 2, {}
    assert raw[:2] == b"\xff\xd8"
    while raw[i + 1] != 0xDA:                                          # up to start of scan
        marker, length = raw[i + 1], int.from_bytes(raw[i + 2:i + 4], "big")
        j = i + 4
        while marker == 0xDB and j < i + 2 + length:
            assert raw[j] >> 4 == 0                                    # 8-bit entries
            table = np.empty(64, int)
            table[ZIGZAG] = np.frombuffer(raw[j + 1:j + 65], np.uint8)
            tables[raw[j] & 15] = table
            j += 65
        i += 2 + length
    return tables


@pytest.mark.parametrize("ext", [".jpg", ".jpeg"])
def test_jpeg_sdr_is_8_bit_quality_95_dithered_and_tagged_srgb(tmp_path, ext):
    """A grey image has no chroma (Cb = Cr = 128), so the error is the luma's: by
    Parseval (the 8x8 DCT is orthonormal) a block's RMS error from quantisation is at
    most RMS(step / 2) over the 64 steps of the quality-95 table, plus ½ LSB of dither
    and 1 LSB for libjpeg's fixed-point colour conversion and integer DCTs."""
    h, w = 48, 64
    yy, xx = np.mgrid[0:h, 0:w]
    grey = 0.15 + 0.55 * xx / (w - 1) + 0.1 * np.sin(yy / 9.0)
    x = np.repeat(grey[:, :, None], 3, axis=2).astype(np.float32)
    p = tmp_path / f"s{ext}"
    write_sdr(p, x, colorspace=color.SRGB_DISPLAY_INTEROP, cicp=color.SRGB_CICP)
    a, px, spec = _read(p)
    assert spec.nchannels == 3 and str(spec.format) == "uint8"
    # tagged as the TIFF: the EXIF sRGB tag, read back as sRGB; no cICP in a JPEG
    assert a["Exif:ColorSpace"] == 1 and a["oiio:ColorSpace"] == "srgb_rec709_scene", a
    assert "CICP" not in a
    tables = jpeg_tables(p)
    assert np.array_equal(tables[0], ijg_table(K1, 95)) and np.array_equal(tables[1], ijg_table(K2, 95))
    rms = np.sqrt(np.mean(((px - x) * 255) ** 2))
    assert rms <= np.sqrt(np.mean((ijg_table(K1, 95) / 2) ** 2)) + 1.5, rms
    plain = tmp_path / f"plain{ext}"
    write_sdr(plain, x, dither=False)
    assert plain.read_bytes() != p.read_bytes()                        # dithered by default


@pytest.mark.parametrize("kwargs, words", [
    (dict(bits=16), "JPEG holds 8 bits per channel; use --bits 8 or a PNG/TIFF"),
    (dict(alpha=np.ones((4, 4))), "JPEG cannot hold an alpha channel (--alpha); use PNG or TIFF"),
    (dict(colorspace="srgb_p3d65_display"), "a JPEG cannot be tagged with the colour space "
                                            "'srgb_p3d65_display' (only sRGB)"),
])
def test_jpeg_refuses_16_bits_alpha_and_other_colour_spaces(tmp_path, kwargs, words):
    p = tmp_path / "s.jpg"
    with pytest.raises(OutputError) as info:
        write_sdr(p, np.zeros((4, 4, 3)), **kwargs)
    assert str(info.value) == f"{p}: {words}" or str(info.value).startswith(f"{p}: {words}")
    assert "\n" not in str(info.value)
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ straight alpha

def _rgba(h=16, w=24, bits=8, seed=0):
    """Colour and alpha in [0, 1]; alpha holds 0, 1 and exact codes k / (2^bits - 1) too."""
    rng = np.random.default_rng(seed)
    rgb = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    alpha = rng.uniform(0, 1, (h, w)).astype(np.float32)
    n = 2 ** bits - 1
    alpha[0, :3] = (0.0, 1.0, 0.5)
    alpha[1] = rng.integers(0, n + 1, w) / n
    return rgb, alpha


def _check_straight(path, rgb, alpha, bits, rgb_lsb):
    n = 2 ** bits - 1
    a, px, spec = _read(path, unassociated=True)
    assert spec.nchannels == 4 and list(spec.channelnames) == ["R", "G", "B", "A"]
    assert spec.alpha_channel == 3 and str(spec.format) == f"uint{bits}"
    # A: rounded, never dithered (≤ ½ LSB even at 8 bits), exact on the codes
    assert np.max(np.abs(px[..., 3] - alpha)) * n <= 0.5 + 1e-3
    assert np.array_equal(np.rint(px[1, :, 3] * n), np.rint(alpha[1] * n))
    assert px[0, 0, 3] == 0.0 and px[0, 1, 3] == 1.0
    # RGB: the colour given, not multiplied (nor divided) by A
    assert np.max(np.abs(px[..., :3] - rgb)) * n <= rgb_lsb + 1e-3
    if not str(path).endswith(".jxl"):
        # The file says "straight": OpenImageIO's default PNG/TIFF reader premultiplies,
        # so it sees RGB x A. (Its JPEG XL writer leaves libjxl's alpha_premultiplied
        # unset, i.e. straight, and its reader returns the values as they are.)
        _, assoc, _ = _read(path)
        want = np.rint(px[..., :3] * n) / n * px[..., 3:]
        assert np.max(np.abs(assoc[..., :3] - want)) * n <= 0.5 + 1e-3
    return a


@pytest.mark.parametrize("ext, bits", [(".png", 8), (".png", 16), (".tif", 8), (".tif", 16)])
def test_sdr_alpha_is_straight_and_exact_to_quantisation(tmp_path, ext, bits):
    rgb, alpha = _rgba(bits=bits)
    p = tmp_path / f"a{ext}"
    write_sdr(p, rgb, bits=bits, alpha=alpha, colorspace=color.SRGB_DISPLAY_INTEROP,
              cicp=color.SRGB_CICP)
    a = _check_straight(p, rgb, alpha, bits, rgb_lsb=1.0 if bits == 8 else 0.5)
    assert a["oiio:ColorSpace"] == "srgb_rec709_scene"
    if ext == ".png":
        assert tuple(a["CICP"]) == color.SRGB_CICP
    else:
        assert a["tiff:UnassociatedAlpha"] == 1                        # EXTRASAMPLES: unassociated


@pytest.mark.parametrize("ext", [".png", ".jxl"])
def test_hdr_alpha_is_16_bit_straight(tmp_path, ext):
    if ext == ".jxl" and not jpegxl_available():
        pytest.skip("no JPEG XL in this OpenImageIO")
    rgb, alpha = _rgba(bits=16, seed=1)
    p = tmp_path / f"h{ext}"
    write_hdr(p, rgb, alpha=alpha)
    a = _check_straight(p, rgb, alpha, 16, rgb_lsb=0.5)
    assert tuple(a["CICP"]) == color.PQ_CICP and a["oiio:ColorSpace"] == "pq_rec2020_display"


def test_alpha_of_the_wrong_shape_is_refused(tmp_path):
    p = tmp_path / "a.png"
    with pytest.raises(OutputError, match=r"expected an alpha channel of shape \(4, 6\)"):
        write_sdr(p, np.zeros((4, 6, 3)), alpha=np.zeros((4, 6, 1)))
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------ --version

def test_version_prints_the_installed_version_and_exits_0(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    assert metadata.version("clphong") == project
    assert capsys.readouterr().out == f"clphong {project}\n"


def test_version_as_a_subprocess():
    r = subprocess.run([sys.executable, "-m", "clphong", "--version"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and r.stdout == f"clphong {metadata.version('clphong')}\n", r
