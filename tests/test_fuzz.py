"""Fuzzing the two doors that take untrusted files: the G-buffer reader and the scene parser.

Property: whatever the bytes, ``read_gbuffer`` and ``load_scene`` either
return a valid result or raise a :class:`~clphong.core.errors.ClphongError` whose
message is one line naming the file. Any other exception (or a crash) is a bug;
each one found became a named regression test at the bottom of this file.

Example counts: each target (the G-buffer reader, the scene parser) gets
``CLPHONG_FUZZ_EXAMPLES`` examples per run, 1000 by default, split over its
strategies. Set it higher for a longer campaign, e.g.
``CLPHONG_FUZZ_EXAMPLES=100000 python -m pytest tests/test_fuzz.py``; see
docs/fuzzing.md for coverage-guided fuzzing with atheris.
"""

from __future__ import annotations

import atexit
import json
import math
import os
import shutil
import struct
import tempfile
import warnings
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from clphong.core.errors import ClphongError, GBufferError, SceneError
from clphong.io.gbuffer import GBuffer, read_gbuffer, write_gbuffer
from clphong.model.scene import SceneWarning, load_scene, parse_scene

#: Examples per fuzzed target per run (split over the target's tests below).
EXAMPLES = int(os.environ.get("CLPHONG_FUZZ_EXAMPLES", "1000"))


