"""Memory: how much a step needs, how much there is, and shading in row bands.

A frame too large to shade in one launch (too large for the memory left, for
the device's largest buffer, or for the kernel's 32-bit plane offsets) is
shaded in bands of whole rows, one launch per band, into one output array.
Every band uses the rebasing origin of the whole frame, so each pixel goes
through exactly the same float32 operations as in a single launch and the
banded image is bit-identical to the unbanded one. A step that cannot fit at
all (reading a G-buffer, parsing a scene file, or even one row of a frame) is
refused with a one-line error that says how much it needs and how much there
is, instead of being killed by the OS.

How much there is (:func:`memory_budget`): the smallest of

- ``MemAvailable`` in ``/proc/meminfo`` (else ``os.sysconf`` available pages),
- the cgroup limit minus current use (containers: the OOM killer acts on it),
- ``RLIMIT_AS`` / ``RLIMIT_DATA`` minus this process's current size,

times :data:`HEADROOM` (for the allocator, OpenImageIO, PoCL and other
processes). ``CLPHONG_MAX_MEMORY`` (bytes, or a number with K, M, G or T,
binary units: ``CLPHONG_MAX_MEMORY=8G``) replaces that figure: lower it to
leave memory to other work, or raise it when you know better (swap, a
machine whose available-memory figure is misleading).

Public functions
----------------
memory_budget
    Bytes this process may still allocate, and where the figure comes from.
parse_size
    ``"8G"`` -> 8589934592.
require_memory
    Raise a given ClphongError class when a step needs more than the budget.
render_bytes_per_pixel, band_rows
    The memory model of one launch, and the rows per band it allows.
render_frame
    Shade a G-buffer with a Renderer, in one launch or in bands.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import time
from dataclasses import dataclass

import numpy as np

from .errors import ClphongError, DeviceError, GBufferError

try:
    import resource
except ImportError:  # pragma: no cover - not on Windows
    resource = None

__all__ = ["memory_budget", "parse_size", "format_size", "require_memory", "MemoryBudget",
           "render_bytes_per_pixel", "output_bytes", "band_rows", "plan_bands", "render_frame", "HEADROOM",
           "ENV_VAR"]

#: Environment variable capping the memory clphong plans to use.
ENV_VAR = "CLPHONG_MAX_MEMORY"
#: Fraction of the available memory clphong plans to use: the rest is left for
#: the allocator's slack, OpenImageIO's and PoCL's own buffers and other processes.
HEADROOM = 0.8
#: Bytes per float32 value.
F32 = 4
#: Band heights are a multiple of this when they can be (the culling super-tile edge).
BAND_ALIGN = 128
#: Factor on the memory model of a launch for allocations it does not count
#: (measured: up to 8 %; see :func:`render_bytes_per_pixel`).
MODEL_MARGIN = 1.25


@dataclass(frozen=True)
class MemoryBudget:
    """Bytes this process may allocate (None: unknown, no limit), and why."""

    bytes: int | None
    source: str

    def describe(self) -> str:
        if self.bytes is None:
            return "unknown"
        return f"{format_size(self.bytes)} ({self.source})"


def parse_size(text: str) -> int:
    """Parse a size such as ``"1048576"``, ``"512M"``, ``"8G"`` or ``"1.5T"`` (binary units).

    Raises
    ------
    ValueError
        If ``text`` is not a non-negative number with an optional K/M/G/T
        suffix (an optional trailing ``B`` or ``iB`` is accepted).
    """
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kKmMgGtT]?)(?:i?[bB])?\s*", str(text))
    if not m:
        raise ValueError(f"not a size: {text!r}; write bytes or a number with K, M, G or T, e.g. 8G")
    scale = {"": 1, "k": 2 ** 10, "m": 2 ** 20, "g": 2 ** 30, "t": 2 ** 40}[m.group(2).lower()]
    return int(float(m.group(1)) * scale)


def format_size(n: float) -> str:
    """``1610612736`` -> ``"1.5 GiB"``."""
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"  # pragma: no cover


def _meminfo_available() -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _read_int(path: str) -> int | None:
    try:
        with open(path) as fh:
            text = fh.read().strip()
    except OSError:
        return None
    if not text or text == "max":
        return None
    try:
        return int(text)
    except ValueError:
        return None


def _cgroup_available() -> int | None:
    """Limit minus usage of this process's memory cgroup (v2, else v1), if limited."""
    try:
        with open("/proc/self/cgroup") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return None
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, rel = parts
        if controllers == "":                                     # cgroup v2
            base = "/sys/fs/cgroup" + rel.rstrip("/")
            limit, used = _read_int(base + "/memory.max"), _read_int(base + "/memory.current")
        elif "memory" in controllers.split(","):                  # cgroup v1
            base = "/sys/fs/cgroup/memory" + rel.rstrip("/")
            limit = _read_int(base + "/memory.limit_in_bytes")
            used = _read_int(base + "/memory.usage_in_bytes")
            if limit is not None and limit >= 2 ** 60:            # v1 "unlimited"
                limit = None
        else:
            continue
        if limit is not None:
            return max(limit - (used or 0), 0)
    return None


