"""Light falloff and spot cones: the attenuation polynomial's checks and bounds, the glTF
cone's scale and offset, and Blender's spot mapping (exact, in Decimal and Fraction)."""

from __future__ import annotations

import math
import re
import struct
from decimal import MAX_EMAX, MIN_EMIN, Context, Decimal, localcontext
from fractions import Fraction

import numpy as np

from ..core.floats import FLT_MAX, U
from .scene_messages import (
    _g,
)

Vec3 = tuple[float, float, float]
#: Decimal arithmetic for the exact checks of a falloff polynomial.
_DEC_CTX = Context(prec=40, Emax=MAX_EMAX, Emin=MIN_EMIN)




# --------------------------------------------------------------------------
# spot cones
# --------------------------------------------------------------------------

#: The largest cone scale s = 1/(cos inner − cos outer) a spot may have: the
#: kernels form t = cos θ·s + o in float32 (|o| ≤ s), which errs by about 4u·s,
#: so this keeps the cone factor's rounding error ≤ 2⁻⁴ at the sharpest edge
#: allowed (cos inner − cos outer ≥ 3.8e-6, e.g. 10° and 10.0013°).
SPOT_MAX_SCALE = 2.0 ** 18


def spot_scale_offset(inner: float, outer: float) -> tuple[float, float]:
    """``(s, o)`` of glTF KHR_lights_punctual's spot factor for half-angles in
    degrees: ``t = clamp(cos θ·s + o, 0, 1)``, factor ``t²``, with
    ``s = 1/(cos inner − cos outer)`` and ``o = −cos outer·s`` (float64); ``s = ∞``
    where the cosines are equal in float64 (e.g. 0 and 1e-40), an edge no scene
    accepts (:data:`SPOT_MAX_SCALE`)."""
    ci, co = math.cos(math.radians(inner)), math.cos(math.radians(outer))
    if outer == 90.0:
        co = 0.0                   # cos(π/2) is 6e-17 in float64: the horizon exactly
    if ci <= co:
        return (math.inf, -math.inf)
    s = 1.0 / (ci - co)
    return (s, -co * s)


#: The ratio of glTF's fade width to Cycles' in cos θ that minimises the largest
#: difference between t² and Cycles' smoothstep: 0.107 (docs/lighting.md, "Spot lights").
BLENDER_SPOT_FIT = 1.255


def spot_angles_from_blender(spot_size: float, spot_blend: float) -> tuple[float, float]:
    """``(inner_angle, outer_angle)`` in degrees for a Blender spot: ``spot_size`` the
    full cone in **radians** as bpy gives it (Blender's interface shows degrees),
    0 < spot_size <= π, and ``spot_blend`` in [0, 1]. outer = spot_size/2 and
    cos inner = cos outer + spot_blend·(1 − cos outer)/:data:`BLENDER_SPOT_FIT`, so
    that t² follows Cycles' smoothstep fade within 0.107; a blend of 0 (Cycles' hard
    edge) gives the sharpest edge the scene allows (:data:`SPOT_MAX_SCALE`).

    Raises
    ------
    ValueError
        For a size or blend out of range (a size in degrees, e.g. 45, is one).
    """
    if not (0.0 < spot_size <= math.pi):
        raise ValueError(f"spot_size {spot_size!r} is not in (0, pi]: Blender's spot_size is the "
                         "full cone in radians (bpy's value; the interface shows degrees)")
    if not (0.0 <= spot_blend <= 1.0):
        raise ValueError(f"spot_blend {spot_blend!r} is not in [0, 1]")
    outer = math.degrees(spot_size / 2)
    co = 0.0 if outer == 90.0 else math.cos(spot_size / 2)
    width = max(spot_blend * (1.0 - co) / BLENDER_SPOT_FIT, 1.0001 / SPOT_MAX_SCALE)
    return math.degrees(math.acos(min(co + width, 1.0))), outer


# --------------------------------------------------------------------------
# attenuation
# --------------------------------------------------------------------------


