"""The Relighter API: inputs, outputs, threads, compile-once, camera from worldToCamera."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from conftest import (
    GBUFFERS,
    make_scene,
    patch_everywhere,
    random_gbuffer,
    random_lights,
    read_rgb,
    record_calls,
)

import clphong
from clphong.core.errors import GBufferError, OutputError
from clphong.io.camera import eye_from_matrix
from clphong.io.gbuffer import write_gbuffer
from clphong.pipeline.relighter import Relighter, write_output

SPHERES = (GBUFFERS / "spheres.toml", GBUFFERS / "spheres.exr")


def test_path_in_array_out_equals_render():
    r = Relighter(SPHERES[0])
    rgb = r.relight(str(SPHERES[1]))
    ref = clphong.render(clphong.load_scene(SPHERES[0]), clphong.read_gbuffer(SPHERES[1]))
    assert rgb.dtype == np.float32 and rgb.shape == ref.shape
    assert np.array_equal(rgb, ref)


def test_numpy_float32_and_float16_inputs():
    rng = np.random.default_rng(3)
    scene = make_scene(random_lights(rng))
    gb = random_gbuffer(rng, 24, 32, background_fraction=0.0)
    r = Relighter(scene)
    ref = clphong.Renderer(scene).render(gb).image
    assert np.array_equal(r.relight((gb.position, gb.normal, gb.albedo)), ref)
    assert np.array_equal(r.relight({"position": gb.position, "normal": gb.normal, "albedo": gb.albedo}), ref)
    # float16 input is widened exactly to float32: the result is that of the rounded G-buffer.
    P16, N16, C16 = (a.astype(np.float16) for a in (gb.position, gb.normal, gb.albedo))
    half = r.relight((P16, N16, C16))
    rounded = clphong.GBuffer(position=P16.astype(np.float32), normal=N16.astype(np.float32),
                              albedo=C16.astype(np.float32))
    assert np.array_equal(half, clphong.Renderer(scene).render(rounded).image)


@pytest.mark.parametrize("frame, fragment", [
    ((np.zeros((4, 5, 3), np.int32),) * 3, "position: expected a float32 or float16 array, got dtype int32"),
    ((np.zeros((4, 5), np.float32),) * 3, "position: expected an (H, W, 3) array"),
    ({"position": np.zeros((4, 5, 3), np.float32)}, "lacks normal, albedo"),
    (42, "cannot relight a int"),
])
def test_bad_array_input_is_one_clear_error(frame, fragment):
    r = Relighter(make_scene())
    with pytest.raises(GBufferError) as info:
        r.relight(frame)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_writes_file_atomically(tmp_path):
    r = Relighter(SPHERES[0])
    out = tmp_path / "lit.exr"
    rgb = r.relight(str(SPHERES[1]), out=out)
    assert np.array_equal(read_rgb(out), rgb)
    assert [p.name for p in tmp_path.iterdir()] == ["lit.exr"]
    with pytest.raises(OutputError, match="overwrite the input"):
        r.relight(str(out), out=out)
    # The scene-linear writer writes EXR only: a PNG is an SDR output (sdr=).
    with pytest.raises(OutputError, match=r"x\.png: a scene-linear output must end in \.exr"):
        write_output(rgb, tmp_path / "x.png", clphong.OutputOptions())
    with pytest.raises(OutputError, match=r"y\.png: a scene-linear output must end in \.exr"):
        r.relight(str(SPHERES[1]), out=tmp_path / "y.png")
    assert [p.name for p in tmp_path.iterdir()] == ["lit.exr"]


def test_compiles_once_for_many_frames():
    rng = np.random.default_rng(9)
    scene = make_scene(random_lights(rng, n_point=2))
    r = Relighter(scene)
    builds = r.renderer.runtime.builds
    for _ in range(4):
        r.relight(random_gbuffer(rng, 16, 16))
    assert r.renderer.runtime.builds == builds


def in_two_threads(n, task):
    """Run task(i) for i < n, even i on one thread and odd i on another, started together;
    re-raise the first exception either thread met."""
    errors = []
    start = threading.Barrier(2)

    def work(k):
        try:
            start.wait()
            for i in range(k, n, 2):
                task(i)
        except BaseException as exc:  # noqa: BLE001 - re-raised below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


def test_two_threads_equal_single_threaded():
    rng = np.random.default_rng(12)
    scene = make_scene(random_lights(rng, n_point=4, n_dir=1))
    frames = [random_gbuffer(rng, 24, 32) for _ in range(12)]
    r = Relighter(scene)
    single = [r.relight(g) for g in frames]
    results = [None] * len(frames)

    def task(i):
        results[i] = r.relight(frames[i])

    in_two_threads(len(frames), task)
    for a, b in zip(single, results):
        assert np.array_equal(a, b)


# ---------------------------------------------------------------- every output kind


def _aces_spheres(tmp_path):
    """spheres.toml delivered in ACEScg with AgX at +1 EV by its [render] table."""
    path = tmp_path / "aces.toml"
    path.write_text(SPHERES[0].read_text() + '\n[render]\nworking_space = "acescg"\n'
                    'tonemap = "agx"\nexposure = 1.0\n')
    return path


def _header(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp, oiio.geterror()
    spec = inp.spec()
    inp.close()
    return {a.name: a.value for a in spec.extra_attribs}, str(spec.format)


def test_relighter_writes_every_kind_like_render(tmp_path):
    from clphong.console.cli import main

    scene = _aces_spheres(tmp_path)
    r = Relighter(scene)
    assert (r.output.working_space, r.output.tonemap, r.output.exposure) == ("acescg", "agx", 1.0)
    out = tmp_path / "api"
    out.mkdir()
    rgb = r.relight(str(SPHERES[1]), out=out / "a.exr", sdr=[out / "a.png", out / "a.tif"],
                    hdr=out / "a_pq.png")
    assert sorted(p.name for p in out.iterdir()) == ["a.exr", "a.png", "a.tif", "a_pq.png"]
    a, _ = _header(out / "a.exr")
    assert a["oiio:ColorSpace"] == "lin_ap1_scene"
    assert np.allclose(a["chromaticities"], clphong.color.ocio.AP1_CHROMATICITIES, atol=1e-6)
    assert np.array_equal(read_rgb(out / "a.exr"), rgb)
    assert tuple(_header(out / "a_pq.png")[0]["CICP"]) == (9, 16, 0, 1)
    # The same bytes as 'clphong render' of the same scene and frame.
    cli = tmp_path / "cli"
    cli.mkdir()
    assert main(["render", str(scene), str(SPHERES[1]), "--sdr", str(cli / "a.png"),
                 "--sdr", str(cli / "a.tif"), "--hdr", str(cli / "a_pq.png")]) == 0
    for name in ("a.png", "a_pq.png"):
        assert (out / name).read_bytes() == (cli / name).read_bytes(), name
    # (TIFF headers carry the time of writing: compare pixels and the other tags.)
    assert np.array_equal(read_rgb(out / "a.tif"), read_rgb(cli / "a.tif"))
    ta, tb = (_header(p)[0] for p in (out / "a.tif", cli / "a.tif"))
    assert ta.pop("DateTime", None) and tb.pop("DateTime", None) and ta == tb
    # OutputOptions override the scene's [render] keys (None keeps the scene's).
    plain = Relighter(scene, output=clphong.OutputOptions(tonemap="none", exposure=0.0, bits=16))
    assert plain.output.working_space == "acescg"
    plain.relight(str(SPHERES[1]), sdr=out / "plain.png")
    assert main(["render", str(scene), str(SPHERES[1]), "--sdr", str(cli / "plain.png"),
                 "--tonemap", "none", "--exposure", "0", "--bits", "16"]) == 0
    assert (out / "plain.png").read_bytes() == (cli / "plain.png").read_bytes()
    assert (out / "plain.png").read_bytes() != (out / "a.png").read_bytes()
    assert _header(out / "plain.png")[1] == "uint16"


def test_relighter_output_errors_are_clear_and_early(tmp_path):
    from clphong.core.errors import ToneMapError

    with pytest.raises(ToneMapError, match="filmic"):
        Relighter(SPHERES[0], output=clphong.OutputOptions(tonemap="filmic"))
    r = Relighter(_aces_spheres(tmp_path))
    with pytest.raises(OutputError, match=r"x\.bmp: a SDR output must end in \.png"):
        r.relight(str(SPHERES[1]), out=tmp_path / "x.exr", sdr=tmp_path / "x.bmp")
    with pytest.raises(OutputError, match="overwrite the input"):
        r.relight(str(SPHERES[1]), sdr=SPHERES[1])
    assert not list(tmp_path.glob("x.*"))       # checked before anything was written


def test_two_threads_writing_sdr_equal_single_threaded(tmp_path):
    """The fused display path must not share a frame's display planes between threads."""
    rng = np.random.default_rng(13)
    scene = make_scene(random_lights(rng, n_point=4, n_dir=1))
    frames = [random_gbuffer(rng, 24, 32) for _ in range(10)]
    r = Relighter(scene, output=clphong.OutputOptions(tonemap="agx", exposure=0.5, bits=16))
    for i, g in enumerate(frames):
        r.relight(g, sdr=tmp_path / f"one.{i}.png")
    in_two_threads(len(frames), lambda i: r.relight(frames[i], sdr=tmp_path / f"two.{i}.png"))
    for i in range(len(frames)):
        assert (tmp_path / f"two.{i}.png").read_bytes() == (tmp_path / f"one.{i}.png").read_bytes(), i
    assert not hasattr(r.renderer, "display")     # a display transform is an argument, not state