def _settings(share: float):
    return settings(max_examples=max(1, int(math.ceil(EXAMPLES * share))), deadline=None,
                    database=None, print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


@pytest.fixture(scope="module", autouse=True)
def _small_memory_limit():
    """A mutated header may claim a huge image: the reader must refuse it, quickly."""
    old = os.environ.get("CLPHONG_MAX_MEMORY")
    os.environ["CLPHONG_MAX_MEMORY"] = "64M"
    yield
    shutil.rmtree(_DIR, ignore_errors=True)
    if old is None:
        del os.environ["CLPHONG_MAX_MEMORY"]
    else:
        os.environ["CLPHONG_MAX_MEMORY"] = old


# In memory where there is a /dev/shm: thousands of small files are written.
_DIR = Path(tempfile.mkdtemp(prefix="clphong-fuzz-",
                             dir="/dev/shm" if os.path.isdir("/dev/shm") else None))
atexit.register(shutil.rmtree, _DIR, True)      # also when imported without running the tests


def _seed_files() -> dict[str, bytes]:
    """Small valid G-buffers in several layouts: the seeds that get mutated."""
    rng = np.random.default_rng(0)
    h, w = 3, 4
    P, N, A = (rng.normal(size=(h, w, 3)).astype(np.float32) for _ in range(3))
    cov = (rng.uniform(size=(h, w)) > 0.3).astype(np.float32)
    seeds = {}
    for name, kw in {
        "generic-scanline-float": dict(),
        "blender-tiled-half": dict(convention="blender", pixel_type="half", tiled=True, coverage=cov),
        "arnold-maps-none": dict(convention="arnold", compression="none",
                                 maps={"k_s": cov, "h": cov * 10}),
        "mitsuba-piz": dict(convention="mitsuba", compression="piz"),
    }.items():
        path = _DIR / f"{name}.exr"
        write_gbuffer(path, P, N, A, **kw)
        seeds[name] = path.read_bytes()
    # a data window inside a larger display window
    spec = oiio.ImageSpec(w, h, 9, "float")
    spec.channelnames = ("P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z", "albedo.R", "albedo.G", "albedo.B")
    spec.x, spec.y, spec.full_x, spec.full_y, spec.full_width, spec.full_height = 1, 2, 0, 0, 8, 8
    spec.attribute("compression", "rle")
    path = str(_DIR / "window.exr")
    out = oiio.ImageOutput.create(path)
    assert out.open(path, spec) and out.write_image(np.ascontiguousarray(np.concatenate([P, N, A], -1)))
    assert out.close()
    seeds["window-rle"] = Path(path).read_bytes()
    return seeds


SEEDS = _seed_files()


def _check_read(data: bytes, name: str = "fuzz.exr") -> None:
    """read_gbuffer of ``data``: a consistent GBuffer, or a one-line ClphongError naming the file."""
    path = _DIR / name
    path.write_bytes(data)
    try:
        with warnings.catch_warnings(record=True) as caught:   # a warning is one line too
            warnings.simplefilter("always")
            gb = read_gbuffer(path)
    except ClphongError as exc:
        msg = str(exc)
        assert "\n" not in msg and msg, msg
        assert str(path) in msg or isinstance(exc, GBufferError), msg
        return
    for w in caught:
        assert "\n" not in str(w.message), w.message
    assert isinstance(gb, GBuffer)
    h, w = gb.shape
    assert gb.position.dtype == np.float32 and gb.position.shape == (h, w, 3)
    assert gb.normal.shape == gb.albedo.shape == (h, w, 3)


# --------------------------------------------------------------------------- G-buffer reader


_EXTREMES = (0, 1, -1, 7, 65535, 2 ** 16, 2 ** 31 - 1, -2 ** 31)


def _mutate(data: bytes, edits, cut) -> bytes:
    """Apply byte edits: flips, overwrites, inserts, deletes, extreme int32 fields, truncation."""
    out = bytearray(data)
    for op, where, value in edits:
        if not out:
            break
        # edits land in the header (the first ~350 bytes) half of the time
        i = where % (min(len(out), 350) if where % 2 else len(out))
        if op == "flip":
            out[i] ^= 1 << (value % 8)
        elif op == "set":
            out[i] = value % 256
        elif op == "insert":
            out[i:i] = value.to_bytes(4, "little")[: 1 + value % 4]
        elif op == "delete":
            del out[i:i + 1 + value % 16]
        else:     # an int32 field (sizes, windows, offsets) set to an extreme
            out[i:i + 4] = struct.pack("<i", _EXTREMES[value % len(_EXTREMES)])
    if cut is not None:
        out = out[: cut % (len(out) + 1)]
    return bytes(out)


_edits = st.lists(st.tuples(st.sampled_from(["flip", "set", "insert", "delete", "int32"]),
                            st.integers(0, 2 ** 20), st.integers(0, 2 ** 32 - 1)),
                  min_size=1, max_size=8)


@_settings(0.6)
@given(st.sampled_from(sorted(SEEDS)), _edits, st.none() | st.integers(0, 2 ** 20))
def test_fuzz_reader_mutated_exr(seed, edits, cut):
    _check_read(_mutate(SEEDS[seed], edits, cut))


def _attr(name: str, type_: str, payload: bytes) -> bytes:
    return name.encode() + b"\0" + type_.encode() + b"\0" + struct.pack("<i", len(payload)) + payload


@st.composite
def random_header_exr(draw):
    """An EXR header written from scratch with random (often absurd) attribute values."""
    i32 = st.integers(-2 ** 31, 2 ** 31 - 1)
    small = st.integers(-4, 70)
    coord = st.one_of(small, i32)
    names = st.sampled_from(["P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z", "albedo.R", "albedo.G",
                             "albedo.B", "A", "R", "G", "B", "", "k_s", "x" * 300])
    chans = draw(st.lists(st.tuples(names, st.integers(-1, 3)), max_size=12))
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", t, 0, 1, 1) for n, t in chans) + b"\0"
    box = struct.pack("<iiii", draw(coord), draw(coord), draw(coord), draw(coord))
    attrs = [
        _attr("channels", "chlist", chlist),
        _attr("compression", "compression", bytes([draw(st.integers(0, 12))])),
        _attr("dataWindow", "box2i", box),
        _attr("displayWindow", "box2i", struct.pack("<iiii", draw(coord), draw(coord), draw(coord), draw(coord))),
        _attr("lineOrder", "lineOrder", bytes([draw(st.integers(0, 3))])),
        _attr("pixelAspectRatio", "float", struct.pack("<f", draw(st.floats(width=32)))),
        _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0)),
        _attr("screenWindowWidth", "float", struct.pack("<f", 1)),
    ]
    if draw(st.booleans()):
        attrs.append(_attr("tiles", "tiledesc", struct.pack("<iiB", draw(small), draw(small), draw(st.integers(0, 255)))))
    if draw(st.booleans()):
        attrs.append(_attr(draw(st.text(max_size=20)), draw(st.sampled_from(["string", "int", "m44f", "bogus"])),
                           draw(st.binary(max_size=40))))
    attrs = draw(st.permutations(attrs)) if draw(st.booleans()) else attrs
    keep = draw(st.integers(0, len(attrs)))
    flags = draw(st.sampled_from([2, 2 | 0x200, 2 | 0x800, 2 | 0x1000, 2 | 0x400, 1, 3]))
    header = b"\x76\x2f\x31\x01" + struct.pack("<I", flags) + b"".join(attrs[:keep]) + b"\0"
    table = b"".join(struct.pack("<Q", draw(st.integers(0, 2 ** 64 - 1))) for _ in range(draw(st.integers(0, 6))))
    return header + table + draw(st.binary(max_size=200))


