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
normal) are not counted: their other buffers are never read. A non-finite
*coverage* (it would make the pixel's alpha, and so its output, NaN) is always
background too, and is counted as ``"coverage"`` (when some is).

Implausible magnitudes
----------------------
A finite value can still be one no G-buffer holds: a damaged EXR (a flipped
compression byte, ZIP read as PXR24) decodes to exponents spread over the whole
float32 range, ±3.4e38 included. Values at or beyond the limits below
(:data:`LIMITS`, per buffer) are counted per channel
(:func:`implausible_counts`) and follow the same policy as NaN/Inf: background
with one warning line giving the counts, refused under ``"error"``, passed
under ``"pass"``. Each limit comes from the kernels' float32 arithmetic on the
value, not from trial:

``position``: 2^127 (1.7e38)
    The kernels form differences of positions in float32: P − origin, L − P,
    E − P. Two float32 values below 2^127 in magnitude are at most
    2·(2^127 − 2^103) = FLT_MAX apart, so every such difference of points inside
    that range is finite; one point at 2^127 or beyond and another on the far
    side of the origin give ±Inf, and Inf·0 = NaN. (Squared distances leave
    float far earlier, from d ≈ 2^64 ≈ 1.8e19, on the float paths only: that is
    their documented limitation (the lanes loop caps d²/16 at 2^125 and gives such
    a light nothing, docs/accuracy.md), which the default path shades exactly, e.g.
    the hard case ``c2-only-huge-d`` at 5e20; it is not a sign of a bad file.)
``albedo``, ``k_d``, ``k_s``, ``specular_color``: 2^63 (9.2e18)
    The float-weight paths form D = C_d·k_d and S = k_s·C_s·(the scene's
    factor) in float32, each a product of up to two G-buffer values, then
    D·w_d + S·w_s with weights w ≤ 1 (or, where the plan's FALLOFF_ON_WEIGHTS
    puts each light's falloff on them, att·w ≤ 1.5). Two values below 2^63 multiply
    to less than 2^126, so that sum stays below 1.5·2^127 < FLT_MAX for any scene whose
    k_d and k_s·specular_color are at most 1 (beyond, a light's radiance
    saturates the pixel at FLT_MAX, as documented). Past it D or S can be ∞,
    and ∞ times a back-facing light's weight 0 is NaN.
``h`` (shininess): 2^126 (8.5e37)
    Blinn-Phong raises to 4h, formed in float32: 4h is finite exactly for
    h ≤ FLT_MAX/4 (the next float32 above it is 2^126), the scene's own rule
    for ``material.h``.
``normal``: no limit
    Normals are normalised on the host in float64 (:func:`clphong.core.geometry.unit_normal_planes`):
    |N|² ≤ 3·FLT_MAX² ≈ 3.5e77 is far below DBL_MAX, and the square of the
    smallest float32 denormal (2e-90) far above DBL_MIN, so every finite
    non-zero normal has a unit direction.
``coverage``: no limit
    Clipped to [0, 1] before shading; only a non-finite one is counted.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from ..core.errors import GBufferError, InputWarning
from ..model.options import check_nonfinite

#: The smallest implausible magnitude of each buffer's values (see the module
#: docstring for the error model): |x| >= LIMITS[buffer] is counted per channel
#: by :func:`implausible_counts`. Normals and coverage have none.
LIMITS = {
    "position": 2.0 ** 127,
    "albedo": 2.0 ** 63,
    "k_d": 2.0 ** 63,
    "k_s": 2.0 ** 63,
    "specular_color": 2.0 ** 63,
    "h": 2.0 ** 126,
}


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


def _extremes(a) -> tuple[float, float]:
    """(min, max) of ``a``. NaN propagates through both and ±Inf shows in one, so
    finite extremes mean every value is finite: the one pass per buffer that
    answers both the non-finite and the implausible check (2.2 ms for a 1080p
    position, where :func:`all_finite`'s sum takes 3.2 ms)."""
    a = np.asarray(a)
    if a.size == 0:
        return 0.0, 0.0
    with np.errstate(invalid="ignore"):
        return float(a.min()), float(a.max())


def _survey(gbuffer) -> dict[str, tuple[float, float]]:
    """:func:`_extremes` of every buffer (:func:`_buffers`)."""
    return {name: _extremes(a) for name, a in _buffers(gbuffer)}


def _finite(extremes: tuple[float, float]) -> bool:
    return math.isfinite(extremes[0]) and math.isfinite(extremes[1])


def nonfinite_counts(gbuffer) -> dict[str, int]:
    """Non-finite pixels per buffer, over the pixels that would be shaded.

    Returns
    -------
    dict of str to int
        ``{"position": n, "normal": n, "albedo": n, <map>: n, ...}``; zero
        counts included, and ``"coverage": n`` only where some coverage is
        NaN/Inf (always background, like a non-finite normal: its alpha, so its
        output, would be NaN).
    """
    return _nonfinite_counts(gbuffer, _survey(gbuffer))


def _nonfinite_counts(gbuffer, survey) -> dict[str, int]:
    counts = {}
    covered = None
    for name, a in _buffers(gbuffer):
        if _finite(survey[name]):                       # the common case: no mask at all
            counts[name] = 0
            continue
        if covered is None:
            covered = np.ones(gbuffer.shape, bool)
            if gbuffer.coverage is not None:
                cov = np.asarray(gbuffer.coverage)
                covered &= (cov != 0) & np.isfinite(cov)     # a NaN coverage is background
        counts[name] = int((_nonfinite_pixels(a) & covered).sum())
    cov = gbuffer.coverage
    if cov is not None and not all_finite(cov):
        counts["coverage"] = int((~np.isfinite(np.asarray(cov))).sum())
    return counts


def _describe(gbuffer, counts: dict[str, int]) -> str:
    parts = []
    for name, n in counts.items():
        if n:
            src = gbuffer.sources.get(name, name) if getattr(gbuffer, "sources", None) else name
            parts.append(f"{src}: {n} pixel(s)")
    return "; ".join(parts)


def _by_channel(gbuffer, counts: dict[str, int]) -> str:
    """``{"albedo.G": 3, "h": 1}`` as ``FILE: CHANNELS: G 3 pixel(s); FILE: CHANNEL: 1 pixel(s)``."""
    src = getattr(gbuffer, "sources", None) or {}
    by_buffer: dict[str, list[str]] = {}
    for k, n in counts.items():
        buf, _, ch = k.partition(".")
        by_buffer.setdefault(buf, []).append(f"{ch} {n}" if ch else str(n))
    return "; ".join(f"{src.get(b, b)}: {', '.join(parts)} pixel(s)" for b, parts in by_buffer.items())


# --------------------------------------------------------------------------- implausible magnitudes


def _planes(name: str, a: np.ndarray):
    """(label, plane) per channel: ``("position.X", P[..., 0])``, …; a scalar buffer as itself."""
    comps = "XYZ" if name in ("position", "normal") else _CHANNELS
    if a.ndim == 2:
        return [(name, a)]
    return [(f"{name}.{comps[c]}", a[..., c]) for c in range(a.shape[-1])]


def _limited(gbuffer):
    """(name, array, limit) of the buffers with a magnitude limit (:data:`LIMITS`)."""
    for name, a in _buffers(gbuffer):
        if name in LIMITS:
            yield name, np.asarray(a), LIMITS[name]


def _implausible(a: np.ndarray, limit: float) -> np.ndarray:
    """Finite values with |x| >= ``limit`` (±Inf is the non-finite count's)."""
    with np.errstate(invalid="ignore"):
        return (np.abs(a) >= limit) & np.isfinite(a)


def _reaches(a: np.ndarray, limit: float, extremes: tuple[float, float]) -> bool:
    """Whether some finite value of ``a`` has |x| >= ``limit``: from its extremes,
    a mask only when they are NaN or ±Inf."""
    if _finite(extremes):
        return extremes[1] >= limit or extremes[0] <= -limit
    return bool(_implausible(a, limit).any())


def implausible_counts(gbuffer) -> dict[str, int]:
    """Finite values at or beyond their buffer's :data:`LIMITS`, over the shaded
    pixels, per buffer and channel: ``{"position.X": 3, "h": 1, ...}`` (only those
    with some). NaN/Inf are not counted here (:func:`nonfinite_counts`), nor are
    background pixels (never read)."""
    return _implausible_counts(gbuffer, _survey(gbuffer))


def _implausible_counts(gbuffer, survey) -> dict[str, int]:
    fg = None
    out = {}
    for name, a, limit in _limited(gbuffer):
        if not _reaches(a, limit, survey[name]):         # the common case: no mask at all
            continue
        if fg is None:
            fg = ~gbuffer.background_mask()
        for label, p in _planes(name, a):
            n = int(np.count_nonzero(_implausible(p, limit) & fg))
            if n:
                out[label] = n
    return out


def _implausible_pixels(gbuffer, survey) -> np.ndarray:
    """(H, W) bool: any channel of any limited buffer is implausibly large."""
    bad = np.zeros(gbuffer.shape, bool)
    for name, a, limit in _limited(gbuffer):
        if _reaches(a, limit, survey[name]):
            m = _implausible(a, limit)
            bad |= m.any(axis=-1) if m.ndim == 3 else m
    return bad


def _limits_text(counts: dict[str, int]) -> str:
    """The limits of the buffers in ``counts``: ``position |x| >= 1.7e+38, albedo |x| >= 9.2e+18``."""
    by_limit: dict[float, list[str]] = {}
    for buf in dict.fromkeys(k.partition(".")[0] for k in counts):
        by_limit.setdefault(LIMITS[buf], []).append(buf)
    return ", ".join(f"{', '.join('shininess' if b == 'h' else b for b in bufs)} |x| >= {limit:.2g}"
                     for limit, bufs in by_limit.items())


def apply_nonfinite_policy(gbuffer, policy: str = "background"):
    """Apply ``policy`` to the non-finite and the implausibly large pixels of ``gbuffer``.

    Parameters
    ----------
    gbuffer : clphong.io.gbuffer.GBuffer
    policy : {"background", "error", "pass"}

    Returns
    -------
    gbuffer : GBuffer
        The input itself when nothing is non-finite or implausible or the policy
        is ``"pass"``; otherwise a copy whose coverage is 0 on those pixels
        (the arrays are shared, not copied).
    counts : dict of str to int
        :func:`nonfinite_counts` of the input (NaN/Inf only; the implausible
        magnitudes are :func:`implausible_counts`).

    Raises
    ------
    ValueError
        An unknown policy (the message lists the valid ones).
    GBufferError
        Policy ``"error"`` and some non-finite or implausible value; the message
        names each buffer (file and channels) and its counts, per channel for the
        implausible ones.
    """
    check_nonfinite(policy)
    survey = _survey(gbuffer)                    # one min/max pass per buffer for both counts
    counts = _nonfinite_counts(gbuffer, survey)
    large = _implausible_counts(gbuffer, survey)
    if not any(counts.values()) and not large:
        return gbuffer, counts
    what = _describe(gbuffer, counts)
    big = _by_channel(gbuffer, large)
    limits = _limits_text(large)
    if policy == "error":
        parts = [f"non-finite (NaN/Inf) G-buffer values: {what}"] if what else []
        if big:
            parts.append(f"implausibly large G-buffer values ({limits}: beyond what the kernels' "
                         f"float32 arithmetic can shade; a damaged file?): {big}")
        raise GBufferError("; ".join(parts) + "; fix the input, or use --nonfinite background to "
                           "leave those pixels unshaded")
    done = "passed to the kernels" if policy == "pass" else "left unshaded as background"
    parts = [f"non-finite G-buffer values {done}: {what}"] if what else []
    if big:
        parts.append(f"implausibly large G-buffer values ({limits}: beyond what the kernels' "
                     f"float32 arithmetic can shade; a damaged file?) {done}: {big}")
    message = "; also ".join(parts)
    if policy == "pass":
        warnings.warn(message, InputWarning, stacklevel=3)
        return gbuffer, counts
    bad = _implausible_pixels(gbuffer, survey) if large else np.zeros(gbuffer.shape, bool)
    for name, a in _buffers(gbuffer):
        if not _finite(survey[name]):
            bad |= _nonfinite_pixels(a)
    if counts.get("coverage"):
        bad |= ~np.isfinite(np.asarray(gbuffer.coverage))
    coverage = (np.ones(gbuffer.shape, np.float32) if gbuffer.coverage is None
                else np.array(gbuffer.coverage, np.float32, copy=True))
    coverage[bad] = 0.0
    warnings.warn(message, InputWarning, stacklevel=3)
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
        if a.min(initial=0.0) >= 0:                      # the common case: one contiguous pass
            continue
        for label, p in _planes(name, a):
            # a NaN anywhere makes the minimum NaN
            # (a NaN pixel the non-finite policy left as background): then the mask
            # decides, or every negative value beside it escaped the clamp
            if not p.min(initial=0.0) >= 0:
                if fg is None:
                    fg = ~gbuffer.background_mask()
                n = int(np.count_nonzero((p < 0) & fg))
                if n:
                    out[label] = n
    return out


def coverage_out_of_range(gbuffer) -> dict[str, int]:
    """Finite coverage outside [0, 1], per side: ``{"coverage.below 0": n, "coverage.above
    1": m}`` (only those with some). A coverage of −1 was shaded at full strength and
    written with A = 0: colour where alpha says nothing is there."""
    cov = gbuffer.coverage
    if cov is None:
        return {}
    cov = np.asarray(cov)
    lo, hi = cov.min(initial=0.0), cov.max(initial=0.0)
    if lo >= 0 and hi <= 1:                            # the common case: two contiguous passes
        return {}
    out = {}
    below, above = int(np.count_nonzero(cov < 0)), int(np.count_nonzero(cov > 1))
    if below:
        out["coverage.below 0"] = below
    if above:
        out["coverage.above 1"] = above
    return out


def apply_range_policy(gbuffer, policy: str = "clamp"):
    """Negative albedo or material-map values (a k_s map of −1 gave negative
    radiance, a shininess of −1e6 NaN pixels, with exit 0), and a coverage outside
    [0, 1] (:func:`coverage_out_of_range`).

    ``"clamp"``: set to 0 (coverage clipped to [0, 1], so that below 0 is background),
    with an :class:`~clphong.core.errors.InputWarning`
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
    covs = coverage_out_of_range(gbuffer)
    if not counts and not covs:
        return gbuffer, counts

    def what(done: tuple[str, str]) -> str:
        parts = ([f"negative G-buffer values{done[0]} (they must be >= 0, as the scene's): "
                  f"{_by_channel(gbuffer, counts)}"] if counts else [])
        parts += [f"coverage outside [0, 1]{done[1]}: {_by_channel(gbuffer, covs)}"] if covs else []
        return "; ".join(parts)

    if policy == "error":
        raise GBufferError(what(("", "")) + "; fix the input, or drop --nonfinite error to "
                           + ("clip them (negative values to 0, coverage to [0, 1])" if covs
                              else "clamp them to 0"))
    coverage = gbuffer.coverage
    if covs:
        # clipped before shading: a coverage below 0 is background, as 0 is
        coverage = np.clip(coverage, 0.0, 1.0).astype(np.float32, copy=False)
    message = what((" clamped to 0", " clipped (below 0: background)"))
    albedo = gbuffer.albedo
    maps = dict(gbuffer.maps)
    if any(k.startswith("albedo") for k in counts):
        albedo = np.maximum(albedo, 0, dtype=np.float32)
    for name in maps:
        if name in NONNEGATIVE and any(k.split(".")[0] == name for k in counts):
            maps[name] = np.maximum(maps[name], 0, dtype=np.float32)
    counts = {**counts, **covs}
    warnings.warn(message, InputWarning, stacklevel=3)
    return dataclasses.replace(gbuffer, albedo=albedo, maps=maps, coverage=coverage), counts
