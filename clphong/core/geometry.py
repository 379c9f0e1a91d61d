"""Geometry shared by the kernels' host side and the float64 reference.

One implementation of each step that both sides must take the same way: unit
normals from stored ones, the frame's bounding box and rebasing origin, the
orthographic view vector and Blinn's half vector, and the hi + lo split of a
float64 value into two float32s.
"""

from __future__ import annotations

import numpy as np

__all__ = ["across", "unit_normal_planes", "position_bounds", "origin_of_bounds", "frame_origin",
           "split_hi_lo", "view_vector", "half_vector"]


def across(ufunc, a: np.ndarray) -> np.ndarray:
    """``ufunc`` over the three columns of an (N, 3) array, a column at a time: the same
    values as ``ufunc.reduce(a, axis=1)`` (and, or, max, min), about ten times faster at
    a few million rows (numpy's reduce of a three-long axis loops per row)."""
    return ufunc(ufunc(a[:, 0], a[:, 1]), a[:, 2])


def unit_normal_planes(normal: np.ndarray) -> list[np.ndarray]:
    """N/|N| in float64, as three (M,) planes x, y, z (|N|² = (x² + y²) + z²).

    The one normalisation of the kernels' host side and of the float64
    reference (:mod:`clphong.reference.shading`), so both see the same unit normals;
    per plane, it runs 1.8× faster than on (M, 3) rows.
    """
    n = normal.reshape(-1, 3)
    c = [n[:, a].astype(np.float64) for a in range(3)]
    length = np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        for x in c:
            np.divide(x, length, out=x)
    return c


def position_bounds(position: np.ndarray, background: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), float64 per axis, of the finite, shaded positions; ±inf if there are none.

    Masked reductions per axis (no boolean-indexed copy of the frame).
    """
    p = position.reshape(-1, 3)
    axes = [p[:, a] for a in range(3)]
    ok = ~background.reshape(-1)
    for c in axes:
        ok &= np.isfinite(c)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    if ok.any():
        for a, c in enumerate(axes):
            lo[a] = c.min(where=ok, initial=np.inf)
            hi[a] = c.max(where=ok, initial=-np.inf)
    return lo, hi


def origin_of_bounds(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The float32 centre of a bounding box; 0 for an empty one."""
    if not np.all(np.isfinite(lo)):
        return np.zeros(3, np.float32)
    return ((lo + hi) / 2).astype(np.float32)


def frame_origin(position: np.ndarray, background: np.ndarray) -> np.ndarray:
    """A float32 point at the centre of the finite, shaded positions (0 if none).

    The kernel subtracts it from P in float32; for positions within a factor 2 of
    it the difference is exact (Sterbenz), so a scene far from the world origin
    keeps the digits of its distances.
    """
    return origin_of_bounds(*position_bounds(position, background))


def split_hi_lo(x) -> tuple[np.ndarray, np.ndarray]:
    """float64 ``x`` as float32 ``hi`` and ``lo = float32(x − hi)``: hi + lo carries ~48 bits."""
    x = np.asarray(x, np.float64)
    hi = x.astype(np.float32)
    return hi, (x - hi.astype(np.float64)).astype(np.float32)


def view_vector(camera) -> np.ndarray | None:
    """Unit v (towards the viewer) of an orthographic camera, else None."""
    if camera.type != "orthographic":
        return None
    return -np.asarray(camera.direction, np.float64)


def half_vector(l: np.ndarray, v: np.ndarray):
    """Blinn's h = (l + v)/|l + v| in float64, and whether it is undefined (l = −v).

    ``l`` may hold many directions (..., 3); then ``undefined`` is a bool array.
    """
    s = np.asarray(l, np.float64) + np.asarray(v, np.float64)
    norm = np.sqrt(np.einsum("...i,...i->...", s, s))
    undefined = norm == 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        h = np.where(undefined[..., None], 0.0, s / norm[..., None])
    if h.ndim == 1:
        return h, bool(undefined)
    return h, undefined


