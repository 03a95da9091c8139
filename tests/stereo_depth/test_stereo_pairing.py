"""Left and right images of two drivers that are not hardware synced pair within a tolerance, as
message_filters' ApproximateTime does (issue #42 item 2); equal stamps stay exact."""

import pytest
from stereo_depth_node.stamp_sync import ExactStampSync, StereoPairing

MS = 1_000_000
PERIOD = 100 * MS  # 10 Hz


def _feed(pairing, lefts, rights):
    """Interleave left and right arrivals by stamp; the pairs formed, as (left, right) stamps."""
    events = sorted([(t, "L") for t in lefts] + [(t, "R") for t in rights])
    out = []
    for t, side in events:
        got = pairing.add_left(t) if side == "L" else pairing.add_right(t, t)
        out += got
    return out


def test_equal_stamps_pair_at_once_whatever_the_tolerance():
    for tol in (-1, 0):
        p = StereoPairing(tolerance_ns=tol)
        assert p.add_left(5 * PERIOD) == []
        assert p.add_right(5 * PERIOD, "r") == [(5 * PERIOD, "r")]


@pytest.mark.parametrize("offset_ms", [1, -1, 3, -5])
def test_derived_tolerance_pairs_stamps_a_few_ms_apart(offset_ms):
    lefts = [k * PERIOD for k in range(16)]
    rights = [t + offset_ms * MS for t in lefts]
    pairs = _feed(StereoPairing(), lefts, rights)
    # every left pairs with its own right; the first waits for the period to be measured
    assert sorted(pairs) == list(zip(lefts, rights, strict=True))
    assert StereoPairing().tolerance() == 0  # no period measured yet: equal stamps only


def test_tolerance_is_a_quarter_period_and_a_parameter_sets_it():
    p = StereoPairing()
    for k in range(4):
        p.add_left(k * PERIOD)
    assert p.tolerance() == PERIOD // 4
    fixed = StereoPairing(tolerance_ns=2 * MS)
    assert _feed(fixed, [0, PERIOD], [3 * MS, PERIOD + 1 * MS]) == [(PERIOD, PERIOD + MS)]
    assert fixed.nearest_right(0) == 3 * MS
    exact = StereoPairing(tolerance_ns=0)
    assert _feed(exact, [0, PERIOD, 2 * PERIOD], [MS, PERIOD + MS, 2 * PERIOD]) == [
        (2 * PERIOD, 2 * PERIOD)
    ]


def test_a_right_image_too_far_away_does_not_pair():
    p = StereoPairing()
    lefts = [k * PERIOD for k in range(6)]
    rights = [t + 40 * MS for t in lefts]  # 40 ms: beyond a quarter period
    assert _feed(p, lefts, rights) == []
    assert p.nearest_right(5 * PERIOD) == 40 * MS


def test_time_going_back_starts_afresh():
    p = StereoPairing()
    _feed(p, [k * PERIOD for k in range(10, 14)], [])
    assert p.add_left(2 * PERIOD) == []  # a restarted camera: the old lefts are forgotten
    assert p.add_right(2 * PERIOD + MS, "r") == []  # no period yet in the new stream
    assert p.add_left(3 * PERIOD) == [(2 * PERIOD, "r")]


def test_take_pending_counts_the_sets_that_never_completed():
    sync = ExactStampSync(("left", "right", "detections"), in_order=True)
    sync.add(1, "left", "l")
    sync.add(1, "detections", "d")
    pending = sync.take_pending()
    assert [e.missing(sync.slots) for e in pending] == [["right"]]
    assert sync.dropped == {"left": 1, "right": 0, "detections": 1} and len(sync) == 0
