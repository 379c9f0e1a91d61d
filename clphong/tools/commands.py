"""Time whole ``clphong`` commands at 1920×1080, as a user runs them.

Not a test. ``clphong bench`` times the shading kernels in one process; this
times the commands around them, each run as a subprocess on files:

``python -m clphong.tools.commands render [--lights 1,16,256] [--kernels lanes,obvious] [--formats toml,csv,npz]``
    ``clphong render SCENE G.exr -o OUT.exr --stats`` per light count, kernel
    and scene format (``toml``: the lights as ``[[light]]`` tables; ``csv``,
    ``npz``: the same lights in a lights file, ``lights = "wideN.npz"``): the
    kernel time, the read stage and the in-process total that ``--stats`` prints,
    and the wall time of the whole command (interpreter start-up, imports, the
    PoCL program cache, reading, shading, writing); medians of ``--runs``,
    taken in turns (one run of each case per round) so that other tenants'
    load falls on every case alike; and each kernel's ratio to the first.

``python -m clphong.tools.commands batch [--frames 24] [--lights 64] [--jobs 1,2] [--dask 2]``
    ``clphong relight`` of a sequence of ``--frames`` frames with one rig of
    ``--lights`` point lights: frames per second from the wall time of the
    whole command, with ``--jobs N`` and with ``--scheduler`` on a local Dask
    cluster of ``--dask`` single-threaded workers (``pip install ".[dask]"``).

``python -m clphong.tools.commands environment [--runs 5] [--model phong,blinn-phong]``
    Issue 25's yardsticks: ``clphong render`` at 1920×1080 of the bench G-buffer lit by
    the 1024 × 512 sample sky with its 1° sun (:func:`clphong.tools.samples.sky_envmap`,
    default ``--env-error``) per material model, warm (its conversion on disk) and cold
    (the environment caches emptied first), against the same command with 256 point
    lights brute force (the ``wide`` scene) and with one directional light instead (the
    scene without the environment); medians of wall times, the warm cases in turns and
    the cold ones after them, and the ratios the issue sets (≤ 1.0× the 256 lights, warm
    ≤ 1.2× without it).

``python -m clphong.tools.commands whole [--runs 5] [--json R.json]`` (``clphong bench --commands``)
    Issue 14's yardsticks, at 1 point light: the wall time of ``clphong render
    G.exr -o OUT.exr`` against ``oiiotool G.exr --ch R=albedo.R,… --compression
    zip -o OUT.exr`` (the same channels out, the same compression) plus the
    kernel time (target ≤ :data:`COMMAND_TARGET` ×), with the render's
    ``--stats`` stages; and per display output (``--sdr`` PNG, ``--hdr`` PQ PNG,
    ``--hdr`` JPEG XL where OpenImageIO writes it) what it adds to that command
    against OpenImageIO's own colour conversion and write of the same frame
    (target ≤ :data:`DISPLAY_TARGET` ×). Markdown tables, and JSON with every time.

The frames are ``clphong.tools.bench``'s G-buffer and ``wide`` scene (point lights
0.5–3 units above a gently curved surface, Blinn-Phong h = 32), written as EXR
and TOML into a temporary folder that is removed at the end unless ``--keep``
(or ``--folder DIR``, an existing folder, which is kept).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..color import ocio as color
from ..core.errors import ClphongError, OutputError
from ..deliver.writers import jpegxl_available
from ..io.atomic import atomic_path, check_output_path, write_exr
from ..io.gbuffer import write_gbuffer
from ..model.light_table import write_light_table
from ..model.options import KERNELS
from .bench import bench_gbuffer, bench_scene
from .report import markdown_table
from .samples import sky_envmap

SIZE = (1920, 1080)


def scene_toml(scene) -> str:
    """``scene`` as scene-file text (its :meth:`~clphong.model.scene.Scene.to_dict`, which round-trips)."""
    import tomli_w

    def plain(x):     # numpy scalars as Python's: their str() follows numpy's print options
        if isinstance(x, dict):
            return {k: plain(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [plain(v) for v in x]
        return float(x) if isinstance(x, float) else x

    return tomli_w.dumps(plain(scene.to_dict()))


#: How a bench scene's lights are written: [[light]] tables, or a lights file.
SCENE_FORMATS = ("toml", "csv", "npz")


def write_scene(folder: Path, n: int, fmt: str = "toml") -> Path:
    """The ``wide`` scene with ``n`` point lights (and its ambient light) as
    ``wide{n}.toml`` (``fmt="toml"``: ``[[light]]`` tables) or as ``wide{n}_{fmt}.toml``
    with ``lights = "wide{n}.{fmt}"``, a lights file beside it holding every light."""
    scene = bench_scene("wide", n)
    if fmt == "toml":
        path = folder / f"wide{n}.toml"
        path.write_text(scene_toml(scene))
        return path
    if fmt not in SCENE_FORMATS:
        raise ValueError(f"scene format must be one of {', '.join(SCENE_FORMATS)}, not {fmt!r}")
    write_light_table(folder / f"wide{n}.{fmt}", scene.lights)
    path = folder / f"wide{n}_{fmt}.toml"
    text = scene_toml(dataclasses.replace(scene, lights=()))
    path.write_text(f'lights = "wide{n}.{fmt}"\n' + text.replace("light = []\n", ""))
    return path


def write_inputs(folder: Path, lights, frames: int = 1, size=SIZE) -> tuple[Path, dict[int, Path]]:
    """The bench G-buffer as ``g.0001.exr`` … and one scene per light count."""
    gb = bench_gbuffer(*size)
    first = folder / "g.0001.exr"
    write_gbuffer(first, gb.position, gb.normal, gb.albedo, coverage=gb.coverage)
    for f in range(2, frames + 1):
        shutil.copyfile(first, folder / f"g.{f:04d}.exr")
    return first, {n: write_scene(folder, n) for n in lights}


def clphong_command() -> list[str]:
    """This Python's ``clphong`` (the console script beside it, else ``-m clphong``)."""
    exe = Path(sys.executable).with_name("clphong")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "clphong"]


