"""Frame ranges (``--frames 1-240x2,300``) held as their items, never as a list of numbers.

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
import re
from collections.abc import Iterable, Iterator
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
