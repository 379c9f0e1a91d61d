"""An environment shaded from the kernels' tables (ENV_TABLE, kernels/include/envtable.h):
against its float64 twin (clphong.reference.environment.table_terms), against the exact
texel sum, in every layer, and which frames take it (clphong.io.envmap)."""

import dataclasses

import numpy as np
import pytest
from conftest import GBUFFERS, heightfield, make_scene, skip_unless_lanes

from clphong.device.renderer import Renderer, prepare_frame
from clphong.io import envmap
from clphong.io.gbuffer import read_gbuffer
from clphong.model.env_table import environment_tables
from clphong.model.scene import directional_lights, load_scene
from clphong.pipeline.relighter import Relighter
from clphong.pipeline.relighter import render as api_render
from clphong.reference.environment import environment_texel_sum, table_terms
from clphong.tools.samples import sky_envmap

U = 2.0 ** -24
CAMERA = {"type": "perspective", "position": (2.2, 1.8, 4.0)}


def _sky(w=256, h=128):
    return np.asarray(sky_envmap(w, h), np.float32)


def _scene(tables, group=None, **material):
    scene = make_scene((), camera=CAMERA, **material)
    suns = directional_lights(tables.sun_l, tables.sun_radiance, group)
    return dataclasses.replace(scene, lights=tuple(suns), env_tables=((tables, group),))


def _kernel_tolerance(tables, ref):
    """The float32 kernel against the float64 twin, per value: the table's rounding and the
    cubic's 16 weighted terms (≤ 64u of the value: the weights' magnitudes sum to at most
    1.6), plus the look-up positions' rounding: atan2 to a few ulp of an angle up to π,
    scaled to table units, ≤ 8u·(rows + cols) units, times the table's largest relative
    step between neighbouring nodes (its slope per unit)."""
    slope = 0.0
    for t in (tables.diffuse, tables.specular):
        v = t.values[..., 0]
        for a, b in ((v[1:], v[:-1]), (v[:, 1:], v[:, :-1])):
            slope = max(slope, float(np.max(np.abs(a - b) / np.maximum(np.minimum(a, b), 1e-30))))
        units = 8 * U * (t.rows + t.cols)
    return (64 * U + slope * units) * np.abs(ref)


@pytest.mark.parametrize("lanes", [None, 1])
def test_the_kernel_is_its_float64_twin(device, lanes):
    """Maps, Fresnel, a rotated and dimmed map, a coloured specular: every pixel within
    the float32 error model of the twin, on every device and width."""
    skip_unless_lanes(lanes, device)
    rng = np.random.default_rng(1)
    g = heightfield(rng, 23, 37, maps=("k_d", "k_s", "specular_color"))
    scene = make_scene((), camera=CAMERA, fresnel="schlick", f0=0.04,
                       specular_color=(1.0, 0.8, 0.6))
    t = environment_tables(_sky(), scene.material, rotation=35.0, intensity=0.7,
                           max_error=1e-3)
    scene = dataclasses.replace(scene, lights=tuple(directional_lights(
        t.sun_l, t.sun_radiance)), env_tables=((t, None),))
    r = Renderer(scene, device=device, lanes=lanes)
    assert r.plan_for(tuple(g.maps)).defines["ENV_TABLE"] == 1
    img = r.shade(prepare_frame(g, lanes=r.lanes)).image.reshape(-1, 3).astype(np.float64)
    fg = ~g.background_mask().reshape(-1)
    d, s = table_terms(scene, g, t)
    ref = d + s + scene.material.k_a * 0                         # no ambient light
    err = np.abs(img[fg] - ref)
    tol = _kernel_tolerance(t, ref)
    assert np.all(err <= tol), float(np.max(err / np.maximum(tol, 1e-300)))
    assert np.all(img[~fg] == 0)                                  # background


