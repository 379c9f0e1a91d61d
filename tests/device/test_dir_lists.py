"""Per-tile lists of directional lights (DIR_CULLING, kernels/cull.cl dir_count).

A tile keeps a directional light unless the kernel's n·l is ≤ 0 at each of its
pixels, where the light adds exactly 0. So the lists change no pixel: the claim
under test is bit-identity with the loop over every light, on scenes with many
directional lights from every side (an environment's), and that they do drop the
lights behind a tile's surface.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GBUFFERS, heightfield, make_scene, point_lights

from clphong.device import plan as plan_module
from clphong.device.renderer import Renderer


def sphere_lights(rng, n, intensity=0.02):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return [dict(type="directional", direction=tuple(x), color=tuple(rng.uniform(0.3, 1, 3)),
                 intensity=intensity) for x in d]


def both(scene, gb, monkeypatch, **kw):
    """(with the lists, without them): the same renderer options, DIR_CULL_MIN moved."""
    listed = Renderer(scene, **kw).render(gb)
    monkeypatch.setattr(plan_module, "DIR_CULL_MIN", 10 ** 9)
    plain = Renderer(scene, **kw).render(gb)
    monkeypatch.undo()
    assert listed.plan.defines["DIR_CULLING"] == 1 and plain.plan.defines["DIR_CULLING"] == 0
    return listed, plain


@pytest.mark.parametrize("model,path", [("phong", None), ("blinn-phong", None),
                                        ("phong", "fast"), ("blinn-phong", "float")])
def test_lists_change_no_pixel(model, path, monkeypatch):
    rng = np.random.default_rng(4)
    gb = heightfield(rng, 45, 70, bumps=0.2)
    lights = sphere_lights(rng, 300) + point_lights(rng, 5)
    scene = make_scene(lights, model=model, h=20.0,
                       camera=dict(type="perspective", position=(2.0, 1.5, 4.0)))
    listed, plain = both(scene, gb, monkeypatch, path=path)
    assert np.array_equal(listed.image, plain.image)
    d = listed.dir_lists
    assert d is not None and 0.3 < d.kept_fraction < 0.8     # about the lights above the surface


def test_lists_with_culled_points_and_layers(monkeypatch):
    """Point-light culling and AOV layers beside the directional lists: still bit-identical."""
    rng = np.random.default_rng(9)
    gb = heightfield(rng, 40, 50)
    scene = make_scene(sphere_lights(rng, 100) + point_lights(rng, 40), model="phong", h=12.0)
    listed, plain = both(scene, gb, monkeypatch, max_error=1e-3, aovs=("diffuse", "specular"))
    assert np.array_equal(listed.image, plain.image)
    for k in listed.layers:
        assert np.array_equal(listed.layers[k], plain.layers[k])


def test_few_directional_lights_take_no_lists():
    rng = np.random.default_rng(1)
    few = make_scene(sphere_lights(rng, 3), model="phong", h=10.0)
    p = Renderer(few).plan_for(())
    assert p.defines["DIR_CULLING"] == 0 and "fewer than 64" in str(p)


def test_light_groups_walk_their_part_of_the_lists(monkeypatch):
    """A sky group of directional lights, listed between a key group's: the beauty and
    every group layer equal the loop's."""
    rng = np.random.default_rng(12)
    gb = heightfield(rng, 40, 44, bumps=0.2)
    sky = sphere_lights(rng, 90)
    lights = ([dict(lt, group="key") for lt in sphere_lights(rng, 40)]
              + [dict(lt, group="sky") for lt in sky]
              + [dict(lt, group="key") for lt in point_lights(rng, 6)]
              + [dict(lt, group="rim") for lt in sphere_lights(rng, 30)])
    scene = make_scene(lights, model="blinn-phong", h=12.0)
    listed, plain = both(scene, gb, monkeypatch, aovs=("key", "sky", "rim"))
    assert np.array_equal(listed.image, plain.image)
    assert set(listed.layers) == {"key", "sky", "rim"}
    for k in listed.layers:
        assert np.array_equal(listed.layers[k], plain.layers[k]), k


def test_the_sample_environment_is_unchanged(monkeypatch):
    """The shipped sky as directional lights (gbuffers/spheres_sky.toml) on the spheres."""
    from clphong.io.envmap import resolve_environment
    from clphong.io.gbuffer import read_gbuffer
    from clphong.model.scene import load_scene

    scene = resolve_environment(load_scene(str(GBUFFERS / "spheres_sky.toml")),
                                max_error=1e-2).scene
    gb = read_gbuffer(str(GBUFFERS / "spheres.exr"))
    listed, plain = both(scene, gb, monkeypatch)
    assert np.array_equal(listed.image, plain.image)
    assert listed.dir_lists.kept_fraction < 0.9


