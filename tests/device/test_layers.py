"""Light groups, diffuse/specular layers and coverage from one shading pass, each held
against the float64 reference of the same sub-scene and its error bound."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import heightfield, point_lights

from clphong.core.errors import SceneError
from clphong.device.renderer import Renderer
from clphong.model.scene import parse_scene
from clphong.reference import shading as reference


def _scene(lights, *, k_a=0.1, k_d=0.6, k_s=0.3, model="phong"):
    data = {"camera": {"type": "perspective", "position": [2.0, 1.5, 6.0]},
            "material": {"model": model, "k_a": k_a, "k_d": k_d, "k_s": k_s, "h": 24.0},
            "light": lights}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(data, source="layers.toml")


def _grouped_lights(rng, n=9):
    lights = point_lights(rng, n, att=(0.0, 0.0, 1.0))
    for k, lt in enumerate(lights):
        if k % 3:
            lt["group"] = ("key", "rim")[k % 3 - 1]      # every third light ungrouped: "default"
    lights.append(dict(type="directional", direction=(-0.3, -0.2, -1.0), intensity=0.7, group="rim"))
    lights.append(dict(type="directional", direction=(0.5, 0.1, -1.0), intensity=0.4))
    lights.append(dict(type="ambient", intensity=0.5, group="key"))
    lights.append(dict(type="ambient", intensity=0.2))
    return lights


def _sub(scene_data_lights, keep, **material):
    return _scene([lt for lt in scene_data_lights if keep(lt)], **material)


def _within(got, scene, gb, plan):
    want = reference.shade(scene, gb)
    bound, _ = reference.error_bound(scene, gb, plan=plan)
    err = np.abs(got.astype(np.float64) - want)
    assert np.all(err <= bound), f"max err/bound {np.max(err / np.maximum(bound, 1e-300)):.3g}"
    return want, bound


@pytest.mark.parametrize("path", [None, "float", "fast"])
@pytest.mark.parametrize("partial", [False, True], ids=["opaque", "partial-coverage"])
def test_each_group_is_its_sub_scene_and_they_sum_to_the_beauty(path, partial, device):
    rng = np.random.default_rng(21)
    gb = heightfield(rng, 40, 48)
    if partial:
        gb.coverage[:] = np.where(gb.coverage > 0, rng.uniform(0.05, 1.0, gb.coverage.shape), 0)
    lights = _grouped_lights(rng)
    scene = _scene(lights)
    assert scene.light_groups == ("default", "key", "rim")
    res = Renderer(scene, path=path, device=device).render(gb)
    assert tuple(res.layers) == ("default", "key", "rim")
    _, beauty_bound = _within(res.image, scene, gb, res.plan)
    total_bound = beauty_bound.copy()
    for g in scene.light_groups:
        sub = _sub(lights, lambda lt: lt.get("group", "default") == g)
        # a layer has no background: the sub-scene's reference with background 0 (the default)
        _, b = _within(res.layers[g], sub, gb, res.plan)
        total_bound += b
    total = sum(res.layers[g].astype(np.float64) for g in scene.light_groups)
    background = gb.background_mask()
    assert np.all(np.abs(total - res.image)[~background] <= total_bound[~background])


@pytest.mark.parametrize("model", ["phong", "blinn-phong"])
def test_diffuse_and_specular_layers_are_their_terms(model, device):
    rng = np.random.default_rng(8)
    gb = heightfield(rng, 32, 40)
    lights = point_lights(rng, 5) + [dict(type="ambient", intensity=0.3)]
    scene = _scene(lights, model=model)
    plain = Renderer(scene, device=device).render(gb)
    res = Renderer(scene, aovs=("diffuse", "specular"), device=device).render(gb)
    assert np.array_equal(res.image, plain.image)        # the beauty's arithmetic is unchanged
    _within(res.layers["diffuse"], _scene(lights, k_s=0.0, model=model), gb, res.plan)
    _within(res.layers["specular"], _scene(lights, k_a=0.0, k_d=0.0, model=model), gb, res.plan)
    assert np.abs(res.layers["diffuse"] + res.layers["specular"] - res.image).max() \
        <= 4 * np.finfo(np.float32).eps * np.abs(res.image).max()


def test_groups_with_culling_stay_within_the_budget():
    rng = np.random.default_rng(4)
    gb = heightfield(rng, 64, 64, bumps=0.1)
    lights = [dict(type="point", position=(float(rng.uniform(0, 6.4)), float(rng.uniform(0, 6.4)),
                                           float(rng.uniform(0.05, 0.3))),
                   intensity=float(rng.uniform(0.001, 0.01)), attenuation=(0.0, 0.0, 1.0),
                   group=("a", "b", "c")[k % 3]) for k in range(48)]
    scene = _scene(lights, k_a=0.0)
    eps = 1e-3
    full = Renderer(scene).render(gb)
    culled = Renderer(scene, max_error=eps).render(gb)
    assert culled.cull is not None and culled.cull.kept_fraction < 0.9
    for g in scene.light_groups:        # dropped lights of a group are dropped from the beauty too
        assert np.abs(culled.layers[g].astype(np.float64) - full.layers[g]).max() <= eps + 1e-6


def test_banded_layers_equal_one_launch():
    rng = np.random.default_rng(2)
    gb = heightfield(rng, 300, 40)
    scene = _scene(_grouped_lights(rng))
    r = Renderer(scene, aovs="diffuse,specular")
    one, banded = r.render(gb), r.render(gb, rows=128)
    assert banded.bands > 1
    for name in one.layers:
        assert np.array_equal(one.layers[name], banded.layers[name]), name


def test_aov_names_are_checked():
    rng = np.random.default_rng(1)
    scene = _scene(_grouped_lights(rng))
    with pytest.raises(SceneError, match=r"--aov 'keys' is neither a component \(diffuse, specular\) "
                                         r"nor a light group \(light groups default, key, rim\)"):
        Renderer(scene, aovs=("keys",))
    # naming a group keeps only its layer; the beauty still has every light
    rng = np.random.default_rng(1)
    gb = heightfield(rng, 24, 30)
    chosen = Renderer(scene, aovs=("rim",)).render(gb)
    assert tuple(chosen.layers) == ("rim",)
    every = Renderer(scene).render(gb)
    assert np.array_equal(chosen.image, every.image)
    assert np.array_equal(chosen.layers["rim"], every.layers["rim"])
    with pytest.raises(SceneError, match="the obvious kernel shades the beauty only"):
        Renderer(scene, kernel="obvious")
