"""How well lat-long tables hold an environment's sums, and what they cost to build (issue 25):
``python -m clphong.tools.env_tables [--map WxH] [--diffuse ROWS:STEP,...]
[--specular H:ROWS:STEP,...] [--probes N] [--keep-sun] [--pixels H:DROWS:SROWS]``.

The map is the bench's sky (:func:`clphong.tools.samples.sky_envmap`: sky, clouds, ground,
and a 1° sun of radiance 2000). Unless ``--keep-sun``, the sun's texels (radiance summed
over the channels above :data:`SUN_RATIO` × the median) are left out of the map, as the
table path would shade them as explicit directional lights. Each row builds one table with
:func:`clphong.model.env_table.zonal_table` (diffuse: power 1; specular: power h, the
Phong lobe without its horizon), then compares :func:`~clphong.model.env_table.lookup`
at ``--probes`` held-out directions (a Fibonacci lattice, not the nodes) with the exact
float64 texel sum of the same map: the maximum relative error per channel on values ≥
1e-3 of the largest, as ``clphong bench`` measures images.

``--pixels H:DROWS:SROWS`` then shades whole pixels (:func:`pixels`): the probe pairs of
:func:`clphong.model.environment.probe_pairs` (every normal, views on its hemisphere),
Phong with k_d = 0.7, k_s = 0.2 and exponent H, white albedo, the sun as exact lights,
the rest from a diffuse table of DROWS rows and a lobe table of SROWS rows, against the
model's exact texel sum (:func:`clphong.model.environment.probe_sums`). The lobe table
has no horizon: the model counts a texel's specular only where n·l > 0, and the rows
say how much that costs and on which views. ``--lower EPS,...`` tries one correction:
subtract the lobe of the lights below each pixel's tangent plane, the sky converted to
directional lights at ``EPS`` (:func:`clphong.model.environment.environment_lights`), and
counts the lights a pixel would visit (below the plane, lobe weight above 1e-4). The
last row is the floor: normals along the map's up axis (+y, which ``rotation`` keeps),
where n·l > 0 is "latitude > 0", so a lobe table of the upper rows alone is exact at its
nodes, horizon included (:func:`floor`).

Two measurements ask what a diffuse table alone would buy, with the specular kept as
directional lights (the only path for Blinn-Phong, whose lobe is not a function of one
direction):

``--split N,...`` (:func:`split`) grows the conversion's light tree
(:class:`clphong.model.environment.LightTree`) of the whole sky, sun included, to N
lights and measures the pixel error on the probe pairs against the exact texel sum three
ways: every term from the N lights; the diffuse exact (a perfect table) and the specular
from the N lights; the specular exact and the diffuse from the lights. The material is
``--model`` (default the bench's Blinn-Phong, k_d 0.7, k_s 0.2, h 32). If the second
column is no smaller than the first, a diffuse table does not let the conversion use
fewer lights.

``--tile-floor EPS,...`` (:func:`tile_floor`) takes the conversion's lights at 1e-3 on the
1080p bench G-buffer and, for 8×8 tiles, drops a tile's specular lights while the sum of
their largest contribution to any of its pixels stays within EPS of the tile's darkest
pixel, the diffuse exact. That bound is the true maximum over the tile's pixels, tighter
than any bound from the tile's normal and view cones, so the lights kept are a floor for a
"diffuse table plus per-tile specular culling" design. ``--cones`` bounds each weight from
two cones instead (:func:`cone_weights`, Blinn-Phong): what such a design would keep. Not a timed test: the figures are
this machine's.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..model.env_table import lookup, weighted_map, zonal_table
from ..model.environment import (FLOOR, LightTree, _fibonacci, _latitudes, _pixels, environment_lights,
                                 lobe_weights, probe_error, probe_pairs,
                                 probe_sums, texel_lights)
from ..model.scene import parse_scene
from .bench_scenes import bench_gbuffer, bench_scene
from .samples import sky_envmap

#: Texels brighter than this many times the median (radiance summed over channels) are the
#: sun's, split out of the table.
SUN_RATIO = 50.0


def _exact(dirs: np.ndarray, l: np.ndarray, E: np.ndarray, power: float, chunk: int = 256):
    out = np.empty((len(dirs), E.shape[1]))
    for i in range(0, len(dirs), chunk):
        c = np.maximum(dirs[i:i + chunk] @ l.T, 0.0)
        out[i:i + chunk] = (c if power == 1 else c ** power) @ E
    return out


def measure(size=(1024, 512), diffuse=((128, 3),), specular=((32.0, 256, 1),),
            probes: int = 1500, keep_sun: bool = False, log=print) -> list[dict]:
    """One row per table: its shape, build seconds and error at the probes."""
    L, sun = _sky(size, keep_sun)
    log(f"map {size[0]}x{size[1]}: " + ("the sun kept in the tables" if keep_sun else
        f"{int((sun.max(axis=-1) > 0).sum())} sun texels split out (explicit lights)"))
    l, E = texel_lights(L)
    M = weighted_map(L)
    dirs = _fibonacci(probes, offset=0.25)
    rows = []
    for kind, power, r, step in ([("diffuse", 1.0, r, s) for r, s in diffuse] +
                                 [("specular", float(h), r, s) for h, r, s in specular]):
        t0 = time.perf_counter()
        table = zonal_table(M, power, r, step)
        seconds = time.perf_counter() - t0
        err = probe_error(lookup(table, dirs), _exact(dirs, l, E, power), FLOOR)
        row = dict(kind=kind, power=power, rows=table.shape[0], cols=table.shape[1],
                   build_s=seconds, max_rel=err)
        log(f"{kind:8s} h={power:<6g} table {table.shape[1]:4d}x{table.shape[0]:<4d} "
            f"build {seconds:6.2f} s   max rel {err:.2e} at {probes} held-out directions")
        rows.append(row)
    return rows


def _sky(size, keep_sun: bool):
    """(the map less its sun, the sun alone), float64 (H, W, 3)."""
    L = np.asarray(sky_envmap(*size), np.float64)
    lum = L.sum(-1)
    sun = (lum > SUN_RATIO * np.median(lum)) & (not keep_sun)
    S = np.where(sun[..., None], L, 0.0)
    return L - S, S


def _phong(h: float, *, k_d: float, k_s: float):
    """A Phong material (white albedo is the probes' own) with exponent ``h``."""
    return parse_scene({"camera": {"type": "perspective", "position": [0.0, 0.0, 5.0]},
                        "material": {"model": "phong", "k_a": 0.0, "k_d": k_d, "k_s": k_s,
                                     "h": float(h)}, "light": []}, "env_tables").material


def pixels(size=(1024, 512), h: float = 32.0, diffuse_rows: int = 128, lobe_rows: int = 256,
           probes: int = 1500, lower=(), log=print) -> dict:
    """Whole pixels from the tables against the exact texel sum (module docstring)."""
    sky, sun = _sky(size, keep_sun=False)
    material = _phong(h, k_d=0.7, k_s=0.2)
    n, v = probe_pairs(probes)
    NoV = np.einsum("ij,ij->i", n, v)
    R = 2.0 * NoV[:, None] * n - v                        # l·R = r·v: the lobe's axis
    parts = {}
    for name, L in (("sky", sky), ("sun", sun)):
        l, E = texel_lights(L)
        keep = E.max(axis=1) > 0
        parts[name] = probe_sums(n, v, l[keep], E[keep], material)
        if name == "sky":
            lobe = _exact(R, l[keep], E[keep], h)         # the sky's lobe without its horizon
    step = next(s for s in (3, 1) if (size[0] - 1) % s == 0)
    M = weighted_map(sky)
    t0 = time.perf_counter()
    d_t = lookup(zonal_table(M, 1.0, diffuse_rows, step), n)
    s_t = lookup(zonal_table(M, h, lobe_rows, 1), R)
    seconds = time.perf_counter() - t0
    (d_sky, s_sky), (d_sun, s_sun) = parts["sky"], parts["sun"]
    truth = 0.7 * (d_sky + d_sun) + 0.2 * (s_sky + s_sun)
    tables = 0.7 * (d_t + d_sun) + 0.2 * (s_t + s_sun)
    no_horizon = 0.7 * (d_sky + d_sun) + 0.2 * (lobe + s_sun)
    over = (0.2 * (lobe - s_sky)).max(axis=1) / truth.max(axis=1)
    row = dict(h=h, build_s=seconds, tables=probe_error(tables, truth),
               horizon=probe_error(no_horizon, truth), diffuse=probe_error(d_t, d_sky),
               lobe=probe_error(s_t, lobe))
    log(f"pixels, h={h:g}, tables {diffuse_rows}/{lobe_rows} rows (build {seconds:.1f} s): max rel "
        f"{row['tables']:.2e}; the horizon alone {row['horizon']:.2e}; the diffuse table "
        f"{row['diffuse']:.2e}; the lobe table {row['lobe']:.2e}")
    for budget in (1e-3, 1e-4):
        bad = over > budget
        row[f"over_{budget:g}"] = float(bad.mean())
        log(f"  the horizon over-counts by more than {budget:g} of the pixel on {100 * bad.mean():.1f} % "
            f"of the probes; their n·v is at most {NoV[bad].max() if bad.any() else float('nan'):.3f}")
    for eps in lower:
        env = environment_lights(sky, material, max_error=eps)
        w = np.maximum(R @ env.l.T, 0.0) ** h
        below = (n @ env.l.T) <= 0.0
        corrected = tables - 0.2 * (np.where(below, w, 0.0) @ env.radiance)
        visits = (below & (w > 1e-4)).sum(axis=1)
        row[f"lower_{eps:g}"] = dict(lights=len(env.l), max_rel=probe_error(corrected, truth),
                                     visits_median=float(np.median(visits)),
                                     visits_p90=float(np.percentile(visits, 90)), visits_max=int(visits.max()))
        log(f"  less the lights below the tangent plane (the sky as {len(env.l)} lights at {eps:g}): "
            f"max rel {row[f'lower_{eps:g}']['max_rel']:.2e}; a pixel visits {np.median(visits):.0f} "
            f"of them (median), {np.percentile(visits, 90):.0f} (90 %), {visits.max()} (max)")
    return row


def floor(size=(1024, 512), h: float = 32.0, lobe_rows: int = 256, probes: int = 1500,
          log=print) -> dict:
    """Specular sums on an up-facing floor (n = +y, views above it): the lobe table of the
    map's upper half (the horizon clipped exactly) and the lobe table of the whole map,
    against the model's exact texel sum."""
    sky, _ = _sky(size, keep_sun=False)
    material = _phong(h, k_d=0.0, k_s=1.0)
    _, v = probe_pairs(probes)
    v = v * np.sign(v[:, 1:2])
    v = v[np.abs(v[:, 1]) > 0.0]
    n = np.broadcast_to(np.array([0.0, 1.0, 0.0]), v.shape).copy()
    R = 2.0 * v[:, 1:2] * n - v
    l, E = texel_lights(sky)
    keep = E.max(axis=1) > 0
    truth = probe_sums(n, v, l[keep], E[keep], material)[1]
    M = weighted_map(sky)
    upper = M.copy()
    upper[_latitudes(size[1], np.arange(size[1])) <= 0.0] = 0.0       # n·l > 0: latitude > 0
    row = dict(h=h, clipped=probe_error(lookup(zonal_table(upper, h, lobe_rows), R), truth),
               whole=probe_error(lookup(zonal_table(M, h, lobe_rows), R), truth))
    log(f"floor (n = +y), h={h:g}, lobe table {lobe_rows} rows: the upper half's table max rel "
        f"{row['clipped']:.2e}; the whole map's {row['whole']:.2e} (views down to n·v = {v[:, 1].min():.1e})")
    return row


def _material(model: str):
    return parse_scene({"camera": {"type": "perspective", "position": [0.0, 0.0, 5.0]},
                        "material": {"model": model, "k_a": 0.0, "k_d": 0.7, "k_s": 0.2, "h": 32.0},
                        "light": []}, "env_tables").material


def split(size=(1024, 512), counts=(1024, 4096, 16384), model: str = "blinn-phong",
          probes: int = 1500, log=print) -> list[dict]:
    """Pixel errors of N tree lights: all terms, the diffuse exact, the specular exact
    (module docstring)."""
    material = _material(model)
    L = np.asarray(sky_envmap(*size), np.float64)
    l, E = texel_lights(L)
    keep = E.max(axis=1) > 0
    n, v = probe_pairs(probes)
    D, S = probe_sums(n, v, l[keep], E[keep], material)
    truth = _pixels(D, S, material)
    H, W = L.shape[:2]
    tree = LightTree(E.reshape(H, W, 3), l.reshape(H, W, 3))
    rows = []
    for k in counts:
        tree.grow(k)
        d, s = probe_sums(n, v, *tree.lights(k), material)
        row = dict(model=model, lights=k, all=probe_error(_pixels(d, s, material), truth),
                   diffuse_exact=probe_error(_pixels(D, s, material), truth),
                   specular_exact=probe_error(_pixels(d, S, material), truth))
        log(f"{model} {k:6d} lights: max rel {row['all']:.2e}; the diffuse exact "
            f"{row['diffuse_exact']:.2e}; the specular exact {row['specular_exact']:.2e}")
        rows.append(row)
    return rows


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles between unit vectors along the last axis (atan2: accurate near 0 and pi)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("...i,...i->...", a, b))


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def cone_weights(N: np.ndarray, V: np.ndarray, l: np.ndarray, exponent: float) -> np.ndarray:
    """(K,): a bound of each light's Blinn-Phong weight ``max(n·h, 0)^exponent`` over a
    tile, from two cones: the tile's normals (axis a, half-angle θ_n) and, per light, the
    half-vectors of its pixels about ``h0 = unit(l + mean view)`` (half-angle θ_h). Then
    n·h ≤ cos(max(0, ∠(a, h0) − θ_n − θ_h)), and 0 where every normal of the cone is
    90° or more from l (n·l ≤ 0)."""
    a = _unit(N.mean(axis=0))
    theta_n = _angle(N, a[None]).max()
    h = _unit(l[None, :, :] + V[:, None, :])                          # (P, K, 3)
    h0 = _unit(l + _unit(V.mean(axis=0))[None])                      # (K, 3)
    theta_h = _angle(h, h0[None]).max(axis=0)
    gap = np.maximum(_angle(a[None], h0) - theta_n - theta_h, 0.0)
    w = np.cos(np.minimum(gap, 0.5 * np.pi)) ** exponent
    return np.where(_angle(a[None], l) - theta_n >= 0.5 * np.pi, 0.0, w)