# ---------------------------------------------------------------- camera from metadata


def look_at_world_to_camera(eye, target, up=(0.0, 1.0, 0.0)):
    """OpenEXR/RenderMan world-to-camera (row vectors, left-handed, +z forward) of a look-at camera."""
    eye = np.asarray(eye, np.float64)
    f = np.asarray(target, np.float64) - eye
    f /= np.linalg.norm(f)
    r = np.cross(np.asarray(up, np.float64), f)
    r /= np.linalg.norm(r)
    u = np.cross(f, r)
    R = np.stack([r, u, f], axis=1)          # columns: camera axes in world space
    M = np.eye(4)
    M[:3, :3] = R                            # p_cam = (p − eye) · R
    M[3, :3] = -eye @ R
    return M


EYE = (1.5, 2.5, 5.0)
#: The same camera in a Z-up world (Blender, 3ds Max, Unreal), by the usual convention of the
#: module docstring and the README, (x, y, z)_Zup -> (x, z, -y)_Yup (as Blender's glTF export):
#: Y-up (1.5, 2.5, 5) is Z-up (1.5, -5, 2.5); the Y-up target (0, 0.5, 0) is Z-up (0, 0, 0.5).
EYE_Z_UP = (1.5, -5.0, 2.5)


def _metadata_frame(tmp_path, name, matrix, gb):
    path = tmp_path / name
    write_gbuffer(path, gb.position, gb.normal, gb.albedo, coverage=gb.coverage,
                  attributes={"worldToCamera": matrix})
    return path


