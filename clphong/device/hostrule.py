"""The host rule: which float-lane widths each OpenCL CPU platform may use on this CPU.

Every entry of :data:`RULES` is a measured fact, not a guess. An OpenCL CPU
compiler targets a CPU: pip's PoCL 3.0 asks LLVM 14 to name the host and compiles
for that name (its HSTR: ``pthread-x86_64-unknown-linux-gnu-znver3``), while
Intel's CPU runtime dispatches on the host's own features. Where the name and the
host disagree, PoCL 3.0 emits code its kernel library and instruction selector do
not expect (PoCL's ``lib/CL/pocl_llvm_utils.cc``, ``pocl_get_llvm_cpu_name``, and
``pocl_llvm_build.cc``, which passes that name as ``-target-cpu`` after the user's
options, so no build option can override it):

* AMD Zen 4 (family 25 model 17): LLVM 14 says ``znver3`` (AVX2) but uses the
  host's AVX-512 features; 16 lanes render wrong pixels with exit 0, 8 lanes abort
  (``LLVM ERROR: Cannot select``), 4 and 1 are right.
* AMD Zen 5 (family 26): LLVM 14 does not know the CPU and says ``generic``, which
  its clang refuses (``unknown target CPU 'generic'``): every build fails.

The rule turns (platform, compiler target, host) into the widths allowed, best
first; the self-test (:mod:`clphong.device.selftest`) then checks the chosen one
on the device before its first frame. A width the rule leaves out is never used,
whatever the self-test says: an abort is not always reproducible on a tiny frame.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass
from typing import Callable

from .platforms import cache_dir

#: LLVM CPU names (prefixes) with avx512f.
AVX512_TARGETS = (
    "skylake-avx512", "cascadelake", "cooperlake", "cannonlake", "icelake", "tigerlake",
    "rocketlake", "sapphirerapids", "graniterapids", "emeraldrapids", "diamondrapids",
    "znver4", "znver5", "knl", "knm", "x86-64-v4",
)
#: LLVM CPU names (prefixes) of x86-64 CPUs without avx512f that PoCL 3.0 has been seen
#: to compile for; other names are unknown to the rule (8 lanes at most).
AVX2_TARGETS = ("znver1", "znver2", "znver3", "haswell", "broadwell", "skylake",
                "alderlake", "raptorlake", "x86-64-v3")
#: Targets where 16 lanes (two 256-bit halves a vector) were measured faster than 8 and
#: passed the whole suite: znver3 under PoCL 3.0, 1.3x (issue 4's notes).
WIDE_AVX2_TARGETS = ("znver3",)
#: What PoCL 3.0 reports when LLVM 14 does not know the host (its clang refuses it).
UNKNOWN_TARGETS = ("generic", "")


@dataclass(frozen=True)
class Host:
    """The CPU this process runs on, as archspec and /proc/cpuinfo see it."""

    name: str                   # archspec's microarchitecture ("zen4", "icelake", "x86_64_v4")
    vendor: str                 # "AuthenticAMD", "GenuineIntel", "" if unknown
    family: int | None          # x86 family and model (AMD 25/17: Zen 4; 26: Zen 5)
    model: int | None
    features: frozenset = frozenset()

    @property
    def avx512(self) -> bool:
        return "avx512f" in self.features

    @property
    def label(self) -> str:
        """One phrase naming the class: ``zen4 (AMD family 25 model 17, AVX-512)``."""
        fam = "" if self.family is None else f", family {self.family} model {self.model}"
        vec = "AVX-512" if self.avx512 else ("AVX2" if "avx2" in self.features else "no AVX2")
        return f"{self.name} ({self.vendor or 'unknown vendor'}{fam}, {vec})"

    @property
    def key(self) -> str:
        """What a cached verdict is keyed by: the class and every feature."""
        return f"{self.name}|{self.vendor}|{self.family}|{self.model}|" + ",".join(
            sorted(self.features))


def _cpuinfo_fields() -> dict[str, str]:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            text = f.read(65536)
    except OSError:
        return {}
    out: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            break                            # the first processor only
        k, _, v = line.partition(":")
        out.setdefault(k.strip(), v.strip())
    return out


@functools.lru_cache(maxsize=1)
def host() -> Host:
    """This machine's CPU (archspec's name and features, the family and model).

    archspec takes about 0.3 s to name a CPU (it loads its table of
    microarchitectures), so its answer is cached in clphong's cache folder, keyed
    by /proc/cpuinfo's vendor, family, model and flags."""
    info = _cpuinfo_fields()
    stamp = "|".join(info.get(k, "") for k in ("vendor_id", "cpu family", "model", "flags"))
    path = None
    if stamp.strip("|"):
        digest = hashlib.sha256(stamp.encode()).hexdigest()[:32]
        path = cache_dir() / "host" / f"{digest}.json"
        try:
            saved = json.loads(path.read_text())
            return Host(name=saved["name"], vendor=saved["vendor"], family=saved["family"],
                        model=saved["model"], features=frozenset(saved["features"]))
        except (OSError, ValueError, KeyError, TypeError):
            pass
    import archspec.cpu

    h = archspec.cpu.host()

    def num(key):
        try:
            return int(info[key])
        except (KeyError, ValueError):
            return None

    features = frozenset(h.features) | frozenset(info.get("flags", "").split())
    found = Host(name=str(h.name), vendor=info.get("vendor_id", str(h.vendor)),
                 family=num("cpu family"), model=num("model"), features=features)
    if path is not None:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps({"name": found.name, "vendor": found.vendor,
                                       "family": found.family, "model": found.model,
                                       "features": sorted(found.features)}))
            os.replace(tmp, path)
        except OSError:
            pass
    return found