def tile_floor(size=(1024, 512), eps=(5e-4,), tiles: int = 150, tile: int = 8,
               frame=(1920, 1080), cones: bool = False, log=print) -> list[dict]:
    """Specular lights an 8×8 tile of the bench G-buffer keeps under an oracle bound, or
    with ``cones`` under :func:`cone_weights` (module docstring)."""
    scene = bench_scene("wide", 1)
    material = scene.material
    env = environment_lights(sky_envmap(*size), material, max_error=1e-3)
    l, rad = env.l, env.radiance
    gb = bench_gbuffer(*frame)
    rng = np.random.default_rng(1)
    eye = np.asarray(scene.camera.position, np.float64)
    kept = {e: [] for e in eps}
    for _ in range(tiles):
        y0, x0 = int(rng.integers(0, frame[1] - tile)), int(rng.integers(0, frame[0] - tile))
        win = (slice(y0, y0 + tile), slice(x0, x0 + tile))
        if gb.coverage[win].min() == 0:
            continue
        P = gb.position[win].reshape(-1, 3).astype(np.float64)
        N = gb.normal[win].reshape(-1, 3).astype(np.float64)
        N /= np.linalg.norm(N, axis=1)[:, None]
        V = eye - P
        V /= np.linalg.norm(V, axis=1)[:, None]
        d, s = probe_sums(N, V, l, rad, material)
        white = _pixels(d, s, material)                        # k_d·E + k_s·S, white albedo
        C = gb.albedo[win].reshape(-1, 3).astype(np.float64)
        pixel = C * (white - material.k_s * s) + material.k_s * s
        # each light's largest specular weight over the tile (Fresnel, at most 1, left out)
        w = (cone_weights(N, V, l, material.exponent) if cones
             else lobe_weights(N, V, l, material).max(axis=0))
        bound = material.k_s * w[:, None] * rad
        order = np.argsort(bound.max(axis=1))
        cum = np.cumsum(bound[order], axis=0)
        for e in eps:
            ok = (cum <= e * pixel.min(axis=0)).all(axis=1)
            kept[e].append(len(l) - (int(np.argmin(ok)) if not ok.all() else len(ok)))
    rows = []
    for e in eps:
        k = np.asarray(kept[e])
        row = dict(eps=e, lights=len(l), tiles=len(k), median=float(np.median(k)),
                   p90=float(np.percentile(k, 90)), max=int(k.max()))
        log(f"tile {'cones' if cones else 'floor'} at {e:g} of the darkest pixel: a {tile}x{tile} tile keeps {row['median']:.0f} "
            f"of {len(l)} specular lights (median of {len(k)} tiles), {row['p90']:.0f} (90 %), "
            f"{row['max']} (max)")
        rows.append(row)
    return rows


