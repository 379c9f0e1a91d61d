"""``clphong bench``: its options and the command (the bench itself is clphong.tools.bench)."""

from __future__ import annotations

import sys

from ..io.atomic import check_output_path, same_file
from ..model.options import DEFAULT_ENV_ERROR, ENV_PROBES, check_env_error, check_lanes
from ..tools.bench import (
    ENV_ERRORS,
    TREE_CASES,
    BenchConfig,
    check_paths,
    missing_bench_modules,
    run_bench,
    save_report,
    summary_lines,
    table,
)
from ..tools.bench import PATHS as BENCH_PATHS
from ..tools.commands import run_commands_bench
from .usage import UsageError as _Usage


def _add_bench_parser(sub):
    b = sub.add_parser(
        "bench", help="throughput against error on the fixed benchmark scenes (JSON + Pareto PNG)",
        description="Time every path and culling budget on the documented scene set "
                    "(1920x1080, N = 1 ... 65536 point lights, a wide-reach and a small-reach "
                    "scene; see clphong/bench.py), against the float64 reference and a numpy "
                    "float32 implementation measured in the same run.")
    b.add_argument("--json", default=None, metavar="REPORT.json",
                   help="JSON report (default bench.json; with --commands, commands.json)")
    b.add_argument("--plot", default=None, metavar="PARETO.png",
                   help="Pareto plot of throughput against error (matplotlib: pip install "
                        "'clphong[bench]'; default bench.png where matplotlib is installed, "
                        "else none, with a note; '' for none)")
    b.add_argument("--quick", action="store_true",
                   help="480x270, N up to 4096, budgets 0 and 1e-3, 3 repeats: about a minute")
    b.add_argument("--sizes", metavar="WxH[,WxH]", help="frame sizes (default 1920x1080)")
    b.add_argument("--lights", metavar="N[,N]", help="point-light counts of the wide scene")
    b.add_argument("--small-lights", metavar="N[,N]", help="point-light counts of the small-reach scene")
    b.add_argument("--paths", metavar="P[,P]", help="paths: " + ", ".join(BENCH_PATHS))
    b.add_argument("--budgets", metavar="EPS[,EPS]", help="culling budgets, relative to white 1.0")
    b.add_argument("--repeats", type=int, metavar="R", help="timed frames per case (median)")
    b.add_argument("--warmup", type=int, metavar="W", help="untimed frames first (default 1)")
    b.add_argument("--crop-pairs", type=float, metavar="P",
                   help="brute force runs on the top rows holding about P pixel-light pairs (default 1.5e8)")
    b.add_argument("--error-pairs", type=float, metavar="P",
                   help="float64 reference on about P/N sampled pixels (default 3e7)")
    b.add_argument("--numpy-pairs", type=float, metavar="P",
                   help="numpy float32 timed on about P pixel-light pairs (default 2e7)")
    b.add_argument("--env-error", metavar="REL[,REL]",
                   help="environment rows (the sample sky on the bench G-buffer, at each of "
                        "--env-sizes): their error targets (default "
                        f"{DEFAULT_ENV_ERROR:g},0.01, none with --sizes; '' for none)")
    b.add_argument("--env-probes", metavar="WHERE[,WHERE]",
                   help="the environment rows' paths: 'tables' (the kernels' tables where their "
                        "bound holds on the bench frame: a Phong material, Blinn-Phong has none), "
                        "'frame' (lights estimated on the bench G-buffer's own pixels, the "
                        "commands' default) and/or 'all' (lights estimated on every normal and "
                        "view) (default tables,frame,all)")
    b.add_argument("--env-sizes", metavar="WxH[,WxH]",
                   help="the environment rows' sky sizes (default 256x128,1024x512,4096x2048)")
    b.add_argument("--tree", metavar="SCENE:N:EPS[:rel][,...]",
                   help="light-tree rows: brute force, culling alone and culling with the tree's "
                        "clusters, in turns, for each scene ('wide' or 'clusters'), point-light "
                        "count and budget (':rel': --relative) (default: "
                        + ",".join(f"{c[0]}:{c[1]}:{c[2]:g}" + (":rel" if len(c) > 3 else "")
                                   for c in TREE_CASES)
                        + ", none with --sizes; '' for none)")
    b.add_argument("--device", metavar="DEV", help="OpenCL device (see 'clphong devices')")
    b.add_argument("--lanes", metavar="N[,N]",
                   help="also time the wide scene's brute-force rows at these lane widths, in "
                        "turns with the device's own (rows marked PATH@N; a width the host rule "
                        "refuses stops the run with one line)")
    b.add_argument("--commands", action="store_true",
                   help="instead, time whole commands at 1 point light: 'clphong render' EXR to EXR "
                        "against oiiotool on the same files (plus the kernel), and each display "
                        "output against OpenImageIO's own conversion and write; medians of "
                        "--repeats runs (default 5) at the first of --sizes, taken in turns "
                        "(clphong.tools.commands)")


