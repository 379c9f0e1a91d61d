"""Tests of clphong.io.gbuffer: reading G-buffers by channel name, in every convention."""

from __future__ import annotations

import warnings

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import GBUFFERS

from clphong.core.errors import GBufferError, InputWarning
from clphong.core.geometry import unit_normal_planes
from clphong.io.atomic import write_exr
from clphong.io.gbuffer import (
    CHANNEL_KEYS,
    GBuffer,
    parse_channel_mapping,
    read_gbuffer,
    write_gbuffer,
)
from clphong.io.nonfinite import (
    LIMITS,
    apply_nonfinite_policy,
    implausible_counts,
    nonfinite_counts,
)

H, W = 5, 7


def _data(seed=0, h=H, w=W):
    rng = np.random.default_rng(seed)
    P = (rng.standard_normal((h, w, 3)) * 10.0 ** rng.integers(-3, 3, (h, w, 3))).astype(np.float32)
    N = rng.standard_normal((h, w, 3)).astype(np.float32)
    A = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    cov = (rng.uniform(size=(h, w)) > 0.3).astype(np.float32)
    maps = {"k_d": rng.uniform(0, 1, (h, w)).astype(np.float32),
            "k_s": rng.uniform(0, 1, (h, w)).astype(np.float32),
            "h": rng.uniform(1, 200, (h, w)).astype(np.float32),
            "specular_color": rng.uniform(0, 1, (h, w, 3)).astype(np.float32)}
    return P, N, A, cov, maps


def _half(x):
    return np.asarray(x, np.float32).astype(np.float16).astype(np.float32)


def _raw(path, planes, *, pixel_type="float", tiled=False, attributes=None, h=None, w=None):
    """Write channels {name: (H, W) array} with OpenImageIO directly, in the given order."""
    names = list(planes)
    data = np.ascontiguousarray(np.stack([np.asarray(planes[n], np.float32) for n in names], -1))
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], len(names), oiio.TypeDesc(pixel_type))
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    if tiled:
        spec.tile_width = spec.tile_height = 64
    for k, v in (attributes or {}).items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(data), out.geterror()
    assert out.close()
    return path


def _vec(prefix, arr, comps="XYZ"):
    return {f"{prefix}.{c}" if prefix else c: arr[..., i] for i, c in enumerate(comps)}


def _assert_same(gb, P, N, A, cov=None, maps=None, conv=lambda x: np.asarray(x, np.float32)):
    for got, want in ((gb.position, P), (gb.normal, N), (gb.albedo, A)):
        assert got.dtype == np.float32 and got.flags.c_contiguous and got.shape == (H, W, 3)
        assert np.array_equal(got, conv(want))
    if cov is None:
        assert gb.coverage is None
    else:
        assert gb.coverage.dtype == np.float32 and np.array_equal(gb.coverage, conv(cov))
    assert set(gb.maps) == set(maps or {})
    for k, v in (maps or {}).items():
        assert gb.maps[k].dtype == np.float32 and np.array_equal(gb.maps[k], conv(v)), k
    assert gb.shape == (H, W)


# --------------------------------------------------------------------------- conventions


@pytest.mark.parametrize("tiled", [False, True], ids=["scanline", "tiled"])
@pytest.mark.parametrize("pixel_type", ["float", "half"])
@pytest.mark.parametrize("convention,detected", [
    ("generic", "generic"), ("blender", "blender"), ("blender-new", "blender"),
    ("arnold", "arnold"), ("mitsuba", "mitsuba")])
def test_roundtrip_every_convention(tmp_path, convention, detected, pixel_type, tiled):
    P, N, A, cov, maps = _data()
    path = tmp_path / "gb.exr"
    write_gbuffer(path, P, N, A, coverage=cov, maps=maps, convention=convention,
                  pixel_type=pixel_type, tiled=tiled)
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    inp.close()
    assert spec.format == oiio.TypeDesc(pixel_type)
    assert spec.tile_width == (64 if tiled else 0)
    gb = read_gbuffer(path)
    assert gb.convention == detected
    _assert_same(gb, P, N, A, cov, maps, conv=_half if pixel_type == "half" else np.asarray)
    assert all(gb.sources[k].startswith(f"{path}: ") for k in ("position", "normal", "albedo", "coverage"))


@pytest.mark.parametrize("convention,expected", [
    ("generic", ["P.X", "N.X", "albedo.R", "A", "k_d", "k_s", "shininess", "specular_color.R"]),
    ("blender", ["ViewLayer.Position.X", "ViewLayer.Normal.X", "ViewLayer.DiffCol.R",
                 "ViewLayer.Combined.A", "ViewLayer.k_s.X", "ViewLayer.shininess.X"]),
    ("blender-new", ["ViewLayer.Diffuse Color.R", "ViewLayer.Combined.R"]),
    ("arnold", ["P.R", "N.B", "diffuse_albedo.G", "A"]),
    ("mitsuba", ["pos.X", "sh_normal.Z", "albedo.R", "R", "G", "B", "A"]),
])
def test_write_gbuffer_channel_names(tmp_path, convention, expected):
    P, N, A, cov, maps = _data()
    write_gbuffer(tmp_path / "g.exr", P, N, A, coverage=cov, maps=maps, convention=convention)
    inp = oiio.ImageInput.open(str(tmp_path / "g.exr"))
    names = inp.spec().channelnames
    inp.close()
    assert set(expected) <= set(names)


