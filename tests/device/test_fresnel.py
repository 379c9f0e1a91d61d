"""Schlick's Fresnel weight W(α) in place of C_s (issue 16, the seed's note 2):
the float64 twin against a hand-computed closed form, and the kernel on every path
against the twin and its error bound."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import check_against_reference, heightfield, make_scene, point_lights

from clphong.core.errors import SceneError
from clphong.device.renderer import Renderer
from clphong.reference import shading as reference
from clphong.tools.hardcases import make_gbuffer


def _one_pixel(model, f0, n, l_dir, v_dir, k_s=0.5, h=3.0):
    """One pixel at the origin with normal n, an orthographic viewer along v and one
    directional light from l (all unit): the whole shade is k_d·C·(n·l) + k_s·W·spec."""
    n, l, v = (np.asarray(x, float) / np.linalg.norm(x) for x in (n, l_dir, v_dir))
    scene = make_scene([dict(type="directional", direction=tuple(-l), intensity=1.0)],
                       model=model, k_a=0.0, k_d=0.3, k_s=k_s, h=h, fresnel="schlick", f0=f0,
                       camera=dict(type="orthographic", direction=tuple(-v)))
    gb = make_gbuffer(np.zeros((1, 1, 3)), n.reshape(1, 1, 3), np.ones((1, 1, 3)))
    return scene, gb, n, l, v


@pytest.mark.parametrize("model", ["phong", "blinn-phong"])
def test_reference_is_the_closed_form(model):
    f0 = (0.9, 0.5, 0.02)
    scene, gb, n, l, v = _one_pixel(model, f0, (0.2, 0.1, 1.0), (0.9, 0.0, 0.3), (-0.7, 0.1, 0.4))
    if model == "phong":
        r = 2 * n.dot(l) * n - l
        spec, cos_a = max(r.dot(v), 0.0) ** 3.0, n.dot(v)
    else:
        hv = (l + v) / np.linalg.norm(l + v)
        spec, cos_a = max(n.dot(hv), 0.0) ** 12.0, v.dot(hv)
    W = np.asarray(f0) + (1 - np.asarray(f0)) * (1 - cos_a) ** 5
    want = 0.3 * n.dot(l) + 0.5 * W * spec
    got = reference.shade(scene, gb)[0, 0]
    assert np.allclose(got, want, rtol=1e-6)      # the G-buffer's float32 normal: ~1e-7
    assert abs(W[0] - W[2]) > 0.1                 # a coloured weight, visibly


@pytest.mark.parametrize("kw", [{}, {"fp64_directions": False}, {"lanes": 4}, {"path": "fast"}],
                         ids=["default", "fp32", "lanes4", "fast"])
@pytest.mark.parametrize("model", ["phong", "blinn-phong"])
def test_kernel_within_the_bound_and_the_weight_matters(kw, model):
    rng = np.random.default_rng(3)
    gb = heightfield(rng)
    lights = point_lights(rng, 8, att=(1.0, 0.0, 1.0)) + [
        dict(type="directional", direction=(0.4, 0.3, -0.2), intensity=0.8), dict(type="ambient")]
    cam = dict(type="perspective", position=(2.0, 1.0, 1.2))      # a low, grazing view
    scene = make_scene(lights, model=model, h=12.0, k_s=0.8, fresnel="schlick",
                       f0=(0.9, 0.4, 0.05), camera=cam)
    rgb, _, _, _ = check_against_reference(scene, gb, **kw)
    assert Renderer(scene, **kw).plan_for(()).defines["FRESNEL"] == 1
    plain = make_scene(lights, model=model, h=12.0, k_s=0.8, camera=cam)
    other = Renderer(plain, **kw).render(gb).image
    fg = ~gb.background_mask()
    assert np.abs(other[fg] - rgb[fg]).max() > 1e-2      # W is applied by the kernel


def test_groups_and_specular_layer_carry_the_weight():
    rng = np.random.default_rng(5)
    gb = heightfield(rng)
    lights = point_lights(rng, 6, att=(1.0, 0.0, 1.0))
    for k, lt in enumerate(lights):
        lt["group"] = "a" if k % 2 else "b"
    scene = make_scene(lights + [dict(type="ambient", intensity=0.1)], model="blinn-phong",
                       h=10.0, k_s=0.9, fresnel="schlick", f0=0.2,
                       camera=dict(type="perspective", position=(2.0, 1.0, 1.5)))
    res = Renderer(scene, aovs=("specular",)).render(gb)
    spec_only = make_scene(lights, model="blinn-phong", h=10.0, k_a=0.0, k_d=0.0, k_s=0.9,
                           fresnel="schlick", f0=0.2, camera=dict(type="perspective", position=(2.0, 1.0, 1.5)))
    want = reference.shade(spec_only, gb)
    bound, _ = reference.error_bound(spec_only, gb, plan=res.plan)
    assert np.all(np.abs(res.layers["specular"].astype(np.float64) - want) <= bound)
    fg = ~gb.background_mask()
    total = sum(res.layers[g].astype(np.float64) for g in scene.light_groups)
    assert np.allclose(total[fg], res.image[fg], rtol=1e-5, atol=1e-6)


def test_obvious_kernel_refuses_fresnel():
    scene, gb, *_ = _one_pixel("phong", 0.04, (0, 0, 1), (0, 0.3, 1), (0, 0, 1))
    with pytest.raises(SceneError, match="material.fresnel: the obvious kernel"):
        Renderer(scene, kernel="obvious").render(gb)