def _run(cmd: list[str], env=None) -> tuple[float, str]:
    """Run ``cmd``; (wall seconds, stderr). A failure is an error with its last line."""
    wall, err, _ = _run_out(cmd, env)
    return wall, err


_STATS = re.compile(r"\(kernel ([0-9.]+) s\).*total ([0-9.]+) s")


def bench_render(folder: Path, lights, kernels, runs: int, size=SIZE,
                 formats=("toml",)) -> list[dict]:
    """Time ``clphong render --stats`` per (light count, kernel, scene format); see the
    module docstring. Ratios are to the first kernel (same count and format)."""
    gbuf, _ = write_inputs(folder, [], size=size)
    scenes = {(n, f): write_scene(folder, n, f) for n in lights for f in formats}
    cases = [(n, k, f) for n in lights for f in formats for k in kernels]
    times = {c: {"kernel": [], "read": [], "total": [], "wall": []} for c in cases}
    base = clphong_command() + ["render"]
    for n, k, f in cases:                            # untimed: builds the PoCL cache
        _run(base + [str(scenes[n, f]), str(gbuf), "-o", str(folder / "o.exr"), "--kernel", k])
    for _ in range(runs):
        for n, k, f in cases:
            wall, err = _run(base + [str(scenes[n, f]), str(gbuf), "-o", str(folder / "o.exr"),
                                     "--kernel", k, "--stats"])
            m = _STATS.search(err)
            if m is None:
                raise ClphongError(f"render --stats printed no timing line: {err[-200:]!r}")
            times[(n, k, f)]["kernel"].append(float(m.group(1)))
            times[(n, k, f)]["total"].append(float(m.group(2)))
            times[(n, k, f)]["read"].append(parse_stats(err).get("read", math.nan))
            times[(n, k, f)]["wall"].append(wall)
    rows = []
    for n, k, f in cases:
        med = {key: statistics.median(v) for key, v in times[(n, k, f)].items()}
        first = {key: statistics.median(v) for key, v in times[(n, kernels[0], f)].items()}
        rows.append(dict(lights=n, kernel=k, format=f, **{f"{key}_s": v for key, v in med.items()},
                         **{f"{key}_ratio": med[key] / first[key] if first[key] > 0 else math.nan
                            for key in med}))
    return rows


