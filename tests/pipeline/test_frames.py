"""clphong.pipeline.frames: ranges held as items, counted and tested without listing them."""

from __future__ import annotations

import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clphong.pipeline.frames import FrameRange, parse_frame_range
from clphong.pipeline.jobs import BatchError

item = st.tuples(st.integers(-50, 200), st.integers(0, 120), st.integers(1, 9))


@settings(max_examples=300, deadline=None)
@given(st.lists(item, min_size=1, max_size=7))
def test_count_membership_and_order_match_the_listed_frames(items):
    """Against the frames listed one by one (the definition): the count with overlapping
    and stepped items (inclusion–exclusion), membership, and the order written."""
    text = ",".join(f"{a}-{a + n}x{s}" for a, n, s in items)
    r = FrameRange.parse(text)
    listed = []
    for a, n, s in items:
        listed += [f for f in range(a, a + n + 1, s) if f not in listed]
    assert list(r) == listed == parse_frame_range(text)
    assert r.count() == len(listed)
    for f in range(-60, 340):
        assert (f in r) == (f in listed)
    present = listed[::3]
    assert r.missing(present, limit=4) == [f for f in listed if f not in present][:4]


def test_a_range_of_a_billion_frames_costs_nothing():
    t0 = time.perf_counter()
    r = FrameRange.parse("1-1000000000,5-2000000000x7")
    assert r.count() == 1_000_000_000 + (2_000_000_000 - 5) // 7 + 1 - ((1_000_000_000 - 5) // 7 + 1)
    assert 999_999_999 in r and 2_000_000_001 not in r
    assert r.missing([1, 2, 4]) == [3, 5, 6, 7, 8]
    assert time.perf_counter() - t0 < 0.5


@pytest.mark.parametrize("bad", ["", "a-b", "5-1", "1-10x0", "1--"])
def test_bad_ranges_name_the_item(bad):
    with pytest.raises(BatchError):
        FrameRange.parse(bad)


def test_too_many_overlapping_items_is_one_line():
    with pytest.raises(BatchError, match="more than 12 items overlap"):
        FrameRange.parse(",".join(["1-100"] * 13)).count()
