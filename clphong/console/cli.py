"""The ``clphong`` command: a thin layer over the library functions.

Usage errors print one line, ``clphong COMMAND: error: … (see clphong COMMAND
--help)``, and exit 2. Processing errors print one line, ``clphong: error: …``,
on stderr and exit 1; nothing is left behind, because every output is written
to a temporary name and renamed into place.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from importlib import metadata
from pathlib import Path

from .. import __version__
from ..color.ocio import WORKING_SPACES, load_config
from ..core.errors import (
    ClphongError,
    OutputError,
    OutputWarning,
    clean_line,
    cut_line,
    printable,
)
from ..core.signals import Terminated as _Terminated
from ..core.signals import signals_as_interrupt as _sigterm_as_interrupt
from ..deliver.outputs import OutputOptions, OutputPaths, check_outputs, render_outputs
from ..deliver.writers import (
    EXR_BASE_COMPRESSIONS,
    HTJ2K_COMPRESSIONS,
    SDR_BITS,
    check_compression,
)
from ..device import runtime as _runtime
from ..device.culling import BLOCK_TILES, BRUTE_ABOVE, TILE
from ..device.envprobe import DeviceProbeShader
from ..device.hostrule import host
from ..device.renderer import Renderer
from ..device.selection import describe_devices
from ..io import envmap as _envmap
from ..io.atomic import PIXEL_TYPES, check_output_path, same_file
from ..io.camera import resolve_camera
from ..io.envmap import FrameSource, check_environment_maps, resolve_environment
from ..io.gbuffer import parse_channel_mapping, read_gbuffer
from ..io.inspection import METRICS, DiffError, diff_images, format_report, inspect_file
from ..model.options import (
    DEFAULT_ENV_ERROR,
    ENV_PATHS,
    ENV_PROBES,
    KERNELS,
    LANES,
    NONFINITE_POLICIES,
    PATHS,
    RendererOptions,
    check_env_error,
    check_number,
)
from ..model.scene import MAP_KEYS, load_scene
from ..model.tonemap import OPERATORS
from ..pipeline.batch import (
    Rig,
    plan_batch,
    remove_stale_temporaries,
    run_batch,
)
from ..pipeline.frames import FrameRange
from ..pipeline.relighter import (
    Relighter,
    RelighterSpec,
    _hashable_channels,
)
from ..tools.samples import write_samples
from .bench import _add_bench_parser, cmd_bench
from .usage import UsageError as _Usage

RENDER_EXAMPLES = """\
examples:
  # one multichannel G-buffer (P, N and albedo layers, detected by channel name)
  clphong render gbuffers/spheres.toml gbuffers/spheres.exr -o spheres.exr

  # separate files, one buffer each (plain R,G,B or X,Y,Z channels)
  clphong render scene.toml --position P.exr --normal N.exr --albedo A.exr -o out.exr

  # explicit channel names override detection
  clphong render scene.toml frame.exr --channels position=Pworld --channels normal=Nw.X,Nw.Y,Nw.Z -o out.exr
"""

class _Parser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line on stderr (exit 2), not the
    whole usage block; its subparsers are of this class too."""

    def error(self, message):
        message = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _version() -> str:
    """The installed distribution's version; the package's own where it is not installed."""
    try:
        return metadata.version("clphong")
    except metadata.PackageNotFoundError:
        return __version__