#: Pixels per block of :func:`nearest_within`'s bounding boxes (a row segment).
NEAR_BLOCK = 256


def nearest_within(planes: np.ndarray, shaded: np.ndarray, points: np.ndarray,
                   radii: np.ndarray, inner: float = 0.0,
                   rebase: np.ndarray | None = None) -> list[tuple[int, float] | None]:
    """For each point, the nearest shaded pixel closer than its radius, if any.

    Parameters
    ----------
    planes : numpy.ndarray
        (3, n) float32 positions, one plane per axis.
    shaded : numpy.ndarray
        (n,) bool: the pixels to consider (finite positions only count).
    points : numpy.ndarray
        (m, 3) float64 points (rebased on ``rebase`` when it is given).
    radii : numpy.ndarray
        (m,) float64 search radii (0: nothing is searched).
    inner : float
        Pixels nearer than this are skipped too.
    rebase : numpy.ndarray, optional
        (3,) float32 origin: distances are those of the pixels' float32
        ``P - rebase`` (as the float kernels form it) to the points.

    Returns
    -------
    list
        Per point, ``(pixel index, distance)`` of the nearest pixel with
        ``0 < d < radius`` and ``d >= inner``, distances in float64 from the
        float32 positions; else None. A pixel at distance exactly 0 is skipped:
        a light there adds nothing (the kernels' and the reference's d = 0 guard).

    Boxes of :data:`NEAR_BLOCK` consecutive pixels (all pixels, NaN ignored: a
    box only needs to contain the shaded ones) are tested first, so the exact
    distances are computed only in the blocks a radius reaches: radii are tiny
    (the near field where a falloff overflows), so that is almost never.
    """
    n = planes.shape[1]
    m = len(points)
    found: list[tuple[int, float] | None] = [None] * m
    todo = [j for j in range(m) if radii[j] > 0]
    if not todo or n == 0:
        return found
    B = NEAR_BLOCK
    full = n // B
    parts = [planes[:, :full * B].reshape(3, full, B)] if full else []
    if n % B:
        parts.append(planes[:, full * B:].reshape(3, 1, n % B))
    lo = np.concatenate([np.fmin.reduce(q, axis=2) for q in parts], axis=1).T.astype(np.float64)
    hi = np.concatenate([np.fmax.reduce(q, axis=2) for q in parts], axis=1).T.astype(np.float64)
    shift = np.zeros(3) if rebase is None else np.asarray(rebase, np.float64)
    # The kernel's fl(P − o) is within 2^-24·|P − o| of P − o per axis, so its distance
    # to L is at least |P − (L + o)| − √3·2^-24·max|P − o|: the boxes' radius widens by that.
    slack = 0.0
    if rebase is not None:
        ext = np.abs(np.concatenate([lo, hi]) - shift)
        slack = 2.0 ** -23 * float(np.max(ext, where=np.isfinite(ext), initial=0.0))
    for j in todo:
        p = np.asarray(points[j], np.float64) + shift                 # in the planes' frame
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)             # NaN for an all-NaN block
        near = np.flatnonzero(np.sqrt((gap * gap).sum(axis=1)) < radii[j] + slack)
        best = None
        for b in near:
            s = slice(b * B, min((b + 1) * B, n))
            q = planes[:, s]
            if rebase is not None:
                q = q - np.asarray(rebase, np.float32)[:, None]       # float32, as the kernel
            d = np.sqrt(sum((q[a].astype(np.float64) - points[j][a]) ** 2 for a in range(3)))
            ok = shaded[s] & np.isfinite(q).all(axis=0) & (d > 0) & (d >= inner)
            d = np.where(ok, d, np.inf)
            k = int(np.argmin(d))
            if d[k] < radii[j] and (best is None or d[k] < best[1]):
                best = (s.start + k, float(d[k]))
        found[j] = best
    return found
