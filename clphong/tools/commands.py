"""Time whole ``clphong`` commands at 1920×1080, as a user runs them.

Not a test. ``clphong bench`` times the shading kernels in one process; this
times the commands around them, each run as a subprocess on files:

``python -m clphong.tools.commands render [--lights 1,16,256] [--kernels lanes,obvious]``
    ``clphong render SCENE G.exr -o OUT.exr --stats`` per light count and
    kernel: the kernel time and the in-process total that ``--stats`` prints,
    and the wall time of the whole command (interpreter start-up, imports, the
    PoCL program cache, reading, shading, writing); medians of ``--runs``,
    taken in turns (one run of each case per round) so that other tenants'
    load falls on every case alike; and each kernel's ratio to the first.

``python -m clphong.tools.commands batch [--frames 24] [--lights 64] [--jobs 1,2] [--dask 2]``
    ``clphong relight`` of a sequence of ``--frames`` frames with one rig of
    ``--lights`` point lights: frames per second from the wall time of the
    whole command, with ``--jobs N`` and with ``--scheduler`` on a local Dask
    cluster of ``--dask`` single-threaded workers (``pip install ".[dask]"``).

The frames are ``clphong.tools.bench``'s G-buffer and ``wide`` scene (point lights
0.5–3 units above a gently curved surface, Blinn-Phong h = 32), written as EXR
and TOML into a temporary folder that is removed at the end unless ``--keep``
(or ``--folder DIR``, an existing folder, which is kept).
"""

from __future__ import annotations

import argparse
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

from ..core.errors import ClphongError, OutputError
from ..io.gbuffer import write_gbuffer
from ..model.options import KERNELS
from .bench import bench_gbuffer, bench_scene
from .report import markdown_table

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


def write_inputs(folder: Path, lights, frames: int = 1, size=SIZE) -> tuple[Path, dict[int, Path]]:
    """The bench G-buffer as ``g.0001.exr`` … and one scene per light count."""
    gb = bench_gbuffer(*size)
    first = folder / "g.0001.exr"
    write_gbuffer(first, gb.position, gb.normal, gb.albedo, coverage=gb.coverage)
    for f in range(2, frames + 1):
        shutil.copyfile(first, folder / f"g.{f:04d}.exr")
    scenes = {}
    for n in lights:
        scenes[n] = folder / f"wide{n}.toml"
        scenes[n].write_text(scene_toml(bench_scene("wide", n)))
    return first, scenes


def clphong_command() -> list[str]:
    """This Python's ``clphong`` (the console script beside it, else ``-m clphong``)."""
    exe = Path(sys.executable).with_name("clphong")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "clphong"]


def _run(cmd: list[str], env=None) -> tuple[float, str]:
    """Run ``cmd``; (wall seconds, stderr). A failure is an error with its last line."""
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise ClphongError(f"{' '.join(cmd[1:3])} … failed (exit {p.returncode}): {last}")
    return wall, p.stderr


_STATS = re.compile(r"\(kernel ([0-9.]+) s\).*total ([0-9.]+) s")


def bench_render(folder: Path, lights, kernels, runs: int, size=SIZE) -> list[dict]:
    """Time ``clphong render --stats`` per (light count, kernel); see the module docstring."""
    gbuf, scenes = write_inputs(folder, lights, size=size)
    cases = [(n, k) for n in lights for k in kernels]
    times = {c: {"kernel": [], "total": [], "wall": []} for c in cases}
    base = clphong_command() + ["render"]
    for c in cases:                                  # untimed: builds the PoCL cache
        _run(base + [str(scenes[c[0]]), str(gbuf), "-o", str(folder / "o.exr"), "--kernel", c[1]])
    for _ in range(runs):
        for n, k in cases:
            wall, err = _run(base + [str(scenes[n]), str(gbuf), "-o", str(folder / "o.exr"),
                                     "--kernel", k, "--stats"])
            m = _STATS.search(err)
            if m is None:
                raise ClphongError(f"render --stats printed no timing line: {err[-200:]!r}")
            times[(n, k)]["kernel"].append(float(m.group(1)))
            times[(n, k)]["total"].append(float(m.group(2)))
            times[(n, k)]["wall"].append(wall)
    rows = []
    for n, k in cases:
        med = {key: statistics.median(v) for key, v in times[(n, k)].items()}
        first = {key: statistics.median(v) for key, v in times[(n, kernels[0])].items()}
        rows.append(dict(lights=n, kernel=k, **{f"{key}_s": v for key, v in med.items()},
                         **{f"{key}_ratio": med[key] / first[key] if first[key] > 0 else math.nan
                            for key in med}))
    return rows


def render_table(rows: list[dict]) -> str:
    return markdown_table(
        ["point lights", "kernel", "kernel ms", "×", "in-process total ms", "×",
         "whole command ms", "×"],
        [[r["lights"], r["kernel"], f"{1e3 * r['kernel_s']:.1f}", f"{r['kernel_ratio']:.1f}",
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
    b = sub.add_parser("batch", help="clphong relight: frames per second")
    b.add_argument("--frames", type=int, default=24, help="frames in the sequence (default 24)")
    b.add_argument("--lights", type=int, default=64, help="point lights in the rig (default 64)")
    b.add_argument("--jobs", type=_ints, default=[1, 2], help="--jobs values (default 1,2)")
    b.add_argument("--dask", type=int, default=2,
                   help="local Dask workers for a --scheduler run (0: none; default 2)")
    for q in (r, b):
        q.add_argument("--size", type=_size, default=SIZE, help="WxH (default 1920x1080)")
        q.add_argument("--folder", default=None, help="existing folder for the files (kept)")
        q.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = p.parse_args(argv)
    try:
        if args.what == "render":
            kernels = [k for k in args.kernels.split(",") if k]
            if args.runs < 1 or not kernels or set(kernels) - set(KERNELS):
                p.error(f"--runs must be >= 1 and --kernels a list of {', '.join(KERNELS)}")
            rows = in_folder(args.folder, args.keep,
                             lambda f: bench_render(f, args.lights, kernels, args.runs, args.size))
            print(f"clphong render at {args.size[0]}x{args.size[1]}, median of {args.runs} runs; "
                  f"× = ratio to {kernels[0]}")
            print(render_table(rows))
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
