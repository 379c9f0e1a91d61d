"""The OpenCL kernels against the float64 reference and closed forms.

Every tolerance is the error model's bound (clphong.reference.error_bound,
docs/error-model.md), or for closed forms a bound stated next to the test.
"""

from __future__ import annotations

import numpy as np
import pytest

from clphong import reference
from clphong.render import Renderer

from conftest import (GBUFFERS, check_against_reference, make_gbuffer, make_scene,
                      random_gbuffer, random_lights)

U = reference.U


# ------------------------------------------------------------------ samples and random inputs

@pytest.mark.parametrize("kernel", ["lanes", "lanes-fp32", "obvious"])
@pytest.mark.parametrize("name", ["spheres", "ortho"])
def test_samples_match_reference_within_error_bound(name, kernel):
    from clphong.gbuffer import read_gbuffer
    from clphong.scene import load_scene

    scene = load_scene(GBUFFERS / f"{name}.toml")
    gb = read_gbuffer(GBUFFERS / f"{name}.exr")
    rgb, ref, bound, band = check_against_reference(
        scene, gb, kernel=kernel.split("-")[0], fp64_directions=False if kernel == "lanes-fp32" else None)
    # Background pixels carry the background value exactly.
    bg = gb.background_mask()
    assert np.array_equal(rgb[bg], np.broadcast_to(np.float32(scene.background), rgb[bg].shape))
    assert (~bg).sum() > 0.3 * bg.size


@pytest.mark.parametrize("fp64", [True, False], ids=["fp64-directions", "fp32-directions"])
@pytest.mark.parametrize("seed", range(6))
def test_random_gbuffers_match_reference(seed, fp64):
    rng = np.random.default_rng(seed)
    model = ["phong", "blinn-phong"][seed % 2]
    camera = (dict(type="orthographic", direction=(0.3, -0.2, -1.0)) if seed % 3 == 2
              else dict(type="perspective", position=tuple(rng.uniform(-2, 2, 3) + [0, 0, 8])))
    maps = [(), ("k_d",), ("k_s", "h"), ("k_d", "k_s", "h", "specular_color")][seed % 4]
    scene = make_scene(random_lights(rng, n_point=1 + seed, n_dir=seed % 3), model=model,
                       h=float(rng.choice([1.0, 8.0, 64.0, 500.0])), camera=camera,
                       specular_color=tuple(rng.uniform(0.5, 1, 3)))
    check_against_reference(scene, random_gbuffer(rng, maps=maps), fp64_directions=fp64)


@pytest.mark.parametrize("fp64", [True, False], ids=["fp64-directions", "fp32-directions"])
@pytest.mark.parametrize("lanes", [1, 4, 8])
def test_every_lane_width_matches_reference(lanes, fp64):
    rng = np.random.default_rng(11)
    scene = make_scene(random_lights(rng, 5, 1), model="blinn-phong", h=100.0)
    check_against_reference(scene, random_gbuffer(rng, 13, 29), lanes=lanes, fp64_directions=fp64)


@pytest.mark.parametrize("compensated", [False, True])
def test_many_lights_with_and_without_compensation(compensated):
    rng = np.random.default_rng(5)
    scene = make_scene(random_lights(rng, 300, 2), h=16.0)
    check_against_reference(scene, random_gbuffer(rng, 8, 16), compensated=compensated)


def test_compensated_sum_is_more_accurate_for_many_lights():
    """Neumaier summation: the error of a 2000-light sum stays near u, not ~√N·u."""
    rng = np.random.default_rng(8)
    lights = [dict(type="directional", direction=(0, 0, -1), color=(1, 1, 1),
                   intensity=float(x)) for x in rng.uniform(0.5, 1.5, 2000)]
    scene = make_scene(lights, k_s=0.0, camera=dict(type="orthographic", direction=(0, 0, -1)))
    P = np.zeros((4, 16, 3))
    N = np.broadcast_to([0.0, 0.0, 1.0], (4, 16, 3))
    C = rng.uniform(0.2, 1.0, (4, 16, 3))
    gb = make_gbuffer(P, N, C)
    ref = reference.shade(scene, gb)
    naive = Renderer(scene, compensated=False).render(gb)
    comp = Renderer(scene, compensated=True).render(gb)
    e_naive = np.max(np.abs(naive - ref) / ref)
    e_comp = np.max(np.abs(comp - ref) / ref)
    assert e_comp <= 4 * U          # error model: 3u from the sum and the products
    assert e_comp < e_naive


