"""Time tone mapping + encoding + writing of a 1920×1080 frame, per output kind.

Not a test: ``python -m clphong.tools.output_bench [--runs N] [--folder DIR] [--keep]`` prints
the median of N runs for each kind. ``--errors`` prints instead each tone-mapping
operator's error against its float64 twin (:func:`operator_errors`). The frame is the spheres sample
(:mod:`clphong.tools.samples`, built in memory: no source checkout needed), or
``--scene S.toml --gbuffer G.exr``, shaded and resized to 1920×1080, so only the
output path is timed, not shading. The files go to a temporary folder, removed
at the end unless ``--keep`` (or ``--folder``, an existing folder, which is kept).
The fused SDR path's tone mapping normally runs inside the shading kernel; here
it is timed with the same device code run on its own (tonemap_apply.cl).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from ..color import ocio as color
from ..core.errors import ClphongError
from ..deliver.contact import write_contact_sheet
from ..deliver.writers import jpegxl_available, write_hdr, write_scene_linear, write_sdr
from ..device.display import DisplayTransform, apply_display_transform
from ..device.renderer import render
from ..io.gbuffer import read_gbuffer
from ..model.scene import load_scene
from ..model.tonemap import OPERATORS
from . import samples
from .commands import in_folder
from .report import markdown_table


def _frame(scene_path=None, gbuffer_path=None) -> np.ndarray:
    """The frame, shaded and resized to 1920×1080 (scene-linear HDR).

    Default: the spheres sample built in memory (clphong.tools.samples); else the
    given scene and G-buffer files.
    """
    import OpenImageIO as oiio

    scene = load_scene(scene_path) if scene_path else samples.spheres_scene()
    gbuffer = read_gbuffer(gbuffer_path) if gbuffer_path else samples.spheres_gbuffer()
    small = render(scene, gbuffer)
    buf = oiio.ImageBufAlgo.resize(oiio.ImageBuf(small), roi=oiio.ROI(0, 1920, 0, 1080, 0, 1, 0, 3))
    return np.ascontiguousarray(buf.get_pixels(oiio.FLOAT))


def main(argv=None) -> int:
    """Run the timing; user errors are one line on stderr (exit 1; usage 2)."""
    p = argparse.ArgumentParser(prog="python -m clphong.tools.output_bench",
                                description="Time tone mapping + encoding + writing of a "
                                            "1920x1080 frame, per output kind.")
    p.add_argument("--runs", type=int, default=5, help="runs per kind (median; default 5)")
    p.add_argument("--folder", default=None,
                   help="existing folder for the files (default: a temporary folder)")
    p.add_argument("--keep", action="store_true",
                   help="keep the temporary folder and its files (printed at the start)")
    p.add_argument("--scene", metavar="SCENE.toml",
                   help="scene of the frame (default: the spheres sample, built in memory)")
    p.add_argument("--gbuffer", metavar="GBUFFER.exr",
                   help="G-buffer of the frame (default: the spheres sample, built in memory)")
    p.add_argument("--errors", action="store_true",
                   help="print each kernel operator's error against its float64 twin and "
                        "error bound (1920x1080 log-uniform values, 1e-4 ... 1e6), no timing")
    args = p.parse_args(argv)
    if args.errors:
        print(operator_errors_table(operator_errors()))
        return 0
    if args.runs < 1:
        p.error("--runs must be >= 1")
    if bool(args.scene) != bool(args.gbuffer):
        p.error("give --scene and --gbuffer together (or neither, for the spheres sample)")
    try:
        return _run(args)
    except ClphongError as exc:
        print(f"clphong: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return exc.exit_code


def _run(args) -> int:
    return in_folder(args.folder, args.keep, lambda folder: _time_outputs(args, folder))


def _time_outputs(args, folder: Path) -> int:
    rgb = _frame(args.scene, args.gbuffer)
    cfg = color.load_config()
    ws = color.WORKING_SPACES["lin_rec709"]
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
    kept = args.folder is not None or args.keep
    print(f"1920x1080, median of {args.runs} runs, files in {folder}"
          + ("" if kept else " (removed at the end; --keep keeps them)"))
    for name, fn in cases.items():
        times = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        print(f"  {name:46s} {1e3 * statistics.median(times):8.1f} ms")
    return 0


def operator_errors(width: int = 1920, height: int = 1080, seed: int = 0) -> list[dict]:
    """Each kernel operator (fused kernel code, run alone: tonemap_apply.cl) against
    its float64 twin, linear and sRGB-encoded, on log-uniform values over
    1e-4 … 1e6 (33 stops: the shoulders and far above them), zeros and 0.18 grey.

    Returns rows of max |err|, the largest bound, max |err|/bound and the count of
    values beyond their bound (0 unless the error model is wrong).
    """
    import math

    rng = np.random.default_rng(seed)
    x = np.exp(rng.uniform(math.log(1e-4), math.log(1e6), (height, width, 3))).astype(np.float32)
    x[0, :4], x[1, :4] = 0.0, 0.18
    rows = []
    for op in OPERATORS:
        for enc in ("linear", "srgb"):
            dt = DisplayTransform(op, encoding=enc)
            err = np.abs(apply_display_transform(x, dt).astype(np.float64) - dt.reference(x))
            bound = dt.error_bound(x)
            with np.errstate(invalid="ignore", divide="ignore"):
                ratio = np.where(err == 0.0, 0.0, err / bound)
            rows.append(dict(operator=op, encoding=enc, max_abs_err=float(err.max()),
                             max_bound=float(bound.max()), max_err_over_bound=float(ratio.max()),
                             beyond_bound=int((err > bound).sum()), values=int(x.size)))
    return rows


def operator_errors_table(rows: list[dict]) -> str:
    """:func:`operator_errors` as a Markdown table."""
    return markdown_table(
        ["operator", "encoding", "max \\|err\\|", "max bound", "max \\|err\\|/bound", "beyond bound"],
        [[r["operator"], r["encoding"], f"{r['max_abs_err']:.2e}", f"{r['max_bound']:.2e}",
          f"{r['max_err_over_bound']:.3f}", f"{r['beyond_bound']} of {r['values']}"] for r in rows])


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