@_settings(0.4)
@given(random_header_exr())
def test_fuzz_reader_random_headers(data):
    _check_read(data)


# --------------------------------------------------------------------------- scene parser

_SCENE_KEYS = ["camera", "material", "render", "light", "type", "position", "direction", "model",
               "k_a", "k_d", "k_s", "h", "specular_color", "background", "color", "intensity",
               "attenuation", "up", "perspective", "orthographic", "phong", "blinn-phong", "point",
               "directional", "ambient"]

_NUMBERS = (0, 1, -1, 2, 0.0, -0.0, 0.5, -3.25, 1e-300, 5e-324, 1.7976931348623157e308, 3.4e38,
            1e39, math.nan, math.inf, -math.inf, 2 ** 63 - 1, -2 ** 63, 32.0, 1e16)
_STRINGS = tuple(_SCENE_KEYS) + ("", " ", "é", "\n", "\t", "\x7f", "\u2028", "a.b", '"', "0.5",
                                 "nan", "[[light]]")


class _Ints:
    """Reads a list of drawn integers as a little program that builds a TOML value.

    Building from a flat list of integers keeps hypothesis fast (one draw per
    integer, where nested strategies cost a draw per node and per decision)
    and still shrinks well: fewer and smaller integers give simpler values.
    """

    def __init__(self, ints):
        self.ints = list(ints)
        self.i = 0

    def next(self, n: int) -> int:
        if self.i >= len(self.ints):
            return 0
        self.i += 1
        return self.ints[self.i - 1] % n

    def key(self) -> str:
        k = self.next(len(_STRINGS) + 3)
        if k < len(_STRINGS):
            return _STRINGS[k]
        return "".join(chr(32 + self.next(0x2FF)) for _ in range(self.next(6)))

    def value(self, depth: int = 0):
        op = self.next(10 if depth < 3 else 6)
        if op <= 1:
            return _NUMBERS[self.next(len(_NUMBERS))]
        if op == 2:
            return self.next(2 ** 31) / (1 + self.next(1000)) - 1000.0
        if op == 3:
            return bool(self.next(2))
        if op in (4, 5):
            return self.key()
        if op in (6, 7):
            return [self.value(depth + 1) for _ in range(self.next(5))]
        return {self.key(): self.value(depth + 1) for _ in range(self.next(5))}


_ints = st.lists(st.integers(0, 2 ** 31 - 1), max_size=40)
_keys = _ints.map(lambda xs: _Ints(xs).key())
_values = _ints.map(lambda xs: _Ints(xs).value())
_documents = _ints.map(lambda xs: _Ints([8] + xs).value(depth=0)).filter(lambda v: isinstance(v, dict))


