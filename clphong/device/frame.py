"""A G-buffer and a scene laid out for the kernels: float32 planes and light records.

:func:`prepare_frame` turns a :class:`~clphong.io.gbuffer.GBuffer` into the
padded planes the kernels read (see ``kernels/include/clphong.h``);
:func:`pack_lights` packs the scene's lights as records, rebased on the frame's
origin for the float path; :func:`material_uniforms` gives the material's
kernel arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import SceneError
from ..core.floats import F32_ROUNDS_TO_INF, FLT_MAX, FLT_MIN, U
from ..core.geometry import (
    half_vector,
    nearest_within,
    origin_of_bounds,
    position_bounds,
    split_hi_lo,
    unit_normal_planes,
    view_vector,
)
from ..model.scene import MATERIAL_MAPS
from .culling import POINT_RECORD
from .plan import FAR_LIGHT

#: Work-items per work-group. PoCL runs anything from 8 to ~1000 equally well
#: and 1 badly (POCL-NOTES "Local size").
LOCAL_SIZE = 64
#: Planes of Frame.gbuf: P xyz, unit N xyz (float), C_d rgb, N's float64 remainder xyz
#: (and, with partly covered pixels, the coverage α: COVERAGE_PLANE).
GBUF_PLANES = 12
COVERAGE_PLANE = 12


@dataclass
class Frame:
    """A G-buffer laid out for the kernels: float32 planes, padded.

    ``gbuf`` holds the planes Px Py Pz Nx Ny Nz Cr Cg Cb, ``stride`` floats
    each. N is unit (normalised in float64 here) and exactly 0 on background
    pixels; P is as stored. ``origin`` is the float32 point the kernel subtracts
    from P (and the host from every light) so that distances keep their digits.
    """

    gbuf: np.ndarray
    maps: np.ndarray
    map_names: tuple[str, ...]
    shape: tuple[int, int]
    stride: int
    origin: np.ndarray        # (3,) float32
    background: np.ndarray    # (H*W,) bool
    coverage: bool = False    # gbuf has the α plane: some pixel is partly covered
    bounds: tuple[np.ndarray, np.ndarray] | None = None   # (lo, hi) float64 of the shaded P

    @property
    def pixels(self) -> int:
        return self.shape[0] * self.shape[1]


def prepare_frame(gbuffer, *, lanes: int = 16) -> Frame:
    """Lay out a :class:`~clphong.io.gbuffer.GBuffer` as kernel planes."""
    h, w = gbuffer.shape
    n = h * w
    block = lanes * LOCAL_SIZE
    stride = max(block, math.ceil(n / block) * block)
    background = gbuffer.background_mask().reshape(-1)
    partial = gbuffer.partly_covered()
    gbuf = np.empty((GBUF_PLANES + partial, stride), np.float32)
    gbuf[:, n:] = 0.0                                       # padding: background
    # P and C: one transposing copy each, (n, 3) rows to 3 planes
    gbuf[0:3, :n] = gbuffer.position.reshape(-1, 3).T
    gbuf[6:9, :n] = gbuffer.albedo.reshape(-1, 3).T
    for a, n64 in enumerate(unit_normal_planes(gbuffer.normal)):
        np.copyto(n64, 0.0, where=background)
        gbuf[3 + a, :n] = n64
        # The float64 remainder of the unit normal, for DIRECTIONS_FP64 (shade.cl), formed in
        # place: n64 is not needed after this (no float64 temporary).
        gbuf[9 + a, :n] = np.subtract(n64, gbuf[3 + a, :n], out=n64)
    if partial:
        gbuf[COVERAGE_PLANE, :n] = np.clip(gbuffer.coverage.reshape(-1), 0.0, 1.0)
    names = []
    planes = []
    for name, channels in MATERIAL_MAPS.items():             # the kernels' order
        if name in gbuffer.maps:
            names.append(name)
            planes.append(gbuffer.maps[name].reshape(-1, channels).T)
    if planes:
        stacked = np.concatenate(planes, axis=0)
        maps = np.zeros((stacked.shape[0], stride), np.float32)
        maps[:, :n] = stacked
    else:
        maps = np.zeros((1, lanes), np.float32)
    # The origin from the position planes just written: the same float32 values, per axis
    # a contiguous plane rather than every third float of the rows (2x faster).
    position = gbuf[:3, :n].T if gbuffer.position.dtype == np.float32 else gbuffer.position
    bounds = position_bounds(position, background)
    return Frame(gbuf=gbuf, maps=maps, map_names=tuple(names), shape=(h, w), stride=stride,
                 origin=origin_of_bounds(*bounds), background=background,
                 coverage=partial, bounds=bounds)


@dataclass(frozen=True)
class LightArrays:
    """The scene's lights packed as the kernels read them (see kernels/clphong.h)."""

    point: np.ndarray        # (n_point*POINT_RECORD, 4) float32: the float path's (and cull.py's source)
    point64: np.ndarray      # the same records in float64, not rebased, for DIRECTIONS_FP64
    directional: np.ndarray  # (n_dir*6, 4) float32
    ambient: np.ndarray      # (3,) float64: k_a·Σ ambient radiance
    eye: np.ndarray          # (3,) float64: perspective eye − origin, or orthographic unit v
    eye64: np.ndarray        # (3,) float64: perspective eye (not rebased), or unit v
    group_table: np.ndarray = None    # (2·max(G, 1),) uint32: directional ends, point ends
    group_ambient: np.ndarray = None  # (2·max(G, 1), 4) float32: k_a·A_g as hi, lo rows

    def kernel_eye(self, fp64: bool) -> tuple[np.ndarray, np.ndarray]:
        """The shading kernel's (eye, eye_lo): with DIRECTIONS_FP64 the eye as it
        is, float32 hi + lo (lo = eye − hi, rounded); else rebased, and lo = 0."""
        return split_hi_lo(self.eye64) if fp64 else (self.eye, np.zeros(3))



