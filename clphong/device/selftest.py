"""The self-test: a small fixed G-buffer shaded on a device and held to the float64 reference.

Before a device's first frame at a lane width, :func:`check` shades a 9×7 frame
(background pixels, a width that is not a multiple of any lane count) with two
scenes, each on the accurate and the fast path:

* ``phong-hard``: Phong at h = 10⁴ with a directional light 10⁻³ rad above the
  horizon of a tilted strip, a point light 10⁻³ from a pixel (d → 0) and ambient;
* ``blinn-many``: Blinn-Phong at h = 32 with 37 point lights (not a multiple of
  any width) under quadratic falloff.

A variant passes when every pixel and channel is finite and within the error
model's bound (:func:`clphong.reference.shading.error_bound`, the same check as
the hard cases). It runs in a child process (``python -m clphong.device.selftest``),
so a compiler abort or a crash in a kernel becomes a verdict, not the end of the
caller; the runtime caches the verdict (:mod:`clphong.device.runtime`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings

import numpy as np

from ..core.errors import ClphongError, InputWarning
from ..io.gbuffer import GBuffer
from ..model.scene import parse_scene
from ..reference import shading as reference
from .peak import measure_builtin_rsqrt_ulp, measure_fp64_ratio, measure_native_rsqrt_ulp
from .runtime import NATIVE_RSQRT_KINDS
from .renderer import Renderer, prepare_frame
from .selection import get_runtime

#: The paths checked at every width: the default and the fast one.
PATHS = ("accurate", "fast")
#: Environment variable of the test-only fault (tests/device/test_selftest.py): the
#: last lane of each work-item scaled by 1 + this value (kernels/shade.cl SELFTEST_FAULT).
FAULT_ENV = "CLPHONG_SELFTEST_FAULT"

_H, _W = 7, 9


def _gbuffer() -> GBuffer:
    """The fixed frame: a strip tilted about y, its normals rising from 89.9° off the
    grazing light, a column of background pixels, and one pixel under a close light."""
    ys, xs = np.mgrid[0:_H, 0:_W].astype(np.float64)
    P = np.stack([(xs - 4) * 0.25, (ys - 3) * 0.25, 0.05 * xs], -1)
    tilt = np.linspace(-0.2, 1.2, _W)[None, :] + 0.0 * ys
    N = np.stack([np.sin(tilt), 0.1 * np.sin(ys), np.cos(tilt)], -1)
    C = np.stack([0.2 + 0.08 * xs, 0.9 - 0.1 * ys, 0.5 + 0.0 * xs], -1)
    coverage = np.ones((_H, _W))
    coverage[:, 2] = 0.0
    coverage[5, 6] = 0.0
    f = np.float32
    return GBuffer(position=np.ascontiguousarray(P, f), normal=np.ascontiguousarray(N, f),
                   albedo=np.ascontiguousarray(C, f), coverage=coverage.astype(f), maps={})


def _scenes() -> dict:
    P00 = [(0 - 4) * 0.25, (3 - 3) * 0.25, 0.0]
    graze = 1e-3                                     # radians above the horizon of z = 0
    phong = {
        "camera": {"type": "perspective", "position": [0.0, 0.5, 4.0]},
        "material": {"model": "phong", "k_a": 0.1, "k_d": 0.6, "k_s": 0.3, "h": 1e4},
        "light": [
            {"type": "directional", "direction": [-float(np.cos(graze)), 0.0, -float(np.sin(graze))],
             "intensity": 2.0},
            {"type": "point", "position": [P00[0], P00[1], P00[2] + 1e-3], "intensity": 1e-6},
            {"type": "point", "position": [0.5, 2.0, 3.0], "intensity": 9.0,
             "attenuation": [1.0, 0.0, 1.0]},
            {"type": "ambient", "intensity": 0.3},
        ],
    }
    rng = np.random.default_rng(31)
    blinn = {
        "camera": {"type": "perspective", "position": [0.3, -0.4, 5.0]},
        "material": {"model": "blinn-phong", "k_a": 0.0, "k_d": 0.6, "k_s": 0.4, "h": 32.0},
        "light": [{"type": "point", "position": [float(x), float(y), float(z)],
                   "color": [float(r), float(g), float(b)], "intensity": 3.0,
                   "attenuation": [1.0, 0.5, 0.25]}
                  for x, y, z, r, g, b in np.column_stack([
                      rng.uniform(-3, 3, (37, 2)), rng.uniform(0.2, 3.0, 37),
                      rng.uniform(0.1, 1.0, (37, 3))])],
    }
    return {"phong-hard": parse_scene(phong, "<self-test phong-hard>"),
            "blinn-many": parse_scene(blinn, "<self-test blinn-many>")}


def _rsqrt_measure(probe, rt, lanes: int) -> float | None:
    """``probe``'s ulp at ``lanes`` on the platforms that measure their 1/√x
    (NATIVE_RSQRT_KINDS); None elsewhere, or where the probe fails: the plan then does
    not take that form, and the device stays usable."""
    if rt.kind not in NATIVE_RSQRT_KINDS:
        return None
    try:
        return probe(rt, lanes)
    except Exception:  # noqa: BLE001 - a probe that fails costs the form, not the device
        return None


def check(device: str, lanes: int, *, fault: float = 0.0) -> dict:
    """Measure the device's double-to-float rate, then shade the fixed frame on ``device``
    ("P:D") at ``lanes`` on every path of :data:`PATHS`; ``{"ok": bool, "worst": max
    |err|/bound, "detail": str, "fp64_ratio": float}``."""
    rt = get_runtime(device, lanes=lanes)
    # measured first: it chooses what the plan computes in double (Runtime.fast_fp64),
    # so the variants checked here are the ones the parent will run
    rt.fp64_ratio = measure_fp64_ratio(rt)
    # likewise: whether the float 1/√x may start from native_rsqrt at this width (plan
    # RSQRT_NATIVE), and whether the builtin rsqrt is within its 2 ulp (RSQRT_BUILTIN),
    # so that the variants checked below are the ones the parent runs
    ulp = rt.native_rsqrt_ulps[lanes] = _rsqrt_measure(measure_native_rsqrt_ulp, rt, lanes)
    builtin = rt.builtin_rsqrt_ulps[lanes] = _rsqrt_measure(measure_builtin_rsqrt_ulp, rt, lanes)
    if fault:
        rt.extra_defines = {"SELFTEST_FAULT": f"{float(fault)!r}f"}
    gb = _gbuffer()
    worst, detail = 0.0, ""
    for name, scene in _scenes().items():
        ref = reference.shade(scene, gb)
        for path in PATHS:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", InputWarning)
                r = Renderer(scene, device=device, lanes=lanes, path=path)
                frame = prepare_frame(gb, lanes=lanes)
                result = r.shade(frame)
            rgb = result.image.astype(np.float64)
            bound, _ = reference.error_bound(scene, gb, origin=frame.origin, plan=result.plan)
            err = np.abs(rgb - ref)
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.where(err == 0.0, 0.0, err / bound)
            bad = ~np.isfinite(rgb)
            ratio = np.where(bad, np.inf, np.nan_to_num(ratio, nan=np.inf))
            here = float(ratio.max(initial=0.0))
            if here > worst:
                y, x, c = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
                worst = here
                detail = (f"{name}, {path} path: pixel ({x}, {y}) channel {'RGB'[c]} "
                          f"{rgb[y, x, c]:.9g} against the reference's {ref[y, x, c]:.9g} "
                          f"(|err|/bound {here:.3g})")
    verdict = {"ok": bool(worst <= 1.0), "worst": worst, "detail": detail,
               "fp64_ratio": rt.fp64_ratio, "native_rsqrt_ulp": ulp,
               "builtin_rsqrt_ulp": builtin}
    if verdict["ok"] and not fault:
        verdict["pair_rate"] = calibrate(device, lanes)
    return verdict


#: The calibration frame: CALIBRATION_SIZE² pixels × CALIBRATION_LIGHTS point lights
#: (16.8 M pixel-light pairs: ~15 ms on two CPU cores, ~0.2 ms on an H200).
CALIBRATION_SIZE = 256
CALIBRATION_LIGHTS = 256


def _calibration_frame():
    """A smooth lit surface, every pixel shaded, and CALIBRATION_LIGHTS point lights
    with quadratic falloff over it (Blinn-Phong, h = 32): the bench's wide scene in small."""
    n = CALIBRATION_SIZE
    ys, xs = np.mgrid[0:n, 0:n] / (n - 1) * 8.0 - 4.0
    z = 0.05 * np.sin(1.3 * xs) * np.cos(1.7 * ys)
    N = np.stack([-0.065 * np.cos(1.3 * xs) * np.cos(1.7 * ys),
                  0.085 * np.sin(1.3 * xs) * np.sin(1.7 * ys), np.ones_like(z)], -1)
    C = np.stack([0.45 + 0.3 * np.sin(xs), 0.5 + 0.3 * np.cos(ys), 0.4 + 0.0 * xs], -1)
    f = np.float32
    gb = GBuffer(position=np.stack([xs, ys, z], -1).astype(f), normal=N.astype(f),
                 albedo=C.astype(f), coverage=None, maps={})
    rng = np.random.default_rng(29)
    scene = parse_scene({
        "camera": {"type": "perspective", "position": [0.0, -3.0, 8.0]},
        "material": {"model": "blinn-phong", "k_a": 0.1, "k_d": 0.7, "k_s": 0.2, "h": 32.0},
        "light": [{"type": "ambient", "intensity": 0.3}] + [
            {"type": "point", "position": [float(x), float(y), float(z)], "intensity": 0.2,
             "attenuation": [1.0, 0.1, 0.05]}
            for x, y, z in np.column_stack([rng.uniform(-4, 4, (CALIBRATION_LIGHTS, 2)),
                                            rng.uniform(0.5, 3.0, CALIBRATION_LIGHTS)])],
    }, "<calibration>")
    return scene, gb


