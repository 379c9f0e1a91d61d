"""Tests of clphong.device.frame: physical (c0 = 0) falloff, checked per frame at the
nearest shaded pixel, and shaded within the error model however near the light."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import check_against_reference, heightfield, make_gbuffer, make_scene

from clphong.core.errors import SceneError
from clphong.core.floats import FLT_MAX, FLT_MIN
from clphong.core.geometry import nearest_within
from clphong.device.frame import near_field_radius
from clphong.device.renderer import Renderer
from clphong.model.scene import WATTS_TO_RADIANCE, parse_scene


def _flat(h=16, w=20):
    """A flat floor z = 0 facing +z, pixels 0.1 apart (exact float32 positions)."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) * 0.125
    P = np.stack([xs, ys, np.zeros_like(xs)], -1)
    N = np.broadcast_to([0.0, 0.0, 1.0], P.shape)
    C = np.full(P.shape, 0.5)
    return make_gbuffer(P, N, C)


def _power_scene(positions, watts=100.0, model="phong"):
    lights = [dict(type="point", position=tuple(map(float, p)), power=watts) for p in positions]
    data = {"camera": {"type": "perspective", "position": [1.0, 1.0, 5.0]},
            "material": {"model": model, "k_a": 0.0, "k_d": 0.7, "k_s": 0.3, "h": 16.0},
            "light": lights}
    return parse_scene(data, source="phys.toml")


def test_near_field_radius_is_where_the_falloff_overflows():
    # 1/d²: R/d² = FLT_MAX at d = sqrt(R/FLT_MAX); the radius sits just outside it
    R = 1e3
    r = float(near_field_radius(0.0, 1.0, R, fp64=True))
    assert math.sqrt(R / FLT_MAX) < r < math.sqrt(R / FLT_MAX) * (1 + 1e-5)
    # linear 1/(c1·d)
    r = float(near_field_radius(2.0, 0.0, R, fp64=True))
    assert R / (2 * FLT_MAX) < r < R / (2 * FLT_MAX) * (1 + 1e-5)
    # the float path also needs p(d) ≥ 4·FLT_MIN: a dim light's radius is set by that
    r = float(near_field_radius(0.0, 1.0, 1e-30, fp64=False))
    assert math.sqrt(4 * FLT_MIN) < r < math.sqrt(4 * FLT_MIN) * (1 + 1e-5)


@pytest.mark.parametrize("rebased", [False, True])
def test_nearest_within_matches_brute_force(rebased):
    """Against every distance, with NaN positions in some blocks and, rebased, the
    float32 P − origin the float kernels form, far from the origin (rounded)."""
    rng = np.random.default_rng(3)
    n = 3000 + 77                                     # a partial last block
    far = np.float32(1000.0) if rebased else np.float32(0.0)
    planes = (rng.uniform(-1, 1, (3, n)) + far).astype(np.float32)
    planes[:, rng.integers(0, n, 40)] = np.nan
    shaded = rng.uniform(size=n) > 0.2
    origin = np.array([far + 0.37, far - 0.2, far + 0.1], np.float32) if rebased else None
    q = planes if origin is None else planes - origin[:, None]
    points = q[:, rng.integers(0, n, 20)].T.astype(np.float64) + rng.normal(0, 0.05, (20, 3))
    radii = rng.uniform(0, 0.2, 20)
    radii[:3] = 0
    got = nearest_within(planes, shaded, points, radii, rebase=origin)
    for j, p in enumerate(points):
        d = np.sqrt(((q.astype(np.float64).T - p) ** 2).sum(axis=1))
        d[~shaded | ~np.isfinite(d)] = np.inf
        k = int(np.argmin(d))
        want = (k, d[k]) if 0 < d[k] < radii[j] else None
        assert got[j] == want, j


@pytest.mark.parametrize("fp64", [True, False], ids=["fp64", "float"])
def test_light_that_overflows_at_the_nearest_pixel_is_named(fp64):
    gb = _flat()
    P = gb.position[5, 7].astype(np.float64)
    # 1000 W at 1e-20 above pixel (7, 5): R/d² ≈ 2.5e41 > FLT_MAX on either path
    scene = _power_scene([(1.0, 1.0, 2.0), P + [0.0, 0.0, 1e-20 if fp64 else 2e-19]], watts=1000.0)
    r = Renderer(scene, fp64_directions=fp64)
    with pytest.raises(SceneError) as info:
        r.render(gb)
    msg = str(info.value)
    assert msg.startswith("phys.toml: light[1]: the frame's pixel x=7, y=5 is ") and "\n" not in msg
    assert "beyond the float32 range" in msg and "c0 > 0" in msg


