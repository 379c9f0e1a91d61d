"""``clphong bench``: throughput against error, on a fixed, documented scene set.

The scenes (seeded, generated in memory; nothing is read from disk)
--------------------------------------------------------------------
G-buffer
    A gently waving surface ``z = 0.05·sin(1.3x)·cos(1.7y) + 0.03·sin(3.1x + 1)``
    over ``x ∈ [−8, 8]``, ``y ∈ [−4.5, 4.5]``, one pixel per grid point of a
    ``W × H`` image (1920×1080 by default), analytic normals, a smooth albedo
    pattern, and a 4 % background corner. Perspective camera at (0, −4, 10).
    Blinn-Phong, ``k_a = 0.1, k_d = 0.7, k_s = 0.2, h = 32`` (exponent 128),
    one ambient light.
``wide`` (N = 1, 16, 256, 4096, 65 536 point lights)
    Lights 0.5–3 units above the surface, attenuation (1, 0.1, 0.05): every
    light reaches every pixel, nothing can be culled at a useful budget.
``small`` (N = 65 536, and the other N)
    Lights 0.01–0.05 units above the surface, attenuation (1, 0, 10⁶),
    k_s = 0.02: each light lights a few pixels, and the sum of the far tails
    stays below 10⁻³ of reference white.

What is measured
----------------
* Each (scene, N, path, budget) runs ``warmup`` frames, then ``repeats``
  frames; the report gives the median, and every time. The runs of one
  (scene, N) take turns, one frame each per round, the numpy baseline too
  (up to 3 of its rounds): a burst of load from another tenant then falls on
  every path alike, and the ratios within a report hold. Time is device time from
  OpenCL profiling events: the shading kernel, plus the culling kernels when
  culling is on (both reported).
* PLE/s counts pixel-light evaluations of shaded pixels: ``S·N / time``, S
  the pixels that are not background (``shaded_pixels``; the kernel skips the
  lights for work-items of background pixels only, and the numpy baseline
  shades only S too). Brute-force equivalent for culled runs, so speed-ups
  read directly.
* Brute force at large N would take minutes a frame; it runs on a crop of the
  frame's top rows (``crop_rows`` in the report, at least 16 rows and about
  ``crop_pairs`` pixel-light pairs). Throughput does not depend on the frame
  height; ``ms_per_frame`` is then scaled to the full frame by its shaded
  pixels (``extrapolated``: the top rows hold more background than the frame).
  Culled runs that evaluate nearly every pair (the wide scene, where nothing
  can be dropped, and ε = 0) use the same crop, but at least 16 rows (one row
  of tiles); the small-reach scene's culled runs at ε > 0 always shade the
  full frame. The obvious kernel is skipped above ``OBVIOUS_MAX_LIGHTS``.
* Error: the float64 reference (:mod:`clphong.reference.shading`) on a seeded random
  subset of the shaded pixels (``sampled_pixels``: all of them up to
  ``--error-pairs``/N, at least 500). Relative error is
  ``|kernel − reference|/reference`` on pixels ≥ 10⁻⁶ of the sample's maximum,
  max and mean, with pixels in the terminator band (``error_bound``'s ``band``)
  counted and reported separately (``band_pixels``, ``band_max_rel``). Culled
  runs also report the max absolute error, to compare with the budget ε.
* numpy: a careful numpy float32 implementation of the same shading (SoA
  planes, in-place operations, a loop over lights, binary powering:
  :func:`numpy_shade`), timed in the same run on at least 1/8 of the frame
  (:func:`numpy_crop`); ``numpy_ratio`` = kernel PLE/s / numpy PLE/s.
* numba: the peer of :mod:`clphong.tools.numba_peer` on the brute-force crop,
  when numba is installed; ``numba_ratio`` = kernel PLE/s / numba PLE/s.
* FP32 peak: ``kernels/peak.cl`` (independent multiply-add chains) measures the
  device's peak GFLOP/s in the same run; ``peak_fraction`` =
  PLE/s × ``flops_per_ple`` / peak, with the run's own flop count
  (:func:`flops_per_ple`, itemised in :data:`FLOPS`; on the bench scene 58 on
  the default path, 71 on the float paths (the integer power of 1 − δ), 93
  with exp/log1p, 89 for the obvious kernel; double operations count as one
  flop each).

* Environment light (issue 16; :func:`run_environment`): the sample sky
  (:func:`clphong.tools.samples.sky_envmap`) at 1024×512 on the bench
  G-buffer, bench material, no other light, for each ``env_errors`` target
  (``--env-error``) and each ``env_probes`` (``frame``: estimated on the bench
  G-buffer's own pixels, as the commands do by default; ``all``: on every normal
  and view): the conversion's light count, estimate and time; ms per
  frame (timed as above, on a crop, in turns with a 256-point-light brute
  force frame of the wide scene: ``time_ratio_256_point``; the wide scene's own
  256-light run, if the run has one, is reported beside it); and the max relative error of the
  kernel's image against the exact float64 texel sum
  (:mod:`clphong.reference.environment`, every texel) on ``env_pixels``
  (2000) seeded random shaded pixels, on those ≥ 10⁻³ of their maximum, with
  the diffuse and specular terms' shares apart and the fewest lights of the
  same tree that would meet the target on these pixels.

The report is JSON (``--json``) and a Pareto plot PNG (``--plot``, matplotlib)
of throughput against error. A benchmark, not a test: the tests only check that
a tiny run produces a well-formed report.
"""