def test_blender_old_and_new_names_detected(tmp_path):
    P, N, A, _, _ = _data(1)
    for pas, name in (("DiffCol", "old.exr"), ("Diffuse Color", "new.exr")):
        _raw(tmp_path / name, {**_vec("ViewLayer.Combined", np.ones((H, W, 3)), "RGB"),
                               **_vec("ViewLayer.Position", P), **_vec("ViewLayer.Normal", N),
                               **_vec(f"ViewLayer.{pas}", A, "RGB")})
        with pytest.warns(InputWarning, match="no coverage channel"):   # Combined has no .A here
            gb = read_gbuffer(tmp_path / name)
        assert gb.convention == "blender"
        _assert_same(gb, P, N, A)
        assert gb.sources["albedo"] == (f"{tmp_path / name}: ViewLayer.{pas}.R,ViewLayer.{pas}.G,"
                                        f"ViewLayer.{pas}.B (view layer 'ViewLayer')")


def test_blender_non_default_view_layer_and_alpha_pass(tmp_path):
    P, N, A, cov, _ = _data(2)
    path = _raw(tmp_path / "rl.exr", {**_vec("RenderLayer.Position", P), **_vec("RenderLayer.Normal", N),
                                      **_vec("RenderLayer.DiffCol", A, "RGB"), "RenderLayer.Alpha.A": cov})
    gb = read_gbuffer(path)
    assert gb.convention == "blender"
    _assert_same(gb, P, N, A, cov)
    assert "view layer 'RenderLayer'" in gb.sources["position"]
    assert gb.sources["coverage"].startswith(f"{path}: RenderLayer.Alpha.A")


def test_blender_view_layer_with_dots_and_no_view_layer(tmp_path):
    P, N, A, cov, maps = _data(3)
    write_gbuffer(tmp_path / "dots.exr", P, N, A, coverage=cov, maps=maps, convention="blender",
                  layer="Layer.v2")
    gb = read_gbuffer(tmp_path / "dots.exr")
    _assert_same(gb, P, N, A, cov, maps)
    assert "view layer 'Layer.v2'" in gb.sources["normal"]
    write_gbuffer(tmp_path / "bare.exr", P, N, A, convention="blender-new", layer="")
    with pytest.warns(InputWarning, match="no coverage channel"):
        gb = read_gbuffer(tmp_path / "bare.exr")
    assert gb.convention == "blender" and gb.sources["albedo"].endswith("Diffuse Color.B")
    _assert_same(gb, P, N, A)


def test_blender_several_view_layers_first_complete_wins(tmp_path):
    P, N, A, cov, _ = _data(4)
    P2, N2, A2, _, _ = _data(5)
    planes = {**_vec("Back.Position", P2), **_vec("Back.Normal", N2),          # no DiffCol: incomplete
              **_vec("Front.Position", P), **_vec("Front.Normal", N), **_vec("Front.DiffCol", A, "RGB"),
              "Front.Combined.A": cov,
              **_vec("Zeta.Position", P2), **_vec("Zeta.Normal", N2), **_vec("Zeta.DiffCol", A2, "RGB")}
    gb = read_gbuffer(_raw(tmp_path / "layers.exr", planes))
    _assert_same(gb, P, N, A, cov)
    assert all("view layer 'Front'" in gb.sources[k] for k in ("position", "normal", "albedo", "coverage"))


def test_arnold_variants(tmp_path):
    P, N, A, cov, _ = _data(6)
    # P.R/G/B and albedo.* -> arnold
    gb = read_gbuffer(_raw(tmp_path / "a1.exr", {**_vec("P", P, "RGB"), **_vec("N", N, "RGB"),
                                                  **_vec("albedo", A, "RGB"), "A": cov}))
    assert gb.convention == "arnold"
    _assert_same(gb, P, N, A, cov)
    # P.X/Y/Z with diffuse_albedo -> arnold
    gb = read_gbuffer(_raw(tmp_path / "a2.exr", {**_vec("P", P), **_vec("N", N),
                                                  **_vec("diffuse_albedo", A, "RGB")}))
    assert gb.convention == "arnold" and "diffuse_albedo.R" in gb.sources["albedo"]
    _assert_same(gb, P, N, A)
    # arnold/* header attributes -> arnold
    gb = read_gbuffer(_raw(tmp_path / "a3.exr", {**_vec("P", P), **_vec("N", N), **_vec("albedo", A, "RGB")},
                           attributes={"arnold/version": "7.3"}))
    assert gb.convention == "arnold"


def test_generic_lowercase_components_and_any_channel_order(tmp_path):
    P, N, A, cov, maps = _data(7)
    planes = {"k_s": maps["k_s"], **_vec("albedo", A, "rgb"), "zzz.extra": np.ones((H, W)),
              **_vec("N", N, "xyz"), "A": cov, **_vec("P", P, "xyz"), "shininess": maps["h"]}
    planes = dict(reversed(list(planes.items())))
    gb = read_gbuffer(_raw(tmp_path / "lc.exr", planes))
    assert gb.convention == "generic"
    _assert_same(gb, P, N, A, cov, {"k_s": maps["k_s"], "h": maps["h"]})
    assert gb.sources["position"].endswith("P.x,P.y,P.z")


def test_many_channels_with_gaps(tmp_path):
    P, N, A, _, _ = _data(8)
    rng = np.random.default_rng(0)
    planes = {}
    for i in range(20):
        planes[f"aaa{i:02d}.V"] = rng.uniform(size=(H, W))
    planes.update(_vec("P", P))
    for i in range(20):
        planes[f"mmm{i:02d}.V"] = rng.uniform(size=(H, W))
    planes.update({**_vec("N", N), **_vec("albedo", A, "RGB")})
    _assert_same(read_gbuffer(_raw(tmp_path / "many.exr", planes)), P, N, A)


def test_mitsuba_with_image_and_rgb_position(tmp_path):
    P, N, A, cov, _ = _data(9)
    planes = {**_vec("", A * cov[..., None], "RGB"), "A": cov, **_vec("albedo", A, "RGB"),
              **_vec("pos", P, "RGB"), **_vec("sh_normal", N)}
    gb = read_gbuffer(_raw(tmp_path / "mi.exr", planes))
    assert gb.convention == "mitsuba"
    _assert_same(gb, P, N, A, cov)


