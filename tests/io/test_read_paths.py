"""The fast read and check paths of clphong.io give what the plain ones give:
a G-buffer read in bands of rows equals one read whole (load + stack), bit for bit;
the structure walk of a scanline EXR passes every whole file and refuses every cut
one; the float32 sum in all_finite and the bit test in background_mask decide as before."""

from __future__ import annotations

import os

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import GBUFFERS

from clphong.io import atomic
from clphong.io import gbuffer as gbmod
from clphong.io.gbuffer import GBuffer, read_gbuffer, write_gbuffer
from clphong.io.nonfinite import all_finite, nonfinite_counts


def _frame(h, w, seed=0):
    rng = np.random.default_rng(seed)
    P = (rng.standard_normal((h, w, 3)) * 10.0 ** rng.integers(-3, 3, (h, w, 3))).astype(np.float32)
    N = rng.standard_normal((h, w, 3)).astype(np.float32)
    N[rng.uniform(size=(h, w)) < 0.1] = 0.0                       # background
    A = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    cov = rng.choice(np.float32([0, 0.25, 1, 1, 1]), (h, w))
    maps = {"k_d": rng.uniform(0, 1, (h, w)).astype(np.float32),
            "h": rng.uniform(1, 200, (h, w)).astype(np.float32),
            "specular_color": rng.uniform(0, 1, (h, w, 3)).astype(np.float32)}
    return P, N, A, cov, maps


def _whole(monkeypatch, *args, **kwargs):
    """read_gbuffer with the band path off: every channel run read whole, then stacked."""
    with monkeypatch.context() as m:
        m.setattr(gbmod._ExrFile, "_bandable", lambda self, groups, runs: False)
        return read_gbuffer(*args, **kwargs)


def _banded_count(monkeypatch):
    calls = []
    real = gbmod._ExrFile._bandable

    def spy(self, groups, runs):
        ok = real(self, groups, runs)
        calls.append(ok)
        return ok

    monkeypatch.setattr(gbmod._ExrFile, "_bandable", spy)
    return calls


