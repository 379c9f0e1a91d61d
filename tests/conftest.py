"""Shared fixtures: scenes and G-buffers built in memory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
GBUFFERS = REPO / "gbuffers"


def make_gbuffer(P, N, C, coverage=None, maps=None):
    from clphong.gbuffer import GBuffer

    return GBuffer(position=np.ascontiguousarray(P, np.float32),
                   normal=np.ascontiguousarray(N, np.float32),
                   albedo=np.ascontiguousarray(C, np.float32),
                   coverage=None if coverage is None else np.asarray(coverage, np.float32),
                   maps={k: np.asarray(v, np.float32) for k, v in (maps or {}).items()})


def make_scene(lights=(), *, model="phong", k_a=0.1, k_d=0.7, k_s=0.2, h=32.0,
               specular_color=(1.0, 1.0, 1.0), camera=None, background=(0.0, 0.0, 0.0)):
    """A Scene built directly (bypassing file validation, so tests may use c0 = 0)."""
    from clphong.scene import Camera, Light, Material, Scene

    if camera is None:
        camera = Camera(type="perspective", position=(0.0, 2.0, 6.0))
    elif isinstance(camera, dict):
        camera = dict(camera)
        if camera.get("direction") is not None:
            d = np.asarray(camera["direction"], np.float64)
            camera["direction"] = tuple(d / np.linalg.norm(d))
        camera = Camera(**camera)
    built = []
    for lt in lights:
        if isinstance(lt, dict):
            lt = dict(lt)
            if lt.get("direction") is not None:
                d = np.asarray(lt["direction"], np.float64)
                lt["direction"] = tuple(d / np.linalg.norm(d))
            lt = Light(**lt)
        built.append(lt)
    return Scene(camera=camera, material=Material(model=model, k_a=k_a, k_d=k_d, k_s=k_s, h=h,
                                                  specular_color=tuple(specular_color)),
                 lights=tuple(built), background=tuple(background))


def random_gbuffer(rng, h=24, w=40, *, spread=3.0, background_fraction=0.1, maps=()):
    """Random positions on a slab, random normals facing +z mostly, random albedo."""
    P = rng.uniform(-spread, spread, (h, w, 3))
    P[..., 2] = rng.uniform(-0.5, 0.5, (h, w))
    N = rng.normal(size=(h, w, 3))
    N[..., 2] = np.abs(N[..., 2]) + 0.3
    N *= rng.uniform(0.5, 2.0, (h, w, 1))            # not unit: the host normalises
    C = rng.uniform(0.0, 1.0, (h, w, 3))
    cov = (rng.uniform(size=(h, w)) > background_fraction).astype(np.float32)
    m = {}
    if "k_d" in maps:
        m["k_d"] = rng.uniform(0, 1, (h, w))
    if "k_s" in maps:
        m["k_s"] = rng.uniform(0, 1, (h, w))
    if "h" in maps:
        m["h"] = rng.uniform(0, 200, (h, w))
    if "specular_color" in maps:
        m["specular_color"] = rng.uniform(0, 1, (h, w, 3))
    return make_gbuffer(P, N, C, cov, m)


def random_lights(rng, n_point=3, n_dir=1, n_amb=1):
    lights = []
    for _ in range(n_point):
        lights.append(dict(type="point", position=tuple(rng.uniform(-4, 4, 3) + [0, 0, 3]),
                           color=tuple(rng.uniform(0.2, 1, 3)), intensity=float(rng.uniform(1, 20)),
                           attenuation=(1.0, float(rng.uniform(0, 0.3)), float(rng.uniform(0, 0.1)))))
    for _ in range(n_dir):
        lights.append(dict(type="directional", direction=tuple(rng.normal(size=3) - [0, 0, 1.5]),
                           color=tuple(rng.uniform(0.2, 1, 3)), intensity=float(rng.uniform(0.5, 3))))
    for _ in range(n_amb):
        lights.append(dict(type="ambient", color=tuple(rng.uniform(0.2, 1, 3)), intensity=1.0))
    return lights


def check_against_reference(scene, gbuffer, *, kernel="lanes", lanes=None, compensated=None):
    """Render, compare with the float64 reference, assert |err| ≤ the error bound.

    Returns (rgb, ref, bound, band) for further checks.
    """
    from clphong import reference
    from clphong.render import Renderer, prepare_frame

    r = Renderer(scene, kernel=kernel, lanes=lanes, compensated=compensated)
    frame = prepare_frame(gbuffer, lanes=r.lanes)
    rgb = r.render(gbuffer, frame=frame)
    plan = r.plan_for(frame.map_names)
    ref = reference.shade(scene, gbuffer)
    bound, band = reference.error_bound(
        scene, gbuffer, origin=frame.origin,
        compensated=bool(plan.defines.get("COMPENSATED_SUM", 0)) and kernel == "lanes",
        form="delta" if kernel == "lanes" else "naive")
    assert np.all(np.isfinite(rgb))
    err = np.abs(rgb.astype(np.float64) - ref)
    worst = np.unravel_index(np.argmax(err - bound), err.shape)
    assert np.all(err <= bound), (
        f"|kernel − reference| exceeds the error bound at pixel {worst[:2]} channel {worst[2]}: "
        f"err {err[worst]:.3g} > bound {bound[worst]:.3g} (kernel {rgb[worst]!r}, reference {ref[worst]!r})")
    return rgb, ref, bound, band


@pytest.fixture(scope="session")
def samples_dir():
    return GBUFFERS
