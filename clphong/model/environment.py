"""Environment lights as directional lights, with a measured error.

An environment light is a latitude-longitude map of radiance at infinity. Its
meaning is the limit of directional lights: every texel is a directional light
from the texel's direction whose radiance (the ``color x intensity`` of a
``directional`` light) is the texel's radiance times its solid angle. The
kernels shade a few hundred to a few thousand directional lights, not half a
million, so :func:`environment_lights` clusters the texels into fewer lights
and measures what that costs.

Orientation (OpenEXR's ``ImfEnvmap.h``, ``LatLongMap``)
------------------------------------------------------
+y is up; latitude 0, longitude 0 looks along +z, longitude +pi/2 along +x.
Pixel *positions* map linearly: pixel (0, 0) is latitude +pi/2, longitude +pi;
pixel (W - 1, H - 1) latitude -pi/2, longitude -pi, so the first and last
columns are the same meridian and the first and last rows the poles. A texel's
direction is ``(sin lon cos lat, sin lat, cos lon cos lat)`` at its position
(:func:`texel_directions`). Its solid angle is that of the cell
``[x - 1/2, x + 1/2] x [y - 1/2, y + 1/2]`` mapped the same way and clipped to
the sphere (:func:`texel_solid_angles`): the first and last columns and rows get
half cells, and the solid angles sum to 4 pi. (Maps written with the other
common convention, texel centres at ``(x + 1/2)/W``, are then off by half a
texel, 0.18 degrees at 1024 x 512.) ``rotation`` turns the map about +y by that
many degrees, counter-clockwise seen from above: content at longitude ``lon``
moves to ``lon + rotation`` (:func:`rotation_about_up`).

The method: a variance-cut light tree
-------------------------------------
The texels are split recursively into lat-long rectangles. Each step splits
the leaf with the largest energy-weighted angular variance ``e - |m|^2/e``
(``e = Σ w``, ``m = Σ w·l`` over its texels, ``w`` the texel's energy summed
over the channels) at the row or column that minimises the children's sum of it
(summed-area tables make every candidate O(1)). A leaf becomes one directional
light at ``m̂ = m/|m|`` with, per channel c, radiance ``m_c·m̂`` (``m_c = Σ E_c·l``):
for a leaf wholly on the lit side of a normal n, the diffuse term
``max(n·l, 0)`` is linear in l, so such a leaf's diffuse sum ``n·m_c`` is exact
(up to the channels' directions differing from ``m̂``). What remains is the
terminator (leaves that n·l = 0 cuts: ``max(n·l, 0)`` is convex there, and the
light underestimates) and the specular lobe's curvature over a leaf; both fall
as the leaves shrink, as ``N^-0.75`` or faster for N lights (the clamped
cosine's spherical-harmonic coefficients decay as ``l^-5/2``; measured on the
bench map: 1.18e-3 at 1024 lights, 3.1e-4 at 4096).

The error control: measured on probes
-------------------------------------
The error of N lights is measured against the 4N lights of the same tree on
:data:`PROBES` probe pixels (normals on a Fibonacci sphere, and views on the
hemisphere about each normal, or the orthographic camera's view), shaded with
the scene's material and a white albedo through the model's own terms (diffuse
``max(n·l, 0)``, Phong or Blinn-Phong specular, Schlick's Fresnel); the
relative error per channel is taken on probes ≥ :data:`FLOOR` of the probes'
maximum, as ``clphong bench`` measures images. Because the error of 4N lights
is at most ``4^-0.75`` of that of N, the error of N lights against the exact
texel sum is at most ``|A_N - A_4N| / (1 - 4^-0.75)`` (:data:`EXTRAPOLATION`).
:func:`environment_lights` returns the fewest lights (on a grid of about 6 %
steps) whose estimate is within ``max_error``. ``clphong bench`` measures the
error of the result against the exact float64 texel sum
(:mod:`clphong.reference.environment`) on the bench G-buffer.

What the probes do not cover: per-pixel material maps (the estimate uses the
scene's ``k_d``, ``k_s`` and ``h``), and dark albedo, which raises the
specular term's share of a pixel (the specular term alone converges slower:
about 2e-2 relative at 1024 lights on the bench map).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import across
from .options import DEFAULT_ENV_ERROR, check_env_error

__all__ = ["texel_directions", "texel_solid_angles", "rotation_about_up", "texel_lights",
           "LightTree", "LeafSums", "probe_pixels", "EnvironmentLights", "environment_lights",
           "probe_pairs", "frame_probe_indices", "FrameProbes", "frame_error",
           "ALBEDO_CAP", "folded_albedo", "probe_terms", "probe_sums", "lobe_weights",
           "probe_error", "check_env_error", "DEFAULT_ENV_ERROR", "PROBES", "FLOOR", "REFINE",
           "RATE", "EXTRAPOLATION", "MAX_ENV_LIGHTS", "MIN_LIGHTS"]

#: Probe pixels of the error estimate.
PROBES = 2048
#: Probes (and image pixels) below this fraction of the maximum are not held to
#: a relative error: the issue's "pixels >= 1e-3 of the image maximum".
FLOOR = 1e-3
#: The error of N lights is measured against REFINE·N lights of the same tree.
REFINE = 4
#: The error falls at least as N^-RATE (see the module docstring).
RATE = 0.75
#: |A_N − exact| ≤ |A_N − A_{REFINE·N}| / (1 − REFINE^−RATE): 1.55 for 4 and 0.75.
EXTRAPOLATION = 1.0 / (1.0 - REFINE ** -RATE)
#: At most this many lights per environment light (the kernels' tested range).
MAX_ENV_LIGHTS = 65536
#: The search starts here (fewer lights are never worth the estimate).
MIN_LIGHTS = 16


# ------------------------------------------------------------------------ geometry

def _latitudes(height: int, y) -> np.ndarray:
    """OpenEXR's latitude of pixel row position ``y`` (float): +pi/2 at 0, -pi/2 at H - 1."""
    return -np.pi * (np.asarray(y, np.float64) / (height - 1) - 0.5)


