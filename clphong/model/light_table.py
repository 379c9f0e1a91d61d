"""Lights files: many lights as columns, read from CSV or ``.npz``.

A scene's top-level ``lights = "rig.csv"`` (or ``"rig.npz"``; a relative path
starts at the scene file's folder) adds one light per row of that file after
the scene's ``[[light]]`` tables. This module reads the file into columns and
checks what is the file's own business (its format, its header, each cell's
syntax, NaN and Inf); :mod:`clphong.model.scene` checks the rows as it checks
``[[light]]`` tables, with the same messages (``_Parser.light_table``).

Columns (all optional; a column left out gives its key's default, or is a
missing key for the rows whose type needs it)::

    type                  point (the default without the column), spot, directional, ambient
    x, y, z               position (point, spot)
    dx, dy, dz            direction (spot: the axis; directional: the way the light travels)
    r, g, b               color (default white)
    intensity             (default 1)
    power                 watts, instead of intensity and c0, c1, c2 (point, spot)
    c0, c1, c2            attenuation 1/(c0 + c1*d + c2*d^2) (point, spot; default 1, 0, 0)
    inner_angle, outer_angle   a spot's half-angles in degrees (default 0 and 45)
    group                 light-group name (default none)

* **CSV**: UTF-8, a header row of column names, then one row per light;
  ``,``-separated, quotes as the csv module reads them, spaces after a comma
  ignored; blank lines and lines starting with ``#`` are skipped. An empty cell
  is "not given". Numbers as Python's ``float()`` reads them; ``nan`` and
  ``inf`` are refused (with their count), as in a scene file.
* **.npz** (``numpy.savez``): one 1-D array per column, all of the same length;
  numbers as float or integer arrays (not bool), ``type`` and ``group`` as str
  arrays. NaN is the empty cell; ``±inf`` is refused (with its count). Read with
  ``allow_pickle=False``: an object array is refused.

A column that is there gives its key to every row whose type takes the key:
those cells must not be empty (but a point or spot row gives ``intensity`` or
``power``, and then no ``c0, c1, c2``), and the cells of rows whose type does not
take it must be (``dx`` of a point light). ``group`` may be empty in any row.
Environment lights need a map file each: give them as ``[[light]]`` tables.

Rows are numbered from 0 (as array indices, and as ``light[i]`` in a scene's
messages); a CSV message adds the file's line. For example::

    rig.csv: row 1234 (line 1236): intensity: must be >= 0, got -1.0
    rig.npz: row 7: c0, c1, c2: p(d) = c0 + c1*d reaches 0 at d = 2.5 ...
"""

from __future__ import annotations

import csv
import difflib
import io
import math
import os
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from ..core.errors import SceneError
from ..core.files import image_kind, open_regular
from ..core.memory import format_size, require_memory

__all__ = ["COLUMNS", "NUMBER_COLUMNS", "TEXT_COLUMNS", "VECTOR_COLUMNS", "LightTable",
           "read_light_table", "column_of", "LIGHTS_FILE_SUFFIXES", "light_columns",
           "write_light_table"]

#: The columns of each 3-vector key, in order.
VECTOR_COLUMNS: Mapping[str, tuple[str, str, str]] = MappingProxyType({
    "position": ("x", "y", "z"), "direction": ("dx", "dy", "dz"), "color": ("r", "g", "b"),
    "attenuation": ("c0", "c1", "c2")})
#: Text columns.
TEXT_COLUMNS: tuple[str, ...] = ("type", "group")
#: Every column a lights file may have, in the order messages and checks take them.
COLUMNS: tuple[str, ...] = ("type", "x", "y", "z", "dx", "dy", "dz", "r", "g", "b", "intensity",
                            "power", "c0", "c1", "c2", "inner_angle", "outer_angle", "group")