def test_light_exactly_at_a_pixel_adds_nothing_there():
    gb = _flat()
    P = gb.position[5, 7].astype(np.float64)
    scene = _power_scene([P], watts=1000.0)
    rgb, ref, _, _ = check_against_reference(scene, gb)
    assert rgb[5, 7].tolist() == [0.0, 0.0, 0.0] and np.all(np.isfinite(rgb))


@pytest.mark.parametrize("height", [1.0, 1e-3, 1e-8, 1e-15])
@pytest.mark.parametrize("model", ["phong", "blinn-phong"])
def test_inverse_square_near_the_surface_within_the_error_bound(height, model, device):
    """d → 0: 1/d² light just above a pixel of a wavy surface; the error model's bound holds
    (the default path: d from double differences, so d's relative error stays ~2⁻⁴⁷)."""
    rng = np.random.default_rng(11)
    gb = heightfield(rng, 24, 30)
    P = gb.position[12, 15].astype(np.float64)
    n = gb.normal[12, 15].astype(np.float64)
    n /= np.linalg.norm(n)
    scene = _power_scene([P + height * n, (1.5, 1.2, 0.8)], watts=1e-6 * height ** 2 + 5.0, model=model)
    rgb, ref, bound, _ = check_against_reference(scene, gb, device=device)
    rel = np.abs(rgb - ref) / np.maximum(np.abs(ref), 1e-30)
    assert rel[ref > 1e-6 * ref.max()].max() < 5e-6        # the accuracy target


def test_power_light_matches_the_closed_form_lambert():
    """One 1/d² light of P watts over a flat floor: the diffuse radiance is
    albedo·P/(4π²)·cosθ/d², computed here in float64 from the geometry."""
    gb = _flat()
    light = np.array([1.1, 0.9, 0.7])
    scene = parse_scene({"camera": {"type": "perspective", "position": [1.0, 1.0, 5.0]},
                         "material": {"model": "phong", "k_a": 0.0, "k_d": 1.0, "k_s": 0.0, "h": 1.0},
                         "light": [{"type": "point", "position": light.tolist(), "power": 250.0}]},
                        source="p.toml")
    rgb = Renderer(scene).render(gb).image
    P = gb.position.astype(np.float64)
    to = light - P
    d = np.linalg.norm(to, axis=-1)
    want = 0.5 * 250.0 / (4 * math.pi ** 2) * (to[..., 2] / d) / d ** 2
    assert WATTS_TO_RADIANCE == 1 / (4 * math.pi ** 2)
    np.testing.assert_allclose(rgb[..., 0], want, rtol=5e-6)


def test_power_lights_cull_with_a_bounded_error():
    """c0 = 0 lights take part in culling: each dropped light's bound holds (max_error)."""
    rng = np.random.default_rng(5)
    gb = heightfield(rng, 64, 64, bumps=0.1)
    lights = [dict(type="point", position=(float(rng.uniform(0, 6.4)), float(rng.uniform(0, 6.4)),
                                           float(rng.uniform(0.05, 0.3))),
                   color=(1.0, 1.0, 1.0), intensity=float(rng.uniform(0.001, 0.01)),
                   attenuation=(0.0, 0.0, 1.0)) for _ in range(40)]
    scene = make_scene(lights)
    eps = 1e-3
    full = Renderer(scene).render(gb).image
    res = Renderer(scene, max_error=eps).render(gb)
    assert res.cull is not None and res.cull.kept_fraction < 0.9      # lights are culled
    assert np.abs(res.image.astype(np.float64) - full).max() <= eps + 1e-6


