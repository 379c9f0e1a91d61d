"""The bench's environment-light and light-tree rows (clphong.tools.bench runs them)."""

from __future__ import annotations

import dataclasses
import math
import statistics
import time

import numpy as np

from ..device.culling import TILE, super_tiles
from ..device.envprobe import DeviceProbeShader
from ..device.renderer import Renderer, prepare_frame
from ..io.envmap import FrameSource, directional_lights, frame_pairs
from ..model.environment import (
    DEFAULT_ENV_ERROR,
    FLOOR,
    LightTree,
    environment_lights,
    texel_lights,
)
from ..model.light_tree import build_light_tree
from ..model.env_table import TablesUnfit, environment_tables
from ..model.scene import Scene
from ..model.scene import directional_lights as sun_lights
from ..reference import environment as env_reference
from . import samples
from .bench_scenes import (
    _crop_rows,
    _time_slots,
    bench_gbuffer,
    bench_scene,
    make_oracle,
    sample_pixels,
    shaded_pixels,
    sub_gbuffer,
    time_frame,
)

#: The environment rows of ``clphong bench`` (``--env-error``): the issue's 1e-3, and 1e-2.
ENV_ERRORS = (DEFAULT_ENV_ERROR, 1e-2)


def environment_scene(lights=()) -> Scene:
    """The bench camera and material with ``lights`` only (no ambient light)."""
    base = bench_scene("wide", 1)
    return Scene(camera=base.camera, material=base.material, lights=tuple(lights),
                 source="bench:environment")


@dataclasses.dataclass(frozen=True)
class TableRow:
    """An environment's tables as a bench row's conversion (the fields the rows read)."""

    tables: object
    count: int
    texels: int
    estimated_error: float
    met: bool
    probes: int
    seconds: float

    @classmethod
    def of(cls, tables) -> "TableRow":
        return cls(tables=tables, count=tables.sun_count, texels=0,
                   estimated_error=tables.estimate, met=tables.estimate <= tables.max_error,
                   probes=0, seconds=tables.seconds)


def _first_n_for(target, exact, D_part, S_part, tree, base_lights):
    """The fewest leaves of ``tree`` within ``target`` on these pixels (geometric steps
    of ~6 %), with the terms' rows of each count from ``base_lights(n)``."""
    def err(n):
        d, sp = base_lights(n)
        return _env_rel(d + sp, exact)
    lo, hi = 0, 16
    while err(hi) > target:
        if hi >= tree.height * tree.width:
            return None
        lo, hi = hi, min(2 * hi, tree.height * tree.width)
    while lo and hi > lo * 1.0625 and hi - lo > 1:
        mid = int(round(math.sqrt(lo * hi)))
        lo, hi = (lo, mid) if err(mid) <= target else (mid, hi)
    return hi


def _env_rel(value, exact):
    """max |value − exact|/exact over the channels ≥ FLOOR (1e-3) of the sample's maximum."""
    top = float(exact.max(initial=0.0))
    big = exact >= FLOOR * top
    return float((np.abs(value - exact)[big] / exact[big]).max(initial=0.0))


#: Texel-pixel pairs of the exact sum an environment row computes at most: its pixel sample
#: shrinks for a large map (4096 x 2048: 238 pixels, about 40 s in numpy on two cores).
ENV_EXACT_PAIRS = 2e9