def test_material_maps_present_absent_and_cs(tmp_path):
    P, N, A, cov, maps = _data(10)
    write_gbuffer(tmp_path / "none.exr", P, N, A)
    gb = read_gbuffer(tmp_path / "none.exr")
    assert gb.maps == {} and gb.coverage is None
    write_gbuffer(tmp_path / "some.exr", P, N, A, maps={"k_s": maps["k_s"], "h": maps["h"]})
    gb = read_gbuffer(tmp_path / "some.exr")
    assert list(gb.maps) == ["k_s", "h"] and gb.coverage is None
    assert gb.sources["h"].endswith(": shininess")
    gb = read_gbuffer(_raw(tmp_path / "cs.exr", {**_vec("P", P), **_vec("N", N), **_vec("albedo", A, "RGB"),
                                                  **_vec("Cs", maps["specular_color"], "RGB"),
                                                  "k_d.V": maps["k_d"]}))
    _assert_same(gb, P, N, A, None, {"specular_color": maps["specular_color"], "k_d": maps["k_d"]})


def test_coverage_from_albedo_layer_alpha(tmp_path):
    P, N, A, cov, _ = _data(11)
    gb = read_gbuffer(_raw(tmp_path / "aa.exr", {**_vec("P", P), **_vec("N", N),
                                                  **_vec("albedo", A, "RGB"), "albedo.A": cov}))
    _assert_same(gb, P, N, A, cov)


def test_header_attributes(tmp_path):
    P, N, A, _, _ = _data(12)
    m = tuple(float(v) for v in range(16))
    write_gbuffer(tmp_path / "m.exr", P, N, A, attributes={"worldToCamera": m, "Software": "test"})
    gb = read_gbuffer(tmp_path / "m.exr")
    assert tuple(gb.attributes["worldToCamera"]) == m and gb.attributes["Software"] == "test"


def test_data_window_inside_display_window(tmp_path):
    P, N, A, _, _ = _data(13, h=3, w=4)
    data = np.concatenate([P, N, A], -1)
    spec = oiio.ImageSpec(4, 3, 9, "float")
    spec.x, spec.y = 2, 1
    spec.full_x, spec.full_y, spec.full_width, spec.full_height = 0, 0, W, H
    spec.channelnames = ("P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z", "albedo.R", "albedo.G", "albedo.B")
    path = str(tmp_path / "dw.exr")
    out = oiio.ImageOutput.create(path)
    assert out.open(path, spec) and out.write_image(np.ascontiguousarray(data)) and out.close()
    gb = read_gbuffer(path)
    assert gb.shape == (H, W)
    assert np.array_equal(gb.position[1:4, 2:6], P) and np.array_equal(gb.albedo[1:4, 2:6], A)
    bg = gb.background_mask()
    assert bg.sum() == H * W - 12 and not bg[1:4, 2:6].any()


# --------------------------------------------------------------------------- separate files


def test_separate_rgb_files(tmp_path):
    P, N, A, cov, _ = _data(14)
    write_exr(tmp_path / "P.exr", P)
    _raw(tmp_path / "N.exr", _vec("", N, "XYZ"), pixel_type="half", tiled=True)
    write_exr(tmp_path / "A.exr", np.concatenate([A, cov[..., None]], -1), channel_names="RGBA")
    gb = read_gbuffer(position=tmp_path / "P.exr", normal=str(tmp_path / "N.exr"), albedo=tmp_path / "A.exr")
    assert gb.convention == "rgb-files"
    assert np.array_equal(gb.position, P) and np.array_equal(gb.normal, _half(N))
    assert np.array_equal(gb.albedo, A) and np.array_equal(gb.coverage, cov)
    assert gb.sources == {"position": f"{tmp_path / 'P.exr'}: R,G,B", "normal": f"{tmp_path / 'N.exr'}: X,Y,Z",
                          "albedo": f"{tmp_path / 'A.exr'}: R,G,B", "coverage": f"{tmp_path / 'A.exr'}: A"}


def test_separate_layered_files(tmp_path):
    P, N, A, _, _ = _data(15)
    _raw(tmp_path / "P.exr", _vec("P", P))
    write_gbuffer(tmp_path / "full.exr", P * 0, N, A * 0, convention="blender")
    _raw(tmp_path / "A.exr", {**_vec("", A * 0, "RGB"), **_vec("albedo", A, "RGB")})   # layer beats plain RGB
    gb = read_gbuffer(position=tmp_path / "P.exr", normal=tmp_path / "full.exr", albedo=tmp_path / "A.exr")
    assert gb.convention == "generic"
    _assert_same(gb, P, N, A)
    assert "ViewLayer.Normal.X" in gb.sources["normal"]


def test_main_file_with_override(tmp_path):
    P, N, A, cov, maps = _data(16)
    write_gbuffer(tmp_path / "main.exr", P, N * 0 + 1, A, coverage=cov, maps=maps)
    write_exr(tmp_path / "N.exr", N)
    gb = read_gbuffer(tmp_path / "main.exr", normal=tmp_path / "N.exr")
    assert gb.convention == "generic"
    _assert_same(gb, P, N, A, cov, maps)
    assert gb.sources["normal"] == f"{tmp_path / 'N.exr'}: R,G,B"
    assert gb.sources["position"].startswith(f"{tmp_path / 'main.exr'}: ")
    # the main file may lack the overridden buffer entirely
    _raw(tmp_path / "partial.exr", {**_vec("P", P), **_vec("albedo", A, "RGB")})
    _assert_same(read_gbuffer(tmp_path / "partial.exr", normal=tmp_path / "N.exr"), P, N, A)