def test_eye_from_matrix_closed_form():
    M = look_at_world_to_camera(EYE, (0, 0.5, 0))
    # float64 matrix: the eye is recovered to rounding.
    assert np.allclose(eye_from_matrix(M), EYE, rtol=0, atol=1e-14)
    # column-vector layout (the transpose) gives the same eye
    assert np.allclose(eye_from_matrix(M.T), EYE, rtol=0, atol=1e-14)
    with pytest.raises(GBufferError, match="not an affine transform"):
        bad = M.copy()
        bad[0, 3] = 0.5
        bad[3, 0] = 0.5
        eye_from_matrix(bad, source="f.exr")
    with pytest.raises(GBufferError, match="singular"):
        eye_from_matrix(np.diag([1.0, 0.0, 1.0, 1.0]))


@pytest.mark.parametrize("up", ["y", "z"])
def test_camera_from_world_to_camera_y_and_z_up(tmp_path, up):
    rng = np.random.default_rng(21)
    lights = random_lights(rng, n_point=3, n_dir=0, n_amb=0)
    gb = random_gbuffer(rng, 24, 32)
    if up == "y":
        M = look_at_world_to_camera(EYE, (0, 0.5, 0))
    else:
        # The camera as a Z-up application writes it: built in Z-up coordinates, up +z.
        M = look_at_world_to_camera(EYE_Z_UP, (0, 0, 0.5), up=(0, 0, 1))
        assert np.allclose(eye_from_matrix(M, up="y"), EYE_Z_UP, rtol=0, atol=1e-14)  # as written
        # Written out by hand: a camera at Z-up (1.5, -5, 2.5) with the world's axes, p_cam =
        # p_world - (1.5, -5, 2.5) (the translation in the last row); its Y-up eye is exact.
        hand = np.array([[1.0, 0.0, 0.0, 0.0],
                         [0.0, 1.0, 0.0, 0.0],
                         [0.0, 0.0, 1.0, 0.0],
                         [-1.5, 5.0, -2.5, 1.0]])
        assert eye_from_matrix(hand, up="z").tolist() == [1.5, 2.5, 5.0]
        assert eye_from_matrix(hand, up="y").tolist() == [1.5, -5.0, 2.5]
    path = _metadata_frame(tmp_path, f"meta_{up}.exr", M, gb)
    scene = clphong.parse_scene({"camera": {"type": "metadata", "up": up},
                                 "material": {"model": "phong", "k_a": 0.0, "k_d": 0.7, "k_s": 0.3, "h": 40.0},
                                 "light": [dict(lt, position=list(lt["position"])) for lt in lights]})
    rgb = Relighter(scene).relight(str(path))
    # The header stores M in float32 (M44f). Its eye is −t·A⁻¹ with A a rotation (condition 1):
    # |Δeye| ≤ |Δt| + |eye|·|ΔA| ≲ 4·2⁻²⁴·(|t| + |eye|) per component.
    M32 = M.astype(np.float32).astype(np.float64)
    eye = eye_from_matrix(M32, up=up)
    assert np.allclose(eye, EYE, rtol=0, atol=4 * 2.0 ** -24 * 2 * np.linalg.norm(EYE))
    # The image is that of an explicit perspective camera at that eye.
    explicit = make_scene(lights, k_a=0.0, k_d=0.7, k_s=0.3, h=40.0,
                          camera=dict(type="perspective", position=tuple(eye)))
    assert np.array_equal(rgb, clphong.Renderer(explicit).render(clphong.read_gbuffer(path)).image)