NUMBER_COLUMNS: tuple[str, ...] = tuple(c for c in COLUMNS if c not in TEXT_COLUMNS)
#: The file name endings read, and their formats.
LIGHTS_FILE_SUFFIXES: tuple[str, ...] = (".csv", ".npz")

#: Peak bytes of memory a lights file needs: ROW_BYTES a row (its Light, its
#: share of the scene's light arrays and, while it is read, its cells) and
#: CSV_BYTES_PER_BYTE a byte of CSV (its text, decoded, and the csv module's
#: strings), upper bounds from tracemalloc over 65 536-row files: 0.9-1.7 KiB a
#: row (1.1 KiB kept), and 11 bytes a byte of the bench rig's CSV beyond that.
ROW_BYTES = 2048
CSV_BYTES_PER_BYTE = 16
#: The longest text cell read (a type or group name is at most 63 characters):
#: numpy's str arrays give every cell the longest one's room.
TEXT_CELL_MAX = 256


def column_of(key_path: str) -> str:
    """The column(s) a light's key path names: ``"color[1]"`` -> ``"g"``,
    ``"position"`` -> ``"x, y, z"``, ``"intensity"`` -> ``"intensity"``."""
    key, _, rest = key_path.partition("[")
    cols = VECTOR_COLUMNS.get(key)
    if cols is None:
        return key_path
    if rest[:1].isdigit() and rest.endswith("]") and int(rest[:-1]) < 3:
        return cols[int(rest[:-1])]
    return ", ".join(cols)


def _one_line(text: str) -> str:
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)