@pytest.mark.parametrize("path", ["accurate", "float", "fast"])
@pytest.mark.parametrize("c0", [0.0, 1.0], ids=["c0=0", "c0=1"])
def test_a_light_at_a_pixel_adds_nothing_with_or_without_the_guard(path, c0, device):
    """A light exactly at a pixel (d = 0) adds nothing there, on every path. The plan
    compiles the lights loop's select for d = 0 (POINT_GUARD) only where some light has
    c0 = 0: with c0 > 0 none is needed (l = 0 there, and 1/c0 is finite: lights.h)."""
    gb = _flat()
    P = gb.position[5, 7].astype(np.float64)
    lights = [dict(type="point", position=tuple(map(float, P)), color=(1.0, 1.0, 1.0), intensity=2.0,
                   attenuation=(c0, 0.5, 1.0)),
              dict(type="point", position=(1.0, 1.0, 2.0), intensity=1.0, attenuation=(1.0, 0.0, 0.3))]
    scene = make_scene(lights, model="blinn-phong", h=32.0)
    assert Renderer(scene, path=path, device=device).plan_for(()).defines["POINT_GUARD"] == (c0 == 0.0)
    rgb, ref, bound, _ = check_against_reference(scene, gb, path=path, device=device)
    alone = make_scene(lights[1:], model="blinn-phong", h=32.0)      # the pixel without the first
    from clphong.reference import shading as reference
    assert np.abs(rgb[5, 7] - reference.shade(alone, gb)[5, 7]).max() <= bound[5, 7].max()


def _far_scene(x, flat, position=None):
    lights = [dict(type="point", position=position or (x, 0.0, 1.0), intensity=1.0,
                   attenuation=(1.0, 0.0, 0.0) if flat else (1.0, 0.0, 1.0)),
              dict(type="point", position=(1.0, 1.0, 2.0), intensity=1.0, attenuation=(1.0, 0.2, 0.3))]
    return make_scene(lights, model="blinn-phong", h=32.0), make_scene(lights[1:], model="blinn-phong", h=32.0)


@pytest.mark.parametrize("path", ["accurate", "float", "fast"])
@pytest.mark.parametrize("x", [3e19, 1e30], ids=["3e19", "1e30"])
@pytest.mark.parametrize("flat", [False, True], ids=["all-fall-off", "one-flat"])
def test_a_light_beyond_float_range_adds_nothing(path, x, flat, device):
    """A light at 3e19 or 1e30 (d ≥ 2⁶⁴·√2: beyond the float loop's cap on d²/16, where the
    error model calls its pixels unbounded): never a NaN, and nothing added. The frame has a
    light that far from its pixels, so on the float paths its plan turns POINT_GUARD on
    (frame.has_far_lights), whose selects give it l = 0 and no falloff; with double
    directions d² stays in range and the falloff (~1e-39, or 1/c0 with c1 = c2 = 0 times
    n·l ~3e-20) adds nothing at float's precision."""
    gb = _flat()
    scene, near_scene = _far_scene(x, flat)
    r = Renderer(scene, path=path, device=device)
    float_dirs = not r.plan_for(()).defines["DIRECTIONS_FP64"]
    assert r.plan_for(()).defines["POINT_GUARD"] == 0          # the scene alone needs none
    rgb, ref, _, _ = check_against_reference(scene, gb, path=path, device=device)
    assert r.render(gb).plan.defines["POINT_GUARD"] == float_dirs   # this frame's plan
    assert np.all(np.isfinite(rgb))
    near = Renderer(near_scene, path=path, device=device).render(gb).image
    np.testing.assert_array_equal(rgb, near) if float_dirs else \
        np.testing.assert_allclose(rgb, near, rtol=1e-6)


@pytest.mark.parametrize("path", ["float", "fast"])
def test_without_the_far_guard_a_far_light_is_wrong(path, device, monkeypatch):
    """The far-light guard is needed: with frame.has_far_lights forced off, a light with
    c1 = c2 = 0 at 1e30 straight above the floor (d²/16 = ∞, capped: l = (Δ/4)·2⁻⁶²·⁵ is
    ~4e10 long, the falloff 1/c0) changes the frame, which with the guard is the near
    light's alone (test_a_light_beyond_float_range_adds_nothing)."""
    import clphong.device.renderer as renderer
    gb = _flat()
    scene, near_scene = _far_scene(1e30, True, position=(0.0, 0.0, 1e30))
    assert np.array_equal(Renderer(scene, path=path, device=device).render(gb).image,
                          Renderer(near_scene, path=path, device=device).render(gb).image)
    monkeypatch.setattr(renderer, "has_far_lights", lambda frame, lights: False)
    res = Renderer(scene, path=path, device=device).render(gb)
    assert res.plan.defines["POINT_GUARD"] == 0
    near = Renderer(near_scene, path=path, device=device).render(gb).image
    assert not np.array_equal(res.image, near)


