"""A light-tree node's diffuse error by Taylor's theorem, bounded over a tile (issue 27).

:func:`~clphong.model.light_tree.cluster_terms`' second order bounds each term's
size, ``sup|∇g|·|F_c| + ½·sup‖∇²g‖·tr M_c``. The error itself is

    e_c = Σ_i R_ic·(g(p_i − P) − g(p_k − P)) = ∇g·F_c + ½·tr(∇²g·M_c) + r₃,

at ``x̄ = p_k − P``, for the diffuse weight ``g(x) = (n·x)·φ(|x|)``, ``φ = A(d)/d``, with
the node's moments about its representative ``F_c = Σ_i R_ic (p_i − p_k)`` and ``M_c =
Σ_i R_ic (p_i − p_k)(p_i − p_k)ᵀ``, and the Lagrange remainder ``|r₃| ≤ ⅙·sup‖∇³g‖·Σ_i
R_ic |p_i − p_k|³`` (the node's box holds every segment from ``p_k`` to a light). Both
terms are linear in the normal: ``∇g·F = n·w₁``, ``w₁ = φF + φ′(u·F)x``, and
``tr(∇²g·M) = n·w₂``, ``w₂ = 2φ′·Mu + x·(φ″·uᵀMu + (φ′/d)·(tr M − uᵀMu))``, so at
the tile's centre (``P₀``, the normals' box centre ``n₀``) ``|n·w| ≤ |n₀·w| + |n −
n₀|·|w|``, and a move of ``P`` by at most ``r`` (the position box's half-diagonal)
changes ``∇g·F`` by at most ``sup‖∇²g‖·|F_c|·r`` and ``tr(∇²g·M)`` by at most
``sup‖∇³g‖·tr M_c·r``. It holds only where the pair is surely lit (g is smooth
there); the measuring tool's derivation and figures are in docs/bench.md ("The
Taylor terms and their remainder"). On ``wide`` at 65 536 lights and a relative
10⁻² it keeps 2–3.6× fewer entries than the size bound (``python -m
clphong.tools.cut_floor --taylor``).

Here in float64 numpy over broadcast (tile, node) arrays; kernels/node_bound.cl
``taylor_term`` is the same in double. The moments are the tree's
(:class:`~clphong.model.light_tree.LightTree` ``first_vector``, ``second_moment``
(xx, yy, zz, xy, xz, yz), ``third_moment``).
"""

from __future__ import annotations

import numpy as np

#: Points of θ ∈ [0, π/2] at which :func:`third_derivative_sup` evaluates its bound
#: (kernels/node_bound.cl THETA_POINTS: the host passes it).
THETA_POINTS = 33
#: The second moment's six entries, in its storage order.
PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def phi_sups(A_lo, a1, a2, a3, d):
    """Sups over ``|x| ≥ d`` of ``|φ′|, |φ″|, |φ‴|`` for ``φ = A/d``, from ``A_lo = A(d)``
    and the sups ``a1, a2, a3`` of ``|A′|, |A″|, |A‴|`` over ``[d, ∞)``: each a sum of
    terms that fall with d (so d^k times them does too, as
    :func:`third_derivative_sup` needs)."""
    d2 = d * d
    d3 = d2 * d
    return (a1 / d + A_lo / d2,
            a2 / d + 2 * a1 / d2 + 2 * A_lo / d3,
            a3 / d + 3 * a2 / d2 + 6 * a1 / d3 + 6 * A_lo / (d3 * d))


def _basis(points: int) -> np.ndarray:
    """(4, points): t³, t·s², s·t², s³ at θ on a grid of [0, π/2] (t = cos θ, s = sin θ)."""
    theta = np.linspace(0.0, np.pi / 2, points)
    t, s = np.cos(theta), np.sin(theta)
    return np.stack([t * t * t, t * (s * s), s * (t * t), s * (s * s)])


_BASIS = _basis(THETA_POINTS)