from __future__ import annotations

import dataclasses

import json
import math
import os
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

from ..device.peak import measure_peak_gflops
from ..device.plan import int_pow_multiplies
from ..device.frame import LOCAL_SIZE
from ..device.renderer import Renderer, prepare_frame
from ..device.selection import get_runtime
from ..io.atomic import atomic_path
from . import numba_peer
from .bench_rows import (
    ENV_ERRORS,
    TREE_CASES,
    environment_summary_lines,
    environment_table,
    run_environment,
    run_tree,
    summarise_environment,
    tree_table,
)
from .bench_scenes import (
    SEED,
    _crop_rows,
    _time_slots,
    bench_gbuffer,
    bench_scene,
    make_oracle,
    numpy_shade,
    shaded_pixels,
)

__all__ = ["BenchConfig", "run_bench", "summarise", "summary_lines", "table", "save_report",
           "plot_pareto", "check_paths", "missing_bench_modules", "flops_per_ple", "PATHS",
           "ENV_ERRORS", "TREE_CASES", "SEED", "bench_gbuffer", "bench_scene", "numpy_shade",
           "shaded_pixels"]
#: Flops per pixel-light evaluation of a point light with attenuation, by part,
#: counted on kernels/lights.cl + brdf.cl (shade_obvious.cl for the naive
#: forms) as written. Comparisons, selects and float/double conversions are
#: not counted; a double operation counts as one flop, as a float one does.
FLOPS = {
    "direction": 18,        # L − P 3, d² 5, rsqrt 2 (as sqrt + div), l 3, n·l 5
    "falloff": 5,           # Horner 4, division 1
    "gates": 2,             # max(n·l, 0), n·l > 0
    "product": 12,          # L·(D·w_d + S·w_s): 3 channels × (2 products, 1 add, 1 product)
    "sum": 3,               # 3 additions (in double with SUM_FP64, or a naive float sum)
    "sum_compensated": 12,  # Neumaier: 3 channels × 4
    "blinn_delta": 22,      # l + v 3, |h|² 5, rsqrt 2, h 3, n − h 3, δ 6
    "phong_delta": 16,      # 2(n·l) 1, r − v 9, δ 6
    "blinn_cos": 11,        # l + v 3, |l + v|² 5, n·l + n·v 1, q² 1, ÷ 1 (SPEC_COS)
    "phong_cos": 8,         # l·v 5, 2(n·l) 1, ×(n·v) − l·v 2 (SPEC_COS)
    "blinn_naive": 18,      # l + v 3, |h|² 5, normalize 5, n·h 5 (shade_obvious.cl)
    "phong_naive": 12,      # 2(n·l)·n − l 7, r·v 5 (shade_obvious.cl)
    "exp_form": 31,         # log1p ≈ 15 and exp ≈ 15 (their polynomial steps), k·log 1; pow alike
    "int_base": 1,          # 1 − δ before the integer power
}