def test_scene_without_camera_uses_header_and_explains_when_missing(tmp_path):
    rng = np.random.default_rng(5)
    gb = random_gbuffer(rng, 8, 8)
    material = {"model": "phong", "k_a": 0.0, "k_d": 0.5, "k_s": 0.5, "h": 8.0}
    light = [{"type": "point", "position": [0.0, 3.0, 3.0], "intensity": 5.0}]
    scene = clphong.parse_scene({"material": material, "light": light}, "shot.toml")
    assert scene.camera.type == "metadata" and scene.camera.up == "y"
    r = Relighter(scene)
    with_cam = _metadata_frame(tmp_path, "a.exr", look_at_world_to_camera(EYE, (0, 0, 0)), gb)
    assert np.isfinite(r.relight(str(with_cam))).all()
    bare = tmp_path / "bare.exr"
    write_gbuffer(bare, gb.position, gb.normal, gb.albedo)
    with pytest.raises(GBufferError) as info:
        r.relight(str(bare))
    assert str(info.value).startswith(f"{bare}: no worldToCamera attribute, and shot.toml has no [camera]")
    # numpy input passes the matrix explicitly (here as the header stores it, in float32)
    M32 = look_at_world_to_camera(EYE, (0, 0, 0)).astype(np.float32)
    arr = r.relight({"position": gb.position, "normal": gb.normal, "albedo": gb.albedo,
                     "coverage": gb.coverage}, world_to_camera=M32)
    assert np.array_equal(arr, r.relight(str(with_cam)))


def test_scene_camera_up_is_validated():
    with pytest.raises(clphong.SceneError) as info:
        clphong.parse_scene({"camera": {"type": "metadata", "up": "x"},
                             "material": {"model": "phong", "k_a": 0, "k_d": 1, "k_s": 0, "h": 1}}, "s.toml")
    assert str(info.value) == "s.toml: camera.up: invalid value 'x'; expected one of 'y', 'z'"