def third_derivative_sup(c_hi, d, f1, f2, f3):
    """sup over unit e of |∇³g[e,e,e]| for g = (n·x)·φ(|x|), given at |x| ≥ d: c⁺ ≥ n·x/|x|
    and sups f1 ≥ |φ′|, f2 ≥ |φ″|, f3 ≥ |φ‴| whose products with the powers of |x| below
    fall with |x| (:func:`phi_sups`). With t = u·e = cos θ, s = sin θ: ∇³g[e,e,e] =
    3(n·e)·∇²φ[e,e] + (n·x)·∇³φ[e,e,e], |n·e| ≤ c⁺t + s, |∇²φ[e,e]| ≤ f2·t² + (f1/d)·s²,
    |∇³φ[e,e,e]| ≤ f3·t³ + 3t·s²·(f2/d + f1/d²), so E(θ) = 3(c⁺t + s)(f2t² + (f1/d)s²) +
    c⁺d·(f3t³ + 3ts²(f2/d + f1/d²)) bounds it: a cubic form a·t³ + b·ts² + c·st² + e·s³
    with a = 3c⁺f2 + c⁺d·f3, b = 3c⁺f1/d + 3c⁺d(f2/d + f1/d²), c = 3f2, e = 3f1/d, all
    ≥ 0. Its largest value on a grid of :data:`THETA_POINTS` over [0, π/2], plus
    |E′|·Δθ/2 with |E′| ≤ 3·(a + b + c + e) (each term is a product of cos and sin of
    degree 3), bounds its sup. (kernels/node_bound.cl steps θ by a rotation: its grid
    points differ from these by ~10⁻¹⁵, far inside the bound's 1 + 10⁻⁶.)"""
    k1, k2 = f2, f1 / d
    B = f2 / d + f1 / (d * d)
    a = 3 * c_hi * k1 + c_hi * d * f3
    b = 3 * c_hi * k2 + 3 * c_hi * d * B
    c, e = 3 * k1, 3 * k2
    best = np.zeros(np.broadcast(a, b, c, e).shape)
    for j in range(THETA_POINTS):
        t3, ts2, st2, s3 = _BASIS[:, j]
        best = np.fmax(best, a * t3 + b * ts2 + c * st2 + e * s3)
    return best + 3 * (a + b + c + e) * (np.pi / 2 / (THETA_POINTS - 1)) / 2


def falloff_derivatives(c0, c1, c2, d):
    """``A, A′, A″`` at ``d`` for ``A = 1/(c0 + c1·d + c2·d²)``."""
    p = c0 + d * (c1 + d * c2)
    return (1.0 / p, -(c1 + 2 * c2 * d) / (p * p),
            2 * (d * (3 * c2 * c2 * d + 3 * c1 * c2) + c1 * c1 - c0 * c2) / (p * p * p))


def taylor_diffuse(x, F, M, T3, n0, dn, r, hess, sup3, c0, c1, c2):
    """(…, 3): each channel's bound of the diffuse error (without D) over a tile, per
    the module docstring: ``x`` (…, 3) = p_k − P₀; ``F`` (…, 3, 3) per channel;
    ``M`` (…, 3, 6) per channel (:data:`PAIRS`); ``T3`` (…, 3); ``n0`` (…, 3), ``dn``,
    ``r`` (…): the tile's normals' centre, the normals' and positions' half-diagonals;
    ``hess`` ≥ sup‖∇²g‖ and ``sup3`` ≥ sup‖∇³g‖ over the pair (…); c0, c1, c2 the
    falloff (…). Not finite where the inputs are not."""
    d = np.sqrt(np.sum(x * x, axis=-1))
    u = x / d[..., None]
    A, A1, A2 = falloff_derivatives(c0, c1, c2, d)
    phi = A / d
    d2 = d * d
    phi1 = A1 / d - A / d2
    phi2 = A2 / d - 2 * A1 / d2 + 2 * A / (d2 * d)
    uF = np.einsum("...ci,...i->...c", F, u)
    w1 = phi[..., None, None] * F + (phi1[..., None] * uF)[..., None] * x[..., None, :]
    Mf = M[..., [0, 3, 4, 3, 1, 5, 4, 5, 2]].reshape(M.shape[:-1] + (3, 3))
    Mu = np.einsum("...cij,...j->...ci", Mf, u)
    uMu = np.einsum("...ci,...i->...c", Mu, u)
    trM = M[..., 0] + M[..., 1] + M[..., 2]
    w2 = (2 * phi1[..., None, None] * Mu
          + (phi2[..., None] * uMu + (phi1 / d)[..., None] * (trM - uMu))[..., None]
          * x[..., None, :])
    n = n0[..., None, :]
    first = (np.abs(np.sum(w1 * n, axis=-1)) + dn[..., None] * np.sqrt(np.sum(w1 * w1, axis=-1))
             + (hess * r)[..., None] * np.sqrt(np.sum(F * F, axis=-1)))
    second = (np.abs(np.sum(w2 * n, axis=-1)) + dn[..., None] * np.sqrt(np.sum(w2 * w2, axis=-1))
              + (sup3 * r)[..., None] * trM)
    return first + 0.5 * second + sup3[..., None] * T3 / 6.0
