"""The light-tree floor tool (clphong.tools.cut_floor): the oracle cut refines to single
lights at ε = 0, collapses to the root at a budget above the whole image, and grows as ε
falls."""

from __future__ import annotations

import numpy as np

from clphong.tools.bench import bench_gbuffer, bench_scene
from clphong.tools.cut_floor import TERMS, cut_sizes, level_slack


def test_oracle_cut_limits_and_monotone():
    n = 128
    scene = bench_scene("wide", n)
    gb = bench_gbuffer(96, 54)
    sizes = cut_sizes(scene, gb, [0.0, 1e-3, 1e-1, 1e3], n_pixels=3)
    for k in range(3):
        s0, s3, s1, big = (sizes[e][k] for e in (0.0, 1e-3, 1e-1, 1e3))
        assert big == 1                        # the root alone errs by less than 1e3
        assert s0 >= s3 >= s1 >= big
        assert s0 >= 0.9 * n                   # exact: (nearly) every light its own node
    assert np.median(sizes[1e-3]) > np.median(sizes[1e-1])


def test_level_slack_holds_the_bound_and_names_its_terms():
    """Per depth, the bound is never below the true error (bound / error ≥ 1 at the 10th
    percentile and so everywhere it is counted), the term shares cover the pairs, and the
    diffuse term's parts are the bound's: a bound that dropped its curvature part would
    fall below the true error at the deep levels."""
    scene = bench_scene("wide", 256)
    rows = level_slack(scene, bench_gbuffer(96, 54), n_pixels=3)
    assert [r["depth"] for r in rows] == list(range(len(rows))) and len(rows) >= 6
    for r in rows:
        assert r["slack_p10"] >= 1.0 and r["slack"] >= r["slack_p10"]
        shares = sum(r[t] for t in TERMS)
        assert 0.99 <= shares <= 1.0 + 1e-9, shares       # ties go to one term
        assert r["bound"] >= r["error"]
