"""clphong.reference.environment (the exact texel sum, two ways the same); named
test_texel_sum.py as test modules need distinct names (tests/model/test_environment.py).

Tolerances: the fast and the reference methods are both float64 sums of the
same terms in different orders: 1e-12 relative. Closed forms of the continuous
sphere hold for the texel sum to its discretisation (measured 2.4e-5 for the
diffuse term at 256 x 128, tests/model/test_environment.py), so 1e-4 here.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from clphong.io.atomic import write_exr
from clphong.io.gbuffer import GBuffer
from clphong.model.scene import Camera, Light, Material, Scene
from clphong.reference import environment as renv
from clphong.reference import shading
from clphong.tools import samples


def _gbuffer(M=60, seed=2, maps=None, coverage=None):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(M, 3))
    P = rng.normal(size=(M, 3)) * 0.5
    C = rng.uniform(0.1, 0.9, (M, 3))
    cov = np.ones(M) if coverage is None else coverage
    return GBuffer(position=P.astype(np.float32)[None], normal=n.astype(np.float32)[None],
                   albedo=C.astype(np.float32)[None], coverage=cov.astype(np.float32)[None],
                   maps=maps or {})


def _scene(tmp_path, material, rgb, *, rotation=15.0, intensity=0.7, extra=()):
    p = tmp_path / "sky.exr"
    write_exr(p, rgb)
    env = Light(type="environment", intensity=intensity, file=str(p), rotation=rotation)
    return Scene(camera=Camera(type="perspective", position=(0.3, 1.0, 4.0)), material=material,
                 lights=(*extra, env), source="t.toml")


PHONG = Material(model="phong", k_a=0.1, k_d=0.7, k_s=0.2, h=32.0)
BLINN = Material(model="blinn-phong", k_a=0.1, k_d=0.7, k_s=0.2, h=32.0)


@pytest.mark.parametrize("material", [PHONG, BLINN, dataclasses.replace(BLINN, k_s=0.0)])
def test_fast_sum_is_the_reference_sum(tmp_path, material):
    amb = Light(type="ambient", intensity=0.4)
    point = Light(type="point", position=(1.0, 2.0, 1.0), intensity=2.0)
    scene = _scene(tmp_path, material, samples.sky_envmap(32, 16), extra=(amb, point))
    gb = _gbuffer(maps={"k_d": np.linspace(0.2, 1, 60, dtype=np.float32)[None]})
    fast = renv.texel_sum(scene, gb, method="fast")
    ref = renv.texel_sum(scene, gb, method="reference")
    assert np.allclose(fast, ref, rtol=1e-12, atol=1e-15)
    # and the environment is there: not the scene without it
    rest = shading.shade(renv.without_environment(scene), gb)
    assert (np.abs(fast - rest) > 1e-3).any()


def test_fresnel_and_shininess_maps_take_the_reference_method(tmp_path):
    m = dataclasses.replace(BLINN, fresnel="schlick", f0=(0.04, 0.04, 0.04))
    scene = _scene(tmp_path, m, samples.sky_envmap(16, 8))
    gb = _gbuffer(M=10)
    with pytest.raises(ValueError, match="reference"):
        renv.texel_sum(scene, gb, method="fast")
    assert np.allclose(renv.texel_sum(scene, gb), renv.texel_sum(scene, gb, method="reference"))
    gbh = _gbuffer(M=10, maps={"h": np.full((1, 10), 8.0, np.float32)})
    with pytest.raises(ValueError):
        renv.texel_sum(_scene(tmp_path, PHONG, samples.sky_envmap(16, 8)), gbh, method="fast")
    with pytest.raises(ValueError, match="method"):
        renv.texel_sum(scene, gb, method="exact")


def test_every_texel_is_a_directional_light(tmp_path):
    """A 4 x 2 map by hand: its 8 texels as directional lights of OpenEXR's directions
    (poles, meridians ±π, 0 ... here with rotation 0) and solid angles, shaded by the
    reference, are the texel sum."""
    from clphong.model.environment import texel_directions, texel_solid_angles

    rng = np.random.default_rng(5)
    L = rng.uniform(0, 2, (2, 4, 3)).astype(np.float32)
    scene = _scene(tmp_path, PHONG, L, rotation=0.0, intensity=1.0)
    d = texel_directions(4, 2).reshape(-1, 3)
    om = texel_solid_angles(4, 2).reshape(-1)
    lights = tuple(Light(type="directional", color=tuple(map(float, L.reshape(-1, 3)[t] * om[t])),
                         direction=tuple(map(float, -d[t]))) for t in range(8) if om[t] > 0)
    gb = _gbuffer(M=20)
    by_hand = shading.shade(dataclasses.replace(scene, lights=lights), gb)
    assert np.allclose(renv.texel_sum(scene, gb), by_hand, rtol=1e-12, atol=1e-15)


def test_constant_sky_gives_pi_radiance_of_diffuse(tmp_path):
    """Constant radiance L0, k_s = 0, k_a = 0: every shaded pixel is C·k_d·π·L0·intensity
    (∫max(n·l, 0)dω = π; the model has no 1/π), to the texel sum's discretisation."""
    m = dataclasses.replace(PHONG, k_s=0.0, k_a=0.0)
    scene = _scene(tmp_path, m, np.full((128, 256, 3), 0.5, np.float32), intensity=0.7)
    gb = _gbuffer(M=50)
    got = renv.texel_sum(scene, gb).reshape(-1, 3)
    C = gb.albedo.reshape(-1, 3).astype(np.float64)
    want = C * 0.7 * math.pi * 0.5 * 0.7
    assert np.allclose(got, want, rtol=1e-4, atol=0)


def test_partial_coverage_is_applied_as_the_reference_applies_it(tmp_path):
    cov = np.linspace(0.0, 1.0, 30)
    gb = _gbuffer(M=30, coverage=cov)
    bg = (0.2, 0.1, 0.05)
    scene = dataclasses.replace(_scene(tmp_path, PHONG, samples.sky_envmap(16, 8)), background=bg)
    full = renv.texel_sum(scene, dataclasses.replace(gb, coverage=np.ones((1, 30), np.float32)))
    part = renv.texel_sum(scene, gb).reshape(-1, 3)
    a = gb.coverage.reshape(-1, 1).astype(np.float64)      # the file's (float32) α
    fg = cov > 0
    want = a * full.reshape(-1, 3) + (1 - a) * np.asarray(bg)
    assert np.allclose(part[fg], want[fg], rtol=1e-12, atol=1e-15)
    assert np.allclose(part[~fg], bg)


def test_resolved_scene_through_the_reference_within_its_target(tmp_path):
    """The resolved directional lights, shaded by the reference, stay within the
    target of the texel sum on pixels ≥ 1e-3 of the maximum (random normals and views)."""
    from clphong.io.envmap import resolve_environment

    scene = _scene(tmp_path, BLINN, samples.sky_envmap(128, 64))
    scene = dataclasses.replace(scene, material=dataclasses.replace(BLINN, k_a=0.0))
    gb = _gbuffer(M=400, seed=9)
    exact = renv.texel_sum(scene, gb)
    resolved = resolve_environment(scene, max_error=1e-2).scene
    got = shading.shade(resolved, gb)
    big = exact >= 1e-3 * exact.max()
    assert (np.abs(got - exact)[big] / exact[big]).max() <= 1e-2
