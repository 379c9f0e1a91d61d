"""The device's FP32 peak, from ``kernels/peak.cl``: independent FMA chains per lane."""

from __future__ import annotations

import os
import statistics

import numpy as np

__all__ = ["measure_peak_gflops"]


def measure_peak_gflops(runtime, repeats: int = 5) -> float:
    """Median FP32 GFLOP/s of kernels/peak.cl on the device."""
    import pyopencl as cl

    lanes = max(runtime.lanes, 1)
    prog = runtime.program("peak.cl", {"LANES": lanes})
    items = 64 * 64 * max(os.cpu_count() or 1, 1)
    iterations = 2048
    out = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, items * lanes * 4)
    times = []
    with runtime.lock:
        kern = runtime.kernel(prog, "fma_peak")
        kern.set_args(out, np.uint32(iterations), np.float32(0.999), np.float32(1e-3))
        for _ in range(repeats + 1):
            evt = cl.enqueue_nd_range_kernel(runtime.queue, kern, (items,), (64,))
            evt.wait()
            times.append((evt.profile.end - evt.profile.start) * 1e-9)
    flops = 2.0 * lanes * 8 * iterations * items
    return flops / statistics.median(times[1:]) / 1e9