def test_different_sizes(tmp_path):
    P, N, A, _, _ = _data(17)
    write_exr(tmp_path / "P.exr", P)
    write_exr(tmp_path / "N.exr", np.zeros((H + 1, W, 3), np.float32))
    write_exr(tmp_path / "A.exr", A)
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(position=tmp_path / "P.exr", normal=tmp_path / "N.exr", albedo=tmp_path / "A.exr")
    msg = str(exc.value)
    assert f"position {tmp_path / 'P.exr'} is 7x5" in msg and f"normal {tmp_path / 'N.exr'} is 7x6" in msg
    assert "\n" not in msg


# --------------------------------------------------------------------------- explicit mapping


def _custom_file(tmp_path, P, N, A, cov, maps):
    """A file whose real buffers have custom names, plus decoy generic layers."""
    z = np.zeros((H, W, 3), np.float32)
    return _raw(tmp_path / "custom.exr", {
        **_vec("P", z), **_vec("N", z), **_vec("albedo", z, "RGB"), "A": np.ones((H, W)),
        **_vec("Pworld", P, "RGB"), "Nw.X": N[..., 0], "Nw.Y": N[..., 1], "Nw.Z": N[..., 2],
        **_vec("base", A, "RGB"), "mask": cov, "spec_weight": maps["k_s"], "gloss.V": maps["h"],
        **_vec("sc", maps["specular_color"], "RGB")})


def test_explicit_mapping_overrides_detection(tmp_path):
    P, N, A, cov, maps = _data(18)
    path = _custom_file(tmp_path, P, N, A, cov, maps)
    gb = read_gbuffer(path, channels={"position": "Pworld", "normal": ["Nw.X", "Nw.Y", "Nw.Z"],
                                      "albedo": "base.R, base.G, base.B", "coverage": "mask",
                                      "k_s": ["spec_weight"], "h": "gloss", "specular_color": "sc"})
    assert gb.convention == "explicit"
    _assert_same(gb, P, N, A, cov, {"k_s": maps["k_s"], "h": maps["h"],
                                    "specular_color": maps["specular_color"]})
    assert gb.sources["normal"] == f"{path}: Nw.X,Nw.Y,Nw.Z"
    assert gb.sources["h"] == f"{path}: gloss.V"
    # partly explicit: the rest is detected
    gb = read_gbuffer(path, channels={"position": "Pworld"})
    assert gb.convention == "generic"
    assert np.array_equal(gb.position, P) and not gb.normal.any()


def test_explicit_mapping_via_parse_channel_mapping(tmp_path):
    P, N, A, cov, maps = _data(19)
    path = _custom_file(tmp_path, P, N, A, cov, maps)
    mapping = parse_channel_mapping(["position=Pworld", "normal=Nw.X,Nw.Y,Nw.Z", "albedo=base",
                                     "coverage=mask", "k_s=spec_weight"])
    assert mapping == {"position": "Pworld", "normal": ["Nw.X", "Nw.Y", "Nw.Z"], "albedo": "base",
                       "coverage": "mask", "k_s": "spec_weight"}
    gb = read_gbuffer(path, channels=mapping)
    _assert_same(gb, P, N, A, cov, {"k_s": maps["k_s"]})


def test_explicit_mapping_with_separate_files(tmp_path):
    P, N, A, cov, maps = _data(20)
    path = _custom_file(tmp_path, P, N, A, cov, maps)
    write_exr(tmp_path / "A.exr", A)
    gb = read_gbuffer(position=path, normal=path, albedo=tmp_path / "A.exr",
                      channels={"position": "Pworld", "normal": "Nw", "coverage": "mask"})
    assert gb.convention == "rgb-files"
    _assert_same(gb, P, N, A, cov)


def test_parse_channel_mapping_errors():
    for item, needle in [("position", "expected KEY=CHANNELS"), ("colour=R,G,B", "unknown key 'colour'"),
                         ("normal=", "no channels"), ("normal=N.X,N.Y", "needs 3 channel names, got 2"),
                         ("k_s=a,b", "needs 1 channel name, got 2"), ("albedo=a,,b", "empty channel name")]:
        with pytest.raises(GBufferError) as exc:
            parse_channel_mapping([item])
        assert item in str(exc.value) and needle in str(exc.value), str(exc.value)
    with pytest.raises(GBufferError, match="more than once"):
        parse_channel_mapping(["normal=N", "normal=Nw"])


def test_channels_unknown_key_and_bad_counts(tmp_path):
    P, N, A, _, _ = _data(21)
    write_gbuffer(tmp_path / "g.exr", P, N, A)
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(tmp_path / "g.exr", channels={"diffuse": "albedo"})
    assert "'diffuse'" in str(exc.value) and ", ".join(CHANNEL_KEYS) in str(exc.value)
    with pytest.raises(GBufferError, match=r"position needs 3 channel names, got 2"):
        read_gbuffer(tmp_path / "g.exr", channels={"position": ["P.X", "P.Y"]})
    with pytest.raises(GBufferError, match=r"coverage needs 1 channel name, got 3"):
        read_gbuffer(tmp_path / "g.exr", channels={"coverage": "P.X,P.Y,P.Z"})


def test_explicit_channels_missing(tmp_path):
    P, N, A, _, _ = _data(22)
    path = tmp_path / "g.exr"
    write_gbuffer(path, P, N, A)
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(path, channels={"normal": "N.X,N.Y,N.W"})
    assert str(exc.value).startswith(f"{path}: channel 'N.W' (normal")
    assert "P.X" in str(exc.value)
    with pytest.raises(GBufferError) as exc:
        read_gbuffer(path, channels={"position": "Pworld"})
    assert str(exc.value).startswith(f"{path}: no layer 'Pworld'") and "position" in str(exc.value)
    with pytest.raises(GBufferError, match="'mask' for coverage"):
        read_gbuffer(path, channels={"coverage": "mask"})


# --------------------------------------------------------------------------- background_mask