def _pairs(text: str, n: int):
    out = []
    for item in filter(None, text.split(",")):
        parts = item.split(":")
        if len(parts) != n:
            raise SystemExit(f"env_tables: {item!r}: expected {n} numbers separated by ':'")
        out.append(tuple(float(p) if i == 0 and n == 3 else int(p) for i, p in enumerate(parts)))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m clphong.tools.env_tables", description=__doc__.split("\n\n")[0])
    p.add_argument("--map", default="1024x512", help="sky size WxH (default 1024x512)")
    p.add_argument("--diffuse", default="128:3,256:3", help="diffuse tables ROWS:STEP,...")
    p.add_argument("--specular", default="32:256:1,32:512:1", help="specular tables H:ROWS:STEP,...")
    p.add_argument("--probes", type=int, default=1500)
    p.add_argument("--keep-sun", action="store_true", help="table the sun too")
    p.add_argument("--pixels", default="", help="whole pixels: H:DROWS:SROWS (module docstring)")
    p.add_argument("--lower", default="", help="with --pixels: the below-the-plane correction at these "
                   "conversion errors EPS,...")
    p.add_argument("--split", default="", help="tree light counts N,...: what a diffuse table "
                   "alone buys (module docstring)")
    p.add_argument("--model", default="blinn-phong", choices=("phong", "blinn-phong"),
                   help="--split's material model")
    p.add_argument("--tile-floor", default="", help="budgets EPS,...: the oracle floor of per-tile "
                   "specular culling on the bench G-buffer")
    p.add_argument("--cones", action="store_true", help="--tile-floor with the bound of a tile's "
                   "normal and half-vector cones instead of the oracle")
    a = p.parse_args(argv)
    w, h = (int(x) for x in a.map.lower().split("x"))
    if a.split:
        split((w, h), [int(x) for x in a.split.split(",") if x], a.model, a.probes)
    if a.tile_floor:
        tile_floor((w, h), [float(x) for x in a.tile_floor.split(",") if x], cones=a.cones)
    measure((w, h), _pairs(a.diffuse, 2), _pairs(a.specular, 3), a.probes, a.keep_sun)
    for hh, dr, sr in _pairs(a.pixels, 3):
        pixels((w, h), hh, dr, sr, a.probes, [float(x) for x in filter(None, a.lower.split(","))])
        floor((w, h), hh, sr, a.probes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
