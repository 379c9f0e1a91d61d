"""Lat-long tables of an environment's zonal sums, exact at their nodes (issue 25, first layer).

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

The kernels do not use these tables yet: this is the exact half of the table path that
issue 25 plans (a sun split out as lights, the specular horizon, Blinn-Phong and per-pixel
h are not here).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .environment import _latitudes, texel_solid_angles

__all__ = ["ZonalTable", "weighted_map", "zonal_table", "lookup"]


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


def zonal_table(weighted: np.ndarray, power: float, rows: int, step: int = 1) -> ZonalTable:
    """The table of ``Σ_t E_t max(d·l_t, 0)^power`` at ``rows`` latitudes and every ``step``-th
    map column (module docstring). ``weighted``: :func:`weighted_map`'s (H, W, C)."""
    H, W, C = weighted.shape
    N = W - 1
    if rows < 2 or step < 1 or N % step:
        raise ValueError(f"a table needs rows >= 2 and a step dividing {N} (the map's "
                         f"{W} columns less the repeated meridian), not rows={rows}, step={step}")
    M = weighted[:, :N].copy()
    M[:, 0] += weighted[:, N]                     # the last column is the first meridian
    # The map rows' spectra, (m, h, c) as real pairs: the kernel's spectrum is real (the
    # kernel is even in the longitude difference), so each frequency's sum over the map
    # rows is one real (1 × h) @ (h × 2c) product.
    F = np.fft.rfft(M, axis=1)                    # (H, N//2+1, C)
    Fm = np.ascontiguousarray(F.transpose(1, 0, 2)).view(np.float64)      # (N//2+1, H, 2C)
    lat_t = _latitudes(H, np.arange(H))
    half = np.cos(2.0 * np.pi * np.arange(N // 2 + 1) / N)
    cos_dlon = np.concatenate([half, half[1:(N + 1) // 2][::-1]])          # even to the bit
    cols = N // step + 1
    out = np.empty((rows, cols, C))
    lats = _latitudes(rows, np.arange(rows))

    def row(i):
        lat = lats[i]
        # map rows 90° or more away in latitude have k = 0 everywhere: skipped, exactly
        near = np.flatnonzero(np.cos(lat - lat_t) > 0.0)
        k = np.maximum(np.sin(lat) * np.sin(lat_t[near])[:, None]
                       + (np.cos(lat) * np.cos(lat_t[near]))[:, None] * cos_dlon[None, :], 0.0)
        if power != 1:
            k **= power
        K = np.ascontiguousarray(np.fft.rfft(k, axis=1).real.T)[:, None, :]   # (m, 1, h)
        G = (K @ Fm[:, near, :])[:, 0, :].view(np.complex128)                 # (m, C)
        g = np.fft.irfft(G, n=N, axis=0)
        out[i, :-1] = g[::step]
        out[i, -1] = g[0]

    with ThreadPoolExecutor(max(1, min(os.cpu_count() or 1, 8))) as pool:
        list(pool.map(row, range(rows)))       # numpy's FFTs and products release the GIL
    return ZonalTable(out, float(power))


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
