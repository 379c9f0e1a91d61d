"""The falloff's slopes over d ≥ d⁻ (clphong/model/falloff.py falloff_peaks and
falloff_slopes), which the light tree's bound uses: each sup is the largest value of the
function on a dense grid of [d⁻, ∞), never below it (a missed turning point would show
as a grid value above the sup), and within the slack of it."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clphong.model.falloff import SLOPE_SLACK, falloff_peaks, falloff_slopes

coefficient = st.one_of(st.just(0.0), st.floats(1e-4, 1e4))


def _on_grid(c0, c1, c2, d):
    x = d * np.exp(np.linspace(0.0, 16.0, 400_001))       # d … d·e¹⁶, then the tail → 0
    p = c0 + x * (c1 + x * c2)
    first = (c1 + 2 * c2 * x) / p ** 2
    second = 2 * np.abs(3 * c2 * c2 * x * x + 3 * c1 * c2 * x + c1 * c1 - c0 * c2) / p ** 3
    return first[0], first.max(), second.max()


@settings(max_examples=300, deadline=None)
@given(c0=coefficient, c1=coefficient, c2=coefficient, d=st.floats(1e-3, 1e3))
def test_the_slopes_sups_are_the_largest_values_beyond_d(c0, c1, c2, d):
    if c0 + c1 + c2 == 0 or (c0 == 0 and c1 == 0 and c2 * d * d < 1e-300):
        return
    at, s1, s2 = falloff_slopes(c0, c1, c2, np.array([d]),
                                tuple(x for x in falloff_peaks([[c0, c1, c2]])))
    a0, m1, m2 = _on_grid(c0, c1, c2, d)
    assert at[0] == a0
    assert m1 <= s1[0] <= m1 * (1 + 1e-6) + 1e-300
    # A″'s sup: the grid's step (relative 4e-5) lies within 1e-6 of a smooth peak
    assert m2 <= s2[0] <= m2 * (1 + 1e-6) + 1e-300


def test_the_turning_points_of_known_falloffs():
    """(1, 0, c2): |A′| peaks where 3c2d² = 1; 1/d² and linear falloffs only fall; no
    falloff has no slope. A row's roots go with it through np.unique."""
    one, two = falloff_peaks([[1.0, 0.0, 0.01], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0],
                              [1.0, 0.0, 0.01]])
    assert np.isclose(one[0, 0], np.sqrt(1 / 0.03)) and np.isnan(one[0, 1])
    assert np.array_equal(one[0], one[3], equal_nan=True) and np.array_equal(two[0], two[3],
                                                                              equal_nan=True)
    assert np.isnan(one[1]).all() and np.isnan(one[2]).all() and np.isnan(two[2]).all()
    _, s1, s2 = falloff_slopes(1.0, 0.0, 0.0, np.array([2.0]), (one[2:3], two[2:3]))
    assert s1[0] == 0 and s2[0] == 0
    # A = 1/d²: |A′| = 2/d³ and |A″| = 6/d⁴ fall, so the sups are the values at d
    _, s1, s2 = falloff_slopes(0.0, 0.0, 1.0, np.array([2.0]), (one[1:2], two[1:2]))
    assert np.isclose(s1[0], 2 / 8 * (1 + SLOPE_SLACK), rtol=1e-15)
    assert np.isclose(s2[0], 6 / 16 * (1 + SLOPE_SLACK), rtol=1e-15)


def _diffuse_weight(c0, c1, c2, n, x):
    """g(p) = max(n·u, 0)·A(|p − x|), u = (p − x)/|p − x|: the light tree's diffuse weight."""
    def g(p):
        v = p - x
        d = np.sqrt(v @ v)
        return max(n @ v / d, 0.0) / (c0 + d * (c1 + d * c2))
    return g


@settings(max_examples=200, deadline=None)
@given(c0=st.floats(0.0, 10.0), c1=st.floats(0.0, 10.0), c2=st.floats(0.0, 10.0),
       d=st.floats(0.05, 50.0), cos=st.floats(0.05, 1.0), az=st.floats(0.0, 6.283),
       seed=st.integers(0, 2**31 - 1))