def flops_per_ple(plan, k: float) -> int:
    """Flops per pixel-light evaluation of ``plan`` (a point light with
    attenuation) for the exponent ``k``, itemised by :data:`FLOPS`.

    The specular power costs exp/log1p's 31, or with SPEC_INT_POW one squaring
    per bit of the exponent and one product per set bit
    (:func:`clphong.device.plan.int_pow_multiplies`): of k, or of k/2 where SPEC_COS
    raises Blinn's (n·h)².
    """
    d = plan.defines
    n = FLOPS["direction"] + FLOPS["falloff"] + FLOPS["gates"] + FLOPS["product"]
    # the obvious kernel sums naively in float whatever the plan says
    compensated = d.get("COMPENSATED_SUM") and plan.kernel != "obvious"
    n += FLOPS["sum_compensated"] if compensated else FLOPS["sum"]
    if not d.get("HAS_SPECULAR", 1):
        return n
    blinn = bool(d.get("MODEL_BLINN"))
    if plan.kernel == "obvious":
        return n + FLOPS["blinn_naive" if blinn else "phong_naive"] + FLOPS["exp_form"]
    if d.get("SPEC_COS"):
        return n + (FLOPS["blinn_cos"] + int_pow_multiplies(int(k) // 2) if blinn
                    else FLOPS["phong_cos"] + int_pow_multiplies(k))
    n += FLOPS["blinn_delta" if blinn else "phong_delta"]
    if d.get("SPEC_INT_POW"):
        return n + FLOPS["int_base"] + int_pow_multiplies(k)
    return n + FLOPS["exp_form"]

DEFAULT_SIZES = ((1920, 1080),)
DEFAULT_LIGHTS = (1, 16, 256, 4096, 65536)
#: The paths: name -> Renderer options.
PATHS = {
    "accurate": {},                                         # the default: double directions where fp64 exists
    "accurate-exp": {"int_pow": False},                     # the same, exp(k·log1p(−δ)) for a whole k too
    "float": {"fp64_directions": False},                    # float32 directions
    "float-naive-sum": {"fp64_directions": False, "compensated": False},
    "fast": {"path": "fast"},                               # float32 throughout, integer power in float
    "obvious": {"kernel": "obvious"},                       # one pixel per work-item, pow()
}


#: The bench's optional modules (the ``bench`` extra): the Pareto plot's and the peer's.
OPTIONAL_MODULES = ("matplotlib", "numba")


def missing_bench_modules() -> tuple[str, ...]:
    """Which of :data:`OPTIONAL_MODULES` are not installed (found without importing them)."""
    import importlib.util

    return tuple(m for m in OPTIONAL_MODULES if importlib.util.find_spec(m) is None)


def check_paths(paths) -> tuple:
    """``paths`` as a tuple if each is one of :data:`PATHS`; a bad one is a ValueError listing them."""
    bad = [p for p in paths if p not in PATHS]
    if bad:
        raise ValueError(f"unknown path {bad[0]!r}; choose from {', '.join(PATHS)}")
    return tuple(paths)


DEFAULT_BUDGETS = (0.0, 1e-4, 1e-3, 1e-2)
#: The numba peer's crop, pixel-light pairs (and the least crop of the OpenCL runs): ~45 ms
#: on 16 cores, well past its per-call overhead.
PEER_PAIRS = 1.5e8
#: Seconds of the device's measured rate (Runtime.pair_rate) that a brute-force crop holds
#: by default: on a GPU 1.5e8 pairs are a few work-groups a row at 65,536 lights, and time
#: the launch, not the shading.
CROP_SECONDS = 0.1
#: ...and at least this many device fills of pixels (Runtime.fill_groups work-groups of
#: frame.LOCAL_SIZE each).
CROP_FILLS = 4


#: The obvious kernel runs at a few MPLE/s: above this many lights even a 4-row
#: crop takes minutes a frame, so it is skipped (and says so).
OBVIOUS_MAX_LIGHTS = 4096


# --------------------------------------------------------------------------------- the run

@dataclass
class BenchConfig:
    sizes: tuple = DEFAULT_SIZES
    lights: tuple = DEFAULT_LIGHTS
    paths: tuple = tuple(PATHS)
    budgets: tuple = DEFAULT_BUDGETS
    repeats: int = 5
    warmup: int = 1
    crop_pairs: float | None = None   # brute force: crop to about this many pixel-light pairs
                                      # (None: CROP_SECONDS of the device's measured rate, at
                                      # least PEER_PAIRS)
    error_pairs: float = 3e7      # reference: sample about this many pixel-light pairs
    numpy_pairs: float = 6.7e7    # numpy: about this many pixel-light pairs (at least 1/8 of the frame)
    numba: bool = True            # the numba peer, where numba is installed
    small_lights: tuple = (65536,)
    device: str | None = None
    log: object = None
    env_errors: tuple = ()                          # environment rows' targets (the CLI: ENV_ERRORS)
    env_sizes: tuple = ((256, 128), (1024, 512), (4096, 2048))   # the sky maps' width x height
    env_pixels: int = 2000                          # pixels of the exact texel sum
    env_probes: tuple = ("tables", "frame", "all")  # each row's path (--env-probes): tables, or lights estimated where
    tree_cases: tuple = ()                          # light-tree rows: (scene, N, ε) (the CLI: TREE_CASES)
    lanes: tuple = (None,)                          # widths of the wide scene's brute-force rows (None: the device's)

    @classmethod
    def quick(cls, **kw):
        base = dict(sizes=((480, 270),), lights=(1, 16, 256, 4096), budgets=(0.0, 1e-3),
                    repeats=3, crop_pairs=3e7, error_pairs=5e6, numpy_pairs=4e6,
                    small_lights=(4096,), env_errors=(1e-2,), env_sizes=((256, 128),),
                    env_pixels=500, tree_cases=(("clusters", 1024, 3e-2),))
        base.update(kw)
        return cls(**base)


def numpy_crop(width: int, height: int, n: int, pairs: float) -> tuple[int, int]:
    """The numpy baseline's (rows, lights): at least 1/8 of the frame's rows (per-call
    overhead then costs little: on 10 rows it dominated, 5× slower per pair), and
    about ``pairs`` pixel-light pairs, using the first lights only where all of
    them would exceed that (numpy's cost per pair does not depend on N: it loops
    over the lights)."""
    rows = max(-(-height // 8), min(height, int(pairs // max(width * n, 1))))
    lights = max(1, min(n, int(pairs // max(width * rows, 1))))
    return rows, lights


def _first_lights(scene, n: int):
    """``scene`` with its ambient lights and its first ``n`` point lights only."""
    import dataclasses

    amb = scene.lights_of("ambient")
    return dataclasses.replace(scene, lights=tuple(amb) + tuple(scene.lights_of("point")[:n]))


def _case_slot(cfg, run, scene, kind, n, full, least_pixels, log) -> dict | None:
    """One timed run of a case, set up: its crop, renderer and frame (None: skipped)."""
    path, budget, width = run
    H, W = full.shape
    opts = dict(PATHS[path])
    if width is not None and path != "obvious":
        opts["lanes"] = width
    brute = budget is None
    # crop where (nearly) every pair is evaluated: brute force, the wide scene
    # (nothing to cull), and ε = 0; the small scene's culled runs use the full frame
    cropped = brute or kind == "wide" or budget == 0
    # culled runs keep at least one row of tiles
    least = 4 if brute else 16
    rows = (max(_crop_rows(W, H, n, cfg.crop_pairs, least), -(-least_pixels // W))
            if cropped else H)
    rows = min(rows, H)
    if path == "obvious":
        if n > OBVIOUS_MAX_LIGHTS:
            log(f"obvious         {kind:5s} N={n:<6d} skipped (> {OBVIOUS_MAX_LIGHTS} lights)")
            return None
        rows = _crop_rows(W, H, n, cfg.crop_pairs / 8, least)
    gb = full if rows == H else bench_gbuffer(W, H, rows)
    r = Renderer(scene, device=cfg.device, max_error=budget, **opts)
    frame = prepare_frame(gb, lanes=max(r.lanes, 1))
    return {"path": path, "budget": budget, "rows": rows, "gb": gb, "r": r,
            "lanes_given": width is not None, "frame": frame, "times": [], "cull": []}


def _run_entry(slot, cfg, scene, kind, n, size, shaded_full, oracle_cache, np_rate, numba_rate,
               peak, log) -> dict:
    """One timed run's report row (and its log line): rate, ratios, error, culling."""
    W, H = size
    path, budget, rows, gb, r, frame = (slot[k] for k in ("path", "budget", "rows", "gb", "r", "frame"))
    brute = budget is None
    times, result = slot["times"], slot["result"]
    med, cull_s = statistics.median(times), statistics.median(slot["cull"])
    key = rows
    if key not in oracle_cache:
        m = max(500, int(cfg.error_pairs // max(n, 1)))
        oracle_cache[key] = make_oracle(scene, gb, frame, m)
    err = oracle_cache[key].errors(result.image)
    # shaded pixel-light evaluations: background pixels cost no light
    # (kernel, culling and numpy alike), so they are not counted
    shaded = shaded_pixels(gb)
    rate = shaded * n / med
    flops = flops_per_ple(result.plan, scene.material.exponent)
    entry = {
        "scene": kind, "size": [W, H], "lights": n, "path": path,
        "lanes": r.lanes, "lanes_given": slot["lanes_given"],
        "max_error": budget, "crop_rows": rows, "extrapolated": rows != H,
        "shaded_pixels": shaded_full,
        "ms_per_frame": med * 1e3 * shaded_full / shaded,
        "times_ms": [t * 1e3 for t in times],
        "cull_ms": cull_s * 1e3 * shaded_full / shaded,
        "ple_per_s": rate, "gple_per_s": rate / 1e9,
        "numpy_ratio": rate / np_rate if np_rate else None,
        "numba_ratio": rate / numba_rate if numba_rate and brute else None,
        # culled runs evaluate fewer pairs than S·N: no peak fraction
        "flops_per_ple": flops,
        "peak_fraction": rate * flops / (peak * 1e9) if brute else None,
        "kept_fraction": (slot["last_cull"].kept_fraction if slot.get("last_cull")
                          else None),
        # timed frames shaded brute force without lists, culling having lost on
        # an earlier frame (renderer.CULL_RETRY)
        "lists_skipped": slot.get("lists_skipped", 0),
        "error": err,
    }
    label = path if brute else f"cull ε={budget:g}"
    if slot["lanes_given"]:
        label += f"@{r.lanes}"
    log(f"{label:15s} {kind:5s} N={n:<6d} {rate / 1e9:7.3f} GPLE/s "
        f"{entry['ms_per_frame']:10.1f} ms/frame"
        + (f" ({W}x{rows} crop)" if rows != H else "")
        + (f" ×{entry['numpy_ratio']:.0f} numpy" if np_rate else "")
        + (f" ×{entry['numba_ratio']:.2f} numba" if entry["numba_ratio"] else "")
        + f"  max rel {err['max_rel']:.2e} mean {err['mean_rel']:.2e}"
        f" abs {err['max_abs']:.2e} band {err['band_pixels']}"
        + (f" kept {entry['kept_fraction']:.4f}" if entry["kept_fraction"] is not None else ""))
    return entry


def _report_header(cfg: BenchConfig, rt, peak: float, shapes: dict, numba_fma, use_numba: bool) -> dict:
    """The report's machine and settings, and its empty row lists."""
    return {
        "clphong_bench": 1,
        "machine": {"device": rt.name, "llvm_target": rt.llvm_target, "lanes": rt.lanes,
                    "host": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count(), "fp32_peak_gflops": peak,
                    "fp32_peak": {
                        "gflops": peak,
                        "method": "kernels/peak.cl: independent FMA chains a = a*b + c on "
                                  "float lanes, 64x64 work-items a core, 1024 steps, median of "
                                  "5 launches by profiling events; best of the (lanes x chains) "
                                  "shapes",
                        "shapes_gflops": {k: v for k, v in shapes.items() if k != "best"},
                        "numba_fma_gflops": numba_fma,
                        "numba_fma_method": None if numba_fma is None else numba_peer.FMA_METHOD,
                    }},
        "settings": {"sizes": [list(s) for s in cfg.sizes], "lights": list(cfg.lights),
                     "paths": list(cfg.paths), "budgets": list(cfg.budgets),
                     "repeats": cfg.repeats, "warmup": cfg.warmup, "crop_pairs": cfg.crop_pairs,
                     "error_pairs": cfg.error_pairs, "numpy_pairs": cfg.numpy_pairs,
                     "numba": use_numba,
                     "small_lights": list(cfg.small_lights), "seed": SEED,
                     "reference_white": 1.0, "env_errors": list(cfg.env_errors),
                     "env_sizes": [list(e) for e in cfg.env_sizes], "env_pixels": cfg.env_pixels,
                     "env_probes": list(cfg.env_probes),
                     "tree_cases": [list(c) for c in cfg.tree_cases]},
        "numpy": [],
        "numba": [],
        "runs": [],
        "environment": [],
        "tree": [],
    }


def run_bench(cfg: BenchConfig) -> dict:
    """Run the benchmark; return the report (a JSON-serialisable dict)."""
    log = cfg.log or (lambda msg: None)
    rt = get_runtime(cfg.device)
    peer_pairs = cfg.crop_pairs or PEER_PAIRS
    if cfg.crop_pairs is None:
        cfg = dataclasses.replace(cfg, crop_pairs=max(PEER_PAIRS, CROP_SECONDS * (rt.pair_rate or 0.0)))
    # a crop holds at least CROP_FILLS times the work-items that fill the device (an H200's
    # 103-row crop at 65,536 lights ran at 136 GPLE/s, the whole frame at 159)
    least_pixels = CROP_FILLS * rt.fill_groups * LOCAL_SIZE * max(rt.lanes, 1)
    shapes: dict = {}
    peak = measure_peak_gflops(rt, detail=shapes)
    use_numba = cfg.numba and numba_peer.available()
    numba_fma = numba_peer.fma_peak_gflops() if use_numba else None
    best = shapes.get("best", {})
    log(f"device: {rt.name}; FP32 peak {peak:.1f} GFLOP/s (kernels/peak.cl, best of "
        f"{len(shapes) - 1} shapes: {best.get('lanes')} lanes x {best.get('chains')} chains)"
        + (f"; numba FMA loop {numba_fma:.1f} GFLOP/s ({numba_peer.fma_vector_bits()}-bit vectors)"
           if numba_fma else ""))
    if not use_numba and cfg.numba:
        log("numba peer: skipped (numba is not installed: pip install 'clphong[bench]')")
    report = _report_header(cfg, rt, peak, shapes, numba_fma, use_numba)
    for (W, H) in cfg.sizes:
        full = bench_gbuffer(W, H)
        shaded_full = shaded_pixels(full)
        cases = [("wide", n) for n in cfg.lights] + [("small", n) for n in cfg.small_lights]
        for kind, n in cases:
            scene = bench_scene(kind, n)
            oracle_cache: dict = {}
            runs = [(p, None, w) for p in cfg.paths for w in cfg.lanes] if kind == "wide" else []
            runs += [("accurate", b, None) for b in cfg.budgets]
            # Set every run of this case up first, then time them round-robin (one
            # frame of each per round, numpy included), so that the other tenants'
            # load falls on every path alike and the ratios hold.
            slots = [slot for run in runs
                     if (slot := _case_slot(cfg, run, scene, kind, n, full, least_pixels, log))]
            crop = peer = None
            if kind == "wide":      # numpy float32, on a crop (wide scene only: same shading)
                np_rows, np_lights = numpy_crop(W, H, n, cfg.numpy_pairs)
                crop, np_times = bench_gbuffer(W, H, np_rows), []
                np_scene = bench_scene(kind, n) if np_lights == n else _first_lights(scene, np_lights)
                if use_numba:       # the numba peer on the accurate path's crop: identical inputs
                    peer_rows = _crop_rows(W, H, n, peer_pairs)
                    peer_gb = full if peer_rows == H else bench_gbuffer(W, H, peer_rows)
                    peer, peer_times = numba_peer.NumbaPeer(scene, peer_gb), []
            for round_ in range(cfg.warmup + cfg.repeats):
                _time_slots(slots, keep=round_ >= cfg.warmup)
                if peer is not None:
                    t0 = time.perf_counter()
                    peer.shade_flat()
                    if round_ >= cfg.warmup:
                        peer_times.append(time.perf_counter() - t0)
                if crop is not None and round_ >= cfg.warmup and round_ - cfg.warmup < 3:
                    t0 = time.perf_counter()
                    numpy_shade(np_scene, crop)
                    np_times.append(time.perf_counter() - t0)
            np_rate = numba_rate = None
            if crop is not None:
                t = statistics.median(np_times)
                np_rate = shaded_pixels(crop) * np_lights / t
                report["numpy"].append({"scene": kind, "lights": n, "crop_rows": np_rows,
                                        "timed_lights": np_lights, "seconds": t,
                                        "ple_per_s": np_rate})
                log(f"numpy float32  {kind:5s} N={n:<6d} {np_rate / 1e6:8.2f} MPLE/s "
                    f"({W}x{np_rows}, {np_lights} lights)")
            if peer is not None:
                t = statistics.median(peer_times)
                numba_rate = shaded_pixels(peer_gb) * n / t
                key = peer_rows
                if key not in oracle_cache:
                    frame = prepare_frame(peer_gb, lanes=1)
                    m = max(500, int(cfg.error_pairs // max(n, 1)))
                    oracle_cache[key] = make_oracle(scene, peer_gb, frame, m)
                err = oracle_cache[key].errors(peer.shade())
                report["numba"].append({
                    "scene": kind, "size": [W, H], "lights": n, "crop_rows": peer_rows,
                    "extrapolated": peer_rows != H, "times_ms": [x * 1e3 for x in peer_times],
                    "ms_per_frame": t * 1e3 * shaded_full / shaded_pixels(peer_gb),
                    "ple_per_s": numba_rate, "gple_per_s": numba_rate / 1e9,
                    "numpy_ratio": numba_rate / np_rate, "error": err})
                log(f"numba peer     {kind:5s} N={n:<6d} {numba_rate / 1e9:7.3f} GPLE/s "
                    f"({W}x{peer_rows})  max rel {err['max_rel']:.2e} mean {err['mean_rel']:.2e}")
            for slot in slots:
                report["runs"].append(_run_entry(slot, cfg, scene, kind, n, (W, H), shaded_full,
                                                 oracle_cache, np_rate, numba_rate, peak, log))
        if cfg.env_errors:
            for env_size in cfg.env_sizes:
                report["environment"] += run_environment(cfg, full, report["runs"], log, env_size)
        if cfg.tree_cases:
            report["tree"] += run_tree(cfg, full, log)
    report["summary"] = summarise(report)
    return report


def summarise(report: dict) -> dict:
    """The issue's targets, as measured (None where the run did not include them)."""
    runs = report["runs"]

    def find(**kw):
        for r in runs:
            if r.get("lanes_given"):
                continue            # the targets are the default width's
            if all(r.get(k) == v for k, v in kw.items()):
                return r
        return None

    out = {}
    acc256 = find(scene="wide", lights=256, path="accurate", max_error=None)
    if acc256:
        out["accurate_256_gple_per_s"] = acc256["gple_per_s"]
        out["accurate_256_numpy_ratio"] = acc256["numpy_ratio"]
        out["target_1gple_met"] = acc256["gple_per_s"] >= 1.0
        out["target_60x_numpy_met"] = (acc256["numpy_ratio"] or 0) >= 60
    # issue 14: the kernels against the numba peer, side by side (1080p wide scene)
    for n in (256, 4096):
        for path, need in (("accurate", 1.0), ("fast", 1.3)):
            r = find(scene="wide", lights=n, path=path, max_error=None)
            if r and r.get("numba_ratio"):
                out[f"{path}_{n}_numba_ratio"] = r["numba_ratio"]
                out[f"target_{path}_{n}_numba_met"] = r["numba_ratio"] >= need
    small = [r for r in runs if r["scene"] == "small" and r["max_error"] == 1e-3]
    if small and acc256:
        s = max(small, key=lambda r: r["lights"])
        out["cull_small_lights"] = s["lights"]
        out["cull_vs_256_brute_time_ratio"] = s["ms_per_frame"] / acc256["ms_per_frame"]
        out["cull_max_abs_error"] = s["error"]["max_abs"]
        out["target_3x_met"] = out["cull_vs_256_brute_time_ratio"] <= 3.0
    out.update(summarise_environment(report.get("environment", [])))
    return out


def summary_lines(summary: dict) -> list[str]:
    """The issue-4 targets of :func:`summarise`, as sentences a user can read."""
    def met(ok):
        return "met" if ok else "not met"

    lines = []
    if "accurate_256_gple_per_s" in summary:
        g = summary["accurate_256_gple_per_s"]
        lines.append(f"issue-4 targets: 1 GPLE/s at 256 lights (accurate path): "
                     f"{met(summary['target_1gple_met'])} ({g:.3g} GPLE/s)")
        ratio = summary.get("accurate_256_numpy_ratio")
        if ratio is None:
            lines.append("issue-4 targets: 60x numpy float32 at 256 lights: n/a (numpy not measured)")
        else:
            lines.append(f"issue-4 targets: 60x numpy float32 at 256 lights: "
                         f"{met(summary['target_60x_numpy_met'])} ({ratio:.3g}x)")
    else:
        lines.append("issue-4 targets: not measured (the run has no 256-light wide-scene "
                     "accurate brute-force case)")
    for n in (256, 4096):
        for path, need in (("accurate", 1.0), ("fast", 1.3)):
            key = f"{path}_{n}_numba_ratio"
            if key in summary:
                lines.append(f"issue-14 targets: {path} at {n} lights >= {need:g}x the numba peer: "
                             f"{met(summary[f'target_{path}_{n}_numba_met'])} ({summary[key]:.3g}x)")
    if "cull_vs_256_brute_time_ratio" in summary:
        lines.append(f"issue-4 targets: culling at eps=1e-3, small scene N={summary['cull_small_lights']}, "
                     f"within 3x the time of 256 lights brute force: {met(summary['target_3x_met'])} "
                     f"({summary['cull_vs_256_brute_time_ratio']:.3g}x; max abs error "
                     f"{summary['cull_max_abs_error']:.2e})")
    lines += environment_summary_lines(summary)
    return lines


# ---------------------------------------------------------------------------------- output

def save_report(report: dict, json_path=None, plot_path=None) -> None:
    """Write the JSON report and the Pareto PNG, each to a temporary name then renamed
    (:func:`clphong.io.atomic.atomic_path`: a failed write leaves nothing behind)."""
    if json_path:
        with atomic_path(json_path) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=1))
    if plot_path:
        plot_pareto(report, plot_path)


def plot_pareto(report: dict, path) -> None:
    """Throughput (GPLE/s, brute-force equivalent) against max relative error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env = report.get("environment") or []
    tree = report.get("tree") or []
    tree_scenes = list(dict.fromkeys(r["scene"] for r in tree))
    panels = 2 + bool(env) + len(tree_scenes)
    fig, axes = plt.subplots(1, panels, figsize=(6 * panels, 5), squeeze=False)
    axes = axes[0]
    ax = axes[0]
    for r in report["runs"]:
        if r["max_error"] is not None:
            continue
        x = max(r["error"]["max_rel"], 1e-9)
        ax.scatter(x, r["gple_per_s"], s=20 + 6 * math.log2(r["lights"] + 1))
        ax.annotate(f"{r['path']} N={r['lights']}", (x, r["gple_per_s"]), fontsize=7)
    for n in report["numpy"]:
        ax.axhline(n["ple_per_s"] / 1e9, color="grey", lw=0.5, ls=":")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("max relative error vs float64 (terminator band excluded)")
    ax.set_ylabel("GPLE/s")
    ax.set_title("paths (brute force); dotted: numpy float32")
    ax = axes[1]
    for r in report["runs"]:
        if r["max_error"] is None:
            continue
        x = max(r["error"]["max_abs"], 1e-12)
        ax.scatter(x, r["gple_per_s"], marker="s" if r["scene"] == "small" else "o")
        ax.annotate(f"{r['scene']} N={r['lights']} ε={r['max_error']:g}", (x, r["gple_per_s"]),
                    fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("max absolute error vs float64 (radiance; white = 1)")
    ax.set_ylabel("GPLE/s (brute-force equivalent)")
    ax.set_title("tiled culling, budget ε")
    if env:
        _plot_environment(axes[2], env)
    for ax, scene in zip(axes[2 + bool(env):], tree_scenes):
        _plot_tree(ax, [r for r in tree if r["scene"] == scene], scene)
    fig.suptitle(f"clphong bench: {report['machine']['device']}", fontsize=9)
    fig.tight_layout()

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        plt.close(fig)


def _plot_tree(ax, rows, scene: str) -> None:
    """One scene's light-tree rows: ms per frame against the max error relative to each
    pixel's own value, for brute force, culling and the tree (issue 27); hollow markers
    for a relative budget, filled for an absolute one."""
    style = {"brute": ("k", "x"), "culling": ("tab:blue", "o"), "tree": ("tab:orange", "s")}
    for r in rows:
        for label, (color, marker) in style.items():
            x = r[label]
            err = max(x.get("max_rel_error", 0.0), 1e-9)
            hollow = r.get("relative") and label != "brute"
            ax.scatter(err, x["ms_per_frame"], color=color, marker=marker,
                       facecolors="none" if hollow else None,
                       label=label if r is rows[0] else None)
            if label != "brute":
                ax.annotate(f"N={r['lights']} ε={r['max_error']:g}{'r' if r.get('relative') else ''}",
                            (err, x["ms_per_frame"]), fontsize=6)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("max error relative to each pixel's own value (float64)")
    ax.set_ylabel("ms per frame")
    ax.set_title(f"light tree, {scene}: brute force, culling, tree (hollow: --relative)")
    ax.legend(fontsize=7)


#: The environment panel's marker per path (bench rows' ``env_probes``).
ENV_MARKERS = {"tables": "s", "frame": "o", "all": "^"}


def _plot_environment(ax, rows) -> None:
    """The environment rows: time against the exact texel sum's error, one line per map and
    path (squares: tables; circles: lights on the frame's probes; triangles: every normal)."""
    series = dict.fromkeys((tuple(r["map"]), r.get("env_probes", "all")) for r in rows)
    colours = {size: f"C{k}" for k, size in enumerate(dict.fromkeys(s for s, _ in series))}
    for size, path in series:
        mine = sorted((r for r in rows if tuple(r["map"]) == size
                       and r.get("env_probes", "all") == path), key=lambda r: r["env_error"])
        xs = [max(r["error"]["max_rel"], 1e-9) for r in mine]
        ys = [r["time_ratio_256_point"] for r in mine]
        ax.plot(xs, ys, marker=ENV_MARKERS.get(path, "o"), color=colours[size],
                label=f"{size[0]}x{size[1]} {path}")
        for r, x, y in zip(mine, xs, ys):
            what = "sun lights" if path == "tables" else "lights"
            ax.annotate(f"ε={r['env_error']:g}, {r['lights']} {what}", (x, y), fontsize=6)
    ax.axhline(1.0, color="grey", lw=0.5, ls=":")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("max relative error vs the exact float64 texel sum")
    ax.set_ylabel("frame time / 256 point lights' (same run)")
    ax.set_title("environment maps; dotted: 256 point lights")
    ax.legend(fontsize=7)


def table(report: dict) -> str:
    """The report as a plain-text table."""
    lines = [f"{'scene':6s} {'N':>6s} {'path':16s} {'GPLE/s':>8s} {'ms/frame':>10s} {'×numpy':>7s} "
             f"{'×numba':>7s} {'peak':>6s} {'max rel':>9s} {'mean rel':>9s} {'max abs':>9s} "
             f"{'band':>5s} {'kept':>7s}"]
    for r in report.get("numba", []):
        e = r["error"]
        lines.append(
            f"{r['scene']:6s} {r['lights']:6d} {'numba peer':16s} {r['gple_per_s']:8.3f} "
            f"{r['ms_per_frame']:10.1f}{'*' if r['extrapolated'] else ' '}"
            f"{r['numpy_ratio']:7.1f} {1.0:7.2f} {'':6s} {e['max_rel']:9.2e} {e['mean_rel']:9.2e} "
            f"{e['max_abs']:9.2e} {e['band_pixels']:5d}")
    for r in report["runs"]:
        label = r["path"] if r["max_error"] is None else f"cull ε={r['max_error']:g}"
        if r.get("lanes_given"):
            label += f"@{r['lanes']}"
        e = r["error"]
        lines.append(
            f"{r['scene']:6s} {r['lights']:6d} {label:16s} {r['gple_per_s']:8.3f} "
            f"{r['ms_per_frame']:10.1f}{'*' if r['extrapolated'] else ' '}"
            + (f"{r['numpy_ratio']:7.1f} " if r["numpy_ratio"] else f"{'n/a':>7s} ")
            + (f"{r['numba_ratio']:7.2f} " if r.get("numba_ratio") else f"{'n/a':>7s} ")
            + (f"{r['peak_fraction']:6.1%} " if r["peak_fraction"] is not None else f"{'':6s} ")
            + f"{e['max_rel']:9.2e} {e['mean_rel']:9.2e} {e['max_abs']:9.2e} {e['band_pixels']:5d} "
            + (f"{r['kept_fraction']:7.4f}" if r["kept_fraction"] is not None else f"{'':7s}"))
    lines.append("* brute force timed on a crop of the top rows; ms/frame scaled to the full frame")
    lines += environment_table(report.get("environment", []))
    lines += tree_table(report.get("tree", []))
    return "\n".join(lines)


# ==================================================================== environment light (issue 16)
# The environment rows: the sample sky as directional lights (clphong.model.environment)
# on the bench G-buffer, timed against 256 point lights brute force and held to the
# exact texel sum (clphong.reference.environment). Everything of the rows is here.