def shading_records(records: np.ndarray, has_spot: bool, *, quarter: bool = False) -> np.ndarray:
    """Point records as the shading kernels read them (POINT_LIGHT_FLOAT4S, plan.h):
    all POINT_RECORD float4s with spots, else the first 3 (a point light's fourth,
    its cone (0, 1), is not read): fewer bytes gathered through the tile lists.

    ``quarter`` (the lane kernel's float path): the (rebased float32) positions × 1/4,
    c1 × 4 and c2 × 16, all exact (a position below 2⁻¹²⁴ becomes subnormal, which the
    kernel flushes; a 4c1 or 16c2 beyond float is clipped to ±FLT_MAX, never ±∞, so
    Horner meets no ∞ − ∞ and d = 0 no ∞·0: the error model calls such a light's pixels
    unbounded). The kernel quarters P − origin too, so its d²/16, 4/d and d/4
    carry the bits of d², 1/d and d, with no scalings or selects in the loop
    (RSQRT_LIGHT, kernels/include/clphong.h)."""
    k = POINT_RECORD if has_spot else 3
    out = np.array(records.reshape(-1, POINT_RECORD, 4)[:, :k])   # a copy, float32 or float64
    if quarter:
        assert out.dtype == np.float32, "the float path's records are quartered, not the fp64 path's"
        with np.errstate(over="ignore"):
            out[:, 0, :3] *= np.float32(0.25)
            out[:, 1, 3] *= np.float32(4.0)
            out[:, 2, 0] *= np.float32(16.0)
        np.clip(out[:, 1, 3], -FLT_MAX, FLT_MAX, out=out[:, 1, 3])
        np.clip(out[:, 2, 0], -FLT_MAX, FLT_MAX, out=out[:, 2, 0])
    return out.reshape(-1, 4)


def _check_reach(scene, o: np.ndarray, rebased: np.ndarray) -> None:
    """Refuse a point light (``rebased``: the positions minus the frame origin ``o``)
    or eye that lies beyond float32 from the frame (one end of the range against
    positions at the other): it would round to ±inf, and the pixels to NaN."""
    reach = np.abs(rebased).max(axis=1, initial=0.0)
    far = None
    if reach.size and reach.max() >= F32_ROUNDS_TO_INF:
        points = list(scene.light_arrays["point_index"])
        far = (f"light[{points[int(np.argmax(reach))]}].position", reach.max())
    elif scene.camera.type == "perspective":
        x = np.abs(np.asarray(scene.camera.position) - o).max()
        if x >= F32_ROUNDS_TO_INF:
            far = ("camera.position", x)
    if far is not None:
        centre = ", ".join(f"{c:.3g}" for c in o)
        raise SceneError(f"{scene.source}: {far[0]} lies {float(far[1]):.3g} units along an axis "
                         f"from this frame's positions (centred near ({centre})), beyond the "
                         "float32 range the kernels compute in (3.4e38)")


