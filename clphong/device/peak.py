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

__all__ = ["measure_peak_gflops", "peak_shapes", "ratio_shapes", "measure_fp64_ratio",
           "FAST_FP64_RATIO", "native_rsqrt_inputs", "measure_native_rsqrt_ulp",
           "measure_builtin_rsqrt_ulp", "measure_rsqrt_ulp", "NATIVE_RSQRT_MAX_ULP"]


def peak_shapes(lanes: int) -> tuple[tuple[int, int], ...]:
    """(LANES, CHAINS) shapes to try on a device whose lane kernel uses ``lanes``."""
    shapes = [(lanes, 8), (lanes, 12)]
    if lanes > 8:
        shapes += [(8, 8), (8, 12)]
    return tuple(shapes)


def _fma_timer(runtime, lanes: int, chains: int, double: bool = False):
    """A function that runs kernels/peak.cl once at one (LANES, CHAINS) shape, in float or
    double, and returns its GFLOP/s; the first run (which may build or page in) is done."""
    import pyopencl as cl

    items = 64 * 64 * max(os.cpu_count() or 1, 1)
    iterations = 1024
    prog = runtime.program("peak.cl", {"LANES": lanes, "CHAINS": chains, "PEAK_DOUBLE": int(double)})
    out = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, items * lanes * (8 if double else 4))
    flops = 2.0 * lanes * chains * iterations * items

    def run() -> float:
        with runtime.lock:
            kern = runtime.kernel(prog, "fma_peak")
            kern.set_args(out, np.uint32(iterations), np.float32(0.999), np.float32(1e-3))
            evt = cl.enqueue_nd_range_kernel(runtime.queue, kern, (items,), (64,))
            evt.wait()
        return flops / ((evt.profile.end - evt.profile.start) * 1e-9) / 1e9

    run()
    return run


def _shape_gflops(runtime, lanes: int, chains: int, repeats: int, double: bool = False) -> float:
    """Median GFLOP/s of kernels/peak.cl at one (LANES, CHAINS) shape, in float or double."""
    run = _fma_timer(runtime, lanes, chains, double)
    return statistics.median(run() for _ in range(repeats))