def test_a_frame_of_tables_is_within_env_error_of_the_exact_texel_sum():
    """The whole path (API render: the frame's check, the tables, the sun as lights) on a
    heightfield, against every texel as a directional light, float64."""
    rng = np.random.default_rng(2)
    g = heightfield(rng, 31, 41)
    sky = _sky(512, 256)
    scene = make_scene((), camera=CAMERA, k_a=0.0)
    for eps in (1e-3, 1e-2):
        t = environment_tables(sky, scene.material, max_error=eps)
        img = Renderer(_scene(t), device=None).render(g).image.reshape(-1, 3).astype(np.float64)
        exact = environment_texel_sum(scene, g, sky)
        fg = ~g.background_mask().reshape(-1)
        rel = np.abs(img[fg] - exact[fg]) / exact[fg]
        assert rel.max() <= eps, (eps, rel.max())
        assert rel.max() > 1e-7            # the tables' own error shows: not the lights' path


def test_layers_and_groups_hold_the_tables():
    """The diffuse and specular layers sum to the beauty; a group holding the environment
    is the beauty less the other group's light."""
    rng = np.random.default_rng(3)
    g = heightfield(rng, 19, 29)
    base = make_scene((), camera=CAMERA, k_a=0.0)
    t = environment_tables(_sky(), base.material, max_error=1e-2)
    scene = _scene(t, group="sky")
    lamp = make_scene([dict(type="point", position=(1.0, 1.0, 2.0), intensity=3.0,
                            group="lamp")]).lights
    scene = dataclasses.replace(scene, lights=scene.lights + lamp)
    r = Renderer(scene, device=None, aovs=("diffuse", "specular", "sky", "lamp"))
    assert r.plan_for(()).defines["ENV_GROUP"] == r.scene.light_groups.index("sky")
    res = r.render(g)
    L = res.layers
    beauty = res.image.astype(np.float64)
    assert np.allclose(L["diffuse"] + L["specular"], beauty, rtol=1e-5, atol=1e-7)
    assert np.allclose(L["sky"] + L["lamp"], beauty, rtol=1e-5, atol=1e-7)
    alone = Renderer(_scene(t), device=None).render(g).image
    assert np.allclose(L["sky"], alone, rtol=1e-6, atol=1e-8)


def test_a_nan_normal_passed_through_reads_inside_the_table():
    """A NaN normal under --nonfinite pass: the look-up's positions are clamped into the
    table (no read outside it), and the pixel is what the lights' path makes of it."""
    rng = np.random.default_rng(4)
    g = heightfield(rng, 16, 16)
    N = np.array(g.normal)
    cov = np.asarray(g.coverage)
    y, x = np.argwhere(cov > 0)[7]
    N[y, x] = np.nan
    g = dataclasses.replace(g, normal=N)
    base = make_scene((), camera=CAMERA)
    t = environment_tables(_sky(), base.material, max_error=1e-2)
    img = Renderer(_scene(t), device=None, nonfinite="pass").render(g).image
    lit = dataclasses.replace(_scene(t), env_tables=())
    ref = Renderer(lit, device=None, nonfinite="pass").render(g).image
    assert np.array_equal(np.isnan(img), np.isnan(ref))
    others = np.ones(cov.shape, bool)
    others[y, x] = False
    assert np.isfinite(img[others]).all()


# ------------------------------------------------------------------ which frames take it


def _sky_scene(tmp_path, model="phong"):
    text = (GBUFFERS / "spheres_sky.toml").read_text().replace('file = "sky.exr"',
                                                                f'file = "{GBUFFERS / "sky.exr"}"')
    text = text.replace('model = "phong"', f'model = "{model}"')
    (tmp_path / "s.toml").write_text(text)
    return load_scene(tmp_path / "s.toml")


