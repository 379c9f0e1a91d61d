"""The output helpers rewritten for speed (issue 14) give the values of their plain
formulations: the EXR's A (coverage_of) and the display code values (writers._check)."""

from __future__ import annotations

import numpy as np
import pytest

from clphong.deliver import writers
from clphong.deliver.outputs import coverage_of
from clphong.io.gbuffer import GBuffer


def _gb(coverage):
    rng = np.random.default_rng(1)
    N = rng.standard_normal((9, 11, 3)).astype(np.float32)
    N[2, :4] = 0.0
    N[3, 0, 1] = np.nan
    P = rng.standard_normal((9, 11, 3)).astype(np.float32)
    return GBuffer(position=P, normal=N, albedo=P, coverage=coverage)


@pytest.mark.parametrize("dtype", [None, np.float32, np.float64, np.float16])
def test_coverage_of_is_the_plain_formula(dtype):
    cov = None
    if dtype is not None:
        cov = np.random.default_rng(2).uniform(-0.5, 1.5, (9, 11)).astype(dtype)
        cov[0, :3] = [np.nan, 0.0, 1.0]
    gb = _gb(cov)
    covered = ~gb.background_mask()
    want = (covered.astype(np.float32) if cov is None
            else np.where(covered, np.clip(cov, 0, 1), 0).astype(np.float32))
    got = coverage_of(gb)
    assert got.dtype == np.float32 and got.shape == (9, 11)
    assert got.tobytes() == want.tobytes()
    if cov is not None:
        assert not np.shares_memory(got, cov)


def test_display_code_values_are_the_plain_clip():
    a = np.array([[[np.nan, np.inf, -np.inf], [-0.0, 0.0, 0.5], [1.0, 1.0000001, -1e-9],
                   [3e38, -3e38, 1e-45]]], np.float32)
    before = a.copy()
    got = writers._check("x.png", a)
    want = np.clip(np.nan_to_num(a, nan=0.0), 0.0, 1.0)
    assert got.dtype == np.float32 and np.array_equal(got, want)     # -0.0 == 0.0
    assert a.tobytes() == before.tobytes() and not np.shares_memory(got, a)
    with pytest.raises(writers.OutputError, match="expected a non-empty"):
        writers._check("x.png", np.zeros((2, 2)))
