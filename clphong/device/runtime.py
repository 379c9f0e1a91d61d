"""OpenCL runtime: one device's context, queue, kernel sources and program cache.

The device and its lane width are chosen by :mod:`clphong.device.selection`.

Programs are built once per (device, kernel sources, options) and cached in the
process. Across processes PoCL's own kernel cache (``$XDG_CACHE_HOME/pocl`` or
``$POCL_CACHE_DIR``) makes a rebuild of the same source and options cost tens of
milliseconds; PyOpenCL skips its own binary cache for PoCL. On PoCL clphong also
keeps each program's PoCL binary in that folder (``clphong/*.poclbin``) and
builds from it, so that a run whose programs are cached writes no file there
(:meth:`Runtime.program`).
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..core.errors import DeviceError
from . import hostrule, platforms
from .isolate import IMPLICIT_VECTOR_KERNELS, build_child, in_child, intel_vectorizer_mode
from .peak import FAST_FP64_RATIO, NATIVE_RSQRT_MAX_ULP

# PoCL's CPU drivers install a SIGFPE handler (integer division by zero in a
# kernel then gives an undefined value instead of killing the process), and to
# order it after LLVM's handlers PoCL 3.0 creates an empty ``tempfile_XXXXXX`` in
# its kernel cache at every device initialisation, never removed
# (lib/CL/devices/signal_handlers.c). clphong's kernels divide only by sizes the
# host checks, so the handler is switched off: a cached run writes nothing. Read
# by PoCL when the devices are first listed, so set here, before any is.
os.environ.setdefault("POCL_SIGFPE_HANDLER", "0")

_INSTALL_HINT = (
    "install PoCL with 'pip install \"pyopencl[pocl]\"', or choose another device "
    "with --device or the PYOPENCL_CTX environment variable (e.g. PYOPENCL_CTX=0)"
)

#: Said when --device names no device: the other ways to choose, and how to get one.
_CHOICE_HINT = (
    "give --device as 'P:D' indices or a name substring of one of these (see 'clphong devices'), "
    "or set the PYOPENCL_CTX environment variable (e.g. PYOPENCL_CTX=0:0); a device that is "
    "not listed needs its vendor's OpenCL driver (ICD); the CPU devices come with PoCL "
    "(pip install \"pyopencl[pocl]\") and Intel's CPU runtime (pip install \"clphong[intel]\")"
)


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


#: Work-groups per compute unit that a launch piece fills at least (Runtime.fill_groups):
#: 32 groups of 64 is an NVIDIA multiprocessor's 2,048 resident work-items.
FILL_GROUPS = 32


#: Platforms (``Runtime.kind``) whose float 1/√x may start from native_rsqrt (plan
#: RSQRT_NATIVE) where the self-test measures it within 2 ulp: Intel's CPU runtime,
#: which inlines it as the hardware estimate. PoCL 3.0 calls it out of line, and a GPU
#: was not measured with it.
NATIVE_RSQRT_KINDS = ("intel-cpu",)

#: Free space below which PoCL's cache folder is taken for full (a compile writes ~1.1 MB).
CACHE_MIN_FREE = 4 << 20


def cache_problem(folder: Path) -> str | None:
    """Why PoCL could not write in ``folder`` (its kernel cache): "is not writable",
    "is full (N free)", "is not a folder"; None when it looks usable. The folder
    need not exist yet: its nearest existing parent is checked."""
    import shutil

    p = Path(folder)
    while not p.exists() and p != p.parent:
        p = p.parent
    if p.exists() and not p.is_dir():
        return f"is not a folder ({p} is a file)"
    if not os.access(p, os.W_OK | os.X_OK):
        return "is not writable"
    try:
        free = shutil.disk_usage(p).free
    except OSError:
        return None
    if free < CACHE_MIN_FREE:
        return f"is full ({free // 1024} KiB free)"
    return None


def pocl_cache_dir() -> Path:
    """PoCL's kernel cache folder, chosen as PoCL 3.0 does (lib/CL/pocl_cache.c):
    ``$POCL_CACHE_DIR``, else ``$XDG_CACHE_HOME/pocl/kcache``, else
    ``~/.cache/pocl/kcache`` (``…/pocl/uncached`` with ``POCL_KERNEL_CACHE=0``)."""
    if os.environ.get("POCL_CACHE_DIR"):
        return Path(os.environ["POCL_CACHE_DIR"])
    sub = "pocl/kcache" if _pocl_kernel_cache_on() else "pocl/uncached"
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]) / sub
    if os.environ.get("HOME") is not None:
        return Path(os.environ["HOME"]) / ".cache" / sub
    return Path("/tmp") / sub


def _pocl_kernel_cache_on() -> bool:
    """PoCL's ``POCL_KERNEL_CACHE`` (on unless set to something not starting with 1)."""
    return os.environ.get("POCL_KERNEL_CACHE", "1").startswith("1")