def render_table(rows: list[dict]) -> str:
    return markdown_table(
        ["point lights", "kernel", "kernel ms", "×", "in-process total ms", "×",
         "whole command ms", "×"],
        [[r["lights"] if r.get("format", "toml") == "toml" else f"{r['lights']} ({r['format']})",
          r["kernel"], f"{1e3 * r['kernel_s']:.1f}", f"{r['kernel_ratio']:.1f}",
          f"{1e3 * r['total_s']:.0f}", f"{r['total_ratio']:.2f}", f"{1e3 * r['wall_s']:.0f}",
          f"{r['wall_ratio']:.2f}"] for r in rows])


def bench_batch(folder: Path, frames: int, lights: int, jobs, dask_workers: int,
                size=SIZE) -> list[dict]:
    """Frames per second of ``clphong relight`` per ``--jobs`` and on local Dask."""
    _, scenes = write_inputs(folder, [lights], frames, size)
    base = clphong_command() + ["relight", str(folder / "g.####.exr"), "--rig", str(scenes[lights]),
                                "--quiet"]
    runs = [(f"--jobs {j}", ["--jobs", str(j)]) for j in jobs]
    cluster = None
    if dask_workers:
        try:
            from distributed import LocalCluster
        except ImportError:
            raise ClphongError("--dask needs Dask: pip install 'clphong[dask]' (or --dask 0)") from None
        # Each worker's PoCL gets its share of the cores, as --jobs gives its workers.
        os.environ["POCL_CPU_MAX_CU_NUM"] = str(max(1, (os.cpu_count() or 1) // dask_workers))
        cluster = LocalCluster(n_workers=dask_workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        runs.append((f"Dask, {dask_workers} local workers", ["--scheduler", cluster.scheduler_address]))
    rows = []
    try:
        for i, (name, extra) in enumerate(runs):
            out = folder / f"out{i}"
            _run(base + ["-o", str(out / "{rig}.####.exr"), "--frames", "1-2"] + extra)  # warm
            shutil.rmtree(out)
            wall, _ = _run(base + ["-o", str(out / "{rig}.####.exr")] + extra)
            written = len(list(out.glob("*.exr")))
            if written != frames:
                raise ClphongError(f"{name}: {written} of {frames} frames written")
            rows.append(dict(run=name, frames=frames, lights=lights, seconds=wall,
                             frames_per_s=frames / wall))
    finally:
        if cluster is not None:
            cluster.close()
    return rows


def batch_table(rows: list[dict]) -> str:
    return markdown_table(["run", "frames", "point lights", "seconds", "frames/s"],
                          [[r["run"], r["frames"], r["lights"], f"{r['seconds']:.1f}",
                            f"{r['frames_per_s']:.2f}"] for r in rows])


# --------------------------------------------------------------------------- whole command vs OpenImageIO

#: Issue 14's targets: ``clphong render`` (1 light, EXR to EXR) within this factor of
#: ``oiiotool`` on the same files plus the kernel; each display output within
#: :data:`DISPLAY_TARGET` of OpenImageIO's own colour conversion and write.
COMMAND_TARGET = 1.3
DISPLAY_TARGET = 1.2
#: The render's EXR: its default compression, and the channels it writes, taken by
#: oiiotool from the bench G-buffer (the albedo as R, G, B; its coverage as A).
COMPRESSION = "zip"
OIIOTOOL_CHANNELS = "R=albedo.R,G=albedo.G,B=albedo.B,A=A"

#: OpenImageIO's own display output of a frame, timed in a fresh process (so its
#: OCIO config is loaded as in a clphong run); the EXR is read before the clock
#: starts, as clphong's frame is in memory when its display output begins.
_OIIO_DISPLAY = r"""
import json, sys, time
import OpenImageIO as oiio
a = json.loads(sys.argv[1])
src = oiio.ImageBuf(a["frame"])
src.read(force=True)
rgb = oiio.ImageBufAlgo.channels(src, (0, 1, 2))
t0 = time.perf_counter()
if a["view"]:
    out = oiio.ImageBufAlgo.ociodisplay(rgb, a["display"], a["view"], fromspace=a["src"],
                                        unpremult=False, colorconfig=a["config"])
else:
    out = oiio.ImageBufAlgo.colorconvert(rgb, a["src"], a["dst"], unpremult=False,
                                         colorconfig=a["config"])
spec = out.specmod()
spec.attribute("CICP", oiio.TypeDesc("int[4]"), tuple(a["cicp"]))
if a["dither"]:
    spec.attribute("oiio:dither", 1)
ok = out.write(a["out"], oiio.UINT8 if a["bits"] == 8 else oiio.UINT16)
seconds = time.perf_counter() - t0
print(json.dumps({"seconds": seconds, "ok": bool(ok), "error": out.geterror()}))
"""


def oiiotool_command() -> str:
    """This Python's ``oiiotool`` (beside it, as the OpenImageIO wheel installs it), else PATH's."""
    exe = Path(sys.executable).with_name("oiiotool")
    found = str(exe) if exe.exists() else shutil.which("oiiotool")
    if found is None:
        raise ClphongError("oiiotool not found beside this Python or on PATH (pip install OpenImageIO)")
    return found


_FIELD = re.compile(r"([a-z_]+) ([0-9.]+) s\b")


def parse_stats(err: str) -> dict[str, float]:
    """The seconds of ``clphong render --stats``'s timing line by name: read, setup,
    shade, kernel, write, each output kind written (exr, sdr, hdr, …) and total."""
    for line in reversed(err.splitlines()):
        fields = {k: float(v) for k, v in _FIELD.findall(line)}
        if "total" in fields and "kernel" in fields:
            return fields
    raise ClphongError(f"render --stats printed no timing line: {err[-200:]!r}")


def display_cases(folder: Path) -> list[dict]:
    """The display outputs timed: (name, clphong option and file, OpenImageIO's equivalent)."""
    cfg = color.load_config()
    src = cfg.space_name(color.WORKING_SPACES["lin_rec709"])
    hdr = dict(view=color.HDR_VIEW, display=color.HDR_DISPLAY, src=src, dst=None,
               cicp=list(color.PQ_CICP), bits=16, dither=False, config=cfg.path)
    cases = [
        # The scene's tone mapping ("none"): the sRGB encoding of the working space, as
        # OpenImageIO's colorconvert to sRGB Encoded Rec.709; 8 bits, dithered, with cICP.
        dict(name="SDR PNG 8-bit (--sdr, sRGB encoding by the display kernel)", option="--sdr", file="sdr.png",
             view=None, display=None, src=src, dst=cfg.oiio.resolve("srgb_rec709_scene"),
             cicp=list(color.SRGB_CICP), bits=8, dither=True, config=cfg.path),
        dict(name=f"PQ PNG 16-bit (--hdr, {color.HDR_VIEW})", option="--hdr", file="pq.png", **hdr),
    ]
    if jpegxl_available():
        cases.append(dict(name=f"PQ JPEG XL (--hdr, {color.HDR_VIEW})", option="--hdr",
                          file="pq.jxl", **hdr))
    for c in cases:
        c["path"] = str(folder / c["file"])
        c["oiio_path"] = str(folder / f"oiio-{c['file']}")
    return cases


def _oiio_display_seconds(case: dict, frame: Path, env=None) -> float:
    import json

    args = {k: case[k] for k in ("view", "display", "src", "dst", "cicp", "bits", "dither", "config")}
    args.update(frame=str(frame), out=case["oiio_path"])
    _, _, out = _run_out([sys.executable, "-c", _OIIO_DISPLAY, json.dumps(args)], env)
    got = json.loads(out.strip().splitlines()[-1])
    if not got["ok"]:
        raise ClphongError(f"OpenImageIO's {case['file']} failed: {got['error'] or 'no message'}")
    return float(got["seconds"])


def _run_out(cmd: list[str], env=None) -> tuple[float, str, str]:
    """:func:`_run`, with stdout too: (wall seconds, stderr, stdout)."""
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise ClphongError(f"{' '.join(cmd[:3])[:80]} … failed (exit {p.returncode}): {last}")
    return wall, p.stderr, p.stdout


def python_env(folder: Path) -> dict:
    """The environment of the timed Python processes: modules compiled once and cached
    (in ``folder``, not beside the sources), as an installed package has them, even
    where PYTHONDONTWRITEBYTECODE is set (a source checkout without ``__pycache__``
    would compile clphong's ~50 modules in every run, 0.1-0.15 s)."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = str(folder / "pycache")
    return env


def _median(values) -> float:
    return statistics.median(values) if values else math.nan


def _timed(cmd: list[str], env=None) -> tuple[float, float, str]:
    """:func:`_run`, with the CPU time the command took too (user + system, its threads
    together): (wall seconds, CPU seconds, stderr). CPU time suffers less than wall time
    from other tenants' load on a shared machine."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall, err = _run(cmd, env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, err


def bench_commands(folder: Path, runs: int, size=SIZE, displays: bool = True,
                   log=None) -> dict:
    """Whole ``clphong render`` against ``oiiotool``, and each display output against
    OpenImageIO's own; every case once per round, ``runs`` rounds (after one untimed
    round), medians. See :func:`commands_tables` for what the figures are."""
    gbuf, scenes = write_inputs(folder, [1], size=size)
    tool = oiiotool_command()
    exr = folder / "render.exr"
    render = clphong_command() + ["render", str(scenes[1]), str(gbuf), "-o", str(exr),
                                  "--exr-compression", COMPRESSION, "--stats"]
    env = python_env(folder)
    commands = {"clphong": (render, env)}
    commands["oiiotool"] = ([tool, str(gbuf), "--ch", OIIOTOOL_CHANNELS, "-d", "float",
                             "--compression", COMPRESSION, "-o", str(folder / "oiiotool.exr")], None)
    # the same command on clphong's own output: its pixels, so its compression work
    commands["oiiotool_rewrite"] = ([tool, str(exr), "-d", "float", "--compression", COMPRESSION,
                                     "-o", str(folder / "rewritten.exr")], None)
    cases = display_cases(folder) if displays else []
    times = {k: {"wall": [], "cpu": []} for k in commands}
    stats = []
    shown = {c["file"]: {"wall": [], "stats": [], "added": [], "oiio": []} for c in cases}
    for r in range(runs + 1):                       # round 0: untimed (PoCL cache, page cache)
        if log:
            log(f"round {r} of {runs}" + (" (untimed)" if r == 0 else ""))
        for name, (cmd, cmd_env) in commands.items():
            wall, cpu, err = _timed(cmd, cmd_env)
            if name == "clphong":
                base = parse_stats(err)
            if r:
                times[name]["wall"].append(wall)
                times[name]["cpu"].append(cpu)
                if name == "clphong":
                    stats.append(base)
        for c in cases:
            wall, err = _run(render + [c["option"], c["path"]], env)
            with_display = parse_stats(err)
            oiio_s = _oiio_display_seconds(c, exr, env)
            if r:
                s = shown[c["file"]]
                s["wall"].append(wall)
                s["stats"].append(with_display)
                # what the output adds to the same command, in-process (paired by round)
                s["added"].append(with_display["total"] - base["total"])
                s["oiio"].append(oiio_s)
    med = {(k, m): _median(v) for k, t in times.items() for m, v in t.items()}
    stage = {k: _median([s.get(k, math.nan) for s in stats])
             for k in ("read", "setup", "shade", "kernel", "write", "total")}
    command = dict(
        **{f"{k}_{m}_s": med.get((k, m), math.nan)
           for k in ("clphong", "oiiotool", "oiiotool_rewrite")
           for m in ("wall", "cpu")},
        **{f"{k}_s": v for k, v in stage.items()},
        ratio=med["clphong", "wall"] / (med["oiiotool", "wall"] + stage["kernel"]),
        cpu_ratio=med["clphong", "cpu"] / (med["oiiotool", "cpu"] + stage["kernel"]),
        target=COMMAND_TARGET,
        **{f"{k}_command": " ".join(cmd) for k, (cmd, _) in commands.items()},
        times=times, stats=stats)
    rows = []
    for c in cases:
        s = shown[c["file"]]
        kind = "hdr" if c["option"] == "--hdr" else "sdr"
        added, oiio_s = _median(s["added"]), _median(s["oiio"])
        rows.append(dict(output=c["name"], file=c["file"], added_s=added,
                         write_s=_median([x.get(kind, math.nan) for x in s["stats"]]),
                         shade_extra_s=_median([x["shade"] for x in s["stats"]]) - stage["shade"],
                         oiio_s=oiio_s, ratio=added / oiio_s if oiio_s > 0 else math.nan,
                         target=DISPLAY_TARGET, wall_s=_median(s["wall"]),
                         times={k: v for k, v in s.items() if k != "stats"}))
    return dict(size=list(size), runs=runs, command=command, displays=rows)


def commands_tables(report: dict) -> str:
    """:func:`bench_commands`'s report as two Markdown tables."""
    w, h = report["size"]
    c = report["command"]
    def ms(s):
        return f"{1e3 * s:.0f}" if math.isfinite(s) else "n/a"

    per = c["oiiotool_wall_s"] + c["kernel_s"], c["oiiotool_cpu_s"] + c["kernel_s"]

    def row(name, key, stages=False, target=""):
        wall, cpu = c[f"{key}_wall_s"], c[f"{key}_cpu_s"]
        cells = ([ms(c["read_s"]), ms(c["setup_s"]), ms(c["shade_s"]), f"{1e3 * c['kernel_s']:.1f}",
                  ms(c["write_s"])] if stages else [""] * 5)
        return [name, ms(wall), ms(cpu), *cells, f"{wall / per[0]:.2f}", f"{cpu / per[1]:.2f}", target]

    rows = [row("clphong render --stats", "clphong", True, f"≤ {c['target']}"),
            row(f"oiiotool G.exr --ch {OIIOTOOL_CHANNELS} -o OUT.exr", "oiiotool"),
            row("oiiotool OUT.exr -o COPY.exr (clphong's pixels)", "oiiotool_rewrite")]
    lines = [(f"Whole command at {w}x{h}, 1 point light, EXR to EXR ({COMPRESSION}, float, "
              f"R,G,B,A); median of {report['runs']} runs taken in turns; wall and CPU (user + "
              "system) time of each command, clphong's stages from its --stats; × = ÷ (oiiotool "
              "+ kernel); clphong's Python bytecode cached, as installed"),
             "",
             markdown_table(["command", "wall ms", "CPU ms", "read", "setup", "shade", "kernel",
                             "write", "× wall", "× CPU", "target"], rows)]
    if report["displays"]:
        lines += ["", ("Display outputs: what each adds to that command (in-process total, "
                       "paired by round) against OpenImageIO's colour conversion and write of the "
                       "same frame (ImageBufAlgo.colorconvert/ociodisplay + ImageBuf.write, in a "
                       "fresh process, the EXR read before the clock)"), "",
                  markdown_table(
                      ["output", "clphong adds ms", "of which writing (--stats)", "shading extra",
                       "OpenImageIO ms", "×", "target"],
                      [[r["output"], ms(r["added_s"]), ms(r["write_s"]), ms(r["shade_extra_s"]),
                        ms(r["oiio_s"]), f"{r['ratio']:.2f}", f"≤ {r['target']}"]
                       for r in report["displays"]])]
    return "\n".join(lines)


def run_commands_bench(*, size=SIZE, runs: int = 5, json_path=None, folder=None, keep: bool = False,
                       displays: bool = True, log=None) -> dict:
    """:func:`bench_commands` in ``folder`` (else a temporary one), the tables printed
    and the report written to ``json_path`` (atomically) when given."""
    import json

    if json_path:
        check_output_path(json_path)                 # before minutes of timing, not after
    report = in_folder(folder, keep, lambda f: bench_commands(f, runs, size, displays, log))
    if json_path:
        with atomic_path(json_path) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=1))
    print(commands_tables(report))
    if json_path:
        print(f"report: {json_path}")
    return report


def in_folder(folder_arg, keep: bool, fn):
    """Call ``fn(folder)``: ``folder_arg`` (an existing folder, kept) or a temporary
    one, removed at the end unless ``keep``."""
    if folder_arg is not None:
        folder = Path(folder_arg)
        if not folder.is_dir():
            what = "is not a folder" if folder.exists() else "does not exist; create it first"
            raise OutputError(f"--folder {folder_arg}: {what}")
        return fn(folder)
    folder = Path(tempfile.mkdtemp(prefix="clphong-bench-"))
    try:
        return fn(folder)
    finally:
        if not keep:
            shutil.rmtree(folder, ignore_errors=True)


def bench_environment(folder: Path, runs: int, models=("phong", "blinn-phong"),
                      size=SIZE, log=None) -> list[dict]:
    """Issue 25's whole commands (module docstring): one row per case, medians of wall
    seconds taken in turns, ratios to the 256 point lights and to the scene without the
    environment of the same model."""
    gbuf, _ = write_inputs(folder, [], size=size)
    write_exr(folder / "sky.exr", sky_envmap(1024, 512))
    wide = bench_scene("wide", 256)
    cases = {}
    for model in models:
        material = dataclasses.replace(wide.material, model=model)
        base = dataclasses.replace(wide, material=material, lights=())
        sky = scene_toml(base).replace("light = []\n", "") + (
            '[[light]]\ntype = "environment"\nfile = "sky.exr"\n')
        (folder / f"sky_{model}.toml").write_text(sky)
        one = scene_toml(dataclasses.replace(base, lights=(
            dataclasses.replace(wide.lights[0], type="directional", direction=(0.0, -1.0, -1.0),
                                intensity=1.0),)))
        (folder / f"one_{model}.toml").write_text(one)
        (folder / f"wide256_{model}.toml").write_text(scene_toml(
            dataclasses.replace(wide, material=material)))
        cases[f"sky {model} warm"] = f"sky_{model}.toml"
        cases[f"sky {model} cold"] = f"sky_{model}.toml"
        cases[f"256 point lights {model}"] = f"wide256_{model}.toml"
        cases[f"one directional light {model}"] = f"one_{model}.toml"
    env = python_env(folder)
    env["CLPHONG_CACHE_DIR"] = str(folder / "cache")
    base_cmd = clphong_command() + ["render"]

    def run(name):
        if name.endswith(" cold"):
            for sub in ("environment", "envtables"):
                shutil.rmtree(folder / "cache" / sub, ignore_errors=True)
        return _run(base_cmd + [str(folder / cases[name]), str(gbuf), "-o",
                                str(folder / "o.exr"), "--stats"], env)

    for name in cases:                    # untimed: compiles, converts, fills the caches
        run(name)
    times = {name: [] for name in cases}
    # the warm cases in turns; the cold ones after them (emptying the caches and converting
    # again disturbs the machine's memory for the next command), each once per round
    warm = [n for n in cases if not n.endswith(" cold")]
    for k in range(runs):
        for name in warm:
            times[name].append(run(name)[0])
        if log is not None:
            log(f"round {k + 1}/{runs}")
    for k in range(runs):
        for name in cases:
            if name.endswith(" cold"):
                times[name].append(run(name)[0])
                run(name.replace(" cold", " warm"))       # untimed: the next starts as warm
    rows = []
    for name in cases:
        model = next(m for m in models if name.endswith(m) or f" {m} " in name)
        med = statistics.median(times[name])
        p256 = statistics.median(times[f"256 point lights {model}"])
        one = statistics.median(times[f"one directional light {model}"])
        rows.append({"case": name, "model": model, "wall_s": med, "times_s": times[name],
                     "ratio_256_point": med / p256, "ratio_without": med / one})
    return rows


def environment_table(rows: list[dict]) -> str:
    return markdown_table(["command", "wall s (median)", "/ 256 point lights",
                           "/ without the environment"],
                          [[r["case"], f"{r['wall_s']:.2f}", f"{r['ratio_256_point']:.2f}",
                            f"{r['ratio_without']:.2f}"] for r in rows])


def _ints(text: str) -> list[int]:
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated whole numbers, not {text!r}")
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected numbers >= 1, not {text!r}")
    return values


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"([1-9][0-9]*)x([1-9][0-9]*)", text)
    if m is None:
        raise argparse.ArgumentTypeError(f"expected WxH, e.g. 1920x1080, not {text!r}")
    return int(m.group(1)), int(m.group(2))