def test_background_mask():
    N = np.ones((2, 3, 3), np.float32)
    N[0, 0] = 0.0                                   # zero normal -> background
    N[0, 1] = [np.nan, 0, 1]                        # NaN -> background
    N[0, 2] = [1e-40, 0, 0]                         # denormal float32: |N|^2 underflows in float32
    N[1, 0] = [np.inf, 0, 0]                        # inf -> background
    cov = np.ones((2, 3), np.float32)
    cov[1, 1] = 0.0                                 # zero coverage -> background
    z = np.zeros_like(N)
    gb = GBuffer(position=z, normal=N, albedo=z, coverage=cov)
    expected = np.array([[True, True, False], [True, True, False]])
    assert gb.background_mask().dtype == bool
    assert np.array_equal(gb.background_mask(), expected)
    gb = GBuffer(position=z, normal=N, albedo=z)
    assert np.array_equal(gb.background_mask(), expected & [[1, 1, 1], [1, 0, 1]])


def test_gbuffer_shape_validation():
    z = np.zeros((2, 3, 3), np.float32)
    with pytest.raises(GBufferError, match="normal has shape"):
        GBuffer(position=z, normal=z[:1], albedo=z)
    with pytest.raises(GBufferError, match="coverage"):
        GBuffer(position=z, normal=z, albedo=z, coverage=np.zeros((3, 2)))


# --------------------------------------------------------------------------- errors


def _one_line_error(fn, *args, **kw):
    with pytest.raises(GBufferError) as exc:
        fn(*args, **kw)
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_error_missing_file(tmp_path):
    msg = _one_line_error(read_gbuffer, tmp_path / "nope.exr")
    assert msg == f"{tmp_path / 'nope.exr'}: file not found"
    write_exr(tmp_path / "P.exr", np.zeros((H, W, 3)))
    msg = _one_line_error(read_gbuffer, position=tmp_path / "P.exr", normal=tmp_path / "P.exr",
                          albedo=tmp_path / "gone.exr")
    assert "gone.exr: file not found" in msg


def test_error_no_file_given():
    assert "albedo" in _one_line_error(read_gbuffer, position="P.exr", normal="N.exr")


def test_error_not_an_exr(tmp_path):
    (tmp_path / "text.exr").write_text("hello, not an image\n")
    msg = _one_line_error(read_gbuffer, tmp_path / "text.exr")
    assert msg.startswith(f"{tmp_path / 'text.exr'}: cannot read as EXR: ") and len(msg) > 60
    (tmp_path / "dir.exr").mkdir()
    assert "is a directory" in _one_line_error(read_gbuffer, tmp_path / "dir.exr")
    png = str(tmp_path / "img.png")
    out = oiio.ImageOutput.create(png)
    assert out.open(png, oiio.ImageSpec(W, H, 3, "uint8")) and out.write_image(np.zeros((H, W, 3), np.uint8))
    out.close()
    msg = _one_line_error(read_gbuffer, png)
    assert msg == f"{png}: not an OpenEXR file (it is a PNG file)"


def test_error_missing_channels(tmp_path):
    P, N, A, _, _ = _data(23)
    path = _raw(tmp_path / "partial.exr", {**_vec("P", P), **_vec("N", N), **_vec("albedo_typo", A, "RGB")})
    msg = _one_line_error(read_gbuffer, path)
    assert msg.startswith(f"{path}: no albedo channels found")
    assert "albedo.*" in msg and "DiffCol" in msg and "albedo_typo.R" in msg and "position" not in msg.split("(")[0]
    path = _raw(tmp_path / "beauty.exr", {**_vec("", A, "RGB"), "A": np.ones((H, W))})
    msg = _one_line_error(read_gbuffer, path)
    assert msg.startswith(f"{path}: no position, normal, albedo channels found")
    assert "the file has: R, G, B, A" in msg or "the file has: A, B, G, R" in msg
    assert "a plain R,G,B file holds one buffer" in msg and "--position" in msg
    # Blender view layer missing a pass
    path = _raw(tmp_path / "bl.exr", {**_vec("VL.Position", P), **_vec("VL.DiffCol", A, "RGB")})
    msg = _one_line_error(read_gbuffer, path)
    assert msg.startswith(f"{path}: no normal channels found in view layer 'VL'")


def test_error_missing_channels_long_list_is_shortened(tmp_path):
    planes = {f"aov{i:02d}.V": np.zeros((H, W)) for i in range(40)}
    msg = _one_line_error(read_gbuffer, _raw(tmp_path / "long.exr", planes))
    assert "(+24 more)" in msg and "aov39" not in msg


def test_error_separate_file_missing_buffer(tmp_path):
    write_exr(tmp_path / "Y.exr", np.zeros((H, W)), channel_names=("Y",))
    write_exr(tmp_path / "P.exr", np.zeros((H, W, 3)))
    msg = _one_line_error(read_gbuffer, position=tmp_path / "P.exr", normal=tmp_path / "Y.exr",
                          albedo=tmp_path / "P.exr")
    assert msg.startswith(f"{tmp_path / 'Y.exr'}: no normal channels found") and "plain R,G,B" in msg
    assert msg.endswith("--channels normal=LAYER or normal=CH1,CH2,CH3")


def test_error_deep(tmp_path):
    spec = oiio.ImageSpec(W, H, 2, "float")
    spec.channelnames = ("A", "Z")
    spec.deep = True
    deep = oiio.DeepData()
    deep.init(spec)
    path = str(tmp_path / "deep.exr")
    out = oiio.ImageOutput.create(path)
    assert out.open(path, spec) and out.write_deep_image(deep) and out.close()
    assert _one_line_error(read_gbuffer, path) == (f"{path}: deep EXR files are not supported; "
                                                   "flatten it first (e.g. oiiotool --flatten)")