def test_the_spheres_rims_take_lights_and_a_plane_takes_tables(tmp_path):
    """The spheres' rims reflect grazing views: their lobes below the horizon may exceed the
    budget, so that frame takes lights and says why; a heightfield seen from above takes
    the tables."""
    scene = _sky_scene(tmp_path)
    r = Relighter(scene, device=None)
    spheres = read_gbuffer(GBUFFERS / "spheres.exr")
    r.renderer_for(spheres)
    (i, path, why), = r.env_paths
    assert path == "lights" and "horizon" in why and r.environments and not r.env_tables
    plane = heightfield(np.random.default_rng(5), 24, 32)
    view = r.renderer_for(plane)
    (i, path, why), = r.env_paths
    assert path == "tables" and r.env_tables and view.scene.env_tables
    assert view.plan_for(()).defines["ENV_TABLE"] == 1


@pytest.mark.parametrize("case", ["blinn", "lights", "obvious", "all"])
def test_what_keeps_the_lights_path(tmp_path, case):
    scene = _sky_scene(tmp_path, "blinn-phong" if case == "blinn" else "phong")
    kw = {"lights": dict(env_path="lights"), "obvious": dict(kernel="obvious"),
          "all": dict(env_probes="all")}.get(case, {})
    r = Relighter(scene, device=None, **kw)
    plane = heightfield(np.random.default_rng(5), 24, 32)
    view = r.renderer_for(plane)
    assert not view.scene.env_tables
    if case != "all":
        (_, path, why), = r.env_paths
        assert path == "lights"
        assert {"blinn": "Blinn-Phong", "lights": "not asked", "obvious": "not asked"}[case] in why


def test_the_api_render_takes_the_tables(tmp_path):
    scene = _sky_scene(tmp_path)
    plane = heightfield(np.random.default_rng(6), 20, 20)
    a = api_render(scene, plane, device=None)
    b = api_render(scene, plane, device=None, env_path="lights")
    fg = ~plane.background_mask()
    rel = np.abs(a[fg] - b[fg]) / b[fg]
    assert 0 < rel.max() <= 2e-3             # two paths, each within 1e-3 of the exact sum


def test_tables_are_kept_on_disk_and_a_second_process_builds_none(tmp_path, monkeypatch):
    from clphong.core.cache import Store

    store = Store(str(tmp_path / "tables"), ".npz", 3)
    monkeypatch.setattr(envmap, "_TABLE_DISK", store)
    monkeypatch.setattr(envmap, "_TABLES", {})
    scene = _sky_scene(tmp_path)
    lt = scene.lights[0]
    first = envmap._tables(lt, "light[0]", scene.material, 1e-3)
    assert first.seconds > 0 and len(list(store.folder.glob("*.npz"))) == 1
    monkeypatch.setattr(envmap, "_TABLES", {})

    def built(*a, **k):
        raise AssertionError("built again")

    monkeypatch.setattr(envmap._env_table, "environment_tables", built)
    again = envmap._tables(lt, "light[0]", scene.material, 1e-3)
    assert again.seconds == 0 and again.estimate == first.estimate
    for name in ("sun_l", "sun_radiance", "power", "radiance_max", "lune", "diffuse_floor"):
        assert np.array_equal(getattr(again, name), getattr(first, name)), name
    assert np.array_equal(again.diffuse.values, first.diffuse.values)
    assert np.array_equal(again.specular.values, first.specular.values)
    # a damaged file only builds again
    for f in store.folder.glob("*.npz"):
        f.write_bytes(b"not a zip")
    monkeypatch.setattr(envmap, "_TABLES", {})
    with pytest.raises(AssertionError, match="built again"):
        envmap._tables(lt, "light[0]", scene.material, 1e-3)