def _rlimit_available() -> int | None:
    """RLIMIT_AS / RLIMIT_DATA soft limit minus this process's current size, if set."""
    size = None
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    size = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    best = None
    if resource is None:  # pragma: no cover
        return None
    for name in ("RLIMIT_AS", "RLIMIT_DATA"):
        which = getattr(resource, name, None)
        if which is None:
            continue
        soft, _ = resource.getrlimit(which)
        if soft == resource.RLIM_INFINITY or soft < 0:
            continue
        left = max(soft - (size or 0), 0)
        best = left if best is None else min(best, left)
    return best


def memory_budget() -> MemoryBudget:
    """Bytes this process may still allocate, and where the figure comes from.

    Returns
    -------
    MemoryBudget
        ``CLPHONG_MAX_MEMORY`` when set; else :data:`HEADROOM` times the
        smallest of the available memory, the cgroup's room and the rlimit's
        room; ``bytes`` is None when none of them is known.

    Raises
    ------
    ClphongError
        If ``CLPHONG_MAX_MEMORY`` is set but is not a size.
    """
    env = os.environ.get(ENV_VAR, "").strip()
    if env:
        try:
            return MemoryBudget(parse_size(env), f"{ENV_VAR}={env}")
        except ValueError as exc:
            raise ClphongError(f"{ENV_VAR}={env!r}: {exc}") from None
    found: list[tuple[int, str]] = []
    for value, source in ((_meminfo_available(), "available memory"),
                          (_cgroup_available(), "room left in the memory cgroup"),
                          (_rlimit_available(), "room left under the address-space rlimit")):
        if value is not None:
            found.append((int(value * HEADROOM), f"{int(HEADROOM * 100)}% of the {source}"))
    if not found:
        return MemoryBudget(None, "unknown")
    value, source = min(found)
    return MemoryBudget(value, source)


def require_memory(need: int, what: str, error: type[ClphongError], hint: str) -> None:
    """Raise ``error`` when ``need`` bytes exceed :func:`memory_budget`.

    Parameters
    ----------
    need : int
        Estimated peak bytes of the step.
    what : str
        The step, naming the file: ``"G-buffer.exr: reading 9 channels of 16384x16384"``.
    error : type
        The ClphongError subclass to raise.
    hint : str
        What the user can do about it.
    """
    budget = memory_budget()
    if budget.bytes is not None and need > budget.bytes:
        raise error(f"{what} needs about {format_size(need)} of memory but only "
                    f"{budget.describe()} is usable; {hint}")


# --------------------------------------------------------------------------- the launch model


def _gbuf_planes() -> int:
    from .render import GBUF_PLANES

    return GBUF_PLANES


def map_planes(gbuffer) -> int:
    """float32 planes of the material maps a frame uploads (0 to 6)."""
    return sum(3 if k == "specular_color" else 1 for k in gbuffer.maps)


