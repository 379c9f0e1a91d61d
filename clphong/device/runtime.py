"""OpenCL runtime: device selection, kernel sources and the program cache.

Device choice, in order:

1. ``device=`` argument (CLI ``--device``), in ``PYOPENCL_CTX`` syntax
   (``"0"``, ``"0:1"``) or as a case-insensitive substring of a platform or
   device name (``"pocl"``, ``"nvidia"``);
2. the ``PYOPENCL_CTX`` environment variable, as PyOpenCL reads it;
3. PoCL's CPU device (installed from PyPI with ``pip install "pyopencl[pocl]"``).

Programs are built once per (device, kernel sources, options) and cached in the
process. Across processes PoCL's own kernel cache (``$XDG_CACHE_HOME/pocl`` or
``$POCL_CACHE_DIR``) makes a rebuild of the same source and options cost tens of
milliseconds; PyOpenCL skips its own binary cache for PoCL.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from ..core.errors import DeviceError

_INSTALL_HINT = (
    "install PoCL with 'pip install \"pyopencl[pocl]\"', or choose another device "
    "with --device or the PYOPENCL_CTX environment variable (e.g. PYOPENCL_CTX=0)"
)

#: Said when --device names no device: the other ways to choose, and how to get one.
_CHOICE_HINT = (
    "give --device as 'P:D' indices or a name substring of one of these (see 'clphong devices'), "
    "or set the PYOPENCL_CTX environment variable (e.g. PYOPENCL_CTX=0:0); a device that is "
    "not listed needs its vendor's OpenCL driver (ICD); the CPU device comes with PoCL: "
    "pip install \"pyopencl[pocl]\""
)


#: LLVM CPU names with avx512f (prefixes), for which 16 float lanes fill a register.
AVX512_TARGETS = (
    "skylake-avx512", "cascadelake", "cooperlake", "cannonlake", "icelake", "tigerlake",
    "rocketlake", "sapphirerapids", "graniterapids", "emeraldrapids", "diamondrapids",
    "znver4", "znver5", "knl", "knm", "x86-64-v4",
)
#: AVX2 targets where 16 lanes (two 256-bit halves per vector) were built,
#: launched, passed the whole test suite and measured faster than 8: on znver3
#: (PoCL 3.0, LLVM 14) the bench scene ran 1.3× faster at 16 lanes, on the fp64
#: and the float path alike (issue 4's notes). Other AVX2 targets keep 8 until
#: measured.
WIDE_AVX2_TARGETS = ("znver3",)


#: The last component of a target triple before PoCL's CPU name (the OS or
#: environment): "pthread-x86_64-unknown-linux-gnu-icelake-client".
_TRIPLE_ENDS = ("gnu", "gnueabihf", "gnueabi", "musl", "android", "elf", "msvc", "darwin",
                "linux", "macosx", "windows")


def cpu_of_hstr(hstr: str) -> str:
    """The LLVM CPU name in PoCL's HSTR, ``DEVICE-TRIPLE-CPU``: what follows the
    triple, which may itself hold dashes ("icelake-client", "skylake-avx512");
    the last dash-separated word if no triple ending is found."""
    parts = hstr.strip().split("-")
    ends = [i for i, p in enumerate(parts) if p in _TRIPLE_ENDS]
    if ends and ends[-1] + 1 < len(parts):
        return "-".join(parts[ends[-1] + 1:])
    return parts[-1]


def kernel_dir() -> Path:
    """The folder holding the ``.cl`` sources.

    In a wheel they are installed as the data package ``clphong.kernels``; in a
    source checkout or an editable install they are the top-level ``kernels/``.
    """
    package = Path(__file__).resolve().parent.parent
    candidates = [package / "kernels", package.parent / "kernels"]
    try:
        # ``kernels/`` has no __init__.py, so clphong.kernels is a namespace
        # package: take its __path__ entries (an editable install maps it to the
        # checkout's kernels/ folder).
        import clphong.kernels as _k
        candidates += [Path(p) for p in getattr(_k, "__path__", [])]
    except ImportError:
        pass
    for path in candidates:
        if (path / "shade.cl").is_file():
            return path
    raise DeviceError(
        "clphong's OpenCL sources (kernels/*.cl) were not found next to the package; "
        "reinstall clphong with 'pip install .'"
    )


_DIGESTS: dict[tuple, str] = {}


def _sources_digest(folder: Path) -> str:
    """SHA-256 of every kernel source, part of the program cache key (an edited
    header rebuilds). Called on every render: the files are re-read only when
    a name, size or modification time changes."""
    files = sorted(folder.glob("*.cl")) + sorted((folder / "include").glob("*.h"))
    stamp = tuple((str(f), st.st_size, st.st_mtime_ns) for f in files for st in [f.stat()])
    digest = _DIGESTS.get(stamp)
    if digest is None:
        h = hashlib.sha256()
        for f in files:
            h.update(f.name.encode())
            h.update(f.read_bytes())
        digest = _DIGESTS[stamp] = h.hexdigest()
    return digest


def _cl():
    try:
        import pyopencl as cl
    except ImportError as exc:  # pragma: no cover - dependency is declared
        raise DeviceError(f"pyopencl is not importable ({exc}); {_INSTALL_HINT}") from exc
    return cl


def _all_devices():
    cl = _cl()
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:
        raise DeviceError(f"no OpenCL platform found ({exc}); {_INSTALL_HINT}") from exc
    out = []
    for pi, plat in enumerate(platforms):
        try:
            devs = plat.get_devices()
        except cl.Error:
            devs = []
        for di, dev in enumerate(devs):
            out.append((pi, di, plat, dev))
    return out


def list_devices() -> list[str]:
    """One line per OpenCL device: ``'P:D  platform / device'``."""
    return [f"{pi}:{di}  {plat.name} / {dev.name.strip()}" for pi, di, plat, dev in _all_devices()]


def _choose(spec: str | None):
    devices = _all_devices()
    if not devices:
        raise DeviceError(f"no OpenCL device found; {_INSTALL_HINT}")
    if spec is None:
        for _, _, plat, dev in devices:
            if "portable computing language" in plat.name.lower() or "pocl" in plat.name.lower():
                if dev.type & _cl().device_type.CPU:
                    return dev
        return devices[0][3]
    spec = spec.strip()
    parts = spec.split(":")
    if all(p.isdigit() for p in parts if p) and parts[0]:
        pi = int(parts[0])
        di = int(parts[1]) if len(parts) > 1 and parts[1] else 0
        for p_i, d_i, _, dev in devices:
            if p_i == pi and d_i == di:
                return dev
        raise DeviceError(
            f"device '{spec}': no such OpenCL device; available: " + "; ".join(list_devices())
            + "; " + _CHOICE_HINT
        )
    low = spec.lower()
    for _, _, plat, dev in devices:
        if low in dev.name.lower() or low in plat.name.lower():
            return dev
    raise DeviceError(f"device '{spec}': no match; available: " + "; ".join(list_devices())
                      + "; " + _CHOICE_HINT)


@dataclass
class Runtime:
    """An OpenCL context and queue on one device, with a program cache."""

    device: object
    context: object
    queue: object
    _programs: dict = field(default_factory=dict)
    _kernels: dict = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    #: Held from a cached kernel's set_args to its enqueue (the kernel object keeps
    #: its arguments in between); re-entrant, so a launch may run culling inside it.
    lock: threading.RLock = field(default_factory=threading.RLock)
    builds: int = 0            # programs actually built in this process
    build_seconds: float = 0.0

    @property
    def name(self) -> str:
        return f"{self.device.platform.name} / {self.device.name.strip()}"

    @property
    def llvm_target(self) -> str:
        """PoCL's LLVM CPU target (from the device version's HSTR), or ''."""
        version = self.device.version
        if "HSTR:" not in version:
            return ""
        return cpu_of_hstr(version.split("HSTR:")[1].split()[0])

    @property
    def has_fp64(self) -> bool:
        """Whether the device computes in double (cl_khr_fp64)."""
        return "cl_khr_fp64" in self.device.extensions.split() or bool(
            getattr(self.device, "double_fp_config", 0))

    @property
    def fast_fp64(self) -> bool:
        """Double precision at a useful speed: cl_khr_fp64 on a CPU device (half
        float's vector rate). GPUs with fp64 often run it at 1/16–1/64 of float,
        so double is used there only where accuracy needs it (directions), not
        for speed (the integer specular power, ``plan.SPEC_INT_POW``)."""
        return self.has_fp64 and bool(self.device.type & _cl().device_type.CPU)

    @property
    def lanes(self) -> int:
        """Pixels per work-item for the lane kernel on this device.

        16 where PoCL compiles for an AVX-512 target, and for the AVX2 targets
        of ``WIDE_AVX2_TARGETS`` where 16 was measured faster; 8 on other CPUs
        (16 lanes were once seen to abort PoCL 3.0 on a target without
        avx512f, so they are used only where tested); 1 on GPUs and other
        devices, whose hardware already runs work-items in SIMD.
        """
        cl = _cl()
        if not self.device.type & cl.device_type.CPU:
            return 1
        target = self.llvm_target
        if target and any(target.startswith(t) for t in AVX512_TARGETS + WIDE_AVX2_TARGETS):
            return 16
        return 8

    def kernel(self, program, name: str):
        """The ``cl.Kernel`` ``name`` of a program built by :meth:`program`, created once
        and reused (as PyOpenCL's ``RepeatedKernelRetrieval`` advises). Set its
        arguments and enqueue it while holding :attr:`lock`."""
        key = (id(program), name)
        with self._lock:
            hit = self._kernels.get(key)
            if hit is None or hit[0] is not program:
                hit = self._kernels[key] = (program, _cl().Kernel(program, name))
            return hit[1]

    def limits(self) -> tuple[int | None, int | None]:
        """The device's largest buffer and its global memory, in bytes (None: unknown)."""
        try:
            return int(self.device.max_mem_alloc_size), int(self.device.global_mem_size)
        except Exception:  # noqa: BLE001 - a stand-in device without these attributes
            return None, None

    def program(self, entry_file: str, defines: dict[str, int | float | str]):
        """Build (once) and return the program for ``kernels/entry_file`` with ``-D`` defines."""
        cl = _cl()
        folder = kernel_dir()
        opts = [f"-D{k}={v}" for k, v in sorted(defines.items())]
        opts += ["-cl-denorms-are-zero", f"-I{folder / 'include'}"]
        # -w: PoCL prints clang's notes ("AVX vector argument of type double8 ...
        # changes the ABI") straight to stderr, which would break the CLI's
        # one-line output. Set CLPHONG_CL_WARNINGS=1 to see them when editing kernels.
        if not os.environ.get("CLPHONG_CL_WARNINGS"):
            opts.append("-w")
        key = (entry_file, tuple(opts), _sources_digest(folder))
        with self._lock:
            prog = self._programs.get(key)
            if prog is not None:
                return prog
            src = (folder / entry_file).read_text()
            t0 = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    # PoCL reports harmless AVX ABI notes for float16 lanes on AVX2 CPUs.
                    warnings.simplefilter("ignore", cl.CompilerWarning)
                    prog = cl.Program(self.context, src).build(options=opts)
            except cl.Error as exc:
                log = str(exc).strip().splitlines()
                first = next((ln for ln in log if "error" in ln.lower()), log[-1] if log else "")
                raise DeviceError(
                    f"kernels/{entry_file} failed to build on {self.name}: "
                    f"{first.strip() or type(exc).__name__}; set PYOPENCL_CTX or --device to use "
                    "another device, e.g. PoCL's CPU device (install it with "
                    "'pip install \"pyopencl[pocl]\"')"
                ) from exc
            self.build_seconds += time.perf_counter() - t0
            self.builds += 1
            self._programs[key] = prog
            return prog


_RUNTIMES: dict[str | None, Runtime] = {}
_RT_LOCK = threading.Lock()


def get_runtime(device: str | None = None) -> Runtime:
    """The process-wide runtime for ``device`` (see the module docstring)."""
    cl = _cl()
    if device is None and os.environ.get("PYOPENCL_CTX"):
        key = "PYOPENCL_CTX=" + os.environ["PYOPENCL_CTX"]
    else:
        key = device
    with _RT_LOCK:
        rt = _RUNTIMES.get(key)
        if rt is not None:
            return rt
        try:
            if device is None and os.environ.get("PYOPENCL_CTX"):
                ctx = cl.create_some_context(interactive=False)
                dev = ctx.devices[0]
            else:
                dev = _choose(device)
                ctx = cl.Context([dev])
            queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
        except DeviceError:
            raise
        except Exception as exc:  # pyopencl raises several types here
            reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            if device is None and os.environ.get("PYOPENCL_CTX"):
                try:
                    choices = "; ".join(list_devices()) or "none"
                except DeviceError:
                    choices = "none"
                raise DeviceError(
                    f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']!r} names no usable OpenCL device "
                    f"({reason}); unset it or set it to one of: {choices}; {_INSTALL_HINT}"
                ) from exc
            raise DeviceError(f"could not open OpenCL device ({reason}); {_INSTALL_HINT}") from exc
        rt = Runtime(device=dev, context=ctx, queue=queue)
        _RUNTIMES[key] = rt
        return rt


def float4(x=0.0, y=0.0, z=0.0, w=0.0):
    """A ``float4`` kernel argument."""
    return _cl().cltypes.make_float4(x, y, z, w)
