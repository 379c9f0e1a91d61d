"""clphong.tools.numba_peer: the bench's numba yardstick shades the bench scene
correctly (a fast wrong peer would make every ratio meaningless)."""

from __future__ import annotations

import numpy as np
import pytest

from clphong.reference import shading as reference
from clphong.tools import (
    bench,
    numba_peer,  # noqa: E402
)

if not numba_peer.available():
    pytest.skip("numba is not installed (the bench extra)", allow_module_level=True)

U = 2.0 ** -24


@pytest.mark.parametrize("n", [1, 16])
def test_peer_matches_the_float64_reference(n):
    """Error model: float32 throughout, a few u per operation (fastmath's rsqrt is
    refined by a Newton step), and the specular power x^K multiplies the base's
    relative error by K and adds one rounding per multiply: ≤ (2K + 64)·u of the
    pixel's value. Terms below FLT_MIN (c^K flushed to 0 by the peer) err by less
    than FLT_MIN·radiance, far below the floor used here."""
    scene = bench.bench_scene("wide", n)
    gb = bench.bench_gbuffer(96, 54)
    peer = numba_peer.NumbaPeer(scene, gb)
    got = peer.shade().astype(np.float64)
    ref = reference.shade(scene, gb)
    K = scene.material.exponent
    tol = (2 * K + 64) * U * np.abs(ref) + 1e-30
    assert np.all(np.abs(got - ref) <= tol), float(np.max(np.abs(got - ref) / np.maximum(np.abs(ref), 1e-30)))
    # and it is not trivially right: the specular term matters on this frame
    flat = bench.bench_scene("wide", n)
    import dataclasses
    matte = dataclasses.replace(flat, material=dataclasses.replace(flat.material, k_s=0.0))
    assert np.max(np.abs(reference.shade(matte, gb) - ref)) > 1e3 * tol.max()


def test_peer_refuses_a_non_whole_exponent():
    import dataclasses
    scene = bench.bench_scene("wide", 1)
    scene = dataclasses.replace(scene, material=dataclasses.replace(scene.material, h=7.3))
    with pytest.raises(ValueError, match="whole exponent"):
        numba_peer.NumbaPeer(scene, bench.bench_gbuffer(16, 8))


def test_fma_loop_reports_a_rate_and_a_vector_width():
    assert numba_peer.fma_peak_gflops(iterations=20_000, repeats=1) > 0
    assert numba_peer.fma_vector_bits() in (128, 256, 512)


def test_bench_runs_the_peer_side_by_side():
    cfg = bench.BenchConfig(sizes=((64, 36),), lights=(4,), small_lights=(), paths=("accurate",),
                            budgets=(), repeats=1, warmup=0)
    report = bench.run_bench(cfg)
    peer = report["numba"]
    assert len(peer) == 1 and peer[0]["gple_per_s"] > 0
    run = [r for r in report["runs"] if r["path"] == "accurate"][0]
    assert run["numba_ratio"] == pytest.approx(run["ple_per_s"] / peer[0]["ple_per_s"])
    assert report["machine"]["fp32_peak"]["numba_fma_gflops"] > 0
