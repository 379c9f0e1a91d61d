"""The device's FP32 peak, from ``kernels/peak.cl``: independent FMA chains per lane.

The probe runs at a few (lanes, chains) shapes and keeps the best: enough
independent chains to hide the FMA latency, few enough to stay in registers
(see the kernel's comment). ``clphong bench`` checks the figure against a
numba FMA loop where numba is installed (:mod:`clphong.tools.numba_peer`).
"""

from __future__ import annotations

import os
import statistics

import numpy as np

__all__ = ["measure_peak_gflops", "peak_shapes", "measure_fp64_ratio", "FAST_FP64_RATIO"]


def peak_shapes(lanes: int) -> tuple[tuple[int, int], ...]:
    """(LANES, CHAINS) shapes to try on a device whose lane kernel uses ``lanes``."""
    shapes = [(lanes, 8), (lanes, 12)]
    if lanes > 8:
        shapes += [(8, 8), (8, 12)]
    return tuple(shapes)


def _shape_gflops(runtime, lanes: int, chains: int, repeats: int, double: bool = False) -> float:
    """Median GFLOP/s of kernels/peak.cl at one (LANES, CHAINS) shape, in float or double."""
    import pyopencl as cl

    items = 64 * 64 * max(os.cpu_count() or 1, 1)
    iterations = 1024
    prog = runtime.program("peak.cl", {"LANES": lanes, "CHAINS": chains, "PEAK_DOUBLE": int(double)})
    out = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, items * lanes * (8 if double else 4))
    times = []
    with runtime.lock:
        kern = runtime.kernel(prog, "fma_peak")
        kern.set_args(out, np.uint32(iterations), np.float32(0.999), np.float32(1e-3))
        for _ in range(repeats + 1):
            evt = cl.enqueue_nd_range_kernel(runtime.queue, kern, (items,), (64,))
            evt.wait()
            times.append((evt.profile.end - evt.profile.start) * 1e-9)
    return 2.0 * lanes * chains * iterations * items / statistics.median(times[1:]) / 1e9


def measure_fp64_ratio(runtime, repeats: int = 3) -> float:
    """The device's double-to-float FMA rate, measured (0 without cl_khr_fp64): about 0.5
    on CPUs with AVX and on the H100/H200, A100 and MI300, 1/16-1/64 on consumer GPUs. The
    shading plan computes in double only where it is at least :data:`FAST_FP64_RATIO`."""
    if not runtime.has_fp64:
        return 0.0
    lanes = max(runtime.lanes, 1)
    single = _shape_gflops(runtime, lanes, 12, repeats)
    double = _shape_gflops(runtime, lanes, 12, repeats, double=True)
    return double / single if single > 0 else 0.0


#: Double at least this fraction of the float rate counts as fast (issue 29): the plan then
#: sums, powers and forms directions in double, which the accurate path's 5e-6 needs.
FAST_FP64_RATIO = 0.25


def measure_peak_gflops(runtime, repeats: int = 5, detail: dict | None = None) -> float:
    """Median FP32 GFLOP/s of kernels/peak.cl on the device, the best shape's.

    ``detail``, a dict, receives each shape's figure ("LxC": GFLOP/s) and the best one.
    """
    best = 0.0
    for lanes, chains in peak_shapes(max(runtime.lanes, 1)):
        gflops = _shape_gflops(runtime, lanes, chains, repeats)
        if detail is not None:
            detail[f"{lanes}x{chains}"] = gflops
        if gflops > best:
            best = gflops
            if detail is not None:
                detail["best"] = {"lanes": lanes, "chains": chains}
    return best