def _short(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


@dataclass(frozen=True)
class LightTable:
    """A lights file's columns, as read (before the rows are checked as lights).

    Attributes
    ----------
    path : str
        The file, as messages name it.
    rows : int
        Number of rows (lights).
    numbers : Mapping of str to ndarray
        The number columns there are, float64 (rows,), NaN where a cell is empty.
    text : Mapping of str to ndarray
        The text columns there are, str (rows,), ``""`` where a cell is empty.
    lines : ndarray or None
        A CSV's line of each row (1-based); None for ``.npz``.
    """

    path: str
    rows: int
    numbers: Mapping[str, np.ndarray]
    text: Mapping[str, np.ndarray]
    lines: np.ndarray | None = None

    def where(self, row: int) -> str:
        """``"row 12"``, or ``"row 12 (line 14)"`` in a CSV."""
        return f"row {row}" if self.lines is None else f"row {row} (line {int(self.lines[row])})"

    def message(self, row: int | None, column: str, problem: str) -> str:
        """``"<path>: row <i>: <column>: <problem>"`` on one line."""
        parts = [self.path] + ([self.where(row)] if row is not None else []) + \
            ([column] if column else []) + [problem]
        return _one_line(": ".join(parts))

    def error(self, row: int | None, column: str, problem: str) -> SceneError:
        return SceneError(self.message(row, column, problem))

    def has(self, column: str) -> bool:
        return column in self.numbers or column in self.text


def read_light_table(path: str, referrer: str = "") -> LightTable:
    """Read a lights file (``.csv`` or ``.npz``, by its name) into columns.

    Parameters
    ----------
    path : str
        The file (already resolved against the scene's folder); messages name it so.
    referrer : str, optional
        What names the file, for the messages about opening it
        (``"scene.toml: lights"``).

    Raises
    ------
    SceneError
        If it cannot be read, is not a regular file, would not fit in memory, is
        not of its format, has an unknown, duplicate or incomplete column, a
        cell that is not a number, or NaN/Inf cells (with their count).
    """
    suffix = os.path.splitext(path)[1].lower()
    head = f"{referrer}: " if referrer else ""
    if suffix not in LIGHTS_FILE_SUFFIXES:
        raise SceneError(_one_line(f"{head}{path}: a lights file is .csv or .npz (by its name), "
                                   f"not {suffix or 'a name without an extension'}"))
    try:
        with open_regular(path, SceneError, "lights file") as f:
            size = os.fstat(f.fileno()).st_size
            if suffix == ".csv":
                table = _read_csv(path, f, size)
            else:
                table = _read_npz(path, f)
    except FileNotFoundError:
        raise SceneError(_one_line(f"{head}cannot read lights file {path}: no such file")) from None
    except IsADirectoryError:
        raise SceneError(_one_line(f"{head}cannot read lights file {path}: it is a directory")) from None
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise SceneError(_one_line(f"{head}cannot read lights file {path}: {reason}")) from None
    except MemoryError:
        raise SceneError(_one_line(f"{path}: out of memory reading the lights file")) from None
    _check_columns(table)
    return table


# ------------------------------------------------------------------ columns


def _require(path: str, need: int, what: str) -> None:
    require_memory(need, f"{path}: {what}", SceneError,
                   "use fewer lights, or set CLPHONG_MAX_MEMORY (e.g. 16G) if you know there is "
                   "more memory")


def _unknown_column(path: str, name: str, where: str) -> SceneError:
    if name in VECTOR_COLUMNS:
        cols = VECTOR_COLUMNS[name]
        hint = (f"a {name} is the three columns {', '.join(cols)}" +
                (f" (np.savez(f, {cols[0]}=a[:, 0], {cols[1]}=a[:, 1], {cols[2]}=a[:, 2]))"
                 if where == "array" else ""))
    else:
        close = difflib.get_close_matches(name, COLUMNS, n=1)
        hint = f"did you mean {close[0]!r}?" if close else f"the columns are {', '.join(COLUMNS)}"
    return SceneError(_one_line(f"{path}: {where} {_short(repr(name), 40)}: unknown column; {hint}"))


def _check_columns(table: LightTable) -> None:
    """Each vector's columns all there or none of them."""
    for key, cols in VECTOR_COLUMNS.items():
        there = [c for c in cols if table.has(c)]
        if there and len(there) < 3:
            missing = [c for c in cols if c not in there]
            raise table.error(None, f"column {missing[0]}",
                              f"missing; the {key} is the three columns {', '.join(cols)} "
                              f"(the file has {', '.join(there)})")


def _nonfinite_error(table: LightTable, bad: dict[str, np.ndarray], values: dict[str, np.ndarray],
                     what: str) -> SceneError:
    """The first non-finite cell (by row, then column), with the count of them all."""
    first = min((int(np.argmax(m)), COLUMNS.index(c), c) for c, m in bad.items())
    row, _, col = first
    counts = ", ".join(f"{c} {int(m.sum())}" for c, m in sorted(bad.items(),
                                                                key=lambda cm: COLUMNS.index(cm[0])))
    total = sum(int(m.sum()) for m in bad.values())
    return table.error(row, col, f"must be finite, got {float(values[col][row])!r}; "
                                 f"{total} {what} cell(s) in all ({counts}); NaN and Inf are refused")


# ------------------------------------------------------------------ CSV


def _read_csv(path: str, f, size: int) -> LightTable:
    _require(path, 2 * size, f"reading a {format_size(size)} lights file")
    raw = f.read()
    rows = raw.count(b"\n") + 1
    _require(path, CSV_BYTES_PER_BYTE * size + ROW_BYTES * rows,
             f"reading {rows} rows ({format_size(size)}) of lights")
    image = image_kind(path, raw)
    if image:
        raise SceneError(_one_line(f"{path}: this is {image} image, not a lights file (CSV)"))
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise SceneError(_one_line(f"{path}:{line}: not UTF-8 (byte {exc.start}); save the "
                                   "file as UTF-8")) from None
    del raw
    reader = csv.reader(io.StringIO(text, newline=""), skipinitialspace=True, strict=True)
    try:
        if '"' in text:                  # a quoted cell may span lines: count them as csv does
            numbered = [(reader.line_num, rec) for rec in reader]
        else:                            # one record a line
            numbered = list(enumerate(reader, 1))
    except csv.Error as exc:
        raise SceneError(_one_line(f"{path}:{reader.line_num}: invalid CSV: {exc}")) from None
    del text
    body = [(ln, rec) for ln, rec in numbered             # not blank lines, nor comments
            if rec and rec[0][:1] != "#" and (len(rec) > 1 or rec[0].strip())]
    del numbered
    if not body:
        raise SceneError(_one_line(f"{path}: no header row; the first line names the columns, "
                                   "e.g. type,x,y,z,r,g,b,intensity"))
    header_line, header = body[0][0], [c.strip() for c in body[0][1]]
    w = len(header)
    for k, (ln, rec) in enumerate(body[1:]):
        if len(rec) != w:
            raise SceneError(_one_line(
                f"{path}: row {k} (line {ln}): expected {w} cells, as in the header (line "
                f"{header_line}), got {len(rec)}"))
    lines = [ln for ln, _ in body[1:]]
    records = [rec for _, rec in body[1:]]
    del body
    seen: dict[str, int] = {}
    for k, name in enumerate(header):
        if name not in COLUMNS:
            raise _unknown_column(path, name, f"line {header_line}: column")
        if name in seen:
            raise SceneError(_one_line(f"{path}: line {header_line}: column {name!r} is there "
                                       f"twice (cells {seen[name] + 1} and {k + 1})"))
        seen[name] = k
    n = len(records)
    table = LightTable(path, n, {}, {}, np.array(lines, np.int64))
    columns = list(zip(*records)) if n else [()] * len(header)
    del records
    numbers, text_cols, bad = {}, {}, {}
    for name, cells in zip(header, columns):
        if name in TEXT_COLUMNS:
            cells = [c.strip() for c in cells]
            longest = max(range(n), key=lambda k: len(cells[k])) if n else 0
            if n and len(cells[longest]) > TEXT_CELL_MAX:
                raise table.error(longest, name, f"{len(cells[longest])} characters; a type or "
                                                 "group name is at most 63")
            text_cols[name] = np.array(cells, dtype=str).reshape(n)
            continue
        a, empty = _csv_numbers(table, name, cells)
        nonfinite = ~np.isfinite(a)
        if empty is not None:
            nonfinite &= ~empty              # an empty cell is NaN; a written nan is not empty
        if nonfinite.any():
            bad[name] = nonfinite
        numbers[name] = a
    table = LightTable(path, n, MappingProxyType(numbers), MappingProxyType(text_cols),
                       table.lines)
    if bad:
        raise _nonfinite_error(table, bad, numbers, "non-finite")
    return table


def _csv_numbers(table: LightTable, name: str, cells) -> tuple[np.ndarray, np.ndarray | None]:
    """A number column and its empty cells (None: none), NaN in those."""
    n = table.rows
    try:
        return np.fromiter(map(float, cells), np.float64, n), None   # every cell a number
    except ValueError:
        pass
    a = np.empty(n)
    empty = np.zeros(n, bool)
    for k, c in enumerate(cells):
        c = c.strip()
        if not c:
            a[k] = np.nan
            empty[k] = True
            continue
        try:
            a[k] = float(c)
        except ValueError:
            raise table.error(k, name, f"expected a number, got {_short(repr(c))}") from None
    return a, empty


# ------------------------------------------------------------------ .npz


def _read_npz(path: str, f) -> LightTable:
    """The arrays of an ``np.savez`` file: their headers first (names, shapes, dtypes,
    and so the memory the rows need), then the data, with ``allow_pickle=False``."""
    magic = f.read(4)
    f.seek(0)
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
        image = image_kind(path, magic)
        what = f"{image} image" if image else "not a zip file"
        raise SceneError(_one_line(f"{path}: this is {what}, not a .npz lights file (numpy.savez "
                                   "of one 1-D array per column)"))
    try:
        zf = zipfile.ZipFile(f)
    except (zipfile.BadZipFile, EOFError, ValueError) as exc:
        raise SceneError(_one_line(f"{path}: not a readable .npz (zip) file: {exc}")) from None
    with zf:
        heads = {}
        for info in zf.infolist():
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            if name not in COLUMNS:
                raise _unknown_column(path, name, "array")
            heads[name] = (info, *_npy_header(path, zf, info, name))
        rows = {name: shape for name, (_, shape, _) in heads.items()}
        n = _common_rows(path, rows)
        # each array as stored and as float64 (or str), and the lights made of the rows
        need = sum(n * (dtype.itemsize + 8) for _, _, dtype in heads.values()) + ROW_BYTES * n
        _require(path, need, f"reading {n} lights")
        numbers, text, bad = {}, {}, {}
        table = LightTable(path, n, numbers, text)
        for name, (info, _, dtype) in heads.items():
            try:
                with zf.open(info) as m:
                    a = np.lib.format.read_array(m, allow_pickle=False)
            except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
                raise table.error(None, f"array {name}", f"cannot be read: {exc}") from None
            if name in TEXT_COLUMNS:
                text[name] = _npz_text(table, name, a)
            else:
                a = a.astype(np.float64)             # exact for ints to 2**53, every float32
                inf = np.isinf(a)
                if inf.any():
                    bad[name] = inf
                numbers[name] = a
    table = LightTable(path, n, MappingProxyType(numbers), MappingProxyType(text))
    if bad:
        raise _nonfinite_error(table, bad, numbers, "infinite")
    return table


def _npy_header(path: str, zf: zipfile.ZipFile, info: zipfile.ZipInfo, name: str):
    """(shape, dtype) of one member, from its header alone; the dtype checked for the column."""
    where = f"{path}: array {name}"
    try:
        with zf.open(info) as m:
            version = np.lib.format.read_magic(m)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(m)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(m)
            else:
                raise ValueError(f".npy format version {version[0]}.{version[1]} is not read "
                                 "(numpy.savez writes 1.0)")
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise SceneError(_one_line(f"{where}: not a readable .npy array: {exc}")) from None
    if dtype.hasobject:
        raise SceneError(_one_line(f"{where}: holds Python objects (dtype {dtype}), which are not "
                                   "read (allow_pickle=False); save numbers as a float array and "
                                   "text as a str array"))
    if name in TEXT_COLUMNS:
        if dtype.kind not in "US":
            raise SceneError(_one_line(f"{where}: expected text (a str array), got dtype {dtype}"))
        chars = dtype.itemsize // (4 if dtype.kind == "U" else 1)
        if chars > TEXT_CELL_MAX:
            raise SceneError(_one_line(f"{where}: cells of up to {chars} characters (dtype "
                                       f"{dtype}); a type or group name is at most 63"))
    elif dtype.kind not in "iuf":
        what = {"b": "booleans", "U": "text", "S": "bytes", "c": "complex numbers"}.get(
            dtype.kind, f"dtype {dtype}")
        raise SceneError(_one_line(f"{where}: expected numbers (a float or integer array), got "
                                   f"{what} (dtype {dtype})"))
    return shape, dtype


def _common_rows(path: str, shapes: dict[str, tuple]) -> int:
    """The rows every array has: each 1-D, all of one length."""
    for name, shape in shapes.items():
        if len(shape) != 1:
            hint = (" (a 2-D array: give one 1-D array per column, e.g. x, y, z)"
                    if len(shape) == 2 else " (a single value: give one per row)" if not shape else "")
            raise SceneError(_one_line(f"{path}: array {name}: expected a 1-D array, one value a "
                                       f"row, got shape {tuple(shape)}{hint}"))
    lengths = sorted(((name, shape[0]) for name, shape in shapes.items()),
                     key=lambda kv: COLUMNS.index(kv[0]))
    for name, n in lengths[1:]:
        if n != lengths[0][1]:
            raise SceneError(_one_line(f"{path}: array {name} has {n} rows but {lengths[0][0]} "
                                       f"has {lengths[0][1]}; every column has one value a row"))
    return lengths[0][1] if lengths else 0


def _npz_text(table: LightTable, name: str, a: np.ndarray) -> np.ndarray:
    if a.dtype.kind == "S":
        try:
            a = np.char.decode(a, "utf-8")
        except UnicodeDecodeError as exc:
            row = next(k for k, x in enumerate(a.tolist()) if not _decodes(x))
            raise table.error(row, name, f"not UTF-8 text: {exc.reason}") from None
    return np.asarray(a, dtype=str)


def _decodes(b: bytes) -> bool:
    try:
        b.decode("utf-8")
        return True
    except UnicodeDecodeError:
        return False


# ------------------------------------------------------------------ writing


def light_columns(lights) -> dict[str, np.ndarray]:
    """The columns of a lights file that holds ``lights`` (scene Lights, in order; no
    environment light): the columns their keys need, NaN or ``""`` in the cells a
    row's type does not take. ``power`` lights keep their power (no intensity, no
    c0, c1, c2), the others their intensity and, point and spot lights, attenuation."""
    lights = list(lights)
    n = len(lights)
    for k, lt in enumerate(lights):
        if lt.type not in ("point", "spot", "directional", "ambient"):
            raise ValueError(f"light {k} is {lt.type!r}: a lights file holds point, spot, "
                             "directional and ambient lights")
    types = [lt.type for lt in lights]
    out: dict[str, np.ndarray] = {"type": np.array(types, dtype=str).reshape(n)}

    def column(values) -> np.ndarray:
        return np.array([math.nan if v is None else v for v in values], np.float64).reshape(n)

    def vector(key, rows):
        for i, c in enumerate(VECTOR_COLUMNS[key]):
            out[c] = column(r[i] if r is not None else None for r in rows)

    point = [t in ("point", "spot") for t in types]
    watts = [lt.power is not None for lt in lights]
    if any(point):
        vector("position", [lt.position if p else None for lt, p in zip(lights, point)])
    if any(t in ("spot", "directional") for t in types):
        vector("direction", [lt.direction if t in ("spot", "directional") else None
                             for lt, t in zip(lights, types)])
    vector("color", [lt.color for lt in lights])
    if not all(watts):
        out["intensity"] = column(None if w else lt.intensity for lt, w in zip(lights, watts))
    if any(watts):
        out["power"] = column(lt.power for lt in lights)
    if any(p and not w for p, w in zip(point, watts)):
        vector("attenuation", [lt.attenuation if p and not w else None
                               for lt, p, w in zip(lights, point, watts)])
    if "spot" in types:
        out["inner_angle"] = column(lt.inner_angle if t == "spot" else None for lt, t in zip(lights, types))
        out["outer_angle"] = column(lt.outer_angle if t == "spot" else None for lt, t in zip(lights, types))
    if any(lt.group is not None for lt in lights):
        out["group"] = np.array([lt.group or "" for lt in lights], dtype=str).reshape(n)
    return {c: out[c] for c in COLUMNS if c in out}


def write_light_table(path, lights) -> None:
    """Write ``lights`` (see :func:`light_columns`) as a ``.csv`` or ``.npz`` lights
    file, by the name; numbers in CSV as ``repr(float)``, which reads back exactly."""
    cols = light_columns(lights)
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if suffix == ".npz":
        with open(path, "wb") as f:
            np.savez(f, **cols)
        return
    if suffix != ".csv":
        raise ValueError(f"{os.fspath(path)}: a lights file is .csv or .npz")
    lists = [a.tolist() for a in cols.values()]
    with open(path, "w", encoding="utf-8", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for row in zip(*lists):
            w.writerow(["" if isinstance(v, float) and v != v else repr(v) if isinstance(v, float)
                        else v for v in row])