def _same_bits(a: GBuffer, b: GBuffer):
    for name in ("position", "normal", "albedo", "coverage"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype == np.float32 and x.shape == y.shape and x.flags.c_contiguous
            assert x.tobytes() == y.tobytes(), name
    assert a.maps.keys() == b.maps.keys()
    for k in a.maps:
        assert a.maps[k].tobytes() == b.maps[k].tobytes() and a.maps[k].shape == b.maps[k].shape, k
    assert (a.convention, a.sources, a.attributes) == (b.convention, b.sources, b.attributes)


@pytest.mark.parametrize("convention", ["generic", "blender", "arnold", "mitsuba"])
@pytest.mark.parametrize("compression,pixel_type,h", [
    ("zip", "float", 130), ("zips", "half", 67), ("piz", "float", 1), ("dwab", "half", 300),
    ("none", "float", 64)])
def test_banded_read_is_the_whole_read(tmp_path, monkeypatch, convention, compression, pixel_type, h):
    P, N, A, cov, maps = _frame(h, 23)
    path = tmp_path / "g.exr"
    write_gbuffer(path, P, N, A, coverage=cov, maps=maps, convention=convention,
                  compression=compression, pixel_type=pixel_type)
    calls = _banded_count(monkeypatch)
    banded = read_gbuffer(path)
    assert calls == [True]                                        # the band path ran
    _same_bits(banded, _whole(monkeypatch, path))


def test_banded_read_of_separate_files_and_multipart(tmp_path, monkeypatch):
    P, N, A, _, _ = _frame(70, 9, seed=1)
    files = {}
    for key, arr in (("position", P), ("normal", N), ("albedo", A)):
        files[key] = tmp_path / f"{key}.exr"
        atomic.write_exr(files[key], arr)                         # plain R, G, B
    calls = _banded_count(monkeypatch)
    _same_bits(read_gbuffer(**files), _whole(monkeypatch, **files))
    assert calls == [True, True, True]
    fixture = GBUFFERS / "blender" / "cycles-5.0.exr"           # multi-part (Blender 5)
    _same_bits(read_gbuffer(fixture), _whole(monkeypatch, fixture))


def test_other_layouts_are_read_whole(tmp_path, monkeypatch):
    """Reversed or gapped channels, a tiled file and a data window smaller than the
    display window take the plain path, with the same values as before."""
    P, N, A, cov, maps = _frame(40, 30, seed=2)
    path = tmp_path / "g.exr"
    write_gbuffer(path, P, N, A, coverage=cov, maps=maps)
    calls = _banded_count(monkeypatch)
    gb = read_gbuffer(path, channels={"position": "P.Z,P.Y,P.X", "normal": "N.X,N.Z,N.Y"})
    assert calls == [False]
    assert np.array_equal(gb.position, P[..., ::-1]) and np.array_equal(gb.normal, N[..., [0, 2, 1]])
    # the same channel for two maps: two arrays, neither a view of the other
    gb = read_gbuffer(path, channels={"k_d": "k_d", "k_s": "k_d"})
    assert not np.shares_memory(gb.maps["k_d"], gb.maps["k_s"])
    assert np.array_equal(gb.maps["k_d"], gb.maps["k_s"])
    tiled = tmp_path / "t.exr"
    write_gbuffer(tiled, P, N, A, coverage=cov, tiled=True)
    calls.clear()
    _same_bits(read_gbuffer(tiled), _whole(monkeypatch, tiled))
    assert calls == [False]
    # a data window inside the display window: placed in it, zeros outside
    names = ["A", "N.X", "N.Y", "N.Z", "P.X", "P.Y", "P.Z", "albedo.R", "albedo.G", "albedo.B"]
    data = np.concatenate([cov[..., None], N, P, A], -1)[5:25, 3:20]
    spec = oiio.ImageSpec(17, 20, len(names), oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.x, spec.y, spec.full_x, spec.full_y, spec.full_width, spec.full_height = 3, 5, 0, 0, 30, 40
    cropped = str(tmp_path / "crop.exr")
    out = oiio.ImageOutput.create(cropped)
    assert out.open(cropped, spec) and out.write_image(np.ascontiguousarray(data)) and out.close()
    calls.clear()
    gb = read_gbuffer(cropped)
    assert calls == [False] and gb.shape == (40, 30)
    assert np.array_equal(gb.position[5:25, 3:20], P[5:25, 3:20]) and not gb.position[:5].any()


def test_banded_read_failure_is_one_line_naming_the_channels(tmp_path):
    P, N, A, cov, _ = _frame(200, 31, seed=3)
    path = tmp_path / "g.exr"
    write_gbuffer(path, P, N, A, coverage=cov)
    data = path.read_bytes()
    cut = tmp_path / "cut.exr"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(gbmod.GBufferError) as exc:
        read_gbuffer(cut)
    msg = str(exc.value)
    assert msg.startswith(f"{cut}: reading channels A,N.X,N.Y,N.Z,P.X") and "\n" not in msg


# --------------------------------------------------------------------------- EXR structure


def _write(path, h, w, c, compression, pixel_type="half", y=0, seed=0):
    spec = oiio.ImageSpec(w, h, c, oiio.TypeDesc(pixel_type))
    spec.attribute("compression", compression)
    spec.y = y
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(np.random.default_rng(seed).random((h, w, c)).astype(np.float32))
    assert out.close()


@pytest.mark.parametrize("compression", ["none", "rle", "zips", "zip", "piz", "pxr24", "b44",
                                         "b44a", "dwaa", "dwab"])
@pytest.mark.parametrize("h,y", [(1, 0), (17, 0), (33, -5), (300, 7)])
def test_exr_structure_walk_passes_whole_files_without_decoding(tmp_path, monkeypatch, compression, h, y):
    path = tmp_path / "w.exr"
    _write(path, h, 13, 4, compression, "float" if h == 17 else "half", y=y)

    def no_decode(name):
        raise AssertionError("a scanline EXR was decoded")

    monkeypatch.setattr(atomic, "_read_back", no_decode)
    assert atomic._exr_layout_problem(str(path)) is None
    atomic.check_image_written(str(path))


@pytest.mark.parametrize("compression", ["zip", "none", "piz"])
def test_exr_structure_walk_refuses_every_cut_and_a_missing_offset_table(tmp_path, compression):
    whole = tmp_path / "w.exr"
    _write(whole, 40, 50, 3, compression)
    data = whole.read_bytes()
    bad = tmp_path / "b.exr"
    for n in range(len(data)):
        bad.write_bytes(data[:n])
        assert atomic._exr_layout_problem(str(bad)) not in (None, "?"), n
    # the offset table never written (zeros, as OpenEXR reserves it), or data after the end
    chunks = {"zip": 3, "none": 40, "piz": 2}[compression]         # 40 rows
    offsets_at = _table_position(data, chunks)
    zeroed = bytearray(data)
    zeroed[offsets_at:offsets_at + 8 * chunks] = bytes(8 * chunks)
    bad.write_bytes(bytes(zeroed))
    assert "offset" in atomic._exr_layout_problem(str(bad))
    bad.write_bytes(data + b"\0")
    assert atomic._exr_layout_problem(str(bad)) == "data after the last chunk"
    with pytest.raises(atomic.OutputError, match=r"^out\.exr: the write failed \(disk full\?\)"):
        atomic.check_image_written(str(bad), "out.exr")


def _table_position(data: bytes, chunks: int) -> int:
    """Where the offset table starts: the first chunk's offset is just past it."""
    for at in range(8, len(data) - 8):
        if data[at - 1] == 0 and int.from_bytes(data[at:at + 8], "little") == at + 8 * chunks:
            return at
    raise AssertionError("no offset table found")


def test_tiled_and_unknown_exrs_are_decoded(tmp_path, monkeypatch):
    path = tmp_path / "t.exr"
    atomic.write_exr(path, np.ones((70, 90, 3), np.float32), tiled=True)
    assert atomic._exr_layout_problem(str(path)) == "?"
    decoded = []
    real = atomic._read_back
    monkeypatch.setattr(atomic, "_read_back", lambda name: decoded.append(name) or real(name))
    atomic.check_image_written(str(path))
    assert decoded == [str(path)]


# --------------------------------------------------------------------------- finite, background


def test_all_finite_decides_as_the_float64_sum():
    a = np.full((64, 64, 3), 3e38, np.float32)          # finite, but its float32 sum overflows
    assert all_finite(a)
    for bad in (np.nan, np.inf, -np.inf):
        b = a.copy()
        b[7, 9, 2] = bad
        assert not all_finite(b)
    assert all_finite(np.zeros(0, np.float32)) and all_finite(np.arange(5))
    assert not all_finite(np.array([np.inf, -np.inf], np.float16))


def test_nonfinite_counts_and_background_mask_as_before():
    rng = np.random.default_rng(5)
    h, w = 20, 30
    N = rng.standard_normal((h, w, 3)).astype(np.float32)
    N[0, :6] = [[0, 0, 0], [-0.0, 0, -0.0], [1e-45, 0, 0], [np.nan, 0, 0], [0, np.inf, 0], [0, 0, -0.0]]
    P = rng.standard_normal((h, w, 3)).astype(np.float32)
    P[3, 4, 1] = np.nan
    cov = np.ones((h, w), np.float32)
    cov[3, 4] = 0                                        # not counted: background
    gb = GBuffer(position=P, normal=N, albedo=np.ones_like(P), coverage=cov)
    x, y, z = N[..., 0], N[..., 1], N[..., 2]
    want = ((x == 0) & (y == 0) & (z == 0)) | ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(z))
    want |= cov == 0
    assert np.array_equal(gb.background_mask(), want)
    assert gb.background_mask()[0, :6].tolist() == [True, True, False, True, True, True]
    assert nonfinite_counts(gb) == {"position": 0, "normal": 2, "albedo": 0}
    for dtype in (np.float16, np.float64):              # the plain comparison
        g = GBuffer(position=P, normal=N.astype(dtype), albedo=P)
        n = N.astype(dtype)
        plain = ((n[..., 0] == 0) & (n[..., 1] == 0) & (n[..., 2] == 0)) | ~np.isfinite(n).all(-1)
        assert np.array_equal(g.background_mask(), plain)


def test_written_files_are_checked_where_they_are(tmp_path):
    """write_exr still refuses nothing whole and leaves one file (the structure walk is
    the check of every scanline EXR clphong writes)."""
    out = tmp_path / "o.exr"
    atomic.write_exr(out, np.ones((37, 41, 4), np.float32), channel_names=("R", "G", "B", "A"))
    assert atomic._exr_layout_problem(str(out)) is None
    assert sorted(os.listdir(tmp_path)) == ["o.exr"]


def test_jpeg_xl_box_walk_passes_whole_files_and_refuses_every_cut(tmp_path, monkeypatch):
    from clphong.deliver.writers import jpegxl_available, write_hdr

    if not jpegxl_available():
        pytest.skip("this OpenImageIO has no JPEG XL writer")
    whole = tmp_path / "w.jxl"
    rgb = np.random.default_rng(4).random((24, 40, 3)).astype(np.float32)
    write_hdr(whole, rgb, alpha=np.linspace(0, 1, 24 * 40, dtype=np.float32).reshape(24, 40))
    data = whole.read_bytes()
    if not data.startswith(atomic._JXL_CONTAINER):
        pytest.skip("this OpenImageIO writes a bare JPEG XL codestream (decoded to check)")
    real = atomic._read_back
    monkeypatch.setattr(atomic, "_read_back", lambda name: pytest.fail("a JPEG XL container was decoded"))
    atomic.check_image_written(str(whole))
    monkeypatch.setattr(atomic, "_read_back", real)
    cut = tmp_path / "c.jxl"
    for n in range(len(data)):
        cut.write_bytes(data[:n])
        with pytest.raises(atomic.OutputError, match=r"^out\.jxl: the write failed \(disk full\?\)"):
            atomic.check_image_written(str(cut), "out.jxl")
