"""A lights file (``lights = "rig.csv"``) checked column by column, each row that fails
checked again as the [[light]] table it stands for."""

from __future__ import annotations

import math
import re
from typing import Any, NoReturn

import numpy as np

from ..core.errors import SceneError
from ..core.floats import FLT_MAX, U
from .light_table import VECTOR_COLUMNS, LightTable, column_of
from .scene_messages import (
    _g,
    _quoted_list,
)
from .scene_parser import (
    _Parser,
)
from .scene_types import (
    _LIGHT_FIELDS,
    _LIGHT_KEYS,
    _LIGHT_PLAIN,
    _NO_FALLOFF,
    _WHITE,
    INVERSE_SQUARE,
    POINT_TYPES,
    SPOT_INNER_DEFAULT,
    SPOT_OUTER_DEFAULT,
    WATTS_TO_RADIANCE,
    Light,
)

#: Light types a lights file's rows may have (an environment light needs a map file).
TABLE_TYPES: tuple[str, ...] = ("point", "spot", "directional", "ambient")
#: The key each column of a lights file gives.
_KEY_OF_COLUMN = {**{c: key for key, cols in VECTOR_COLUMNS.items() for c in cols},
                  **{c: c for c in ("type", "intensity", "power", "inner_angle", "outer_angle",
                                    "group")}}
_ROW_PATH = re.compile(r"light\[(\d+)\]\.?(.*)\Z", re.S)