def _csv(text, conv, what):
    try:
        return tuple(conv(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise _Usage(f"{what}: expected a comma-separated list, got {text!r}") from None


def _env_size(text: str) -> tuple[int, int]:
    """``WxH`` of --env-sizes: a 2:1 lat-long map, at least 4x2."""
    try:
        w, h = (int(v) for v in text.strip().lower().split("x"))
    except ValueError:
        raise _Usage(f"--env-sizes: {text.strip()!r} is not WxH (e.g. 1024x512)") from None
    if w != 2 * h or h < 2:
        raise _Usage(f"--env-sizes: {w}x{h} is not a 2:1 map of at least 4x2 (e.g. 1024x512)")
    return w, h


def _tree_case(text):
    kind, n, eps, *rest = text.split(":")
    if (kind.strip() not in ("wide", "clusters", "small") or int(n) <= 0 or not float(eps) >= 0
            or rest not in ([], ["rel"])):
        raise ValueError(text)
    return (kind.strip(), int(n), float(eps), *(("relative",) if rest else ()))


def _size(text):
    w, h = text.lower().split("x")
    w, h = int(w), int(h)
    if w <= 0 or h <= 0:
        raise ValueError(text)
    return (w, h)


def cmd_bench(args) -> int:
    if args.commands:
        return _bench_commands(args)
    if args.json is None:
        args.json = "bench.json"
    kw = {}
    if args.sizes is not None:
        kw["sizes"] = _csv(args.sizes, _size, "--sizes")
        if not kw["sizes"]:
            raise _Usage("--sizes: give at least one WxH")
    if args.lights is not None:
        kw["lights"] = _csv(args.lights, int, "--lights")
    if args.small_lights is not None:
        kw["small_lights"] = _csv(args.small_lights, int, "--small-lights")
    if args.paths is not None:
        kw["paths"] = _csv(args.paths, str, "--paths")
        try:
            kw["paths"] = check_paths(kw["paths"])
        except ValueError as exc:
            raise _Usage(f"--paths: {exc}") from None
    if args.budgets is not None:
        kw["budgets"] = _csv(args.budgets, float, "--budgets")
    # the environment rows by default at the bench's own size (the 1080p), or --quick's
    kw["env_errors"] = (BenchConfig.quick().env_errors if args.quick
                        else () if args.sizes else ENV_ERRORS)
    if args.env_error is not None:
        kw["env_errors"] = _csv(args.env_error, float, "--env-error")
        try:
            kw["env_errors"] = tuple(check_env_error(x) for x in kw["env_errors"])
        except ValueError as exc:
            raise _Usage(f"--env-error: {exc}") from None
    if args.env_probes is not None:
        kw["env_probes"] = _csv(args.env_probes, str, "--env-probes")
        bad = [x for x in kw["env_probes"] if x not in ("tables", *ENV_PROBES)]
        if bad or not kw["env_probes"]:
            raise _Usage(f"--env-probes: expected {' and/or '.join(('tables', *ENV_PROBES))}, not "
                         f"{args.env_probes!r}")
    if args.env_sizes:
        kw["env_sizes"] = tuple(_env_size(x) for x in args.env_sizes.split(",") if x.strip())
    kw["tree_cases"] = (BenchConfig.quick().tree_cases if args.quick
                        else () if args.sizes else TREE_CASES)
    if args.tree is not None:
        kw["tree_cases"] = _csv(args.tree, _tree_case, "--tree")
    for name in ("repeats", "warmup"):
        value = getattr(args, name)
        if value is not None:
            if value < (1 if name == "repeats" else 0):
                raise _Usage(f"--{name}: {value} is too small")
            kw[name] = value
    if any(n <= 0 for n in kw.get("lights", ()) + kw.get("small_lights", ())):
        raise _Usage("--lights/--small-lights: counts must be > 0")
    for name in ("crop_pairs", "error_pairs", "numpy_pairs"):
        value = getattr(args, name)
        if value is not None:
            if not value > 0:
                raise _Usage(f"--{name.replace('_', '-')}: expected a number > 0")
            kw[name] = value
    if args.lanes is not None:
        try:
            kw["lanes"] = (None,) + tuple(check_lanes(w) for w in _csv(args.lanes, int, "--lanes"))
        except ValueError as exc:
            raise _Usage(f"--lanes: {exc}") from None
    kw["device"] = args.device
    kw["log"] = lambda msg: print(msg, file=sys.stderr, flush=True)
    # The report's names are checked before the run (a minute or more), not after it.

    json_path, plot_path = args.json or None, args.plot or None
    # Optional dependencies before any work (a run takes minutes): an asked-for plot
    # needs matplotlib (one line, exit 2); the default plot is skipped with a note.
    missing = missing_bench_modules()
    if "matplotlib" in missing:
        if args.plot:
            raise _Usage(f"--plot {args.plot}: needs matplotlib, which is not installed: "
                         "pip install 'clphong[bench]', or --plot '' for no plot")
        if args.plot is None:
            print("clphong bench: no Pareto plot (matplotlib is not installed: "
                  "pip install 'clphong[bench]')", file=sys.stderr)
    elif args.plot is None:
        plot_path = "bench.png"
    for out in (json_path, plot_path):
        if out:
            check_output_path(out)

    if json_path and plot_path and same_file(json_path, plot_path):
        raise _Usage(f"--json and --plot name the same file {json_path!r}")
    cfg = BenchConfig.quick(**kw) if args.quick else BenchConfig(**kw)
    report = run_bench(cfg)
    save_report(report, json_path, plot_path)
    print(table(report))
    for line in summary_lines(report["summary"]):
        print(line)
    if json_path:
        print(f"report: {json_path}")
    if plot_path:
        print(f"Pareto plot: {plot_path}")
    return 0


def _bench_commands(args) -> int:
    """``bench --commands``: clphong.tools.commands' whole-command timings."""
    size = _csv(args.sizes, _size, "--sizes")[0] if args.sizes else (1920, 1080)
    if args.repeats is not None and args.repeats < 1:
        raise _Usage(f"--repeats: {args.repeats} is too small")
    run_commands_bench(size=size, runs=args.repeats or 5,
                       json_path="commands.json" if args.json is None else (args.json or None),
                       log=lambda msg: print(msg, file=sys.stderr, flush=True))
    return 0
