"""Shading a frame in row bands: the memory model of one launch and the band plan.

A frame too large to shade in one launch (too large for the memory left, for
the device's largest buffer, or for the kernel's 32-bit plane offsets) is
shaded in bands of whole rows, one launch per band, into one output array
(:meth:`clphong.device.renderer.Renderer.render`). Every band uses the rebasing
origin of the whole frame, and band edges lie on the culling grid
(:func:`band_align`), so each pixel goes through exactly the same float32
operations, and gets the same light list, as in a single launch: the banded
image is bit-identical to the unbanded one.

Public functions
----------------
render_bytes_per_pixel, band_rows
    The memory model of one launch, and the rows per band it allows.
band_align
    The row multiple that keeps band edges on culling super-tile edges.
plan_bands, band_of, frame_origin_banded
    The bands of a frame, one band's G-buffer views, and the whole frame's origin.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..core.geometry import origin_of_bounds, position_bounds
from ..core.memory import F32, MODEL_MARGIN
from ..model.scene import MATERIAL_MAPS
from .culling import TILE, super_tiles
from .frame import GBUF_PLANES, LOCAL_SIZE

# --------------------------------------------------------------------------- the launch model


def map_planes(gbuffer) -> int:
    """float32 planes of the material maps a frame uploads (0 to 6)."""
    return sum(MATERIAL_MAPS[k] for k in gbuffer.maps)


def render_bytes_per_pixel(n_map_planes: int, gbuf_planes: int | None = None,
                           display: bool = False) -> int:
    """Peak host bytes per pixel of one launch (prepare_frame + Renderer.render).

    The model, per pixel, for ``g`` G-buffer planes and ``m`` map planes of
    float32 (``frame.prepare_frame`` and ``Renderer.shade``):

    - ``Frame.gbuf`` and ``Frame.maps``: ``4(g + m)``; the background mask: 1;
    - their device copies (PoCL's CPU device keeps buffers in host memory, and
      ``COPY_HOST_PTR`` copies): ``4(g + m)``;
    - the device output, the host output and the returned (H, W, 3) array:
      ``3 * 12``;
    - the float64 temporaries of ``prepare_frame`` (normals, their lengths and
      remainders, up to 72) are freed before the device buffers exist.

    - with ``display`` (the fused SDR output, ``Renderer.render(..., display=...)``), its device
      buffer, host buffer and (H, W, 3) array: another ``3 * 12``.

    That is ``8(g + m) + 37`` (``+ 36``). Measured peaks (VmHWM − VmRSS around one
    ``Renderer.render`` of a 2000x2000 frame, g = 12) were 143 B/px for m = 0
    (model 133) and 189 B/px for m = 6 (model 181): up to 8 % of unmodelled
    allocations, so the model is multiplied by :data:`MODEL_MARGIN`.
    """
    g = GBUF_PLANES if gbuf_planes is None else gbuf_planes
    return int(math.ceil(MODEL_MARGIN * (8 * (g + n_map_planes) + 37 + (36 if display else 0))))


def light_bytes(scene) -> int:
    """Bytes of memory the light records of ``scene`` take, packed and on the device."""
    # Per light: render.pack_lights' records and temporaries while packing (peak
    # 240 bytes a point light, 433 a directional light with an orthographic camera:
    # six float4 records and their float64 forms, measured with tracemalloc over
    # 100 000 lights), the device copy (96, in host memory on a CPU), and with
    # culling a point light's records (64) and their packing (~200): 576 bytes;
    # with the spot cone in every point record (4 float4 instead of 3: +16 float32,
    # +32 float64 and its temporaries, +32 on the device, +16 culling), scaled to 704.
    return 704 * shaded_lights(scene)


def shaded_lights(scene) -> int:
    """The lights of ``scene`` that have records: all but the ambient ones."""
    return len(scene.lights) - len(scene.lights_of("ambient"))


def band_rows(shape: tuple[int, int], *, n_map_planes: int, lanes: int, light_bytes: int = 0,
              budget: int | None, max_alloc: int | None = None, global_mem: int | None = None,
              local_size: int | None = None, display: bool = False) -> int:
    """The most rows of a frame one launch may shade.

    Parameters
    ----------
    shape : (H, W)
        The frame.
    n_map_planes : int
        float32 material-map planes uploaded with the frame.
    lanes : int
        Pixels per work-item (the padding block is ``lanes * LOCAL_SIZE``).
    light_bytes : int
        Bytes of the light records (uploaded once per launch).
    budget : int or None
        Host bytes usable (:func:`memory_budget`), None for no limit.
    max_alloc, global_mem : int, optional
        The device's largest buffer and its global memory
        (``CL_DEVICE_MAX_MEM_ALLOC_SIZE``, ``CL_DEVICE_GLOBAL_MEM_SIZE``).
    local_size : int, optional
        Work-group size (default ``render.LOCAL_SIZE``).
    display : bool
        Whether the launch also writes the fused SDR output.

    Returns
    -------
    int
        ``H`` when the whole frame fits one launch; else the rows per band
        (>= 1) that fit next to the full (H, W, 3) output; 0 when not even one
        row fits.

    Notes
    -----
    Limits on the padded plane length ``stride`` of a band: every buffer at
    most ``max_alloc`` bytes; all device buffers together at most
    ``global_mem``; and ``g * stride < 2^32``, because the kernels address
    plane ``p`` as ``gbuf + p * stride`` with a 32-bit ``uint`` stride.
    """
    h, w = int(shape[0]), int(shape[1])
    block = max(int(lanes), 1) * int(local_size or LOCAL_SIZE)
    g = GBUF_PLANES
    m = int(n_map_planes)
    bpp = render_bytes_per_pixel(m, g, display)

    def stride_of(rows: int) -> int:
        n = rows * w
        return max(block, math.ceil(n / block) * block)

    def device_ok(rows: int) -> bool:
        s = stride_of(rows)
        if g * s >= 2 ** 32:
            return False
        if max_alloc is not None:
            if F32 * max(g, m, 3) * s > max_alloc or light_bytes > max_alloc:
                return False
        if global_mem is not None and F32 * (g + m + 3) * s + light_bytes > global_mem:
            return False
        return True

    def host_ok(rows: int, full_output: bool) -> bool:
        if budget is None:
            return True
        extra = F32 * 3 * h * w if full_output else 0
        return bpp * stride_of(rows) + light_bytes + extra <= budget

    if device_ok(h) and host_ok(h, False):
        return h
    # Bands: the (H, W, 3) output lives beside each band; bisect the largest band.
    lo, hi = 0, h - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if device_ok(mid) and host_ok(mid, True):
            lo = mid
        else:
            hi = mid - 1
    return lo


def plan_bands(h: int, rows: int) -> list[tuple[int, int]]:
    """Split ``h`` rows into bands of at most ``rows`` (the last one shorter)."""
    if rows <= 0:
        raise ValueError("rows must be >= 1")
    return [(y, min(y + rows, h)) for y in range(0, h, rows)]


def band_align(lanes: int) -> int:
    """Rows that band edges are a multiple of, so that they lie on culling super-tile edges.

    Culling (:mod:`clphong.device.culling`) lists lights per ``TILE``-pixel tile
    within super-tiles of ``super_tiles(lanes)`` tiles, counted from the frame's
    top-left corner; a band that starts on a super-tile edge sees the same tiles
    and super-tiles, and so the same lists, as the whole frame. (A band edge on
    the grid is also a multiple of ``lanes`` pixels from the frame's start, so
    each work-item shades the same pixels.)
    """
    return TILE * super_tiles(lanes)


def band_of(gbuffer, y0: int, y1: int):
    """Rows ``y0:y1`` of a G-buffer (views, no copy); other fields kept."""
    return dataclasses.replace(
        gbuffer,
        position=gbuffer.position[y0:y1], normal=gbuffer.normal[y0:y1], albedo=gbuffer.albedo[y0:y1],
        coverage=None if gbuffer.coverage is None else gbuffer.coverage[y0:y1],
        maps={k: v[y0:y1] for k, v in gbuffer.maps.items()})


def frame_origin_banded(gbuffer, bands: list[tuple[int, int]]) -> np.ndarray:
    """``render.frame_origin`` of the whole frame, computed band by band.

    The origin is the float32 centre of the bounding box of the finite, shaded
    positions; min and max combine exactly across bands, so this equals
    ``frame_origin(position, background_mask())`` of the whole frame without
    the whole frame's temporaries.
    """
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for y0, y1 in bands:
        part = band_of(gbuffer, y0, y1)
        b_lo, b_hi = position_bounds(part.position, part.background_mask())
        lo, hi = np.minimum(lo, b_lo), np.maximum(hi, b_hi)
    return origin_of_bounds(lo, hi)