def test_far_lights_are_those_that_may_pass_the_cap():
    """has_far_lights: the lights' reach from the frame's origin plus the pixels' half
    extent, against FAR_LIGHT = 2⁶⁴ (1.84e19); the frame's own extent counts."""
    from clphong.device.frame import has_far_lights, pack_lights, prepare_frame
    from clphong.device.plan import FAR_LIGHT
    gb = _flat()
    frame = prepare_frame(gb)
    assert FAR_LIGHT == 2.0 ** 64
    for x, far in [(1.0, False), (1.8e19, False), (1.85e19, True), (1e30, True)]:
        scene, _ = _far_scene(x, False)
        assert has_far_lights(frame, pack_lights(scene, frame.origin)) == far, x
    # the same light, and pixels 2e18 away on the other side: now far
    P = gb.position.copy()
    P[0, 0] = (-2e18, 0.0, 0.0)
    wide = prepare_frame(make_gbuffer(P.astype(np.float64), gb.normal.astype(np.float64),
                                      gb.albedo.astype(np.float64)))
    scene, _ = _far_scene(1.7e19, False)
    assert not has_far_lights(frame, pack_lights(scene, frame.origin))
    assert has_far_lights(wide, pack_lights(scene, wide.origin))


def test_the_weights_take_the_falloff_only_where_it_cannot_overflow(device, monkeypatch):
    """FALLOFF_ON_WEIGHTS (lights.h): R·(D·att·w_d + S·att·w_s) on the float path only where
    every falloff stays ≤ 1.5. Here D = C·k_d = 2⁶²·2⁶² (both inside io/nonfinite.py's
    limits) and a light with c0 = 0.01 just above the floor (att ≈ 80) and no green: the
    plan keeps (att·R)·(D·w_d), whose green is 0·finite = 0; forced on, D·att·w_d
    overflows and green is 0·∞ = NaN."""
    import dataclasses

    import clphong.device.renderer as renderer
    from clphong.device.plan import make_plan
    from clphong.tools.hardcases import make_gbuffer as mk
    base = _flat()
    big = np.float64(2.0 ** 62)
    gb = mk(base.position.astype(np.float64), base.normal.astype(np.float64),
            np.full(base.albedo.shape, big), maps={"k_d": np.full(base.albedo.shape[:2], big)})
    lights = [dict(type="point", position=(1.0, 1.0, 0.05), color=(1.0, 0.0, 1.0), intensity=1.0,
                   attenuation=(0.01, 0.0, 1.0))]
    scene = make_scene(lights, model="blinn-phong", h=32.0)
    tame = make_scene([dict(lights[0], attenuation=(1.0, 0.0, 1.0))], model="blinn-phong", h=32.0)
    assert make_plan(scene, ["k_d"]).defines["FALLOFF_ON_WEIGHTS"] == 0
    assert make_plan(tame, ["k_d"]).defines["FALLOFF_ON_WEIGHTS"] == 1
    assert make_plan(scene, ["k_d"], fp64_directions=True, has_fp64=True).defines["FALLOFF_ON_WEIGHTS"] == 1
    res = Renderer(scene, path="fast", device=device, nonfinite="pass").render(gb)
    assert res.plan.defines["FALLOFF_ON_WEIGHTS"] == 0
    assert not np.isnan(res.image).any() and np.all(res.image[..., 1] == res.image[0, 0, 1])
    orig = renderer.make_plan

    def forced(*a, **k):
        p = orig(*a, **k)
        return dataclasses.replace(p, defines={**p.defines, "FALLOFF_ON_WEIGHTS": 1})
    monkeypatch.setattr(renderer, "make_plan", forced)
    wrong = Renderer(scene, path="fast", device=device, nonfinite="pass").render(gb)
    assert np.isnan(wrong.image[..., 1]).any()
