"""The Taylor term of the light tree's diffuse bound (clphong/model/taylor.py, and its
use in light_tree.cluster_terms): the third derivative's sup, φ's sups over d ≥ d⁻, and
the term itself never below a node's true diffuse error at any pixel of its tile."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clphong.model.falloff import falloff_slopes, falloff_third_sup, falloff_peaks
from clphong.model.light_tree import (SpecularModel, TileBoxes, build_light_tree, cluster_terms,
                                      leaf_ranges)
from clphong.model.taylor import THETA_POINTS, phi_sups, third_derivative_sup
from clphong.reference import shading as reference
from clphong.tools.cut_floor import node_errors
from clphong.tools.hardcases import make_scene

ATTS = [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (1.0, 0.5, 0.0), (0.2, 0.1, 0.3), (1.0, 0.1, 0.05),
        (0.0, 1.0, 0.0)]


def _phis(c0, c1, c2, d):
    """φ′, φ″, φ‴ of φ = A/d at d, A = 1/p, by A's closed-form derivatives."""
    p = c0 + d * (c1 + d * c2)
    p1, p2 = c1 + 2 * c2 * d, 2 * c2
    A, A1 = 1 / p, -p1 / p ** 2
    A2 = 2 * p1 ** 2 / p ** 3 - p2 / p ** 2
    A3 = 6 * p1 * (p * p2 - p1 ** 2) / p ** 4
    return (A1 / d - A / d ** 2, A2 / d - 2 * A1 / d ** 2 + 2 * A / d ** 3,
            A3 / d - 3 * A2 / d ** 2 + 6 * A1 / d ** 3 - 6 * A / d ** 4)


@settings(max_examples=60, deadline=None)
@given(c0=st.floats(0.0, 5.0), c1=st.floats(0.0, 5.0), c2=st.floats(0.0, 5.0),
       d=st.floats(0.1, 20.0), cos=st.floats(0.02, 1.0), seed=st.integers(0, 2**31 - 1))
def test_third_derivative_sup_bounds_the_diffuse_weights_third_derivative(c0, c1, c2, d, cos, seed):
    """At one point, with φ's derivatives given exactly there: no direction's third
    derivative of g = (n·x)·A(|x|)/|x| (fourth-order differences, 500 random directions)
    exceeds third_derivative_sup. (It is 1.5–7× the largest, median 3.4×, over 400 random
    points: the triangle inequalities between φ's derivatives are what it loses.)"""
    if c0 + c1 + c2 < 1e-2:
        return
    rng = np.random.default_rng(seed)
    n = np.array([0.0, 0.0, 1.0])
    az = rng.uniform(0, 2 * np.pi)
    sin = np.sqrt(1 - cos * cos)
    x = d * np.array([sin * np.cos(az), sin * np.sin(az), cos])

    def g(y):
        r = np.linalg.norm(y, axis=-1)
        return (y @ n) / (r * (c0 + r * (c1 + r * c2)))

    f1, f2, f3 = (abs(f) for f in _phis(c0, c1, c2, d))
    bound = third_derivative_sup(np.array(cos), np.array(d), f1, f2, f3)
    U = rng.normal(size=(500, 3))
    U /= np.linalg.norm(U, axis=1)[:, None]
    h = 2e-3 * d
    d3 = np.abs((g(x + 2 * h * U) - 2 * g(x + h * U) + 2 * g(x - h * U) - g(x - 2 * h * U))
                / (2 * h ** 3))
    assert d3.max() <= bound * (1 + 1e-3)


@settings(max_examples=100, deadline=None)
@given(c=st.floats(0.0, 1.0), d=st.floats(0.1, 10.0),
       f=st.lists(st.floats(0.0, 10.0), min_size=3, max_size=3))
def test_third_derivative_sup_covers_its_expression_between_the_grids_points(c, d, f):
    """The grid's largest E(θ) plus the slope's margin is at least E's largest on a grid
    100× finer (without the margin the coarse grid misses the peaks between its points)."""
    f1, f2, f3 = f
    got = third_derivative_sup(np.array(c), np.array(d), np.array(f1), np.array(f2), np.array(f3))
    theta = np.linspace(0.0, np.pi / 2, 100 * (THETA_POINTS - 1) + 1)
    t, s = np.cos(theta), np.sin(theta)
    B = f2 / d + f1 / d ** 2
    E = 3 * (c * t + s) * (f2 * t * t + f1 / d * s * s) + c * d * (f3 * t ** 3 + 3 * t * s * s * B)
    assert E.max() <= got * (1 + 1e-12) + 1e-300


@settings(max_examples=60, deadline=None)
@given(att=st.sampled_from(ATTS), d_lo=st.floats(0.05, 20.0),
       ratio=st.lists(st.floats(1.0, 50.0), min_size=20, max_size=20))