def render_bytes_per_pixel(n_map_planes: int, gbuf_planes: int | None = None,
                           display: bool = False) -> int:
    """Peak host bytes per pixel of one launch (prepare_frame + Renderer.render).

    The model, per pixel, for ``g`` G-buffer planes and ``m`` map planes of
    float32 (``render.prepare_frame`` and ``Renderer.render``):

    - ``Frame.gbuf`` and ``Frame.maps``: ``4(g + m)``; the background mask: 1;
    - their device copies (PoCL's CPU device keeps buffers in host memory, and
      ``COPY_HOST_PTR`` copies): ``4(g + m)``;
    - the device output, the host output and the returned (H, W, 3) array:
      ``3 * 12``;
    - the float64 temporaries of ``prepare_frame`` (normals, their lengths and
      remainders, up to 72) are freed before the device buffers exist.

    - with ``display`` (the fused SDR output, ``Renderer.display``), its device
      buffer, host buffer and (H, W, 3) array: another ``3 * 12``.

    That is ``8(g + m) + 37`` (``+ 36``). Measured peaks (VmHWM − VmRSS around one
    ``Renderer.render`` of a 2000x2000 frame, g = 12) were 143 B/px for m = 0
    (model 133) and 189 B/px for m = 6 (model 181): up to 8 % of unmodelled
    allocations, so the model is multiplied by :data:`MODEL_MARGIN`.
    """
    g = _gbuf_planes() if gbuf_planes is None else gbuf_planes
    return int(math.ceil(MODEL_MARGIN * (8 * (g + n_map_planes) + 37 + (36 if display else 0))))


#: Peak bytes per pixel each kind of output file needs beyond the scene-linear
#: frame while it is formed, encoded and written (VmHWM above the frame, measured
#: at 3072² and 2048² with OpenImageIO 3.2: SDR 36–38 whether fused or through an
#: OCIO view, PNG or TIFF, 8 or 16 bits; HDR PQ PNG 18, JPEG XL 75; the scene-linear
#: EXR and the contact sheet, formed from a downscaled copy, ~0).
OUTPUT_BYTES_PER_PIXEL = {"exr": 0, "sdr": 38, "hdr": 18, "hdr_jxl": 76, "contact_sheet": 0}


def output_bytes(shape: tuple[int, int], kinds) -> int:
    """Peak bytes of writing the outputs ``kinds`` (keys of OUTPUT_BYTES_PER_PIXEL)
    of an (H, W) frame: the frame (12 B/px) and every kind's buffers, which may all
    be alive at once, times MODEL_MARGIN."""
    per_pixel = F32 * 3 + sum(OUTPUT_BYTES_PER_PIXEL[k] for k in kinds)
    return int(math.ceil(MODEL_MARGIN * per_pixel * int(shape[0]) * int(shape[1])))


def _light_bytes(scene) -> int:
    # Per light: render.pack_lights' records and temporaries while packing (peak
    # 240 bytes a point light, 433 a directional light with an orthographic camera:
    # six float4 records and their float64 forms, measured with tracemalloc over
    # 100 000 lights), the device copy (96, in host memory on a CPU), and with
    # culling a point light's records (64) and their packing (~200): 576 bytes.
    return 576 * sum(1 for lt in scene.lights if lt.type != "ambient")


def _device_limits(renderer) -> tuple[int | None, int | None]:
    dev = getattr(renderer.runtime, "device", None)
    try:
        return int(dev.max_mem_alloc_size), int(dev.global_mem_size)
    except Exception:  # noqa: BLE001 - a stand-in device without these attributes
        return None, None


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
    from .render import LOCAL_SIZE

    h, w = int(shape[0]), int(shape[1])
    block = max(int(lanes), 1) * int(local_size or LOCAL_SIZE)
    g = _gbuf_planes()
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


def _band(gbuffer, y0: int, y1: int):
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
    from .render import origin_of_bounds, position_bounds

    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for y0, y1 in bands:
        part = _band(gbuffer, y0, y1)
        b_lo, b_hi = position_bounds(part.position, part.background_mask())
        lo, hi = np.minimum(lo, b_lo), np.maximum(hi, b_hi)
    return origin_of_bounds(lo, hi)