# ---------------------------------------------------------------- renderer options


def test_renderer_options_are_constructor_arguments_and_part_of_the_spec():
    import pickle

    from clphong.device.renderer import Renderer
    from clphong.pipeline.relighter import RelighterSpec, cached_relighter

    rng = np.random.default_rng(21)
    scene = make_scene(random_lights(rng, n_point=4))
    opts = dict(fp64_directions=False, max_error=1e-3, reference_white=2.0, nonfinite="error")
    r = Relighter(scene, **opts)
    rr = r.renderer
    assert (rr.fp64_directions, rr.max_error, rr.reference_white, rr.nonfinite) == (False, 2e-3, 2.0, "error")
    plan = rr.plan_for(())
    assert plan.defines["DIRECTIONS_FP64"] == 0 and plan.defines["CULLING"] == 1
    assert {k: getattr(r.spec, k) for k in opts} == opts
    # A worker rebuilds an identical relighter from the pickled spec.
    spec = pickle.loads(pickle.dumps(r.spec))
    assert spec == r.spec and hash(spec) == hash(r.spec)
    w = spec.build().renderer
    assert (w.fp64_directions, w.max_error, w.reference_white, w.nonfinite) == (False, 2e-3, 2.0, "error")
    assert w.plan_for(()).defines == plan.defines
    # Same images as a Renderer given the same options directly.
    g = random_gbuffer(rng, 20, 24)
    assert np.array_equal(r.relight(g), Renderer(scene, fp64_directions=False, max_error=1e-3,
                                                 reference_white=2.0, nonfinite="error").render(g).image)
    # The per-process cache keys on the options: another option, another relighter.
    base = RelighterSpec(scene=scene)
    assert cached_relighter(base) is cached_relighter(RelighterSpec(scene=scene))
    for change in (dict(fp64_directions=False), dict(max_error=1e-3), dict(nonfinite="pass"),
                   dict(max_error=1e-3, reference_white=2.0)):
        other = cached_relighter(RelighterSpec(scene=scene, **change))
        assert other is not cached_relighter(base), change
        for k, v in change.items():
            assert getattr(other.spec, k) == v
    assert cached_relighter(RelighterSpec(scene=scene, fp64_directions=False)).renderer.fp64_directions is False


def test_renderer_attributes_still_work_after_construction():
    rng = np.random.default_rng(22)
    scene = make_scene(random_lights(rng, n_point=3))
    g = random_gbuffer(rng, 16, 16)
    poked = Relighter(scene)
    poked.renderer.fp64_directions = False
    poked.renderer.max_error = 1e-3
    built = Relighter(scene, fp64_directions=False, max_error=1e-3)
    assert np.array_equal(poked.relight(g), built.relight(g))
    assert poked.renderer.render(g).plan.defines == built.renderer.render(g).plan.defines


def test_accurate_and_float_paths_differ():
    rng = np.random.default_rng(23)
    scene = make_scene(random_lights(rng, n_point=3))
    g = random_gbuffer(rng, 24, 32)
    accurate, fast = Relighter(scene), Relighter(scene, fp64_directions=False)
    if accurate.renderer.runtime.has_fp64:
        assert accurate.renderer.plan_for(()).defines["DIRECTIONS_FP64"] == 1
        assert not np.array_equal(accurate.relight(g), fast.relight(g))
    assert fast.renderer.plan_for(()).defines["DIRECTIONS_FP64"] == 0