def test_phi_sups_hold_beyond_d_lo(att, d_lo, ratio):
    """For φ = A/d at any d ≥ d⁻: d^k·|φ^(k)(d)| ≤ d⁻^k·f_k (f_k at d⁻ bounds |φ^(k)|
    beyond it, and its terms fall with d, as third_derivative_sup needs)."""
    c0, c1, c2 = att
    lo = np.array([d_lo])
    a1_lo, a1, a2 = falloff_slopes(c0, c1, c2, lo, tuple(x for x in falloff_peaks([att])))
    a3 = falloff_third_sup([att], lo)
    A_lo = 1.0 / (c0 + d_lo * (c1 + d_lo * c2))
    fs = phi_sups(A_lo, a1, a2, a3, lo)
    d = d_lo * np.asarray(ratio)
    for k, (phi, f) in enumerate(zip(_phis(c0, c1, c2, d), fs), start=1):
        assert (d ** k * np.abs(phi) <= d_lo ** k * f * (1 + 1e-9)).all(), k


SPEC = SpecularModel(blinn=False, exponent=None, fresnel=False, eye=np.zeros(3), perspective=True)


def _cloud(rng, att, spread, dist, size, grey, n=96):
    lights = []
    for _ in range(n):
        pos = np.array([0.0, 0.0, dist]) + rng.normal(0, spread, 3)
        pos[2] = abs(pos[2]) + 0.05 + size               # in front of the surface z = 0
        lights.append(dict(type="point", position=tuple(pos), attenuation=att,
                           color=(1.0, 1.0, 1.0) if grey else tuple(rng.uniform(0.3, 1.0, 3)),
                           intensity=float(rng.uniform(0.5, 2.0))))
    return make_scene(lights)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), att=st.sampled_from(ATTS),
       spread=st.sampled_from([0.02, 0.3, 1.5]), dist=st.sampled_from([0.8, 3.0, 20.0]),
       tilt=st.sampled_from([0.0, 0.5, 1.2]), grey=st.booleans(),
       size=st.sampled_from([0.0, 0.05, 0.3]), bend=st.sampled_from([0.0, 0.02, 0.15]))
def test_taylor_term_holds_over_its_tile(seed, att, spread, dist, tilt, grey, size, bend):
    """cluster_terms' Taylor term of the diffuse error over a tile (a box of positions and
    of unit normals; size 0 and bend 0: one pixel) is never below any node's true diffuse
    error (float64) at any of the tile's pixels, for falloffs from constant to inverse
    square, clouds of lights near and far, tilted and spread normals, coloured or grey
    lights; and it is finite where the whole cloud is in front of the surface (the test
    is not vacuous). It fails with the remainder /10, or with either tile-spread term
    (the normals' dn or the positions' r) dropped."""
    rng = np.random.default_rng(seed)
    scene = _cloud(rng, att, spread, dist, size, grey)
    a = scene.light_arrays
    tree = build_light_tree(a)
    m = 6 if size or bend else 1
    P = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 0.0]) + rng.uniform(-size, size, (m, 3))
    P[:, 2] = np.minimum(P[:, 2], 0.0)
    n = np.array([np.sin(tilt), 0.0, np.cos(tilt)]) + rng.uniform(-bend, bend, (m, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    D = np.array([0.7, 0.5, 0.3])
    tile = TileBoxes.of_pixels(P, n, np.broadcast_to(D, (m, 3)), np.zeros(3))
    parts = {}
    cluster_terms(tree, tile, SPEC, np.zeros(3), parts=parts)
    tb = np.broadcast_to(parts["diffuse_taylor"], (1, tree.n_nodes, 3))[0]
    px = reference.Pixels(p=P, n=n, v=np.tile([0.0, 0.0, 1.0], (m, 1)), k=np.full(m, 32.0),
                          blinn=False, specular=False)
    start, end, _ = leaf_ranges(tree)
    lights = (end - start)[:, None]
    for j in range(m):
        exact, mag = node_errors(tree, a, px, np.broadcast_to(D, (m, 3)), np.zeros((m, 3)), j,
                                 magnitude=True)
        # the true error's float64 rounding: each contribution carries ≤ 16 roundings (the
        # reference's distance, direction, cosine and falloff), and the node's sum one an
        # addition: ≤ (16 + 2·lights)·2⁻⁵³ of the magnitudes summed
        assert (exact <= tb + (16 + 2 * lights) * 2.0 ** -53 * mag).all()
    if tilt == 0.0 and bend == 0.0:
        assert np.isfinite(tb).mean() >= 0.9


def test_taylor_term_is_what_the_diffuse_bound_takes_on_a_far_cloud():
    """On a far cloud of coloured lights (a tile of 4×4 pixels, normals within 0.05), the
    Taylor term is the least of the diffuse bounds at most nodes, and the diffuse term is
    the least of them all (the bound takes it: the term is not merely computed)."""
    rng = np.random.default_rng(3)
    scene = _cloud(rng, (1.0, 0.1, 0.05), 1.5, 6.0, 0.0, False, n=256)
    tree = build_light_tree(scene.light_arrays)
    P = rng.uniform(-0.02, 0.02, (16, 3)) * [1, 1, 0]
    n = np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.025, 0.025, (16, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    parts = {}
    cluster_terms(tree, TileBoxes.of_pixels(P, n, np.ones((16, 3)), np.zeros(3)), SPEC,
                  np.zeros(3), parts=parts)
    size = np.fmin(np.fmin(parts["diffuse_range"], parts["diffuse_first"]), parts["diffuse_second"])
    tay = np.broadcast_to(parts["diffuse_taylor"], size.shape)
    assert np.mean(tay < size) >= 0.5
    np.testing.assert_array_equal(parts["diffuse"], np.fmin(size, tay))