def run_environment(cfg, full, runs, log, env_size) -> list[dict]:
    """The environment rows of the report for one map size (width, height); ``cfg`` a
    :class:`clphong.tools.bench.BenchConfig`."""
    H, W = full.shape
    mw, mh = env_size
    L = samples.sky_envmap(mw, mh)
    base = environment_scene()
    material = base.material
    # the exact texel sum on a seeded pixel sample, each term apart (computed once)
    idx = sample_pixels(full, min(cfg.env_pixels, max(100, int(ENV_EXACT_PAIRS / (mw * mh)))))
    sub = sub_gbuffer(full, idx)
    t0 = time.perf_counter()
    l_all, E_all = texel_lights(L)
    keep = E_all.max(axis=1) > 0
    exact_terms = env_reference.texel_terms(base, sub, l_all[keep], E_all[keep])
    t_exact = time.perf_counter() - t0
    log(f"environment: exact texel sum of {mw}x{mh} texels on {len(idx)} pixels in {t_exact:.1f} s")
    tree = LightTree(*(a.reshape(mh, mw, 3) for a in (E_all, l_all)))

    def terms_of(n):
        return env_reference.texel_terms(base, sub, *tree.lights(n))

    # 256 point lights brute force, timed here in turns with the environment frames (so
    # that other tenants' load falls on both alike); the wide scene's run, if any, beside it
    p256 = next((r for r in runs if r["scene"] == "wide" and r["lights"] == 256
                 and r["path"] == "accurate" and r["max_error"] is None), None)
    slots = []
    shade = DeviceProbeShader(cfg.device)          # the probes on the device, as the commands
    # the frame's own probes (the commands' default, env_probes="frame"): the bench G-buffer's
    pairs = frame_pairs(base.camera, full, material=material)
    # the tables' rows shade a Phong material (Blinn-Phong's lobe has no table), the bench's
    # otherwise, against the exact Phong texel sum on the same pixels
    phong = Scene(camera=base.camera, material=dataclasses.replace(material, model="phong"),
                  source="bench:environment")
    exact_phong = None
    if "tables" in cfg.env_probes:
        exact_phong = env_reference.texel_terms(phong, sub, l_all[keep], E_all[keep])
    for target, probes in ((t, p) for t in cfg.env_errors for p in cfg.env_probes):
        if probes == "tables":
            try:
                conv = TableRow.of(environment_tables(L, phong.material, max_error=target))
            except TablesUnfit as exc:
                log(f"environment {mw}x{mh} eps={target:g}: no tables ({exc})")
                continue
            miss = FrameSource(phong.camera, full, phong.material).horizon_misses(conv.tables)
            if miss:
                log(f"environment {mw}x{mh} eps={target:g}: the tables' bound misses {miss} "
                    "pixels of the bench frame: no tables row")
                continue
            scene = dataclasses.replace(phong, lights=sun_lights(conv.tables.sun_l,
                                                                 conv.tables.sun_radiance),
                                        env_tables=((conv.tables, None),))
        else:
            conv = environment_lights(L, material, max_error=target, shade=shade,
                                      pairs=pairs if probes == "frame" else None)
            scene = environment_scene(directional_lights(conv))
        n = len(scene.lights)
        rows = _crop_rows(W, H, max(n, 1), cfg.crop_pairs)
        gb = full if rows == H else bench_gbuffer(W, H, rows)
        r = Renderer(scene, device=cfg.device)
        slots.append({"target": target, "probes": probes, "conv": conv, "scene": scene,
                      "rows": rows, "gb": gb,
                      "r": r, "frame": prepare_frame(gb, lanes=max(r.lanes, 1)), "times": []})
    sc = bench_scene("wide", 256)
    rows = _crop_rows(W, H, 256, cfg.crop_pairs)
    gb = full if rows == H else bench_gbuffer(W, H, rows)
    r = Renderer(sc, device=cfg.device)
    slots.append({"target": None, "rows": rows, "gb": gb, "r": r,
                  "frame": prepare_frame(gb, lanes=max(r.lanes, 1)), "times": []})
    for round_ in range(cfg.warmup + cfg.repeats):
        for slot in slots:
            t, _, _ = time_frame(slot["r"], slot["gb"], slot["frame"])
            if round_ >= cfg.warmup:
                slot["times"].append(t)
    shaded_full = shaded_pixels(full)

    def per_frame(slot):
        return statistics.median(slot["times"]) * 1e3 * shaded_full / shaded_pixels(slot["gb"])

    p256_ms = per_frame(slots[-1])
    p256_wide = p256["ms_per_frame"] if p256 is not None else None
    out = []
    for slot in slots:
        if slot["target"] is None:
            continue
        conv, target = slot["conv"], slot["target"]
        got = slot["r"].render(sub).image.reshape(-1, 3).astype(np.float64)
        tabled = slot["probes"] == "tables"
        ex_d, ex_s = exact_phong if tabled else exact_terms
        exact = ex_d + ex_s
        if tabled:
            d, sp = env_reference.table_terms(phong, sub, conv.tables)
        else:
            d, sp = env_reference.texel_terms(base, sub, conv.l, conv.radiance)
        top = float(exact.max(initial=0.0))
        big = exact >= FLOOR * top
        rel = np.abs(got - exact)[big] / exact[big]
        ms = per_frame(slot)
        entry = {
            "scene": "environment", "size": [W, H], "map": [mw, mh], "texels": conv.texels,
            "env_error": target, "env_probes": slot["probes"], "lights": conv.count,
            "estimated_error": conv.estimated_error,
            "estimate_met": conv.met, "probes": conv.probes, "conversion_s": conv.seconds,
            "crop_rows": slot["rows"], "extrapolated": slot["rows"] != H,
            "ms_per_frame": ms, "times_ms": [t * 1e3 for t in slot["times"]],
            "point256_ms_per_frame": p256_ms, "point256_wide_run_ms_per_frame": p256_wide,
            "time_ratio_256_point": ms / p256_ms,
            "error": {
                "max_rel": float(rel.max(initial=0.0)),
                "mean_rel": float(rel.mean()) if rel.size else 0.0,
                "floor": FLOOR, "sampled_pixels": int(len(idx)), "exact_seconds": t_exact,
                # each term's error as a share of the pixel (float64 model sums, no kernel)
                "diffuse_max_rel": _env_rel(d + ex_s, exact),
                "specular_max_rel": _env_rel(ex_d + sp, exact),
                "model_max_rel": _env_rel(d + sp, exact),
            },
            "material": slot["scene"].material.model,
            "lights_for_target_on_sample": (None if tabled else
                                            _first_n_for(target, exact, ex_d, ex_s, tree, terms_of)),
        }
        out.append(entry)
        e = entry["error"]
        log(f"environment {mw}x{mh} eps={target:<6g} probes={slot['probes']:5s} {conv.count:6d} lights (est {conv.estimated_error:.2e}, "
            f"{conv.seconds:.1f} s) {ms:10.1f} ms/frame x{entry['time_ratio_256_point']:.2f} of 256 "
            f"point lights  max rel {e['max_rel']:.2e} (diffuse {e['diffuse_max_rel']:.2e}, "
            f"specular {e['specular_max_rel']:.2e}); {entry['lights_for_target_on_sample']} lights "
            f"would do on these pixels")
    return out