def pack_lights(scene, origin: np.ndarray) -> LightArrays:
    """Point lights as float64 records as they are (the fp64 path's: it does not
    rebase, L − P in double is correctly rounded from them and the float32 P) and
    as float32 records rebased on ``origin`` in float64 (the float path's, and
    culling's); other lights as float32 records with hi+lo remainders."""
    o = np.asarray(origin, np.float64)
    arrays = scene.light_arrays
    n_pts = len(arrays["point_position"])
    rec = np.zeros((max(n_pts, 1), POINT_RECORD, 4))   # culling.POINT_RECORD's layout
    rec[:n_pts, 0, :3] = arrays["point_position"]
    if n_pts:
        att = arrays["point_attenuation"]
        rec[:, 0, 3] = att[:, 0]
        rec[:, 1, :3] = arrays["point_radiance"]
        rec[:, 1, 3] = att[:, 1]
        rec[:, 2, 0] = att[:, 2]
        cone = arrays["point_cone"]
        rec[:, 2, 1:4] = cone[:, :3]           # a spot's axis (0 for a point light)
        rec[:, 3, 0:2] = cone[:, 3:5]          # (s, o): (0, 1) for a point light
    point64 = rec.reshape(-1, 4).copy()
    rec[:n_pts, 0, :3] -= o
    _check_reach(scene, o, rec[:n_pts, 0, :3])
    point = rec.reshape(-1, 4).astype(np.float32)
    n_dirs = len(arrays["directional_direction"])
    directional = np.zeros((max(n_dirs, 1) * 6, 4), np.float32)
    v = view_vector(scene.camera)
    if n_dirs:
        rec = np.zeros((n_dirs, 6, 4))
        l = -arrays["directional_direction"]
        rec[:, 0, :3] = l
        rec[:, 3, :3] = split_hi_lo(l)[1]
        rec[:, 1, :3] = arrays["directional_radiance"]
        rec[:, 5, :3] = split_hi_lo(arrays["directional_radiance"])[1]
        if v is not None:
            hv, undefined = half_vector(l, v)
            rec[:, 2, :3] = hv
            rec[:, 4, :3] = split_hi_lo(hv)[1]
            rec[:, 2, 3] = np.where(undefined, 1.0, 0.0)
        directional = rec.reshape(-1, 4).astype(np.float32)
    amb = arrays["ambient_radiance"] * scene.material.k_a
    eye64 = v if v is not None else np.asarray(scene.camera.position, np.float64)
    eye = eye64 if v is not None else eye64 - o
    G = len(scene.light_groups)
    table = np.zeros(2 * max(G, 1), np.uint32)
    gamb = np.zeros((2 * max(G, 1), 4), np.float32)
    if G:
        table[:G] = arrays["directional_group_end"]
        table[G:] = arrays["point_group_end"]
        hi, lo = split_hi_lo(arrays["ambient_group_radiance"] * scene.material.k_a)
        gamb[0:2 * G:2, :3] = hi
        gamb[1:2 * G:2, :3] = lo
    return LightArrays(point=point, point64=point64, directional=directional, ambient=amb,
                       eye=eye, eye64=eye64, group_table=table, group_ambient=gamb)


#: On the float path a pixel nearer a light than this has d² flushed to 0 (the
#: d = 0 guard: no contribution), so its falloff cannot overflow there.
FLOAT_PATH_INNER = math.sqrt(FLT_MIN) * (1 - 64 * U)


def near_field_radius(c1, c2, radiance, fp64: bool):
    """The distance below which a point light with ``c0 = 0`` overflows the kernels.

    With ``c0 = 0`` (and ``c1, c2 >= 0``) the falloff ``1/p(d)``, ``p(d) = c1*d +
    c2*d^2``, grows without bound as d -> 0. A pixel at ``0 < d < radius`` would
    take ``radiance x 1/p(d)`` beyond float32 (the kernels store it in float, or
    saturate the sum to FLT_MAX): ``p(d)`` must stay above ``radiance x (1 +
    16u) / FLT_MAX``, with p's own rounding (4u, doubled, docs/error-model.md row
    "attenuation 1/p(d)": κ_p = 1 here). On the float path p is formed in float
    and flushed to 0 below FLT_MIN, so it must also stay above 4·FLT_MIN where
    d² is a normal float (:data:`FLOAT_PATH_INNER`; nearer, d² flushes to 0 and
    the d = 0 guard adds nothing: wrong, but finite, and ``error_bound`` says ∞).
    Arrays of the lights' coefficients and largest radiance component.
    """
    c1 = np.asarray(c1, np.float64)
    c2 = np.asarray(c2, np.float64)
    q = np.asarray(radiance, np.float64) * (1 + 16 * U) / FLT_MAX
    if not fp64:
        q = np.maximum(q, 4 * FLT_MIN)
    q = q / (1 - 8 * U)
    with np.errstate(divide="ignore", invalid="ignore"):
        # the positive root of c2·d² + c1·d = q, in the stable form
        d = 2 * q / (c1 + np.sqrt(c1 * c1 + 4 * c2 * q))
    return np.where(np.isfinite(d), d, 0.0) * (1 + 64 * U)