def calibrate(device: str, lanes: int, repeats: int = 3) -> float:
    """The device's measured pixel-light pairs a second on the default (accurate) path:
    the median kernel time of the calibration frame after one untimed frame. The default
    device is the fastest that passes its self-test (:mod:`clphong.device.selection`),
    and a long frame is launched in pieces sized from this rate (``renderer.launch_pieces``)."""
    scene, gb = _calibration_frame()
    r = Renderer(scene, device=device, lanes=lanes)
    frame = prepare_frame(gb, lanes=lanes)
    times = [r.shade(frame).stats.kernel_seconds for _ in range(repeats + 1)][1:]
    pairs = CALIBRATION_SIZE * CALIBRATION_SIZE * CALIBRATION_LIGHTS
    return pairs / max(float(np.median(times)), 1e-9)


def main(argv=None) -> int:
    """The child: ``python -m clphong.device.selftest --device P:D --lanes N``; prints
    the verdict as one JSON line on stdout."""
    p = argparse.ArgumentParser(prog="python -m clphong.device.selftest")
    p.add_argument("--device", required=True)
    p.add_argument("--lanes", type=int, required=True)
    args = p.parse_args(argv)
    fault = float(os.environ.get(FAULT_ENV, "0") or 0)
    try:
        verdict = check(args.device, args.lanes, fault=fault)
    except ClphongError as exc:
        verdict = {"ok": False, "worst": float("inf"), "detail": str(exc).splitlines()[0]}
    sys.stdout.write(json.dumps(verdict) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