def test_delta_form_beats_naive_pow_on_sharp_highlights():
    """At h = 2000 the obvious kernel's pow(r·v, h) loses ~h·u; the δ form does not."""
    scene = make_scene([dict(type="directional", direction=(0.2, 0.1, -1), color=(1, 1, 1), intensity=1.0)],
                       k_a=0.0, k_d=0.0, k_s=1.0, h=2000.0,
                       camera=dict(type="orthographic", direction=(-0.2, -0.1, -1)))
    # Normals spread around the highlight peak (n halfway between l and v = z).
    ys, xs = np.mgrid[-1:1:64j, -1:1:64j] * 0.03
    N = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    gb = make_gbuffer(np.zeros_like(N), N, np.ones_like(N))
    lanes, ref, _, _ = check_against_reference(scene, gb, kernel="lanes")
    naive, _, _, _ = check_against_reference(scene, gb, kernel="obvious")
    big = ref > 1e-3 * ref.max()
    e_lanes = np.max(np.abs(lanes - ref)[big] / ref[big])
    e_naive = np.max(np.abs(naive - ref)[big] / ref[big])
    assert e_lanes * 10 < e_naive


# ------------------------------------------------------------------------------ closed forms

def _ortho_plane(normals, albedo=(0.8, 0.5, 0.25)):
    N = np.asarray(normals, np.float64).reshape(1, -1, 3)
    return make_gbuffer(np.zeros_like(N), N, np.broadcast_to(albedo, N.shape))


def _closed_form_tol(value, ops=12):
    """|kernel − exact| ≤ ops·u·|exact|: each operation of the term rounds once (u), the
    inputs (unit normals, light directions) are rounded to float32 (a few u)."""
    return ops * U * np.abs(value) + 1e-30


def test_lambert_cosine_law_over_a_sweep_of_angles():
    theta = np.linspace(0, np.pi, 91)   # 0 .. 180 degrees, past the terminator
    normals = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=-1)
    I, k_d, C = 2.5, 0.7, np.array([0.8, 0.5, 0.25])
    scene = make_scene([dict(type="directional", direction=(0, 0, -1), intensity=I)],
                       k_a=0.0, k_d=k_d, k_s=0.0,
                       camera=dict(type="orthographic", direction=(0, 0, -1)))
    rgb = Renderer(scene).render(_ortho_plane(normals, C))[0]
    exact = C * k_d * I * np.maximum(np.cos(theta), 0.0)[:, None]
    # cos θ of the rounded normal: an absolute error ≤ 2u besides the relative one.
    assert np.all(np.abs(rgb - exact) <= _closed_form_tol(exact) + 2 * U * C * k_d * I)


def test_directional_light_at_normal_incidence():
    scene = make_scene([dict(type="directional", direction=(0, -1, 0), color=(1, 0.5, 0.25), intensity=3.0)],
                       k_a=0.0, k_d=0.6, k_s=0.0, camera=dict(type="orthographic", direction=(0, -1, 0)))
    rgb = Renderer(scene).render(_ortho_plane([[0, 1, 0]] * 5, (0.5, 0.5, 0.5)))
    exact = 0.5 * 0.6 * 3.0 * np.array([1, 0.5, 0.25])
    assert np.all(np.abs(rgb - exact) <= _closed_form_tol(exact))


def test_ambient_alone():
    scene = make_scene([dict(type="ambient", color=(0.5, 1.0, 2.0), intensity=0.5)], k_a=0.3)
    C = (0.8, 0.5, 0.25)
    rgb = Renderer(scene).render(_ortho_plane([[0, 0, 1]] * 3, C))
    exact = np.array(C) * 0.3 * 0.5 * np.array([0.5, 1.0, 2.0])
    assert np.all(np.abs(rgb - exact) <= _closed_form_tol(exact, 4))