def _longitudes(width: int, x) -> np.ndarray:
    """OpenEXR's longitude of pixel column position ``x``: +pi at 0, -pi at W - 1."""
    return -2.0 * np.pi * (np.asarray(x, np.float64) / (width - 1) - 0.5)


def _check_size(width: int, height: int) -> None:
    if width < 2 or height < 2:
        raise ValueError(f"a latitude-longitude map needs at least 2 x 2 texels, not {width} x {height}")


def texel_directions(width: int, height: int) -> np.ndarray:
    """(H, W, 3) float64 unit directions of the texels (OpenEXR's LatLongMap::direction).

    >>> d = texel_directions(8, 4)
    >>> d[0, 0].round(12).tolist(), d[-1, 0].round(12).tolist()     # the poles
    ([0.0, 1.0, 0.0], [0.0, -1.0, 0.0])
    """
    _check_size(width, height)
    lat = _latitudes(height, np.arange(height))[:, None]
    lon = _longitudes(width, np.arange(width))[None, :]
    c = np.cos(lat)
    # cos(±pi/2) is 6e-17, not 0: the poles exactly (0, ±1, 0)
    c = np.where(np.abs(lat) == np.pi / 2, 0.0, c)
    return np.stack(np.broadcast_arrays(np.sin(lon) * c, np.sin(lat), np.cos(lon) * c), axis=-1)


def texel_solid_angles(width: int, height: int) -> np.ndarray:
    """(H, W) float64 solid angle of each texel's cell, clipped to the sphere; sums to 4 pi.

    The cell of pixel (x, y) is ``[x - 1/2, x + 1/2] x [y - 1/2, y + 1/2]`` in pixel
    positions, clipped to ``[0, W - 1] x [0, H - 1]`` (the lat-long domain), mapped
    to longitudes and latitudes as :func:`texel_directions`: ``Δlon·(sin lat_top −
    sin lat_bottom)``.
    """
    _check_size(width, height)
    x = np.arange(width, dtype=np.float64)
    y = np.arange(height, dtype=np.float64)
    dlon = 2.0 * np.pi * (np.clip(x + 0.5, 0, width - 1) - np.clip(x - 0.5, 0, width - 1)) / (width - 1)
    top = _latitudes(height, np.clip(y - 0.5, 0, height - 1))
    bottom = _latitudes(height, np.clip(y + 0.5, 0, height - 1))
    return (np.sin(top) - np.sin(bottom))[:, None] * dlon[None, :]


def rotation_about_up(degrees: float) -> np.ndarray:
    """The 3 x 3 rotation about +y by ``degrees``: +z turns towards +x (longitude grows)."""
    t = math.radians(float(degrees) % 360.0)
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def texel_lights(radiance, *, rotation: float = 0.0, intensity: float = 1.0):
    """Every texel as a directional light: (l (T, 3) unit towards the light, radiance
    (T, 3) = texel radiance x intensity x solid angle), float64, row-major texel order."""
    L = np.asarray(radiance)
    H, W = L.shape[:2]
    d = texel_directions(W, H).reshape(-1, 3) @ rotation_about_up(rotation).T
    E = L.reshape(-1, 3).astype(np.float64) * (texel_solid_angles(W, H).reshape(-1, 1) * float(intensity))
    return d, E


# ------------------------------------------------------------------------ the tree

def _sat(a: np.ndarray) -> np.ndarray:
    """Summed-area table with a zero first row and column."""
    s = np.zeros((a.shape[0] + 1, a.shape[1] + 1) + a.shape[2:])
    np.cumsum(a, axis=0, out=s[1:, 1:])
    np.cumsum(s[1:, 1:], axis=1, out=s[1:, 1:])
    return s