def _unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(a, axis=0, return_inverse=True)`` of a (k, m) float array without
    NaN, at once where every row is the first (a rig's lights share one falloff)."""
    if (a == a[0]).all():
        return a[:1], np.zeros(len(a), np.intp)
    uniq, inv = np.unique(a, axis=0, return_inverse=True)
    return uniq, inv.reshape(-1)


class _TableParser(_Parser):
    """The rows of a lights file (:mod:`clphong.model.light_table`) checked as
    ``[[light]]`` tables are, vectorised: each check runs on whole columns, and a
    row that any check cannot clear is checked again by :meth:`_Parser.light`
    itself (as the table ``{"type": ..., "position": [x, y, z], ...}`` it stands for),
    which raises the message a ``[[light]]`` would get, naming the file, the row and
    the column (``light[i].color[1]`` -> ``<file>: row i: g``). Structural problems
    (a cell a row's type does not take, an empty cell it needs) have messages of
    their own. The first row with a problem is reported."""

    def __init__(self, parent: _Parser, table: LightTable):
        super().__init__(parent.source, parent.base_dir, parent.table_parser)
        self.table = table
        self.warnings = parent.warnings
        self._falloffs = parent._falloffs           # shared: the same polynomials

    def fail(self, path: str, problem: str) -> NoReturn:
        m = _ROW_PATH.match(path)
        if m is None:
            raise self.table.error(None, path, problem)
        raise self.table.error(int(m.group(1)), column_of(m.group(2)), problem)

    def warn(self, path: str, problem: str) -> None:
        m = _ROW_PATH.match(path)
        self.warnings.append(self.table.message(int(m.group(1)) if m else None,
                                                column_of(m.group(2)) if m else path, problem))

    def _clears(self, check, *args) -> bool:
        try:
            check(*args)
            return True
        except SceneError:
            return False

    def rows(self) -> tuple[Light, ...]:
        t, n = self.table, self.table.rows
        num, txt = t.numbers, t.text
        given = {c: ~np.isnan(a) for c, a in num.items()}
        none = np.zeros(n, bool)
        problems: list[tuple[np.ndarray, Any]] = []   # (rows, fn(row) -> raises), in check order

        # -- the type of each row
        if "type" in txt:
            index = {x: k for k, x in enumerate(TABLE_TYPES)}
            code = np.array([index.get(x, -1) for x in txt["type"].tolist()], np.int8).reshape(n)
            problems.append((code < 0, lambda r: self.type_problem(str(txt["type"][r]), r)))
        else:
            code = np.zeros(n, np.int8)                           # every row a point light
        is_t = {x: code == k for k, x in enumerate(TABLE_TYPES)}
        type_names = np.array(TABLE_TYPES + ("?",))

        def takes(key: str) -> np.ndarray:
            m = none.copy()
            for x in TABLE_TYPES:
                if key in _LIGHT_KEYS[x]:
                    m |= is_t[x]
            return m

        def ty(r: int) -> str:
            return str(type_names[code[r]])

        # -- structure: cells a type does not take, cells it needs, keys it needs
        pg = given.get("power", none)
        ig = given.get("intensity", none)
        point = is_t["point"] | is_t["spot"]
        for c in num:
            key = _KEY_OF_COLUMN[c]
            applies = takes(key)
            problems.append((given[c] & ~applies, lambda r, c=c, key=key: self.not_taken(r, c, key, ty(r))))
            if key == "power":
                problems.append((given[c] & ig, lambda r: self.fail(
                    f"light[{r}].power", "give power (watts, with Cycles' 1/d^2 falloff) or "
                                         "intensity, not both")))
                needed = applies & ~ig if "intensity" in num else applies
            elif key == "intensity":
                needed = applies & ~(point & pg) if "power" in num else applies
            elif key == "attenuation":
                problems.append((given[c] & pg, lambda r: self.fail(
                    f"light[{r}].power", "give power (watts, with Cycles' 1/d^2 falloff) or "
                                         "attenuation, not both")))
                needed = applies & ~pg
            else:
                needed = applies
            missing = needed & ~given[c]
            problems.append((missing, lambda r, c=c, key=key, m=missing:
                             self.empty(r, c, key, ty(r), int(m.sum()))))
        for key, types_ in (("position", point), ("direction", is_t["spot"] | is_t["directional"])):
            cols = VECTOR_COLUMNS[key]
            if cols[0] not in num:
                problems.append((types_, lambda r, key=key, cols=cols: self.table_fail(
                    r, ", ".join(cols), f"missing; a {ty(r)!r} light needs a {key}: give the "
                                        f"columns {', '.join(cols)}")))
        bad = none.copy()
        for rows, _ in problems:
            bad |= rows

        # -- values: every check _Parser.light makes, on whole columns; a row not
        #    cleared is checked again by _Parser.light itself (the exact check)
        def col(c: str, default: float) -> np.ndarray:
            return np.where(given[c], num[c], default) if c in num else np.full(n, default)

        ok = ~bad
        if "group" in txt:                  # each name once (a rig has a few)
            names = txt["group"].tolist()
            valid = {x: x == "" or self._clears(self.group, x, "light[0].group") for x in set(names)}
            ok &= np.array([valid[x] for x in names], bool).reshape(n)
        with np.errstate(over="ignore", invalid="ignore"):    # beyond float64: not cleared
            self.values(ok, col, given, is_t, point, pg)
        intensity = np.where(pg, col("power", 0.0) * WATTS_TO_RADIANCE, col("intensity", 1.0))

        # -- the first row with a problem raises; a row only not cleared is a light
        exact: dict[int, Light] = {}
        for r in np.flatnonzero(~ok).tolist():
            if bad[r]:
                for rows, raise_for in problems:
                    if rows[r]:
                        raise_for(r)
                raise AssertionError(f"row {r} flagged but no check raised")  # pragma: no cover
            exact[r] = _Parser.light(self, self.row(r, code), r)
        return self.build(code, intensity, exact)

    def values(self, ok, col, given, is_t, point, pg) -> None:
        """Clear, in ``ok``, the rows that pass every value check of _Parser.light
        (conservatively: a row not cleared is checked again by _Parser.light itself)."""
        num, none = self.table.numbers, np.zeros(self.table.rows, bool)
        r_, g_, b_ = col("r", 1.0), col("g", 1.0), col("b", 1.0)
        ok &= (r_ >= 0) & (g_ >= 0) & (b_ >= 0)
        power = col("power", 0.0)
        ok &= col("intensity", 0.0) >= 0
        ok &= power >= 0
        intensity = np.where(pg, power * WATTS_TO_RADIANCE, col("intensity", 1.0))
        radiance = np.maximum(np.maximum(r_, g_), b_) * intensity
        ok &= np.abs(radiance) <= FLT_MAX
        if "x" in num:
            x, y, z = col("x", 0.0), col("y", 0.0), col("z", 0.0)
            ok &= ~point | ((np.abs(x) <= FLT_MAX) & (np.abs(y) <= FLT_MAX) & (np.abs(z) <= FLT_MAX))
        with_dir = is_t["spot"] | is_t["directional"]
        if "dx" in num:
            dx, dy, dz = col("dx", 0.0), col("dy", 0.0), col("dz", 0.0)
            ok &= ~with_dir | (dx != 0) | (dy != 0) | (dz != 0)
        ag = given.get("c0", none) & point
        if ag.any():
            c = np.stack([num["c0"], num["c1"], num["c2"]], axis=1)
            ok &= ~ag | (np.abs(c) <= FLT_MAX).all(axis=1)         # each a float32, too
            falls = (c[:, 0] != 1) | (c[:, 1] != 0) | (c[:, 2] != 0)
            rows = np.flatnonzero(ag & falls & ok)
            if rows.size:
                uniq, inv = _unique_rows(c[rows])
                bound = np.empty(len(uniq))
                for k, att in enumerate(map(tuple, uniq.tolist())):
                    f = self._falloffs.get(att)
                    if f is None:
                        try:
                            f = self._falloffs[att] = self.falloff(att, "light[0].attenuation")
                        except SceneError:
                            f = math.nan                    # the row's own check says why
                    bound[k] = f
                peak = radiance[rows] * bound[inv.reshape(-1)] * (1 + U)
                ok[rows] &= np.abs(peak) <= FLT_MAX           # NaN: a polynomial not cleared
        spot = is_t["spot"]
        inner, outer = col("inner_angle", SPOT_INNER_DEFAULT), col("outer_angle", SPOT_OUTER_DEFAULT)
        rows = np.flatnonzero(spot & ok)
        if rows.size:
            uniq, inv = _unique_rows(np.stack([inner[rows], outer[rows]], axis=1))
            cok = np.array([self._clears(self.cone, {"direction": [0.0, 0.0, 1.0],
                                                     "inner_angle": a, "outer_angle": b},
                                         "light[0]") for a, b in uniq.tolist()], bool)
            ok[rows] &= cok[inv.reshape(-1)]

    # -- messages of the structural checks

    def table_fail(self, r: int, column: str, problem: str) -> NoReturn:
        raise self.table.error(r, column, problem)

    def type_problem(self, value: str, r: int) -> NoReturn:
        if value == "":
            self.table_fail(r, "type", f"empty; one of {_quoted_list(TABLE_TYPES)}")
        if value == "environment":
            self.table_fail(r, "type", "an 'environment' light needs a map file: give it as a "
                                       "[[light]] table in the scene")
        self.enum(value, f"light[{r}].type", TABLE_TYPES)
        raise AssertionError(value)  # pragma: no cover

    def not_taken(self, r: int, c: str, key: str, type_: str) -> NoReturn:
        owners = [x for x in TABLE_TYPES if key in _LIGHT_KEYS[x]]
        an = "an" if type_[0] in "aeiou" else "a"
        self.table_fail(r, c, f"{_g(float(self.table.numbers[c][r]))} but {an} {type_!r} light "
                              f"takes no {key} (only {' and '.join(map(repr, owners))} lights "
                              "do); leave the cell empty" +
                        (" (NaN in .npz)" if self.table.lines is None else ""))

    def empty(self, r: int, c: str, key: str, type_: str, count: int) -> NoReturn:
        an = "an" if type_[0] in "aeiou" else "a"
        if key in ("intensity", "power") and type_ in POINT_TYPES:
            need = "gives intensity or power"
        else:
            need = f"takes {key} and the file has the column"
        what = "empty" if self.table.lines is not None else "NaN (an empty cell)"
        self.table_fail(r, c, f"{what}; {an} {type_!r} light {need} ({count} such cell(s) in "
                              f"column {c})")

    # -- the lights

    def row(self, r: int, code: np.ndarray) -> dict:
        """Row ``r`` as the ``[[light]]`` table it stands for (its cells that are there)."""
        t = self.table
        d: dict[str, Any] = {"type": TABLE_TYPES[code[r]]}
        for key, cols in VECTOR_COLUMNS.items():
            if cols[0] in t.numbers and not math.isnan(t.numbers[cols[0]][r]):
                d[key] = [float(t.numbers[c][r]) for c in cols]
        for c in ("intensity", "power", "inner_angle", "outer_angle"):
            if c in t.numbers and not math.isnan(t.numbers[c][r]):
                d[c] = float(t.numbers[c][r])
        if "group" in t.text and t.text["group"][r]:
            d["group"] = str(t.text["group"][r])
        return d

    def build(self, code: np.ndarray, intensity: np.ndarray, exact: dict[int, Light]) -> tuple[Light, ...]:
        """The Light of each row that every check cleared (and ``exact``'s own), made
        as :func:`new_light` makes them: a tight loop over the columns as lists."""
        t, n = self.table, self.table.rows
        num = t.numbers

        def vectors(key, default):
            c = VECTOR_COLUMNS[key]
            if c[0] not in num:
                return [default] * n
            return [None if v[0] != v[0] else v for v in zip(*(num[x].tolist() for x in c))]

        def scalars(c, default):
            if c not in num:
                return [default] * n
            return [default if v != v else v for v in num[c].tolist()]

        colors = vectors("color", _WHITE)
        pos, dirs, atts = vectors("position", None), vectors("direction", None), vectors("attenuation", None)
        powers = scalars("power", None)
        inner = scalars("inner_angle", SPOT_INNER_DEFAULT)
        outer = scalars("outer_angle", SPOT_OUTER_DEFAULT)
        groups = [g or None for g in t.text["group"].tolist()] if "group" in t.text else [None] * n
        proto = _LIGHT_FIELDS.copy()
        unit, new, set_dict, plain = self.unit, object.__new__, object.__setattr__, _LIGHT_PLAIN
        out = []
        for r, k, c, i, g, p, w, a in zip(range(n), code.tolist(), colors, intensity.tolist(),
                                          groups, pos, powers, atts):
            lt = exact.get(r) if exact else None
            if lt is None:
                d = proto.copy()
                d["type"], d["color"], d["intensity"], d["group"] = TABLE_TYPES[k], c, i, g
                if k <= 1:                                          # point, spot
                    d["position"], d["power"] = p, w
                    d["attenuation"] = a if a is not None else \
                        INVERSE_SQUARE if w is not None else _NO_FALLOFF
                    if k == 1:
                        d["direction"] = unit(list(dirs[r]), f"light[{r}].direction")
                        d["inner_angle"], d["outer_angle"] = inner[r], outer[r]
                elif k == 2:                                        # directional
                    d["direction"] = unit(list(dirs[r]), f"light[{r}].direction")
                if plain:
                    lt = new(Light)
                    set_dict(lt, "__dict__", d)
                else:                                               # pragma: no cover
                    lt = Light(**d)
            out.append(lt)
        return tuple(out)
