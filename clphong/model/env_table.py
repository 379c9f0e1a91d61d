"""Lat-long tables of an environment's zonal sums, exact at their nodes (issue 25).

Two sums of an environment light depend on one direction only:

* the diffuse sum ``E(n) = Σ_t E_t max(n·l_t, 0)`` (irradiance, per channel);
* the Phong lobe without its horizon, ``T_h(R) = Σ_t E_t max(R·l_t, 0)^h``, R the view
  reflected about n (a Phong light's ``r·v`` is ``l·R``).

``E_t`` is a texel's radiance times its solid angle (:func:`.environment.texel_lights`),
``l_t`` its direction. Both kernels are zonal: they depend on the angle between the node
and the texel, which on a lat-long map is a function of (node latitude, texel latitude,
longitude difference). So one table row (one node latitude) is, for each map row, a
circular convolution along longitude, done with FFTs and summed over the map rows:
``rows × H`` kernel FFTs of length ``W - 1`` in all. The first and last map columns are the
same meridian (OpenEXR's LatLongMap, :mod:`.environment`), so a row is periodic with
``W - 1`` samples once the last column's energy is added to the first.

The nodes' longitudes are every ``step``-th map column (``step`` divides ``W - 1``); their
latitudes are any ``rows`` from pole to pole. There the table is the texel sum itself, up
to float64 rounding (about 1e-13 relative): no texels are merged. Between nodes
:func:`lookup` interpolates bilinearly in (latitude, longitude); that is where the table's
error is, and ``python -m clphong.tools.env_tables`` measures it against the exact sum at
held-out directions, with the build time.

The kernels' tables (ENV_TABLE, kernels/include/envtable.h) are built here too
(:func:`environment_tables`):

* **What is split out.** Texels over SUN_RATIO × the median (a sun) are exact directional
  lights, one a texel: a table cannot hold the kink a small bright source makes in E(n)
  at its terminator, or its needle in the lobe. Where the tables of the rest still miss
  their budget, lower ratios (SUN_RATIOS) split out more.
* **What is tabled.** E(n) and the Phong lobe T(R) of the rest, on lat-long grids exact at
  their nodes (rows over the poles too), read with 4 × 4 Lagrange cubics
  (:func:`env_table_lookup`; their error falls as the fourth power of the spacing until
  the texel sum's own kinks, where a normal's horizon crosses a texel, floor it).
* **The estimate.** Each table's interpolation error is measured against the exact sums
  on a check grid (its node rows and the rows midway between them at every map
  column, and every half texel row within a cell of each pole, where those kinks line up
  with the rows; where every map column is a node, at the half columns too), times
  CHECK_MARGIN; the fewest TABLE_ROWS rows within TABLE_SHARE of ``--env-error`` are used.
* **The horizon.** The model counts a texel's specular only where n·l > 0; T(R) counts
  every texel. What it over-counts is bounded per pixel (:func:`horizon_misses`: the
  texels' largest radiance times the lobe's integral over the lune below the plane,
  :func:`lune_weights`, against E(n) from below); a frame where any pixel's bound
  exceeds the rest of the budget takes the directional lights instead
  (clphong.io.envmap).
* **Not tabled.** Blinn-Phong's lobe (n·h)^(4h) depends on n and v, not on one direction;
  a shininess map needs a table per h. Those take the lights.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .environment import _latitudes, rotation_about_up, texel_directions, texel_solid_angles

__all__ = ["ZonalTable", "weighted_map", "zonal_table", "lookup", "CubicTable", "cubic_table",
           "env_table_coords", "env_table_lookup", "EnvTables", "environment_tables",
           "TABLE_ROWS", "SUN_RATIO", "SUN_RATIOS", "MAX_SUN_TEXELS", "TABLE_SHARE",
           "horizon_misses", "horizon_budget", "lune_weights", "lune_bound",
           "diffuse_lower_bound", "TablesUnfit", "table_refusal"]


@dataclass(frozen=True)
class ZonalTable:
    """``values`` (rows, cols, 3) float64 at the nodes ``texel_directions(cols, rows)``: the
    first and last columns are the same meridian, the first and last rows the poles."""

    values: np.ndarray
    power: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape[0], self.values.shape[1]


def weighted_map(radiance, intensity: float = 1.0) -> np.ndarray:
    """(H, W, 3) float64: each texel's radiance × intensity × solid angle (map frame)."""
    L = np.asarray(radiance, np.float64)
    if L.ndim == 2:
        L = L[..., None]
    H, W = L.shape[:2]
    return L * (texel_solid_angles(W, H)[..., None] * float(intensity))


