"""Memory: how much a step needs and how much there is.

A step that cannot fit (reading a G-buffer, parsing a scene file, shading even
one row of a frame, writing the outputs) is refused with a one-line error that
says how much it needs and how much there is, instead of being killed by the OS.

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
parse_size, format_size
    ``"8G"`` -> 8589934592, and back to ``"8.0 GiB"``.
require_memory
    Raise a given ClphongError class when a step needs more than the budget.
output_bytes
    The memory model of writing a frame's outputs.
gc_paused
    The cyclic garbage collector off while objects are made by the hundred thousand.
"""

from __future__ import annotations

import contextlib
import gc
import math
import os
import re
from dataclasses import dataclass

from .errors import ClphongError

try:
    import resource
except ImportError:  # pragma: no cover - not on Windows
    resource = None

__all__ = ["gc_paused", "memory_budget", "parse_size", "format_size", "require_memory",
           "MemoryBudget", "output_bytes", "HEADROOM", "ENV_VAR", "MODEL_MARGIN", "F32"]

#: Environment variable capping the memory clphong plans to use.
ENV_VAR = "CLPHONG_MAX_MEMORY"
#: Fraction of the available memory clphong plans to use: the rest is left for
#: the allocator's slack, OpenImageIO's and PoCL's own buffers and other processes.
HEADROOM = 0.8
#: Bytes per float32 value.
F32 = 4
#: Factor on a memory model for allocations it does not count (measured: up to
#: 8 %; see :func:`clphong.device.bands.render_bytes_per_pixel`).
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


@contextlib.contextmanager
def gc_paused():
    """The cyclic garbage collector off for a while (if it was on): parsing a scene and
    making an environment's directional lights make objects by the hundred thousand
    and no cycles, and each of the collector's passes over the growing heap took
    20-50% of validating 65 536 lights, and, in a process that has loaded scenes
    before, a quarter of rtoml's parse of them (Zen 5: 0.37-0.38 s against 0.46-0.56 s;
    the whole load's median 0.92 s against 1.13-1.19 s; a fresh process's first load
    was about the same either way, 0.74-0.85 s). Making 200 000 directional lights
    took 0.86 s with it on, 0.26 s off (Ice Lake, 2 cores)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
