"""Frame ranges, sequences on disk, and the names of a batch's outputs.

Frame ranges (``--frames 1-240x2,300``) are held as their items, never as a list of numbers.

``relight --frames 1-1000000000`` on a four-frame shot built a list of 10⁹ frames
and was killed by the out-of-memory killer. A :class:`FrameRange` keeps the items
(start, end, step); the batch enumerates the frames that exist on disk and asks
the range whether each is in it (time and memory proportional to the files), and
counts the frames of the range that are missing from the items alone
(:meth:`FrameRange.count`, exact, overlapping items included).
"""

from __future__ import annotations

import itertools
import math
import os
import re
import string
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

from .jobs import BatchError

_RANGE_ITEM = re.compile(r"^\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*(?:[x:]\s*(\d+)\s*)?)?$")

#: Inclusion–exclusion over the overlapping items costs 2^n intersections.
_MAX_OVERLAPPING_ITEMS = 12


def _intersect(p, q):
    """The intersection of two arithmetic progressions (start, end, step), or None."""
    (a1, b1, s1), (a2, b2, s2) = p, q
    g = math.gcd(s1, s2)
    if (a2 - a1) % g:
        return None
    lcm = s1 // g * s2
    # x = a1 + s1·t with s1·t ≡ a2 − a1 (mod s2): t = ((a2 − a1)/g)·(s1/g)⁻¹ mod s2/g
    m = s2 // g
    t = ((a2 - a1) // g) * pow(s1 // g, -1, m) % m if m > 1 else 0
    x0 = a1 + s1 * t
    lo, hi = max(a1, a2), min(b1, b2)
    start = x0 + (-(-(lo - x0) // lcm)) * lcm          # the first x ≡ x0 (mod lcm) at or above lo
    return (start, hi, lcm) if start <= hi else None


def _size(p) -> int:
    a, b, s = p
    return 0 if a > b else (b - a) // s + 1


@dataclass(frozen=True)
class FrameRange:
    """The items of a range string: (start, end, step) each, in the order written."""

    items: tuple[tuple[int, int, int], ...]
    text: str = ""

    @classmethod
    def parse(cls, text: str) -> FrameRange:
        """Parse ``N``, ``A-B`` (inclusive) and ``A-BxS`` items, comma-separated.

        Raises
        ------
        BatchError
            Naming the bad item: not a range, ``B < A`` or a step < 1.
        """
        if not str(text).strip():
            raise BatchError("frame range is empty; write e.g. 1-240 or 1-240x2")
        items = []
        for item in str(text).split(","):
            m = _RANGE_ITEM.match(item)
            if not m:
                raise BatchError(f"frame range {text!r}: {item.strip()!r} is not N, A-B or A-BxSTEP")
            a = int(m.group(1))
            b = int(m.group(2)) if m.group(2) is not None else a
            step = int(m.group(3)) if m.group(3) is not None else 1
            if step < 1:
                raise BatchError(f"frame range {text!r}: step in {item.strip()!r} must be >= 1")
            if b < a:
                raise BatchError(f"frame range {text!r}: {item.strip()!r} ends before it starts")
            items.append((a, b - (b - a) % step, step))       # the end a member
        return cls(tuple(items), str(text).strip())

    def __contains__(self, frame: int) -> bool:
        return any(a <= frame <= b and (frame - a) % s == 0 for a, b, s in self.items)

    def __iter__(self) -> Iterator[int]:
        """The frames in the order written, each once (lazily: for a range of 10⁹ frames,
        take only what is needed)."""
        for i, (a, b, s) in enumerate(self.items):
            earlier = FrameRange(self.items[:i])
            for f in range(a, b + 1, s):
                if f not in earlier:
                    yield f

    def count(self) -> int:
        """How many distinct frames the range holds, without listing them: the items' sizes
        less their overlaps (inclusion–exclusion over the items that overlap)."""
        items = [p for p in self.items if _size(p)]
        overlapping = {k for i, j in itertools.combinations(range(len(items)), 2)
                       if _intersect(items[i], items[j]) is not None for k in (i, j)}
        total = sum(_size(p) for i, p in enumerate(items) if i not in overlapping)
        group = [items[i] for i in sorted(overlapping)]
        if len(group) > _MAX_OVERLAPPING_ITEMS:
            raise BatchError(f"frame range {self.text!r}: more than {_MAX_OVERLAPPING_ITEMS} "
                             "items overlap; write it with fewer overlapping items")
        for k in range(1, len(group) + 1):
            for subset in itertools.combinations(group, k):
                common = subset[0]
                for p in subset[1:]:
                    common = _intersect(common, p)
                    if common is None:
                        break
                if common is not None:
                    total += (-1) ** (k + 1) * _size(common)
        return total

    def missing(self, present: Iterable[int], limit: int = 5) -> list[int]:
        """The first ``limit`` frames of the range, in order, that are not in ``present``."""
        have = set(present)
        return list(itertools.islice((f for f in self if f not in have), limit))


def parse_frame_range(text: str) -> list[int]:
    """Frames of a range string, in order, without duplicates (a list: for ranges a user
    may give, use :meth:`FrameRange.parse`, which does not list them).

    Examples
    --------
    >>> parse_frame_range("1-9x4,20")
    [1, 5, 9, 20]
    """
    return list(FrameRange.parse(text))


# --------------------------------------------------------------------------- sequences and names


_HASHES = re.compile(r"#+")
_PRINTF = re.compile(r"%(0?)(\d*)d")


def _frame_token(pattern: str) -> tuple[str, str, int] | None:
    """(prefix, suffix, padding) of the one frame token of a file pattern, or None."""
    base = os.path.basename(pattern)
    hashes = list(_HASHES.finditer(base))
    printf = list(_PRINTF.finditer(base))
    if len(hashes) + len(printf) > 1:
        raise BatchError(f"{pattern}: more than one frame token (#### or %04d); use exactly one")
    if not hashes and not printf:
        return None
    m = (hashes or printf)[0]
    pad = len(m.group(0)) if hashes else (int(m.group(2)) if m.group(2) else 1)
    folder = pattern[: len(pattern) - len(base)]
    return folder + base[: m.start()], base[m.end():], pad


def _pad(frame: int, pad: int) -> str:
    return f"{frame:0{pad}d}" if frame >= 0 else f"-{-frame:0{pad}d}"


_TRAILING_NUMBER = re.compile(r"^(.*?)(\d+)$")


def _split_stem(stem: str) -> tuple[str, int | None]:
    """('shot', 12) for 'shot.0012' / 'shot_0012'; (stem, None) without a number."""
    m = _TRAILING_NUMBER.match(stem)
    if not m:
        return stem, None
    return m.group(1).rstrip("._-") or m.group(1), int(m.group(2))


def _pattern_of(folder: str, numbered) -> str:
    """``folder/gbuf.####.exr`` from the first numbered file name of ``numbered`` (for messages)."""
    for n, f in numbered:
        if n is not None:
            stem, ext = os.path.splitext(f)
            m = _TRAILING_NUMBER.match(stem)
            return os.path.join(folder, m.group(1) + "#" * len(m.group(2)) + ext)
    return os.path.join(folder, "NAME.####.exr")




def expand_sequence(pattern: str, frames: Sequence[int] | None = None) -> list[tuple[int, str]]:
    """The (frame, path) pairs of a sequence (see the module docstring).

    A folder's frames are numbered by the digits at the end of each file's
    own stem, so ``--frames`` means the same frames for a folder as for its
    ``P.####.exr`` pattern. A folder is refused (rather than renumbered, or
    partly skipped) when one of its EXRs has no frame number or two have the
    same one: a stray file there is either a misnamed frame or not part of
    the shot, which only the user can tell.

    Raises
    ------
    BatchError
        No frames found; a pattern without a frame token given ``frames``; a
        folder with an un-numbered EXR (the message names it) or with two
        EXRs of one frame number (it names both).
    """
    pattern = os.fspath(pattern)
    if os.path.isdir(pattern):
        files = [f for f in sorted(os.listdir(pattern))
                 if f.lower().endswith(".exr") and not f.startswith(".")
                 and os.path.isfile(os.path.join(pattern, f))]
        numbered = [(_split_stem(os.path.splitext(f)[0])[1], f) for f in files]
        owner: dict[int, str] = {}
        for n, f in numbered:
            if n is None:
                raise BatchError(f"{os.path.join(pattern, f)}: no frame number at the end of its name, and "
                                 "every .exr in a sequence folder is a frame; move it out, or give a "
                                 f"pattern such as {_pattern_of(pattern, numbered)}")
            if n in owner:
                raise BatchError(f"{os.path.join(pattern, owner[n])} and {os.path.join(pattern, f)} are "
                                 f"both frame {n} (two sequences in one folder?); give a pattern such as "
                                 f"{_pattern_of(pattern, [(n, f)])} to pick one")
            owner[n] = f
        pairs = _in_range(sorted((n, os.path.join(pattern, f)) for n, f in numbered), frames)
        if not pairs:
            what = f" in frames {_short_frames(frames)}" if frames is not None else ""
            raise BatchError(f"{pattern}: no .exr files{what}")
        return pairs
    token = _frame_token(pattern)
    if token is None:
        n = _split_stem(os.path.splitext(os.path.basename(pattern))[0])[1]
        if frames is not None and not (n in _wanted(frames) and _range_size(frames) == 1):
            raise BatchError(f"{pattern}: a frame range needs a sequence pattern (P.####.exr, P.%04d.exr) "
                             "or a folder")
        return [(n if n is not None else 1, pattern)]
    prefix, suffix, pad = token
    regex = re.compile(re.escape(os.path.basename(prefix)) + r"(-?\d+)" + re.escape(suffix) + r"$")
    folder = os.path.dirname(prefix) or "."
    found = []
    try:
        names = os.listdir(folder)
    except OSError as exc:
        raise BatchError(f"{pattern}: cannot list folder {folder}: {exc.strerror or exc}") from None
    for fname in names:
        m = regex.match(fname)
        if m and _pad(int(m.group(1)), pad) == m.group(1):
            found.append((int(m.group(1)), os.path.join(os.path.dirname(prefix), fname)))
    found = _in_range(sorted(found), frames)
    if not found:
        what = f" in frames {_short_frames(frames)}" if frames is not None else ""
        raise BatchError(f"{pattern}: no files match the pattern{what}")
    return found


def _wanted(frames):
    """Something to test ``frame in`` against: a :class:`FrameRange` as it is (never listed)."""
    return frames if isinstance(frames, FrameRange) else set(frames)


def _range_size(frames) -> int:
    return frames.count() if isinstance(frames, FrameRange) else len(set(frames))


def _first_missing(frames, present, limit: int = 5) -> list[int]:
    """The first ``limit`` frames of ``frames`` (a FrameRange or a sequence), in order,
    that are not in ``present``."""
    if isinstance(frames, FrameRange):
        return frames.missing(present, limit)
    have = set(present)
    return list(itertools.islice((f for f in dict.fromkeys(frames) if f not in have), limit))


def _in_range(pairs, frames):
    """The (frame, path) pairs found on disk whose frame is in ``frames`` (all if None):
    time and memory go with the files, not with the range (10⁹ frames were listed)."""
    if frames is None:
        return pairs
    wanted = _wanted(frames)
    return [p for p in pairs if p[0] in wanted]


def _short_frames(frames) -> str:
    if isinstance(frames, FrameRange):
        return frames.text
    frames = list(frames or [])
    return ", ".join(map(str, frames[:5])) + (", ..." if len(frames) > 5 else "")


_FIELDS = ("frame", "rig", "stem", "name")


def _check_template(template: str) -> None:
    try:
        parsed = list(string.Formatter().parse(template))
    except ValueError as exc:
        raise BatchError(f"output template {template!r}: {exc}") from None
    for _, fld, _, _ in parsed:
        if fld is not None and fld not in _FIELDS:
            raise BatchError(f"output template {template!r}: unknown field {{{fld}}}; "
                             f"use {', '.join('{' + f + '}' for f in _FIELDS)}")


def format_output(template: str, *, frame: int, rig: str, source: str) -> str:
    """The output path of one frame and rig.

    Examples
    --------
    >>> format_output("out/{rig}/{name}.####.exr", frame=7, rig="key", source="in/shot.0007.exr")
    'out/key/shot.0007.exr'
    """
    stem = os.path.splitext(os.path.basename(source))[0]
    name = _split_stem(stem)[0]
    text = _HASHES.sub(lambda m: _pad(frame, len(m.group(0))), template)
    text = _PRINTF.sub(lambda m: _pad(frame, int(m.group(2)) if m.group(2) else 1), text)
    try:
        return text.format(frame=frame, rig=rig, stem=stem, name=name)
    except (ValueError, KeyError, IndexError) as exc:
        raise BatchError(f"output template {template!r}: {exc}") from None
