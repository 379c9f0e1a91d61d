"""clphong.reference.shading: the float64 twins of the kernel's specular forms."""

from __future__ import annotations

import numpy as np
import pytest

from clphong.reference import shading as reference


@pytest.mark.parametrize("K", [0, 1, 2, 3, 7, 32, 128, 1000, 40000, 65536])
def test_reference_integer_power_is_the_same_function(K):
    """reference.specular_power_int (the kernel's twin) against exp(k·log1p(−δ)) in
    float64: both are max(1 − δ, 0)^K; binary powering errs by ≤ 2K·2⁻⁵³ and the exp
    form by ~(2 + |y|)·2⁻⁵³ relative, y = K·log1p(−δ); 0⁰ := 1 and δ ≥ 1 give 0 in both."""
    delta = np.concatenate([[0.0, 1e-300, 1e-12, 1e-6, 0.5, 1.0 - 1e-12, 1.0, 1.5, 2.0],
                            np.geomspace(1e-9, 0.9, 200)])
    a = reference.specular_power_int(delta, K)
    b = reference.specular_power(delta, float(K))
    tiny = b < 1e-290                            # deep underflow: both 0 or denormal
    y = np.abs(K * np.log1p(-np.where(delta < 1.0, delta, 0.0)))     # exp's argument
    tol = (2 * K + 8 + 4 * y) * 2.0 ** -53
    assert np.all(np.abs(a - b)[~tiny] <= tol[~tiny] * b[~tiny])
    assert np.all(a[delta >= 1.0] == (1.0 if K == 0 else 0.0))
    # NaN δ (NaN inputs under the "pass" policy) stays NaN, for K = 0 too, as in the exp form.
    assert np.isnan(reference.specular_power_int(np.array([np.nan]), K)[0])
    assert np.isnan(reference.specular_power(np.array([np.nan]), float(K))[0])


def test_reference_cosine_forms_are_the_same_function():
    """The SPEC_COS twins against the δ forms in float64, on random unit vectors: for
    unit n, l, v, r·v = 1 − |r − v|²/2 and n·h = 1 − |n − h|²/2 are identities, so
    they differ only by float64 roundings (terms ≤ 3: ≤ 32·2⁻⁵³); guards alike."""
    rng = np.random.default_rng(5)

    def unit(m):
        x = rng.normal(size=(m, 3))
        return x / np.linalg.norm(x, axis=1)[:, None]

    n, l, v = unit(20000), unit(20000), unit(20000)
    l[:50] = -v[:50]                                   # Blinn's undefined half vector
    NoL, NoV = np.sum(n * l, 1), np.sum(n * v, 1)
    tol = 32 * 2.0 ** -53
    x = reference.phong_cos(l, v, NoL, NoV)
    assert np.max(np.abs(x - np.maximum(1.0 - reference.phong_delta(n, l, v, NoL), 0.0))) <= tol
    y = reference.blinn_cos_sq(l, v, NoL, NoV)
    c = 1.0 - reference.blinn_delta(n, l, v)           # n·h, and 0 where l = −v
    assert np.all(y[:50] == 0.0)
    assert np.max(np.abs(y - np.where(c > 0, c * c, 0.0))[50:]) <= tol
    h = (l + v)[50:] / np.linalg.norm((l + v)[50:], axis=1)[:, None]
    yc = reference.blinn_cos_sq_const_h(n[50:], h)
    assert np.max(np.abs(yc - np.where(c[50:] > 0, c[50:] ** 2, 0.0))) <= tol
    assert np.all(reference.blinn_cos_sq_const_h(n[50:], h, undefined=True) == 0.0)
    # x^K for x ≥ 0: 0⁰ := 1, NaN stays NaN, and 1 − δ gives the δ form; phong_cos
    # clamps r·v ≤ 0 to 0 (blinn_cos_sq never goes below 0).
    assert np.all(x >= 0.0) and np.all(y >= 0.0)
    for K in (0, 1, 2, 33, 128, 65536):
        edge = reference.specular_power_cos(np.array([0.0, 1.0, 0.5, np.nan]), K)
        assert np.array_equal(edge[:3], [1.0, 1.0, 1.0] if K == 0 else [0.0, 1.0, 0.5 ** K])
        assert np.isnan(edge[3])
        d = np.geomspace(1e-9, 0.99, 50)
        assert np.array_equal(reference.specular_power_cos(1.0 - d, K),
                              reference.specular_power_int(d, K))