def test_pixels_the_bound_misses_take_lights_in_a_second_launch(tmp_path, monkeypatch):
    """Spheres under the sky, every share of misses allowed: the rims take the environment's
    directional lights (estimated on them), the rest the tables; the frame, in every
    layer, is within --env-error of the exact texel sum on the pixels of both kinds."""
    from clphong.reference.environment import texel_sum
    from clphong.tools import samples

    monkeypatch.setattr(envmap, "MIXED_SHARE", 1.0)
    scene = _sky_scene(tmp_path)
    g = samples.spheres_gbuffer(96, 64)
    r = Relighter(scene, device=None, aovs=("diffuse", "specular"))
    view = r.renderer_for(g)
    (_, path, why), = r.env_paths
    assert path == "tables" and "directional lights there" in why
    other, miss = view._fallback
    fg = np.flatnonzero(~g.background_mask().reshape(-1))
    assert 0 < len(miss) < len(fg) and not other.scene.env_tables
    res = view.render(g)
    beauty = res.image.reshape(-1, 3).astype(np.float64)
    L = res.layers
    assert np.allclose((L["diffuse"] + L["specular"]).reshape(-1, 3), beauty, rtol=1e-5, atol=1e-7)
    rng = np.random.default_rng(0)
    kept = np.setdiff1d(fg, miss)
    idx = np.concatenate([rng.choice(miss, 150, replace=False), rng.choice(kept, 150, replace=False)])
    exact = texel_sum(scene, g.pixels(idx)).reshape(-1, 3)
    big = exact >= 1e-3 * exact.max()
    rel = np.abs(beauty[idx] - exact)[big] / exact[big]
    assert rel.max() <= 1e-3, rel.max()
    # without the second launch the rims are the tables' alone: they differ there only
    plain = Renderer(view.scene, device=None).render(g).image.reshape(-1, 3)
    assert np.array_equal(plain[kept], beauty[kept].astype(np.float32))
    assert not np.array_equal(plain[miss], beauty[miss].astype(np.float32))


def test_a_k_s_map_over_k_s_0_takes_lights_and_the_plan_refuses_what_tables_cannot_hold(tmp_path):
    from clphong.core.errors import SceneError
    from clphong.device.plan import make_plan

    text = (GBUFFERS / "spheres_sky.toml").read_text().replace(
        'file = "sky.exr"', f'file = "{GBUFFERS / "sky.exr"}"').replace("k_s = 0.2", "k_s = 0.0")
    (tmp_path / "s.toml").write_text(text)
    scene = load_scene(tmp_path / "s.toml")
    plane = heightfield(np.random.default_rng(7), 16, 20, maps=("k_s",))
    r = Relighter(scene, device=None)
    view = r.renderer_for(plane)
    (_, path, why), = r.env_paths
    assert path == "lights" and "k_s map" in why and not view.scene.env_tables
    assert np.isfinite(view.render(plane).image).all()
    t = environment_tables(_sky(), make_scene(()).material, max_error=1e-2)
    blinn = _scene(t, model="blinn-phong")
    with pytest.raises(SceneError, match="tables hold the Phong lobe"):
        make_plan(blinn, ())
    with pytest.raises(SceneError, match="tables hold the Phong lobe"):
        make_plan(_scene(t), ("h",))


def test_the_horizon_check_sees_the_albedo_the_kernels_shade(tmp_path, monkeypatch):
    """With an albedo_space, the frame is resolved on its albedo in the working space (as
    render_outputs converts it before shading), not on the stored values."""
    from clphong.deliver.outputs import OutputOptions

    import clphong.pipeline.relighter as relighter

    scene = _sky_scene(tmp_path)
    plane = heightfield(np.random.default_rng(8), 16, 20)
    real, seen_pairs = relighter.resolve_environment, []

    def spy(*a, **kw):
        seen_pairs.append(kw["pairs"])
        return real(*a, **kw)

    monkeypatch.setattr(relighter, "resolve_environment", spy)
    r = Relighter(scene, device=None,
                  output=OutputOptions(albedo_space="sRGB Encoded Rec.709 (sRGB)"))
    r.renderer_for(plane)
    seen = seen_pairs[-1].gbuffer.albedo
    assert seen.shape == plane.albedo.shape and np.all(seen <= plane.albedo + 1e-7)
    assert np.mean(seen) < 0.8 * np.mean(plane.albedo)        # sRGB-encoded: darker in linear
