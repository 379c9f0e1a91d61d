"""Every user option that takes one of a fixed set of values: one registry each, one validator.

Each registry is a mapping from the valid names to what they stand for; the
command line builds its ``choices=`` from the same registries, and
:func:`validate_method` (after colour-science's ``colour.utilities.validate_method``)
is the one check of a name: a bad one is a ``ValueError`` listing the valid
ones. Numeric options with a range (exposure) have one checker each here too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from ..core.errors import ClphongError, ToneMapError, abbreviate

__all__ = ["validate_method", "PATHS", "path_options", "NONFINITE_POLICIES", "check_nonfinite",
           "KERNELS", "check_kernel", "LANES", "check_lanes", "UNROLLS", "check_unroll",
           "INT_POW", "check_int_pow",
           "check_fp64_directions", "check_float_power",
           "MAX_EXPOSURE", "check_exposure", "ENCODINGS", "CullingError", "check_budget",
           "NUMBERS", "check_number", "RendererOptions", "finished", "DEFAULT_ENV_ERROR",
           "check_env_error", "ENV_PROBES", "ENV_PATHS"]


def validate_method(value, methods, what: str, error: type[Exception] = ValueError):
    """``value`` if it is one of ``methods`` (a mapping's keys or a sequence), else ``error``.

    The message names the option and lists the valid values:
    ``nonfinite must be one of background, error, pass, not 'x'``.
    """
    valid = tuple(methods)
    if any(value == v and type(value) is type(v) for v in valid):   # True is not 1
        return value
    raise error(f"{what} must be one of {', '.join(str(v) for v in valid)}, not {value!r}")


#: The shading paths a user picks (``--path``, ``Renderer(path=...)``) and the
#: Renderer options each stands for (docs/error-model.md, docs/bench.md):
#: ``accurate`` (default: double directions, weights and sums where the device
#: has fp64), ``float`` (float32 directions), ``fast`` (float32 throughout:
#: directions, the integer power and a naive light sum).
PATHS: Mapping[str, Mapping] = {
    "accurate": {},
    "float": {"fp64_directions": False},
    "fast": {"fp64_directions": False, "compensated": False, "int_pow": "float"},
}


def path_options(path: str) -> dict:
    """The Renderer options of a shading path (``PATHS``); a bad name lists the valid ones."""
    return dict(PATHS[validate_method(path, PATHS, "path")])


#: The default relative error of an environment light (``--env-error``;
#: clphong.model.environment says how it is measured).
DEFAULT_ENV_ERROR = 1e-3


#: Where an environment's error is estimated (``--env-probes``; RendererOptions.env_probes).
ENV_PROBES = {"frame": "on each frame's own pixels (its normals and views)",
              "all": "on every normal and view (one conversion serves any frame)"}


#: How an environment is shaded (``--env-path``; RendererOptions.env_path).
ENV_PATHS = {"auto": "from tables (irradiance and the Phong lobe, the sun as lights) where their "
                     "bound holds on the frame's pixels, else as directional lights",
             "lights": "as directional lights always"}


def check_env_error(value) -> float:
    """``value`` as a float if it is a finite number > 0, else a ValueError saying so."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"the environment error must be a number > 0, not {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise ValueError(f"the environment error must be a finite number > 0, not {value!r}")
    return x


#: What happens to NaN/Inf G-buffer values (``--nonfinite``; clphong.io.nonfinite).
NONFINITE_POLICIES: Mapping[str, str] = {
    "background": "the pixel is not shaded and takes the background value (a warning gives the counts)",
    "error": "the frame is refused, naming each buffer and its count",
    "pass": "the values go to the kernels as they are",
}


def check_nonfinite(policy: str) -> str:
    return validate_method(policy, NONFINITE_POLICIES, "nonfinite")


#: The shading kernels (``--kernel``): the SIMD-lane kernel, or the
#: one-pixel-per-work-item baseline (float32 with pow()).
KERNELS: Mapping[str, str] = {"lanes": "shade.cl", "obvious": "shade_obvious.cl"}


def check_kernel(kernel: str) -> str:
    return validate_method(kernel, KERNELS, "kernel")


#: Pixels per work-item of the lane kernel (``--lanes``).
LANES = (1, 4, 8, 16)


def check_lanes(lanes: int) -> int:
    return validate_method(lanes, LANES, "lanes")


#: Lights an iteration of the lane kernel's light loops (``Renderer(light_unroll=)``,
#: the plan's LIGHT_UNROLL; 0: one).
UNROLLS = (0, 2, 4, 8)


def check_unroll(unroll: int) -> int:
    return validate_method(unroll, UNROLLS, "light_unroll")


#: The specular power: True, binary powering of a whole exponent in double;
#: False, always exp(k·log1p(−δ)); "float", binary powering in float (the fast path).
INT_POW = (True, False, "float")


def check_int_pow(int_pow):
    if isinstance(int_pow, bool) or int_pow == "float":
        return int_pow
    raise ValueError(f"int_pow must be True, False or 'float', not {int_pow!r}")


def check_fp64_directions(fp64_directions):
    """``fp64_directions``: None (the device decides), True or False."""
    if fp64_directions is None or isinstance(fp64_directions, bool):
        return fp64_directions
    raise ValueError(f"fp64_directions must be None, True or False, not {fp64_directions!r}")


def check_float_power(int_pow, fp64_directions):
    """The power in float (``int_pow="float"``, the fast path) takes float directions."""
    if int_pow == "float" and fp64_directions:
        raise ValueError("int_pow='float' is for float directions (fp64_directions=False)")


#: DISPLAY_ENCODING values: display-linear Rec.709, or sRGB (IEC 61966-2-1) encoded.
ENCODINGS: Mapping[str, int] = {"linear": 0, "srgb": 1}

#: Largest |exposure| in stops, for every display output and the scene key
#: ``render.exposure`` alike: 2^±100 (1.3e30, 7.9e-31) and a pixel times it stay
#: normal float32 numbers.
MAX_EXPOSURE = 100.0


def check_exposure(ev, what: str = "exposure") -> float:
    """``ev`` as a float if it is a finite number of stops within ±:data:`MAX_EXPOSURE`.

    Raises
    ------
    ToneMapError
        One line naming ``what`` (e.g. ``--exposure``).
    """
    ev = float(ev)
    if not math.isfinite(ev):
        problem = f"must be a finite number of stops, got {ev!r}"
    elif abs(ev) > MAX_EXPOSURE:
        problem = (f"{ev:g} stops is out of range (2^EV must stay a float32); "
                   f"use -{MAX_EXPOSURE:g}..{MAX_EXPOSURE:g}")
    else:
        return ev
    error = ToneMapError(f"{what} {problem}")
    error.problem = problem           # without the subject, for messages that name it first
    raise error


#: Numeric options with a range: the lowest value and whether it is allowed. One entry,
#: one range, one message (:func:`check_number`), whichever door the value comes in by.
NUMBERS: Mapping[str, tuple[float, bool]] = {
    "--max-error": (0.0, True),          # 0: drop only lights whose bound is exactly 0
    "--reference-white": (0.0, False),   # divides the budget's units
    "--floor": (0.0, False),             # diff's max-rel denominator: inf made any image match
    "--peak": (0.0, False),              # diff's psnr peak: inf made any image match
    "--scheduler-timeout": (0.0, False),  # seconds: a silent peer held relight forever
}


def check_number(x, name: str, error: type[Exception] = ValueError) -> float:
    """``x`` as a float if it is a finite number in :data:`NUMBERS`' range for ``name``;
    else ``error``: ``--floor: expected a finite number > 0, got inf``."""
    low, inclusive = NUMBERS[name]
    ok = (isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
          and (x >= low if inclusive else x > low))
    if not ok:
        raise error(f"{name}: expected a finite number {'≥' if inclusive else '>'} {low:g}, got {x!r}")
    return float(x)


class CullingError(ClphongError):
    """The culling options are invalid (e.g. a negative ``--max-error``)."""


def check_budget(max_error, reference_white=1.0) -> float | None:
    """The absolute budget ``max_error·reference_white``, validated; None: no culling.

    ``reference_white`` is checked even without a budget, so a bad value fails
    the same way whether or not culling is on.
    """
    if max_error is not None:
        check_number(max_error, "--max-error", CullingError)
    check_number(reference_white, "--reference-white", CullingError)
    if max_error is None:
        return None
    return float(max_error) * float(reference_white)


def check_relative(relative, max_error) -> bool:
    """``--relative``: a bool, and only with a ``--max-error`` budget to make relative."""
    if not isinstance(relative, bool):
        raise CullingError(f"--relative: expected true or false, got {abbreviate(repr(relative))}")
    if relative and max_error is None:
        raise CullingError("--relative needs a --max-error budget (a fraction of each pixel's "
                           "own value, e.g. --max-error 1e-2 --relative)")
    return bool(relative)


def finished(cls, **values):
    """An instance of the frozen dataclass ``cls`` from values checked already (by an
    instance of it, or of the options they came from), without its ``__post_init__``:
    how a checked value is handed down, so that nothing below checks it again. Every
    field must be given."""
    missing = set(cls.__dataclass_fields__) - set(values)
    extra = set(values) - set(cls.__dataclass_fields__)
    if missing or extra:
        raise TypeError(f"{cls.__name__}: finished() takes every field and only those; "
                        f"missing {', '.join(sorted(missing)) or 'none'}, "
                        f"not fields {', '.join(sorted(extra)) or 'none'}")
    obj = object.__new__(cls)
    for k, v in values.items():
        object.__setattr__(obj, k, v)
    return obj


@dataclass(frozen=True)
class RendererOptions:
    """The renderer options of one command or one :class:`~clphong.pipeline.relighter.Relighter`,
    checked once, where they come in (the command line, a TOML rig, the Python API), then
    handed down finished: the Relighter, its RelighterSpec and the Renderer take them as
    they are and check nothing again.

    Attributes
    ----------
    fp64_directions : bool, optional
        None: the device decides; not with ``path``.
    max_error : float, optional
        The culling budget in units of ``reference_white`` (≥ 0; None: brute force), or
        with ``relative`` a fraction of each pixel's own value.
    reference_white : float
        > 0.
    relative : bool
        ``max_error`` is relative: every pixel's culling error is within ``max_error``
        of the pixel's own value, per channel (``--relative``); needs ``max_error``.
    nonfinite : str
        :data:`NONFINITE_POLICIES`.
    path : str, optional
        :data:`PATHS` (None: the default, accurate).
    aovs : tuple of str
        Component layers (checked against the scene by the renderer).
    env_error : float
        The environment lights' error target (> 0).
    env_probes : str
        :data:`ENV_PROBES`: where that error is estimated. ``"frame"`` (default): on
        each frame's own pixels, so each frame gets the lights it needs (its own
        conversion, cached by its probes); ``"all"``: on every normal and view, one
        conversion for any frame.
    env_path : str
        :data:`ENV_PATHS`: ``"auto"`` (default) shades an environment from tables where
        they hold ``env_error`` on the frame (``env_probes="frame"``, the lane kernel),
        ``"lights"`` always from directional lights.
    light_tree : bool or "always"

    Raises
    ------
    CullingError
        A negative or non-finite ``max_error``, or a ``reference_white`` that is not a
        finite number > 0.
    ValueError
        An unknown ``nonfinite`` policy or ``path``, ``fp64_directions`` not None/bool,
        both ``path`` and ``fp64_directions``, an ``env_error`` that is not a finite
        number > 0, or an unknown ``env_probes`` or ``env_path``.
    """

    fp64_directions: bool | None = None
    max_error: float | None = None
    reference_white: float = 1.0
    nonfinite: str = "background"
    path: str | None = None
    aovs: tuple = ()
    env_error: float = DEFAULT_ENV_ERROR
    light_tree: bool | str = True
    relative: bool = False
    env_probes: str = "frame"
    env_path: str = "auto"

    def __post_init__(self):
        check_fp64_directions(self.fp64_directions)
        if self.path is not None:
            validate_method(self.path, PATHS, "path")
            if self.fp64_directions is not None:
                raise ValueError("give either path or fp64_directions")
        check_budget(self.max_error, self.reference_white)
        check_relative(self.relative, self.max_error)
        check_nonfinite(self.nonfinite)
        object.__setattr__(self, "env_error", check_env_error(self.env_error))
        validate_method(self.env_probes, ENV_PROBES, "env_probes")
        validate_method(self.env_path, ENV_PATHS, "env_path")
        aovs = self.aovs
        if isinstance(aovs, str):         # "diffuse,specular", as --aov and the scene key
            aovs = tuple(a.strip() for a in aovs.split(",") if a.strip())
        object.__setattr__(self, "aovs", tuple(aovs))

    @property
    def budget(self) -> float | None:
        """The culling budget: absolute, ``max_error·reference_white``, or with ``relative``
        the fraction ``max_error`` (None: no culling)."""
        if self.max_error is None:
            return None
        return float(self.max_error) * (1.0 if self.relative else float(self.reference_white))

    @property
    def path_options(self) -> dict:
        """The Renderer options ``path`` stands for (:data:`PATHS`; {} without one)."""
        return dict(PATHS[self.path]) if self.path is not None else {}

    def kwargs(self) -> dict:
        """The renderer options as keyword arguments (of Relighter; a subclass's own
        fields, RelighterSpec's, are not among them)."""
        return {k: getattr(self, k) for k in RendererOptions.__dataclass_fields__}