class LightTree:
    """The variance-cut tree of a map's texels (see the module docstring).

    Parameters
    ----------
    energy : (H, W, 3) array
        Per texel: radiance x solid angle (x intensity), >= 0, float64.
    directions : (H, W, 3) array
        Per texel: unit direction towards it (rotation applied).

    Each node's split is its best row or column cut; its priority is its score,
    capped by its parent's (a child's variance is at most its parent's, and the
    cap keeps that true through the roundings). The leaves after ``n - 1``
    splits (:meth:`lights` of ``n``) are those of the ``n - 1`` nodes of highest
    priority, equal ones by depth and then by their top-left texel: the order in
    which one split at a time of the largest would make them, so they refine
    those of any smaller n, and the same whatever counts were grown before.
    :meth:`grow` makes the nodes in rounds, every candidate at once: a round
    splits every unsplit node whose priority is at least the ``n - 1``-th known
    one (no node below that can be among the first ``n - 1``: its descendants
    rank lower still). Each node's light is summed from its own texels when the
    node is made (not from the summed-area tables, whose roundings scale with
    the whole map's energy).
    """

    def __init__(self, energy: np.ndarray, directions: np.ndarray):
        self.energy = np.asarray(energy, np.float64)
        self.directions = np.asarray(directions, np.float64)
        self.height, self.width = self.energy.shape[:2]
        w = self.energy.sum(axis=-1)
        # one table of (w, w·l): a split's candidates cost four gathers
        self._sat = _sat(np.concatenate([w[..., None], w[..., None] * self.directions], axis=-1))
        # each texel's E_c·l_xyz, (H·W, 9): the small rectangles' moments gather these
        # products rather than form them at each of the ~16 depths a texel is summed at
        self._flat_products = (self.energy[..., :, None] * self.directions[..., None, :]
                               ).reshape(-1, 9)
        #: Every node as (y0, y1, x0, x1); node 0 is the whole map.
        self.nodes = np.zeros((0, 4), np.int64)
        self._prio = np.zeros(0)                 # capped score; -inf: never split
        self._kids = np.zeros((0, 2), np.int64)  # -1 until split
        self._depth = np.zeros(0, np.int64)
        self._l = np.zeros((0, 3))
        self._rad = np.zeros((0, 3))
        #: The nodes split, in order: the first n - 1 give the leaves of n.
        self.split_order = np.zeros(0, np.int64)
        self._exhausted = False
        self._make(np.array([[0, self.height, 0, self.width]]), None, np.array([np.inf]),
                   np.zeros(1, np.int64))

    def _score(self, y0, y1, x0, x1):
        """e − |m|²/e of rectangles (bounds broadcast): the energy-weighted angular variance."""
        s = self._sat
        return self._variance(s[y1, x1] - s[y0, x1] - s[y1, x0] + s[y0, x0])

    @staticmethod
    def _variance(r):
        """e − |m|²/e of the rectangles' sums r (..., 4): (w, w·l)."""
        e = r[..., 0]
        q = r[..., 1] ** 2 + r[..., 2] ** 2 + r[..., 3] ** 2
        return np.maximum(e - q / np.maximum(e, 1e-300), 0.0)

    def _make(self, rects: np.ndarray, scores, cap: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Add nodes (rects (K, 4), at ``depth``) with their scores (None: from the
        tables) capped by ``cap``: their lights from their own texels; their ids."""
        y0, y1, x0, x1 = rects.T
        if scores is None:
            scores = self._score(y0, y1, x0, x1)
        area = (y1 - y0) * (x1 - x0)
        mc = self._moments(y0, y1, x0, x1, area)                      # (node, c, xyz)
        m = mc.sum(axis=1)
        norm = np.sqrt(np.einsum("ij,ij->i", m, m))
        lit = norm > 0
        mh = np.where(lit[:, None], m / np.where(lit, norm, 1.0)[:, None], 0.0)
        # m_c·m̂: the exact diffuse on the lit side; no energy, or none net: no light
        rad = np.where(lit[:, None], np.maximum(np.einsum("ncx,nx->nc", mc, mh), 0.0), 0.0)
        prio = np.minimum(scores, cap)
        prio = np.where((area > 1) & (prio > 0), prio, -np.inf)  # one texel is exact already
        ids = np.arange(len(self.nodes), len(self.nodes) + len(rects))
        self.nodes = np.concatenate([self.nodes, rects])
        self._prio = np.concatenate([self._prio, prio])
        self._kids = np.concatenate([self._kids, np.full((len(rects), 2), -1)])
        self._depth = np.concatenate([self._depth, depth])
        self._l = np.concatenate([self._l, mh])
        self._rad = np.concatenate([self._rad, rad])
        return ids

    #: A rectangle of at least this many texels is summed alone (a slice and a matrix
    #: product); smaller ones together, by gathers, at most CHUNK texels at a time.
    BIG = 64
    CHUNK = 1 << 18

    def _moments(self, y0, y1, x0, x1, area) -> np.ndarray:
        """Σ E_c·l_xyz over each rectangle's own texels, (K, 3, 3): each sum has its own
        roundings only, whatever else the map holds."""
        mc = np.empty((len(area), 3, 3))
        for i in np.flatnonzero(area >= self.BIG):
            E = self.energy[y0[i]:y1[i], x0[i]:x1[i]].reshape(-1, 3)
            mc[i] = E.T @ self.directions[y0[i]:y1[i], x0[i]:x1[i]].reshape(-1, 3)
        small = np.flatnonzero(area < self.BIG)
        ends = np.cumsum(area[small])
        a = 0
        while a < len(small):
            b = max(int(np.searchsorted(ends, (ends[a - 1] if a else 0) + self.CHUNK, "right")),
                    a + 1)
            k = small[a:b]
            w = x1[k] - x0[k]
            # every texel of these rectangles, rectangle by rectangle, row by row
            start = np.concatenate([[0], np.cumsum(area[k])[:-1]])
            owner = np.repeat(np.arange(len(k)), area[k])
            q = np.arange(int(area[k].sum())) - start[owner]
            texel = (y0[k][owner] + q // w[owner]) * self.width + x0[k][owner] + q % w[owner]
            mc[k] = np.add.reduceat(self._flat_products[texel], start, axis=0).reshape(-1, 3, 3)
            a = b
        return mc

    def _split(self, ids: np.ndarray) -> None:
        """Split the nodes ``ids`` at once, each at the row or column cut that minimises
        its parts' summed score (rows first, then columns; the first of equals)."""
        y0, y1, x0, x1 = self.nodes[ids].T
        ny, nx = y1 - y0 - 1, x1 - x0 - 1
        count = ny + nx
        seg = np.repeat(np.arange(len(ids)), count)
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        j = np.arange(int(count.sum())) - start[seg]          # candidate within its node
        row = j < ny[seg]
        c = np.where(row, y0[seg] + 1 + j, x0[seg] + 1 + (j - ny[seg]))
        # the two parts of each cut: (a) above / left of c, (b) below / right of it
        ay0, ay1 = y0[seg], np.where(row, c, y1[seg])
        ax0, ax1 = x0[seg], np.where(row, x1[seg], c)
        by0, by1 = np.where(row, c, y0[seg]), y1[seg]
        bx0, bx1 = np.where(row, x0[seg], c), x1[seg]
        sa = self._score(ay0, ay1, ax0, ax1)
        sb = self._score(by0, by1, bx0, bx1)
        total = sa + sb
        best = np.minimum.reduceat(total, start)
        pick = np.flatnonzero(total == best[seg])
        first = pick[np.unique(seg[pick], return_index=True)[1]]   # per node, its first best
        a = np.stack([ay0[first], ay1[first], ax0[first], ax1[first]], axis=1)
        b = np.stack([by0[first], by1[first], bx0[first], bx1[first]], axis=1)
        cap, depth = self._prio[ids], self._depth[ids] + 1
        ka = self._make(a, sa[first], cap, depth)
        kb = self._make(b, sb[first], cap, depth)
        self._kids[ids] = np.stack([ka, kb], axis=1)

    def _ranked(self) -> np.ndarray:
        """The splittable nodes made so far, highest priority first. Equal priorities
        go by depth, then by the top-left texel (unique among the nodes of one depth,
        which are disjoint): an order of the nodes alone, not of the rounds that made
        them, so the leaves of n never depend on which counts were grown before."""
        ok = np.flatnonzero(self._prio > -np.inf)
        y0, x0 = self.nodes[ok, 0], self.nodes[ok, 2]
        return ok[np.lexsort((x0, y0, self._depth[ok], -self._prio[ok]))]

    @property
    def leaves(self) -> int:
        """The leaves so far: splits + 1."""
        return len(self.split_order) + 1

    def grow(self, n: int) -> int:
        """Make the first ``n - 1`` splits (or every one the map has); the leaves."""
        want = int(n) - 1
        while want > len(self.split_order) and not self._exhausted:
            prio = self._prio
            known = prio[prio > -np.inf]
            # the (n-1)-th priority known; a node below it and its descendants rank lower
            bar = -np.partition(-known, want - 1)[want - 1] if len(known) >= want else -np.inf
            todo = np.flatnonzero((prio >= bar) & (prio > -np.inf) & (self._kids[:, 0] < 0))
            if len(todo):
                self._split(todo)
                continue
            ranked = self._ranked()
            self._exhausted = len(ranked) < want
            self.split_order = ranked[:want]
        return self.leaves

    def leaf_nodes(self, n: int) -> np.ndarray:
        """The nodes that are the leaves after ``n - 1`` splits (grown as needed)."""
        n = max(1, min(n, self.grow(n)))                  # at least the whole map
        split = self.split_order[:n - 1]
        leaf = np.zeros(len(self.nodes), bool)
        leaf[0] = True
        leaf[self._kids[split].ravel()] = True
        leaf[split] = False
        return np.flatnonzero(leaf)

    def lights(self, n: int):
        """The first ``n`` leaves as lights: (l (K, 3) unit towards the light, radiance
        (K, 3)), K ≤ n (leaves without energy give no light)."""
        k = self.leaf_nodes(n)
        l, rad = self._l[k], self._rad[k]
        lit = rad.max(axis=1, initial=0.0) > 0
        return l[lit], rad[lit]


# ------------------------------------------------------------------------ probes

def _fibonacci(n: int, offset: float = 0.5) -> np.ndarray:
    """n points on the unit sphere, a Fibonacci lattice."""
    i = np.arange(n) + offset
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = np.pi * (3.0 - math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), z, r * np.sin(phi)], axis=-1)