@pytest.mark.parametrize("coeffs,falloff", [
    ((2.0, 0.0, 0.0), lambda d: 1 / 2.0 + 0 * d),
    ((0.0, 0.5, 0.0), lambda d: 1 / (0.5 * d)),
    ((0.0, 0.0, 0.25), lambda d: 1 / (0.25 * d * d)),
])
def test_each_attenuation_coefficient_alone(coeffs, falloff):
    """A light on the normal at distance d: E = C_d·k_d·I·1/(c0 + c1·d + c2·d²)."""
    d = np.geomspace(0.01, 100.0, 25)
    I, k_d = 4.0, 0.5
    for dist, expect in zip(d, falloff(d)):
        scene = make_scene([dict(type="point", position=(0.0, 0.0, float(dist)), intensity=I,
                                 attenuation=coeffs)], k_a=0.0, k_d=k_d, k_s=0.0)
        rgb = Renderer(scene).render(_ortho_plane([[0, 0, 1]], (1, 1, 1)))
        exact = k_d * I * expect
        assert np.all(np.abs(rgb - exact) <= _closed_form_tol(exact)), (dist, rgb, exact)


def test_phong_reflection_vector():
    """n between l and v: r = 2n(n·l) − l = v, so r·v = 1 and the highlight is C_s·k_s·I.
    Tilting n by φ turns r by 2φ: r·v = cos 2φ, so the term is cos(2φ)^h."""
    l = np.array([np.sin(0.6), 0.0, np.cos(0.6)])       # towards the light
    v = np.array([-np.sin(0.6), 0.0, np.cos(0.6)])      # towards the viewer
    phis = np.linspace(0, 0.3, 7)
    normals = np.stack([np.sin(phis), np.zeros_like(phis), np.cos(phis)], axis=-1)
    h, I = 20.0, 1.5
    scene = make_scene([dict(type="directional", direction=tuple(-l), intensity=I)],
                       k_a=0.0, k_d=0.0, k_s=1.0, h=h, camera=dict(type="orthographic", direction=tuple(-v)))
    rgb = Renderer(scene).render(_ortho_plane(normals, (1, 1, 1)))[0, :, 0]
    exact = I * np.cos(2 * phis) ** h
    # Error model: δ-form relative error ≤ 4u(1 + h·δ) + h·|Δδ|, |Δδ| ≤ √(2δ)·8u: ≤ 400u here.
    assert np.all(np.abs(rgb - exact) <= 400 * U * exact + 1e-30)
    assert abs(rgb[0] - I) <= 8 * U * I


def test_blinn_half_vector():
    """h = (l + v)/|l + v|; n = h gives n·h = 1; n tilted by ψ from h gives cos(ψ)^(4h)."""
    l = np.array([np.sin(0.8), 0.0, np.cos(0.8)])
    v = np.array([0.0, 0.0, 1.0])
    hvec = (l + v) / np.linalg.norm(l + v)
    psi = np.linspace(0, 0.2, 6)
    axis = np.array([0.0, 1.0, 0.0])
    normals = [np.cos(p) * hvec + np.sin(p) * axis for p in psi]
    shin, I = 10.0, 2.0
    for camera in (dict(type="orthographic", direction=(0, 0, -1)),):
        scene = make_scene([dict(type="directional", direction=tuple(-l), intensity=I)],
                           model="blinn-phong", k_a=0.0, k_d=0.0, k_s=1.0, h=shin, camera=camera)
        rgb = Renderer(scene).render(_ortho_plane(normals, (1, 1, 1)))[0, :, 0]
        exact = I * np.cos(psi) ** (4 * shin)
        assert np.all(np.abs(rgb - exact) <= 400 * U * exact + 1e-30)
        assert abs(rgb[0] - I) <= 8 * U * I