def _build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="clphong",
        description="OpenCL image-space Phong relighting of EXR G-buffers.",
    )
    p.add_argument("--version", action="version", version=f"clphong {_version()}",
                   help="print clphong's version and exit")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    r = sub.add_parser(
        "render", help="shade a G-buffer with a scene and write scene-linear EXR",
        description="Shade a G-buffer (world-space P, N, albedo) with the lights and "
                    "material of SCENE.toml and write a scene-linear EXR (R, G, B, A = coverage, "
                    "RGB premultiplied, and the light-group and --aov layers), and display outputs.",
        epilog=RENDER_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("scene", metavar="SCENE.toml", help="scene file (see docs/lighting.md)")
    r.add_argument("gbuffer", metavar="GBUFFER.exr", nargs="?",
                   help="multichannel G-buffer EXR (omit when giving --position/--normal/--albedo)")
    _add_gbuffer_options(r)
    r.add_argument("-o", "--output", metavar="OUT.exr",
                   help="scene-linear EXR output (tagged with the working space)")
    _add_color_options(r)
    r.add_argument("--half", action="store_true", help="write half-float instead of float32")
    _add_device_options(r)
    _add_renderer_options(r)
    r.add_argument("--stats", action="store_true", help="print timings and the shading plan on stderr")

    pl = sub.add_parser(
        "plan", help="print which kernel variant a scene compiles, and why",
        description="Print the shading plan: the -D defines chosen for SCENE.toml "
                    "(and the material maps of GBUFFER.exr, if given) with the reason for each.")
    pl.add_argument("scene", metavar="SCENE.toml")
    pl.add_argument("gbuffer", metavar="GBUFFER.exr", nargs="?")
    _add_gbuffer_options(pl)
    _add_device_options(pl)
    _add_speed_options(pl)

    _add_relight_parser(sub)
    _add_inspect_parsers(sub)
    _add_bench_parser(sub)
    p._clphong_commands = sub.choices      # name -> subparser (unknown options: main)

    sub.add_parser("devices", help="list the OpenCL devices and the one chosen by default")

    dp = sub.add_parser("displays", help="list OCIO displays, views and looks, working spaces "
                                         "and tone-mapping operators")
    dp.add_argument("--ocio-config", metavar="PATH",
                    help="OCIO config (default: $OCIO, else the built-in ocio://default)")

    s = sub.add_parser("samples", help="regenerate the sample G-buffers (spheres.exr, ortho.exr)",
                       description="Write spheres.exr and ortho.exr into FOLDER, which must exist "
                                   "(as for every output) unless -p is given.")
    s.add_argument("folder", nargs="?", default="gbuffers", metavar="FOLDER",
                   help="destination folder (default gbuffers)")
    s.add_argument("-p", "--parents", action="store_true",
                   help="create FOLDER (and its missing parents) if it does not exist")
    return p


RELIGHT_EXAMPLES = """\
examples:
  # every frame on disk, two rigs, outputs named by rig and frame
  clphong relight shot/gbuf.####.exr --rig key=key.toml --rig fill.toml -o out/{rig}/beauty.####.exr

  # every other frame of 1-240, 2 local worker processes, finish an interrupted run
  clphong relight shot/gbuf.%04d.exr --rig key.toml -o out/{rig}.{frame:04d}.exr --frames 1-240x2 --jobs 2 --skip-existing

  # also an 8-bit sRGB PNG and a PQ HDR PNG per frame; tone mapping from each rig's [render]
  # table, here overridden: AgX at +1 EV
  clphong relight shot/gbuf.####.exr --rig key.toml -o out/{rig}/beauty.####.exr \
      --sdr out/{rig}/png/beauty.####.png --hdr out/{rig}/hdr/beauty.####.png --tonemap agx --exposure 1

  # frames as tasks on a Dask cluster (pip install 'clphong[dask]')
  clphong relight shot/ --rig key.toml -o out/{name}.{rig}.####.exr --scheduler tcp://farm-scheduler:8786
"""


def _add_relight_parser(sub):
    r = sub.add_parser(
        "relight", help="relight a frame sequence with one or more light rigs",
        description="Relight every frame of SEQUENCE (P.####.exr, P.%04d.exr or a folder of "
                    "multichannel EXRs) with each --rig, writing one output per frame per rig. "
                    "Outputs are written atomically; a bad frame is reported and the others "
                    "complete (exit status 1 when any failed).",
        epilog=RELIGHT_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("sequence", metavar="SEQUENCE", help="frame pattern (#### or %%04d) or folder of EXRs")
    r.add_argument("--rig", action="append", required=True, metavar="[NAME=]SCENE.toml",
                   help="a light rig (scene file); repeat for several; NAME defaults to the file stem")
    r.add_argument("-o", "--output", metavar="TEMPLATE.exr",
                   help="scene-linear EXR path template: {frame} (e.g. {frame:04d}), ####, %%04d, "
                        "{rig}, {stem} (input file name), {name} (input name without its frame "
                        "number); --sdr, --hdr and --contact-sheet take templates too")
    r.add_argument("--frames", metavar="RANGE", help="frames to relight, e.g. 1-240x2 or 1-10,20 "
                                                     "(default: every frame on disk)")
    r.add_argument("-j", "--jobs", type=int, default=1, metavar="N",
                   help="local worker processes (default 1: one process, reading, shading and "
                        "writing of consecutive frames overlapped)")
    r.add_argument("--skip-existing", "--resume", dest="skip_existing", action="store_true",
                   help="skip outputs that exist (complete: writes are atomic); finishes an interrupted run")
    r.add_argument("--dry-run", action="store_true", help="list what would be written, and stop")
    r.add_argument("-q", "--quiet", action="store_true",
                   help="no progress bar or totals (failures are still listed)")
    r.add_argument("--scheduler", metavar="ADDRESS",
                   help="run frames as tasks on this Dask distributed scheduler (tcp://host:8786)")
    r.add_argument("--scheduler-timeout", type=float, default=20.0, metavar="S",
                   help="seconds to connect to the scheduler and hear its handshake (default 20); "
                        "then one line naming the address and the cause")
    r.add_argument("--half", action="store_true", help="write half-float instead of float32")
    _add_color_options(r, templates=True)
    _add_gbuffer_options(r, files=False)
    _add_device_options(r)
    _add_renderer_options(r)


def _add_inspect_parsers(sub):
    i = sub.add_parser("inspect", help="channels, sizes, pixel types, G-buffer convention, camera, NaN/Inf",
                       description="Print what an image file holds: parts, sizes, channels and pixel "
                                   "types, the detected G-buffer convention, the camera metadata "
                                   "(worldToCamera) and per-channel NaN, Inf and negative counts.")
    i.add_argument("file", metavar="FILE")
    i.add_argument("--json", action="store_true", help="print the report as JSON")
    i.add_argument("--no-stats", action="store_true", help="do not read the pixels")

    d = sub.add_parser("diff", help="compare two images by a metric and a tolerance (exit 0 match, 1 differ)",
                       description="Compare test image B with reference A. Exit status: 0 match, "
                                   "1 differ, 2 trouble (unreadable file, bad option).")
    d.add_argument("a", metavar="A", help="reference image")
    d.add_argument("b", metavar="B", help="test image")
    d.add_argument("--metric", choices=METRICS, default="max-rel",
                   help="max-rel: max |B-A|/max(|A|, floor); mean-abs: mean |B-A|; psnr: dB "
                        "(match when >= tol); flip: mean FLIP error (OpenImageIO FLIP_diff)")
    d.add_argument("--tol", type=float, required=True, metavar="X",
                   help="largest allowed error (psnr: smallest allowed dB)")
    d.add_argument("--heatmap", metavar="OUT", help="write the per-pixel error (EXR: raw; else false colour)")
    d.add_argument("--channels", metavar="C1,C2,...", help="channels to compare (default: all; flip: R,G,B)")
    d.add_argument("--floor", type=float, help="max-rel denominator floor (default 1e-6 x max|A|)")
    d.add_argument("--peak", type=float, help="psnr peak (default max|A|)")


def _add_gbuffer_options(p, files: bool = True):
    if files:
        p.add_argument("--position", metavar="P.exr", help="file holding world-space positions")
        p.add_argument("--normal", metavar="N.exr", help="file holding world-space normals")
        p.add_argument("--albedo", metavar="A.exr", help="file holding the albedo C_d")
    p.add_argument("--channels", action="append", default=[], metavar="KEY=CHANNELS",
                   help="override channel detection: KEY is position, normal, albedo, coverage, "
                        f"{', '.join(MAP_KEYS[:-1])} or {MAP_KEYS[-1]}; "
                        "CHANNELS a layer prefix or a comma-separated list")


def _add_device_options(p):
    p.add_argument("--device", metavar="DEV",
                   help="OpenCL device: 'P:D' indices, a name substring, 'pocl' or 'intel' "
                        "(default: the first CPU device whose self-test passes, Intel's runtime "
                        "before PoCL, or PYOPENCL_CTX if set); see 'clphong devices'")
    p.add_argument("--kernel", choices=tuple(KERNELS), default="lanes",
                   help="'lanes' (default, fast) or 'obvious' (one pixel per work-item, the baseline)")
    p.add_argument("--lanes", type=int, choices=LANES,
                   help="pixels per work-item of the lane kernel (default: the widest the host "
                        "rule allows on the device whose self-test passes; an unsafe one is "
                        "refused)")


def _env_error(text: str) -> float:
    """``--env-error``: a finite number > 0 (argparse: one usage line otherwise)."""
    try:
        return check_env_error(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


ENV_ERROR_HELP = ("environment lights: each map becomes the fewest directional lights whose "
                  "estimated relative error against the exact sum over its texels is within "
                  f"REL on pixels >= 1e-3 of the maximum (default {DEFAULT_ENV_ERROR:g}); "
                  "larger is faster (docs/lighting.md, 'Environment light')")


def _add_speed_options(p):
    p.add_argument("--env-error", type=_env_error, default=DEFAULT_ENV_ERROR, metavar="REL",
                   help=ENV_ERROR_HELP)
    p.add_argument("--env-probes", choices=tuple(ENV_PROBES), default="frame",
                   help="where --env-error is estimated: 'frame' (default) on the frame's own "
                        "normals and views, so a frame gets the lights it needs (each frame "
                        "converts once, cached on disk); 'all' on every normal and view, one "
                        "conversion for every frame (docs/lighting.md, 'Environment light')")
    p.add_argument("--env-path", choices=tuple(ENV_PATHS), default="auto",
                   help="'auto' (default): an environment is shaded from tables (irradiance and "
                        "the Phong lobe, exact at their nodes, the sun as lights) where their "
                        "horizon bound holds, and as directional lights on the pixels where it "
                        "does not (all of them if more than half); 'lights': always as "
                        "directional lights (docs/lighting.md, 'Tables')")
    p.add_argument("--max-error", type=float, metavar="EPS",
                   help="tiled light culling: per 16x16 tile, drop point lights only while the sum "
                        "of their upper bounds stays within EPS x reference white of output radiance "
                        "per pixel and channel (0: bit-identical to brute force; default: no culling)")
    p.add_argument("--relative", action="store_true",
                   help="with --max-error: EPS is a fraction of each pixel's own value, per "
                        "channel (as Lightcuts): a tile drops lights only within EPS x a proven "
                        "lower bound of its pixels' totals, each light group's layer within "
                        "EPS of its own (docs/speed.md, 'Relative budget')")
    p.add_argument("--reference-white", type=float, default=1.0, metavar="W",
                   help="output radiance of reference white for --max-error (default 1.0)")
    p.add_argument("--no-light-tree", dest="light_tree", action="store_false",
                   help="with --max-error: no light-tree clusters, culling only (by default, "
                        "where culling keeps most lights, compact groups of point lights may "
                        "shade as one representative within a proven share of EPS; docs/speed.md, "
                        "'Light tree')")
    p.add_argument("--path", choices=tuple(PATHS), default="accurate",
                   help="'accurate' (default: directions, weights and sums in double where the "
                        "device has fp64), 'float' (float32 directions, for devices without fast "
                        "double: larger error near grazing light and for high shininess; on a CPU "
                        "with fp64 not faster from 16 lights on) or 'fast' (float32 throughout, "
                        "the integer power and a naive light sum too: fastest from 16 lights on, "
                        "relative error 1e-6 to 3e-6 on the bench scene, bounded by ~2k*u); "
                        "'clphong bench' reports each")


def _add_renderer_options(p):
    """The renderer options of 'render' and 'relight': one definition, the same help."""
    p.add_argument("--nonfinite", choices=tuple(NONFINITE_POLICIES), default="background",
                   help="NaN/Inf in the G-buffer: leave those pixels unshaded as background "
                        "(default, with a warning giving the counts per buffer), stop with an "
                        "error (relight: that frame fails, the others complete), or pass them "
                        "through (they stay in their own pixels)")
    _add_speed_options(p)


def _renderer_options(args) -> RendererOptions:
    """The renderer options, checked once here (one-line errors) and handed down finished."""
    return RendererOptions(
        path=None if args.path == "accurate" else args.path,
        max_error=args.max_error, reference_white=args.reference_white,
        env_error=args.env_error, light_tree=args.light_tree,
        env_probes=getattr(args, "env_probes", "frame"),
        env_path=getattr(args, "env_path", "auto"),
        relative=getattr(args, "relative", False),
        nonfinite=getattr(args, "nonfinite", "background"),
        aovs=tuple(a.strip() for a in (getattr(args, "aov", None) or "").split(",") if a.strip()))


def _read_gbuffer(args):
    if args.gbuffer is None and not (args.position or args.normal or args.albedo):
        raise _Usage("give a G-buffer file, or --position, --normal and --albedo")
    channels = parse_channel_mapping(args.channels) if args.channels else None
    return read_gbuffer(args.gbuffer, position=args.position, normal=args.normal,
                        albedo=args.albedo, channels=channels)




def _inputs_of(args) -> list[str]:
    return [x for x in (args.scene, args.gbuffer, args.position, args.normal, args.albedo) if x]


def cmd_render(args) -> int:
    renderer_options = _renderer_options(args)       # bad values: before any file is touched
    display_paths = [*args.sdr, *args.hdr, *([args.contact_sheet] if args.contact_sheet else [])]
    if not args.output and not display_paths:
        raise _Usage("give at least one output: -o OUT.exr, --sdr OUT.png, --hdr OUT.png or "
                     "--contact-sheet OUT.png")
    for out in ([args.output] if args.output else []) + display_paths:
        for src in _inputs_of(args):
            if same_file(src, out):
                raise OutputError(f"{out}: output would overwrite the input {src}; choose another name")
        check_output_path(out, exr=out == args.output)   # fail before the work, not after
    t0 = time.perf_counter()
    scene = load_scene(args.scene)
    if renderer_options.aovs and not args.output:
        warnings.warn(OutputWarning("--aov adds EXR layers, and no EXR is written (-o)"))
    paths = _output_paths(args, args.output)
    options = check_outputs(_output_options(args).for_scene(scene), paths)   # bad names: before any work
    _remove_stale_temporaries(paths.files)
    gbuffer = _read_gbuffer(args)
    t_read = time.perf_counter()
    # The same constructor path as 'relight' and the API (--path, --max-error, --nonfinite).
    relighter = Relighter(scene, device=args.device, kernel=args.kernel, lanes=args.lanes,
                          output=options, options=renderer_options)
    # A scene without [camera] takes this frame's worldToCamera (clphong.io.camera).
    renderer = relighter.renderer_for(gbuffer, source=args.gbuffer or args.position)
    # The one output step of render, relight and the API: EXR / SDR / HDR / contact sheet.
    result, times = render_outputs(renderer, gbuffer, relighter.output, paths)
    t_end = time.perf_counter()
    t_shade = times.pop("shade")            # the launch (and the SDR tone mapping on the device)
    t_write = sum(times.values())           # per output kind: tone mapping, encoding, writing
    if args.stats:
        st = result.stats
        h, w = gbuffer.shape
        # The plan that ran (culling fallback), not a fresh one; then the display program's.
        plan = result.plan
        text = str(plan)
        if result.cull is not None and result.cull.brute:
            # the brute-force variant ran although a budget was given: say so on its line
            text = "\n".join(ln.replace("no --max-error budget: every light shades every pixel",
                                         "--max-error given, but the lists keep nearly every light: "
                                         "every light shades every pixel (culling line below)")
                              if ln.lstrip().startswith("-DCULLING=") else ln
                              for ln in text.split("\n"))
        print(text, file=sys.stderr)
        dt = result.display_transform
        if dt is not None:
            print("display: kernels/tonemap_apply.cl on the shaded planes (rebuilt alone when "
                  "the operator or output changes)", file=sys.stderr)
            why = dt.reasons()
            for name, value in dt.defines().items():
                print(f"  -D{name}={value}  {why.get(name, '')}", file=sys.stderr)
        print(f"device: {renderer.runtime.name}", file=sys.stderr)
        for i, env in relighter.environments:
            print(f"environment: light[{i}]: {env.texels} texels as {env.count} directional lights, "
                  f"estimated max relative error {env.estimated_error:.2g} (--env-error "
                  f"{env.max_error:g}), {env.seconds:.2f} s", file=sys.stderr)
        for i, path, why in relighter.env_paths:
            print(f"environment: light[{i}]: {path}: {why}", file=sys.stderr)
        kinds = ", ".join(f"{k} {v:.3f} s" for k, v in times.items())
        print(f"{w}x{h}: read {t_read - t0:.3f} s, setup {t_end - t_read - t_shade - t_write:.3f} s, "
              f"shade {t_shade:.3f} s (kernel {st.kernel_seconds:.4f} s), write {t_write:.3f} s"
              + (f" ({kinds})" if kinds else "") + f", total {t_end - t0:.3f} s", file=sys.stderr)
        dl = result.dir_lists
        if dl is not None:
            print(f"directional lists: {dl.seconds * 1e3:.1f} ms, tiles keep {dl.kept_fraction:.1%} "
                  f"of {dl.n_dir} directional lights (the others face away: exact)", file=sys.stderr)
        cull = result.cull
        if cull is not None:
            print(f"culling: {cull.seconds * 1e3:.1f} ms, tiles keep {cull.kept_fraction:.2%} of "
                  f"{cull.n_point} point lights on average", file=sys.stderr)
            if cull.clusters:
                print(f"light tree: {cull.tree_nodes} clusters over {cull.tree_lights} lights, "
                      f"built in {cull.tree_build_seconds:.3f} s; the cuts use {cull.clusters} "
                      f"clusters for {cull.covered} lights over the "
                      f"{f'{BLOCK_TILES * TILE}-pixel blocks' if cull.tree_blocks else 'super-tiles'}, host cut "
                      f"{cull.tree_seconds:.3f} s", file=sys.stderr)
            if cull.brute:
                print("culling: the lists keep nearly every light (more than "
                      f"{BRUTE_ABOVE:.0%}): shaded brute force", file=sys.stderr)
    return 0


def _remove_stale_temporaries(files) -> None:
    """Remove what a killed earlier run left for these outputs (``.NAME.tmp-XXXXXXXX.EXT``,
    only that pattern for these names, as ``relight`` does), with one warning line."""
    removed = remove_stale_temporaries(files)
    if removed:
        warnings.warn(OutputWarning(
            f"removed {len(removed)} temporary file(s) an interrupted earlier run left: "
            + ", ".join(os.path.basename(p) for p in removed[:3]) + (" ..." if len(removed) > 3 else "")))


def cmd_plan(args) -> int:
    opts = _renderer_options(args)
    original = load_scene(args.scene)
    env_error = opts.env_error
    gbuffer = None
    if args.gbuffer or args.position or args.normal or args.albedo:
        gbuffer = _read_gbuffer(args)
    # the frame's own probes where the frame is given (a metadata camera: the frame's)
    pairs = None
    if gbuffer is not None and opts.env_probes == "frame" and original.lights_of("environment"):
        camera = original.camera
        if camera.type == "metadata":
            camera = resolve_camera(original, gbuffer.attributes,
                                    source=args.gbuffer or args.position).camera
        pairs = FrameSource(camera, gbuffer, original.material)
    resolved = resolve_environment(original, max_error=env_error, nonfinite=opts.nonfinite,
                                   shade=DeviceProbeShader(args.device), pairs=pairs,
                                   tables=opts.env_path == "auto" and args.kernel == "lanes")
    scene = resolved.scene
    maps = tuple(gbuffer.maps) if gbuffer is not None else ()
    # The renderer 'render' builds, so the plan printed is the one it compiles
    # (device, lane width, --path, --max-error).
    renderer = Renderer(scene, device=args.device, kernel=args.kernel, lanes=args.lanes,
                        options=opts)
    print(renderer.plan_for(maps))
    print(f"device: {renderer.runtime.name}, {renderer.lanes} lane(s); "
          f"{renderer.runtime.double_line()}")
    for i, path, why in resolved.paths:
        print(f"environment: light[{i}] {original.lights[i].file}: {path}: {why}")
    for i, env in resolved.environments:
        print(f"environment: light[{i}] {original.lights[i].file}: "
              f"{env.count:,} directional lights of its {env.texels:,} texels (the light tree's "
              f"split), estimated "
              + ("on this frame's pixels" if pairs is not None else
                 "on every normal and view" + (" (give the G-buffer for its own pixels)"
                                               if opts.env_probes == "frame" else ""))
              + f": error {env.estimated_error:.2g} "
              + ("within" if env.met else "NOT within") + f" --env-error {env_error:g}"
              + ("" if env.seconds else "; from the disk cache"))
    return 0


def cmd_devices(args) -> int:
    rows, why = describe_devices()
    print(f"host: {host().label}")
    for row in rows:
        mark = "  (default)" if row["default"] else ""
        print(f"{row['selector']}  {row['name']}{mark}")
        if "target" in row:
            print(f"      compiler target {row['target']}; matches the host: {row['match']}")
        width = f"{row['width']} lane(s)" if row.get("width") else "no width"
        print(f"      {width}; self-test: {row['verdict']}")
        if row.get("double"):
            print(f"      {row['double']}")
        if row.get("rsqrt"):
            print(f"      {row['rsqrt']}")
        if "rule" in row:
            print(f"      rule: {row['rule']}")
    default = next((r for r in rows if r["default"]), None)
    print(f"default: {default['name']}: {why}" if default else f"default: none: {why}")
    return 0


def cmd_samples(args) -> int:
    try:
        written = write_samples(args.folder, parents=args.parents)
    except OutputError as exc:
        if "does not exist" not in str(exc):
            raise
        raise OutputError(f"{exc}, or give -p to create it") from None
    for path in written:
        print(path)
    return 0


def _rig(text: str):
    """``NAME=SCENE.toml`` or ``SCENE.toml`` (named after the file stem)."""
    name, sep, path = text.partition("=")
    if not sep:
        name, path = Path(text).stem, text
    if not name or not path:
        raise _Usage(f"--rig {text!r}: expected SCENE.toml or NAME=SCENE.toml")
    return Rig(name, load_scene(path))


def cmd_relight(args) -> int:
    if args.jobs < 1:
        raise _Usage("--jobs must be >= 1")
    try:
        check_number(args.scheduler_timeout, "--scheduler-timeout")
    except ValueError as exc:
        raise _Usage(str(exc)) from None
    renderer_options = _renderer_options(args)       # bad values: once, before any frame
    templates = _output_paths(args, args.output)
    if not templates:
        raise _Usage("give at least one output template: -o OUT.####.exr, --sdr OUT.####.png, "
                     "--hdr OUT.####.png or --contact-sheet OUT.####.png")
    rigs = [_rig(r) for r in args.rig]
    if renderer_options.env_probes == "all":
        # environment maps resolved once here, not in every worker
        rigs = [type(r)(r.name, resolve_environment(r.scene, max_error=args.env_error,
                                                    nonfinite=args.nonfinite).scene)
                for r in rigs]
    else:
        # each frame resolves them on its own pixels (cached on disk); a bad map fails here, once
        for r in rigs:
            check_environment_maps(r.scene, nonfinite=args.nonfinite)
    frames = FrameRange.parse(args.frames) if args.frames else None    # never listed: 1-1000000000
    plan = plan_batch(args.sequence, rigs, args.output, sdr=args.sdr, hdr=args.hdr,
                      contact_sheet=args.contact_sheet, frames=frames,
                      skip_existing=args.skip_existing)
    # Each rig's colour settings: its scene's [render] keys, overridden by the options given;
    # names, OCIO displays/views and extensions are checked before anything runs.
    base = _output_options(args).checked()          # a bad option fails once, not per rig
    options = {}
    for rig in rigs:
        try:
            options[rig.name] = check_outputs(base.for_scene(rig.scene), templates)
        except ClphongError as exc:
            msg = f"rig {rig.name!r} ({rig.scene.source}): {exc}"
            try:
                named = type(exc)(msg)
            except Exception:  # noqa: BLE001 - a subclass with another constructor
                named = ClphongError(msg)
            raise named from None
    if args.dry_run:
        for frame, rig, paths in plan.skipped:
            for path in paths.files:
                print(f"skip   frame {frame} [{rig}] {path} (exists)")
        for frame, rig, path in plan.kept:
            print(f"skip   frame {frame} [{rig}] {path} (exists; the frame's other outputs are written)")
        for job in plan.jobs:
            missing = "" if os.path.isfile(job.source) else " (input missing: will fail)"
            for rig, paths in job.outputs:
                for path in paths.files:
                    print(f"write  frame {job.frame} [{rig}] {job.source} -> {path}{missing}")
        print(f"{plan.files} file(s) to write for {plan.outputs} frame(s) x rig(s), "
              f"{len(plan.skipped)} skipped", file=sys.stderr)
        if plan.missing:
            print(plan.missing_line(), file=sys.stderr)
        return 0
    channels = _hashable_channels(parse_channel_mapping(args.channels)) if args.channels else ()
    specs = {r.name: RelighterSpec.of(renderer_options, scene=r.scene, device=args.device,
                                      kernel=args.kernel, lanes=args.lanes, channels=channels,
                                      output=options[r.name])
             for r in rigs}
    progress = not args.quiet and sys.stderr.isatty()
    result = run_batch(plan, specs, jobs=args.jobs, scheduler=args.scheduler, progress=progress,
                       scheduler_timeout=args.scheduler_timeout)
    lines = result.summary()
    for i, line in enumerate(lines):
        if i == 0 and args.quiet:
            continue
        # a failed frame's reason may quote a user's long format string: cut as error lines are
        line = cut_line(printable(line))
        print(f"clphong relight: {line}" if i == 0 else line, file=sys.stderr)
    if plan.missing:
        print(cut_line(printable(plan.missing_line())), file=sys.stderr)
    if result.interrupted:
        return 128 + int(result.interrupted)
    return 1 if result.failed or plan.missing else 0


def cmd_inspect(args) -> int:
    import json

    report = inspect_file(args.file, stats=not args.no_stats)
    # json.dumps escapes control characters itself; the table shows names read from
    # the file (channels, attributes), escaped like every other line clphong prints
    print(json.dumps(report, indent=2) if args.json else printable(format_report(report)))
    return 0


def cmd_diff(args) -> int:
    channels = [c.strip() for c in args.channels.split(",")] if args.channels else None
    try:
        result = diff_images(args.a, args.b, metric=args.metric, tol=args.tol, channels=channels,
                             heatmap=args.heatmap, floor=args.floor, peak=args.peak)
    except (ClphongError, ValueError) as exc:
        raise DiffError(str(exc)) from None     # exit 2: could not compare
    print(printable(result.line()))
    return 0 if result.match else 1


def _exr_compression(value: str) -> str:
    """``--exr-compression``: :func:`check_compression`'s value, or a one-line usage error."""
    try:
        return check_compression(value)
    except OutputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _add_color_options(r, templates: bool = False):
    """Tone mapping, colour management and output options of 'render' and 'relight'."""
    what = "TEMPLATE" if templates else "OUT"
    per = " per frame and rig (a path template, as -o)" if templates else ""
    g = r.add_argument_group("tone mapping and colour (override the scene's [render] keys"
                             + (" of each rig)" if templates else ")"))
    g.add_argument("--exposure", type=float, metavar="EV",
                   help="exposure in stops: display outputs see the scene-linear value x 2^EV")
    g.add_argument("--tonemap", metavar="OP",
                   help="operator of the SDR output without an OCIO view: "
                        + ", ".join(n + (" (clip)" if n == "none" else "") for n in OPERATORS))
    g.add_argument("--white", type=float, metavar="W",
                   help="white point of reinhard-extended (default 4) and hable (default 11.2)")
    g.add_argument("--working-space", choices=tuple(WORKING_SPACES),
                   help="colour space of albedo, lights and the EXR (default lin_rec709)")
    g.add_argument("--albedo-space", metavar="COLORSPACE",
                   help="OCIO colour space the G-buffer's albedo is in (e.g. 'sRGB Encoded Rec.709 "
                        "(sRGB)' for a texture-like albedo), converted to the working space before "
                        "shading (default: the scene's render.albedo_space, else the working space)")
    g.add_argument("--ocio-config", metavar="PATH",
                   help="OCIO config (default: $OCIO, else the built-in ocio://default)")
    g.add_argument("--display", help="OCIO display of the SDR output (as oiiotool --ociodisplay)")
    g.add_argument("--view", help="OCIO view of the SDR output (default: the display's default)")
    g.add_argument("--look", help="OCIO look(s), comma-separated")
    o = r.add_argument_group("outputs (any combination; see 'clphong displays' for names)")
    o.add_argument("--exr-type", choices=PIXEL_TYPES, default="float",
                   help="EXR pixel type (--half is the same as --exr-type half)")
    o.add_argument("--exr-compression", type=_exr_compression, default="zip", metavar="NAME[:LEVEL]",
                   # the names every writer has, without probing this one at start-up
                   help=f"EXR compression: {', '.join(EXR_BASE_COMPRESSIONS)}, and "
                        f"{', '.join(HTJ2K_COMPRESSIONS)} where OpenEXR has them (default zip); lossy: "
                        "pxr24, b44, b44a, dwaa, dwab. A level after a colon: zip:L or zips:L, L "
                        "from 1 to 9 (zlib, default 4); dwaa:N or dwab:N, N a whole number >= 1 "
                        "(default 45; larger is smaller and lossier)")
    o.add_argument("--sdr", action="append", default=[], metavar=f"{what}.png|{what}.tif|{what}.jpg",
                   help=f"display-referred SDR image{per}; repeatable")
    o.add_argument("--bits", type=int, choices=SDR_BITS, default=8, help="SDR bit depth")
    o.add_argument("--no-dither", action="store_true", help="no dither before 8-bit quantisation")
    o.add_argument("--hdr", action="append", default=[], metavar=f"{what}.png|{what}.jxl",
                   help=f"HDR Rec.2100 PQ (1000-nit view), 16-bit PNG with cICP or JPEG XL{per}; "
                        "repeatable")
    o.add_argument("--hdr-view", help="OCIO view of the HDR output on 'Rec.2100-PQ - Display' "
                                      "(default 'ACES 2.0 - HDR 1000 nits (Rec.2020)')")
    o.add_argument("--alpha", action="store_true",
                   help="give the SDR and HDR outputs a straight alpha channel (coverage); the EXR "
                        "always has A, with RGB premultiplied; JPEG cannot hold one")
    o.add_argument("--aov", metavar="NAME[,NAME]",
                   help="extra EXR layers from the same pass: diffuse (with ambient), specular, "
                        "or light-group names (only those groups; by default every group of a "
                        "scene whose lights have 'group')")
    o.add_argument("--contact-sheet", metavar=f"{what}.png",
                   help=f"PNG of the frame through every operator and view, labelled{per}")


def _output_options(args):
    """OutputOptions of the formats and colour options; None fields take each scene's [render] value."""
    return OutputOptions(
        pixel_type="half" if args.half else args.exr_type, compression=args.exr_compression,
        bits=args.bits, dither=not args.no_dither, working_space=args.working_space,
        exposure=args.exposure, tonemap=args.tonemap, white=args.white, display=args.display,
        view=args.view, look=args.look, hdr_view=args.hdr_view, ocio_config=args.ocio_config,
        alpha=args.alpha, albedo_space=args.albedo_space)


def _output_paths(args, exr):
    """OutputPaths (or, for relight, templates) of -o, --sdr, --hdr and --contact-sheet."""
    return OutputPaths(exr=exr, sdr=args.sdr, hdr=args.hdr, contact_sheet=args.contact_sheet)


def cmd_displays(args) -> int:
    print(load_config(args.ocio_config).describe())
    print("working spaces: " + ", ".join(f"{k} ({w.description})" for k, w in WORKING_SPACES.items()))
    print("tone-mapping operators: " + ", ".join(f"{k} ({op.source})" for k, op in OPERATORS.items()))
    return 0


COMMANDS = {"displays": cmd_displays, "render": cmd_render, "plan": cmd_plan, "devices": cmd_devices, "samples": cmd_samples,
            "relight": cmd_relight, "inspect": cmd_inspect, "diff": cmd_diff,
            "bench": cmd_bench}


def _unrecognized(parser: argparse.ArgumentParser, args, extras: list[str]) -> None:
    """Report unknown arguments through the subcommand's own parser (its usage line),
    with a did-you-mean from that subcommand's options; exits 2."""
    import difflib

    sub = getattr(parser, "_clphong_commands", {}).get(getattr(args, "command", None), parser)
    options = sorted(sub._option_string_actions)
    msg = "unrecognized arguments: " + " ".join(extras)
    hints = []
    for extra in extras:
        if extra.startswith("-") and len(extra) > 1:
            name = extra.partition("=")[0]
            close = difflib.get_close_matches(name, options, n=1, cutoff=0.75)
            if close:
                hints.append((name, close[0]))
    if len(hints) == 1:
        msg += f"; did you mean {hints[0][1]}?"
    elif hints:
        msg += "; did you mean " + ", ".join(f"{good} (for {bad})" for bad, good in hints) + "?"
    sub.error(msg)


#: The exit status of a process killed by SIGPIPE (128 + 13), as 'yes | head' reports.
EXIT_BROKEN_PIPE = 141


def _stdout_to_devnull() -> None:
    """After a broken pipe: point stdout at /dev/null, so that the interpreter's
    final flush does not fail again (Python docs, 'Note on SIGPIPE')."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):     # no real stdout (e.g. captured in tests)
        pass


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return the exit code.

    A closed stdout (``clphong inspect F | head -1``) ends the command quietly
    with :data:`EXIT_BROKEN_PIPE`, as a command killed by SIGPIPE.
    """
    try:
        code = _main(argv)
        sys.stdout.flush()        # here, where a broken pipe is still caught
        return code
    except BrokenPipeError:
        _stdout_to_devnull()
        return EXIT_BROKEN_PIPE


def _main(argv: list[str] | None) -> int:
    parser = _build_parser()
    args, extras = parser.parse_known_args(argv)
    if extras:
        _unrecognized(parser, args, extras)
    # One line on a terminal when a kernel really compiles (1-30 s); none when piped.
    _runtime.compile_notice = _runtime.notice_on_tty
    # and when an environment map is converted (seconds; cached on disk afterwards)
    _envmap.conversion_notice = _runtime.notice_on_tty
    import warnings

    def _one_line_warning(message, category, filename, lineno, file=None, line=None):
        # clphong's own warnings (policies applied, suspicious scenes) as one line each,
        # control bytes from a file or a library escaped, an endless one cut; one write with
        # its newline (print writes the two apart, and a frame's reader thread may warn
        # beside the main thread: two lines ran together once)
        (sys.stderr if file is None else file).write(f"clphong: warning: {clean_line(message)}\n")

    try:
        import numpy as np

        # numpy's floating-point warnings ("invalid value encountered in cast" from a
        # signalling NaN in a file) are never a user's line: clphong counts and
        # reports non-finite values itself (clphong.io.nonfinite)
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.showwarning = _one_line_warning
            with _sigterm_as_interrupt():
                return COMMANDS[args.command](args)
    except _Usage as exc:
        # exits 2, with the subcommand's usage line
        getattr(parser, "_clphong_commands", {}).get(args.command, parser).error(clean_line(exc))
    except ClphongError as exc:
        # one line: what OpenImageIO, OpenEXR or a scene file put in the message is
        # escaped (terminal control bytes) and cut to MAX_LINE characters
        print(f"clphong: error: {clean_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except MemoryError:
        # A step whose size clphong could not foresee (clphong.device.bands plans the
        # big ones); outputs are written atomically, so nothing partial is left.
        print(f"clphong: error: out of memory in '{args.command}'; free memory, or set "
              "CLPHONG_MAX_MEMORY lower so that large frames are shaded in smaller bands",
              file=sys.stderr)
        return 1
    except _Terminated as exc:
        print(f"clphong: terminated ({exc.name}); no partial output was left", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print("clphong: interrupted (SIGINT); no partial output was left", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
