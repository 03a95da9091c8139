"""Exact-stamp synchroniser: grouping, bounded cache, counted evictions."""

from __future__ import annotations

import pytest
from stereo_depth_node.stamp_sync import ExactStampSync


def test_groups_complete_on_equal_stamps_in_any_order():
    s = ExactStampSync(("frame", "detections"), cache_size=4)
    assert s.add((1, 0), "detections", "d1") is None
    assert s.add((2, 0), "frame", "f2") is None
    assert s.add((1, 0), "frame", "f1") == {"frame": "f1", "detections": "d1"}
    assert s.pending_stamps() == [(2, 0)]
    assert s.add((2, 0), "detections", "d2") == {"frame": "f2", "detections": "d2"}
    assert len(s) == 0 and s.take_evicted() == []


def test_cache_is_bounded_and_evictions_are_counted():
    s = ExactStampSync(("frame", "detections"), cache_size=3)
    for k in range(5):
        s.add((k, 0), "detections", f"d{k}")  # frames never arrive
    assert len(s) == 3
    ev = s.take_evicted()
    assert [e.stamp for e in ev] == [(0, 0), (1, 0)]
    assert ev[0].missing(s.slots) == ["frame"] and ev[0].values == {"detections": "d0"}
    assert s.dropped == {"frame": 0, "detections": 2}
    assert s.take_evicted() == []
    # a late frame of an evicted stamp does not complete anything
    assert s.add((0, 0), "frame", "f0") is None
    assert s.add((4, 0), "frame", "f4") == {"frame": "f4", "detections": "d4"}


def test_bad_configuration_raises():
    with pytest.raises(ValueError):
        ExactStampSync(("a",), cache_size=0)
    with pytest.raises(ValueError):
        ExactStampSync(("a", "a"))
    with pytest.raises(KeyError):
        ExactStampSync(("a", "b")).add(1, "c", None)


def test_in_order_a_complete_stamp_evicts_the_older_pending_ones():
    s = ExactStampSync(("left", "right"), cache_size=10, in_order=True)
    assert s.add(10, "left", "l10") is None  # right 10 is lost
    assert s.add(20, "left", "l20") is None
    assert s.add(30, "right", "r30") is None  # newer than the complete stamp: kept
    assert s.add(20, "right", "r20") == {"left": "l20", "right": "r20"}
    ev = s.take_evicted()
    assert [(e.stamp, e.values) for e in ev] == [(10, {"left": "l10"})]
    assert s.pending_stamps() == [30] and s.dropped == {"left": 1, "right": 0}
    # without in_order the stale stamp stays until the cache overflows
    plain = ExactStampSync(("left", "right"), cache_size=10)
    plain.add(10, "left", "l10")
    plain.add(20, "left", "l20")
    plain.add(20, "right", "r20")
    assert plain.pending_stamps() == [10] and plain.take_evicted() == []