def _spectra(weighted: np.ndarray):
    """The map rows' longitude spectra, (m, H, 2C) float64 real pairs, and N = W - 1: the
    last column is the first meridian, its energy added to the first column's."""
    H, W, C = weighted.shape
    N = W - 1
    M = weighted[:, :N].copy()
    M[:, 0] += weighted[:, N]                     # the last column is the first meridian
    # The map rows' spectra, (m, h, c) as real pairs: the kernel's spectrum is real (the
    # kernel is even in the longitude difference), so each frequency's sum over the map
    # rows is one real (1 × h) @ (h × 2c) product.
    F = np.fft.rfft(M, axis=1)                    # (H, N//2+1, C)
    return np.ascontiguousarray(F.transpose(1, 0, 2)).view(np.float64), N


def _zonal_rows(weighted: np.ndarray, power: float, lats, shift: float = 0.0) -> np.ndarray:
    """(len(lats), N, C): ``Σ_t E_t max(d·l_t, 0)^power`` at each latitude of ``lats`` and
    every map column's longitude (N = W - 1 of them, the repeated meridian once), or with
    ``shift`` at the longitudes ``shift`` columns further (between the columns). A
    latitude beyond a pole (|lat| > π/2) is the direction over it: (π - lat, lon + π)."""
    H, W, C = weighted.shape
    Fm, N = _spectra(weighted)
    lat_t = _latitudes(H, np.arange(H))
    sin_t, cos_t = np.sin(lat_t), np.cos(lat_t)
    if shift:
        # the kernel at column differences j + shift is not even: its spectrum is complex
        cos_dlon = np.cos(2.0 * np.pi * (np.arange(N) + shift) / N)
        F = Fm.view(np.complex128)                                          # (m, H, C)
    else:
        half = np.cos(2.0 * np.pi * np.arange(N // 2 + 1) / N)
        cos_dlon = np.concatenate([half, half[1:(N + 1) // 2][::-1]])      # even to the bit
    lats = np.asarray(lats, np.float64)
    out = np.empty((len(lats), N, C))
    # A latitude and its mirror -lat see the map rows mirrored (lat_t(H-1-j) = -lat_t(j)):
    # one kernel spectrum serves both, read against the mirrored rows.
    pairs: dict = {}
    for i, lat in enumerate(lats.tolist()):
        pairs.setdefault(round(abs(lat), 12), []).append(i)

    def row(members):
        lat = abs(float(lats[members[0]]))
        s, c = math.sin(lat), math.cos(lat)
        # map rows whose kernel is 0 at every longitude difference are skipped, exactly
        near = np.flatnonzero(s * sin_t + np.abs(c * cos_t) > 0.0)
        k = np.maximum(s * sin_t[near][:, None] + (c * cos_t[near])[:, None] * cos_dlon[None, :],
                       0.0)
        if power != 1:
            k **= power
        if shift:
            K = np.ascontiguousarray(np.fft.rfft(k, axis=1).T)                # (m, h) complex
        else:
            K = np.ascontiguousarray(np.fft.rfft(k, axis=1).real.T)[:, None, :]   # (m, 1, h)
        for i in members:
            rows_ = near if lats[i] >= 0 else H - 1 - near
            if shift:
                G = np.einsum("mh,mhc->mc", K, F[:, rows_, :])
            else:
                G = (K @ Fm[:, rows_, :])[:, 0, :].view(np.complex128)        # (m, C)
            out[i] = np.fft.irfft(G, n=N, axis=0)

    with ThreadPoolExecutor(max(1, min(os.cpu_count() or 1, 8))) as pool:
        list(pool.map(row, pairs.values()))  # numpy's FFTs and products release the GIL
    return out


def zonal_table(weighted: np.ndarray, power: float, rows: int, step: int = 1) -> ZonalTable:
    """The table of ``Σ_t E_t max(d·l_t, 0)^power`` at ``rows`` latitudes and every ``step``-th
    map column (module docstring). ``weighted``: :func:`weighted_map`'s (H, W, C)."""
    H, W, C = weighted.shape
    N = W - 1
    if rows < 2 or step < 1 or N % step:
        raise ValueError(f"a table needs rows >= 2 and a step dividing {N} (the map's "
                         f"{W} columns less the repeated meridian), not rows={rows}, step={step}")
    g = _zonal_rows(weighted, power, _latitudes(rows, np.arange(rows)))[:, ::step]
    return ZonalTable(np.concatenate([g, g[:, :1]], axis=1), float(power))


def lookup(table: ZonalTable, dirs: np.ndarray) -> np.ndarray:
    """(..., C) bilinear interpolation of ``table`` at unit directions ``dirs`` (..., 3), in
    (latitude, longitude) position space, the map's orientation."""
    d = np.asarray(dirs, np.float64)
    rows, cols = table.shape
    lat = np.arcsin(np.clip(d[..., 1], -1.0, 1.0))
    lon = np.arctan2(d[..., 0], d[..., 2])
    x = (np.pi - lon) / (2.0 * np.pi) * (cols - 1)
    y = (0.5 * np.pi - lat) / np.pi * (rows - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, cols - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, rows - 2)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    T = table.values
    top = (1.0 - fx) * T[y0, x0] + fx * T[y0, x0 + 1]
    bottom = (1.0 - fx) * T[y0 + 1, x0] + fx * T[y0 + 1, x0 + 1]
    return (1.0 - fy) * top + fy * bottom


# ------------------------------------------------------------------ the kernels' tables

#: Rows (pole to pole) a kernel table may have: the first that meets its share of the budget.
TABLE_ROWS = (17, 33, 65, 129, 257)
#: Texels brighter than this many times the median (radiance summed over the channels) are a
#: sun: shaded as exact directional lights, one a texel, and left out of the tables (a kink
#: in E(n) at its terminator, a needle in the lobe: what a table cannot hold).
SUN_RATIO = 50.0
#: The ratios tried in turn, while the tables of what is left miss their budget.
SUN_RATIOS = (SUN_RATIO, 12.0, 4.0)
#: More bright texels than this: the map is not "a sky and a few suns"; its lights instead.
MAX_SUN_TEXELS = 2048
#: The tables' share of ``--env-error``; the rest is the horizon's (:func:`horizon_budget`).
TABLE_SHARE = 0.5
#: The measured error between check points is taken as this much more than at them.
CHECK_MARGIN = 1.25
#: Check rows within a cell of each pole (every half texel row, or the cell in this many).
POLE_CHECKS = 16


@dataclass(frozen=True)
class CubicTable:
    """A kernel table: ``values`` (rows + 2, cols, 3) float64 at latitudes π/2 − Δ(j − 1),
    Δ = π/(rows − 1) (j = 0 and rows + 1 are over the poles: (π − lat, lon + π)), and
    longitudes π − 2π·c/cols (periodic). Interpolated by 4-point Lagrange cubics along
    both axes (:func:`env_table_lookup`, kernels/include/envtable.h). ``estimate``: the
    largest relative error of the interpolation measured against the exact sums at the
    check points (every map column's longitude on the node rows and on the rows midway
    between them), times CHECK_MARGIN."""

    values: np.ndarray
    power: float
    estimate: float
    seconds: float
    #: (3,): the sum from below over every direction: the least exact value on the check
    #: grid less P_c × the farthest any direction lies from it (E(n) is P_c-Lipschitz;
    #: :func:`diffuse_lower_bound`), set by :func:`environment_tables` for E(n)
    least: np.ndarray | None = None

    @property
    def rows(self) -> int:
        return self.values.shape[0] - 2

    @property
    def cols(self) -> int:
        return self.values.shape[1]


def _cols(N: int, rows: int) -> int:
    """The fewest columns dividing N (so that each is a map column) that are at least
    2(rows - 1): cells about square at the equator."""
    want = 2 * (rows - 1)
    return min((d for d in range(1, N + 1) if N % d == 0 and d >= want), default=N)


def cubic_table(weighted: np.ndarray, power: float, rows: int) -> CubicTable:
    """The kernel table of ``Σ_t E_t max(d·l_t, 0)^power`` with ``rows`` latitudes, exact at
    its nodes, and its measured interpolation error (:class:`CubicTable`)."""
    t0 = time.perf_counter()
    N = weighted.shape[1] - 1
    cols = _cols(N, rows)
    step = N // cols
    delta = np.pi / (rows - 1)
    node = 0.5 * np.pi - delta * (np.arange(rows + 2) - 1.0)
    mid = 0.5 * np.pi - delta * (np.arange(rows - 1) + 0.5)
    # Within a cell of either pole the texel rows lie parallel to a normal's horizon, which
    # crosses a whole row at once: the sum has kinks there that no cubic holds, so that
    # band is checked at every half texel row too (at most POLE_CHECKS rows a pole).
    H = weighted.shape[0]
    step_ = max(0.5 * np.pi / (H - 1), delta / POLE_CHECKS)
    band = 0.5 * np.pi - np.arange(0.5, POLE_CHECKS + 0.5) * step_
    band = band[band > 0.5 * np.pi - delta]
    pole = np.concatenate([band, -band])
    exact = _zonal_rows(weighted, power, np.concatenate([node, mid, pole]))
    values = np.ascontiguousarray(exact[:rows + 2, ::step])
    # the check grid: node and mid rows (Δ/2 apart) at every column (2π/N apart)
    reach = math.hypot(0.25 * delta, math.pi / N)
    least = exact[1:].reshape(-1, exact.shape[2]).min(axis=0) - reach * weighted.reshape(
        -1, weighted.shape[2]).sum(axis=0) if power == 1 else None
    lon = np.pi - 2.0 * np.pi * np.arange(N) / N
    worst = 0.0
    top = float(exact.max(initial=0.0))
    checks = [(node[1:-1], exact[1:rows + 1], lon), (mid, exact[rows + 2:2 * rows + 1], lon),
              (pole, exact[2 * rows + 1:], lon)]
    if step == 1:
        # every map column is a node: the longitudes midway between them are checked too
        lats = np.concatenate([node[1:-1], mid])
        checks.append((lats, _zonal_rows(weighted, power, lats, shift=0.5), lon - np.pi / N))
    for lats, want, lons in checks:
        if not len(lats):
            continue
        y, x = _positions(np.broadcast_to(lats[:, None], want.shape[:2]),
                          np.broadcast_to(lons[None, :], want.shape[:2]), rows, cols)
        got = env_table_lookup(values, y, x)
        if top > 0:                  # an all-black map's table is exact: 0
            rel = np.abs(got - want) / np.maximum(want, 1e-12 * top)
            worst = max(worst, float(rel.max(initial=0.0)))
    return CubicTable(values, float(power), CHECK_MARGIN * worst, time.perf_counter() - t0,
                      None if least is None else np.maximum(least, 0.0))


def env_table_coords(d, rotation: float, rows: int, cols: int):
    """(y, x) table positions of unit directions ``d`` (..., 3) in the world, the map turned
    by ``rotation`` radians about +y (the kernel's env_table_coords, float64): latitude
    atan2(d_y, |d_xz|), map longitude atan2(d_x, d_z) − rotation."""
    d = np.asarray(d, np.float64)
    lat = np.arctan2(d[..., 1], np.hypot(d[..., 0], d[..., 2]))
    return _positions(lat, np.arctan2(d[..., 0], d[..., 2]) - rotation, rows, cols)


def _positions(lat, lon, rows: int, cols: int):
    """(y, x) of latitudes and map longitudes: y = 1 + (π/2 − lat)/Δ, x = (π − lon)/(2π)·cols
    wrapped into [0, cols)."""
    y = 1.0 + (0.5 * np.pi - np.asarray(lat, np.float64)) * ((rows - 1) / np.pi)
    xx = (np.pi - np.asarray(lon, np.float64)) * (cols / (2.0 * np.pi))
    return y, xx - cols * np.floor(xx / cols)


def _cubic_weights(t: np.ndarray) -> np.ndarray:
    """(..., 4) Lagrange weights of the nodes -1, 0, 1, 2 at t in [0, 1]."""
    a, b, c = t + 1.0, t - 1.0, t - 2.0
    return np.stack([-t * b * c / 6.0, a * b * c / 2.0, -a * t * c / 2.0, a * t * b / 6.0], -1)


def env_table_lookup(values: np.ndarray, y, x) -> np.ndarray:
    """(..., 3): the table ``values`` (rows + 2, cols, 3) at positions (y, x) by 4 × 4
    Lagrange cubics, x periodic (the kernel's env_table_lookup, float64)."""
    rows, cols = values.shape[0] - 2, values.shape[1]
    y = np.asarray(y, np.float64)
    x = np.asarray(x, np.float64)
    y0 = np.clip(np.floor(y), 1, rows - 1)       # as the kernel's fmax/fmin (NaN: 1 and 0)
    x0 = np.clip(np.floor(x), 0, cols - 1)
    y0 = np.where(np.isnan(y0), 1.0, y0)
    x0 = np.where(np.isnan(x0), 0.0, x0)
    wy = _cubic_weights(y - y0)
    wx = _cubic_weights(x - x0)
    y0 = y0.astype(np.int64)
    x0 = x0.astype(np.int64)
    flat = values.reshape(-1, values.shape[2])
    out = np.zeros(y.shape + (values.shape[2],))
    for a in range(4):
        base = (y0 - 1 + a) * cols
        for b in range(4):
            out += (wy[..., a] * wx[..., b])[..., None] * flat[base + np.mod(x0 - 1 + b, cols)]
    return out


@dataclass(frozen=True, eq=False)
class EnvTables:
    """An environment light as the kernels' tables (issue 25): the diffuse sum E(n) and the
    Phong lobe T(R) of the map less its sun, and the sun's texels as exact lights.

    Attributes
    ----------
    diffuse, specular : CubicTable (specular None without a specular term)
    sun_l, sun_radiance : (S, 3) float64
        The sun's texels as directional lights (towards the light; radiance × solid angle ×
        intensity), exact.
    power : (3,) float64
        Σ_t E_t of the tabled texels (the Lipschitz constant of E(n)).
    radiance_max : (3,) float64
        The tabled texels' largest radiance × intensity.
    lune : (LUNE_STEPS + 1,) float64
        :func:`lune_weights` of the lobe's exponent (zeros without a lobe table).
    diffuse_floor : (3,) float64
        E(n) from below over every direction (:attr:`CubicTable.least`).
    texel_angle : float
        The map's largest texel spacing (radians): :func:`lune_bound`'s allowance.
    rotation : float
        The light's rotation (degrees about +y): the kernels turn directions back by it.
    estimate : float
        The tables' error estimate, the larger of the two.
    max_error : float
    seconds : float
    """

    diffuse: CubicTable
    specular: CubicTable | None
    sun_l: np.ndarray
    sun_radiance: np.ndarray
    power: np.ndarray
    radiance_max: np.ndarray
    lune: np.ndarray
    diffuse_floor: np.ndarray
    texel_angle: float
    rotation: float
    estimate: float
    max_error: float
    seconds: float

    @property
    def sun_count(self) -> int:
        return len(self.sun_l)

    def describe(self) -> str:
        parts = [f"diffuse {self.diffuse.rows}x{self.diffuse.cols}"]
        if self.specular is not None:
            parts.append(f"lobe h={self.specular.power:g} {self.specular.rows}x"
                         f"{self.specular.cols}")
        return (f"{', '.join(parts)} (estimated error {self.estimate:.2g}), "
                f"{self.sun_count} sun texel(s) as lights")


class TablesUnfit(ValueError):
    """Why an environment cannot be tabled (the caller shades its lights instead)."""


def table_refusal(material, maps=()) -> str | None:
    """Why ``material`` (with the frame's material ``maps``) cannot use the tables, or None."""
    if "k_s" in maps and material.k_s <= 0:
        return "a k_s map over a material k_s of 0: the tables' weights are relative to k_s"
    if material.k_s <= 0:
        return None
    if material.model == "blinn-phong":
        return ("Blinn-Phong's lobe (n·h)^(4h) depends on n and v, not on one direction: "
                "no table holds it")
    if "h" in maps:
        return "a shininess map: the lobe table holds one exponent"
    if material.exponent < 1:
        return (f"an exponent of {material.exponent:g}: below 1 the lobe is too wide for the "
                "horizon's bound")
    return None


#: A lobe table's first size: the cubic's error falls as (Δ·√h)⁴ for a lobe of width
#: ~1/√h; this constant makes it about the sample sky's at h = 32 (5.6e-3 at 33 rows).
LOBE_ERROR = 0.06


def _first_rows(power: float, target: float) -> int:
    """Index into TABLE_ROWS of the first size to try: 33 rows for E(n); for a lobe, the
    size LOBE_ERROR·(Δ·√h)⁴ ≤ target predicts (a wrong guess costs one more build)."""
    if power <= 1:
        return 1
    want = math.pi * math.sqrt(power) * (LOBE_ERROR / target) ** 0.25 + 1
    return next((j for j, r in enumerate(TABLE_ROWS) if r >= want), len(TABLE_ROWS) - 1)


def _sized(weighted, power, target, on_size=None) -> CubicTable:
    """The table of the fewest TABLE_ROWS rows whose estimate is within ``target``: from the
    first size's estimate, the next tried is the one the cubic's Δ⁴ predicts."""
    i = _first_rows(power, target)
    tried = None
    while True:
        table = cubic_table(weighted, power, TABLE_ROWS[i])
        if on_size is not None:
            on_size(table)
        if table.estimate <= target:
            return table
        if i == len(TABLE_ROWS) - 1:
            raise TablesUnfit(f"the largest table ({table.rows} rows) errs by an estimated "
                              f"{table.estimate:.2g}, over its share {target:.2g} of --env-error")
        want = (table.rows - 1) * (table.estimate / target) ** 0.25 + 1
        nxt = next((j for j in range(i + 1, len(TABLE_ROWS)) if TABLE_ROWS[j] >= want),
                   len(TABLE_ROWS) - 1)
        if tried is not None and nxt <= tried:
            nxt = tried + 1
        i = tried = nxt


def environment_tables(radiance, material, *, rotation: float = 0.0, intensity: float = 1.0,
                       max_error: float = 1e-3, on_size=None) -> EnvTables:
    """The kernels' tables of an environment map for ``material`` (Phong), each sized so
    that its estimate is within TABLE_SHARE of ``max_error``.

    Raises
    ------
    TablesUnfit
        The material or the map cannot be tabled within the budget (its message says why).
    """
    t0 = time.perf_counter()
    why = table_refusal(material)
    if why:
        raise TablesUnfit(why)
    L = np.asarray(radiance, np.float64)
    if L.ndim == 2:
        L = L[..., None]
    if L.shape[2] == 1:
        L = np.repeat(L, 3, axis=2)
    H, W = L.shape[:2]
    lum = L.sum(-1)
    median = float(np.median(lum))
    weighted = weighted_map(L, intensity)
    target = TABLE_SHARE * float(max_error)
    # the sun: the texels over SUN_RATIO x the median; where the tables then miss their
    # budget (a bright region left in them), the next ratio splits out more
    for k, ratio in enumerate(SUN_RATIOS):
        sun = lum > ratio * median
        if int(sun.sum()) > MAX_SUN_TEXELS:
            raise TablesUnfit(f"{int(sun.sum())} texels are over {ratio:g}x the median, more "
                              f"than the {MAX_SUN_TEXELS} a table path shades one by one")
        sky = np.where(sun[..., None], 0.0, weighted)
        try:
            diffuse = _sized(sky, 1.0, target, on_size)
            specular = None
            if material.k_s > 0:
                specular = _sized(sky, float(material.exponent), target, on_size)
            break
        except TablesUnfit:
            if k == len(SUN_RATIOS) - 1:
                raise
    sun_E = weighted[sun]
    d = texel_directions(W, H)[sun] @ rotation_about_up(rotation).T
    estimate = max(diffuse.estimate, 0.0 if specular is None else specular.estimate)
    lit = sun_E.max(axis=1, initial=0.0) > 0 if len(sun_E) else np.zeros(0, bool)
    power = sky.reshape(-1, 3).sum(axis=0)
    return EnvTables(diffuse=diffuse, specular=specular, sun_l=d[lit], sun_radiance=sun_E[lit],
                     power=power, radiance_max=np.where(sun[..., None], 0.0, L).reshape(-1, 3)
                     .max(axis=0) * float(intensity),
                     lune=(lune_weights(specular.power) if specular is not None
                           else np.zeros(2 * LUNE_STEPS + 1)),
                     diffuse_floor=diffuse.least,
                     texel_angle=max(math.pi / (H - 1), 2.0 * math.pi / (W - 1)), rotation=float(rotation),
                     estimate=estimate, max_error=float(max_error),
                     seconds=time.perf_counter() - t0)


def horizon_budget(tables: EnvTables) -> float:
    """The horizon's share of the budget: a pixel's error is at most max(e_d, e_s)·pixel +
    (1 + e_s)·S·C (e the tables' estimates, S·C the lobe the table counts below the
    tangent plane), so S·C ≤ ε_h·D·E with ε_h = (ε − max(e_d, e_s))/(1 + e_s) keeps it ≤ ε."""
    e_s = 0.0 if tables.specular is None else tables.specular.estimate
    return max(tables.max_error - tables.estimate, 0.0) / (1.0 + e_s)


def diffuse_lower_bound(tables: EnvTables, n: np.ndarray) -> np.ndarray:
    """(P, 3): E(n) from below, from the nearest node of the diffuse table: |E(a) − E(b)| ≤
    P_c·|a − b| (|max(a·l, 0) − max(b·l, 0)| ≤ |a − b| for unit l), so E(n) ≥ E(node) −
    P_c·|n − node|. Exact node values; no interpolation error enters."""
    d = tables.diffuse
    n = np.asarray(n, np.float64).reshape(-1, 3)
    rot = math.radians(tables.rotation % 360.0)
    y, x = env_table_coords(n, rot, d.rows, d.cols)
    iy = np.clip(np.rint(y), 1, d.rows).astype(np.int64)
    ix = np.mod(np.rint(x), d.cols).astype(np.int64)
    lat = 0.5 * np.pi - (iy - 1) * (np.pi / (d.rows - 1))
    lon = np.pi - ix * (2.0 * np.pi / d.cols) + rot
    c = np.cos(lat)
    node = np.stack([np.sin(lon) * c, np.sin(lat), np.cos(lon) * c], axis=-1)
    chord = np.sqrt(np.einsum("ij,ij->i", n - node, n - node))
    return np.maximum(d.values[iy, ix] - chord[:, None] * tables.power[None, :], 0.0)


#: Latitudes of R above the tangent plane at which :func:`lune_weights` are tabulated.
LUNE_STEPS = 256
#: The texels' sum of the lune's weights against its integral (a smooth integrand on
#: texels far smaller than the lobe): taken as at most this much more.
LUNE_MARGIN = 1.1


def lune_weights(exponent: float, steps: int = LUNE_STEPS) -> np.ndarray:
    """(2·steps + 1,): G(e_k) = ∫ max(l·R, 0)^h dω over the directions l below a plane that R
    rises e_k = (k − steps)·(π/2)/steps above (below it where e < 0; unit radiance): over
    the polar angle θ from R, the arc below the plane is 2·acos(tan e/tan θ) (clipped: 2π
    where the whole circle is below, 0 where none is), so G(e) = ∫_{max(e,0)}^{π/2} cos^h θ
    sin θ · 2 acos(tan e/tan θ) dθ (Gauss-Legendre, 256 nodes on each side of |e|). G
    falls as e grows: a pixel takes the value of the node at or below its e."""
    x, wq = np.polynomial.legendre.leggauss(256)

    def part(a, b, e):
        th = a + (b - a) * 0.5 * (x + 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.tan(e) / np.tan(th), -1.0, 1.0)
        f = np.cos(th) ** exponent * np.sin(th) * 2.0 * np.arccos(t)
        return 0.5 * (b - a) * float(wq @ f)

    out = np.empty(2 * steps + 1)
    for k in range(2 * steps + 1):
        e = 0.5 * np.pi * (k - steps) / steps
        if k == 2 * steps:
            out[k] = 0.0
        elif e >= 0:
            out[k] = part(e, 0.5 * np.pi, e)
        else:                 # the whole circle below up to |e|, then the arc
            out[k] = part(0.0, -e, e) + part(-e, 0.5 * np.pi, e)
    return out


def lune_bound(G: np.ndarray, NoV, texel_angle: float) -> np.ndarray:
    """(P,) float64: a bound of Σ_t ω_t max(l_t·R, 0)^h over the texels below a pixel's
    tangent plane (unit radiance), R rising e = asin(n·v) above it: G at the node at or below
    e − ``texel_angle`` (G falls as e grows; a texel whose centre is below the plane lies
    below the plane raised by its own size, so the texels' sum is the integral below that
    plane, within LUNE_MARGIN for the lobe's variation over a texel). ∞ where n·v ≤ 0."""
    c = np.asarray(NoV)
    steps = (len(G) - 1) // 2
    k = np.arcsin(np.clip(c, 0.0, 1.0).astype(np.float32))
    k -= np.float32(texel_angle)
    k *= np.float32(2.0 * steps / np.pi)
    k += np.float32(steps)
    g = np.asarray(G, np.float64)[np.clip(np.floor(k), 0, 2 * steps).astype(np.int32)]
    g[~(c > 0)] = np.inf
    return g


def horizon_misses(tables: EnvTables, material, NoV, diffuse, specular, normals) -> np.ndarray:
    """Which pixels (bool (P,)) the tables cannot shade within the budget: those where the
    lobe the table counts below the tangent plane, at most L_max,c·G(e)·LUNE_MARGIN (the
    tabled texels' largest radiance over the lune of :func:`lune_weights`, e = asin(n·v)
    the rise of R over the plane), may exceed ε_h of the diffuse term
    (:func:`horizon_budget`), E(n) taken from below: first its least value over the
    sphere (:attr:`EnvTables.diffuse_floor`), then, for the pixels that fail that, its
    own (:func:`diffuse_lower_bound`).

    ``NoV`` (P,): the pixels' n·v; ``diffuse``, ``specular`` (P, 3): their weights of
    the two terms (albedo and maps over the material's k_d and k_s·C_s, as
    :func:`clphong.io.envmap.frame_pairs`; Fresnel's W ≤ 1 is left out, in the bound's
    favour); ``normals`` (P, 3): their normals, any length (read only where the first
    test fails). A pixel seen from behind (n·v ≤ 0) with a specular weight misses.
    Without a specular term none does."""
    c = np.asarray(NoV).reshape(-1)
    if tables.specular is None or material.k_s <= 0 or not len(c):
        return np.zeros(len(c), bool)
    # k_s·C_s; a channel where C_s is 0 takes 1 (a specular-colour map's weights are the
    # map itself there: clphong.io.envmap._probe_weights)
    cs = np.asarray(material.specular_color, np.float64)
    ks = material.k_s * (np.ones(3) if material.fresnel == "schlick" else np.where(cs > 0, cs, 1.0))
    g = lune_bound(tables.lune, c, tables.texel_angle)
    eps = horizon_budget(tables) * material.k_d
    d = np.asarray(diffuse).reshape(-1, 3)
    sp = np.asarray(specular).reshape(-1, 3)
    K = LUNE_MARGIN * ks * tables.radiance_max
    F = eps * tables.diffuse_floor
    miss = np.zeros(len(c), bool)
    for ch in range(3):            # a column at a time: no (P, 3) temporaries
        hidden = g * (sp[:, ch] * K[ch])
        hidden[sp[:, ch] == 0] = 0.0
        miss |= hidden > d[:, ch] * F[ch]
    idx = np.flatnonzero(miss)
    if len(idx):
        n = np.asarray(normals, np.float64).reshape(-1, 3)[idx]
        n /= np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
        E = diffuse_lower_bound(tables, n)
        hidden = g[idx, None] * sp[idx] * K
        hidden[sp[idx] == 0] = 0.0
        miss[idx] = (hidden > eps * d[idx] * E).any(axis=1)
    return miss