def attenuation_problem(c0: float, c1: float, c2: float) -> str | None:
    """Why ``p(d) = c0 + c1*d + c2*d^2`` is not > 0 for all ``d > 0``, if it is not.

    ``p(d) > 0`` for every ``d > 0`` exactly when either ``c0 = 0``, ``c1 >= 0``,
    ``c2 >= 0`` and not both are 0 (physical falloffs such as pure inverse-square
    ``(0, 0, 1)``: ``p(0) = 0``, where a light adds nothing, the kernels' d = 0
    guard), or ``c0 > 0`` and

    * ``c2 > 0`` and (``c1 >= 0`` or ``c1^2 < 4*c0*c2``), or
    * ``c2 == 0`` and ``c1 >= 0``.

    (``c2 < 0`` always fails: the ``d^2`` term wins at large ``d``.) The
    discriminant is compared exactly, in rational arithmetic on the float64
    values, so there is no rounding at the boundary.

    Parameters
    ----------
    c0, c1, c2 : float
        Finite coefficients.

    Returns
    -------
    str or None
        None when the polynomial stays positive; otherwise a one-line
        description of where it reaches zero or goes negative, e.g.
        ``"p(d) = c0 + c1*d reaches 0 at d = 2.5 and goes negative for d > 2.5
        (c1 = -0.4 < 0 with c2 = 0); need c1 >= 0"``.
    """
    if c0 == 0:
        if c1 == 0 and c2 == 0:
            return "p(d) = 0 for every d (c0 = c1 = c2 = 0): no finite falloff"
        if c1 < 0 or c2 < 0:
            return (f"with c0 = 0, p(d) = d*(c1 + c2*d) is negative for small or large d "
                    f"(c1 = {_g(c1)}, c2 = {_g(c2)}); with c0 = 0 both must be >= 0")
        return None
    if c0 < 0:
        return (f"p(d) = c0 + c1*d + c2*d^2 is negative at d = 0 (c0 = {_g(c0)}); "
                "c0 must be >= 0")
    if c2 < 0:
        r = _gd(max(_roots(c0, c1, c2)))
        return (f"p(d) = c0 + c1*d + c2*d^2 reaches 0 at d = {r} and goes negative for "
                f"d > {r} (c2 = {_g(c2)} < 0, so the d^2 term wins at large d); "
                "need c2 >= 0")
    if c1 >= 0:
        return None
    if c2 == 0:
        r = _gd(_quotient(c0, -c1))
        return (f"p(d) = c0 + c1*d reaches 0 at d = {r} and goes negative for "
                f"d > {r} (c1 = {_g(c1)} < 0 with c2 = 0); need c1 >= 0")
    # c0 > 0, c1 < 0, c2 > 0: both roots (if real) are positive.
    f0, f1, f2 = Fraction(c0), Fraction(c1), Fraction(c2)
    disc = f1 * f1 - 4 * f0 * f2
    if disc < 0:
        return None
    if disc == 0:
        r = _gd(_half(_quotient(-c1, c2)))
        return (f"p(d) = c0 + c1*d + c2*d^2 reaches 0 at d = {r} (a double root: "
                "c1^2 = 4*c0*c2); need c1 >= 0 or c1^2 < 4*c0*c2")
    r1, r2 = (_gd(r) for r in sorted(_roots(c0, c1, c2)))
    return (f"p(d) = c0 + c1*d + c2*d^2 reaches 0 at d = {r1} and goes negative for "
            f"{r1} < d < {r2} (c1 < 0 and c1^2 > 4*c0*c2); "
            "need c1 >= 0 or c1^2 < 4*c0*c2")


def largest_falloff(c0: float, c1: float, c2: float) -> float:
    """``1 / min p(d)`` over ``d >= 0``, for a ``p(d) = c0 + c1*d + c2*d^2`` that
    :func:`attenuation_problem` accepts: ``1/c0`` when ``c1 >= 0``, else the
    vertex value ``1 / (c0 - c1^2/(4*c2))`` (exact rational arithmetic); ``inf``
    beyond float64.

    >>> largest_falloff(0.5, 0.0, 1.0), largest_falloff(1.0, -2.0, 2.0)
    (2.0, 2.0)
    """
    if c1 >= 0:
        return 1.0 / c0            # inf, not an error, beyond float64
    # c2 > 0: the minimum is at d = -c1/(2*c2) > 0
    p = Fraction(c0) - Fraction(c1) ** 2 / (4 * Fraction(c2))
    try:
        return float(1 / p)
    except OverflowError:
        return math.inf


def kernel_falloff_bound(c0: float, c1: float, c2: float) -> float:
    """An upper bound of the falloff ``1/p(d)`` the float32 kernels compute at any
    ``d >= 0``; ``inf`` where their ``p(d)`` may round to 0 or below.

    docs/error-model.md, row "attenuation 1/p(d)": Horner's roundings (and the
    coefficients' own) move ``p(d)`` by at most ``4u*(c0 + |c1|*d + |c2|*d^2)``,
    the reciprocal and the rest add ``3u`` relative (``u = 2^-24``). So the bound
    is ``(1 + 3u) * largest_falloff`` of ``p(d) - 4u*(c0 + |c1|*d + c2*d^2)``.
    (A changed ``d``, from the directions' errors, is still some ``d >= 0``.)
    """
    k = 4 * U
    lo = (c0 * (1 - k), c1 - k * abs(c1), c2 * (1 - k))
    if attenuation_problem(*lo) is not None:
        return math.inf
    return largest_falloff(*lo) * (1 + 3 * U)


