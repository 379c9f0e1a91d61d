"""Tone-mapping operators: the registry, each operator's parameters and their validation.

The kernels (``kernels/include/tonemap.h``) select an operator by its ID; the
float64 twins and the error model are :mod:`clphong.reference.tonemap`. A bad
name is a :class:`~clphong.core.errors.ToneMapError` listing the valid ones
(:func:`operator`), as colour-science's ``validate_method`` does.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import ToneMapError
from ..core.floats import FLT_MAX

#: Hable's (Uncharted 2) filmic curve: its constants, the exposure bias applied
#: before it and the default linear white point W (Hable 2010).
HABLE_A, HABLE_B, HABLE_C, HABLE_D, HABLE_E, HABLE_F = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
HABLE_EXPOSURE_BIAS = 2.0
HABLE_W = 11.2


@dataclass(frozen=True)
class Operator:
    """A tone-mapping operator: its kernel ID, white-point use and source."""

    name: str
    id: int
    source: str
    default_white: float | None = None

    @property
    def uses_white(self) -> bool:
        return self.default_white is not None


#: Reinhard's eq. 4 maps L_white to 1; the paper sets it to the scene's largest
#: luminance. clphong's default: 4 (two stops above 1).
REINHARD_DEFAULT_WHITE = 4.0

OPERATORS: dict[str, Operator] = {op.name: op for op in (
    Operator("none", 0, "clip to [0, 1]"),
    Operator("reinhard", 1, "Reinhard et al. 2002, eq. 3"),
    Operator("reinhard-extended", 2, "Reinhard et al. 2002, eq. 4 (white point)", REINHARD_DEFAULT_WHITE),
    Operator("hable", 3, "Hable 2010, Uncharted 2 filmic (white point W)",
             HABLE_W),
    Operator("aces-hill", 4, "Stephen Hill's ACES fit (BakingLab)"),
    Operator("agx", 5, "Wrensch's minimal AgX fit"),
    Operator("pbr-neutral", 6, "Khronos PBR Neutral"),
)}

#: Other names users type for the same operators.
ALIASES = {"clip": "none", "uncharted2": "hable", "filmic-hable": "hable", "aces": "aces-hill",
           "khronos-pbr-neutral": "pbr-neutral", "neutral": "pbr-neutral"}


def operator_names() -> tuple[str, ...]:
    return tuple(OPERATORS)


def operator(name: str) -> Operator:
    """The operator called ``name`` (or an alias); a bad name lists the valid ones.

    Raises
    ------
    ToneMapError
        ``unknown tone-mapping operator 'x'; valid: 'none', 'reinhard', ...``
    """
    if isinstance(name, str):
        key = name.strip().lower().replace("_", "-")
        key = ALIASES.get(key, key)
        if key in OPERATORS:
            return OPERATORS[key]
    valid = ", ".join(repr(n) for n in OPERATORS)
    close = difflib.get_close_matches(str(name).lower(), list(OPERATORS) + list(ALIASES), n=1)
    hint = f"; did you mean {ALIASES.get(close[0], close[0])!r}?" if close else ""
    raise ToneMapError(f"unknown tone-mapping operator {name!r}; valid: {valid}{hint}")


def operator_params(name: str, white: float | None = None) -> np.ndarray:
    """The kernel's ``tonemap_params`` (float64, x used): 1/L_white² or 1/f(W).

    Raises
    ------
    ToneMapError
        If ``white`` is not a finite number > 0 (Hable: > 0 and f(W) > 0).
    """
    op = operator(name)
    p = np.zeros(4)
    if not op.uses_white:
        return p
    w = op.default_white if white is None else float(white)

    def refuse(problem: str):
        error = ToneMapError(f"white point of {op.name!r} {problem}")
        error.problem = f"{problem} for {op.name!r}"   # without the subject, for messages naming it
        raise error

    if not (math.isfinite(w) and w > 0):
        refuse(f"must be a finite number > 0, got {w!r}")
    if op.name == "reinhard-extended":
        ww = w * w
        # the kernel takes 1/W² as a float32: W below ~5.4e-20 overflows it (1e-300: 1/0)
        if not ww > 0 or 1.0 / ww > FLT_MAX:
            refuse(f"must be at least {1 / math.sqrt(FLT_MAX):.3g} (1/W² a float32), got {w!r}")
        p[0] = 1.0 / ww
    else:
        fw = hable_exact(w)
        if not fw > 0:
            refuse(f"must map above 0, got W = {w!r}")
        if 1.0 / fw > FLT_MAX:
            refuse(f"maps too close to 0 (1/f(W) must be a float32), got W = {w!r}")
        p[0] = 1.0 / fw
    return p


def hable_exact(x: float) -> float:
    A, B, C, D, E, F = HABLE_A, HABLE_B, HABLE_C, HABLE_D, HABLE_E, HABLE_F
    return (x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F) - E / F
