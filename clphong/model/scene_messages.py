"""How the scene parser names keys and values in its one-line messages."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

# --------------------------------------------------------------------------
# message helpers
# --------------------------------------------------------------------------

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+\Z")
_LIGHT_PATH = re.compile(r"light\[(\d+)\]")


def _g(x: float) -> str:
    """A short human form of a float for messages."""
    return f"{x:.6g}"


def _ordinal(n: int) -> str:
    if 10 <= n % 100 <= 20:
        suffix = "th"
    else:
        suffix = {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def _short(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _quoted_list(items) -> str:
    return ", ".join(repr(i) for i in items)


def _key(k: Any) -> str:
    """A key as it appears in a path: bare if TOML allows it, else quoted."""
    if isinstance(k, str) and _BARE_KEY.match(k):
        return k
    return _short(repr(k), 40)


def _join(path: str, key: Any) -> str:
    return f"{path}.{_key(key)}" if path else _key(key)


def _describe(v: Any) -> str:
    """What a value is, for 'expected X, got Y' messages."""
    if isinstance(v, bool):
        return f"boolean {'true' if v else 'false'}"
    if isinstance(v, int):
        return f"integer {_short(str(v), 30)}"
    if isinstance(v, float):
        return f"float {v!r}"
    if isinstance(v, str):
        return f"string {_short(repr(v))}"
    if isinstance(v, Mapping):
        return f"table {{{_short(', '.join(_key(k) for k in v), 50)}}}"
    if isinstance(v, (list, tuple)):
        return f"array {_short(repr(list(v)))}"
    if v is None:
        return "nothing (None)"
    return f"{type(v).__name__} {_short(repr(v))}"


def _one_line(text: str) -> str:
    """Escape anything that could break a message over several lines."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)


def _message(source: str, path: str, problem: str) -> str:
    head = f"{source}: {path}: " if path else f"{source}: "
    m = _LIGHT_PATH.match(path)
    note = ""
    if m:
        i = int(m.group(1))
        note = f" (light[{i}] is the {_ordinal(i + 1)} [[light]])"
    return _one_line(head + problem + note)