def _multipart(path, parts, windows=None):
    """Write a multi-part EXR: parts = [(part name, {channel: (H, W) array}), ...];
    windows = {part index: (x, y, w, h) data window} (default: the whole image)."""
    specs, datas = [], []
    for i, (name, planes) in enumerate(parts):
        data = np.ascontiguousarray(np.stack([np.asarray(v, np.float32) for v in planes.values()], -1))
        x, y, w, h = (windows or {}).get(i, (0, 0, W, H))
        data = np.ascontiguousarray(data[y:y + h, x:x + w])
        s = oiio.ImageSpec(w, h, len(planes), "float")
        s.x, s.y, s.full_x, s.full_y, s.full_width, s.full_height = x, y, 0, 0, W, H
        s.channelnames = tuple(planes)
        s.attribute("name", name)
        s.attribute("compression", "zip")
        specs.append(s)
        datas.append(data)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), specs), out.geterror()
    for i, data in enumerate(datas):
        if i:
            assert out.open(str(path), specs[i], "AppendSubimage"), out.geterror()
        assert out.write_image(data), out.geterror()
    assert out.close()
    return str(path)


def test_multipart_full_channel_names(tmp_path):
    """Parts whose channels carry their full names (Nuke, Arnold) are gathered as one file."""
    P, N, A, cov, maps = _data(24)
    path = _multipart(tmp_path / "mp.exr", [("geo", {**_vec("P", P), **_vec("N", N)}),
                                            ("col", _vec("albedo", A, "RGB")),
                                            ("rgba", {"R": A[..., 0], "A": cov}),   # Nuke's beauty part
                                            ("k_s", {"X": maps["k_s"]})])     # a value AOV part
    gb = read_gbuffer(path)
    _assert_same(gb, P, N, A, cov, {"k_s": maps["k_s"]})
    assert gb.convention == "generic"
    assert gb.sources["position"] == f"{path}: P.X,P.Y,P.Z (part 0 geo)"
    assert gb.sources["albedo"] == f"{path}: albedo.R,albedo.G,albedo.B (part 1 col)"
    assert gb.sources["coverage"] == f"{path}: rgba.A (part 2 rgba)"


@pytest.mark.parametrize("diffuse", ["Diffuse Color", "DiffCol"])
def test_multipart_blender5_bare_names(tmp_path, diffuse):
    """Blender 5's default: one part per pass, named by its layer; bare channel names get that prefix."""
    P, N, A, cov, _ = _data(26)
    layer = "View Layer"                      # a space in the view-layer name
    combined = np.concatenate([A * cov[..., None], cov[..., None]], -1)
    path = _multipart(tmp_path / "b5.exr", [
        (f"{layer}.Combined", _vec(f"{layer}.Combined", combined, "RGBA")),
        (f"{layer}.Position", _vec("", P)),
        (f"{layer}.Normal", _vec("", N)),
        (f"{layer}.{diffuse}", _vec("", A, "RGB"))])
    gb = read_gbuffer(path)
    _assert_same(gb, P, N, A, cov)
    assert gb.convention == "blender"
    assert gb.sources["albedo"].startswith(f"{path}: {layer}.{diffuse}.R,")
    assert gb.sources["coverage"] == (f"{path}: {layer}.Combined.A (part 0 {layer}.Combined) "
                                      f"(view layer '{layer}')")
    # --channels names channels by their gathered full names
    gb = read_gbuffer(path, channels={"normal": f"{layer}.Position"})
    assert np.array_equal(gb.normal, P)


def test_multipart_data_windows_per_part(tmp_path):
    """Each part has its own data window: a pixel is shaded only where all three buffers have data."""
    P, N, A, _, _ = _data(27)
    N = N + np.float32(3)                     # no zero normals of their own
    path = _multipart(tmp_path / "win.exr", [("P", _vec("P", P)), ("N", _vec("N", N)),
                                             ("albedo", _vec("albedo", A, "RGB"))],
                      windows={0: (1, 1, W - 1, H - 1), 2: (0, 0, W - 2, H)})
    gb = read_gbuffer(path)
    inside = np.zeros((H, W), bool)
    inside[1:, 1:W - 2] = True
    assert np.array_equal(~gb.background_mask(), inside)
    assert np.array_equal(gb.position[1:, 1:], P[1:, 1:]) and not gb.position[0].any()


def test_error_multipart_duplicate_channel(tmp_path):
    P, N, A, _, _ = _data(24)
    path = _multipart(tmp_path / "dup.exr", [("geo", {**_vec("P", P), **_vec("N", N)}),
                                             ("col", {**_vec("albedo", A, "RGB"), "P.Y": A[..., 0]})])
    msg = _one_line_error(read_gbuffer, path)
    assert msg.startswith(f"{path}: channel 'P.Y' is in part 0 (geo) and in part 1 (col): "
                          "a channel name must be unique across parts")


def test_error_multipart_deep_part(tmp_path):
    path = str(tmp_path / "deep2.exr")
    specs = []
    for name in ("one", "two"):               # OpenImageIO writes deep parts with deep parts only
        deep = oiio.ImageSpec(W, H, 2, "float")
        deep.channelnames = ("A", "Z")
        deep.deep = True
        deep.attribute("name", name)
        specs.append(deep)
    dd = oiio.DeepData()
    dd.init(specs[0])
    out = oiio.ImageOutput.create(path)
    assert out.open(path, specs) and out.write_deep_image(dd)
    assert out.open(path, specs[1], "AppendSubimage") and out.write_deep_image(dd) and out.close()
    msg = _one_line_error(read_gbuffer, path)
    assert msg.startswith(f"{path}: part 0: deep EXR files are not supported")


def test_error_ambiguous_scalar_layer(tmp_path):
    P, N, A, _, maps = _data(25)
    path = _raw(tmp_path / "amb.exr", {**_vec("P", P), **_vec("N", N), **_vec("albedo", A, "RGB"),
                                        **_vec("k_s", maps["specular_color"], "RGB")})
    msg = _one_line_error(read_gbuffer, path)
    assert msg.startswith(f"{path}: layer 'k_s' has 3 channels") and "--channels k_s=k_s." in msg
    gb = read_gbuffer(path, channels={"k_s": "k_s.G"})
    assert np.array_equal(gb.maps["k_s"], maps["specular_color"][..., 1])


