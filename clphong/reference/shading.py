"""The float64 reference: a numpy mirror of every kernel function.

Each function here has the name, argument order and guards of its twin in
``kernels/*.cl``, evaluated in float64 on the same float32 G-buffer values. It is
the oracle for every kernel test and every error figure (``clphong bench``).

:func:`error_bound` is the error model of the float32 kernels
(``docs/error-model.md``): for each pixel and channel it returns an upper bound
of |kernel − reference| built from the operation count of each term, the
conditioning of each term, and the documented guards. Tests compare the kernels
to the reference with exactly this bound; nothing is tuned to pass.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..core.floats import FLT_MAX, FLT_MIN, U_D, U
from ..core.geometry import half_vector, unit_normal_planes, view_vector


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


# --------------------------------------------------------------------------- brdf.cl

def lambert(NoL):
    """Lambert's cosine law: max(n·l, 0)."""
    return np.maximum(NoL, 0.0)


def phong_delta(n, l, v, NoL):
    """δ = 1 − r·v = |r − v|²/2 with r = 2n(n·l) − l (unit vectors)."""
    e = 2.0 * NoL[..., None] * n - l - v
    return 0.5 * _dot(e, e)


def blinn_delta(n, l, v):
    """δ = 1 − n·h = |n − h|²/2, h = (l + v)/|l + v|; δ = 1 where l = −v."""
    hv = l + v
    hh = _dot(hv, hv)
    with np.errstate(invalid="ignore", divide="ignore"):
        h = hv / np.sqrt(hh)[..., None]
    e = n - h
    return np.where(hh <= 0.0, 1.0, 0.5 * _dot(e, e))


def blinn_delta_const_h(n, h, undefined=False):
    """δ = |n − h|²/2 for a half vector constant per light; 1 if it is undefined."""
    e = n - h
    return np.where(undefined, 1.0, 0.5 * _dot(e, e))


def specular_power(delta, k):
    """max(1 − δ, 0)^k as exp(k·log1p(−δ)); 0 for δ ≥ 1 unless k = 0 (0⁰ := 1)."""
    k = np.broadcast_to(np.asarray(k, np.float64), np.shape(delta))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        s = np.exp(k * np.log1p(-np.minimum(delta, 1.0)))
    return np.where(delta >= 1.0, np.where(k == 0.0, 1.0, 0.0), s)


def phong_cos(l, v, NoL, NoV):
    """max(r·v, 0) with r·v = 2(n·l)(n·v) − l·v (SPEC_COS: the cosine itself, in
    double); NaN stays NaN."""
    x = 2.0 * NoL * NoV - _dot(l, v)
    return np.where(x <= 0.0, 0.0, x)