#: The light-tree rows of ``clphong bench`` (``--tree``): (scene, N, ε), and with a fourth
#: item "relative" ε is a fraction of each pixel's own value (``--relative``, issue 27).
TREE_CASES = (("wide", 4096, 1e-3), ("wide", 4096, 1e-2), ("clusters", 4096, 1e-3),
              ("clusters", 4096, 1e-2), ("clusters", 65536, 1e-2), ("clusters", 65536, 1e-3),
              *((kind, 4096, eps, "relative") for kind in ("wide", "clusters")
                for eps in (1e-1, 1e-2, 1e-3)),
              ("wide", 65536, 1e-2, "relative"), ("clusters", 65536, 1e-2, "relative"))


def relative_errors(oracle, rgb) -> dict:
    """Max and mean of |error| / |reference| over the oracle's pixels and channels whose
    reference is not 0 (the relative budget's measure: no floor, no band excluded)."""
    got = rgb.reshape(-1, 3)[oracle.idx].astype(np.float64)
    ref = np.abs(oracle.ref)
    on = ref > 0
    rel = np.abs(got - oracle.ref)[on] / ref[on]
    return {"max_rel_error": float(rel.max(initial=0.0)),
            "mean_rel_error": float(rel.mean()) if rel.size else 0.0}


def run_tree(cfg, full, log) -> list[dict]:
    """The light-tree rows (module docstring): per (scene, N, ε), brute force, culling
    alone and culling with the tree's clusters, timed in turns on the same crop."""
    H, W = full.shape
    out = []
    for kind, n, eps, *rest in cfg.tree_cases:
        relative = rest == ["relative"]
        scene = bench_scene(kind, n)
        t0 = time.perf_counter()
        built = build_light_tree(scene.light_arrays)
        build_s = time.perf_counter() - t0
        # whole rows of super-tiles (the cut's unit), about crop_pairs pairs
        slots = []
        for label, opts in (("brute", dict(max_error=None)),
                            ("culling", dict(max_error=eps, light_tree=False, relative=relative)),
                            ("tree", dict(max_error=eps, light_tree="always", relative=relative))):
            r = Renderer(scene, device=cfg.device, **opts)
            band = super_tiles(max(r.lanes, 1)) * TILE
            rows = min(H, band * max(1, round(_crop_rows(W, H, n, cfg.crop_pairs) / band)))
            gb = full if rows == H else bench_gbuffer(W, H, rows)
            slots.append({"label": label, "r": r, "rows": rows, "gb": gb, "times": [], "cull": [],
                          "frame": prepare_frame(gb, lanes=max(r.lanes, 1))})
        for round_ in range(cfg.warmup + cfg.repeats):
            _time_slots(slots, keep=round_ >= cfg.warmup)
        shaded_full = shaded_pixels(full)
        rows = slots[0]["rows"]
        oracle = make_oracle(scene, slots[0]["gb"], slots[0]["frame"],
                             max(500, int(cfg.error_pairs // max(n, 1))))
        row = {"scene": kind, "size": [W, H], "lights": n, "max_error": eps, "relative": relative,
               "crop_rows": rows,
               "extrapolated": rows != H, "tree_nodes": built.n_nodes if built else 0,
               "tree_lights": built.clusterable if built else 0, "tree_build_s": build_s}
        for slot in slots:
            res = slot["result"]
            # the lists of the last frame that built them (a lost culling skips CULL_RETRY)
            c = slot.get("last_cull")
            ms = statistics.median(slot["times"]) * 1e3 * shaded_full / shaded_pixels(slot["gb"])
            row[slot["label"]] = {
                "ms_per_frame": ms, "times_ms": [t * 1e3 for t in slot["times"]],
                "cull_ms": statistics.median(slot["cull"]) * 1e3 * shaded_full
                / shaded_pixels(slot["gb"]),
                "kept_fraction": None if c is None else c.kept_fraction,
                "brute_fallback": None if c is None else c.brute,
                "clusters": 0 if c is None else c.clusters,
                "covered": 0 if c is None else c.covered,
                "cut_ms": 0.0 if c is None else c.tree_seconds * 1e3 * shaded_full
                / shaded_pixels(slot["gb"]),
                "max_abs_error": oracle.errors(res.image)["max_abs"],
                **relative_errors(oracle, res.image),
            }
        b = row["brute"]["ms_per_frame"]
        for label in ("culling", "tree"):
            x = row[label]
            x["speedup"] = b / x["ms_per_frame"]
            got = x["max_rel_error"] if relative else x["max_abs_error"]
            x["within_budget"] = got <= eps
            # how far the error stayed below the budget (the bound's and the floor's slack)
            x["slack"] = eps / got if got > 0 else None
        out.append(row)
        t, cu = row["tree"], row["culling"]
        log(f"tree {kind:8s} N={n:<6d} eps={eps:<6g}{' rel' if relative else ''} brute {b:9.1f} ms  culling {cu['ms_per_frame']:9.1f} "
            f"ms (x{cu['speedup']:.2f}, kept {cu['kept_fraction'] or 0:.3f})  tree "
            f"{t['ms_per_frame']:9.1f} ms (x{t['speedup']:.2f}, kept {t['kept_fraction'] or 0:.3f}, "
            f"{t['clusters']} clusters, cut {t['cut_ms']:.0f} ms)  max abs {t['max_abs_error']:.2e}"
            f" max rel {t['max_rel_error']:.2e}"
            f"  tree {row['tree_nodes']} nodes in {build_s:.2f} s")
    return out


def tree_table(rows: list[dict]) -> list[str]:
    if not rows:
        return []
    lines = [f"{'tree':9s} {'N':>6s} {'eps':>7s} {'brute ms':>10s} {'cull ms':>10s} {'x':>6s} "
             f"{'tree ms':>10s} {'x':>6s} {'kept':>6s} {'clusters':>9s} {'cut ms':>7s} "
             f"{'max abs':>9s} {'max rel':>9s} {'slack':>7s} {'nodes':>6s} {'build s':>7s}"]
    for r in rows:
        c, t = r["culling"], r["tree"]
        slack = f"{t['slack']:7.1f}" if t.get("slack") else f"{'-':>7s}"
        eps = f"{r['max_error']:6.0e}" + ("r" if r.get("relative") else " ")
        lines.append(f"{r['scene']:9s} {r['lights']:6d} {eps} "
                     f"{r['brute']['ms_per_frame']:10.1f}{'*' if r['extrapolated'] else ' '}"
                     f"{c['ms_per_frame']:9.1f} {c['speedup']:6.2f} {t['ms_per_frame']:10.1f} "
                     f"{t['speedup']:6.2f} {t['kept_fraction'] or 0:6.3f} {t['clusters']:9d} "
                     f"{t['cut_ms']:7.0f} {t['max_abs_error']:9.2e} {t['max_rel_error']:9.2e} "
                     f"{slack} {r['tree_nodes']:6d} "
                     f"{r['tree_build_s']:7.2f}")
    lines.append("tree: ms per frame (brute force, culling alone, culling with the light tree's "
                 "clusters; * from a crop of whole super-tile rows), speed-ups over brute force, "
                 "the tree run's kept share, clusters over the super-tiles, host cut (per frame), max abs "
                 "and max relative error against the float64 reference (within eps, or with an r "
                 "within eps of each pixel's own value: the budget held), slack = eps / that error, "
                 "the tree's size and build time")
    return lines


def summarise_environment(rows: list[dict]) -> dict:
    """The issue-16 targets: the 1e-3 row's error and its time against 256 point lights."""
    row = next((r for r in rows if r["env_error"] == DEFAULT_ENV_ERROR), None)
    if row is None:
        return {}
    return {"env_lights": row["lights"], "env_max_rel": row["error"]["max_rel"],
            "env_probes": row.get("env_probes", "all"), "env_material": row.get("material"),
            "env_time_ratio_256_point": row["time_ratio_256_point"],
            "env_lights_for_target_on_sample": row["lights_for_target_on_sample"],
            "target_env_error_met": row["error"]["max_rel"] <= DEFAULT_ENV_ERROR,
            "target_env_time_met": row["time_ratio_256_point"] <= 1.0}


def environment_summary_lines(summary: dict) -> list[str]:
    if "env_lights" not in summary:
        return []
    def met(ok):
        return "met" if ok else "not met"
    need = summary["env_lights_for_target_on_sample"]
    how = (f"from tables and {summary['env_lights']} sun lights ({summary.get('env_material')})"
           if summary.get("env_probes") == "tables" else
           f"{summary['env_lights']} lights; {need} would meet it on the sampled pixels")
    return [f"issue-16 targets: environment at {DEFAULT_ENV_ERROR:g}: error "
            f"{met(summary['target_env_error_met'])} (max rel {summary['env_max_rel']:.2e}); time "
            f"within 256 point lights brute force {met(summary['target_env_time_met'])} "
            f"({summary['env_time_ratio_256_point']:.3g}x, {how})"]


def environment_table(rows: list[dict]) -> list[str]:
    if not rows:
        return []
    lines = [f"{'environment':12s} {'eps':>7s} {'probes':>6s} {'lights':>7s} {'est':>9s} {'conv s':>7s} "
             f"{'ms/frame':>10s} {'x256pt':>7s} {'max rel':>9s} {'diffuse':>9s} {'specular':>9s} "
             f"{'pixels':>6s} {'enough':>7s}"]
    for r in rows:
        e = r["error"]
        lines.append(f"{'x'.join(map(str, r['map'])):12s} {r['env_error']:7.0e} "
                     f"{r.get('env_probes', 'all'):>6s} {r['lights']:7d} "
                     f"{r['estimated_error']:9.2e} {r['conversion_s']:7.1f} {r['ms_per_frame']:10.1f}"
                     f"{'*' if r['extrapolated'] else ' '}{r['time_ratio_256_point']:7.2f} "
                     f"{e['max_rel']:9.2e} {e['diffuse_max_rel']:9.2e} {e['specular_max_rel']:9.2e} "
                     f"{e['sampled_pixels']:6d} {r['lights_for_target_on_sample'] or 0:7d}")
    lines.append("environment: max rel against the exact float64 texel sum on the sampled pixels "
                 ">= 1e-3 of their maximum; diffuse/specular: each term's approximation alone; "
                 "enough: the fewest lights of the same tree within eps on those pixels; "
                 "probes: the estimate's, the frame's own pixels or every normal and view; "
                 "tables: the kernels' tables (Phong: Blinn-Phong has none), lights = sun texels")
    return lines