def _frame(n: np.ndarray):
    """Two unit tangents orthogonal to each unit row of n."""
    a = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = np.cross(n, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def probe_pairs(count: int = PROBES, view=None):
    """(n, v), (count, 3) each: the probe normals and views.

    ``view`` None (a perspective or metadata camera): normals on a Fibonacci
    sphere, each with a view on its hemisphere (uniform in solid angle, a second
    low-discrepancy sequence); ``view`` a unit vector (an orthographic camera's
    v = −direction): that view, with normals on its hemisphere.
    """
    if view is not None:
        v = np.asarray(view, np.float64)
        v = v / np.linalg.norm(v)
        s = _fibonacci(2 * count)
        # the half of the sphere facing v, rotated so +y (the lattice's pole) is v
        s = s[s[:, 1] > 0][:count]
        t, b = _frame(v[None, :])
        n = s[:, :1] * t + s[:, 1:2] * v[None, :] + s[:, 2:3] * b
        return n, np.broadcast_to(v, n.shape).copy()
    n = _fibonacci(count)
    i = np.arange(count)
    cos_t = 1.0 - (i * 0.7548776662466927 + 0.5) % 1.0           # R2 sequence, uniform on (0, 1]
    phi = 2.0 * np.pi * ((i * 0.5698402909980532 + 0.5) % 1.0)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    t, b = _frame(n)
    v = cos_t[:, None] * n + (sin_t * np.cos(phi))[:, None] * t + (sin_t * np.sin(phi))[:, None] * b
    return n, v


#: Frame probes: normal cells of the octahedral map (FRAME_CELLS² of them) × n·v bins
#: (equal steps of √(n·v), so that grazing views get bins of their own).
FRAME_CELLS = 24
FRAME_NV_BINS = 4


def frame_probe_indices(n, v, count: int = PROBES, seed: int = 0, albedo=None) -> np.ndarray:
    """The indices, ascending, of at most ``count`` probes among a frame's pixels (unit
    normals ``n``, views ``v``, albedos; (P, 3) each, float32 will do: only the cells
    are read from them).

    Stratified: one pixel from each occupied cell of (normal direction, n·v), the
    normal's octahedral map cut into :data:`FRAME_CELLS` ² cells and √(n·v) into
    :data:`FRAME_NV_BINS` bins (the rim of a sphere, a few pixels, gets its own
    probes: the horizon's error is largest at grazing views), the cell's darkest
    albedo channel first (a dark channel is mostly specular, whose relative error
    is the larger), the first such pixel of equals; then pixels drawn at random up to
    ``count``. Seeded: the same frame gives the same probes. Every pixel when there
    are at most ``count``. One sort of the pixels (about 0.2 s at 1920 × 1080)."""
    n = np.asarray(n).reshape(-1, 3)
    P = len(n)
    if P <= count:
        return np.arange(P)
    v = np.asarray(v).reshape(-1, 3)
    one = n.dtype.type(1)
    a = n / np.maximum(across(np.add, np.abs(n)), np.finfo(n.dtype).tiny)[:, None]
    x, z = a[:, 0], a[:, 2]
    low = a[:, 1] < 0                                   # the lower half folded out
    x, z = (np.where(low, (one - np.abs(z)) * np.copysign(one, x), x),
            np.where(low, (one - np.abs(x)) * np.copysign(one, z), z))
    cells = FRAME_CELLS
    cx = np.clip(((x + one) * (cells / 2)).astype(np.int64), 0, cells - 1)
    cz = np.clip(((z + one) * (cells / 2)).astype(np.int64), 0, cells - 1)
    nv = np.clip(np.einsum("ij,ij->i", n, v), 0, 1)
    b = np.minimum((np.sqrt(nv) * FRAME_NV_BINS).astype(np.int64), FRAME_NV_BINS - 1)
    key = ((cx * cells + cz) * FRAME_NV_BINS + b).astype(np.int16)     # < 2^12
    # per pixel its darkest channel (16 bits) above its index: the least of a cell is its
    # darkest pixel, the first of equals; the cells grouped by a radix sort of the keys
    dark = (np.zeros(P, np.int64) if albedo is None else
            (np.clip(across(np.minimum, np.asarray(albedo).reshape(-1, 3)), 0, 1) * 65535)
            .astype(np.int64))
    rank = (dark << 32) | np.arange(P, dtype=np.int64)
    by = np.argsort(key, kind="stable")
    k = key[by]
    starts = np.flatnonzero(np.concatenate([[True], k[1:] != k[:-1]]))
    pick = np.minimum.reduceat(rank[by], starts) & 0xFFFFFFFF
    rng = np.random.default_rng(seed)
    if len(pick) > count:
        pick = rng.choice(pick, count, replace=False)
    elif len(pick) < count:
        taken = np.zeros(P, bool)
        taken[pick] = True
        more: list = []
        need = count - len(pick)
        while need > 0:                   # draws without a permutation of every pixel
            draw = np.unique(rng.integers(0, P, 2 * need))
            draw = draw[~taken[draw]]
            draw = draw[rng.permutation(len(draw))][:need]
            taken[draw] = True
            more.append(draw)
            need -= len(draw)
        pick = np.concatenate([pick, *more])
    return np.sort(pick)


#: The largest folded albedo (diffuse weight / specular weight) a frame's range takes: a
#: pixel without specular (a k_s map of 0) is pure diffuse, which this stands for.
ALBEDO_CAP = 1e3


def folded_albedo(diffuse, specular) -> np.ndarray:
    """a = diffuse weight / specular weight per channel (a pixel's relative error depends on
    this ratio alone), at most :data:`ALBEDO_CAP` (a pixel without specular)."""
    d = np.asarray(diffuse)
    sp = np.asarray(specular)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(sp > 0, d / np.where(sp > 0, sp, 1), ALBEDO_CAP)
    return np.minimum(a, ALBEDO_CAP).astype(d.dtype)


@dataclass(frozen=True)
class FrameProbes:
    """A frame's probes (:func:`clphong.io.envmap.frame_pairs`): ``n``, ``v`` (P, 3) unit
    normals and views; ``diffuse`` and ``specular`` (P, 3) their pixels' weights of the
    material's two terms (a pixel is diffuse·D + specular·S, D = k_d·diffuse sum, S =
    k_s·C_s·specular sum: the albedo, and the k_d, k_s and specular-colour maps against
    the material's values); and over every shaded pixel of the frame, per channel: the
    range ``low``..``high`` of the folded albedo diffuse/specular (:func:`folded_albedo`)
    and the largest weights ``diffuse_max``, ``specular_max``. :func:`frame_error` says
    how the estimate holds them."""

    n: np.ndarray
    v: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    low: np.ndarray
    high: np.ndarray
    diffuse_max: np.ndarray
    specular_max: np.ndarray

    def __post_init__(self):
        n, v, d, sp = (np.asarray(x, np.float64).reshape(-1, 3)
                       for x in (self.n, self.v, self.diffuse, self.specular))
        lo, hi, dm, sm = (np.asarray(x, np.float64).reshape(3)
                          for x in (self.low, self.high, self.diffuse_max, self.specular_max))
        if not (len(n) == len(v) == len(d) == len(sp)) or not len(n):
            raise ValueError(f"frame probes: {len(n)} normals, {len(v)} views, {len(d)} and "
                             f"{len(sp)} weights; give as many of each, at least one")
        if not (np.isfinite([*lo, *hi, *dm, *sm]).all() and (0 <= lo).all() and (lo <= hi).all()
                and (dm >= 0).all() and (sm >= 0).all()):
            raise ValueError(f"frame probes: an albedo range of finite 0 <= low <= high, not "
                             f"{lo.tolist()} .. {hi.tolist()}, and weights >= 0")
        for name, x in (("n", n), ("v", v), ("diffuse", d), ("specular", sp), ("low", lo),
                        ("high", hi), ("diffuse_max", dm), ("specular_max", sm)):
            object.__setattr__(self, name, x)

    @property
    def albedo(self) -> np.ndarray:
        """The probes' folded albedos (:func:`folded_albedo`)."""
        return folded_albedo(self.diffuse, self.specular)

    def digest(self) -> str:
        """SHA-256 of every array: the conversion caches' name for these probes."""
        h = hashlib.sha256()
        for f in dataclasses.fields(self):
            h.update(np.ascontiguousarray(getattr(self, f.name), np.float64).tobytes())
        return h.hexdigest()


def frame_error(coarse: np.ndarray, fine: np.ndarray, probes: FrameProbes,
                floor: float = FLOOR) -> float:
    """The relative error of ``coarse`` against ``fine`` (each (P, 6): the probes' D and
    S terms, :class:`LeafSums` with ``terms=True``) over every pixel the frame may hold
    at each probe's normal and view that is above the floor.

    A pixel of weights (α, β) is α·D + β·S; its relative error in a channel depends on
    its folded albedo a = α/β alone and is a monotone function of it (|a·ΔD + ΔS| /
    (a·D + S)), so over an interval of a it is largest at an end. The frame's pixels
    have a in [low, high], α ≤ diffuse_max and β ≤ specular_max; the floor is ``floor``
    of the largest probe pixel (the probes' own weights). The brightest such pixel of
    a given a is min(specular_max, diffuse_max/a)·(a·D + S), rising then falling in a,
    so the a whose pixels can reach the floor are an interval [a₁, a₂]: the error is
    taken at both ends of [low, high] ∩ [a₁, a₂], per probe and channel."""
    Dc, Sc, Df, Sf = coarse[:, :3], coarse[:, 3:], fine[:, :3], fine[:, 3:]
    top = float(np.max(probes.diffuse * Df + probes.specular * Sf, initial=0.0))
    if not top > 0:
        return 0.0
    lim = floor * top
    am = probes.diffuse_max
    bm = np.maximum(probes.specular_max, am / ALBEDO_CAP)   # a ≤ the cap: β ≥ α/cap
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # a₁: bm·(a·D + S) = lim; a₂: am·(D + S/a) = lim (none where am·D reaches it)
        a1 = np.where(Df > 0, (lim / bm - Sf) / np.where(Df > 0, Df, 1),
                      np.where(bm * Sf >= lim, -np.inf, np.inf))
        a2 = np.where(am * Df >= lim, np.inf, Sf / (lim / am - Df))
        lo = np.maximum(probes.low, a1)
        hi = np.minimum(probes.high, np.nan_to_num(a2, nan=np.inf))
        held = lo <= hi
        err = 0.0
        for a in (lo, hi):
            truth = a * Df + Sf
            ok = held & (truth > 0)
            e = np.abs(a * Dc + Sc - truth)[ok] / truth[ok]
            err = max(err, float(np.max(e, initial=0.0)))
    return err


def _power(x: np.ndarray, k: float) -> np.ndarray:
    """x^k for x in [0, 1], in place where it can: binary powering for a whole k (as
    SPEC_INT_POW), else exp·log; 0⁰ := 1."""
    if float(k).is_integer() and 0 <= k <= 1 << 20:
        K = int(k)
        if K == 0:
            return np.ones_like(x)
        s = None
        while K:
            if K & 1:
                s = x.copy() if s is None else np.multiply(s, x, out=s)
            K >>= 1
            if K:
                np.multiply(x, x, out=x)
        return s
    with np.errstate(divide="ignore"):
        return np.where(x > 0, np.exp(k * np.log(np.where(x > 0, x, 1.0))), 1.0 if k == 0 else 0.0)


def probe_sums(n, v, l, radiance, material, *, chunk: int = 128, specular: bool | None = None,
               threads: int | None = None):
    """:func:`_probe_sums` with the probes split among ``threads`` threads (default: the
    CPU count; numpy's array operations release the GIL): the same sums, to the bit (each
    probe's sum is its own)."""
    n = np.asarray(n, np.float64)
    v = np.asarray(v, np.float64)
    threads = max(1, min(threads or os.cpu_count() or 1, len(n) // 256 or 1))
    if threads == 1:
        return _probe_sums(n, v, l, radiance, material, chunk=chunk, specular=specular)
    parts = np.array_split(np.arange(len(n)), threads)
    with ThreadPoolExecutor(threads) as pool:
        done = list(pool.map(lambda idx: _probe_sums(n[idx], v[idx], l, radiance, material,
                                                     chunk=chunk, specular=specular), parts))
    return (np.concatenate([d for d, _ in done]), np.concatenate([q for _, q in done]))


def _probe_sums(n, v, l, radiance, material, *, chunk: int = 128, specular: bool | None = None):
    """The model's diffuse and specular sums of directional lights at probe pixels.

    ``diffuse`` (P, 3) = Σ_i L_i·max(n·l_i, 0); ``specular`` (P, 3) =
    Σ_i L_i·W_i·s_i with s the Phong ``max(r·v, 0)^h`` or Blinn-Phong
    ``max(n·h, 0)^(4h)`` weight where n·l > 0 (the SPEC_COS forms: r·v =
    2(n·l)(n·v) − l·v, (n·h)² = (n·l + n·v)²/(2 + 2 l·v)) and W Schlick's
    ``f0 + (1 − f0)(1 − cos α)^5`` with ``material.fresnel == "schlick"`` (cos α
    = v·h for Blinn-Phong, n·v for Phong), else 1. Twins of
    :mod:`clphong.reference.shading` on dot products (tests/model/test_environment.py
    holds them to it); ``chunk`` lights at a time (128: the arrays stay in cache,
    about 16 ns a pair on one core). ``specular``: whether to form the specular
    sum (default: ``material.k_s > 0``); else it is 0.
    """
    n = np.asarray(n, np.float64)
    v = np.asarray(v, np.float64)
    l = np.asarray(l, np.float64)
    radiance = np.asarray(radiance, np.float64)
    P = len(n)
    want_specular = material.k_s > 0 if specular is None else bool(specular)
    diffuse = np.zeros((P, 3))
    specular = np.zeros((P, 3))
    blinn = material.model == "blinn-phong"
    k = material.exponent
    f0 = np.asarray(material.f0, np.float64) if material.fresnel == "schlick" else None
    NoV = np.einsum("ij,ij->i", n, v)[:, None]
    for a in range(0, len(l), chunk):
        li, Li = l[a:a + chunk], radiance[a:a + chunk]
        NoL = n @ li.T
        LoV = v @ li.T
        diffuse += np.maximum(NoL, 0.0) @ Li
        if not want_specular:
            continue
        s = _lobe(NoL, NoV, LoV, blinn, k)
        if f0 is None:
            specular += s @ Li
        else:
            cos_a = np.sqrt(np.maximum(0.5 * (1.0 + LoV), 0.0)) if blinn else np.broadcast_to(NoV, s.shape)
            g = (1.0 - np.clip(cos_a, 0.0, 1.0)) ** 5
            for c in range(3):
                specular[:, c] += (s * (f0[c] + (1.0 - f0[c]) * g)) @ Li[:, c]
    return diffuse, specular


def _lobe(NoL, NoV, LoV, blinn: bool, k: float) -> np.ndarray:
    """The specular weight of each (probe, light) pair without Fresnel: Blinn-Phong's
    ``(n·h)^k`` or Phong's ``(r·v)^k`` in their SPEC_COS forms, 0 where n·l ≤ 0."""
    if blinn:
        # (n·h)² = max(n·l + n·v, 0)²/(2 + 2 l·v), at most 1; 0 where l = −v
        x = np.add(NoL, NoV)
        np.maximum(x, 0.0, out=x)
        np.multiply(x, x, out=x)
        hh = np.multiply(LoV, 2.0)
        hh += 2.0
        np.divide(x, np.maximum(hh, 1e-300), out=x)
        np.minimum(x, 1.0, out=x)
        s = _power(x, k / 2.0)
    else:
        x = np.multiply(NoL, 2.0 * NoV)
        x -= LoV
        np.maximum(x, 0.0, out=x)
        s = _power(x, k)
    return np.where(NoL > 0, s, 0.0)


def lobe_weights(n, v, l, material) -> np.ndarray:
    """(P, K): the specular weight of light ``l[k]`` at probe (``n[p]``, ``v[p]``) as
    :func:`probe_sums` forms it, less Fresnel (a factor of at most 1)."""
    n, v, l = (np.asarray(a, np.float64) for a in (n, v, l))
    NoV = np.einsum("ij,ij->i", n, v)[:, None]
    return _lobe(n @ l.T, NoV, v @ l.T, material.model == "blinn-phong", material.exponent)


def probe_pixels(n, v, l, radiance, material, albedo=None) -> np.ndarray:
    """(P, 3): the probes' pixel values, without ambient (k_d·C_d·diffuse +
    k_s·C_s·specular, Fresnel's W in the specular), from the float64 sums of
    :func:`probe_sums`; C_d is ``albedo`` (P, 3), or white. The conversion's default probe
    shader; a device layer may pass another with the same meaning
    (``environment_lights(shade=...)``)."""
    return _pixels(*probe_sums(n, v, l, radiance, material), material, albedo)


class LeafSums:
    """The probes' pixel sums (``shade``, by default :func:`probe_pixels`) of a tree's
    first k leaves, for the k the search asks for, each formed from the set already
    summed that differs least.

    The leaves of two counts differ only where one set split further: the sums of k
    are those of k′ minus the leaves of k′ that k lacks, plus k's that k′ lacks. The
    search's bisection steps a few hundred splits at a time among ten thousand leaves,
    so this sums a few thousand lights where a fresh sum would take every one. The
    result differs from a fresh sum by roundings of the order of the larger sum's (the
    shader's own: 1e-16 relative in float64 numpy, within 5e-6 on a device's accurate
    path, against estimates of 1e-3); tests/model/test_environment.py holds it to a
    fresh sum.
    """

    def __init__(self, tree: LightTree, n, v, material, shade=probe_pixels, terms: bool = False):
        self.tree, self.n, self.v, self.material, self.shade = tree, n, v, material, shade
        #: the two terms apart, (P, 6), k_d·diffuse and k_s·C_s·specular (probe_terms, or
        #: the shader's ``terms``); else the white-albedo pixel (P, 3)
        self.terms = bool(terms)
        if self.terms and shade is not probe_pixels and not callable(getattr(shade, "terms", None)):
            raise TypeError(f"a frame's probes need the diffuse and specular terms apart: "
                            f"{type(shade).__name__} has no terms(n, v, l, radiance, material)")
        self.done: dict[int, tuple] = {}       # k -> (leaf ids, pixels)

    def _sum(self, ids: np.ndarray) -> np.ndarray:
        rad = self.tree._rad[ids]
        lit = rad.max(axis=1, initial=0.0) > 0
        if not lit.any():
            return np.zeros((len(self.n), 6 if self.terms else 3))
        l, rad = self.tree._l[ids][lit], rad[lit]
        if not self.terms:
            return np.asarray(self.shade(self.n, self.v, l, rad, self.material), np.float64)
        terms = probe_terms if self.shade is probe_pixels else self.shade.terms
        return np.asarray(terms(self.n, self.v, l, rad, self.material), np.float64)

    def __call__(self, k: int) -> np.ndarray:
        """(P, 3): the probes' pixels lit by the first ``k`` leaves."""
        if k in self.done:
            return self.done[k][1]
        leaves = self.tree.leaf_nodes(k)
        best = None
        for ids, p in self.done.values():
            gone = np.setdiff1d(ids, leaves, assume_unique=True)
            new = np.setdiff1d(leaves, ids, assume_unique=True)
            if best is None or len(gone) + len(new) < best[0]:
                best = (len(gone) + len(new), gone, new, p)
        if best is None or best[0] >= len(leaves):
            p = self._sum(leaves)
        else:
            _, gone, new, p = best
            p = p + self._sum(new) - self._sum(gone)
        self.done[k] = (leaves, p)
        return p


def probe_terms(n, v, l, radiance, material) -> np.ndarray:
    """(P, 6): the probes' two terms apart, k_d·diffuse and k_s·C_s·specular (Fresnel's W in
    the specular), from the float64 sums of :func:`probe_sums`: a pixel of albedo a is
    a·(first three) + (last three). A probe shader may offer the same as its ``terms``
    method (:class:`clphong.device.envprobe.DeviceProbeShader`: one launch)."""
    d, sp = probe_sums(n, v, l, radiance, material)
    kd, ks = _term_weights(material)
    return np.concatenate([kd * d, ks * sp], axis=1)


def _term_weights(material):
    """(k_d, k_s·C_s): the material's weights of the diffuse and specular sums (with
    Schlick's Fresnel, its W is in the specular sum and C_s is white)."""
    cs = np.ones(3) if material.fresnel == "schlick" else \
        np.asarray(material.specular_color, np.float64)
    return material.k_d, material.k_s * cs


def _pixels(diffuse, specular, material, albedo=None) -> np.ndarray:
    """Probe pixel values: k_d·C_d·diffuse + k_s·C_s·specular (Fresnel's W in specular),
    C_d ``albedo`` or white."""
    kd, ks = _term_weights(material)
    d = diffuse if albedo is None else np.asarray(albedo, np.float64) * diffuse
    return kd * d + ks * specular


def probe_error(value, truth, floor: float = FLOOR) -> float:
    """max |value − truth|/truth over channels where truth ≥ ``floor`` of its maximum (0 if none)."""
    top = float(np.max(truth, initial=0.0))
    if not top > 0:
        return 0.0
    big = truth >= floor * top
    return float(np.max(np.abs(value - truth)[big] / truth[big], initial=0.0))


# ------------------------------------------------------------------------ the conversion

@dataclass(frozen=True)
class EnvironmentLights:
    """An environment light as directional lights, and what it costs.

    Attributes
    ----------
    l : (K, 3) float64
        Unit directions towards the lights (a directional light's ``direction``
        is ``-l``).
    radiance : (K, 3) float64
        Per light and channel: the summed texel radiance x solid angle x intensity,
        projected on ``l`` (see the module docstring).
    texels : int
        The map's texels (W x H).
    estimated_error : float
        The estimate of the max relative error against the exact texel sum
        (probes, extrapolated; 0 when every texel is its own light).
    max_error : float
        The target.
    met : bool
        Whether ``estimated_error <= max_error`` (False where ``max_lights``
        stopped the search).
    probes : int
    seconds : float
        Time of the conversion.
    """

    l: np.ndarray = field(repr=False)
    radiance: np.ndarray = field(repr=False)
    texels: int
    estimated_error: float
    max_error: float
    met: bool
    probes: int
    seconds: float

    @property
    def count(self) -> int:
        return len(self.l)


def environment_lights(radiance, material, *, rotation: float = 0.0, intensity: float = 1.0,
                       view=None, max_error: float = DEFAULT_ENV_ERROR,
                       max_lights: int = MAX_ENV_LIGHTS, probes: int = PROBES,
                       progress=None, shade=None, pairs=None) -> EnvironmentLights:
    """The fewest directional lights whose estimated error is within ``max_error``.

    Parameters
    ----------
    radiance : (H, W, 3) array
        The lat-long map (W = 2H), finite and >= 0.
    material : clphong.model.scene.Material
        The scene's material (the probes are shaded with it).
    rotation, intensity : float
        The light's ``rotation`` (degrees about +y) and ``intensity``.
    view : (3,) array, optional
        An orthographic camera's unit v (towards the viewer); None otherwise.
    max_error : float
        Relative error target against the exact texel sum (module docstring).
    max_lights, probes : int
        Most lights to return; probe pixels of the estimate.
    progress : callable, optional
        Called as ``progress(k, e)`` after each estimate of the search: k lights,
        estimated relative error e.
    shade : callable, optional
        The probe shader, ``shade(n, v, l, radiance, material)`` → (P, 3), with the
        meaning of :func:`probe_pixels` (the default, float64 numpy).
        :class:`clphong.device.envprobe.DeviceProbeShader` shades them on an OpenCL
        device, at the probes' float32 roundings: that moves an estimate by about 1e-4
        of itself, so the search ends on the same count or, where an estimate lies
        that close to the target, a neighbouring one.
    pairs : FrameProbes or ((P, 3), (P, 3)) arrays, optional
        The probes instead of :func:`probe_pairs` of ``probes`` and ``view``: a frame's
        own (:class:`FrameProbes`; :func:`clphong.io.envmap.frame_pairs`), so that the
        estimate speaks of that frame's normals, views and albedos
        (:func:`frame_error`; ``shade`` then needs ``terms``, as
        :class:`~clphong.device.envprobe.DeviceProbeShader` has), or unit normals and
        views at white albedo.

    Returns
    -------
    EnvironmentLights
    """
    t0 = time.perf_counter()
    max_error = check_env_error(max_error)
    L = np.asarray(radiance)
    H, W = L.shape[:2]
    d = (texel_directions(W, H).reshape(-1, 3) @ rotation_about_up(rotation).T).reshape(H, W, 3)
    E = L.astype(np.float64) * (texel_solid_angles(W, H) * float(intensity))[..., None]
    tree = LightTree(E, d)
    frame = pairs if isinstance(pairs, FrameProbes) else None
    if frame is not None:
        n, v = frame.n, frame.v
    elif pairs is None:
        n, v = probe_pairs(probes, view)
    else:
        n, v = (np.asarray(a, np.float64).reshape(-1, 3) for a in pairs)
        if len(n) != len(v) or not len(n):
            raise ValueError(f"probe pairs: {len(n)} normals, {len(v)} views; give as many "
                             "of each, at least one")
    pixels = LeafSums(tree, n, v, material, shade or probe_pixels,        # each count's, kept
                      terms=frame is not None)
    error = probe_error if frame is None else (lambda a, b: frame_error(a, b, frame))

    def estimate(k: int, fine: int | None = None) -> float:
        """The error estimate of k leaves against ``fine`` ≥ REFINE·k leaves (default
        REFINE·k); 0 where the k leaves are every texel's own light."""
        fine = min(fine or REFINE * k, tree.grow(fine or REFINE * k))
        if fine <= k:                      # nothing left to split: k leaves are every texel's
            e = 0.0
        else:
            # fewer than REFINE·k leaves: the tree ran out of texels to split, so the
            # finer set is exact where it is short of them. More than REFINE·k: at most
            # REFINE^-RATE of k's error, so the same factor holds.
            e = EXTRAPOLATION * error(pixels(k), pixels(fine))
        if progress is not None:
            progress(k, e)
        return e

    def done(k: int, fine: int | None = None) -> EnvironmentLights:
        e = estimate(k, fine)
        l, rad = tree.lights(k)
        return EnvironmentLights(l=l, radiance=rad, texels=H * W, estimated_error=e,
                                 max_error=max_error, met=e <= max_error, probes=len(n),
                                 seconds=time.perf_counter() - t0)

    cap = max(1, min(int(max_lights), H * W))
    # Search: two estimates give the observed rate; each next count is predicted from
    # the last two (at least 1.25x, at most 16x the last failure); then bisection on a
    # geometric grid (~6 % steps) between the last failure and the first success.
    lo, k = 0, min(MIN_LIGHTS, cap)
    e = estimate(k)
    last = None
    while e > max_error and k < cap:
        rate = RATE
        if last is not None and last[1] > e > 0:
            rate = min(max(math.log(last[1] / e) / math.log(k / last[0]), 0.5), 1.5)
        grow_by = 2.0 if e <= 0 else (e / max_error) ** (1.0 / rate) * 1.1
        last, lo = (k, e), k
        k = min(cap, int(math.ceil(k * min(max(grow_by, 1.25), 16.0))))
        e = estimate(k)
    if e > max_error:
        return done(k)                            # max_lights stopped the search
    fine = REFINE * k                             # bisection: every candidate against one fine set
    while lo and k > lo * 1.0625 and k - lo > 1:
        mid = int(round(math.sqrt(lo * k)))
        if mid in (lo, k):
            break
        if estimate(mid, fine) <= max_error:
            k = mid
        else:
            lo = mid
    return done(k, fine)
