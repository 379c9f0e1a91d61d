"""Which OpenCL device, at which lane width: the choice, the self-test verdicts, and the
process-wide runtimes.

Device choice, in order:

1. ``device=`` argument (CLI ``--device``), in ``PYOPENCL_CTX`` syntax
   (``"0"``, ``"0:1"``) or as a case-insensitive substring of a platform or
   device name (``"pocl"``, ``"intel"``, ``"nvidia"``);
2. the ``PYOPENCL_CTX`` environment variable, as PyOpenCL reads it;
3. of the devices whose width from the host rule (:mod:`clphong.device.hostrule`)
   passes the self-test, the fastest on a small calibration frame
   (:func:`clphong.device.selftest.calibrate`, measured with the self-test and cached
   with it): a GPU over the CPU where it is faster; otherwise the first CPU device in
   the order of :data:`clphong.device.platforms.PREFERENCE` (Intel's CPU runtime, then
   PoCL), then the others, a later one only where it is :data:`RATE_MARGIN` times
   faster than the one before it.

Whatever chose the device, its lane width comes from the host rule and is
self-tested (:mod:`clphong.device.selftest`, in a child process) before the first
frame; a width that fails is never used: the next one the rule allows is tried
with a one-line warning. Verdicts are cached in clphong's cache folder, keyed by
the platform, the driver, the host's features and the kernel sources.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import warnings
from pathlib import Path

from ..core.errors import DeviceError, DeviceWarning
from . import hostrule, platforms
from .isolate import VariantCrash, in_child, intel_vectorizer_mode, run_child
from .runtime import (
    _CHOICE_HINT,
    _INSTALL_HINT,
    Runtime,
    _all_devices,
    _cl,
    _full_names,
    _sources_digest,
    _start_notice,
    kernel_dir,
    list_devices,
)

__all__ = ["get_runtime", "verify", "check_width", "next_default", "describe_devices"]


def _choose(spec: str):
    """The device a --device value names: "P:D" indices, or a name substring or alias."""
    devices = _all_devices()
    if not devices:
        raise DeviceError(f"no OpenCL device found; {_INSTALL_HINT}")
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
    for name, dev in _full_names():            # the exact full name (what children are given)
        if spec == name:
            return dev
    for _, _, plat, dev in devices:
        if platforms.matches(spec, plat.name, dev.name):
            return dev
    raise DeviceError(f"device '{spec}': no match; available: " + "; ".join(list_devices())
                      + "; " + _CHOICE_HINT)



def _candidates() -> list:
    """Devices in the default order: CPU devices by platform preference, then the rest."""
    cl = _cl()
    devices = [dev for _, _, _, dev in _all_devices()]
    cpus = [d for d in devices if d.type & cl.device_type.CPU]
    rank = {k: i for i, k in enumerate(platforms.PREFERENCE)}
    cpus.sort(key=lambda d: rank.get(platforms.device_kind(d), len(rank)))
    return cpus + [d for d in devices if not d.type & cl.device_type.CPU]



_RUNTIMES: dict[str | None, Runtime] = {}
_RT_LOCK = threading.Lock()

#: Bumped when the self-test changes what it checks: older verdicts are not reused.
SELFTEST_VERSION = 5
_VERDICTS: dict[Path, dict] = {}


def _verdict_path(rt: Runtime, width: int) -> Path:
    dev, plat = rt.device, rt.device.platform
    h = hashlib.sha256()
    for part in (plat.name, plat.version, dev.name, dev.version, dev.driver_version,
                 hostrule.host().key, _sources_digest(kernel_dir()), width, SELFTEST_VERSION,
                 os.environ.get("POCL_EXTRA_BUILD_FLAGS", ""), intel_vectorizer_mode()):
        h.update(str(part).encode() + b"\0")
    return platforms.cache_dir() / "selftest" / f"{h.hexdigest()[:40]}.json"


def verify(rt: Runtime, width: int) -> dict:
    """The self-test verdict of ``rt``'s device at ``width`` lanes
    (:mod:`clphong.device.selftest`, run in a child process once, then cached on disk):
    ``{"ok": bool, "worst": max |err|/bound, "detail": str}``. In a child: not checked."""
    if in_child():
        return {"ok": True, "worst": 0.0, "detail": "not checked in a child process"}
    verdict = _verdict(rt, width)
    # the width's measure of native_rsqrt goes with every reading of its verdict, so the
    # plan at this width takes what its self-test ran (Runtime.rsqrt_native)
    rt.native_rsqrt_ulps[width] = verdict.get("native_rsqrt_ulp") if verdict.get("ok") else None
    rt.builtin_rsqrt_ulps[width] = verdict.get("builtin_rsqrt_ulp") if verdict.get("ok") else None
    return verdict


def _verdict(rt: Runtime, width: int) -> dict:
    path = _verdict_path(rt, width)
    verdict = _VERDICTS.get(path)
    if verdict is not None:
        return verdict
    try:
        verdict = json.loads(path.read_text())
        if isinstance(verdict, dict) and isinstance(verdict.get("ok"), bool):
            _VERDICTS[path] = verdict
            return verdict
    except (OSError, ValueError):
        pass
    what = f"the self-test of {rt.name} at {width} lane(s)"
    notice = _start_notice(None, f"clphong: checking {rt.name} at {width} lane(s) against the "
                                 "float64 reference (first use; cached afterwards)\u2026")
    keep = True
    try:
        out = run_child("clphong.device.selftest", ["--device", rt.selector, "--lanes", str(width)],
                        timeout=SELFTEST_TIMEOUT_S, what=what)
        verdict = json.loads(out.strip().splitlines()[-1])
    except VariantCrash as exc:
        verdict = {"ok": False, "worst": float("inf"), "detail": str(exc)}
        keep = not exc.transient          # a timeout or ^C says nothing about the device
    except (ValueError, IndexError):
        verdict = {"ok": False, "worst": float("inf"), "detail": f"{what}: no verdict"}
    finally:
        if notice is not None:
            notice.cancel()
    _VERDICTS[path] = verdict
    if keep:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(verdict))
            os.replace(tmp, path)
        except OSError:
            pass
    return verdict


#: A self-test compiles four small variants: seconds; more means a hung compiler.
SELFTEST_TIMEOUT_S = 300.0


def _configure(rt: Runtime, lanes: int | None) -> Runtime:
    """Give ``rt`` its lane width: ``lanes`` if given (a child's), else the best width
    the host rule allows whose self-test passes, warning at each that fails."""
    decision = rt.decision
    if in_child():
        rt.lanes = lanes or (decision.widths or (1,))[0]
        rt.choice = "a child process: the parent chose the width"
        return rt
    h = hostrule.host()
    if decision.refused:
        raise DeviceError(f"{rt.name} cannot be used on this CPU, {h.label}: {decision.why()}; "
                          f"{_other_device_hint()}")
    for i, width in enumerate(decision.widths):
        verdict = verify(rt, width)
        if verdict["ok"]:
            rt.lanes = width
            rt.fp64_ratio = verdict.get("fp64_ratio")
            rt.pair_rate = verdict.get("pair_rate")
            rt.choice = (f"{width} lane(s), the host rule's best that passed the self-test "
                         f"(worst |err|/bound {verdict['worst']:.2g}); rule: {decision.why()}")
            return rt
        rest = decision.widths[i + 1:]
        warnings.warn(DeviceWarning(
            f"{rt.name} at {width} lane(s) failed its self-test ({verdict['detail']}); "
            + (f"trying {rest[0]} lane(s)" if rest else "not using this device")))
    raise DeviceError(f"{rt.name} passed its self-test at no lane width the host rule allows "
                      f"({', '.join(map(str, decision.widths))}); {_other_device_hint()}")


def _other_device_hint() -> str:
    """What to do when a device is refused: another device, or Intel's runtime if it is
    not installed (naming the install to someone who has it only confuses)."""
    if platforms.intel_cpu_runtime() is not None:
        return ("choose another device with --device (see 'clphong devices'), e.g. --device "
                "intel")
    return ("choose another device with --device (see 'clphong devices'), or install Intel's "
            "CPU runtime: pip install \"clphong[intel]\"")


def _open(dev) -> Runtime:
    cl = _cl()
    ctx = cl.Context([dev])
    queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
    return Runtime(device=dev, context=ctx, queue=queue)


#: Devices whose compiler died on a variant at every width (:func:`next_default`).
_CRASHED: list = []


def next_default(rt: Runtime) -> Runtime | None:
    """The default device after ``rt``'s, once ``rt``'s compiler has died at every width
    it allows: ``rt``'s device is passed over for the rest of the process. None if no
    other device passes (or ``rt`` was not the default)."""
    with _RT_LOCK:
        if _RUNTIMES.get(None) is not rt:
            return None
        _CRASHED.append(rt.device)
        del _RUNTIMES[None]
        try:
            other = _RUNTIMES[None] = _default_runtime()
        except DeviceError:
            return None
        return other


#: How much faster on the calibration frame a later candidate must be to displace an
#: earlier one as the default. On two Ice Lake cores with another process running, PoCL's
#: frame read 0.734 GPLE/s against Intel's runtime's 0.713 and PoCL became the default,
#: though at 1080p Intel's runtime is the faster (docs/platforms.md's table: 1.22 against
#: 1.06x numba accurate, 2.41 against 1.57x fast); a GPU's lead is 3x and more where it
#: wins (issue 29).
RATE_MARGIN = 1.25


def _default_runtime() -> Runtime:
    """Of the devices of :func:`_candidates` that the host rule allows and whose self-test
    passes at some width (none whose compiler died: :func:`next_default`), the one with
    the highest measured rate on the calibration frame (``Runtime.pair_rate``); the
    first in candidate order where rates tie or were not measured."""
    reasons, passed = [], []
    for dev in _candidates():
        if any(dev == crashed for crashed in _CRASHED):
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeviceWarning)   # each device is said below
                passed.append(_configure(_open(dev), None))
        except DeviceError as exc:
            reasons.append(str(exc).split("; choose another device")[0])
    if passed:
        # in candidate order, a later device displaces the best so far only when it is
        # RATE_MARGIN times faster: the calibration frame is short (about 20 ms on two CPU
        # cores) and its rate moves with other load, while the order has measured reasons
        best = passed[0]
        for rt in passed[1:]:
            if (rt.pair_rate or 0.0) > RATE_MARGIN * (best.pair_rate or 0.0):
                best = rt
        if len(passed) > 1:
            rates = ", ".join(f"{rt.name} {_rate(rt)}" for rt in passed)
            best.choice = (f"the fastest of {len(passed)} devices that passed their self-tests "
                           f"on the calibration frame ({rates}; a later one in the order of "
                           f"preference only at {RATE_MARGIN:g}x the rate before it); "
                           f"{best.choice}")
        return best
    if not reasons:
        raise DeviceError(f"no OpenCL device found; {_INSTALL_HINT}")
    raise DeviceError("no OpenCL device renders right on this CPU: " + "; ".join(reasons)
                      + "; install Intel's CPU runtime: pip install \"clphong[intel]\"")


def _rate(rt: Runtime) -> str:
    """A device's calibration rate for messages: "1.2 GPLE/s" (pixel-light pairs)."""
    return "rate not measured" if rt.pair_rate is None else f"{rt.pair_rate / 1e9:.3g} GPLE/s"


def get_runtime(device: str | None = None, *, lanes: int | None = None) -> Runtime:
    """The process-wide runtime for ``device`` (see the module docstring); ``lanes``
    is for child processes, which are told their width."""
    cl = _cl()
    if device is None and os.environ.get("PYOPENCL_CTX"):
        key = "PYOPENCL_CTX=" + os.environ["PYOPENCL_CTX"]
    else:
        key = device
    with _RT_LOCK:
        rt = _RUNTIMES.get(key)
        if rt is not None:
            return rt
        if device is None and not os.environ.get("PYOPENCL_CTX"):
            rt = _RUNTIMES[key] = _default_runtime()
            return rt
        try:
            if device is None:
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
            if device is None:
                try:
                    choices = "; ".join(list_devices()) or "none"
                except DeviceError:
                    choices = "none"
                raise DeviceError(
                    f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']!r} names no usable OpenCL device "
                    f"({reason}); unset it or set it to one of: {choices}; {_INSTALL_HINT}"
                ) from exc
            raise DeviceError(f"could not open OpenCL device ({reason}); {_INSTALL_HINT}") from exc
        rt = _configure(Runtime(device=dev, context=ctx, queue=queue), lanes)
        _RUNTIMES[key] = rt
        return rt


def describe_devices() -> tuple[list[dict], str]:
    """For ``clphong devices``: per device, its selector, name, kind, compiler target,
    whether that matches the host, the width the rule and the self-test give (or why
    none), and whether it is the default; and why the default is the default."""
    h = hostrule.host()
    try:
        default = get_runtime(None)
        default_dev, default_why = default.device, default.choice
    except DeviceError as exc:
        default_dev, default_why = None, str(exc)
    rows = []
    for pi, di, plat, dev in _all_devices():
        rt = default if default_dev is not None and dev == default_dev else None
        row = {"selector": f"{pi}:{di}", "name": f"{plat.name} / {dev.name.strip()}",
               "default": rt is not None}
        try:
            rt = rt or _open(dev)
            decision = rt.decision
            has512 = hostrule.target_has_avx512(rt.target)
            row.update(kind=rt.kind, target=rt.target, host=h.label,
                       match=("n/a" if rt.kind == "gpu" else "yes (the host's own features)"
                              if rt.target == "host" else "unknown target" if has512 is None
                              else "yes" if has512 == h.avx512 else
                              "NO: " + ("AVX-512 host, target without it" if h.avx512
                                        else "target with AVX-512, host without")),
                       rule=decision.why())
            if decision.refused:
                row.update(width=None, verdict="refused by the host rule")
            else:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", DeviceWarning)
                    chosen = rt if row["default"] else _configure(rt, None)
                v = verify(chosen, chosen.lanes)
                row.update(width=chosen.lanes,
                           verdict=f"passed (worst |err|/bound {v['worst']:.2g}); "
                                   f"calibration frame {_rate(chosen)}",
                           double=chosen.double_line(), rsqrt=chosen.rsqrt_line())
        except DeviceError as exc:
            row.setdefault("width", None)
            row["verdict"] = "failed: " + str(exc).split("; choose another device")[0]
        rows.append(row)
    return rows, default_why



def check_width(rt: Runtime, lanes: int) -> None:
    """Refuse, in one line, a lane width the host rule leaves out on this device or
    whose self-test fails (run now if it never ran here)."""
    if lanes == rt.lanes or in_child():
        return
    decision = rt.decision
    allowed = " or ".join(map(str, decision.widths)) or "none"
    if lanes not in decision.widths:
        raise DeviceError(f"--lanes {lanes} is not safe on {rt.name}: {decision.why()}; "
                          f"use --lanes {allowed} (or leave it out: {rt.lanes})")
    verdict = verify(rt, lanes)
    if not verdict["ok"]:
        raise DeviceError(f"--lanes {lanes} failed the self-test on {rt.name} "
                          f"({verdict['detail']}); leave it out to use {rt.lanes}")
