"""Time light-group and AOV layers against the beauty alone, in one run, taking turns.

Not a test: ``python -m clphong.tools.layer_bench [--size WxH] [--lights N] [--runs R]``
prints, per variant, the median kernel time and ``Renderer.render`` time and the ratio
of kernel times to the beauty alone. The frame is a wavy surface seen from above (a
G-buffer made in memory, every pixel covered); the N point lights are 1/d² lights
given by power, spread over it; the groups put light k in group k mod 3.
"""

from __future__ import annotations

import argparse
import statistics
import sys

import numpy as np

from ..device.renderer import Renderer
from ..io.gbuffer import GBuffer
from ..model.scene import parse_scene

#: The variants timed: (name, number of groups, AOVs).
VARIANTS = (("beauty", 0, ()), ("3 groups", 3, ()), ("diffuse+specular", 0, ("diffuse", "specular")),
            ("3 groups+diffuse+specular", 3, ("diffuse", "specular")))


def surface(h: int, w: int, seed: int = 0) -> GBuffer:
    """A wavy surface z = 0.2·sin·cos over 0.1-unit pixels, seen from above."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) * 0.1
    z = 0.2 * np.sin(xs * 1.7) * np.cos(ys * 1.3)
    n = np.stack([-0.34 * np.cos(xs * 1.7) * np.cos(ys * 1.3),
                  0.26 * np.sin(xs * 1.7) * np.sin(ys * 1.3), np.ones_like(z)], -1)
    rng = np.random.default_rng(seed)
    return GBuffer(position=np.stack([xs, ys, z], -1).astype(np.float32), normal=n.astype(np.float32),
                   albedo=rng.uniform(0.1, 1.0, (h, w, 3)).astype(np.float32))


def scene(h: int, w: int, n_lights: int, groups: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    lights = []
    for k in range(n_lights):
        lt = {"type": "point", "power": float(rng.uniform(50, 500)),
              "position": [float(rng.uniform(0, w * 0.1)), float(rng.uniform(0, h * 0.1)), 2.0]}
        if groups:
            lt["group"] = f"g{k % groups}"
        lights.append(lt)
    return parse_scene({"camera": {"type": "perspective", "position": [w * 0.05, h * 0.05, 100.0]},
                        "material": {"model": "blinn-phong", "k_a": 0.0, "k_d": 0.7, "k_s": 0.3,
                                     "h": 32.0},
                        "light": lights}, source="layer_bench")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m clphong.tools.layer_bench", description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="1920x1080", metavar="WxH")
    ap.add_argument("--lights", type=int, default=64)
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.size.lower().split("x"))
    gb = surface(h, w)
    renderers = {name: Renderer(scene(h, w, args.lights, g), aovs=aovs) for name, g, aovs in VARIANTS}
    times = {name: [] for name in renderers}
    for r in renderers.values():
        r.render(gb)                                     # compile, warm up
    for _ in range(args.runs):
        for name, r in renderers.items():                # taking turns: the same load for each
            s = r.render(gb).stats
            times[name].append((s.kernel_seconds, s.total_seconds))
    base = statistics.median(t[0] for t in times["beauty"])
    print(f"{w}x{h}, {args.lights} point lights, median of {args.runs} (taking turns):")
    for name, ts in times.items():
        k = statistics.median(t[0] for t in ts)
        total = statistics.median(t[1] for t in ts)
        print(f"  {name:26s} kernel {k * 1e3:8.1f} ms  ({k / base:.3f}x beauty)   render() {total * 1e3:8.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