def ratio_shapes(lanes: int) -> tuple[tuple[tuple[int, int], ...], tuple[tuple[int, int], ...]]:
    """The (LANES, CHAINS) shapes at which :func:`measure_fp64_ratio` times float, and
    those at which it times double: the float shapes' widths and, where it is a width
    lanes.h takes (4, 8 or 16), half of each (the same register bytes a chain). Each
    precision keeps its best shape, so that neither is read through spills: 12 chains of
    float16 are 24 ymm registers on AVX2 (16 in all), and of double16 48; Intel's runtime
    at 16 lanes read 0.2 on Zen 3 (AVX2), whose hardware runs double at half the float
    rate (2026-12-07)."""
    single = tuple(dict.fromkeys([(lanes, 12), (min(lanes, 8), 12)]))
    halves = [(n // 2, c) for n, c in single if n // 2 in (4, 8, 16)]
    return single, tuple(dict.fromkeys([*single, *halves]))


def measure_fp64_ratio(runtime, repeats: int = 5) -> float:
    """The device's double-to-float FMA rate, measured (0 without cl_khr_fp64): about 0.5
    on CPUs with AVX and on the H100/H200, A100 and MI300, 1/16-1/64 on consumer GPUs. The
    shading plan computes in double only where it is at least :data:`FAST_FP64_RATIO`.

    Float and double run in turns and each keeps its best run: a busy machine only ever
    slows a run, and slowed float runs must not read as double outrunning float (a CI
    run on 2-core Zen 4 measured 1.79 with medians of three float runs, then three double).
    Each precision is timed at the shapes of :func:`ratio_shapes` and keeps its best."""
    if not runtime.has_fp64:
        return 0.0
    single_shapes, double_shapes = ratio_shapes(max(runtime.lanes, 1))
    single = [_fma_timer(runtime, n, c) for n, c in single_shapes]
    double = [_fma_timer(runtime, n, c, double=True) for n, c in double_shapes]
    best_single = best_double = 0.0
    for _ in range(repeats):
        best_single = max([best_single] + [run() for run in single])
        best_double = max([best_double] + [run() for run in double])
    return best_double / best_single if best_single > 0 else 0.0


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


#: The error model's 1/√x in float: within 2 ulp, the OpenCL C builtin's specified bound.
NATIVE_RSQRT_MAX_ULP = 2.0


def native_rsqrt_inputs() -> np.ndarray:
    """Every float of [1, 4) (a factor 4 in x moves the hardware estimate and the Newton
    step by exactly ½, so this binade stands for every normal float where the estimate
    scales so), every third float of the bottom binades [FLT_MIN, 4·FLT_MIN) (where the
    other guesses' rsqrt_dist rescales, and this one's Newton step never forms x/2),
    and 100,001 floats spread from FLT_MIN to FLT_MAX in case an implementation's
    estimate does not scale."""
    binade = np.arange(0x3F800000, 0x40800000, dtype=np.uint32).view(np.float32)
    bottom = np.arange(0x00800000, 0x01800000, 3, dtype=np.uint32).view(np.float32)
    f32 = np.finfo(np.float32)
    spread = np.geomspace(f32.tiny, f32.max, 100_001).astype(np.float32)
    return np.concatenate([binade, bottom, spread])


def measure_native_rsqrt_ulp(runtime, lanes: int | None = None, chunk: int = 1 << 22) -> float:
    """The largest error, in float ulp of 1/√x, of the shading kernel's rsqrt_dist with
    native_rsqrt as its first guess and one Newton step (kernels/rsqrt_probe.cl,
    RSQRT_GUESS_KIND 4) at ``lanes`` (the runtime's width by default), over
    :func:`native_rsqrt_inputs`; inf where it is not finite there, or gets rsqrt(0) = +∞
    or rsqrt(+∞) = 0 wrong. The plan takes that guess (RSQRT_NATIVE) only within
    :data:`NATIVE_RSQRT_MAX_ULP`."""
    return measure_rsqrt_ulp(runtime, lanes, chunk, guess=4)


def measure_builtin_rsqrt_ulp(runtime, lanes: int | None = None, chunk: int = 1 << 22) -> float:
    """:func:`measure_native_rsqrt_ulp` for the OpenCL C builtin rsqrt in float
    (RSQRT_GUESS_KIND 3), built as the shading kernel is (``-cl-denorms-are-zero``). The
    specification allows it 2 ulp, but Intel's CPU runtime 2026.2 on an AVX2 host (Zen 3)
    returned 2.4·10⁻¹⁹ for every x ≥ 8.5·10³⁷ at 1, 8 and 16 lanes (2·10⁷ ulp; right at 4
    lanes, and without denormals flushed): the plan takes the builtin (RSQRT_BUILTIN)
    only at a width where this is within :data:`NATIVE_RSQRT_MAX_ULP` (2026-12-07)."""
    return measure_rsqrt_ulp(runtime, lanes, chunk, guess=3)


def measure_rsqrt_ulp(runtime, lanes: int | None = None, chunk: int = 1 << 22, *,
                      guess: int) -> float:
    """The largest error, in float ulp, of rsqrt_dist with the first guess ``guess``
    (clphong.h's RSQRT_GUESS_KIND) over :func:`native_rsqrt_inputs`, 0 and +∞."""
    import pyopencl as cl

    lanes = max(lanes or runtime.lanes, 1)
    defines = {"LANES": lanes, "RSQRT_GUESS_KIND": guess, "DIRECTIONS_FP64": 0, "SUM_FP64": 0,
               "SPEC_INT_POW": 0, "SPEC_COS": 0, "POW_FP32": 0, "WEIGHTS_FP64": 0}
    prog = runtime.program("rsqrt_probe.cl", defines)
    x_all = np.concatenate([np.float32([0.0, np.inf]), native_rsqrt_inputs()])
    chunk -= chunk % lanes
    worst = 0.0
    with runtime.lock:
        kern = runtime.kernel(prog, "rsqrt_probe")
        for a in range(0, len(x_all), chunk):
            x = x_all[a:a + chunk]
            n = len(x)
            x = np.concatenate([x, np.ones(-n % lanes, np.float32)])
            mf = cl.mem_flags
            xb = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
            yb = cl.Buffer(runtime.context, mf.WRITE_ONLY, x.nbytes)
            kern(runtime.queue, (len(x) // lanes,), None, xb, yb)
            y = np.empty_like(x)
            cl.enqueue_copy(runtime.queue, y, yb)
            y, x = y[:n].astype(np.float64), x[:n].astype(np.float64)
            if a == 0:                   # rsqrt(0) = +inf, rsqrt(+inf) = 0, as the builtin's
                if not (y[0] == np.inf and y[1] == 0.0):
                    return float("inf")
                y, x = y[2:], x[2:]
            ref = 1.0 / np.sqrt(x)
            ulp = np.exp2(np.floor(np.log2(ref)) - 23)
            err = np.abs(y - ref) / ulp
            if not np.all(np.isfinite(err)):
                return float("inf")
            worst = max(worst, float(err.max()))
    return worst