def _launch(renderer, gbuffer, frame):
    """``renderer.render`` of a prepared frame, with OpenCL failures as DeviceError."""
    import pyopencl as cl

    try:
        return renderer.render(gbuffer, frame=frame)
    except cl.Error as exc:
        h, w = frame.shape
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise DeviceError(
            f"shading a {w}x{h} band on {renderer.runtime.name} failed ({first}); lower "
            f"{ENV_VAR} (e.g. {ENV_VAR}=1G) to shade in smaller bands, or choose another "
            "device with --device or PYOPENCL_CTX") from exc


def render_frame(renderer, gbuffer, *, rows: int | None = None) -> np.ndarray:
    """Shade ``gbuffer`` with ``renderer``, in one launch or in row bands.

    Parameters
    ----------
    renderer : clphong.render.Renderer
    gbuffer : clphong.gbuffer.GBuffer
    rows : int, optional
        Rows per band; by default :func:`band_rows` of the memory budget and
        the device's limits (the whole frame when it fits).

    Returns
    -------
    numpy.ndarray
        (H, W, 3) float32, bit-identical to one launch.

    Raises
    ------
    GBufferError
        When not even one row fits beside the output, with the sizes.
    DeviceError
        When an OpenCL allocation or launch fails anyway.
    """
    from .render import prepare_frame

    t0 = time.perf_counter()
    h, w = gbuffer.shape
    lanes = max(int(renderer.lanes), 1)
    m = map_planes(gbuffer)
    light_bytes = _light_bytes(renderer.scene)
    max_alloc, global_mem = _device_limits(renderer)
    if max_alloc is not None and light_bytes > max_alloc:
        n = sum(1 for lt in renderer.scene.lights if lt.type != "ambient")
        raise DeviceError(
            f"{renderer.scene.source}: {n} point and directional lights need about "
            f"{format_size(light_bytes)} of light records, more than the largest buffer "
            f"{renderer.runtime.name} allows ({format_size(max_alloc)}); use fewer lights")
    if rows is None:
        budget = memory_budget()
        display = getattr(renderer, "display", None) is not None
        rows = band_rows((h, w), n_map_planes=m, lanes=lanes, light_bytes=light_bytes,
                         budget=budget.bytes, max_alloc=max_alloc, global_mem=global_mem,
                         display=display)
        if rows <= 0:
            row_bytes = render_bytes_per_pixel(m, display=display) * w
            one_row = row_bytes + F32 * 3 * h * w + light_bytes
            raise GBufferError(
                f"a {w}x{h} frame cannot be shaded here: its output alone needs "
                f"{format_size(F32 * 3 * h * w)} and one row of shading "
                f"{format_size(row_bytes)} more ({format_size(one_row)} in "
                f"all), but only {budget.describe()} is usable; crop the G-buffer or use a "
                "machine with more memory")
    if rows >= h:
        renderer.last_bands = 1
        return _launch(renderer, gbuffer, prepare_frame(gbuffer, lanes=lanes))

    if rows >= BAND_ALIGN:
        # Bands on the culling grid (clphong.cull: 16x16 tiles in 128x128
        # super-tiles from the frame's corner) keep each tile's light list,
        # and so the result, the same as in one launch.
        rows -= rows % BAND_ALIGN
    bands = plan_bands(h, rows)
    origin = frame_origin_banded(gbuffer, bands)
    try:
        out = np.empty((h, w, 3), np.float32)
    except MemoryError:
        raise GBufferError(f"a {w}x{h} frame: no memory for its "
                           f"{format_size(F32 * 3 * h * w)} output") from None
    kernel_s = upload_s = 0.0
    for y0, y1 in bands:
        part = _band(gbuffer, y0, y1)
        frame = prepare_frame(part, lanes=lanes)
        frame.origin = origin
        out[y0:y1] = _launch(renderer, part, frame)
        st = renderer.last_stats
        if st is not None:
            kernel_s += st.kernel_seconds
            upload_s += st.upload_seconds
        del frame, part
    if renderer.last_stats is not None:
        renderer.last_stats = dataclasses.replace(
            renderer.last_stats, kernel_seconds=kernel_s, upload_seconds=upload_s,
            total_seconds=time.perf_counter() - t0)
    renderer.last_bands = len(bands)
    return out
