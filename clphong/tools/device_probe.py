"""Whole-frame kernel rates on one device, by light loop shape and light count (docs/bench.md,
"GPUs"): ``python -m clphong.tools.device_probe [--device DEV] [--size WxH] [--lights N,N]
[--tiles T,T] [--json OUT]``.

Each row is the wide bench scene on the whole bench G-buffer (no crop), shaded with the
light records read by every work-item (tile 0) or staged through local memory T at a time
(the plan's LIGHT_TILE): the median kernel time of ``--repeats`` frames after one untimed
frame, as GPLE/s over the shaded pixels. Then the culling rows: the lists' time beside the
shading, and the share of lights they keep. Not a timed test: the figures are the
device's.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys

from ..device.renderer import Renderer, prepare_frame
from ..device.selection import get_runtime
from .bench_scenes import bench_gbuffer, bench_scene, shaded_pixels

#: (scene, lights, budget) of the culling rows
CULL_CASES = (("wide", 4096, 1e-3), ("small", 65536, 1e-3), ("clusters", 65536, 1e-3))


def _median_frame(r: Renderer, frame, repeats: int):
    r.shade(frame)                                   # untimed: builds, first-use costs
    results = [r.shade(frame) for _ in range(repeats)]
    return statistics.median(x.stats.kernel_seconds for x in results), results[-1]


def probe(device=None, size=(1920, 1080), lights=(4096, 65536), tiles=(0, 64),
          paths=("accurate", "fast"), cull=CULL_CASES, repeats: int = 3, log=print) -> dict:
    """The rows described in the module docstring, as a JSON-serialisable dict."""
    rt = get_runtime(device)
    gb = bench_gbuffer(*size)
    shaded = shaded_pixels(gb)
    out = {"device": rt.name, "lanes": rt.lanes, "fp64_ratio": rt.fp64_ratio,
           "pair_rate": rt.pair_rate, "size": list(size), "loops": [], "culling": []}
    log(f"{rt.name}: {rt.lanes} lane(s), double at {rt.fp64_ratio or 0:.2g} of float, "
        f"calibration frame {(rt.pair_rate or 0) / 1e9:.3g} GPLE/s")
    for n in lights:
        scene = bench_scene("wide", n)
        for path in paths:
            for tile in tiles:
                r = Renderer(scene, device=device, path=path, light_tile=tile)
                seconds, result = _median_frame(r, prepare_frame(gb, lanes=r.lanes), repeats)
                row = {"lights": n, "path": path, "tile": result.plan.defines.get("LIGHT_TILE", 0),
                       "kernel_s": seconds, "gple_per_s": shaded * n / seconds / 1e9}
                out["loops"].append(row)
                log(f"wide N={n:<6d} {path:8s} tile {row['tile']:<4d} {row['gple_per_s']:8.2f} GPLE/s")
    for kind, n, eps in cull:
        r = Renderer(bench_scene(kind, n), device=device, max_error=eps)
        frame = prepare_frame(gb, lanes=r.lanes)
        r.shade(frame)                               # the lists of the first frame, untimed
        r._cull_rest = 0                             # time the lists, not the skip after a loss
        result = r.shade(frame)
        c = result.cull
        row = {"scene": kind, "lights": n, "max_error": eps,
               "kernel_s": result.stats.kernel_seconds,
               "lists_s": None if c is None else c.seconds + c.tree_seconds,
               "kept_fraction": None if c is None else c.kept_fraction,
               "brute": None if c is None else c.brute}
        out["culling"].append(row)
        lists = "-" if c is None else f"{row['lists_s'] * 1e3:.1f} ms"
        kept = "-" if c is None else f"{c.kept_fraction:.4f}"
        lost = " (brute force: the lists lost)" if c is not None and c.brute else ""
        log(f"cull {kind:8s} N={n:<6d} eps {eps:g}: shading {row['kernel_s'] * 1e3:.1f} ms, "
            f"lists {lists}, kept {kept}{lost}")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m clphong.tools.device_probe", description=__doc__.split("\n")[0])
    p.add_argument("--device")
    p.add_argument("--size", default="1920x1080")
    p.add_argument("--lights", default="4096,65536")
    p.add_argument("--tiles", default="0,64")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--no-culling", action="store_true")
    p.add_argument("--json")
    a = p.parse_args(argv)
    w, h = (int(x) for x in a.size.lower().split("x"))
    report = probe(a.device, (w, h), tuple(int(x) for x in a.lights.split(",")),
                   tuple(int(x) for x in a.tiles.split(",")), repeats=a.repeats,
                   cull=() if a.no_culling else CULL_CASES)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
