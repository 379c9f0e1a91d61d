"""The trip of one command's arguments through the package (issue 26): which rooms they enter.

``python tests/option_trip.py [--show] [RENDER-ARGS...]``

Runs ``clphong render`` on the shipped samples in-process, with options given
values that occur nowhere else (an exposure of 0.3712, a budget of 0.00123, ...),
under :func:`sys.setprofile`. A call is on the trip when one of its arguments
is one of those values, or a container or object holding one (one level deep:
``OutputOptions.exposure``, a ``dict`` of Renderer keyword arguments). For the
calls on the trip, in order, it counts:

* **rooms**: the distinct modules of ``clphong`` entered;
* **climbs**: returns from a function on the trip to a caller in a module of a
  higher layer (docs/architecture.md's floors: core < model < … < console), that
  is, a check done below and handed back up;
* **returns**: entries into a module the trip had entered and left before.

The floors and the modules are those of ``tests/test_architecture.py``. Not a
test itself: a measure to report (docs/architecture.md, "One option's trip"); tests/test_option_trip.py
holds the checks to once each.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from dataclasses import dataclass, field, fields, is_dataclass

from clphong.console import cli

#: Layers, lowest first (tests/test_architecture.py).
LAYERS = ("core", "model", "io", "color", "reference", "device", "deliver", "pipeline", "tools",
          "console")

#: The render options the trip follows, each with a value found nowhere else.
TRACED = {"--exposure": "0.3712", "--max-error": "0.00123", "--env-error": "0.00456",
          "--tonemap": "hable", "--path": "fast", "--nonfinite": "error", "--exr-type": "half",
          "--exr-compression": "piz", "--white": "7.125"}


def _values(args: dict) -> set:
    out = set()
    for k, v in args.items():
        for x in (v,):
            try:
                out.add(float(x))
            except ValueError:
                out.add(x)
    return out


def _floor(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def _holds(value, wanted: set, depth: int = 1) -> bool:
    try:
        if isinstance(value, (str, int, float)) and not isinstance(value, bool):
            return value in wanted
    except TypeError:
        return False
    if depth <= 0:
        return False
    if isinstance(value, dict):
        return any(_holds(v, wanted, depth - 1) for v in value.values())
    if isinstance(value, (list, tuple)):
        return any(_holds(v, wanted, depth - 1) for v in value[:16])
    if is_dataclass(value) and not isinstance(value, type):
        return any(_holds(getattr(value, f.name, None), wanted, depth - 1) for f in fields(value))
    if hasattr(value, "__dict__") and type(value).__module__ == "argparse":
        return any(_holds(v, wanted, depth - 1) for v in vars(value).values())
    return False


@dataclass
class Trip:
    """The calls on the trip, in order: (module, function) of each."""

    calls: list = field(default_factory=list)
    climbs: list = field(default_factory=list)

    @property
    def rooms(self) -> list[str]:
        seen = []
        for m, _ in self.calls:
            if m not in seen:
                seen.append(m)
        return seen

    @property
    def returns(self) -> int:
        """Entries into a module entered and left before."""
        left, last, n = set(), None, 0
        for m, _ in self.calls:
            if m != last:
                if m in left:
                    n += 1
                if last is not None:
                    left.add(last)
                last = m
        return n


def trace(argv: list[str], only: str | None = None) -> tuple[int, Trip]:
    """Run ``clphong render`` with ``argv`` under the profiler: (exit code, the trip of
    every traced option's value, or of option ``only``'s alone)."""
    wanted = set()
    for opt, val in TRACED.items():
        if opt in argv and (only is None or opt == only):
            v = argv[argv.index(opt) + 1]
            wanted.add(v)
            try:
                wanted.add(float(v))
            except ValueError:
                pass
    trip = Trip()
    on_trip: dict[int, str] = {}              # frame id -> module of a call on the trip

    def hook(frame, event, arg):
        if event not in ("call", "return"):
            return
        mod = frame.f_globals.get("__name__", "")
        if not mod.startswith("clphong."):
            return
        if event == "call":
            code = frame.f_code
            names = code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]
            if any(_holds(frame.f_locals.get(n), wanted) for n in names):
                on_trip[id(frame)] = mod
                trip.calls.append((mod, code.co_qualname))
        elif id(frame) in on_trip:
            callee = on_trip.pop(id(frame))
            caller = frame.f_back
            cmod = caller.f_globals.get("__name__", "") if caller is not None else ""
            a, b = _floor(callee), _floor(cmod)
            if a is not None and b is not None and b > a:
                trip.climbs.append((callee, frame.f_code.co_qualname, cmod))

    sys.setprofile(hook)
    try:
        rc = cli.main(argv)
    finally:
        sys.setprofile(None)
    return rc, trip


def default_argv(out_dir: str) -> list[str]:
    """``clphong render`` on the spheres sample with every traced option set."""
    samples = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "gbuffers")
    argv = ["render", os.path.join(samples, "spheres.toml"), os.path.join(samples, "spheres.exr"),
            "-o", os.path.join(out_dir, "trip.exr"), "--sdr", os.path.join(out_dir, "trip.png")]
    for opt, val in TRACED.items():
        argv += [opt, val]
    return argv


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python tests/option_trip.py",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--show", action="store_true", help="list every call on the trip")
    p.add_argument("render_args", nargs="*", help="clphong render's arguments (default: the "
                   "spheres sample with every traced option)")
    a = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        rc, trip = trace(a.render_args or default_argv(tmp))
    if a.show:
        for m, f in trip.calls:
            print(f"  {m}.{f}")
        for callee, f, caller in trip.climbs:
            print(f"  climb: {callee}.{f} -> {caller}")
    print(f"exit {rc}; {len(trip.rooms)} rooms, {len(trip.climbs)} climbs back up, "
          f"{trip.returns} returns to a room already left, {len(trip.calls)} calls")
    print("rooms: " + ", ".join(r.removeprefix("clphong.") for r in trip.rooms))
    if not a.render_args:
        print("each option alone:")
        with tempfile.TemporaryDirectory() as tmp:
            argv = default_argv(tmp)
            for opt in TRACED:
                _, one = trace(argv, only=opt)
                print(f"  {opt:18} {len(one.rooms)} rooms, {len(one.climbs):2} climbs: "
                      + ", ".join(r.removeprefix("clphong.") for r in one.rooms))
    return 0


if __name__ == "__main__":
    sys.exit(main())
