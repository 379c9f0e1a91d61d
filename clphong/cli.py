"""The ``clphong`` command: a thin layer over the library functions.

Usage errors exit 2 (argparse). Processing errors print one line,
``clphong: error: …``, on stderr and exit 1; nothing is left behind, because
every output is written to a temporary name and renamed into place.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from .errors import ClphongError, OutputError

RENDER_EXAMPLES = """\
examples:
  # one multichannel G-buffer (P, N and albedo layers, detected by channel name)
  clphong render gbuffers/spheres.toml gbuffers/spheres.exr -o spheres.exr

  # separate files, one buffer each (plain R,G,B or X,Y,Z channels)
  clphong render scene.toml --position P.exr --normal N.exr --albedo A.exr -o out.exr

  # explicit channel names override detection
  clphong render scene.toml frame.exr --channels position=Pworld --channels normal=Nw.X,Nw.Y,Nw.Z -o out.exr
"""

#: Rec.709 primaries and D65 white: the working space of the default output.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
SCENE_LINEAR_COLORSPACE = "Linear Rec.709 (sRGB)"


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clphong",
        description="OpenCL image-space Phong relighting of EXR G-buffers.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    r = sub.add_parser(
        "render", help="shade a G-buffer with a scene and write scene-linear EXR",
        description="Shade a G-buffer (world-space P, N, albedo) with the lights and "
                    "material of SCENE.toml and write a float32 scene-linear RGB EXR.",
        epilog=RENDER_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("scene", metavar="SCENE.toml", help="scene file (see README)")
    r.add_argument("gbuffer", metavar="GBUFFER.exr", nargs="?",
                   help="multichannel G-buffer EXR (omit when giving --position/--normal/--albedo)")
    _add_gbuffer_options(r)
    r.add_argument("-o", "--output", required=True, metavar="OUT.exr", help="output EXR path")
    r.add_argument("--half", action="store_true", help="write half-float instead of float32")
    _add_device_options(r)
    r.add_argument("--stats", action="store_true", help="print timings and the shading plan on stderr")

    pl = sub.add_parser(
        "plan", help="print which kernel variant a scene compiles, and why",
        description="Print the shading plan: the -D defines chosen for SCENE.toml "
                    "(and the material maps of GBUFFER.exr, if given) with the reason for each.")
    pl.add_argument("scene", metavar="SCENE.toml")
    pl.add_argument("gbuffer", metavar="GBUFFER.exr", nargs="?")
    _add_gbuffer_options(pl)
    _add_device_options(pl)

    sub.add_parser("devices", help="list the OpenCL devices and the one chosen by default")

    s = sub.add_parser("samples", help="regenerate the sample G-buffers (spheres.exr, ortho.exr)")
    s.add_argument("folder", nargs="?", default="gbuffers")
    return p


def _add_gbuffer_options(p):
    p.add_argument("--position", metavar="P.exr", help="file holding world-space positions")
    p.add_argument("--normal", metavar="N.exr", help="file holding world-space normals")
    p.add_argument("--albedo", metavar="A.exr", help="file holding the albedo C_d")
    p.add_argument("--channels", action="append", default=[], metavar="KEY=CHANNELS",
                   help="override channel detection: KEY is position, normal, albedo, coverage, "
                        "k_d, k_s, h or specular_color; CHANNELS a layer prefix or a comma-separated list")


def _add_device_options(p):
    p.add_argument("--device", metavar="DEV",
                   help="OpenCL device: 'P:D' indices or a name substring (default: PoCL CPU, "
                        "or PYOPENCL_CTX if set); see 'clphong devices'")
    p.add_argument("--kernel", choices=("lanes", "obvious"), default="lanes",
                   help="'lanes' (default, fast) or 'obvious' (one pixel per work-item, the baseline)")
    p.add_argument("--lanes", type=int, choices=(1, 4, 8, 16),
                   help="pixels per work-item of the lane kernel (default: chosen for the device)")


def _read_gbuffer(args):
    from .gbuffer import parse_channel_mapping, read_gbuffer

    if args.gbuffer is None and not (args.position or args.normal or args.albedo):
        raise _Usage("give a G-buffer file, or --position, --normal and --albedo")
    channels = parse_channel_mapping(args.channels) if args.channels else None
    return read_gbuffer(args.gbuffer, position=args.position, normal=args.normal,
                        albedo=args.albedo, channels=channels)


class _Usage(Exception):
    pass


def _inputs_of(args) -> list[str]:
    return [x for x in (args.scene, args.gbuffer, args.position, args.normal, args.albedo) if x]


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def cmd_render(args) -> int:
    from .output import write_exr
    from .render import Renderer
    from .scene import load_scene

    for src in _inputs_of(args):
        if _same_file(src, args.output):
            raise OutputError(f"{args.output}: output would overwrite the input {src}; choose another -o")
    t0 = time.perf_counter()
    scene = load_scene(args.scene)
    gbuffer = _read_gbuffer(args)
    t_read = time.perf_counter()
    renderer = Renderer(scene, device=args.device, kernel=args.kernel, lanes=args.lanes)
    rgb = renderer.render(gbuffer)
    t_shade = time.perf_counter()
    write_exr(args.output, rgb, pixel_type="half" if args.half else "float",
              attributes={"chromaticities": REC709_CHROMATICITIES,
                          "oiio:ColorSpace": SCENE_LINEAR_COLORSPACE,
                          "Software": "clphong"})
    t_end = time.perf_counter()
    if args.stats:
        st = renderer.last_stats
        h, w = gbuffer.shape
        print(renderer.plan_for(tuple(gbuffer.maps)), file=sys.stderr)
        print(f"device: {renderer.runtime.name}", file=sys.stderr)
        print(f"{w}x{h}: read {t_read - t0:.3f} s, shade {t_shade - t_read:.3f} s "
              f"(kernel {st.kernel_seconds:.4f} s), write {t_end - t_shade:.3f} s, "
              f"total {t_end - t0:.3f} s", file=sys.stderr)
    return 0


def cmd_plan(args) -> int:
    from .plan import make_plan
    from .scene import load_scene

    scene = load_scene(args.scene)
    maps = ()
    if args.gbuffer or args.position or args.normal or args.albedo:
        maps = tuple(_read_gbuffer(args).maps)
    from .runtime import get_runtime

    # The lane width depends on the device, as in 'render'.
    lanes = args.lanes or get_runtime(args.device).lanes
    print(make_plan(scene, maps, kernel=args.kernel, lanes=lanes))
    return 0


def cmd_devices(args) -> int:
    from .runtime import get_runtime, list_devices

    for line in list_devices():
        print(line)
    rt = get_runtime(None)
    print(f"default: {rt.name} ({rt.lanes} lane(s); LLVM target {rt.llvm_target or 'n/a'})")
    return 0


def cmd_samples(args) -> int:
    from .samples import write_samples

    for path in write_samples(args.folder):
        print(path)
    return 0


COMMANDS = {"render": cmd_render, "plan": cmd_plan, "devices": cmd_devices, "samples": cmd_samples}


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return the exit code."""
    parser = _build_parser()
    args = parser.parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except _Usage as exc:
        parser.error(str(exc))   # exits 2
    except ClphongError as exc:
        msg = " ".join(str(exc).split("\n")).strip()
        print(f"clphong: error: {msg}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("clphong: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
