"""Hard cases for the float32 kernels: each a small G-buffer and scene.

Every case is shaded by the default path and compared with the float64
reference (:mod:`clphong.reference.shading`) on the same float32 inputs:

* ``|kernel − reference| ≤ error_bound`` on every pixel and channel, the
  terminator band included (the bound covers the whole switched term there);
* no NaN or Inf comes out of finite inputs (after the input policy,
  :mod:`clphong.io.nonfinite`);
* the accuracy target of issue 5: relative error ≤ :data:`TARGET_REL` on every
  pixel whose value is at least 10⁻⁶ of the image maximum (and a normal
  float32, ≥ FLT_MIN), outside the
  terminator band (whose pixels are counted and reported, not hidden). This
  includes a cancellation (``negative-albedo-cancels``): the default path forms
  every product in double, so it loses no digits the reference keeps.

``python -m clphong.tools.hardcases`` prints the table of cases with the measured
error against the bound; ``tests/test_hard_cases.py`` asserts it.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..core.errors import InputWarning
from ..core.floats import FLT_MIN
from ..device.renderer import Renderer, prepare_frame
from ..io.gbuffer import GBuffer, read_gbuffer
from ..io.nonfinite import apply_nonfinite_policy
from ..model.options import KERNELS
from ..model.scene import Camera, Light, Material, Scene, load_scene
from ..reference import shading as reference
from .report import markdown_table

#: Max relative error of the default path on pixels ≥ 1e-6 of the image max
#: (issue 5), outside the terminator band.
TARGET_REL = 5e-6
#: Pixels below this fraction of the image maximum are not held to TARGET_REL.
SIGNIFICANT = 1e-6


def significant(ref, foreground, band):
    """Where the target applies: (H, W, 3) mask of non-zero values of ``ref`` at
    least SIGNIFICANT of the image maximum and FLT_MIN, outside the band."""
    peak = float(np.max(np.abs(ref[foreground]), initial=0.0))
    floor = max(SIGNIFICANT * peak, FLT_MIN)
    return (foreground & ~band)[..., None] & (np.abs(ref) >= floor) & (ref != 0.0)


# ------------------------------------------------------------------ building blocks

def make_gbuffer(P, N, C, coverage=None, maps=None):
    """A :class:`~clphong.io.gbuffer.GBuffer` from arrays (converted to float32)."""
    return GBuffer(position=np.ascontiguousarray(P, np.float32),
                   normal=np.ascontiguousarray(N, np.float32),
                   albedo=np.ascontiguousarray(C, np.float32),
                   coverage=None if coverage is None else np.asarray(coverage, np.float32),
                   maps={k: np.asarray(v, np.float32) for k, v in (maps or {}).items()})


def make_scene(lights=(), *, model="phong", k_a=0.1, k_d=0.7, k_s=0.2, h=32.0,
               specular_color=(1.0, 1.0, 1.0), camera=None, background=(0.0, 0.0, 0.0),
               fresnel="none", f0=None):
    """A Scene built directly, bypassing the file validation (so c0 = 0 is possible).

    ``lights`` are dicts of :class:`~clphong.model.scene.Light` fields (directions are
    normalised here) or Light objects; ``camera`` a dict of Camera fields.
    """
    def unit_direction(fields: dict) -> dict:
        fields = dict(fields)
        if fields.get("direction") is not None:
            d = np.asarray(fields["direction"], np.float64)
            fields["direction"] = tuple(d / np.linalg.norm(d))
        return fields

    if camera is None:
        camera = Camera(type="perspective", position=(0.0, 2.0, 6.0))
    elif isinstance(camera, dict):
        camera = Camera(**unit_direction(camera))
    built = [Light(**unit_direction(lt)) if isinstance(lt, dict) else lt for lt in lights]
    if f0 is not None and not isinstance(f0, (tuple, list)):
        f0 = (float(f0),) * 3
    return Scene(camera=camera, material=Material(model=model, k_a=k_a, k_d=k_d, k_s=k_s, h=h,
                                                  specular_color=tuple(specular_color),
                                                  fresnel=fresnel,
                                                  f0=None if f0 is None else tuple(f0)),
                 lights=tuple(built), background=tuple(background))


@dataclass
class HardCase:
    """One hard case: what it probes, and how it is built."""

    name: str
    group: str
    what: str
    build: Callable[[], tuple]          # () -> (scene, gbuffer)
    finite_inputs: bool = True          # False: NaN/Inf in the G-buffer (input policy)


CASES: list[HardCase] = []


def case(name, group, what, **kw):
    def register(fn):
        CASES.append(HardCase(name=name, group=group, what=what, build=fn, **kw))
        return fn
    return register


def _strip(n):
    """A 1×n row of pixels at the origin facing +z, white albedo."""
    P = np.zeros((1, n, 3))
    P[0, :, 0] = np.linspace(-0.5, 0.5, n)
    N = np.broadcast_to([0.0, 0.0, 1.0], (1, n, 3)).copy()
    return P, N, np.ones((1, n, 3))


def _tilted_normals(angles):
    """Normals (sin θ, 0, cos θ): with l = (1, 0, 0), n·l = sin θ."""
    a = np.asarray(angles, np.float64)
    N = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], -1)
    return N[None]


def _sphere(n=24, radius=1.0, center=(0.0, 0.0, 0.0)):
    """The visible hemisphere of a sphere seen from +z, n×n pixels."""
    y, x = np.mgrid[-1:1:n * 1j, -1:1:n * 1j] * 0.999
    r2 = x * x + y * y
    inside = r2 < 1.0
    z = np.sqrt(np.clip(1.0 - r2, 0.0, None))
    N = np.stack([x, -y, z], -1)
    P = np.asarray(center) + radius * N
    cov = inside.astype(np.float32)
    return P, N, np.full(P.shape, 0.8), cov


_LIGHT_X = dict(type="directional", direction=(-1.0, 0.0, 0.0), intensity=1.0)  # l = +x
_ORTHO_DOWN = dict(type="orthographic", direction=(0.0, 0.0, -1.0))              # v = +z


# --------------------------------------------------------------- geometry and angles

@case("grazing-above", "angles", "n·l = sin θ for θ from 1e-7 to 1e-2 rad (light just above)")
def _grazing_above():
    N = _tilted_normals(np.geomspace(1e-7, 1e-2, 64))
    P = np.zeros_like(N)
    return make_scene([_LIGHT_X], k_a=0.0, camera=_ORTHO_DOWN), make_gbuffer(P, N, np.ones_like(N))


@case("grazing-below", "angles", "n·l = −sin θ for θ from 1e-7 to 1e-2 rad (light just below)")
def _grazing_below():
    N = _tilted_normals(-np.geomspace(1e-7, 1e-2, 64))
    P = np.zeros_like(N)
    return make_scene([_LIGHT_X], k_a=0.05, camera=_ORTHO_DOWN), make_gbuffer(P, N, np.ones_like(N))


@case("grazing-across", "angles", "n·l crosses 0: θ in [−1e-6, 1e-6] (the terminator band)")
def _grazing_across():
    N = _tilted_normals(np.linspace(-1e-6, 1e-6, 65))
    P = np.zeros_like(N)
    return (make_scene([_LIGHT_X], k_a=0.0, h=1.0, camera=dict(type="orthographic", direction=(1, 0, -1))),
            make_gbuffer(P, N, np.ones_like(N)))


@case("light-behind", "angles", "every light behind the surface: only ambient remains")
def _light_behind():
    P, N, C = _strip(32)
    lights = [dict(type="directional", direction=(0.3, 0.1, 1.0), intensity=3.0),
              dict(type="point", position=(0.0, 0.0, -2.0), intensity=5.0), dict(type="ambient")]
    return make_scene(lights), make_gbuffer(P, N, C)


@case("viewer-behind-phong", "angles", "the viewer below the surface, the light above (Phong)")
def _viewer_behind_phong():
    P, N, C = _strip(32)
    lights = [dict(type="point", position=(0.3, 0.0, 2.0), intensity=4.0)]
    cam = dict(type="perspective", position=(0.0, 0.5, -3.0))
    return make_scene(lights, k_a=0.0, h=8.0, camera=cam), make_gbuffer(P, N, C)


@case("viewer-behind-blinn", "angles", "the viewer below the surface, the light above (Blinn)")
def _viewer_behind_blinn():
    P, N, C = _strip(32)
    lights = [dict(type="point", position=(0.3, 0.0, 2.0), intensity=4.0)]
    cam = dict(type="perspective", position=(0.0, 0.5, -3.0))
    return make_scene(lights, model="blinn-phong", k_a=0.0, h=8.0, camera=cam), make_gbuffer(P, N, C)


@case("blinn-l-equals-minus-v", "angles", "l = −v exactly: the half vector is undefined (δ := 1)")
def _blinn_undefined():
    N = _tilted_normals(np.linspace(-1.2, 1.2, 33))
    P = np.zeros_like(N)
    # Orthographic v = +x' and a directional light with l = −v: constant h undefined.
    cam = dict(type="orthographic", direction=(1.0, 0.0, 0.0))          # v = (−1, 0, 0)
    light = dict(type="directional", direction=(-1.0, 0.0, 0.0), intensity=2.0)   # l = (1, 0, 0)
    return (make_scene([light], model="blinn-phong", k_a=0.0, h=4.0, camera=cam),
            make_gbuffer(P, N, np.ones_like(N)))


@case("blinn-l-near-minus-v", "angles", "a point light almost opposite the viewer: |l + v| ≈ 1e-4")
def _blinn_near_undefined():
    N = _tilted_normals(np.linspace(0.5, 1.5, 16))
    P = np.zeros_like(N)
    P[0, :, 1] = np.linspace(-1e-4, 1e-4, 16)
    cam = dict(type="perspective", position=(-3.0, 0.0, 0.0))
    light = dict(type="point", position=(3.0, 0.0, 0.0), intensity=2.0)
    return (make_scene([light], model="blinn-phong", k_a=0.0, h=2.0, camera=cam),
            make_gbuffer(P, N, np.ones_like(N)))


@case("blinn-l-minus-v-collinear", "angles",
      "eye, pixels and a point light on one slanted line: |l + v| is rounding noise")
def _blinn_collinear():
    # Pixels at t·w between the eye (−2w) and the light (10w), exact in float32, so l
    # and v are opposite up to the roundings of their normalisation; normals face the
    # light. The reference sees |l + v| = 0 or noise, the kernel noise: the model
    # bounds the whole term, and (n·h)² from noise must not exceed 1 (brdf.cl).
    w = np.array([3.0, 4.0, 12.0])
    t = (np.arange(64) + 1) / 32.0
    P = (t[:, None] * w).reshape(4, 16, 3)
    N = (w + np.random.default_rng(1).normal(scale=3.0, size=(64, 3))).reshape(4, 16, 3)
    light = dict(type="point", position=tuple(10.0 * w), intensity=1.0)
    cam = dict(type="perspective", position=tuple(-2.0 * w))
    return (make_scene([light], model="blinn-phong", k_a=0.0, k_d=0.0, k_s=1.0, h=32.0,
                       camera=cam), make_gbuffer(P, N, np.ones_like(N)))


@case("phong-r-dot-v-one", "angles", "mirror geometry: r = v exactly, r·v = 1 (δ = 0)")
def _mirror():
    P, N, C = _strip(16)
    light = dict(type="directional", direction=(-0.6, 0.0, -0.8), intensity=1.0)     # l = (0.6, 0, 0.8)
    cam = dict(type="orthographic", direction=(0.6, 0.0, -0.8))                     # v = (−0.6, 0, 0.8)
    return make_scene([light], k_a=0.0, k_d=0.0, k_s=1.0, h=1e4, camera=cam), make_gbuffer(P, N, C)


# ------------------------------------------------------------------------- normals

def _normal_case(N_of):
    P, N0, C, cov = _sphere(16)
    lights = [dict(type="point", position=(2.0, 2.0, 3.0), intensity=6.0,
                   attenuation=(1.0, 0.0, 0.05)), dict(type="ambient")]
    return make_scene(lights, camera=dict(type="perspective", position=(0.0, 0.0, 5.0))), \
        make_gbuffer(P, N_of(N0), C, coverage=cov)


@case("zero-normal", "normals", "zero-length normals: background")
def _zero_normal():
    def f(N):
        N = N.copy()
        N[::3, ::2] = 0.0
        return N
    return _normal_case(f)


@case("denormal-normal", "normals", "normals with denormal components (length ~1e-40)")
def _denormal_normal():
    return _normal_case(lambda N: (N * 1e-40).astype(np.float32))


@case("normal-length-half", "normals", "un-normalised normals of length 0.5")
def _half_length():
    return _normal_case(lambda N: 0.5 * N)


@case("normal-length-two", "normals", "un-normalised normals of length 2")
def _two_length():
    return _normal_case(lambda N: 2.0 * N)


@case("nan-normal", "normals", "NaN normals: background (no direction to shade with)", finite_inputs=False)
def _nan_normal():
    def f(N):
        N = N.copy()
        N[2::4, 1::3, 1] = np.nan
        return N
    return _normal_case(f)


@case("half-float-normals", "normals", "normals stored as half floats (not unit after rounding)")
def _half_normals():
    return _normal_case(lambda N: N.astype(np.float16).astype(np.float32))


# ---------------------------------------------------------------- distance and falloff

def _towards_light(d, c, intensity):
    """Pixels on the z axis at distance d[i] below a point light at the origin."""
    n = len(d)
    P = np.zeros((1, n, 3))
    P[0, :, 2] = -np.asarray(d)
    N = np.broadcast_to([0.0, 0.6, 0.8], (1, n, 3)).copy()
    light = dict(type="point", position=(0.0, 0.0, 0.0), intensity=intensity, attenuation=c)
    cam = dict(type="perspective", position=(0.0, 3.0, -1.0))
    return make_scene([light], k_a=0.0, h=4.0, camera=cam), make_gbuffer(P, N, np.full((1, n, 3), 0.5))


@case("light-at-point", "distance", "a light exactly at the shaded point (d = 0) adds nothing")
def _at_point():
    return _towards_light([0.0, 1e-3, 0.5, 1.0], (1.0, 0.5, 0.25), 2.0)


@case("c0-zero-near", "distance", "c0 = 0 (1/(c1·d)), d from 1e-1 down to 1e-30, and d = 0")
def _c0_zero():
    return _towards_light(list(np.geomspace(1e-1, 1e-30, 30)) + [0.0], (0.0, 1.0, 0.0), 1e-6)


@case("light-touching", "distance", "c0 = 1 and a light 1e-17 … 1 above the surface, "
      "far closer than the frame's extent (the fp64 path does not rebase: d is exact)")
def _touching():
    return _towards_light([1e-17, 1e-12, 1e-6, 1e-3, 1.0], (1.0, 0.0, 0.0), 0.5)


@case("c2-only-tiny-d", "distance", "c2 only at d = 1e-20: c2·d² = 1e-40 is below float's range")
def _c2_tiny():
    return _towards_light([1e-20, 2e-20, 5e-20], (0.0, 0.0, 1.0), 1e-36)


@case("c2-only-huge-d", "distance", "c2 only at d = 1e20: d² = 1e40 is above float's range")
def _c2_huge():
    return _towards_light([1e20, 2e20, 5e20], (0.0, 0.0, 1.0), 1e36)


# ------------------------------------------------------------------------- exponents

def _highlight(model, h, n=24):
    P, N, C, cov = _sphere(n)
    lights = [dict(type="point", position=(1.0, 1.0, 4.0), intensity=3.0)]
    cam = dict(type="perspective", position=(-0.5, -0.3, 5.0))
    return make_scene(lights, model=model, k_a=0.0, k_d=0.2, k_s=1.0, h=h, camera=cam), \
        make_gbuffer(P, N, C, coverage=cov)


@case("h-zero-phong", "exponents", "h = 0: max(r·v, 0)^0 = 1 wherever n·l > 0 (0⁰ := 1)")
def _h0_phong():
    return _highlight("phong", 0.0)


@case("h-zero-blinn", "exponents", "h = 0 with Blinn: (n·h)^0 = 1 wherever n·l > 0")
def _h0_blinn():
    return _highlight("blinn-phong", 0.0)


def _needle(model, h, n=32):
    """A highlight resolved by n×n pixels: normals tilted around the mirror normal
    by up to ±2.5/√k rad, so the whole lobe down to e⁻¹⁴ of its peak is sampled.
    Point light and perspective eye 3 units away from a 1 mm patch."""
    Lpos, eye = np.array([1.2, 0.4, 2.7]), np.array([-0.9, -0.3, 2.8])
    l0, v0 = Lpos / np.linalg.norm(Lpos), eye / np.linalg.norm(eye)
    n0 = (l0 + v0) / np.linalg.norm(l0 + v0)
    k = 4.0 * h if model == "blinn-phong" else h
    t = np.linspace(-2.5, 2.5, n) / np.sqrt(k)
    a = np.cross(n0, [0.0, 1.0, 0.0]); a /= np.linalg.norm(a)
    b = np.cross(n0, a)
    N = n0 + t[:, None, None] * a + t[None, :, None] * b
    P = np.zeros((n, n, 3))
    P[..., 0], P[..., 1] = np.meshgrid(np.linspace(-5e-4, 5e-4, n), np.linspace(-5e-4, 5e-4, n))
    lights = [dict(type="point", position=tuple(Lpos), intensity=2.0)]
    return make_scene(lights, model=model, k_a=0.0, k_d=0.0, k_s=1.0, h=h,
                      camera=dict(type="perspective", position=tuple(eye))), \
        make_gbuffer(P, N, np.full(P.shape, 0.8))


@case("h-1e4-phong", "exponents", "h = 1e4: the whole needle highlight resolved, condition number 1e4")
def _h1e4_phong():
    return _needle("phong", 1e4)


@case("h-1e4-blinn", "exponents", "h = 1e4 with Blinn's 4h = 4e4, the whole lobe resolved")
def _h1e4_blinn():
    return _needle("blinn-phong", 1e4)


@case("h-non-integer", "exponents", "h = 37.3, not an integer")
def _h_frac():
    return _highlight("phong", 37.3)


@case("h-map-large", "exponents", "a shininess map from 0 to 1e4 (Blinn)")
def _h_map():
    scene, gb = _highlight("blinn-phong", 1.0, n=32)
    h = np.geomspace(1.0, 1e4, 32 * 32).reshape(32, 32)
    h[0, :4] = 0.0
    gb.maps["h"] = h.astype(np.float32)
    return scene, gb


# ------------------------------------------------------------------------- positions

@case("far-from-origin", "positions", "P and the light at 1e5 units from the origin, 1 unit apart")
def _far():
    P, N, C, cov = _sphere(24, radius=0.5, center=(1e5, -1e5, 1e5))
    lights = [dict(type="point", position=(1e5 + 0.6, -1e5 + 0.4, 1e5 + 0.8), intensity=1.0)]
    cam = dict(type="perspective", position=(1e5, -1e5, 1e5 + 3.0))
    return make_scene(lights, k_a=0.0, h=64.0, camera=cam), make_gbuffer(P, N, C, coverage=cov)


@case("half-float-positions", "positions", "positions stored as half floats (11-bit steps)")
def _half_positions():
    P, N, C, cov = _sphere(24, radius=3.0, center=(10.0, 0.0, 0.0))
    P = P.astype(np.float16).astype(np.float32)
    lights = [dict(type="point", position=(12.0, 2.0, 6.0), intensity=10.0, attenuation=(1, 0, 0.02))]
    cam = dict(type="perspective", position=(10.0, 0.0, 9.0))
    return make_scene(lights, h=50.0, camera=cam), make_gbuffer(P, N, C, coverage=cov)


# ------------------------------------------------------------------------ light sums

@case("lights-65536-12-decades", "sums", "65 536 lights whose contributions span 12 orders of magnitude")
def _many_lights():
    rng = np.random.default_rng(65536)
    n = 65536
    dirs = rng.normal(size=(n, 3))
    dirs[:, 2] = -np.abs(dirs[:, 2]) - 0.2
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    inten = 10.0 ** rng.uniform(-6, 6, n)
    lights = [Light(type="directional", direction=tuple(d), intensity=float(i))
              for d, i in zip(dirs, inten)]
    P = np.zeros((2, 4, 3))
    N = _tilted_normals(np.linspace(-0.5, 0.5, 8)).reshape(2, 4, 3)
    return make_scene(lights, h=16.0, camera=_ORTHO_DOWN), make_gbuffer(P, N, np.full((2, 4, 3), 0.5))


@case("negative-albedo-cancels", "sums", "negative albedo whose diffuse cancels the specular highlight")
def _cancel():
    P, N, C, cov = _sphere(24)
    C = np.full(P.shape, -0.05)
    lights = [dict(type="point", position=(1.0, 1.0, 4.0), intensity=3.0)]
    cam = dict(type="perspective", position=(1.0, 1.0, 5.0))
    return make_scene(lights, k_a=0.0, k_d=1.0, k_s=0.05, h=8.0, camera=cam), \
        make_gbuffer(P, N, C, coverage=cov)


@case("negative-albedo", "outputs", "negative albedo: a negative, finite result")
def _negative():
    scene, gb = _highlight("phong", 16.0)
    gb.albedo[...] = -np.abs(gb.albedo)
    return scene, gb


@case("nan-albedo", "outputs", "NaN albedo: counted, those pixels left as background", finite_inputs=False)
def _nan_albedo():
    scene, gb = _highlight("phong", 16.0)
    gb.albedo[5:9, 5:9, 1] = np.nan
    return scene, gb


@case("inf-position", "outputs", "±Inf positions: counted, those pixels left as background",
      finite_inputs=False)
def _inf_position():
    scene, gb = _highlight("phong", 16.0)
    gb.position[10, 10:14, 0] = np.inf
    gb.position[3, 3, 2] = -np.inf
    return scene, gb


@case("all-black", "outputs", "zero albedo and no specular: an all-black frame")
def _black():
    scene, gb = _highlight("phong", 16.0)
    gb.albedo[...] = 0.0
    scene = make_scene([dict(type="point", position=(1.0, 1.0, 4.0), intensity=3.0)], k_s=0.0)
    return scene, gb


@case("all-background", "outputs", "zero coverage everywhere: only the background value")
def _all_bg():
    scene, gb = _highlight("phong", 16.0)
    gb.coverage[...] = 0.0
    return make_scene([dict(type="ambient")], background=(0.1, 0.2, 0.3)), gb


@case("beyond-float-range", "outputs", "a true value above FLT_MAX saturates at FLT_MAX, never Inf")
def _beyond():
    P, N, C = _strip(4)
    lights = [dict(type="directional", direction=(0.0, 0.0, -1.0), intensity=3e38),
              dict(type="directional", direction=(0.0, 0.1, -1.0), intensity=3e38)]
    return make_scene(lights, k_a=0.0, k_d=1.0, k_s=0.0, camera=_ORTHO_DOWN), make_gbuffer(P, N, C)


@case("above-half-range", "outputs", "values above 65504 (written to half EXR: clamped with a warning)")
def _above_half():
    P, N, C = _strip(8)
    lights = [dict(type="directional", direction=(0.0, 0.0, -1.0), intensity=1e6)]
    return make_scene(lights, k_a=0.0, camera=_ORTHO_DOWN), make_gbuffer(P, N, C)


# --------------------------------------------------------------------------- spots

def _spot_over_plane(inner, outer, *, height=1.0, n=96, reach=None, model="phong", **light):
    """A spot at (0, 0, height) pointing down −z over a 1×n row of the z = 0 plane,
    the pixels' angles θ from the axis running from 0 to past the outer edge (and
    exactly through both edges)."""
    top = math.radians(min(outer * 1.25 + 1.0, 89.9)) if reach is None else reach
    theta = np.concatenate([np.linspace(0.0, top, n - 2),
                            [math.radians(inner), math.radians(outer) if outer < 90 else top]])
    theta.sort()
    P = np.zeros((1, n, 3))
    P[0, :, 0] = height * np.tan(theta)
    N = np.broadcast_to([0.0, 0.0, 1.0], (1, n, 3)).copy()
    lt = dict(type="spot", position=(0.0, 0.0, height), direction=(0.0, 0.0, -1.0),
              inner_angle=inner, outer_angle=outer, intensity=2.0, **light)
    scene = make_scene([lt, dict(type="ambient", intensity=0.01)], model=model,
                       camera=dict(type="perspective", position=(0.3, 0.2, 2.0)))
    return scene, make_gbuffer(P, N, np.ones((1, n, 3)))


@case("spot-cone-edges", "spots", "across a 20°/35° spot's cone: full inside, t² between, 0 outside")
def _spot_edges():
    return _spot_over_plane(20.0, 35.0)


@case("spot-inner-near-outer", "spots", "inner 30°, outer 30.05°: a hard edge, s = 1/(cos i − cos o) ≈ 2200")
def _spot_sharp():
    return _spot_over_plane(30.0, 30.05, n=128, reach=math.radians(30.1))


@case("spot-inner-zero", "spots", "inner 0°: the factor falls from the axis itself")
def _spot_inner0():
    return _spot_over_plane(0.0, 25.0, model="blinn-phong")


@case("spot-outer-90", "spots", "outer 90°: the factor reaches 0 only at the horizon (θ to 89.9°)")
def _spot_outer90():
    return _spot_over_plane(40.0, 90.0, height=0.05, attenuation=(1.0, 0.0, 0.5))


@case("spot-on-sphere-with-points", "spots", "spots and point lights on a sphere, in one light sum")
def _spot_sphere():
    P, N, C, cov = _sphere()
    lights = [dict(type="spot", position=(0.0, 0.0, 3.0), direction=(0.0, 0.1, -1.0),
                   inner_angle=5.0, outer_angle=15.0, intensity=4.0),
              dict(type="spot", position=(2.0, 1.0, 1.0), direction=(-2.0, -1.0, -1.0),
                   inner_angle=10.0, outer_angle=12.0, intensity=3.0, attenuation=(0.0, 0.0, 1.0)),
              dict(type="point", position=(-2.0, 1.0, 2.0), intensity=1.5),
              dict(type="ambient", intensity=0.05)]
    return make_scene(lights, model="blinn-phong"), make_gbuffer(P, N, C, coverage=cov)


# ------------------------------------------------------------------------- Fresnel

def _grazing_view(model, f0, n=96):
    """A row of normals tilting from facing the viewer (+z, orthographic) to 1e-6 rad
    short of edge-on, lit by directional lights near the mirror direction and near
    grazing, so that cos α (n·v or v·h) runs from 1 down to ~1e-6 and W from f0 to ~1."""
    a = np.concatenate([np.linspace(0.0, 1.5, n // 2),
                        math.pi / 2 - np.geomspace(1e-1, 1e-6, n - n // 2)])
    N = _tilted_normals(a)
    P = np.zeros((1, n, 3))
    P[0, :, 0] = np.linspace(-0.5, 0.5, n)
    lights = [dict(type="directional", direction=(-0.999, 0.0, -0.045), intensity=2.0),
              dict(type="directional", direction=(-0.6, 0.1, -0.8), intensity=1.0),
              dict(type="ambient", intensity=0.02)]
    scene = make_scene(lights, model=model, h=8.0, k_s=1.0, fresnel="schlick", f0=f0,
                       camera=_ORTHO_DOWN)
    return scene, make_gbuffer(P, N, np.ones((1, n, 3)))


@case("fresnel-grazing-phong", "fresnel", "Phong's W with cos α = n·v from 1 to 1e-6 (edge-on)")
def _fresnel_phong():
    return _grazing_view("phong", 0.04)


@case("fresnel-grazing-blinn", "fresnel", "Blinn's W with cos α = v·h, light near grazing on the far side")
def _fresnel_blinn():
    return _grazing_view("blinn-phong", 0.04)


@case("fresnel-rgb-f0-points", "fresnel", "RGB f0 (a metal) with point lights and a perspective camera")
def _fresnel_rgb():
    P, N, C, cov = _sphere()
    lights = [dict(type="point", position=(2.0, 1.0, 1.5), intensity=3.0),
              dict(type="point", position=(-1.5, 0.5, -0.2), intensity=2.0),   # behind the limb
              dict(type="ambient", intensity=0.05)]
    return (make_scene(lights, model="blinn-phong", h=16.0, k_s=1.0, fresnel="schlick",
                       f0=(0.95, 0.64, 0.54), camera=dict(type="perspective", position=(0.0, 0.0, 4.0))),
            make_gbuffer(P, N, C, coverage=cov))


@case("fresnel-f0-zero-phong", "fresnel", "f0 = 0: W = (1 − n·v)⁵ alone, 0 where the view is head-on")
def _fresnel_zero():
    P, N, C, cov = _sphere()
    lights = [dict(type="point", position=(0.5, 1.0, 3.0), intensity=3.0), dict(type="ambient")]
    return (make_scene(lights, model="phong", h=4.0, k_s=1.0, fresnel="schlick", f0=0.0,
                       camera=dict(type="perspective", position=(0.0, 0.0, 4.0))),
            make_gbuffer(P, N, C, coverage=cov))


# ----------------------------------------------------------------------- evaluation

@dataclass
class CaseResult:
    name: str
    group: str
    what: str
    pixels: int                 # shaded pixels
    band: int                   # pixels in the terminator band
    significant: int            # pixels held to TARGET_REL
    max_err_over_bound: float   # max over pixels and channels of |err|/bound (0/0 := 0)
    max_rel: float              # max relative error on the significant pixels
    bound_max: float = 0.0      # largest bound (∞ where the path gives no bound)
    nonfinite_in: dict = field(default_factory=dict)
    nonfinite_out: int = 0
    rgb: np.ndarray | None = None
    ref: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        return (self.max_err_over_bound <= 1.0 and self.nonfinite_out == 0
                and self.max_rel <= TARGET_REL)


def evaluate(hc: HardCase, **renderer_kwargs) -> CaseResult:
    """Shade ``hc`` (default path unless ``renderer_kwargs`` say otherwise) and compare."""
    import warnings

    scene, gb = hc.build()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        gb, counts = apply_nonfinite_policy(gb, "background")
    r = Renderer(scene, **renderer_kwargs)
    frame = prepare_frame(gb, lanes=max(r.lanes, 1))
    result = r.shade(frame)
    rgb, plan = result.image, result.plan        # plan: the variant that ran
    ref = reference.shade(scene, gb)
    bound, band = reference.error_bound(scene, gb, origin=frame.origin, plan=plan)
    err = np.abs(rgb.astype(np.float64) - ref)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(err == 0.0, 0.0, err / bound)
    fg = ~gb.background_mask()
    sig = significant(ref, fg, band)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = err[sig] / np.abs(ref[sig])
    return CaseResult(
        name=hc.name, group=hc.group, what=hc.what, pixels=int(fg.sum()), band=int(band.sum()),
        significant=int(sig.any(axis=-1).sum()),
        max_err_over_bound=float(np.max(ratio, initial=0.0)),
        bound_max=float(np.max(bound[fg], initial=0.0)),
        max_rel=float(np.max(rel, initial=0.0)),
        nonfinite_in={k: v for k, v in counts.items() if v},
        nonfinite_out=int((~np.isfinite(rgb)).any(axis=-1).sum()),
        rgb=rgb, ref=ref)


def table(results) -> str:
    """The results as a Markdown table."""
    rows = []
    for r in results:
        nin = ", ".join(f"{k} {v}" for k, v in r.nonfinite_in.items()) or "0"
        ratio = "∞ bound" if math.isinf(r.bound_max) else f"{r.max_err_over_bound:.3f}"
        rows.append([r.name, r.group, r.pixels, r.band, ratio, f"{r.max_rel:.2e}",
                     f"{nin} → {r.nonfinite_out}", "yes" if r.ok else "NO"])
    return markdown_table(["case", "group", "shaded px", "band px", "max \\|err\\|/bound",
                           "max rel err", "non-finite in → out", "ok"], rows)


def sample_cases(folder) -> list[HardCase]:
    """Each ``NAME.toml`` of ``folder`` with its ``NAME.exr`` (the shipped samples),
    as a case held to the same bound and target."""
    from pathlib import Path

    cases = []
    for toml in sorted(Path(folder).glob("*.toml")):
        exr = toml.with_suffix(".exr")
        if exr.exists():
            cases.append(HardCase(name=toml.stem, group="samples", what=f"{toml} with {exr.name}",
                                  build=lambda t=toml, e=exr: (load_scene(t), read_gbuffer(e))))
    return cases


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m clphong.tools.hardcases",
                                description="Run the hard-case suite and print its table.")
    p.add_argument("--fp32-directions", action="store_true",
                   help="use the float32-directions fast path instead of the default")
    p.add_argument("--kernel", choices=tuple(KERNELS), default="lanes",
                   help="the lane kernel (default) or the one-pixel-per-work-item baseline")
    p.add_argument("-k", metavar="SUBSTRING", help="only cases whose name contains this")
    p.add_argument("--samples", nargs="?", const="gbuffers", metavar="DIR",
                   help="instead of the hard cases, the samples of DIR (default gbuffers/): "
                        "each NAME.toml with its NAME.exr")
    args = p.parse_args(argv)
    kw = {"fp64_directions": False} if args.fp32_directions else {}
    if args.kernel != "lanes":
        kw["kernel"] = args.kernel
    cases = CASES
    if args.samples is not None:
        cases = sample_cases(args.samples)
        if not cases:
            p.error(f"{args.samples}: no NAME.toml with a NAME.exr beside it")
    chosen = [c for c in cases if not args.k or args.k in c.name]
    if not chosen:
        p.error(f"no case name contains {args.k!r}; cases: {', '.join(c.name for c in cases)}")
    results = [evaluate(c, **kw) for c in chosen]
    try:
        print(table(results))
        print(f"\n{sum(r.ok for r in results)}/{len(results)} within the bound and the target "
              f"(relative error ≤ {TARGET_REL:g} on pixels ≥ {SIGNIFICANT:g} of the max, off band)")
        if any(math.isinf(r.bound_max) for r in results):
            print("∞ bound: the float path's range does not cover these pixels (d², c2·d² or the "
                  "falloff outside float's normal range); its error there is not bounded")
        sys.stdout.flush()
    except BrokenPipeError:                 # e.g. | head
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