def has_far_lights(frame: Frame, lights: LightArrays) -> bool:
    """Whether some point light may lie :data:`~clphong.device.plan.FAR_LIGHT` (2⁶⁴) or
    more from a shaded pixel of ``frame`` (the reach of the rebased records plus the
    pixels' bounding box about the frame's origin, an upper bound): the float lanes loop
    then needs POINT_GUARD (clphong.h RSQRT_LIGHT's cap)."""
    recs = lights.point.reshape(-1, POINT_RECORD, 4)[:, 0, :3].astype(np.float64)
    reach = float(np.sqrt((recs * recs).sum(axis=1)).max(initial=0.0))
    n = frame.pixels
    lo, hi = frame.bounds if frame.bounds is not None else \
        position_bounds(frame.gbuf[:3, :n].T, frame.background[:n])
    if not np.all(np.isfinite(lo)):
        return False                       # no shaded pixel
    o = frame.origin.astype(np.float64)
    half = np.maximum(np.abs(hi - o), np.abs(lo - o))
    return reach + float(np.sqrt((half * half).sum())) >= FAR_LIGHT


def check_near_field(scene, frame: Frame, lights: LightArrays, fp64: bool) -> None:
    """Refuse a frame in which a point light with ``c0 = 0`` (e.g. 1/d²) is so
    near a shaded pixel that its falloff overflows float32 there.

    The scene loader cannot know the distances; this is that check, per frame,
    at the nearest shaded pixel to each such light (:func:`near_field_radius`).
    The distances are those the kernel of the path forms: from the float32
    positions and the float64 light records with ``fp64`` directions, else from
    the rebased float32 positions and records. A pixel exactly at the light
    (d = 0) adds nothing and is not an error.

    Raises
    ------
    SceneError
        Naming the light, the pixel, its distance and the falloff's value there.
    """
    points = list(scene.light_arrays["point_index"])
    recs = (lights.point64 if fp64 else lights.point.astype(np.float64)).reshape(
        -1, POINT_RECORD, 4)[:len(points)]
    physical = np.flatnonzero(recs[:, 0, 3] == 0) if len(points) else np.zeros(0, int)
    if physical.size == 0:
        return
    r = recs[physical]
    radius = near_field_radius(r[:, 1, 3], r[:, 2, 0], np.abs(r[:, 1, :3]).max(axis=1), fp64)
    if not radius.any():
        return
    n = frame.pixels
    hits = nearest_within(frame.gbuf[:3, :n], ~frame.background[:n], r[:, 0, :3], radius,
                          inner=0.0 if fp64 else FLOAT_PATH_INNER,
                          rebase=None if fp64 else frame.origin)   # the float kernel's P − origin
    for k, hit in zip(physical, hits):
        if hit is None:
            continue
        pixel, d = hit
        c1, c2 = recs[k, 1, 3], recs[k, 2, 0]
        value = float(np.abs(recs[k, 1, :3]).max()) / (c1 * d + c2 * d * d)
        y, x = divmod(pixel, frame.shape[1])
        i = points[k]
        raise SceneError(
            f"{scene.source}: light[{i}]: the frame's pixel x={x}, y={y} is {d:.3g} units from this point "
            f"light, where its radiance x 1/(c1*d + c2*d^2) = {value:.3g} is beyond the float32 "
            f"range the kernels compute in ({FLT_MAX:.3g}{'' if fp64 else ', or p(d) below FLT_MIN on the float path'}); "
            "move the light off the surface, or give attenuation c0 > 0")


def material_uniforms(scene, map_names) -> tuple[float, np.ndarray, float]:
    """(k_d, S_uniform, exponent) kernel arguments; maps replace uniform values."""
    m = scene.material
    cs = np.asarray(m.specular_color, np.float64)
    ks = 1.0 if "k_s" in map_names else m.k_s
    S = (np.ones(3) if "specular_color" in map_names else cs) * ks
    return m.k_d, S, m.exponent
