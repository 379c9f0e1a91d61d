"""Time tone mapping + encoding + writing of a 1920×1080 frame, per output kind.

Not a test: ``python -m clphong.bench_output [--runs N] [--folder DIR]`` prints the
median of N runs for each kind. The frame is the shipped spheres sample shaded
and resized to 1920×1080 (needs a source checkout), so only the output path is
timed, not shading.
The fused SDR path's tone mapping normally runs inside the shading kernel; here
it is timed with the same device code run on its own (tonemap_apply.cl).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _frame() -> np.ndarray:
    """The shipped spheres sample, shaded and resized to 1920×1080 (scene-linear HDR)."""
    import OpenImageIO as oiio

    from .gbuffer import read_gbuffer
    from .render import render
    from .scene import load_scene

    root = Path(__file__).resolve().parent.parent / "gbuffers"
    small = render(load_scene(root / "spheres.toml"), read_gbuffer(root / "spheres.exr"))
    buf = oiio.ImageBufAlgo.resize(oiio.ImageBuf(small), roi=oiio.ROI(0, 1920, 0, 1080, 0, 1, 0, 3))
    return np.ascontiguousarray(buf.get_pixels(oiio.FLOAT))


def main(argv=None) -> int:
    from . import color
    from .contact import write_contact_sheet
    from .display import DisplayTransform, apply_display_transform
    from .writers import jpegxl_available, write_hdr, write_scene_linear, write_sdr

    p = argparse.ArgumentParser(prog="python -m clphong.bench_output")
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--folder", default=None)
    args = p.parse_args(argv)
    rgb = _frame()
    cfg = color.load_config()
    ws = color.WORKING_SPACES["lin_rec709"]
    folder = Path(args.folder or tempfile.mkdtemp(prefix="clphong-bench-"))
    apply_display_transform(rgb[:8, :64], DisplayTransform("agx"))       # build once

    def fused(op, bits, ext):
        def run():
            shown = apply_display_transform(rgb, DisplayTransform(op))
            write_sdr(folder / f"sdr{ext}", shown, bits=bits, cicp=color.SRGB_CICP)
        return run

    def ocio_sdr():
        shown = cfg.display_view(rgb, ws, None, None)
        write_sdr(folder / "view.png", shown, bits=8, cicp=color.SRGB_CICP)

    def hdr(ext):
        def run():
            pq = cfg.display_view(rgb, ws, color.HDR_DISPLAY, color.HDR_VIEW)
            write_hdr(folder / f"hdr{ext}", pq)
        return run

    cases = {
        "EXR float zip": lambda: write_scene_linear(folder / "a.exr", rgb, ws),
        "EXR half piz": lambda: write_scene_linear(folder / "b.exr", rgb, ws,
                                                   pixel_type="half", compression="piz"),
        "SDR PNG 8-bit, agx fused kernel op, dithered": fused("agx", 8, ".png"),
        "SDR PNG 16-bit, agx": fused("agx", 16, ".png"),
        "SDR TIFF 8-bit, pbr-neutral": fused("pbr-neutral", 8, ".tif"),
        "SDR PNG 8-bit, OCIO ACES 2.0 SDR view": ocio_sdr,
        "HDR PQ PNG 16-bit, ACES 2.0 HDR 1000 nits": hdr(".png"),
        "contact sheet PNG (7 operators + 3 views)": lambda: write_contact_sheet(
            folder / "sheet.png", rgb, ws, cfg),
    }
    if jpegxl_available():
        cases["HDR PQ JPEG XL, ACES 2.0 HDR 1000 nits"] = hdr(".jxl")
    print(f"1920x1080, median of {args.runs} runs, files in {folder}")
    for name, fn in cases.items():
        times = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        print(f"  {name:46s} {1e3 * statistics.median(times):8.1f} ms")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