def test_write_gbuffer_bad_arguments(tmp_path):
    P, N, A, cov, _ = _data(26)
    with pytest.raises(GBufferError, match="unknown convention 'vray'"):
        write_gbuffer(tmp_path / "x.exr", P, N, A, convention="vray")
    with pytest.raises(GBufferError, match="unknown material map 'gloss'"):
        write_gbuffer(tmp_path / "x.exr", P, N, A, maps={"gloss": cov})
    with pytest.raises(GBufferError, match="normal has shape"):
        write_gbuffer(tmp_path / "x.exr", P, N[:, :3], A)
    with pytest.raises(GBufferError, match="pixel type"):
        write_gbuffer(tmp_path / "x.exr", P, N, A, pixel_type="double")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------- the shipped samples in gbuffers/

@pytest.mark.parametrize("name", ["spheres", "ortho"])
def test_shipped_samples_are_the_generator_output(name):
    """gbuffers/NAME.exr holds exactly what clphong.tools.samples.NAME() computes, rounded to
    the file's storage type, and the [camera] of gbuffers/NAME.toml is the generator's
    camera constant (clphong.tools.samples' docstring)."""
    import tomllib

    from clphong.tools import samples

    path = GBUFFERS / f"{name}.exr"
    made = getattr(samples, name)()
    P, N, A, cov = made[:4]
    maps = made[4] if len(made) > 4 else {}
    inp = oiio.ImageInput.open(str(path))
    stored = {str(t) for t in inp.spec().channelformats} or {str(inp.spec().format)}
    inp.close()
    assert stored <= {"float", "half"}, stored
    storage = np.float16 if stored == {"half"} else np.float32

    def conv(x):
        return np.asarray(x).astype(storage).astype(np.float32)

    gb = read_gbuffer(path)
    for channel, got, want in (("position", gb.position, P), ("normal", gb.normal, N),
                               ("albedo", gb.albedo, A), ("coverage", gb.coverage, cov)):
        assert got.shape == want.shape and np.array_equal(got, conv(want)), channel
    assert sorted(gb.maps) == sorted(maps)
    for key, want in maps.items():
        assert np.array_equal(gb.maps[key], conv(want)), key

    constant = getattr(samples, f"{name.upper()}_CAMERA")
    with open(GBUFFERS / f"{name}.toml", "rb") as f:
        camera = tomllib.load(f)["camera"]
    # the keys that shading uses: the eye of a perspective camera, the view direction
    # of an orthographic one
    assert {"type", "position" if constant["type"] == "perspective" else "direction"} <= set(camera)
    for key, value in camera.items():
        want = constant[key]
        assert (tuple(value) if isinstance(value, list) else value) == want, key


# --------------------------------------------------------------------------- issue 15: implausible decodes


def test_the_magnitude_limits_follow_the_kernels_float32_arithmetic():
    """What each limit of clphong.io.nonfinite.LIMITS claims, in float32 as the kernels
    compute: below it the operation is finite, at it it can overflow."""
    f32 = np.float32
    below = {k: np.nextafter(f32(v), f32(0)) for k, v in LIMITS.items()}
    with np.errstate(over="ignore", invalid="ignore"):
        # positions: the difference of two points on either side of the origin
        p = below["position"]
        assert np.isfinite(p - (-p))
        assert np.isinf(f32(LIMITS["position"]) - f32(-LIMITS["position"]))
        # colours and weights: D + S, each a product of two G-buffer values (scene factors <= 1)
        c = below["albedo"]
        assert np.isfinite(c * c + c * c) and c * c + c * c < f32(2.0 ** 127)
        assert all(below[k] == c for k in ("k_d", "k_s", "specular_color"))
        # and past it a product can be ∞, and ∞ · 0 (a back-facing light's weight) NaN
        big = f32(2.0 ** 65)
        assert np.isnan((big * big) * f32(0))
        # Blinn's exponent 4h
        assert np.isfinite(f32(4) * below["h"]) and np.isinf(f32(4) * f32(LIMITS["h"]))
    # normals have no limit: normalised in float64, the extremes are unit
    for n in ([3.4028235e38, 3.4028235e38, -3.4028235e38], [1e-45, 0, 0], [1e-45, 3.4e38, 0]):
        x, y, z = unit_normal_planes(np.array([[n]], np.float32))
        assert abs(float(x[0] ** 2 + y[0] ** 2 + z[0] ** 2) - 1.0) < 1e-15


def test_implausible_counts_per_channel_at_the_limits():
    f32 = np.float32
    rng = np.random.default_rng(2)
    P = rng.uniform(-1, 1, (2, 3, 3)).astype(np.float32)
    N = rng.normal(size=(2, 3, 3)).astype(np.float32)
    A = rng.uniform(0, 1, (2, 3, 3)).astype(np.float32)
    maps = {"k_d": np.full((2, 3), 0.5, f32), "k_s": np.full((2, 3), 0.5, f32),
            "h": np.full((2, 3), 10, f32), "specular_color": np.ones((2, 3, 3), f32)}
    gb = GBuffer(P, N, A, coverage=np.ones((2, 3), f32), maps=maps)
    assert implausible_counts(gb) == {}
    for key, limit in LIMITS.items():
        for value, counted in ((np.nextafter(f32(limit), f32(0)), False), (f32(limit), True),
                               (-f32(limit), True), (np.inf, False), (np.nan, False)):
            arrays = {"position": P.copy(), "albedo": A.copy(), **{k: v.copy() for k, v in maps.items()}}
            a = arrays[key]
            if a.ndim == 2:
                a[0, 1] = value
            else:
                a[0, 1, 1] = value                                     # the G/Y channel of pixel (0, 1)
            cov = np.ones((2, 3), f32)
            g = GBuffer(arrays["position"], N, arrays["albedo"], coverage=cov,
                        maps={k: arrays[k] for k in maps})
            label = key if a.ndim == 2 else f"{key}.{'Y' if key == 'position' else 'G'}"
            assert implausible_counts(g) == ({label: 1} if counted else {}), (key, value)
            cov[0, 1] = 0                                              # background: not counted
            assert implausible_counts(g) == {}
    # a huge normal is a direction like any other
    N2 = N.copy()
    N2[1, 2] = [3.4e38, -3.4e38, 1.0]
    assert implausible_counts(GBuffer(P, N2, A)) == {}