def target_has_avx512(target: str) -> bool | None:
    """Whether an LLVM CPU name has avx512f; None for a name the rule does not know."""
    if any(target.startswith(t) for t in AVX512_TARGETS):
        return True
    if any(target.startswith(t) for t in AVX2_TARGETS):
        return False
    return None


@dataclass(frozen=True)
class Rule:
    """One entry of the table: where it applies, the widths it allows, and why."""

    platform: str                           # a kind of :mod:`clphong.device.platforms`
    when: str                               # the condition, in words
    applies: Callable[[str, Host], bool]    # (compiler target, host) -> bool
    widths: tuple[int, ...]                 # allowed, best first; () refuses the platform
    reason: str                             # the measurement behind it


def _pocl_unknown(target, h):
    return target in UNKNOWN_TARGETS


def _pocl_narrow_target_wide_host(target, h):
    return h.avx512 and target_has_avx512(target) is not True


def _pocl_wide(target, h):
    return target_has_avx512(target) is True and h.avx512


def _pocl_wide_avx2(target, h):
    return any(target.startswith(t) for t in WIDE_AVX2_TARGETS) and not h.avx512


def _always(target, h):
    return True


RULES: tuple[Rule, ...] = (
    Rule("pocl", "LLVM does not know the CPU (target 'generic')", _pocl_unknown, (),
         "PoCL 3.0's clang refuses -target-cpu generic: every build fails (AMD family 26, "
         "Zen 5, 2026-12-04)"),
    Rule("pocl", "an AVX-512 host compiled for a target without AVX-512", _pocl_narrow_target_wide_host,
         (4, 1),
         "LLVM 14 calls Zen 4 znver3 but uses its AVX-512: 16 lanes gave 1.3 M wrong pixels "
         "with exit 0, 8 aborted (LLVM 'Cannot select'), 4 and 1 were right (2026-12-03)"),
    Rule("pocl", "an AVX-512 target on an AVX-512 host", _pocl_wide, (16, 8, 4, 1),
         "16 lanes fill a 512-bit register; right and fastest on Ice Lake (issue 4); right at "
         "16, 8, 4, 1 on Emerald Rapids (family 6 model 207, target icelake-client), 16 lanes "
         "1.01x 8 accurate, 1.57x fast (2026-12-06)"),
    Rule("pocl", "znver3 on an AVX2 host", _pocl_wide_avx2, (16, 8, 4, 1),
         "16 lanes (two 256-bit halves) right and 1.3x faster than 8 on Zen 3 (issue 4)"),
    Rule("pocl", "any other CPU target", _always, (8, 4, 1),
         "16 lanes once aborted PoCL 3.0 on a target without avx512f; 8 fill a 256-bit "
         "register"),
    Rule("intel-cpu", "any x86-64 host", _always, (16, 8, 4, 1),
         "Intel's CPU runtime dispatches on the host's own features: 1, 4 and 16 lanes "
         "bit-identical on Zen 4, 16 fastest (0.42-0.44 s against 0.71 at 4, 1080p x 256 "
         "lights); right at every width on Zen 5 (2026-12-04); on Emerald Rapids 16 lanes 1.20x 8 accurate, "
         "2.2x fast (2026-12-06); on Zen 3 (AVX2) 16 lanes 1.16x 8 accurate, 1.31x fast (2026-12-07)"),
    Rule("gpu", "a GPU or accelerator", _always, (1,),
         "its hardware runs work-items in SIMD already: one pixel a work-item"),
    Rule("other", "another CPU platform", _always, (8, 4, 1),
         "not measured: 8 lanes fill a 256-bit register, the width most CPUs have"),
)


@dataclass(frozen=True)
class Decision:
    """The widths allowed on one device, best first, and the rule that gave them."""

    widths: tuple[int, ...]
    rule: Rule

    @property
    def refused(self) -> bool:
        return not self.widths

    def why(self) -> str:
        return f"{self.rule.when}: {self.rule.reason}"


def decide(kind: str, target: str, h: Host | None = None) -> Decision:
    """The first rule of :data:`RULES` for this platform kind that applies."""
    h = host() if h is None else h
    for rule in RULES:
        if rule.platform == kind and rule.applies(target, h):
            return Decision(rule.widths, rule)
    return decide("other", target, h)


def table() -> list[tuple[str, str, str, str]]:
    """The rule as rows (platform, condition, widths, reason), for docs and `devices`."""
    return [(r.platform, r.when, ", ".join(map(str, r.widths)) or "refused", r.reason)
            for r in RULES]