def test_blinn_const_h_equals_per_pixel_half_vector():
    """Blinn's orthographic shortcut (host half vector) agrees with the per-pixel form."""
    rng = np.random.default_rng(2)
    lights = random_lights(rng, n_point=0, n_dir=3, n_amb=0)
    gb = random_gbuffer(rng, 9, 17)
    ortho = make_scene(lights, model="blinn-phong", h=50.0, camera=dict(type="orthographic", direction=(0.1, 0.2, -1)))
    r = Renderer(ortho)
    assert r.plan_for(()).defines["BLINN_CONST_H"] == 1
    check_against_reference(ortho, gb)


# ----------------------------------------------------------------------------------- guards

def test_h_zero_defines_0_to_the_0_as_1():
    """h = 0: max(r·v, 0)^0 = 1 wherever n·l > 0, also where r·v ≤ 0."""
    scene = make_scene([dict(type="directional", direction=(0, 0, -1), intensity=1.0)],
                       k_a=0.0, k_d=0.0, k_s=1.0, h=0.0,
                       camera=dict(type="orthographic", direction=(1, 0, 0)))   # v ⟂ surface
    rgb = Renderer(scene).render(_ortho_plane([[0, 0, 1], [0.3, 0, 1]], (1, 1, 1)))
    assert np.all(rgb == 1.0)
    assert np.all(reference.shade(scene, _ortho_plane([[0, 0, 1], [0.3, 0, 1]], (1, 1, 1))) == 1.0)


def test_light_at_the_shaded_point_contributes_nothing():
    scene = make_scene([dict(type="point", position=(0.0, 0.0, 0.0), intensity=5.0)], k_a=0.0)
    gb = _ortho_plane([[0, 0, 1]], (1, 1, 1))
    rgb = Renderer(scene).render(gb)
    assert np.all(rgb == 0.0)
    assert np.all(reference.shade(scene, gb) == 0.0)


def test_no_specular_behind_the_terminator():
    """Specular only where n·l > 0, even where r·v would be large."""
    scene = make_scene([dict(type="directional", direction=(0, 0, 1), intensity=1.0)],   # from below
                       k_a=0.0, k_d=0.5, k_s=1.0, h=1.0, camera=dict(type="orthographic", direction=(0, 0, 1)))
    rgb = Renderer(scene).render(_ortho_plane([[0, 0, 1]], (1, 1, 1)))
    assert np.all(rgb == 0.0)


def test_background_pixels_take_the_background_value():
    P = np.zeros((2, 3, 3))
    N = np.array([[[0, 0, 1], [0, 0, 0], [0, 0, 1]], [[np.nan, 0, 1], [0, 0, 1], [0, 0, 1]]], float)
    cov = np.array([[1, 1, 0], [1, 1, 1]], np.float32)
    gb = make_gbuffer(P, N, np.ones_like(P), coverage=cov)
    scene = make_scene([dict(type="ambient")], background=(0.25, 0.5, 1.0))
    from clphong.errors import InputWarning
    with pytest.warns(InputWarning, match="normal: 1 pixel"):      # counted and reported
        rgb = Renderer(scene).render(gb)
    bg = np.array([[False, True, True], [True, False, False]])
    assert np.all(rgb[bg] == np.float32([0.25, 0.5, 1.0]))
    assert np.all(rgb[~bg] == np.float32(0.1))


# ----------------------------------------------------------------------------- the program cache

def test_programs_are_built_once_per_variant(monkeypatch):
    from clphong.runtime import get_runtime

    rt = get_runtime()
    monkeypatch.setattr(rt, "_programs", {})     # start from an empty cache; restored afterwards
    rng = np.random.default_rng(0)
    scene = make_scene(random_lights(rng, 2, 1), h=7.0, model="blinn-phong")
    before = rt.builds
    Renderer(scene)
    assert rt.builds == before + 1
    before = rt.builds
    Renderer(scene).render(random_gbuffer(rng, 4, 4))
    Renderer(make_scene(random_lights(rng, 3, 1), h=9.0, model="blinn-phong")).render(random_gbuffer(rng, 4, 4))
    assert rt.builds == before        # same variant: no rebuild, whatever the light values
    Renderer(make_scene(random_lights(rng, 2, 0), k_s=0.0))
    assert rt.builds == before + 1    # a new variant builds once