def blinn_cos_sq(l, v, NoL, NoV):
    """(n·h)² = (n·l + n·v)²/|l + v|² where n·h > 0, else 0; 0 where l = −v; capped
    at 1 where |l + v| is rounding noise (SPEC_COS). The kernel's guards: max(q, 0)²
    over max(|l + v|², FLT_MIN), then min(·, 1), a NaN q counting as 0."""
    hv = l + v
    hh = _dot(hv, hv)
    q0 = NoL + NoV
    q = np.where(q0 > 0.0, q0, 0.0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        y = q * q / np.where(hh > FLT_MIN, hh, FLT_MIN)
    return np.where(y < 1.0, y, 1.0)


def blinn_cos_sq_const_h(n, h, undefined=False):
    """(n·h)² where n·h > 0, else 0, for a half vector constant per light; 0 if undefined."""
    x = _dot(n, h)
    return np.where(undefined | ~(x > 0.0), 0.0, x * x)


def specular_power_cos(x, K: int):
    """x^K for x ≥ 0 (the callers clamp) by binary powering, K a whole number ≥ 0
    (SPEC_INT_POW); 0⁰ := 1; a NaN x stays NaN, also for K = 0."""
    K = int(K)
    if K < 0:
        raise ValueError(f"K must be a whole number ≥ 0, not {K}")
    x = np.asarray(x, np.float64)
    if K == 0:
        return np.where(np.isnan(x), np.nan, 1.0)
    s = x if K & 1 else np.ones_like(x)
    b = x
    e = K >> 1
    while e:
        b = b * b
        if e & 1:
            s = s * b
        e >>= 1
    return s


def specular_power_int(delta, K: int):
    """max(1 − δ, 0)^K: :func:`specular_power_cos` of 1 − δ (0 for δ ≥ 1; NaN stays NaN).

    The same function as :func:`specular_power` (to float64 rounding); the
    kernel's twin computes it this way, in double.
    """
    delta = np.asarray(delta, np.float64)
    return specular_power_cos(np.where(delta >= 1.0, 0.0, 1.0 - delta), K)


# ------------------------------------------------------------------------- lights.cl

def attenuation(c0, c1, c2, d):
    """1/(c0 + c1·d + c2·d²)."""
    return 1.0 / (c0 + d * (c1 + d * c2))


@dataclass
class Pixels:
    """The per-pixel shading inputs (float64), shaded pixels only."""

    p: np.ndarray   # (M, 3) position
    n: np.ndarray   # (M, 3) unit normal
    v: np.ndarray   # (M, 3) unit direction to the viewer
    k: np.ndarray   # (M,) specular exponent: h (Phong) or 4h (Blinn)
    blinn: bool
    specular: bool
    f0: np.ndarray | None = None   # (3,) Schlick's f0 with material.fresnel, else None
    S_base: np.ndarray | None = None   # (M, 3) Phong with Fresnel: k_s·C_s before W


def shade_direction(px: Pixels, l, NoL):
    """(diffuse, specular) weights for unit l; specular only where n·l > 0."""
    diffuse = lambert(NoL)
    if not px.specular:
        return diffuse, np.zeros_like(diffuse)
    if px.blinn:
        delta = blinn_delta(px.n, l, px.v)
    else:
        delta = phong_delta(px.n, l, px.v, NoL)
    return diffuse, np.where(NoL > 0.0, specular_power(delta, px.k), 0.0)


def schlick_weight(cos_a):
    """(1 − cos α)⁵ for cos α clamped to [0, 1] (brdf.h)."""
    return (1.0 - np.clip(cos_a, 0.0, 1.0)) ** 5


def v_dot_h(l, v):
    """cos α = v·h = √((1 + l·v)/2) for h = (l + v)/|l + v| (lights.h); 0 at l = −v."""
    return np.sqrt(np.maximum(0.5 * (1.0 + _dot(l, v)), 0.0))


def spot_factor(l, axis, s, o):
    """A spot's cone factor t², t = clamp(cos θ·s + o, 0, 1), cos θ = −l·axis
    (lights.h; a point light: axis 0, s = 0, o = 1, the factor 1)."""
    t = np.clip(-_dot(l, axis) * s + o, 0.0, 1.0)
    return t * t


def shade_point_light(px: Pixels, L, c0, c1, c2, cone=None):
    """Weights of a point light at L, times attenuation(d) (and, with ``cone`` =
    (axis, s, o), a spot's :func:`spot_factor`); nothing when d = 0."""
    dv = np.asarray(L, np.float64) - px.p
    d2 = _dot(dv, dv)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.sqrt(d2)
        l = dv / d[..., None]
    NoL = np.where(d2 <= 0.0, 0.0, _dot(px.n, l))
    l = np.where((d2 <= 0.0)[..., None], 0.0, l)
    diffuse, specular = shade_direction(px, l, NoL)
    with np.errstate(divide="ignore"):
        # d = 0: no contribution, also where c0 = 0 makes the falloff infinite.
        att = np.where(d2 <= 0.0, 0.0, attenuation(c0, c1, c2, d))
    if cone is not None:
        att = att * spot_factor(l, *cone)
    return diffuse * att, specular * att


def shade_directional_light(px: Pixels, l, h=None, h_undefined=False):
    """Weights of a directional light (unit l towards it); constant h if given."""
    l = np.asarray(l, np.float64)
    NoL = _dot(px.n, l)
    if h is not None and px.blinn and px.specular:
        delta = blinn_delta_const_h(px.n, np.asarray(h, np.float64), h_undefined)
        return lambert(NoL), np.where(NoL > 0.0, specular_power(delta, px.k), 0.0)
    return shade_direction(px, np.broadcast_to(l, NoL.shape + (3,)), NoL)


# -------------------------------------------------------------------------- shade.cl

def _inputs(scene, gbuffer):
    """Shaded-pixel inputs and per-pixel material, in float64."""
    bg = gbuffer.background_mask().reshape(-1)
    fg = ~bg
    P = gbuffer.position.reshape(-1, 3)[fg].astype(np.float64)
    N = gbuffer.normal.reshape(-1, 3)[fg].astype(np.float64)
    n = np.stack(unit_normal_planes(N), axis=-1)     # as the kernels' host side
    C = gbuffer.albedo.reshape(-1, 3)[fg].astype(np.float64)
    m = scene.material
    maps = gbuffer.maps
    k_d = maps["k_d"].reshape(-1)[fg].astype(np.float64) if "k_d" in maps else m.k_d
    k_s = maps["k_s"].reshape(-1)[fg].astype(np.float64) if "k_s" in maps else m.k_s
    h = maps["h"].reshape(-1)[fg].astype(np.float64) if "h" in maps else np.full(len(P), m.h)
    Cs = (maps["specular_color"].reshape(-1, 3)[fg].astype(np.float64)
          if "specular_color" in maps else np.asarray(m.specular_color, np.float64))
    D = C * np.asarray(k_d)[..., None] if np.ndim(k_d) else C * k_d
    S = Cs * (np.asarray(k_s)[..., None] if np.ndim(k_s) else k_s) * np.ones((len(P), 3))
    blinn = m.model == "blinn-phong"
    k = 4.0 * h if blinn else h
    # The kernel's exponent is a float32 that -cl-denorms-are-zero flushes: an h
    # below FLT_MIN is 0 there (and 0⁰ := 1), so it is here.
    k = np.where(np.abs(k) < FLT_MIN, 0.0, k)
    v_ortho = view_vector(scene.camera)
    if v_ortho is not None:
        v = np.broadcast_to(v_ortho, P.shape)
    else:
        # A pixel exactly at the eye is seen head-on: v := n (shade.cl's guard).
        e = np.asarray(scene.camera.position, np.float64) - P
        de = np.sqrt(_dot(e, e))[..., None]
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.where(de > 0, e / de, n)
    specular = m.k_s > 0 or "k_s" in maps
    f0 = None
    if m.fresnel == "schlick" and specular:
        f0 = np.asarray(m.f0, np.float64)
        if not blinn:
            # Phong: cos α = n·v, one W = f0 + (1 − f0)(1 − n·v)⁵ per pixel (shade.cl)
            S_base = S
            S = S * (f0 + (1.0 - f0) * schlick_weight(_dot(n, v))[:, None])
    px = Pixels(p=P, n=n, v=v, k=k, blinn=blinn, specular=specular, f0=f0,
                S_base=S_base if f0 is not None and not blinn else None)
    return px, C, D, S, fg


def specular_rgb(px: Pixels, S, specular, l):
    """S·w_s per light, pixel and channel, (K, M, 3): with Blinn-Phong's Fresnel the
    per-light W = f0 + (1 − f0)(1 − v·h)⁵ (Phong's W is in S already, :func:`_inputs`)."""
    if px.f0 is None or not px.blinn:
        return S * specular[..., None]
    W = px.f0 + (1.0 - px.f0) * schlick_weight(v_dot_h(l, px.v))[..., None]
    return S * W * specular[..., None]


#: Pixel-light pairs evaluated at once by the reference (memory ~ 100 bytes each).
BATCH_PAIRS = 1 << 20


def _light_terms(scene, px: Pixels):
    """Yield (kind, L, params, diffuse, specular) per batch of K lights of one kind.

    Lights run along a leading axis: ``L`` (K, 1, 3) radiance, ``diffuse`` and
    ``specular`` (K, M) weights; ``params`` holds the batch's positions (K, 1, 3)
    and attenuation coefficients (K, 1) for point lights, or unit l (K, 1, 3)
    for directional ones. Every function above broadcasts over that axis.
    """
    v_ortho = view_vector(scene.camera)
    K = max(1, BATCH_PAIRS // max(len(px.p), 1))
    arrays = scene.light_arrays
    dirs, dir_L = arrays["directional_direction"], arrays["directional_radiance"]
    for a in range(0, len(dirs), K):
        l = -dirs[a:a + K, None, :]
        L = dir_L[a:a + K, None, :]
        if v_ortho is not None:
            h, undefined = half_vector(l, v_ortho)              # (K, 1, 3), (K, 1)
            diffuse, specular = shade_directional_light(px, l, h, undefined)
        else:
            diffuse, specular = shade_directional_light(px, l)
        yield "directional", L, {"l": l}, diffuse, specular
    pts, pt_L, pt_c = arrays["point_position"], arrays["point_radiance"], arrays["point_attenuation"]
    cones, spots = arrays["point_cone"], arrays["point_is_spot"]
    for a in range(0, len(pts), K):
        pos = pts[a:a + K, None, :]
        L = pt_L[a:a + K, None, :]
        c = pt_c[a:a + K, :, None]                                                 # (K, 3, 1)
        cone = None
        if spots[a:a + K].any():
            q = cones[a:a + K]
            cone = (q[:, None, :3], q[:, 3:4], q[:, 4:5])              # (K, 1, 3), (K, 1) × 2
        diffuse, specular = shade_point_light(px, pos, c[:, 0], c[:, 1], c[:, 2], cone)
        l = None
        if px.f0 is not None and px.blinn:             # v·h per light (specular_rgb)
            dv = pos - px.p
            dd = np.sqrt(_dot(dv, dv))[..., None]
            with np.errstate(invalid="ignore", divide="ignore"):
                l = np.where(dd > 0, dv / dd, 0.0)
        yield "point", L, {"position": pos, "c": (c[:, 0], c[:, 1], c[:, 2]), "cone": cone, "l": l}, \
            diffuse, specular


def Lc_max(L):
    """The largest |radiance| channel of each light (over the last axis)."""
    return np.max(np.abs(L), axis=-1)


def _specular_error(px: Pixels, l, NoL, eps_NoL, eta_l, eta_v, eta_n, k, form, ud=U, r_out=0.0,
                    uw=U):
    """(absolute error bound, upper bound of the value) of the specular power.

    Ungated by n·l: the caller applies the terminator rule. ``ud`` is the unit
    roundoff of the direction arithmetic (u in float, 2⁻⁴⁷ with hi+lo inputs in
    double), ``r_out`` the rounding of δ to float afterwards (0 or u), ``uw``
    the rounding of the integer power's result (u to float, 2⁻⁵³ with
    WEIGHTS_FP64).
    """
    if px.blinn:
        delta = blinn_delta(px.n, l, px.v)
        lv = np.sqrt(_dot(l + px.v, l + px.v))
        with np.errstate(divide="ignore"):
            # h = (l + v)/|l + v| turns direction errors of l and v into
            # (η_l + η_v)/|l + v|: Blinn's half vector is ill-conditioned as l → −v.
            e_vec = eta_n + 2.0 * (eta_l + eta_v + 2.0 * ud) / lv
            # SPEC_COS: n·(l + v) and |l + v|² in double, off by the roundings and
            # the unit vectors' length errors (≤ ud each), ≤ 4ud/|l + v| in x = n·h.
            # "cos32" (the fast path, all in float): n·l and n·v 3u each, their sum
            # u·|q| ≤ 2u, so ≤ 8u in q = n·(l + v), 8u/|l + v| in n·h = q/|l + v|;
            # |l + v|² relative ≤ 5u, q² u, the division 2.5 ulp (5u): ≤ 5.5u more
            # in n·h ≤ 1 (docs/error-model.md).
            e_cos = 8.0 * ud / lv if form != "cos32" else (8.0 / lv + 6.0) * U
    else:
        delta = phong_delta(px.n, l, px.v, NoL)
        # r = 2n(n·l) − l: twice the error of n·l and of n, plus l's; then − v.
        e_vec = 3.0 * eps_NoL + eta_v
        # SPEC_COS: 2(n·l)(n·v) − l·v in double, terms ≤ 3: length errors of n
        # (≤ 4ud: |n|² enters 2(n·l)(n·v)) and of l, v (a few 2⁻⁵³), ~20 roundings of
        # 2⁻⁵³: about 6ud; 8ud kept. "cos32" (all in float): n·l and n·v 3u each,
        # times 2|n·v|, 2|n·l| ≤ 2: 12u; l·v 3u; the fused rounding u; |n|² off by
        # ≤ 4u (n rounded to float, in both dot products): 20u; 24u kept.
        e_cos = np.full(np.shape(delta), 8.0 * ud if form != "cos32" else 24.0 * U)
    delta = np.minimum(delta, 2.0)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        if form in ("cos", "cos32"):
            # x = 1 − δ formed directly, in double: the directions' first-order
            # error √(2δ)·e (as for δ, the same quantity for unit vectors) plus
            # the absolute e_cos; x^k relative k·|Δx|/x; the powering (Blinn:
            # (x²)^(k/2), one division more) ≤ 4k·2⁻⁵³; one rounding uw.
            # "cos32" (POW_FP32): the powering in float, ≤ 2k·u as "int32" (the
            # division is in e_cos).
            d_delta = np.sqrt(2.0 * delta) * e_vec + 0.5 * e_vec ** 2 + e_cos
            s = specular_power(delta, k)
            pow_err = 2.0 * k * U if form == "cos32" else 4.0 * k * U_D
            rel = uw + k * d_delta / np.maximum(1.0 - delta, 1e-300) + pow_err
        elif form in ("delta", "int", "int32"):
            # |Δδ| for δ = |e|²/2 when |Δe| ≤ e_vec and |e| = √(2δ); the exp form
            # rounds δ to float first (r_out), the integer power takes it as it is.
            r_delta = r_out if form == "delta" and uw >= U else 0.0
            d_delta = np.sqrt(2.0 * delta) * e_vec + 0.5 * e_vec ** 2 + (4.0 * ud + r_delta) * delta
            s = specular_power(delta, k)
            if form == "delta":
                y = np.abs(k * np.log1p(-np.minimum(delta, 1.0 - 1e-300)))
                # log1p 2 ulp, k·(·) 1, exp 3 ulp (relative in y), k rounded to float32
                # (1 u); then Δδ through d/dδ of k·log1p(−δ) = −k/(1 − δ). With double
                # weights (uw = 2⁻⁵³) all of it in double, units 2⁻⁵³, and k as hi + lo.
                pu, uk = (uw, ud) if uw < U else (U, U)
                rel = 4.0 * pu + (3.0 * pu + uk) * y + k * d_delta / np.maximum(1.0 - delta, 1e-300)
            else:
                # x = 1 − δ in double (≤ 2⁻⁵³ absolute), binary powering of a whole k
                # (≤ 2k·2⁻⁵³ relative), one rounding to float; Δδ through k·x^(k−1).
                # "int32" (POW_FP32, the fast path): the same in float, unit u.
                up = U if form == "int32" else U_D
                rel = uw + k * (d_delta + up) / np.maximum(1.0 - delta, 1e-300) + 2.0 * k * up
        else:
            # pow(x, k) with x = r·v: |Δx| ≤ e_vec + 4u, pow 16 ulp: relative k·|Δx|/x.
            d_delta = e_vec + 4.0 * U
            x = 1.0 - delta
            s = specular_power(delta, k)
            rel = 16.0 * U + k * d_delta / np.maximum(x, 1e-300)
        upper = specular_power(np.maximum(delta - d_delta, 0.0), k)
        err = np.minimum(np.nan_to_num(s * rel, nan=np.inf, posinf=np.inf), upper)
    return err, upper


def ambient_radiance(scene) -> np.ndarray:
    """k_a·Σ ambient radiance (rgb)."""
    return scene.light_arrays["ambient_radiance"] * scene.material.k_a


def shade_straight(scene, gbuffer) -> np.ndarray:
    """:func:`shade` before coverage: the straight shade S (the background where not shaded)."""
    return shade(scene, dataclasses.replace(gbuffer, coverage=_binary(gbuffer.coverage)))


def _binary(cov):
    return None if cov is None else np.where(np.asarray(cov) > 0, np.float32(1), np.float32(0))


def shade(scene, gbuffer) -> np.ndarray:
    """E = E_A + Σ_i (E_D + E_S)_i·attenuation_i per pixel, (H, W, 3) float64;
    with partial coverage, α·E + (1 − α)·background (:func:`cover`)."""
    H, W = gbuffer.shape
    out = np.empty((H * W, 3))
    out[:] = np.asarray(scene.background, np.float64)
    px, C, D, S, fg = _inputs(scene, gbuffer)
    E = C * ambient_radiance(scene)
    for _, L, params, diffuse, specular in _light_terms(scene, px):
        E += np.sum(L * (D * diffuse[..., None] + specular_rgb(px, S, specular, params["l"])), axis=0)
    out[fg] = E
    return cover(finish_sum(out), gbuffer, scene.background).reshape(H, W, 3)


def partial_coverage(gbuffer):
    """(H·W,) float64 coverage where some pixel is partly covered (0 < α < 1), else None:
    only then do the kernels apply it (COVERAGE, clphong/device/plan.py)."""
    if not gbuffer.partly_covered():
        return None
    return np.asarray(gbuffer.coverage, np.float64).reshape(-1)


def cover(E, gbuffer, background):
    """The kernels' COVERAGE store: α·S + (1 − α)·background per pixel ((H·W, 3)
    rows); None's twin is the identity. A layer (light group, AOV) has background 0."""
    a = partial_coverage(gbuffer)
    if a is None:
        return E
    return a[:, None] * E + (1.0 - a[:, None]) * np.asarray(background, np.float64)




def finish_sum(E):
    """Saturate at ±FLT_MAX as the kernel does (never an Inf from finite inputs); NaN stays."""
    return np.where(np.abs(E) > FLT_MAX, np.sign(E) * FLT_MAX, E)


# ------------------------------------------------------------------- the error model

def _plan_forms(plan):
    """(compensated, sum_fp64, form, directions, weights) of :func:`error_bound` for the
    variant a plan compiled."""
    lanes = plan.kernel == "lanes"
    compensated = lanes and bool(plan.defines.get("COMPENSATED_SUM", 0))
    sum_fp64 = lanes and bool(plan.defines.get("SUM_FP64", 0))
    fp32_pow = plan.defines.get("POW_FP32", 0)
    form = ((("cos32" if fp32_pow else "cos") if plan.defines.get("SPEC_COS", 0)
             else "int32" if fp32_pow else "int")
            if plan.defines.get("SPEC_INT_POW", 0) else "delta") if lanes else "naive"
    directions = "fp64" if plan.defines.get("DIRECTIONS_FP64", 0) else "fp32"
    weights = "fp64" if lanes and plan.defines.get("WEIGHTS_FP64", 0) else "fp32"
    return compensated, sum_fp64, form, directions, weights


def _check_forms(form, directions, weights) -> None:
    if directions not in ("fp32", "fp64"):
        raise ValueError(f"directions must be 'fp32' or 'fp64', not {directions!r}")
    if form in ("int32", "cos32") and directions != "fp32":
        raise ValueError(f"form {form!r} (the fast path's float power) goes with fp32 directions")
    if weights not in ("fp32", "fp64") or (weights == "fp64" and directions != "fp64"):
        raise ValueError(f"weights must be 'fp32', or 'fp64' with fp64 directions, not {weights!r}")


#: The float path's smallest bounded squared distance to a point light: 2⁻⁹⁶ (d ≈ 3.6e-15),
#: where the lights loop's bias 2⁻¹²² (RSQRT_LIGHT, kernels/include/clphong.h) moves
#: 1/√d² by 2⁻²⁷ relative, 1/16 of a float ulp.
D2_FLOOR = 2.0 ** -96

def _quarter_eta(d):
    """The float lanes loop's own relative error in l (and d) at distance ``d``: it works
    on quartered positions (d²/16; frame.shading_records), so a square (Δ/4)² below
    FLT_MIN flushes (d² may lose up to 3·2⁻¹²²; RSQRT_LIGHT's bias adds 2⁻¹²²), and a
    component flushes too: L/4, P/4 and their difference, ≤ 3·2⁻¹²⁶ each, so ≤ 2⁻¹²²/d
    in l after 4/d. Their sum: 2⁻¹²¹/d² + 2⁻¹²²/d (2⁻²⁵ at D2_FLOOR)."""
    return 2.0 ** -121 / (d * d) + 2.0 ** -122 / d


def _point_geometry(params, px, o, rp, ud, uw, fp64):
    """A batch of point lights' geometry and falloff errors for :func:`error_bound`:
    (n·l, l, η_l, the falloff's relative error, d, the pixels whose float path leaves
    float's range)."""
    Lp = params["position"]                                     # (K, 1, 3)
    dv = Lp - px.p
    d = np.sqrt(_dot(dv, dv))
    unbounded = None
    with np.errstate(divide="ignore", invalid="ignore"):
        rl = 0.0 if fp64 else np.sqrt(_dot(Lp - o, Lp - o))     # float32 record
        # float: + the bias of RSQRT_LIGHT, 1/√(d² + 2⁻¹²²), and the flushes of the quartered
        # loop (_quarter_eta) relative in l (and d)
        eta_l = np.where(d > 0, ud * (2.0 + (rp + rl) / d) + (0.0 if fp64 else _quarter_eta(d)), 0.0)
        c0, c1, c2 = params["c"]
        cond = (abs(c0) + abs(c1) * d + abs(c2) * d * d) / (c0 + c1 * d + c2 * d * d)
        cond = np.where(d > 0, cond, 0.0)     # d = 0 adds nothing (shade_point_light)
        if not fp64:
            # float d², c2·d² or the polynomial outside float's normal
            # range: flushed or infinite, the result is not bounded.
            # Below D2_FLOOR the lights loop's 1/√(d² + 2⁻¹²²) (RSQRT_LIGHT, clphong.h)
            # is off by more than 2⁻²⁷ relative: not bounded either.
            # The quartered loop's 4·c1 and 16·c2 (frame.shading_records) beyond float: ∞.
            terms = np.stack([d * d, np.abs(c2) * d * d, c0 + c1 * d + c2 * d * d])
            c32 = np.float32
            scaled = (np.abs(c1.astype(c32).astype(float)) * 4.0 > FLT_MAX) | \
                (np.abs(c2.astype(c32).astype(float)) * 16.0 > FLT_MAX)
            out_of_range = (d > 0) & (np.any((terms > FLT_MAX) | ((terms > 0) & (terms < FLT_MIN)), axis=0)
                                      | (d * d < D2_FLOOR) | scaled)
            unbounded = np.any(out_of_range, axis=0)
    # d from the rounded position difference and rsqrt; Horner's three
    # roundings; the coefficients rounded to float32; the division.
    # fp64: d and the falloff in double, att·L rounded to float once.
    e_att = (cond * (4.0 * ud + 2.0 * eta_l) + uw) if fp64 else \
        (cond * (4.0 * U + 2.0 * eta_l) + 3.0 * U)
    with np.errstate(invalid="ignore"):
        NoL = np.where(d > 0, _dot(px.n, dv) / d, 0.0)
        lvec = np.where((d > 0)[..., None], dv / d[..., None], 0.0)
    return NoL, lvec, eta_l, e_att, d, unbounded


def _cone_error(cone, lvec, eta_l, ud, fp64):
    """A spot's cone factor F = t², t = clamp(x, 0, 1), x = cos θ·s + o, cos θ = −l·a
    (spot_factor), and F's absolute error: (t, ΔF). cos θ errs by l's error η_l, the
    axis's rounding to float (float path) and the dot product's 3 roundings; x by s times
    that, the roundings of s and o to float (float path) and the fused add's; the clamp is
    1-Lipschitz; t·t rounds once. ΔF = 2tΔt + Δt² + u·t² (t → 0 at the outer edge)."""
    axis, sc, off = cone
    cos_t = -_dot(lvec, axis)
    t = np.clip(cos_t * sc + off, 0.0, 1.0)
    e_cos = eta_l + 3.0 * ud + (0.0 if fp64 else U)
    # MUL_ADD may or may not be fused: the product's own rounding too
    e_x = sc * e_cos + (ud if fp64 else U) * (np.abs(cos_t * sc + off) + np.abs(cos_t) * sc) + \
        (0.0 if fp64 else U * (np.abs(cos_t) * sc + np.abs(off)))
    return t, 2.0 * t * e_x + e_x * e_x + (ud if fp64 else U) * t * t


def _fresnel_error(px, lvec, w_hi, eta_l, eta_v, eta_n, S, Lc, ud, uw, w64):
    """Schlick's W ∈ [f0, 1] scales the specular weight (≤ 1: |S|·e_spec still bounds its
    error); W's own error on the computed weight ``w_hi`` = w_s + e_spec: (1 − f0)·ΔF5,
    ΔF5 = 5(1 − c)⁴Δc + 5 roundings of the power + its rounding to the weights' type,
    c = cos α; and 3 roundings of the products with f0. Summed over the batch's lights."""
    if px.blinn:
        # c = v·h = √x, x = (1 + l·v)/2: l·v errs by η_l + η_v + 3u_d, x by half
        # that and a rounding; √ by Δx/(2c), or √Δx near c = 0, and a rounding
        c = v_dot_h(lvec, px.v)
        dx = 0.5 * (eta_l + eta_v + 3.0 * ud) + ud
        # |√a − √b| = |a − b|/(√a + √b) ≤ Δx/c when the kernel's x is the
        # smaller one; ≤ √Δx always
        with np.errstate(divide="ignore"):
            dc = np.minimum(dx / c, np.sqrt(dx)) + ud
        dF5 = 5.0 * dc + 8.0 * ud + uw
        S_abs = np.abs(S)
    else:
        c = _dot(px.n, px.v)                                    # (M,)
        dc = eta_n + eta_v + 3.0 * ud
        dF5 = 5.0 * (1.0 - np.clip(c - dc, 0.0, 1.0)) ** 4 * dc + 8.0 * ud + uw
        S_abs = np.abs(px.S_base)
    # 1 − m enters the power's 3 products 5 times (8u); the products with f0
    # and 1 − f0, w·F5, S1·w_f and the add (7u); f0 itself rounded to float
    # without WEIGHTS_FP64 (W_HI_LO keeps the hi part only: u·f0 ≤ u)
    e_f0 = 0.0 if w64 else U
    return np.sum(Lc * S_abs * ((1.0 - px.f0) * dF5[..., None] + 7.0 * uw + e_f0)
                  * w_hi[..., None], axis=0)


def _view_error(camera, px, o, rp, ud):
    """η_v, the relative error of each pixel's unit view vector: orthographic, its rounding;
    perspective, eye − P's (the rebased P's and eye's roundings over their distance)."""
    if view_vector(camera) is not None:
        return np.full(len(px.p), ud)
    eye = np.asarray(camera.position, np.float64)
    de = np.sqrt(_dot(eye - px.p, eye - px.p))
    with np.errstate(divide="ignore"):
        return ud * (2.0 + (rp + np.linalg.norm(eye - o)) / de)


def _sum_error(total, n_direct, *, sum_fp64, compensated):
    """The light sum's error: in double (SUM_FP64) by ≤ n·2⁻⁵³·Σ|c| before the one final
    rounding; Neumaier's compensated sum by ≤ 2u|Σ| + O(n·u²)Σ|c|; the naive one by
    (n − 1)·u·Σ|c|; plus the final rounding."""
    if sum_fp64:
        return (U + (n_direct + 1) * U_D) * total
    if compensated:
        return (3.0 * U + 2.0 * n_direct * U * U) * total
    return (max(n_direct, 1) * U + U) * total


def _with_background(bound, fg, scene, gbuffer):
    """The bound with the background pixels' (the background value rounded to float32)
    and, with partial coverage, the blend's: fl(α·S + fl(fl(1 − α)·bg)): α scales S's
    error; 1 − α, the product and the fused add round once each (3u of α|S| + |bg|,
    doubled)."""
    bg_abs = np.abs(np.asarray(scene.background, np.float64))
    bound[~fg] = U * bg_abs
    a = partial_coverage(gbuffer)
    if a is None:
        return bound
    ref = np.abs(shade_straight(scene, gbuffer)).reshape(-1, 3)
    return a[:, None] * bound + 6.0 * U * (a[:, None] * ref + bg_abs)


@dataclass(frozen=True)
class _Rounding:
    """What :func:`error_bound` fixes before the lights: the pixels, D and S, the rebasing
    origin and |P − o|, the unit roundoffs, the formats, and the view's and normal's
    direction errors."""

    px: Pixels
    D: np.ndarray
    S: np.ndarray
    o: np.ndarray
    rp: object
    ud: float
    uw: float
    r_nol: float
    r_out: float
    fp64: bool
    w64: bool
    eta_v: np.ndarray
    eta_n: np.ndarray
    k: np.ndarray
    form: str


def _batch_error(e: _Rounding, kind, L, params, diffuse, specular):
    """One batch of lights' share of :func:`error_bound`: (the error bound's parts, to add
    in order, their part of Σ|c|, the band pixels among the shaded ones, the pixels the float path cannot
    bound or None)."""
    px, D, S, ud, uw, fp64, w64 = e.px, e.D, e.S, e.ud, e.uw, e.fp64, e.w64
    eta_v, eta_n, r_nol = e.eta_v, e.eta_n, e.r_nol
    out = None
    if kind == "point":
        NoL, lvec, eta_l, e_att, d, out = _point_geometry(params, px, e.o, e.rp, ud, uw, fp64)
        c0, c1, c2 = params["c"]
    else:
        NoL = _dot(px.n, params["l"])                               # (K, M)
        eta_l = np.full(NoL.shape, ud)
        e_att = np.zeros(NoL.shape)
        lvec = np.broadcast_to(params["l"], NoL.shape + (3,))
        d = None
    eps_dir = eta_n + eta_l + 4.0 * ud
    # n·l as the weights see it: rounded to float (flushed below FLT_MIN) when
    # it was computed in double and the weights are float.
    eps_NoL = eps_dir + (r_nol * np.abs(NoL) + FLT_MIN if fp64 and not w64 else 0.0)
    Lc = np.abs(L)
    # Diffuse: max(n·l, 0) is continuous, so its error is that of n·l.
    diff_abs = np.where(NoL > -eps_NoL, eps_NoL, 0.0)
    if d is None:
        att = np.ones(NoL.shape)
    else:
        with np.errstate(divide="ignore"):
            att = np.where(d > 0, attenuation(c0, c1, c2, d), 0.0)
    # A spot's cone factor (_cone_error): F's error is absolute, charged below on the
    # unattenuated weights' upper bounds; att·F rounds once more (into e_att).
    cone = params.get("cone") if kind == "point" else None
    dF = None
    if cone is not None:
        att_raw = att
        t, dF = _cone_error(cone, lvec, eta_l, ud, fp64)
        att = att_raw * t * t
        e_att = e_att + (ud if fp64 else U)
    # The product L·(D·w_d + S·w_s): five roundings, in float or (WEIGHTS_FP64)
    # in double (att·R, D·w_d, S·w_s, their sum and the product; or, where att and
    # FALLOFF_ON_WEIGHTS, att·w_d, att·w_s, S·(att·w_s), the sum and R·(…): four
    # on each term); D = C·k_d and S = k_s·C_s: k_d, k_s rounded to float and up to
    # two products (3u), or (WEIGHTS_FP64) in double from hi + lo (3u_d).
    e_prod = 5.0 * U if not w64 else 3.0 * ud + 5.0 * uw
    e_diff = diffuse * e_att + att * diff_abs + diffuse * e_prod
    if dF is not None:
        e_diff = e_diff + att_raw * dF * (np.maximum(NoL, 0.0) + eps_NoL)
    # Specular: the error of δ (or of r·v for the naive form) through the power.
    if px.specular:
        spec_abs, spec_upper = _specular_error(px, lvec, NoL, eps_dir, eta_l, eta_v, eta_n, e.k,
                                               e.form, ud, e.r_out, uw)
        e_spec = specular * (e_att + e_prod) + att * spec_abs
        if dF is not None:
            e_spec = e_spec + att_raw * dF * np.where(NoL > -eps_NoL, spec_upper, 0.0)
        # The terminator: within eps_NoL of n·l = 0 the float32 gate n·l > 0
        # may disagree with float64's, switching the whole term.
        near = (np.abs(NoL) <= eps_NoL) & (spec_upper > 0)
        e_spec = np.where(near, e_spec + att * spec_upper, e_spec)
        band_fg = np.any(near & (np.abs(S).max(axis=1) * Lc_max(L) > 0), axis=0)
    else:
        e_spec = np.zeros(NoL.shape)
        band_fg = np.zeros(len(px.p), bool)
    # Underflow: intermediates below FLT_MIN are flushed to zero: the weights
    # and their products with D and S (each then scaled by att·L), and att·L
    # itself; or (lights.h, FALLOFF_ON_WEIGHTS) att·w_d, att·w_s (and Blinn's Fresnel
    # att·w_f), their products with D and S and their sum (each then scaled by L),
    # and the last product with L.
    DS = np.abs(D) + np.abs(S)
    floor = FLT_MIN * ((3.0 + DS) * (np.maximum(att, 1.0)[..., None] * Lc) + DS + 1.0)
    b_add = np.sum(Lc * (np.abs(D) * e_diff[..., None] + np.abs(S) * e_spec[..., None]) + floor, axis=0)
    parts = [b_add]                              # added to the bound in this order
    if px.f0 is not None:
        parts.append(_fresnel_error(px, lvec, specular + e_spec, eta_l, eta_v, eta_n, S, Lc, ud,
                                    uw, w64))
    t_add = np.sum(Lc * (np.abs(D) * diffuse[..., None] + np.abs(S) * specular[..., None]), axis=0)
    return parts, t_add, band_fg, out


def error_bound(scene, gbuffer, *, origin=None, compensated=True, form="delta",
                directions="fp32", plan=None, sum_fp64=False, weights="fp32"):
    """Upper bound of |float32 kernel − :func:`shade`| per pixel and channel.

    Parameters
    ----------
    scene, gbuffer
        As for :func:`shade`.
    origin : (3,) array, optional
        The float32 rebasing origin of the float path (``Frame.origin``); 0 if
        omitted. The fp64 path does not rebase and ignores it.
    compensated : bool
        Whether the kernel summed the lights with Neumaier compensation.
    sum_fp64 : bool
        Whether it summed them in double, rounded once (SUM_FP64; overrides
        ``compensated``).
    form : {"delta", "int", "int32", "cos", "cos32", "naive"}
        ``"delta"``: the specular power as exp(k·log1p(−δ)) with δ from
        |r − v|²/2 (shade.cl). ``"int"``: (1 − δ)^k by binary powering in
        double, k whole (SPEC_INT_POW). ``"cos"``: the same powering of the
        cosine formed in double (SPEC_COS: :func:`phong_cos`,
        :func:`blinn_cos_sq`). ``"int32"``: (1 − δ)^k by binary powering in
        float (POW_FP32, the fast path), ``"cos32"`` the cosine's, all in float
        (POW_FP32 with SPEC_COS: the fast path where k allows it). ``"naive"``: pow(r·v, k)
        (shade_obvious.cl).
    directions : {"fp32", "fp64"}
        Whether positions, directions, n·l and δ were computed in float or in
        double from hi+lo inputs (``DIRECTIONS_FP64``).
    weights : {"fp32", "fp64"}
        Whether the weights, the falloff and each light's product were rounded
        to float (``"fp32"``) or kept in double into the double sum
        (``WEIGHTS_FP64``).
    plan : clphong.device.plan.ShadingPlan, optional
        The plan the kernel ran with; sets ``compensated``, ``sum_fp64``, ``form``,
        ``directions`` and ``weights`` from its defines.

    Returns
    -------
    bound : (H, W, 3) float64 array
        Absolute bound; 0 on background pixels.
    band : (H, W) bool array
        Pixels where some light's n·l lies within its own error of 0, so the
        float32 kernel may switch the specular term on where the reference has it
        off, or the reverse. The bound there includes that whole term; report
        these pixels separately (POCL-NOTES "The terminator").

    Notes
    -----
    See ``docs/error-model.md`` for the derivation. Constants: u = 2⁻²⁴; the
    OpenCL 1.2 ulp limits of the builtins (rsqrt 2, division 2.5, log1p 2,
    exp 3, pow 16); every first-order bound is doubled to cover the
    second-order terms and the rounding of the float32 inputs.
    """
    if plan is not None:
        compensated, sum_fp64, form, directions, weights = _plan_forms(plan)
    _check_forms(form, directions, weights)
    # ud: unit roundoff of the direction arithmetic. In double from float32
    # inputs and float32 hi+lo pairs (48 significant bits), 2⁻⁴⁷ covers the pairs'
    # truncation and the double roundings. r_out: n·l and δ rounded to float.
    fp64 = directions == "fp64"
    ud, r_out = (2.0 ** -47, U) if fp64 else (U, 0.0)
    # uw: the rounding of each weight, falloff and light product: to float, or
    # 2⁻⁵³ in double with WEIGHTS_FP64 (then n·l is not rounded to float either).
    w64 = weights == "fp64"
    uw = U_D if w64 else U
    r_nol = 0.0 if w64 else r_out
    H, W = gbuffer.shape
    bound = np.zeros((H * W, 3))
    band = np.zeros(H * W, bool)
    px, C, D, S, fg = _inputs(scene, gbuffer)
    # The float path rounds P − o and the rebased light records; the fp64 path does
    # not rebase (P and the lights' float64 positions are exact in double), so only
    # L − P, eye − P and the eye's hi+lo are rounded.
    o = np.zeros(3) if origin is None or fp64 else np.asarray(origin, np.float64)
    rp = np.sqrt(_dot(px.p - o, px.p - o)) if np.any(o != 0) else 0.0   # |P − o| if rounded
    eta_v = _view_error(scene.camera, px, o, rp, ud)
    eta_n = np.full(len(px.p), ud)                  # unit normal rounded (or as hi+lo)
    k = np.broadcast_to(px.k, (len(px.p),))
    total = np.abs(C * ambient_radiance(scene))    # Σ|c_i|, for the summation error
    # ambient: two roundings, k_a·A rounded to float and C·(k_a·A) (WEIGHTS_FP64:
    # k_a·A as hi + lo, the product in double: 2u_d); a flush below FLT_MIN (in
    # float, or the result's final rounding)
    B = (2.0 * ud if w64 else 2.0 * U) * total + FLT_MIN * (1.0 + np.abs(C))
    n_direct = 0
    unbounded = np.zeros(len(px.p), bool)
    env = _Rounding(px=px, D=D, S=S, o=o, rp=rp, ud=ud, uw=uw, r_nol=r_nol, r_out=r_out,
                    fp64=fp64, w64=w64, eta_v=eta_v, eta_n=eta_n, k=k, form=form)
    idx = np.flatnonzero(fg)
    for kind, L, params, diffuse, specular in _light_terms(scene, px):
        n_direct += len(L)
        parts, t_add, band_fg, out = _batch_error(env, kind, L, params, diffuse, specular)
        for part in parts:
            B += part
        total += t_add
        band[idx[band_fg]] = True
        if out is not None:
            unbounded |= out
    B += _sum_error(total, n_direct, sum_fp64=sum_fp64, compensated=compensated)
    B[unbounded] = np.inf          # float path out of its range (see docs/error-model.md)
    bound[fg] = 2.0 * B
    return _with_background(bound, fg, scene, gbuffer).reshape(H, W, 3), band.reshape(H, W)
