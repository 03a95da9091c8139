"""Why a labelled car is missed (issue #34 part 4): each missed ground-truth box of the tracking
evaluation traced back to its first cause, and the per-cause table."""

from __future__ import annotations

from eval_node.lost_cars import cause_table, lost_cars
from vehicle_common.kitti import KittiObject


def car(tid: int, x1: float, frame: int, score=None, z: float = 20.0) -> KittiObject:
    """A 60 x 40 px Car box at column x1 whose 3D centre is 2 m to the right per 100 px."""
    return KittiObject(
        "Car",
        bbox=(x1, 150.0, x1 + 60.0, 190.0),
        dimensions=(1.5, 1.6, 3.9),
        location=((x1 - 600.0) / 50.0, 1.65, z),
        rotation_y=-1.57,
        frame=frame,
        track_id=tid,
        score=score,
    )


def test_every_missed_box_gets_its_first_cause():
    # car 1 (x1 100): tracked in frame 0; then not detected (1), 2D but no 3D detection (2),
    # a low score with no track (3), a tentative track (4), a coasting track whose box is off
    # (5), a good detection no track took (6)
    gt = {k: [car(1, 100, k)] for k in range(7)}
    det2d = {k: [car(-1, 100, k, 0.9)] for k in (0, 2, 3, 4, 5, 6)}
    det3d = {0: [car(-1, 100, 0, 0.9)], 3: [car(-1, 100, 3, 0.2)], 4: [car(-1, 100, 4, 0.9)]}
    det3d |= {5: [car(-1, 100, 5, 0.9)], 6: [car(-1, 100, 6, 0.9)]}
    tracks = {0: [car(7, 100, 0, 0.9)], 5: [car(7, 140, 5, 0.9)]}  # frame 5: 40 px off
    tentative = {4: [car(8, 100, 4, 0.3)]}
    (rec,) = lost_cars("0000", gt, det2d, det3d, tracks, tentative, birth_score=0.35)
    assert (rec.frames, rec.tracked) == (7, 1)
    assert dict(rec.causes) == {
        "not detected": 1,
        "no 3D detection": 1,
        "below birth_score": 1,
        "tentative (min_hits)": 1,
        "track off the box": 1,
        "no track (association)": 1,
    }
    assert rec.mostly_lost  # 1 of 7 frames tracked
    # the caller that knows why the stereo node dropped a box splits that cause
    (rec,) = lost_cars(
        "0000", gt, det2d, det3d, tracks, tentative, 0.35, drop_causes=lambda k, d: "not ranged"
    )
    assert rec.causes["not ranged"] == 1 and "no 3D detection" not in rec.causes


def test_uncounted_boxes_and_the_table():
    truncated = KittiObject(
        "Car", truncated=1.0, bbox=(0.0, 150.0, 60.0, 190.0), track_id=2, frame=0
    )
    gt = {0: [car(1, 100, 0), truncated], 1: [car(1, 100, 1)]}
    tracks = {0: [car(7, 100, 0, 0.9)], 1: [car(7, 100, 1, 0.9)]}
    recs = lost_cars("0000", gt, {}, {}, tracks, {})
    # the truncated car does not count (KITTI tracking rules)
    assert [(r.track_id, r.frames, r.tracked) for r in recs] == [(1, 2, 2)]
    table = cause_table(recs)
    assert "recall 1.000" in table and "mostly lost (< 20 % tracked) 0" in table


def other(kind: str, x1: float, frame: int, w: float = 60.0) -> KittiObject:
    """A labelled object of another class (or a DontCare region) at column x1."""
    return car(-1, x1, frame).with_(type=kind, bbox=(x1, 150.0, x1 + w, 190.0))


def test_every_false_track_row_gets_its_cause():
    """Issue #41: a duplicate on a tracked car, a box off an untracked car, a track that
    outlived its car, a track on a pedestrian / in a DontCare region, a ghost."""
    from eval_node.lost_cars import false_track_table, false_tracks

    # frame 0: car 1 at 100 tracked by 7; car 2 at 400 tracked by 8
    # frame 1: car 1 tracked by 7 and a duplicate 9 (30 px off, same car); car 2 has left,
    #   track 8 coasts on (its car was matched in frame 0); car 3 at 700 boxed 35 px off by 10
    # frame 2: track 11 on a pedestrian, 12 in a DontCare region, 13 where nothing is
    gt = {
        0: [car(1, 100, 0), car(2, 400, 0)],
        1: [car(1, 100, 1), car(3, 700, 1)],
        2: [other("Pedestrian", 300, 2, 30), other("DontCare", 600, 2, 200)],
    }
    tracks = {
        0: [car(7, 100, 0, 0.9), car(8, 400, 0, 0.9)],
        1: [car(7, 100, 1, 0.9), car(9, 130, 1, 0.8), car(8, 420, 1, 0.7), car(10, 735, 1)],
        2: [car(11, 290, 2, 0.9), car(12, 610, 2, 0.9).with_(bbox=(610, 150, 700, 180))],
    }
    tracks[2].append(car(13, 1000, 2, 0.9).with_(location=(30.0, 1.65, 40.0)))
    rows = false_tracks("0000", gt, tracks)
    got = {(r.frame, r.track_id): r.cause for r in rows}
    assert got == {
        (1, 9): "duplicate",
        (1, 8): "outlived its car",
        (1, 10): "off the box",
        (2, 11): "wrong class",
        (2, 13): "ghost",
    }, got  # track 12: over half its box in the DontCare region, ignored by the evaluation
    table = false_track_table(rows)
    assert "| duplicate | 1 | 0.20 | 1 |" in table and "| ghost | 1 | 0.20 | 1 |" in table