def test_render_stats_say_what_the_lists_keep(tmp_path, capsys):
    from clphong.console.cli import main

    args = ["render", str(GBUFFERS / "spheres_sky.toml"), str(GBUFFERS / "spheres.exr"),
            "-o", str(tmp_path / "o.exr"), "--env-error", "1e-2", "--stats", "--env-path", "lights"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "-DDIR_CULLING=1" in err and "directional lists:" in err and "face away" in err


def test_lights_grazing_a_flat_tile_are_kept(monkeypatch):
    """Normals exactly +z and lights within 1e-7 of the tangent plane, on both sides: the
    kernel's n·l is l_z, so those above must be kept (the bound's margin, not its sign,
    decides), and the image is the loop's."""
    from conftest import make_gbuffer

    P = np.zeros((20, 40, 3))
    P[..., 0] = np.arange(40) * 0.1
    P[..., 1] = np.arange(20)[:, None] * 0.1
    gb = make_gbuffer(P, np.broadcast_to([0.0, 0.0, 1.0], P.shape), np.full(P.shape, 0.5))
    rng = np.random.default_rng(2)
    lights = []
    for z in np.linspace(-1e-7, 1e-7, 80):
        a = rng.uniform(0, 2 * np.pi)
        lights.append(dict(type="directional", direction=(-np.cos(a), -np.sin(a), -z),
                           intensity=1.0))
    scene = make_scene(lights, model="phong", h=5.0, k_a=0.0,
                       camera=dict(type="perspective", position=(2.0, 1.0, 3.0)))
    for path in (None, "float"):
        listed, plain = both(scene, gb, monkeypatch, path=path)
        assert np.array_equal(listed.image, plain.image)
        assert listed.dir_lists.kept_fraction == 1.0      # within the margin: all kept


@pytest.mark.parametrize("case", ["ortho_blinn_fresnel", "lanes4_bands", "coverage"])
def test_other_variants_change_no_pixel(case, monkeypatch):
    rng = np.random.default_rng(6)
    gb = heightfield(rng, 37, 53, bumps=0.15)
    kw, scene_kw = {}, dict(camera=dict(type="perspective", position=(2.0, 1.5, 4.0)))
    if case == "ortho_blinn_fresnel":
        scene_kw = dict(camera=dict(type="orthographic", direction=(0.0, 0.0, -1.0)),
                        model="blinn-phong", fresnel="schlick", f0=0.04)
    elif case == "lanes4_bands":
        kw = dict(lanes=4)
    scene = make_scene(sphere_lights(rng, 120), h=16.0, **{"model": "phong", **scene_kw})
    if case == "lanes4_bands":
        listed = Renderer(scene, **kw).render(gb, rows=9)
        monkeypatch.setattr(plan_module, "DIR_CULL_MIN", 10 ** 9)
        plain = Renderer(scene, **kw).render(gb, rows=9)
        assert listed.bands > 1 and listed.plan.defines["DIR_CULLING"] == 1
    else:
        if case != "coverage":
            gb.coverage[...] = 1.0
        listed, plain = both(scene, gb, monkeypatch, **kw)
    assert np.array_equal(listed.image, plain.image)


def test_nonfinite_inputs_keep_every_light(monkeypatch):
    """--nonfinite pass: a NaN k_d times a light facing away is NaN in the loop over every
    light. Under lights from below only, an upward tile's list is empty, yet the tile
    holding the NaN keeps every light, so the lists give the loop's NaN there (and the
    other tiles' pixels are unchanged)."""
    rng = np.random.default_rng(3)
    gb = heightfield(rng, 32, 48, bumps=0.05, maps=("k_d",))
    gb.maps["k_d"][5, 9] = np.nan
    below = [dict(lt, direction=(lt["direction"][0], lt["direction"][1],
                                 abs(lt["direction"][2]) + 0.2)) for lt in sphere_lights(rng, 100)]
    scene = make_scene(below + [dict(type="ambient", intensity=0.1)], model="phong", h=10.0,
                       k_a=0.2)
    with pytest.warns(UserWarning, match="non-finite"):
        listed, plain = both(scene, gb, monkeypatch, nonfinite="pass")
    assert np.isnan(plain.image[5, 9]).any()
    assert np.array_equal(listed.image, plain.image, equal_nan=True)


def test_lists_too_long_fall_back_to_the_loop(monkeypatch):
    from clphong.device import culling

    rng = np.random.default_rng(5)
    gb = heightfield(rng, 30, 40)
    scene = make_scene(sphere_lights(rng, 100), model="phong", h=10.0)
    plain = Renderer(scene).render(gb)
    monkeypatch.setattr(culling, "MAX_LIST_ENTRIES", 10)
    r = Renderer(scene)
    result = r.render(gb)
    assert result.plan.defines["DIR_CULLING"] == 0 and result.dir_lists is None
    assert "MAX_LIST_ENTRIES" in str(result.plan)
    assert np.array_equal(result.image, plain.image)
