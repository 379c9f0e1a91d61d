"""The light-tree floor tool (clphong.tools.cut_floor): the oracle cut refines to single
lights at ε = 0, collapses to the root at a budget above the whole image, and grows as ε
falls."""

from __future__ import annotations

import numpy as np

from clphong.tools.bench import bench_gbuffer, bench_scene
from clphong.tools.cut_floor import cut_sizes


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