#: Slack on the sups of :func:`falloff_slopes`: their float64 evaluation (a few u) and a
#: root's error (the function is flat at its peak, so second order in it).
SLOPE_SLACK = 1e-9


def _positive_roots(poly, most: int) -> np.ndarray:
    """The polynomial's (coefficients, lowest degree first) positive real roots, ascending,
    at most ``most`` of them (a root counts as real within 10⁻⁹ of its size)."""
    P = np.polynomial.polynomial
    poly = P.polytrim(np.asarray(poly, np.float64))
    r = P.polyroots(poly) if len(poly) > 1 else np.zeros(0)
    real = np.real(r[np.abs(np.imag(r)) <= 1e-9 * (np.abs(r) + 1.0)])
    return np.sort(real[real > 0])[:most]


def falloff_peaks(att) -> tuple:
    """Where the slopes of the falloff ``A(d) = 1/p(d)``, ``p = c0 + c1·d + c2·d²``
    (``c0, c1, c2 ≥ 0``, one row of ``att`` (K, 3) each), may peak for ``d > 0``.

    ``A′ = −(c1 + 2c2·d)/p²`` and ``A″ = 2N/p³`` with ``N(d) = 3c2²d² + 3c1c2·d + c1² −
    c0c2``, so ``|A′|`` turns where ``N = 0``; ``A‴ = 2C/p⁴`` with ``C = N′·p − 3N·p′``,
    so ``A″`` turns where that cubic is 0. Returns ((K, 2), (K, 3)): the positive real
    roots of N and of C, NaN where none. One root search per distinct row."""
    att = np.asarray(att, np.float64).reshape(-1, 3)
    rows, inv = np.unique(att, axis=0, return_inverse=True)
    one, two = np.full((len(rows), 2), np.nan), np.full((len(rows), 3), np.nan)
    P = np.polynomial.polynomial
    # a row's roots are those of the row over its largest coefficient (N scales by its
    # square, C by its cube): no overflow of c2³ nor underflow of products
    scale = np.maximum(rows.max(axis=1, keepdims=True), np.finfo(np.float64).tiny)
    for i, (c0, c1, c2) in enumerate((rows / scale).tolist()):
        N = np.array([c1 * c1 - c0 * c2, 3 * c1 * c2, 3 * c2 * c2])     # lowest degree first
        C = P.polysub(P.polymul([3 * c1 * c2, 6 * c2 * c2], [c0, c1, c2]),
                      P.polymul(3 * N, [c1, 2 * c2]))
        for out, poly in ((one, N), (two, C)):
            real = _positive_roots(poly, out.shape[1])
            out[i, :len(real)] = real
    inv = inv.reshape(-1)
    return one[inv], two[inv]


def falloff_slopes(c0, c1, c2, d, peaks):
    """``(|A′(d)|, sup |A′|, sup |A″|)``, the sups over ``[d, ∞)``, for ``A = 1/(c0 + c1·d
    + c2·d²)`` (arrays that broadcast; ``peaks``: :func:`falloff_peaks`'s pair, indexed
    alike with a trailing axis). A smooth function's sup over ``[d, ∞)`` is its value at
    ``d``, at a turning point beyond ``d``, or its limit (0 here); the sups carry
    :data:`SLOPE_SLACK`."""
    def slope(x):
        p = c0 + x * (c1 + x * c2)
        return (c1 + 2.0 * c2 * x) / (p * p)

    def curve(x):
        p = c0 + x * (c1 + x * c2)
        n = x * (3.0 * c2 * c2 * x + 3.0 * c1 * c2) + (c1 * c1 - c0 * c2)
        return 2.0 * np.abs(n) / (p * p * p)

    at = slope(d)
    s1, s2 = at, curve(d)
    one, two = peaks
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for j in range(one.shape[-1]):
            r = one[..., j]
            s1 = np.fmax(s1, np.where(r > d, slope(r), 0.0))
        for j in range(two.shape[-1]):
            r = two[..., j]
            s2 = np.fmax(s2, np.where(r > d, curve(r), 0.0))
    return at, s1 * (1 + SLOPE_SLACK), s2 * (1 + SLOPE_SLACK)


