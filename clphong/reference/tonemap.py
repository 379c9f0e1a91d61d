"""Tone-mapping operators: float64 reference twins, error model, inverses.

Every operator of ``kernels/tonemap.cl`` has a twin here with the same name, the
same order of operations and the same guards, evaluated in float64 on the same
float32 inputs. The twins run on :class:`Bounded` numbers: each carries its
float64 value and a first-order bound on how far the float32 kernel's value of
the same expression can be from it (Wilkinson's running error analysis). So
:func:`reference` gives the float64 result and :func:`error_bound` the tolerance
of every kernel test, from one transcription of the formula.

The error model (see ``docs/error-model.md`` for u and the builtin accuracies):

* a float literal of the kernel is the float32 rounding of the published
  constant: its exact rounding error |f32(c) − c| is carried;
* ``+ − ×``: one rounding, ≤ u·|result|; a fused ``MUL_ADD`` is bounded as two;
* division ≤ 2.5 ulp ≤ 5u·|result|; ``log2``, ``exp2`` ≤ 3 ulp ≤ 6u·|result|;
  ``pow`` ≤ 16 ulp ≤ 32u·|result| (OpenCL 1.2 single-precision limits);
* each operand's error propagates through the operation's derivative
  (|b|·e_a + |a|·e_b for a product, and so on, second-order terms included
  where they are cheap);
* ``min``, ``max``, ``clamp`` are 1-Lipschitz and add nothing;
* a branch (``select``) whose condition is within its own error bound of the
  switch point may go either way: the bound adds the gap between the branches;
* ``-cl-denorms-are-zero``: FLT_MIN absolute per operation;
* the sum of the first-order terms is doubled at the end, as in the shading
  kernels' model, to cover the remaining second-order terms.

Operators (``name``: ID in ``TONEMAP``):

============================  ==  ==========================================
``none``                       0  clip to [0, 1]
``reinhard``                   1  Reinhard et al. 2002, eq. 3
``reinhard-extended``          2  Reinhard et al. 2002, eq. 4, white point
``hable``                      3  Hable 2010 (Uncharted 2), white point W
``aces-hill``                  4  Hill's ACES fit with its matrices
``agx``                        5  Wrensch's minimal AgX fit
``pbr-neutral``                6  Khronos PBR Neutral
============================  ==  ==========================================
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..core.floats import FLT_MIN, U
from ..model.tonemap import (
    HABLE_A,
    HABLE_B,
    HABLE_C,
    HABLE_D,
    HABLE_E,
    HABLE_EXPOSURE_BIAS,
    HABLE_F,
    Operator,
    ToneMapError,
    hable_exact,
    operator,
    operator_params,
)

__all__ = [
    "TWINS", "Bounded", "reference", "error_bound", "inverse",
    "tonemap_none", "tonemap_reinhard", "tonemap_reinhard_extended", "tonemap_hable",
    "tonemap_aces_hill", "tonemap_agx", "tonemap_pbr_neutral", "encode_srgb",
    "display_transform", "U", "FLT_MIN",
]

_LN2 = math.log(2.0)


# --------------------------------------------------------------------------- Bounded

def _f32_error(c: float) -> float:
    """|f32(c) − c|: the rounding of a kernel literal (exact, in float64)."""
    return abs(float(np.float32(c)) - c)


class Bounded:
    """A float64 value and a bound on the float32 kernel's error in computing it.

    Arithmetic with a Python float treats the float as a kernel literal (a
    float32 constant): its rounding error is carried. Use :meth:`exact` for
    values known exactly in float32 (the kernel's inputs).
    """

    __slots__ = ("v", "e")
    __array_priority__ = 1000

    def __init__(self, v, e):
        self.v = np.asarray(v, np.float64)
        self.e = np.asarray(e, np.float64)

    @classmethod
    def exact(cls, x) -> "Bounded":
        x = np.asarray(x, np.float64)
        return cls(x, np.zeros_like(x))

    @classmethod
    def const(cls, c: float) -> "Bounded":
        return cls(c, _f32_error(float(c)))

    @staticmethod
    def wrap(x) -> "Bounded":
        return x if isinstance(x, Bounded) else Bounded.const(float(x))

    @staticmethod
    def _round(v, e, ulps: float = 1.0) -> "Bounded":
        """Result v with propagated error e, plus its own rounding (ulps·2u relative)."""
        # 1 correctly rounded op: ≤ u·|x|; k ulp: ≤ 2k·u·|x|; plus the flush-to-zero step.
        rel = U if ulps == 1.0 else 2.0 * ulps * U
        return Bounded(v, e + rel * (np.abs(v) + e) + FLT_MIN)

    def __add__(self, o):
        o = Bounded.wrap(o)
        return Bounded._round(self.v + o.v, self.e + o.e)

    __radd__ = __add__

    def __sub__(self, o):
        o = Bounded.wrap(o)
        return Bounded._round(self.v - o.v, self.e + o.e)

    def __rsub__(self, o):
        return Bounded.wrap(o) - self

    def __neg__(self):
        return Bounded(-self.v, self.e)

    def __mul__(self, o):
        o = Bounded.wrap(o)
        e = np.abs(self.v) * o.e + np.abs(o.v) * self.e + self.e * o.e
        return Bounded._round(self.v * o.v, e)

    __rmul__ = __mul__

    def __truediv__(self, o):
        o = Bounded.wrap(o)
        den = np.abs(o.v) - o.e
        with np.errstate(divide="ignore", invalid="ignore"):
            v = self.v / o.v
            e = np.where(den > 0, (self.e + np.abs(v) * o.e) / den, np.inf)
        return Bounded._round(v, e, ulps=2.5)

    def __rtruediv__(self, o):
        return Bounded.wrap(o) / self


def mul_add(a, b, c) -> Bounded:
    """MUL_ADD(a, b, c) = a·b + c, bounded as two roundings (fused or not)."""
    return Bounded.wrap(a) * b + c


def fmin(a, b) -> Bounded:
    """min is 1-Lipschitz: max(e_a, e_b), or the smaller operand's error where it is
    smaller whatever the rounding."""
    a, b = Bounded.wrap(a), Bounded.wrap(b)
    e = np.maximum(a.e, b.e)
    e = np.where(a.v + a.e < b.v - b.e, a.e, np.where(b.v + b.e < a.v - a.e, b.e, e))
    return Bounded(np.minimum(a.v, b.v), e)


def fmax(a, b) -> Bounded:
    """max: as :func:`fmin`."""
    a, b = Bounded.wrap(a), Bounded.wrap(b)
    e = np.maximum(a.e, b.e)
    e = np.where(a.v - a.e > b.v + b.e, a.e, np.where(b.v - b.e > a.v + a.e, b.e, e))
    return Bounded(np.maximum(a.v, b.v), e)


def clamp(x, lo, hi) -> Bounded:
    return fmin(fmax(x, lo), hi)


def clamp01(x) -> Bounded:
    return clamp(x, 0.0, 1.0)


def log2(a: Bounded) -> Bounded:
    low = a.v - a.e
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.log2(a.v)
        e = np.where(low > 0, a.e / (low * _LN2), np.inf)
    return Bounded._round(v, e, ulps=3)


def exp2(a: Bounded) -> Bounded:
    v = np.exp2(a.v)
    return Bounded._round(v, v * np.expm1(_LN2 * a.e), ulps=3)


def pow_(a: Bounded, y) -> Bounded:
    """pow(a, y) for a ≥ 0 and a literal y > 1 (16 ulp)."""
    y = Bounded.wrap(y)
    high = a.v + a.e
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.power(a.v, y.v)
        # |d a^y/da| = y·a^(y−1) is increasing for y > 1: take it at a + e.
        e = y.v * np.power(high, y.v - 1.0) * a.e
        e = e + np.where(a.v > 0, np.abs(v * np.log(np.where(a.v > 0, a.v, 1.0))), 0.0) * y.e
    return Bounded._round(v, e, ulps=16)


def select(margin: Bounded, if_negative: Bounded, otherwise: Bounded,
           strict: bool = True) -> Bounded:
    """The branch ``margin < 0`` (``<= 0`` unless strict), as the kernel's select().

    Where |margin| is within its error bound the float32 kernel may take the
    other branch: the bound then covers both values.
    """
    t, f = Bounded.wrap(if_negative), Bounded.wrap(otherwise)
    cond = margin.v < 0 if strict else margin.v <= 0
    v = np.where(cond, t.v, f.v)
    e = np.where(cond, t.e, f.e)
    unsure = np.abs(margin.v) <= margin.e
    e = np.where(unsure, np.maximum(t.e, f.e) + np.abs(t.v - f.v), e)
    return Bounded(v, e)


RGB = tuple  # (r, g, b) of Bounded


def _mat3(m, c: RGB) -> RGB:
    """mat3_apply: rows of m (literals) times c, as MUL_ADD(m0, r, MUL_ADD(m1, g, m2·b))."""
    r, g, b = c
    return tuple(mul_add(row[0], r, mul_add(row[1], g, Bounded.wrap(row[2]) * b)) for row in m)


def _mat3_args(m: Bounded, c: RGB) -> RGB:
    """mat3_apply with the host's float32 matrix (a 3×3 Bounded of kernel arguments)."""
    r, g, b = c
    rows = []
    for i in range(3):
        mi = [Bounded(m.v[i, j], m.e[i, j]) for j in range(3)]
        rows.append(mul_add(mi[0], r, mul_add(mi[1], g, mi[2] * b)))
    return tuple(rows)


# --------------------------------------------------------------------------- twins

def tonemap_none(c: RGB) -> RGB:
    """Clip to the display range [0, 1]."""
    return tuple(clamp01(x) for x in c)


def reinhard_curve(x):
    """Reinhard et al. 2002, eq. 3: x/(1 + x)."""
    return x / (1.0 + x)


def tonemap_reinhard(c: RGB) -> RGB:
    return tuple(reinhard_curve(x) for x in c)


def reinhard_extended_curve(x, inv_white2):
    """Reinhard et al. 2002, eq. 4: x·(1 + x/L_white²)/(1 + x)."""
    return x * mul_add(x, inv_white2, 1.0) / (1.0 + x)


def tonemap_reinhard_extended(c: RGB, inv_white2) -> RGB:
    return tuple(clamp01(reinhard_extended_curve(x, inv_white2)) for x in c)




def hable_partial(x):
    """Hable 2010: (x(Ax + CB) + DE)/(x(Ax + B) + DF) − E/F."""
    A, B, C, D, E, F = (Bounded.const(k) for k in (HABLE_A, HABLE_B, HABLE_C, HABLE_D,
                                                     HABLE_E, HABLE_F))
    return (mul_add(x, mul_add(A, x, C * B), D * E) / mul_add(x, mul_add(A, x, B), D * F)
            - E / F)


def tonemap_hable(c: RGB, white_scale) -> RGB:
    return tuple(clamp01(hable_partial(HABLE_EXPOSURE_BIAS * x) * white_scale) for x in c)


ACES_HILL_IN = ((0.59719, 0.35458, 0.04823),
                (0.07600, 0.90834, 0.01566),
                (0.02840, 0.13383, 0.83777))
ACES_HILL_OUT = ((1.60475, -0.53108, -0.07367),
                 (-0.10208, 1.10813, -0.00605),
                 (-0.00327, -0.07276, 1.07602))


def aces_hill_rrt_odt_fit(v):
    """Hill's RRT+ODT fit: (v(v + 0.0245786) − 0.000090537)/(v(0.983729v + 0.4329510) + 0.238081)."""
    a = mul_add(v, v + 0.0245786, -0.000090537)
    b = mul_add(v, mul_add(0.983729, v, 0.4329510), 0.238081)
    return a / b


def tonemap_aces_hill(c: RGB) -> RGB:
    v = _mat3(ACES_HILL_IN, c)
    v = tuple(aces_hill_rrt_odt_fit(x) for x in v)
    v = _mat3(ACES_HILL_OUT, v)
    return tuple(clamp01(x) for x in v)


AGX_INSET = ((0.842479062253094, 0.0784335999999992, 0.0792237451477643),
             (0.0423282422610123, 0.878468636469772, 0.0791661274605434),
             (0.0423756549057051, 0.0784336, 0.879142973793104))
AGX_OUTSET = ((1.19687900512017, -0.0980208811401368, -0.0990297440797205),
              (-0.0528968517574562, 1.15190312990417, -0.0989611768448433),
              (-0.0529716355144438, -0.0980434501171241, 1.15107367264116))
AGX_MIN_EV, AGX_MAX_EV = -12.47393, 4.026069
AGX_POLY = (15.5, -40.14, 31.96, -6.868, 0.4298, 0.1191, -0.00232)  # x^6 ... x^0


#: max |p''(x)| over [0, 1] for the AgX polynomial p: Σ_k |a_k|·k(k − 1).
AGX_POLY_D2_MAX = sum(abs(a) * k * (k - 1) for a, k in zip(AGX_POLY, range(6, -1, -1)))


def agx_contrast_approx(x):
    """Wrensch's 6th-order fit of the AgX sigmoid, in the kernel's order of operations.

    The input's error goes through the polynomial's derivative p'(x) (|p'| ≤ 1.2 on
    [0, 1]) rather than through each term's (Σ|a_k|·k ≈ 440: the terms cancel),
    plus ½·max|p''|·e²; the rounding errors are those of the evaluation at x.
    """
    if np.any(x.e):
        r = agx_contrast_approx(Bounded.exact(x.v))
        dp = np.polyval(np.polyder(np.array(AGX_POLY)), x.v)
        return Bounded(r.v, r.e + np.abs(dp) * x.e + 0.5 * AGX_POLY_D2_MAX * x.e ** 2)
    x2 = x * x
    x4 = x2 * x2
    return (15.5 * x4 * x2 - 40.14 * x4 * x + 31.96 * x4 - 6.868 * x2 * x
            + 0.4298 * x2 + 0.1191 * x - 0.00232)


def agx_log_encode(x):
    ev = clamp(log2(fmax(x, 1e-10)), AGX_MIN_EV, AGX_MAX_EV)
    return (ev - AGX_MIN_EV) / (Bounded.const(AGX_MAX_EV) - AGX_MIN_EV)


def agx_linearize(x):
    return pow_(fmax(x, 0.0), 2.2)


def tonemap_agx(c: RGB) -> RGB:
    v = _mat3(AGX_INSET, c)
    v = tuple(agx_contrast_approx(agx_log_encode(x)) for x in v)
    v = _mat3(AGX_OUTSET, v)
    return tuple(clamp01(agx_linearize(x)) for x in v)


PBR_START_COMPRESSION = 0.8 - 0.04
PBR_DESATURATION = 0.15


def tonemap_pbr_neutral(c: RGB) -> RGB:
    """Khronos PBR Neutral, the published formula (see kernels/tonemap.cl)."""
    start = Bounded.const(0.8) - 0.04
    d = 1.0 - start
    r, g, b = c
    x = fmin(r, fmin(g, b))
    offset = select(x - 0.08, x - 6.25 * x * x, Bounded.const(0.04))
    r, g, b = r - offset, g - offset, b - offset
    peak = fmax(r, fmax(g, b))
    new_peak = 1.0 - d * d / (peak + d - start)
    margin = peak - start              # compress where peak >= start
    scale = select(margin, Bounded.const(1.0), new_peak / _nonzero(peak))
    mix_g = select(margin, Bounded.const(0.0),
                   1.0 - 1.0 / mul_add(PBR_DESATURATION, peak - new_peak, 1.0))
    out = []
    for ch in (r, g, b):
        s = ch * scale
        out.append(clamp01(mul_add(new_peak - s, mix_g, s)))
    return tuple(out)


def _nonzero(x: Bounded) -> Bounded:
    """x where the division's branch is unused (peak < start), kept finite: the
    kernel computes new_peak/peak there too and discards it."""
    return Bounded(np.where(x.v == 0, 1.0, x.v), x.e)


SRGB_BREAK = 0.0031308


def encode_srgb(x):
    """IEC 61966-2-1 sRGB inverse EOTF, as the kernel evaluates it."""
    lo = 12.92 * x
    xh = fmax(x, SRGB_BREAK)
    hi = mul_add(1.055, exp2(log2(xh) * (Bounded.const(1.0) / 2.4)), -0.055)
    return select(x - SRGB_BREAK, lo, hi, strict=False)


TWINS: dict[str, Callable] = {
    "none": tonemap_none, "reinhard": tonemap_reinhard,
    "reinhard-extended": tonemap_reinhard_extended, "hable": tonemap_hable,
    "aces-hill": tonemap_aces_hill, "agx": tonemap_agx, "pbr-neutral": tonemap_pbr_neutral,
}
"""The twin of each operator of :data:`clphong.model.tonemap.OPERATORS`, by name."""


# --------------------------------------------------------------------------- pipeline

DISPLAY_SATURATE = 2.0 ** 24


def display_clip(x) -> Bounded:
    """Twin of display_clip (kernels/tonemap.cl): [0, 2^24], where every operator
    is saturated and x² stays finite in float32."""
    return clamp(x, 0.0, DISPLAY_SATURATE)


def display_transform(c: RGB, op: Operator, exposure: Bounded, params: Bounded,
                      matrix: Bounded | None, encoding: int) -> RGB:
    """Twin of display_transform (kernels/tonemap.cl)."""
    c = tuple(x * exposure for x in c)
    if matrix is not None:
        c = _mat3_args(matrix, c)
    c = tuple(display_clip(x) for x in c)
    if op.name == "reinhard-extended" or op.name == "hable":
        c = TWINS[op.name](c, params)
    else:
        c = TWINS[op.name](c)
    if encoding == 1:
        c = tuple(encode_srgb(x) for x in c)
    return c


def _kernel_arg(x) -> Bounded:
    """A host value passed to the kernel as float32: its rounding is carried."""
    x = np.asarray(x, np.float64)
    return Bounded(x, np.abs(x.astype(np.float32).astype(np.float64) - x))


def _evaluate(rgb, name, exposure_ev, white, matrix, encoding) -> RGB:
    op = operator(name)
    rgb = np.asarray(rgb, np.float32).astype(np.float64)
    c = tuple(Bounded.exact(rgb[..., k]) for k in range(3))
    scale = _kernel_arg(2.0 ** float(exposure_ev))
    params = _kernel_arg(operator_params(op.name, white)[0])
    m = None if matrix is None else _kernel_arg(np.asarray(matrix, np.float64))
    return display_transform(c, op, scale, params, m, encoding)


def reference(rgb, name: str = "none", *, exposure: float = 0.0, white: float | None = None,
              matrix=None, encoding: int = 0) -> np.ndarray:
    """The float64 display transform of float32 ``rgb`` (..., 3).

    Parameters
    ----------
    rgb : array_like, (..., 3)
        Scene-linear working-space RGB; rounded to float32 first, as the kernel sees it.
    name : str
        Operator name (see :data:`OPERATORS`).
    exposure : float
        Stops: the input is multiplied by 2^exposure before tone mapping.
    white : float, optional
        White point of ``reinhard-extended`` / ``hable``; the operator's default if None.
    matrix : (3, 3) array_like, optional
        Working space → Rec.709, applied after exposure (None: identity).
    encoding : {0, 1}
        0: display-linear output; 1: sRGB-encoded.

    Returns
    -------
    numpy.ndarray
        float64, shape of ``rgb``.
    """
    out = _evaluate(rgb, name, exposure, white, matrix, encoding)
    return np.stack([x.v for x in out], axis=-1)


def error_bound(rgb, name: str = "none", *, exposure: float = 0.0, white: float | None = None,
                matrix=None, encoding: int = 0) -> np.ndarray:
    """Bound on |kernel − :func:`reference`| for each pixel and channel (same arguments)."""
    out = _evaluate(rgb, name, exposure, white, matrix, encoding)
    return 2.0 * np.stack([x.e for x in out], axis=-1)   # ×2: second-order terms


# --------------------------------------------------------------------------- inverses

def _bisect(f, y, lo, hi, iters=200):
    """Invert an increasing f on [lo, hi] element-wise (float64 bisection)."""
    lo = np.full_like(y, lo)
    hi = np.full_like(y, hi)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        below = f(mid) < y
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def _ev(x):
    """A float64 curve evaluated through the twins (no error tracking needed)."""
    return x.v


def inverse(y, name: str, *, white: float | None = None) -> np.ndarray:
    """The float64 inverse of an operator (display-linear → linear Rec.709), where it is one-to-one.

    Valid where no output channel is clipped to 0 or 1 and, for AgX, no channel
    is in its log-encoding clamp; elsewhere the operator is not invertible.
    """
    op = operator(name)
    y = np.asarray(y, np.float64)
    B = Bounded.exact
    if op.name == "none":
        return y.copy()
    if op.name == "reinhard":
        return y / (1.0 - y)
    if op.name == "reinhard-extended":
        iw2 = operator_params(op.name, white)[0]
        one_m = 1.0 - y
        return 2.0 * y / (one_m + np.sqrt(one_m * one_m + 4.0 * y * iw2))
    if op.name == "hable":
        ws = operator_params(op.name, white)[0]
        t = _bisect(lambda t: hable_exact(t) * ws, y, 0.0, 1e4)
        return t / HABLE_EXPOSURE_BIAS
    if op.name == "aces-hill":
        v = y @ np.linalg.inv(np.array(ACES_HILL_OUT)).T
        v = _bisect(lambda t: _ev(aces_hill_rrt_odt_fit(B(t))), v, 0.0, 1e4)
        return v @ np.linalg.inv(np.array(ACES_HILL_IN)).T
    if op.name == "agx":
        v = np.power(y, 1.0 / 2.2) @ np.linalg.inv(np.array(AGX_OUTSET)).T
        v = _bisect(lambda t: _ev(agx_contrast_approx(B(t))), v, 0.0, 1.0)
        v = np.exp2(v * (AGX_MAX_EV - AGX_MIN_EV) + AGX_MIN_EV)
        return v @ np.linalg.inv(np.array(AGX_INSET)).T
    if op.name == "pbr-neutral":
        start, d = PBR_START_COMPRESSION, 1.0 - PBR_START_COMPRESSION
        y_peak = y.max(axis=-1, keepdims=True)
        compressed = y_peak >= start
        peak = np.where(compressed, d * d / (1.0 - np.minimum(y_peak, 1 - 1e-300)) - d + start, y_peak)
        new_peak = 1.0 - d * d / (peak + d - start)
        g = np.where(compressed, 1.0 - 1.0 / (PBR_DESATURATION * (peak - new_peak) + 1.0), 0.0)
        scale = np.where(compressed, new_peak / peak, 1.0)
        s = (y - new_peak * g) / (1.0 - g)          # undo the mix
        x_off = s / scale                           # undo the shoulder: c − offset
        m = x_off.min(axis=-1, keepdims=True)       # = x − offset(x), x the input minimum
        x_min = np.where(m < 0.04, np.sqrt(np.maximum(m, 0.0) / 6.25), m + 0.04)
        offset = np.where(x_min < 0.08, x_min - 6.25 * x_min * x_min, 0.04)
        return x_off + offset
    raise ToneMapError(f"{op.name!r} has no inverse")  # pragma: no cover