def _toml_str(s: str) -> str:
    body = json.dumps(s, ensure_ascii=False)[1:-1]
    return '"' + body.replace("\x7f", "\\u007f") + '"'


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{_toml_str(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"


def _toml_doc(d: dict) -> str:
    return "".join(f"{_toml_str(k)} = {_toml_value(v)}\n" for k, v in d.items())


VALID = {
    "camera": {"type": "perspective", "position": [0.0, 2.0, 6.0]},
    "material": {"model": "phong", "k_a": 0.1, "k_d": 0.7, "k_s": 0.2, "h": 32.0},
    "render": {"background": [0.0, 0.0, 0.0]},
    "light": [
        {"type": "point", "position": [3.0, 5.0, 4.0], "color": [1, 0.9, 0.8], "intensity": 5.0,
         "attenuation": [1.0, 0.0, 0.02]},
        {"type": "directional", "direction": [-1.0, -1.5, -1.0], "intensity": 2.0},
        {"type": "ambient", "intensity": 1.0},
    ],
}


@st.composite
def scene_like(draw):
    """The valid scene with a few values replaced, deleted or added at random paths."""
    doc = json.loads(json.dumps(VALID))
    for _ in range(draw(st.integers(1, 4))):
        node = doc
        while True:
            keys = list(node) if isinstance(node, dict) else list(range(len(node)))
            if not keys:
                break
            k = draw(st.sampled_from(keys))
            child = node[k]
            if isinstance(child, (dict, list)) and child and draw(st.booleans()):
                node = child
                continue
            op = draw(st.sampled_from(["replace", "delete", "add"]))
            if op == "replace":
                node[k] = draw(_values)
            elif op == "delete":
                del node[k]
            elif isinstance(node, dict):
                node[draw(_keys)] = draw(_values)
            else:
                node.append(draw(_values))
            break
    return doc


def _check_scene(text: str | bytes, name="fuzz.toml") -> None:
    path = _DIR / name
    if isinstance(text, str):
        path.write_text(text, encoding="utf-8")
    else:
        path.write_bytes(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        try:
            load_scene(path)
        except ClphongError as exc:
            msg = str(exc)
            assert isinstance(exc, SceneError), (type(exc), msg)
            assert msg.startswith(str(path)) and "\n" not in msg, msg


@_settings(0.35)
@given(scene_like())
def test_fuzz_scene_values(doc):
    _check_scene(_toml_doc(doc))
    # the same data through the API, without TOML
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        try:
            parse_scene(doc, "api.toml")
        except SceneError as exc:
            assert str(exc).startswith("api.toml") and "\n" not in str(exc)


@_settings(0.3)
@given(_documents)
def test_fuzz_scene_random_documents(doc):
    _check_scene(_toml_doc(doc))


_VALID_TEXT = _toml_doc({k: v for k, v in VALID.items() if k != "light"}) + "".join(
    "[[light]]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in lt.items()) for lt in VALID["light"])


@_settings(0.35)
@given(st.data())
def test_fuzz_scene_text_mutations(data):
    text = bytearray(_VALID_TEXT.encode())
    for _ in range(data.draw(st.integers(1, 6))):
        i = data.draw(st.integers(0, len(text)))
        op = data.draw(st.sampled_from(["set", "insert", "delete", "snippet"]))
        if op == "set" and i < len(text):
            text[i] = data.draw(st.integers(0, 255))
        elif op == "insert":
            text[i:i] = data.draw(st.binary(min_size=1, max_size=8))
        elif op == "delete":
            del text[i:i + data.draw(st.integers(1, 20))]
        else:
            snippet = data.draw(st.sampled_from(
                ["[", "]", "{", "}", "=", "\n[[light]]\n", "nan", "-inf", "1e999", '"', "'''",
                 "\\u0000", "[camera]\n", "0x7fffffffffffffffffff", "\ttype = 'point'\n", "#", "."]))
            text[i:i] = snippet.encode()
    _check_scene(bytes(text))


# --------------------------------------------------------------------------- issue 15: shipped samples, flipped


#: The shipped samples and their scenes (gbuffers/): what a user renders first.
_SAMPLES = Path(__file__).resolve().parent.parent / "gbuffers"
SHIPPED = {"spheres.exr": "spheres.toml", "ortho.exr": "ortho.toml",
           "blender/cycles-4.5.exr": "blender/spheres.toml",
           "blender/cycles-5.0.exr": "blender/spheres.toml"}
_SHIPPED_BYTES = {name: (_SAMPLES / name).read_bytes() for name in SHIPPED}
_COMPRESSION = b"compression\x00compression\x00\x01\x00\x00\x00"


def _compression_offsets(data: bytes) -> list[int]:
    """Byte offsets of the compression attribute's value, one per part."""
    out, at = [], data.find(_COMPRESSION)
    while at >= 0:
        out.append(at + len(_COMPRESSION))
        at = data.find(_COMPRESSION, at + 1)
    return out


def _all_chlist_type_offsets(data: bytes) -> list[int]:
    """:func:`_chlist_type_offsets` of every part's header (a multi-part file has one each)."""
    out, at = [], 0
    while True:
        found = _chlist_type_offsets(data[at:])
        if not found:
            return out
        out += [at + i for i in found]
        at += found[-1] + 16


def _flip(data: bytes, kind: str, which: int, value: int, every_part: bool) -> bytes:
    """The compression byte of one part (or all) set to ``value`` (0-9 are OpenEXR's:
    5 = PXR24, 6 = B44, ...), or channel ``which``'s pixel-type byte (0 UINT, 1 HALF,
    2 FLOAT, others invalid)."""
    raw = bytearray(data)
    offsets = _compression_offsets(data) if kind == "compression" else _all_chlist_type_offsets(data)
    assert offsets, kind
    for off in (offsets if every_part and kind == "compression" else [offsets[which % len(offsets)]]):
        raw[off] = value
    return bytes(raw)


def _render_cli(argv) -> tuple[int, str]:
    """``clphong`` in-process: (exit status, stderr). Any exception escapes (a traceback)."""
    import contextlib
    import io

    from clphong.console.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, err.getvalue()


@_settings(0.015)
@given(st.sampled_from(sorted(SHIPPED)),
       st.tuples(st.sampled_from(["compression", "pixel-type"]), st.integers(0, 63),
                 st.sampled_from(range(10)) | st.integers(0, 255), st.booleans()),
       st.sampled_from(["background", "error"]))
@example("spheres.exr", ("compression", 0, 5, True), "background")       # the finding: ZIP as PXR24
@example("ortho.exr", ("compression", 0, 5, True), "background")         # NaN beside a shininess of -1e6
@example("blender/cycles-5.0.exr", ("compression", 0, 5, True), "error")
@example("spheres.exr", ("pixel-type", 4, 1, False), "background")       # P.X FLOAT -> HALF
@example("spheres.exr", ("pixel-type", 4, 0, False), "background")       # P.X FLOAT -> UINT
def test_fuzz_shipped_samples_with_a_flipped_compression_or_pixel_type(sample, edit, policy):
    """A shipped sample (gbuffers/) with its compression byte (one part or all) or one
    channel's pixel type changed, rendered through the CLI under ``--nonfinite``
    background or error: no traceback; exit 0, or 1 with one ``clphong: error:`` line
    naming the file and no output; every line one clphong message; under ``error``
    stderr is at most one line; under ``background`` at most two warning lines (the
    NaN/implausible policy's and the negative clamp's: the renderer applies them one
    after the other), and never a NaN or Inf in the output file (R, G, B, A).
    ~0.07 s an example; CLPHONG_FUZZ_EXAMPLES scales the count."""
    path = _DIR / "flipped.exr"
    out = _DIR / "flipped-out.exr"
    path.write_bytes(_flip(_SHIPPED_BYTES[sample], *edit))
    out.unlink(missing_ok=True)
    rc, err = _render_cli(["render", _SAMPLES / SHIPPED[sample], path, "-o", out, "--nonfinite", policy])
    lines = err.splitlines()
    assert "Traceback" not in err, err
    assert all(ln.startswith(("clphong: warning: ", "clphong: error: ")) for ln in lines), err
    errors = [ln for ln in lines if ln.startswith("clphong: error: ")]
    assert rc in (0, 1), (rc, err)
    if rc == 1:
        assert len(errors) == 1 and lines[-1] == errors[0] and str(path) in errors[0], err
        assert not out.exists()
    else:
        assert not errors and out.exists(), err
        pix = oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)
        assert np.all(np.isfinite(pix)), f"{int((~np.isfinite(pix)).sum())} non-finite output value(s)"
    assert len(lines) <= (1 if policy == "error" else 2), err


# --------------------------------------------------------------------------- regressions found by fuzzing


def test_regression_exr_header_with_non_utf8_bytes(tmp_path):
    """A flipped byte in an attribute name: OpenImageIO's error text is not UTF-8 and
    the Python binding raised UnicodeDecodeError while building the message."""
    data = bytearray(SEEDS["generic-scanline-float"])
    i = data.index(b"channels")
    data[i] = 0x83
    path = tmp_path / "bad-name.exr"
    path.write_bytes(bytes(data))
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(path)
    assert str(exc.value).startswith(f"{path}: ") and "\n" not in str(exc.value)


@pytest.mark.parametrize("opener,closer", [("[", "]"), ("{a=", "}")], ids=["arrays", "inline-tables"])
def test_regression_deeply_nested_toml(tmp_path, opener, closer):
    """tomllib parses nesting recursively: ~300 levels raised RecursionError."""
    path = tmp_path / "deep.toml"
    path.write_text("x = " + opener * 5000 + "1" * (opener == "{a=") + closer * 5000 + "\n")
    with pytest.raises(SceneError, match="nested too deeply"):
        load_scene(path)


def test_regression_channel_name_with_a_newline(tmp_path):
    """A channel renamed to "\\nP.G" by a byte edit: the message listing the channels
    spanned two lines. Names with control characters are now shown escaped."""
    data = SEEDS["generic-scanline-float"]
    i = data.index(b"P.Y\0")
    path = tmp_path / "newline.exr"
    path.write_bytes(data[:i] + b"\nPY" + data[i + 3:])             # same length: "P.Y" -> "\nPY"
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: no position channels found") and "\n" not in msg
    assert "'\\nPY'" in msg


def test_regression_absurd_tile_size(tmp_path, monkeypatch):
    """A 4x3 image whose header claims 16384x16384 tiles (atheris found 10560x16384):
    OpenImageIO allocates whole tiles, 8.6 GB of RSS for that input. Now the tile
    is part of the memory estimate and the read is refused before it starts."""
    P = np.ones((3, 4, 3), np.float32)
    write_gbuffer(tmp_path / "t.exr", P, P, P, tiled=True)
    data = bytearray((tmp_path / "t.exr").read_bytes())
    i = data.index(b"tiles\0tiledesc\0") + len(b"tiles\0tiledesc\0") + 4      # after the size field
    assert struct.unpack("<II", data[i:i + 8]) == (64, 64)
    data[i:i + 8] = struct.pack("<II", 16384, 16384)
    path = tmp_path / "tiles.exr"
    path.write_bytes(bytes(data))
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "1G")
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: reading 9 channels of a 4x3 image (tiles of 16384x16384) needs about")


def test_regression_truncated_file_with_a_newline_in_a_channel_name(tmp_path):
    """atheris: the "reading channels ... failed" message listed the run's raw names."""
    names = ("N.X", "N.Y", "N.Z", "N.Z\nnote", "P.X", "P.Y", "P.Z", "albedo.R", "albedo.G", "albedo.B")
    spec = oiio.ImageSpec(4, 3, len(names), "float")
    spec.channelnames = names
    spec.attribute("compression", "none")
    full = str(tmp_path / "full.exr")
    out = oiio.ImageOutput.create(full)
    assert out.open(full, spec) and out.write_image(np.ones((3, 4, len(names)), np.float32)) and out.close()
    data = Path(full).read_bytes()
    path = tmp_path / "cut.exr"
    path.write_bytes(data[: len(data) - 60])
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: reading channels ") and "'N.Z\\nnote'" in msg and "\n" not in msg


# --------------------------------------------------------------------------- issue 15: targeted edits


def _chlist_type_offsets(data: bytes) -> list[int]:
    """Byte offsets of each channel's pixel-type int32 in the header's chlist."""
    at = data.find(b"channels\x00chlist\x00")
    if at < 0:
        return []
    i = at + len(b"channels\x00chlist\x00") + 4          # after the attribute's size
    out = []
    while data[i] != 0:
        i = data.index(b"\x00", i) + 1                   # the channel's name
        out.append(i)
        i += 16                                          # type, pLinear+reserved, xs, ys
    return out


@_settings(0.3)
@given(st.sampled_from(sorted(SEEDS)), st.data())
def test_fuzz_reader_window_and_pixel_type_edits(seed, data):
    """One flipped byte in 'displayWindow' (OpenEXR then falls back to a 64x64 window)
    or a channel's pixel type changed (FLOAT -> UINT or HALF): a G-buffer that reads
    shades to finite values; otherwise one line naming the file."""
    raw = bytearray(SEEDS[seed])
    if data.draw(st.booleans(), label="window"):
        at = raw.find(b"displayWindow")
        if at >= 0:
            k = data.draw(st.integers(0, len("displayWindow") - 1), label="byte")
            raw[at + k] ^= data.draw(st.integers(1, 255), label="xor")
    else:
        offsets = _chlist_type_offsets(bytes(raw))
        if offsets:
            off = data.draw(st.sampled_from(offsets), label="channel")
            raw[off:off + 4] = struct.pack("<i", data.draw(st.sampled_from([0, 1, 2, 3, -1]), label="type"))
    _check_read(bytes(raw), "edit.exr")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gb = read_gbuffer(_DIR / "edit.exr")
    except ClphongError:
        return
    _check_finite_render(gb)


def _check_finite_render(gb) -> None:
    from conftest import make_scene, random_lights

    from clphong.device.renderer import Renderer

    scene = make_scene(random_lights(np.random.default_rng(1), 2, 1), model="blinn-phong", h=8.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            image = Renderer(scene).render(gb).image
        except ClphongError as exc:
            assert "\n" not in str(exc)
            return
    assert np.all(np.isfinite(image))


@_settings(0.2)
@given(st.lists(st.sampled_from([-1e6, -2.0, -1.0, -1e-38, 0.0, 1e-38, 0.5, 1e4, 6e4, 1e38, 3.4e38]),
                min_size=12, max_size=12),
       st.sampled_from(["k_d", "k_s", "h", "specular_color", "albedo"]),
       st.sampled_from(["float", "half"]))
def test_fuzz_maps_with_negative_and_huge_values(values, which, pixel_type):
    """Maps and albedo anywhere in range, written and read back as EXR (half clamps
    beyond 65504 with a warning): they read, and shade to finite values."""
    rng = np.random.default_rng(0)
    h, w = 3, 4
    P, N, A = (rng.normal(size=(h, w, 3)).astype(np.float32) for _ in range(3))
    plane = np.array(values, np.float32).reshape(h, w)
    maps = {}
    if which == "albedo":
        A = np.repeat(plane[..., None], 3, axis=-1)
    elif which == "specular_color":
        maps[which] = np.repeat(plane[..., None], 3, axis=-1)
    else:
        maps[which] = plane
    path = _DIR / "maps.exr"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        write_gbuffer(path, P, N, A, maps=maps, pixel_type=pixel_type)
    _check_read(path.read_bytes(), "maps.exr")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gb = read_gbuffer(_DIR / "maps.exr")
    _check_finite_render(gb)