def falloff_third_roots(att) -> np.ndarray:
    """(K, 4): where ``|A‴|`` may peak for ``d > 0``, for ``A = 1/p``, ``p = c0 + c1·d +
    c2·d²`` (``att`` (K, 3) rows, ``c0, c1, c2 ≥ 0``): ``A‴ = 6p′(p·p″ − p′²)/p⁴`` (p‴ =
    0), and ``A⁗``'s numerator ``6p″²p² − 36p′²p″p + 24p′⁴`` is a quartic in d; its
    positive real roots, ascending, NaN where none. One root search per distinct row,
    on the row over its largest coefficient, as :func:`falloff_peaks` does."""
    att = np.asarray(att, np.float64).reshape(-1, 3)
    rows, inv = np.unique(att, axis=0, return_inverse=True)
    roots = np.full((len(rows), 4), np.nan)
    P = np.polynomial.polynomial
    scale = np.maximum(rows.max(axis=1, keepdims=True), np.finfo(np.float64).tiny)
    for i, (c0, c1, c2) in enumerate((rows / scale).tolist()):
        p, p1, p2 = [c0, c1, c2], [c1, 2 * c2], [2 * c2]
        quartic = P.polyadd(P.polysub(P.polymul(P.polymul([6.0], P.polymul(p2, p2)), P.polymul(p, p)),
                                      P.polymul(P.polymul([36.0], P.polymul(p1, p1)), P.polymul(p2, p))),
                            P.polymul([24.0], P.polymul(P.polymul(p1, p1), P.polymul(p1, p1))))
        real = _positive_roots(quartic, 4)
        roots[i, :len(real)] = real
    return roots[inv.reshape(-1)]


def falloff_third_sup(att, d, roots=None):
    """``sup |A‴|`` over ``[d, ∞)`` for ``A = 1/p`` (``att`` (…, 3), ``d`` (…)): the
    value at ``d`` or at one of :func:`falloff_third_roots`' roots beyond ``d``
    (``roots`` (…, 4), by default found here; the limit is 0); the sup carries
    :data:`SLOPE_SLACK`. kernels/node_bound.cl ``falloff_third`` is the same."""
    att = np.asarray(att, np.float64)
    d = np.asarray(d, np.float64)
    if roots is None:
        roots = falloff_third_roots(att).reshape(att.shape[:-1] + (4,))
    c0, c1, c2 = att[..., 0], att[..., 1], att[..., 2]

    def third(x):
        p = c0 + x * (c1 + x * c2)
        p1 = c1 + 2.0 * c2 * x
        return 6.0 * np.abs(p1 * (2.0 * c2 * p - p1 * p1)) / (p * p) / (p * p)

    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        s = third(d)
        for j in range(roots.shape[-1]):
            r = roots[..., j]
            s = np.fmax(s, np.where(r > d, third(r), 0.0))
    return s * (1 + SLOPE_SLACK)


def radiance_problem(radiance: float, att: Vec3) -> str:
    """The message for a light whose ``max(color) x intensity`` (``radiance``) times
    the largest falloff of ``att`` is beyond float32 (see :func:`kernel_falloff_bound`)."""
    return ("color x intensity x the largest falloff 1/min p(d) = "
            f"{_g(radiance * largest_falloff(*att))} is beyond the "
            "float32 range the kernels compute in (|x| <= "
            f"{_g(FLT_MAX)}, less their rounding error); lower the "
            "intensity or raise the minimum of p(d)")


def _roots(c0: float, c1: float, c2: float) -> tuple[Decimal, Decimal]:
    """Both real roots of ``c2*d^2 + c1*d + c0`` (``c2 != 0``, ``c0 != 0``).

    Only used for messages. Computed with the numerically stable form of the
    quadratic formula in 40-digit decimal arithmetic, whose exponent range
    covers any float64 coefficients (their squares and quotients included).
    """
    with localcontext(_DEC_CTX):
        a, b, c = Decimal(c2), Decimal(c1), Decimal(c0)
        disc = max(b * b - 4 * a * c, Decimal(0))
        root = disc.sqrt()
        q = -(b + root if b >= 0 else b - root) / 2
        return (q / a, c / q)


def _quotient(n: float, d: float) -> Decimal:
    """``n / d`` without overflow or underflow (for messages)."""
    with localcontext(_DEC_CTX):
        return Decimal(n) / Decimal(d)


def _half(x: Decimal) -> Decimal:
    with localcontext(_DEC_CTX):
        return x / 2


def _gd(x: Decimal) -> str:
    """A short form of a (possibly out-of-float-range) root for messages."""
    if x == 0 or Decimal("1e-300") < abs(x) < Decimal("1e300"):
        return _g(float(x))
    return re.sub(r"\.?0+e", "e", f"{x:.5e}")


def _f32(x: float) -> float:
    """``x`` rounded to float32 (as the kernels store it), back as a float."""
    try:
        return struct.unpack("f", struct.pack("f", x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)