@pytest.mark.parametrize("kwargs, exc, fragment", [
    (dict(max_error=-1.0), "CullingError", "--max-error: expected a finite number ≥ 0"),
    (dict(max_error=float("inf")), "CullingError", "--max-error: expected a finite number ≥ 0"),
    (dict(reference_white=0.0), "CullingError", "--reference-white: expected a finite number > 0, got 0.0"),
    (dict(nonfinite="ignore"), "ValueError", "nonfinite must be one of background, error, pass"),
    (dict(fp64_directions="no"), "ValueError", "fp64_directions must be None, True or False"),
])
def test_bad_renderer_options_fail_before_compiling(kwargs, exc, fragment, monkeypatch):
    import sys

    from clphong.pipeline.relighter import RelighterSpec

    def no_renderer(*a, **k):
        raise AssertionError("a renderer was built before the options were checked")

    patch_everywhere(monkeypatch, sys.modules["clphong.device.renderer"], "Renderer", no_renderer)
    scene = make_scene(random_lights(np.random.default_rng(1), n_point=1))
    for make in (lambda: Relighter(scene, **kwargs), lambda: RelighterSpec(scene=scene, **kwargs)):
        with pytest.raises(Exception) as info:
            make()
        assert type(info.value).__name__ == exc and fragment in str(info.value)
        assert "\n" not in str(info.value)


def test_nonfinite_error_policy_raises_naming_the_buffer():
    rng = np.random.default_rng(24)
    scene = make_scene(random_lights(rng, n_point=2))
    g = random_gbuffer(rng, 16, 16, background_fraction=0.0)
    P = g.position.copy()
    P[2, 3, 0] = np.inf
    frame = {"position": P, "normal": g.normal, "albedo": g.albedo}
    with pytest.raises(GBufferError, match=r"non-finite .*position: 1 pixel\(s\)"):
        Relighter(scene, nonfinite="error").relight(frame)
    with pytest.warns(clphong.core.errors.InputWarning):
        rgb = Relighter(scene).relight(frame)
    assert np.all(np.isfinite(rgb)) and np.all(rgb[2, 3] == 0)


def test_an_environment_resolves_on_each_frames_own_pixels_once(tmp_path, monkeypatch):
    """env_probes="frame" (the default): each frame's environment lights come from its own
    probes, once per frame (kept), and a frame seen from elsewhere converts again; a
    frame with no shaded pixel converts nothing; "all" converts once, at construction.
    (env_path="lights": with tables a frame is resolved each time, its horizon check
    costing less than the frame's hash; tests/device/test_env_table_kernel.py.)"""
    import OpenImageIO as oiio

    import clphong.pipeline.relighter as relighter
    from clphong.io import envmap
    from clphong.tools import samples

    monkeypatch.setattr(envmap, "_CACHE", {})
    from clphong.core.cache import Store
    monkeypatch.setattr(envmap, "_DISK", Store(str(tmp_path / "cache"), ".npz", 8))
    sky = samples.sky_envmap(32, 16)
    out = oiio.ImageOutput.create(str(tmp_path / "sky.exr"))
    out.open(str(tmp_path / "sky.exr"), oiio.ImageSpec(32, 16, 3, oiio.FLOAT))
    out.write_image(sky)
    out.close()
    (tmp_path / "s.toml").write_text(
        '[camera]\ntype = "perspective"\nposition = [0.0, 2.0, 6.0]\n'
        '[material]\nmodel = "phong"\nk_a = 0.0\nk_d = 0.7\nk_s = 0.2\nh = 16.0\n'
        '[[light]]\ntype = "environment"\nfile = "sky.exr"\n')
    calls = record_calls(monkeypatch, relighter, "resolve_environment")
    r = Relighter(tmp_path / "s.toml", env_error=0.02, env_path="lights")
    assert calls == [] and r.environments == ()
    gb = samples.spheres_gbuffer(48, 24)
    first = r.relight(gb)
    assert len(calls) == 1 and r.environments[0][1].count > 0 and np.isfinite(first).all()
    assert np.array_equal(r.relight(gb), first) and len(calls) == 1       # kept
    moved = samples.spheres_gbuffer(48, 24)
    moved.position[...] += np.float32(0.5)                                # other views
    r.relight(moved)
    assert len(calls) == 2
    dark = samples.spheres_gbuffer(48, 24)
    dark.normal[...] = 0.0
    r.relight(dark)
    assert len(calls) == 2
    every = Relighter(tmp_path / "s.toml", env_error=0.02, env_probes="all")
    assert len(calls) == 3 and every.environments[0][1].count > 0
    every.relight(gb)
    assert len(calls) == 3
    with pytest.raises(ValueError, match="env_probes must be one of frame, all"):
        Relighter(tmp_path / "s.toml", env_probes="some")