def test_the_diffuse_weights_slopes_are_within_the_trees_constants(c0, c1, c2, d, cos, az, seed):
    """light_tree.cluster_bounds' diffuse constants, at a point: |∇g| ≤ max(A/d, |A′|) and
    ‖∇²g‖ ≤ √(m² + max(m, |A″|)²), m = A/d² + |A′|/d, against central differences of g
    itself (the module docstring derives them from the Hessian in the frame (u, w, u × w))."""
    if c0 + c1 + c2 < 1e-3:
        return
    rng = np.random.default_rng(seed)
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    t = np.cross(n, rng.normal(size=3))
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    sin = np.sqrt(1.0 - cos * cos)
    u = cos * n + sin * (np.cos(az) * t + np.sin(az) * b)
    x = rng.normal(size=3)
    p = x + d * u
    g = _diffuse_weight(c0, c1, c2, n, x)
    h = 1e-4 * d * min(cos, 1.0)              # stays on the lit side: g is smooth there
    E = np.eye(3) * h
    grad = np.array([(g(p + e) - g(p - e)) / (2 * h) for e in E])
    hess = np.array([[(g(p + ei + ej) - g(p + ei - ej) - g(p - ei + ej) + g(p - ei - ej))
                      / (4 * h * h) for ej in E] for ei in E])
    P = c0 + d * (c1 + d * c2)
    A, A1 = 1.0 / P, (c1 + 2 * c2 * d) / P ** 2
    A2 = 2 * abs(3 * c2 * c2 * d * d + 3 * c1 * c2 * d + c1 * c1 - c0 * c2) / P ** 3
    m = A / d ** 2 + A1 / d
    # central differences err by O(h²) relative: 1e-5 of the bound covers them
    assert np.linalg.norm(grad) <= max(A / d, A1) * (1 + 1e-5)
    assert np.linalg.norm(hess, 2) <= np.sqrt(m * m + max(m, A2) ** 2) * (1 + 1e-4)


def test_the_slopes_hold_at_the_float32_extremes_a_scene_allows():
    """Coefficients at the ends of the normal float32 range, which the scene parser
    accepts: the turning points are found (the roots are searched on the row over its
    largest coefficient, so c2³ neither overflows nor underflows), and each sup is the
    grid's largest value."""
    tiny, huge = float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max)
    for row, d in (((huge, 0.0, tiny), 1e37), ((tiny, 0.0, huge), 1e-40),
                   ((1.0, tiny, tiny), 1e18)):
        peaks = falloff_peaks([row])
        assert not np.isnan(peaks[0][0, 0])           # |A′| turns beyond 0 in each
        _, s1, s2 = falloff_slopes(*row, np.array([d]), peaks)
        _, m1, m2 = _on_grid(*row, d)
        assert m1 <= s1[0] <= m1 * (1 + 1e-6) and m2 <= s2[0] <= m2 * (1 + 1e-6), row


@settings(max_examples=300, deadline=None)
@given(c0=coefficient, c1=coefficient, c2=coefficient, d=st.floats(1e-3, 1e3))
def test_the_third_derivatives_sup_is_the_largest_value_beyond_d(c0, c1, c2, d):
    """falloff_third_sup against |A‴| on a dense grid of [d, ∞) (A‴ by its closed form,
    itself checked against differences of A below): never below the grid's largest
    value (a missed turning point would show), and within the slack of it."""
    from clphong.model.falloff import falloff_third_sup
    if c0 + c1 + c2 == 0 or (c0 == 0 and c1 == 0 and c2 * d * d < 1e-300):
        return
    x = d * np.exp(np.linspace(0.0, 16.0, 400_001))
    p = c0 + x * (c1 + x * c2)
    p1 = c1 + 2 * c2 * x
    grid = np.abs(6 * p1 * (2 * c2 * p - p1 * p1) / p ** 4)
    s = falloff_third_sup([[c0, c1, c2]], np.array([d]))[0]
    assert grid.max() <= s <= grid.max() * (1 + 1e-6) + 1e-300


def test_the_third_derivatives_closed_form():
    """A‴ = 6p′(p·p″ − p′²)/p⁴ against fourth-order differences of A, and its known sup:
    for A = 1/d², |A‴| = 24/d⁵ falls, so the sup over [d, ∞) is the value at d."""
    from clphong.model.falloff import SLOPE_SLACK, falloff_third_sup
    c0, c1, c2, d, h = 0.7, 0.3, 0.2, 1.3, 1e-3
    A = lambda x: 1.0 / (c0 + x * (c1 + x * c2))               # noqa: E731
    fd = (A(d + 2 * h) - 2 * A(d + h) + 2 * A(d - h) - A(d - 2 * h)) / (2 * h ** 3)
    p, p1 = c0 + d * (c1 + d * c2), c1 + 2 * c2 * d
    assert np.isclose(fd, 6 * p1 * (p * 2 * c2 - p1 * p1) / p ** 4, rtol=1e-5)
    s = falloff_third_sup([[0.0, 0.0, 1.0]], np.array([2.0]))
    assert np.isclose(s[0], 24 / 32 * (1 + SLOPE_SLACK), rtol=1e-15)