def test_nonfinite_coverage_is_background_and_counted():
    rng = np.random.default_rng(3)
    P, N, A = (rng.uniform(0.1, 1, (2, 3, 3)).astype(np.float32) for _ in range(3))
    cov = np.full((2, 3), 0.5, np.float32)
    assert "coverage" not in nonfinite_counts(GBuffer(P, N, A, coverage=cov))
    cov[0, 0], cov[1, 2] = np.nan, np.inf
    gb = GBuffer(P, N, A, coverage=cov)
    assert gb.background_mask().tolist() == [[True, False, False], [False, False, True]]
    assert nonfinite_counts(gb)["coverage"] == 2
    with pytest.warns(InputWarning, match=r"coverage: 2 pixel\(s\)"):
        out, _ = apply_nonfinite_policy(gb)
    assert np.all(np.isfinite(out.coverage)) and out.coverage[0, 0] == out.coverage[1, 2] == 0
    with pytest.raises(GBufferError, match=r"non-finite .*coverage: 2 pixel\(s\)"):
        apply_nonfinite_policy(gb, "error")


def test_implausible_values_follow_the_nonfinite_policy_in_one_line():
    rng = np.random.default_rng(4)
    P, N, A = (rng.uniform(0.1, 1, (2, 3, 3)).astype(np.float32) for _ in range(3))
    P[0, 0, 2] = -3e38
    A[1, 1] = [1e20, 0.5, 1e30]
    P[1, 2, 0] = np.nan
    gb = GBuffer(P, N, A, coverage=np.ones((2, 3), np.float32),
                 sources={"position": "f.exr: P.X,P.Y,P.Z", "albedo": "f.exr: albedo.R,albedo.G,albedo.B"})
    with pytest.warns(InputWarning) as caught:
        out, counts = apply_nonfinite_policy(gb)
    (w,) = caught
    text = str(w.message)
    assert "\n" not in text and counts["position"] == 1
    assert text.startswith("non-finite G-buffer values left unshaded as background: f.exr: P.X,P.Y,P.Z: 1 pixel(s); "
                           "also implausibly large G-buffer values (position |x| >= 1.7e+38, albedo |x| >= 9.2e+18")
    assert text.endswith("left unshaded as background: f.exr: P.X,P.Y,P.Z: Z 1 pixel(s); "
                         "f.exr: albedo.R,albedo.G,albedo.B: R 1, B 1 pixel(s)")
    assert out.coverage.tolist() == [[0, 1, 1], [1, 0, 0]]
    with pytest.raises(GBufferError, match=r"implausibly large .*albedo.R,albedo.G,albedo.B: R 1, B 1 pixel\(s\); "
                                           r"fix the input"):
        apply_nonfinite_policy(gb, "error")
    with pytest.warns(InputWarning, match="implausibly large .* passed to the kernels"):
        same, _ = apply_nonfinite_policy(gb, "pass")
    assert same is gb


def _typed(path, types):
    P, N, A, _, _ = _data(6)
    planes = {**{f"P.{c}": P[..., i] for i, c in enumerate("XYZ")},
              **{f"N.{c}": N[..., i] for i, c in enumerate("XYZ")},
              **{f"albedo.{c}": A[..., i] for i, c in enumerate("RGB")}}
    names = list(planes)
    spec = oiio.ImageSpec(W, H, len(names), oiio.TypeDesc("float"))
    spec.channelnames = tuple(names)
    spec.channelformats = tuple(oiio.TypeDesc(types.get(n, "float")) for n in names)
    o = oiio.ImageOutput.create(str(path))
    assert o.open(str(path), spec)
    assert o.write_image(np.ascontiguousarray(np.stack([planes[n] for n in names], -1)))
    assert o.close()
    return path


def test_a_vector_of_mixed_pixel_types_warns_a_layer_of_another_type_does_not(tmp_path):
    with pytest.warns(InputWarning, match=r"mixed.exr: channels of one buffer stored as different pixel "
                                          r"types \(normal: N.Z as half and N.X, N.Y as float\)"):
        gb = read_gbuffer(_typed(tmp_path / "mixed.exr", {"N.Z": "half"}))
    assert gb.normal.dtype == np.float32
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_gbuffer(_typed(tmp_path / "layers.exr", {"albedo.R": "half", "albedo.G": "half",
                                                      "albedo.B": "half"}))


def test_a_read_failure_names_a_lone_channel_of_another_pixel_type(tmp_path):
    """A flipped pixel-type byte in a channel that is no vector's (A): the chunks no
    longer decode; the error names it. A whole layer of another type is not named."""
    P, N, A, cov, _ = _data(7)
    write_gbuffer(tmp_path / "g.exr", P, N, A, coverage=cov)
    data = bytearray((tmp_path / "g.exr").read_bytes())
    at = data.find(b"A\x00\x02\x00\x00\x00")
    data[at + 2] = 1                                                     # FLOAT -> HALF
    (tmp_path / "a.exr").write_bytes(bytes(data))
    with pytest.raises(GBufferError, match=r"failed: .*; the header gives A as half but the other 9 "
                                           r"channels as float: a flipped pixel-type byte\?$"):
        read_gbuffer(tmp_path / "a.exr")