#: The largest file PoCL writes while compiling a program from source, with a
#: margin: the preprocessed source (``tempfile_*.preproc.cl``, with every macro of
#: Clang's opencl-c.h), 1.1 MB for shade.cl under PoCL 3.0 / LLVM 14. Under a
#: smaller ``ulimit -f`` LLVM aborts the process ("IO failure on output stream").
_SOURCE_BUILD_BYTES = 2 << 20

#: clphong's binaries in PoCL's cache folder: ``clphong/NAME-KEY.poclbin``, a
#: header line, the SHA-256 of the rest, then the program as PoCL serialises it
#: (CL_PROGRAM_BINARIES: program.bc and the kernels' machine code).
_STORE_DIR = "clphong"
_STORE_MAGIC = b"clphong-poclbin 1\n"


def _file_size_limit() -> int | None:
    """The soft RLIMIT_FSIZE (``ulimit -f``) in bytes; None where unlimited or unknown."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not POSIX
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    return None if soft == resource.RLIM_INFINITY or soft < 0 else int(soft)


#: Called with one line (no newline) when a program build is still running after
#: :data:`COMPILE_NOTICE_AFTER_S`: a real compile, not a hit in a cache. None (the
#: library's default) is silent; the CLI sets :func:`notice_on_tty`.
compile_notice: Callable[[str], None] | None = None
#: A build from clphong's or PoCL's disk cache takes 0.01–0.05 s, a compile 0.3–30 s.
COMPILE_NOTICE_AFTER_S = 0.2


def notice_on_tty(message: str, stream=None) -> None:
    """Write ``message`` as one line to ``stream`` (default ``sys.stderr``) if it is a
    terminal; nothing otherwise (pipelines and tests capture stderr)."""
    stream = sys.stderr if stream is None else stream
    try:
        if not stream.isatty():
            return
        stream.write(message + "\n")
        stream.flush()
    except (AttributeError, ValueError, OSError):
        pass


def _cl():
    # Intel's pip-installed CPU runtime becomes a platform only if the ICD loader sees it
    # when platforms are first listed
    platforms.register_pip_runtimes()
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


def _full_names() -> list[tuple[str, object]]:
    """Each device's full name, ``PLATFORM / DEVICE``, with `` #N`` from the second
    device of the same name on."""
    out, seen = [], {}
    for _, _, plat, dev in _all_devices():
        name = f"{plat.name} / {dev.name.strip()}"
        seen[name] = seen.get(name, 0) + 1
        out.append((name if seen[name] == 1 else f"{name} #{seen[name]}", dev))
    return out


def _selector(device) -> str:
    """``device``'s full name (:func:`_full_names`): what a child process is told. Not the
    "P:D" indices, which differ in a child if this process listed the platforms before
    Intel's runtime was registered."""
    for name, dev in _full_names():
        if dev == device:
            return name
    return "0:0"


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
    #: Of :attr:`builds`, those compiled from source: not found in clphong's
    #: binaries in PoCL's cache folder (:meth:`program`).
    compiled: int = 0
    #: Pixels per work-item of the lane kernel: the best width the host rule allows on
    #: this device whose self-test passed (set by :func:`get_runtime`).
    lanes: int = 1
    #: Why this device and width: a line for ``clphong devices`` and ``--stats``.
    choice: str = ""
    #: Defines added to every program (the self-test's test-only fault; else empty).
    extra_defines: dict = field(default_factory=dict)
    #: The device's double-to-float FMA rate, measured by the self-test
    #: (:func:`clphong.device.peak.measure_fp64_ratio`); None: not measured.
    fp64_ratio: float | None = None
    #: Pixel-light pairs a second on the calibration frame, measured with the self-test
    #: (:func:`clphong.device.selftest.calibrate`); None: not measured.
    pair_rate: float | None = None
    #: Per lane width, the error in float ulp of 1/√x from native_rsqrt and one Newton
    #: step, measured by the self-test (:func:`clphong.device.peak.measure_native_rsqrt_ulp`);
    #: None or absent: not measured.
    native_rsqrt_ulps: dict = field(default_factory=dict)
    #: Per lane width, the error in float ulp of the builtin rsqrt, measured by the
    #: self-test (:func:`clphong.device.peak.measure_builtin_rsqrt_ulp`); None or absent:
    #: not measured.
    builtin_rsqrt_ulps: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        """The host rule's kind of this device (:func:`clphong.device.platforms.device_kind`)."""
        return platforms.device_kind(self.device)

    @property
    def target(self) -> str:
        """What the device's compiler targets: PoCL's LLVM CPU name, "host" for Intel's CPU
        runtime (it dispatches on the host's own features), else the device's name."""
        if self.llvm_target or self.is_pocl:
            return self.llvm_target or "generic"
        return "host" if self.kind == "intel-cpu" else self.device.name.strip()

    @property
    def decision(self) -> hostrule.Decision:
        """The widths the host rule allows on this device, best first, and why."""
        return hostrule.decide(self.kind, self.target)

    @property
    def selector(self) -> str:
        """This device's full name, ``PLATFORM / DEVICE`` (what a child process is given)."""
        return _selector(self.device)

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
    def fill_groups(self) -> int:
        """Work-groups that keep every compute unit busy: FILL_GROUPS per compute unit (two
        on a CPU, whose compute unit is a core that runs one work-group at a time). A launch
        piece holds at least this many (of ``frame.LOCAL_SIZE`` work-items each)."""
        per_unit = 2 if self.device.type & _cl().device_type.CPU else FILL_GROUPS
        return int(self.device.max_compute_units) * per_unit

    def rsqrt_builtin(self, lanes: int) -> tuple[str, ...]:
        """The formats, "float" and "double", in which the shading kernel at ``lanes``
        takes 1/√x from the OpenCL C builtin (``plan``'s RSQRT_BUILTIN), on Intel's CPU
        runtime only: PoCL 3.0 calls it out of line at a higher cost, and a GPU was not
        measured with it (clphong's inline steps there).

        * float: where the width's self-test measured it within the specification's 2
          ulp (:func:`~clphong.device.peak.measure_builtin_rsqrt_ulp`; Intel's runtime on
          Zen 3's AVX2 returned 2.4e-19 for every x ≥ 2^126 at 1, 8 and 16 lanes until
          rsqrt_dist scaled such x). Faster than the inline steps on Zen 5 (the fast
          path's lights loop 2x) and on Zen 3 (0.822 against 0.765 GPLE/s, 2026-12-07).
        * double: on an AVX-512 host (Zen 5: the accurate path's lights loop 1.5x). On
          Zen 3 (AVX2) the double SVML call was the slower: 0.527 against 0.629 GPLE/s for
          the inline steps, 1080p × 256 lights, 16 lanes (2026-12-07)."""
        if self.kind not in NATIVE_RSQRT_KINDS:
            return ()
        ulp = self.builtin_rsqrt_ulps.get(lanes)
        formats = ("float",) if ulp is not None and ulp <= NATIVE_RSQRT_MAX_ULP else ()
        return formats + (("double",) if hostrule.host().avx512 else ())

    def rsqrt_native(self, lanes: int) -> bool:
        """Whether the shading kernel's float 1/√x at ``lanes`` starts from native_rsqrt
        with one Newton step (``plan``'s RSQRT_NATIVE): on the platforms where it was
        measured faster (:data:`NATIVE_RSQRT_KINDS`: Intel's CPU runtime inlines the
        hardware estimate where its builtin is a call, 1.06x the fast path on Zen 5),
        and only at a width whose self-test measured it within the error model's 2 ulp.
        The step's form (clphong.h) reads 1.74 ulp on Zen 3 at every width (its 12-bit
        vrsqrtps), where the textbook form read 2.39 and kept the builtin's call: the
        fast path 1.23-1.26x there; the textbook form read 1.96 at 16 lanes on Zen 5
        and 2.39 at 1 and 8. The new form is not measured on Zen 4 or 5: where it reads
        within 2 ulp at 8 or 1 lanes too, those widths now take it instead of the
        builtin."""
        ulp = self.native_rsqrt_ulps.get(lanes)
        return self.kind in NATIVE_RSQRT_KINDS and ulp is not None and ulp <= NATIVE_RSQRT_MAX_ULP

    @property
    def light_unroll(self) -> int:
        """Lights an iteration of the shading kernel's light loops (``plan``'s
        LIGHT_UNROLL): 4 on Intel's CPU runtime on an AVX-512 host, whose compiled loop let
        the core overlap too little of one light's ~40-operation chain with the next (Zen
        5, 1080p × 256 lights: fast 1.27x, accurate 1.35x; 8 added 0-3 % more for twice
        the code); 2 on an AVX2 host, whose 16 vector registers hold fewer chains (Zen 3,
        the same frame: accurate 0.635 → 0.721 GPLE/s at 2, 0.703 at 4; fast 0.835 →
        0.866, 0.870; 2026-12-07). 0 elsewhere: PoCL (Zen 3: no faster at 2 or 4) and
        GPUs (not measured)."""
        if self.kind != "intel-cpu":
            return 0
        return 4 if hostrule.host().avx512 else 2

    @property
    def light_tile(self) -> bool:
        """Whether the shading kernel stages the light records through local memory
        (``plan.LIGHT_TILE``): on a GPU, where a work-group's work-items would each read
        every record from global memory; not on a CPU, whose L1 holds them."""
        return not self.device.type & _cl().device_type.CPU

    @property
    def fast_fp64(self) -> bool:
        """Double precision at a useful speed: cl_khr_fp64 at a measured double-to-float
        rate of at least :data:`~clphong.device.peak.FAST_FP64_RATIO` (1/2 on CPUs and on
        the H100/H200, A100 and MI300; 1/16-1/64 on consumer GPUs). Where the rate was
        not measured, a CPU device with fp64. The plan then computes the sums, the integer
        specular power and the weights in double (``plan.SPEC_INT_POW``, ``SUM_FP64``)."""
        if not self.has_fp64:
            return False
        if self.fp64_ratio is None:
            return bool(self.device.type & _cl().device_type.CPU)
        return self.fp64_ratio >= FAST_FP64_RATIO

    def double_line(self) -> str:
        """What the device's double rate means for the shading plan, in one line."""
        if not self.has_fp64:
            return "no double precision (cl_khr_fp64): float directions, compensated float sums"
        rate = ("not measured" if self.fp64_ratio is None
                else f"{self.fp64_ratio:.2g} of the float rate (measured)")
        if self.fast_fp64:
            return (f"double at {rate}: the accurate path forms directions, weights, sums and the "
                    "integer power in double (relative error target 5e-6)")
        return (f"double at {rate}, under {FAST_FP64_RATIO:g}: the accurate path keeps double "
                "directions only, with compensated float sums and weights; each pixel stays "
                "within the error model's bound, but lights that cancel may miss the 5e-6 target")

    def rsqrt_line(self) -> str | None:
        """How the fast path forms 1/√x at the chosen width, in one line (None where the
        platform does not measure native_rsqrt: :data:`NATIVE_RSQRT_KINDS`)."""
        if self.kind not in NATIVE_RSQRT_KINDS:
            return None
        native = self.native_rsqrt_ulps.get(self.lanes)
        builtin = self.builtin_rsqrt_ulps.get(self.lanes)
        how = ("native_rsqrt and one Newton step" if self.rsqrt_native(self.lanes)
               else "the builtin rsqrt" if "float" in self.rsqrt_builtin(self.lanes)
               else "clphong's inline Newton steps")

        def measured(ulp):
            return "not measured at this width" if ulp is None else f"{ulp:.3g} ulp"

        return (f"float 1/√x: {how} (each within 2 ulp or not taken; over every float of "
                f"[1, 4) and more: native_rsqrt and one step {measured(native)}, the builtin "
                f"{measured(builtin)})")

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

    def build_options(self, defines: dict[str, int | float | str]) -> list[str]:
        """The build options of a program with these ``-D`` defines."""
        folder = kernel_dir()
        opts = [f"-D{k}={v}" for k, v in sorted({**defines, **self.extra_defines}.items())]
        opts += ["-cl-denorms-are-zero", f"-I{folder / 'include'}"]
        # -w: PoCL prints clang's notes ("AVX vector argument of type double8 ...
        # changes the ABI") straight to stderr, which would break the CLI's
        # one-line output. Set CLPHONG_CL_WARNINGS=1 to see them when editing kernels.
        if not os.environ.get("CLPHONG_CL_WARNINGS"):
            opts.append("-w")
        return opts

    def program(self, entry_file: str, defines: dict[str, int | float | str]):
        """Build (once) and return the program for ``kernels/entry_file`` with ``-D`` defines.

        A program not in the binary store is compiled in a child process
        (:mod:`clphong.device.isolate`), so that a compiler abort becomes a
        :class:`~clphong.device.isolate.VariantCrash`; its binary is loaded here."""
        opts = self.build_options(defines)
        mode = None
        if entry_file in IMPLICIT_VECTOR_KERNELS and self.kind == "intel-cpu":
            # its own vectoriser mode on Intel's runtime (isolate.py), named in the
            # options so that PyOpenCL's binary cache keeps the modes apart; a child
            # compiles with its own process's mode, and names that one
            mode = intel_vectorizer_mode(implicit=not in_child())
            opts.append(f"-DCLPHONG_VECTORIZER={mode}")
        key = (entry_file, tuple(opts), _sources_digest(kernel_dir()))
        with self._lock:
            prog = self._programs.get(key)
            if prog is not None:
                return prog
            t0 = time.perf_counter()
            store = self._binary_path(entry_file, opts, key[2], mode)
            prog = self._load_binary(store, opts) if store is not None else None
            if prog is None:
                self._check_room_to_compile(entry_file)
                notice = _start_notice(entry_file)
                try:
                    prog = (self._compile(entry_file, opts) if in_child()
                            else self._compile_in_child(entry_file, opts, mode))
                finally:
                    if notice is not None:
                        notice.cancel()
                if store is not None:
                    self._save_binary(prog, store)
                self.compiled += 1
            self.build_seconds += time.perf_counter() - t0
            self.builds += 1
            self._programs[key] = prog
            return prog

    def _compile(self, entry_file: str, opts: list[str]):
        """Compile ``kernels/entry_file`` from source in this process."""
        cl = _cl()
        src = (kernel_dir() / entry_file).read_text()
        try:
            with warnings.catch_warnings():
                # PoCL reports harmless AVX ABI notes for float16 lanes on AVX2 CPUs.
                warnings.simplefilter("ignore", cl.CompilerWarning)
                return cl.Program(self.context, src).build(options=opts)
        except cl.Error as exc:
            log = str(exc).strip().splitlines()
            first = next((ln for ln in log if "error" in ln.lower()), log[-1] if log else "")
            problem = cache_problem(pocl_cache_dir()) if self.is_pocl else None
            if problem:
                # PoCL writes its compiles there: a full or read-only folder fails the
                # build, and it is not the device or the install that is at fault
                raise DeviceError(
                    f"kernels/{entry_file} failed to build: PoCL's kernel cache folder "
                    f"{pocl_cache_dir()} {problem}; free space there or make it writable, or "
                    "set POCL_CACHE_DIR to a writable folder with room (about 2 MiB a "
                    "kernel variant)") from exc
            raise DeviceError(
                f"kernels/{entry_file} failed to build on {self.name}: "
                f"{first.strip() or type(exc).__name__}; choose another device with --device "
                "or PYOPENCL_CTX (see 'clphong devices')"
            ) from exc

    def compile_to(self, entry_file: str, opts: list[str], out: str) -> None:
        """The compiling child's side: compile in this process, the binary written to ``out``."""
        prog = self._compile(entry_file, opts)
        if not self._save_binary(prog, Path(out)):
            raise DeviceError(f"kernels/{entry_file}: the compiled binary could not be written "
                              f"to {out}")

    def _compile_in_child(self, entry_file: str, opts: list[str], mode: str | None = None):
        """Compile in the device's compiling child (of Intel's vectoriser ``mode``; None:
        the default) and load the binary it hands back."""
        lanes = next((o.split("=", 1)[1] for o in opts if o.startswith("-DLANES=")), "?")
        what = f"kernels/{entry_file} at {lanes} lane(s) on {self.name}"
        fd, out = tempfile.mkstemp(prefix="clphong-build-", suffix=".bin")
        os.close(fd)
        try:
            build_child(self.selector, mode).build(entry_file, opts, out, what)
            prog = self._load_binary(Path(out), opts)
        finally:
            try:
                os.unlink(out)
            except OSError:
                pass
        if prog is None:
            raise DeviceError(f"{what}: the binary compiled in a child process did not load")
        return prog

    # PoCL 3.0 writes on every build from source, cached or not: the source to
    # ``tempfile_*.cl`` and its preprocessed text (1.1 MB, every macro of
    # opencl-c.h) to ``tempfile_*.preproc.cl`` in its cache folder, because its
    # cache key is a hash of the preprocessed text (pocl_llvm_build.cc,
    # pocl_llvm_build_program), and LLVM aborts when that write fails (``ulimit
    # -f``). A program created from PoCL's own binary (CL_PROGRAM_BINARIES: the
    # build hash, program.bc and kernel code) skips the preprocessor and reuses
    # the same cache entry, whose files exist, so nothing is written. clphong
    # keeps those binaries next to PoCL's entries, keyed by what the program was
    # built from, and compiles from source only when its binary is missing.

    @property
    def is_pocl(self) -> bool:
        """Whether the device is PoCL's (whose kernel cache clphong's binaries join)."""
        name = str(getattr(self.device.platform, "name", "")).lower()
        return "portable computing language" in name or "pocl" in name

    def _binary_path(self, entry_file: str, opts: list[str], digest: str,
                     mode: str | None = None) -> Path | None:
        """Where clphong keeps this program's binary: beside PoCL's kernel cache on PoCL
        (None with it switched off, ``POCL_KERNEL_CACHE=0``), in clphong's cache folder
        (``bin/``) on other platforms."""
        if self.is_pocl and not _pocl_kernel_cache_on():
            return None
        dev, plat = self.device, self.device.platform
        h = hashlib.sha256()
        # What PoCL's own key covers (source, options, device) and the PoCL
        # build (driver version); plus the two knobs PoCL 3.0 reads at build time.
        for part in (entry_file, *opts, digest, plat.name, plat.version, dev.name, dev.version,
                     dev.driver_version, os.environ.get("POCL_EXTRA_BUILD_FLAGS", ""),
                     os.environ.get("POCL_WORK_GROUP_METHOD", ""),
                     intel_vectorizer_mode() if mode is None else mode):
            h.update(str(part).encode() + b"\0")
        if not self.is_pocl:
            return platforms.cache_dir() / "bin" / f"{Path(entry_file).stem}-{h.hexdigest()[:40]}.clbin"
        name = f"{Path(entry_file).stem}-{h.hexdigest()[:40]}.poclbin"
        return pocl_cache_dir() / _STORE_DIR / name

    def _load_binary(self, path: Path, opts: list[str]):
        """The program built from the binary at ``path``, or None (missing, damaged,
        or refused by PoCL, e.g. after a PoCL upgrade: then it is compiled again)."""
        cl = _cl()
        try:
            data = path.read_bytes()
        except OSError:
            return None
        n = len(_STORE_MAGIC)
        blob = data[n + 32:]
        if data[:n] != _STORE_MAGIC or not blob or hashlib.sha256(blob).digest() != data[n:n + 32]:
            return None     # never hand PoCL a truncated binary: it does not check one
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", cl.CompilerWarning)
                return cl.Program(self.context, [self.device], [blob]).build(options=opts)
        except cl.Error:
            return None

    def _save_binary(self, prog, path: Path) -> bool:
        """Keep ``prog``'s binary at ``path`` (atomically); whether it was written (a
        folder that cannot be written only costs the next process a compile)."""
        cl = _cl()
        try:
            blob = bytes(prog.binaries[0])
        except cl.Error:
            return False
        if not blob:
            return False
        tmp = path.with_name(f".{path.name}.{os.getpid()}-{threading.get_ident()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_bytes(_STORE_MAGIC + hashlib.sha256(blob).digest() + blob)
            os.replace(tmp, path)
            return True
        except OSError:
            return False
        finally:
            try:
                tmp.unlink()
            except OSError:
                pass

    def _check_room_to_compile(self, entry_file: str) -> None:
        """A one-line error, instead of LLVM's abort (SIGABRT, "IO failure on output
        stream"), where ``ulimit -f`` is too small for PoCL's files of a compile."""
        limit = _file_size_limit()
        if limit is None or limit >= _SOURCE_BUILD_BYTES or not self.is_pocl:
            return
        raise DeviceError(
            f"kernels/{entry_file} must be compiled for this scene, and PoCL writes files of "
            f"about 1.1 MB into its kernel cache ({pocl_cache_dir()}) to do so, over the file-size "
            f"limit of {limit // 1024} KiB (ulimit -f); run once with a higher limit "
            f"('ulimit -f unlimited', or at least {_SOURCE_BUILD_BYTES >> 20} MiB) to fill the "
            "cache (or point POCL_CACHE_DIR at a cache filled that way): later runs of the same "
            "scene write nothing there"
        )


def _start_notice(entry_file: str | None, message: str = ""):
    """Call :data:`compile_notice` if the build started now is still running after
    :data:`COMPILE_NOTICE_AFTER_S`; the timer to cancel when it ends (or None)."""
    hook = compile_notice
    if hook is None:
        return None
    what = "" if entry_file == "peak.cl" else " for this scene"
    message = message or f"clphong: compiling {entry_file}{what} (first run; cached afterwards)\u2026"
    if COMPILE_NOTICE_AFTER_S <= 0:
        hook(message)
        return None
    timer = threading.Timer(COMPILE_NOTICE_AFTER_S, hook, (message,))
    timer.daemon = True
    timer.start()
    return timer


def float4(x=0.0, y=0.0, z=0.0, w=0.0):
    """A ``float4`` kernel argument."""
    return _cl().cltypes.make_float4(x, y, z, w)
