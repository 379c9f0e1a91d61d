"""The OpenCL platforms clphong knows, and the pip-installed runtimes it registers.

pyopencl's wheel bundles the ocl-icd loader, which finds pip's PoCL beside itself
and reads ``OCL_ICD_VENDORS`` once, when platforms are first listed: a folder
named there replaces ``/etc/OpenCL/vendors`` and adds its ``.icd`` files to pip's
PoCL. Intel's CPU runtime from pip (``pip install "clphong[intel]"``) ships an
ICD file naming a build path, useless as it is; :func:`register_pip_runtimes`
writes one naming the installed ``libintelocl.so`` into a folder of clphong's
cache, with a copy of every system ICD file (so system drivers stay visible), and
points ``OCL_ICD_VENDORS`` there. A user's own ``OCL_ICD_VENDORS`` is left as it
is: whatever it names is what clphong sees.
"""

from __future__ import annotations

import hashlib
import os
import sys
import sysconfig
import tempfile
from pathlib import Path

from ..core.cache import cache_dir  # noqa: F401 (clphong's cache folder; named here too)

#: Platform kinds, by a lower-case substring of the platform name.
KINDS = (("pocl", ("portable computing language", "pocl")),
         ("intel-cpu", ("intel(r) opencl", "intel(r) cpu runtime")),
         ("nvidia", ("nvidia",)))
#: Short names a user may give to --device (matched like substrings of platform names).
ALIASES = {"pocl": "portable computing language", "intel": "intel(r) opencl"}
#: Default platform preference among CPU devices, best first: Intel's runtime was
#: 2x faster than PoCL's one right width on Zen 4, and PoCL cannot build on Zen 5.
PREFERENCE = ("intel-cpu", "pocl", "other")

_SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
_INTEL_LIB = "libintelocl.so"

#: What :func:`register_pip_runtimes` did: "user" (OCL_ICD_VENDORS was set), a folder
#: path, or "" (nothing to register); None before it ran.
registered: str | None = None


def platform_kind(platform_name: str) -> str:
    """``pocl``, ``intel-cpu``, ``nvidia`` or ``other``, from a platform's name."""
    low = platform_name.lower()
    for kind, needles in KINDS:
        if any(n in low for n in needles):
            return kind
    return "other"


def device_kind(device) -> str:
    """The rule's kind of a device: its platform's kind on a CPU, else ``gpu``."""
    import pyopencl as cl

    if not device.type & cl.device_type.CPU:
        return "gpu"
    return platform_kind(device.platform.name)


def matches(spec: str, platform_name: str, device_name: str) -> bool:
    """Whether a --device name matches: a case-insensitive substring of the platform or
    device name, or an alias of :data:`ALIASES` ("pocl", "intel")."""
    low = spec.strip().lower()
    names = (platform_name.lower(), device_name.lower())
    return any(low in n for n in names) or (low in ALIASES and ALIASES[low] in names[0])


def intel_cpu_runtime() -> Path | None:
    """The ``libintelocl.so`` that ``pip install intel-opencl-rt`` put in this
    environment's ``lib/`` folder, or None."""
    roots = {Path(sys.prefix), Path(sysconfig.get_paths()["data"])}
    for root in sorted(roots):
        lib = root / "lib" / _INTEL_LIB
        if lib.is_file():
            return lib.resolve()
    return None


def _icd_folder(lines: dict[str, str]) -> Path:
    """A folder holding one ``NAME.icd`` per entry, named by a hash of the contents so
    that concurrent processes agree; written atomically, reused when present."""
    digest = hashlib.sha256(repr(sorted(lines.items())).encode()).hexdigest()[:16]
    for base in (cache_dir(), Path(tempfile.gettempdir()) / f"clphong-{os.getuid()}"):
        folder = base / f"icd-{digest}"
        if all((folder / f"{n}.icd").is_file() for n in lines):
            return folder
        try:
            folder.mkdir(parents=True, exist_ok=True)
            for name, text in lines.items():
                tmp = folder / f".{name}.{os.getpid()}.tmp"
                tmp.write_text(text + "\n")
                os.replace(tmp, folder / f"{name}.icd")
            return folder
        except OSError:
            continue
    raise OSError("no writable folder for clphong's OpenCL ICD files")


def register_pip_runtimes() -> str:
    """Make Intel's pip-installed CPU runtime an OpenCL platform beside pip's PoCL.

    Call before pyopencl first lists platforms (later calls change nothing the
    loader sees). Returns what was done (also in :data:`registered`)."""
    global registered
    if registered is not None:
        return registered
    if "OCL_ICD_VENDORS" in os.environ:
        registered = "user"
        return registered
    lib = intel_cpu_runtime()
    if lib is None:
        registered = ""
        return registered
    lines = {"clphong-intel-cpu": str(lib)}
    try:
        for icd in sorted(_SYSTEM_VENDORS.glob("*.icd")):
            lines[f"system-{icd.stem}"] = icd.read_text().strip()
    except OSError:
        pass
    try:
        folder = _icd_folder(lines)
    except OSError:
        registered = ""
        return registered
    os.environ["OCL_ICD_VENDORS"] = str(folder)
    registered = str(folder)
    return registered