def main(argv=None) -> int:
    """Run a timing; user errors are one line on stderr (exit 1; usage 2)."""
    p = argparse.ArgumentParser(prog="python -m clphong.tools.commands",
                                description="Time whole clphong commands at 1920x1080.")
    sub = p.add_subparsers(dest="what", required=True)
    r = sub.add_parser("render", help="clphong render: kernel, in-process and whole-command time")
    r.add_argument("--lights", type=_ints, default=[1, 16, 256], help="point-light counts")
    r.add_argument("--kernels", default=",".join(KERNELS),
                   help="kernels to compare (the first is the ratios' base)")
    r.add_argument("--runs", type=int, default=3, help="timed runs per case (median; default 3)")
    r.add_argument("--formats", default="toml",
                   help="how the lights are given: toml ([[light]] tables), csv, npz (lights "
                        "files); comma-separated (default toml)")
    b = sub.add_parser("batch", help="clphong relight: frames per second")
    b.add_argument("--frames", type=int, default=24, help="frames in the sequence (default 24)")
    b.add_argument("--lights", type=int, default=64, help="point lights in the rig (default 64)")
    b.add_argument("--jobs", type=_ints, default=[1, 2], help="--jobs values (default 1,2)")
    b.add_argument("--dask", type=int, default=2,
                   help="local Dask workers for a --scheduler run (0: none; default 2)")
    w = sub.add_parser("whole", help="clphong render against oiiotool, and each display output "
                                     "against OpenImageIO's own (as clphong bench --commands)")
    w.add_argument("--runs", type=int, default=5, help="timed rounds (median; default 5)")
    w.add_argument("--json", default=None, metavar="REPORT.json", help="also write the report as JSON")
    w.add_argument("--no-displays", action="store_true", help="only the EXR-to-EXR command")
    e = sub.add_parser("environment", help="issue 25: a sky against 256 point lights and "
                                           "against no environment, whole commands")
    e.add_argument("--runs", type=int, default=5, help="timed rounds (median; default 5)")
    e.add_argument("--models", default="phong,blinn-phong",
                   help="material models, comma-separated (default phong,blinn-phong)")
    for q in (r, b, w, e):
        q.add_argument("--size", type=_size, default=SIZE, help="WxH (default 1920x1080)")
        q.add_argument("--folder", default=None, help="existing folder for the files (kept)")
        q.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = p.parse_args(argv)
    try:
        if args.what == "render":
            kernels = [k for k in args.kernels.split(",") if k]
            formats = [f for f in args.formats.split(",") if f]
            if args.runs < 1 or not kernels or set(kernels) - set(KERNELS):
                p.error(f"--runs must be >= 1 and --kernels a list of {', '.join(KERNELS)}")
            if not formats or set(formats) - set(SCENE_FORMATS):
                p.error(f"--formats must be a list of {', '.join(SCENE_FORMATS)}")
            rows = in_folder(args.folder, args.keep,
                             lambda f: bench_render(f, args.lights, kernels, args.runs, args.size,
                                                    formats))
            print(f"clphong render at {args.size[0]}x{args.size[1]}, median of {args.runs} runs; "
                  f"× = ratio to {kernels[0]}")
            print(render_table(rows))
        elif args.what == "environment":
            models = [m for m in args.models.split(",") if m]
            if args.runs < 1 or not models or set(models) - {"phong", "blinn-phong"}:
                p.error("--runs must be >= 1 and --models a list of phong, blinn-phong")
            rows = in_folder(args.folder, args.keep,
                             lambda f: bench_environment(
                                 f, args.runs, models, args.size,
                                 log=lambda msg: print(msg, file=sys.stderr, flush=True)))
            print(f"clphong render at {args.size[0]}x{args.size[1]}, the 1024x512 sample sky, "
                  f"median of {args.runs} rounds in turns")
            print(environment_table(rows))
        elif args.what == "whole":
            if args.runs < 1:
                p.error("--runs must be >= 1")
            run_commands_bench(size=args.size, runs=args.runs, json_path=args.json,
                               folder=args.folder, keep=args.keep, displays=not args.no_displays,
                               log=lambda msg: print(msg, file=sys.stderr, flush=True))
        else:
            if args.frames < 2 or args.lights < 1 or args.dask < 0:
                p.error("--frames must be >= 2, --lights >= 1, --dask >= 0")
            rows = in_folder(args.folder, args.keep,
                             lambda f: bench_batch(f, args.frames, args.lights, args.jobs, args.dask,
                                                 args.size))
            print(f"clphong relight at {args.size[0]}x{args.size[1]}, {args.frames} frames, one rig "
                  f"of {args.lights} point lights (wall time of the whole command)")
            print(batch_table(rows))
    except ClphongError as exc:
        print(f"clphong: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return exc.exit_code
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
