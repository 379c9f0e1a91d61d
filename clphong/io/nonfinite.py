"""The input policy for non-finite G-buffer values (NaN, ±Inf).

Every buffer is counted separately (:func:`nonfinite_counts`), and one policy
decides what happens to the pixels concerned (:func:`apply_nonfinite_policy`):

``"background"`` (default)
    The pixel is not shaded and takes the background value, like a pixel with
    zero coverage. A NaN therefore never reaches the kernels, the light sum, a
    neighbouring pixel or tone mapping. An :class:`~clphong.core.errors.InputWarning`
    gives the counts per buffer.
``"error"``
    A :class:`~clphong.core.errors.GBufferError` naming the buffer (file and channels)
    and the count; nothing is written.
``"pass"``
    The values go to the kernels as they are. Every pixel is shaded on its own,
    so a NaN or Inf stays in the pixels that hold it (no neighbour is touched),
    but those pixels come out non-finite. For debugging and for pipelines that
    mark holes with NaN on purpose.

A non-finite *normal* is always background (:meth:`GBuffer.background_mask`):
it has no direction to shade with. Background pixels (zero coverage or a zero
normal) are not counted: their other buffers are never read.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ..core.errors import GBufferError, InputWarning
from ..model.options import check_nonfinite


def all_finite(array) -> bool:
    """Whether every value is finite: a sum, far cheaper than a per-pixel mask.

    A NaN or ±Inf makes any sum non-finite, so a finite sum in the array's own type
    (float32: 2.3x faster than accumulating in float64) settles it; only a sum that
    overflowed is redone in float64 (where a sum of float32 or half values cannot).
    """
    a = np.asarray(array)
    with np.errstate(invalid="ignore", over="ignore"):
        return bool(np.isfinite(a.sum())) or bool(np.isfinite(a.sum(dtype=np.float64)))


def _nonfinite_pixels(array: np.ndarray) -> np.ndarray:
    """(H, W) bool: any component of the pixel is NaN or ±Inf."""
    a = np.asarray(array)
    shape = a.shape[:2]
    if all_finite(a):                       # the common case, cheaply
        return np.zeros(shape, bool)
    if a.ndim == 2:
        return ~np.isfinite(a)
    ok = np.ones(shape, bool)
    for c in range(a.shape[-1]):
        ok &= np.isfinite(a[..., c])
    return ~ok


def _buffers(gbuffer):
    yield "position", gbuffer.position
    yield "normal", gbuffer.normal
    yield "albedo", gbuffer.albedo
    for name in sorted(gbuffer.maps):
        yield name, gbuffer.maps[name]


def nonfinite_counts(gbuffer) -> dict[str, int]:
    """Non-finite pixels per buffer, over the pixels that would be shaded.

    Returns
    -------
    dict of str to int
        ``{"position": n, "normal": n, "albedo": n, <map>: n, ...}``; zero
        counts included. Coverage is not a shading input and is not counted
        (a NaN coverage is treated as covered only if it is not 0).
    """
    counts = {}
    covered = None
    for name, a in _buffers(gbuffer):
        if all_finite(a):                       # the common case: no mask at all
            counts[name] = 0
            continue
        if covered is None:
            covered = np.ones(gbuffer.shape, bool)
            if gbuffer.coverage is not None:
                covered &= np.asarray(gbuffer.coverage) != 0
        counts[name] = int((_nonfinite_pixels(a) & covered).sum())
    return counts


def _describe(gbuffer, counts: dict[str, int]) -> str:
    parts = []
    for name, n in counts.items():
        if n:
            src = gbuffer.sources.get(name, name) if getattr(gbuffer, "sources", None) else name
            parts.append(f"{src}: {n} pixel(s)")
    return "; ".join(parts)


def apply_nonfinite_policy(gbuffer, policy: str = "background"):
    """Apply ``policy`` to the non-finite pixels of ``gbuffer``.

    Parameters
    ----------
    gbuffer : clphong.io.gbuffer.GBuffer
    policy : {"background", "error", "pass"}

    Returns
    -------
    gbuffer : GBuffer
        The input itself when nothing is non-finite or the policy is
        ``"pass"``; otherwise a copy whose coverage is 0 on the non-finite
        pixels (the arrays are shared, not copied).
    counts : dict of str to int
        :func:`nonfinite_counts` of the input.

    Raises
    ------
    ValueError
        An unknown policy (the message lists the valid ones).
    GBufferError
        Policy ``"error"`` and some non-finite value; the message names each
        buffer and its count.
    """
    check_nonfinite(policy)
    counts = nonfinite_counts(gbuffer)
    if not any(counts.values()):
        return gbuffer, counts
    what = _describe(gbuffer, counts)
    if policy == "error":
        raise GBufferError(f"non-finite (NaN/Inf) G-buffer values: {what}; "
                           "fix the input, or use --nonfinite background to leave those pixels unshaded")
    if policy == "pass":
        warnings.warn(f"non-finite G-buffer values passed to the kernels: {what}", InputWarning,
                      stacklevel=3)
        return gbuffer, counts
    bad = np.zeros(gbuffer.shape, bool)
    for _, a in _buffers(gbuffer):
        bad |= _nonfinite_pixels(a)
    coverage = (np.ones(gbuffer.shape, np.float32) if gbuffer.coverage is None
                else np.array(gbuffer.coverage, np.float32, copy=True))
    coverage[bad] = 0.0
    warnings.warn(f"non-finite G-buffer values left unshaded as background: {what}", InputWarning,
                  stacklevel=3)
    return dataclasses.replace(gbuffer, coverage=coverage), counts


# --------------------------------------------------------------------------- out of range

#: The buffers whose values must be >= 0, as the scene's own values are
#: (material.k_d, k_s, h and specular_color; an albedo is a reflectance).
NONNEGATIVE = ("albedo", "k_d", "k_s", "h", "specular_color")
_CHANNELS = "RGB"


def out_of_range_counts(gbuffer) -> dict[str, int]:
    """Negative values of the shaded pixels, per buffer and channel: ``{"albedo.G": 3,
    "h": 1, ...}`` (only those with some). NaN is not counted here (the
    non-finite policy's), nor are background pixels (never read)."""
    fg = None                                           # the shaded pixels, only if needed
    out = {}
    for name in NONNEGATIVE:
        a = gbuffer.albedo if name == "albedo" else gbuffer.maps.get(name)
        if a is None:
            continue
        a = np.asarray(a)
        planes = [(name, a)] if a.ndim == 2 else [(f"{name}.{_CHANNELS[c]}", a[..., c])
                                                 for c in range(a.shape[-1])]
        for label, p in planes:
            if p.min(initial=0.0) < 0:                   # the common case costs one pass
                if fg is None:
                    fg = ~gbuffer.background_mask()
                n = int(np.count_nonzero((p < 0) & fg))
                if n:
                    out[label] = n
    return out


def apply_range_policy(gbuffer, policy: str = "clamp"):
    """Negative albedo or material-map values (a k_s map of −1 gave negative
    radiance, a shininess of −1e6 NaN pixels, with exit 0).

    ``"clamp"``: set to 0, with an :class:`~clphong.core.errors.InputWarning`
    giving the counts per buffer and channel; ``"error"``: a
    :class:`~clphong.core.errors.GBufferError` with those counts. Returns the
    G-buffer (a copy of the buffers concerned when clamped) and the counts.
    The renderer applies ``"error"`` under ``--nonfinite error`` and clamps
    otherwise (``"pass"`` passes non-finite values only: a finite value never
    becomes a NaN or an Inf in an output).
    """
    if policy not in ("clamp", "error"):
        raise ValueError(f"out-of-range policy must be 'clamp' or 'error', not {policy!r}")
    counts = out_of_range_counts(gbuffer)
    if not counts:
        return gbuffer, counts
    src = getattr(gbuffer, "sources", None) or {}
    by_buffer: dict[str, list[str]] = {}
    for k, n in counts.items():
        buf, _, ch = k.partition(".")
        by_buffer.setdefault(buf, []).append(f"{ch} {n}" if ch else str(n))
    what = "; ".join(f"{src.get(b, b)}: {', '.join(parts)} pixel(s)" for b, parts in by_buffer.items())
    if policy == "error":
        raise GBufferError(f"negative G-buffer values (they must be >= 0, as the scene's): {what}; "
                           "fix the input, or drop --nonfinite error to clamp them to 0")
    albedo = gbuffer.albedo
    maps = dict(gbuffer.maps)
    if any(k.startswith("albedo") for k in counts):
        albedo = np.maximum(albedo, 0, dtype=np.float32)
    for name in maps:
        if name in NONNEGATIVE and any(k.split(".")[0] == name for k in counts):
            maps[name] = np.maximum(maps[name], 0, dtype=np.float32)
    warnings.warn(f"negative G-buffer values clamped to 0 (they must be >= 0, as the scene's): "
                  f"{what}", InputWarning, stacklevel=3)
    return dataclasses.replace(gbuffer, albedo=albedo, maps=maps), counts
