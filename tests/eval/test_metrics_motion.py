"""Motion metrics: velocity error against finite-difference ground truth, and jitter."""

from __future__ import annotations

import math

import pytest
from eval_node.motion_metrics import (
    jitter,
    matched_jitter,
    stability,
    track_velocities,
    velocity_errors,
)
from vehicle_common.kitti import KittiObject, read_tracking_labels


def obj(frame, tid, x=0.0, z=20.0, x1=100.0, h=1.5):
    return KittiObject(
        "Car",
        bbox=(x1, 100.0, x1 + 100.0, 150.0),
        dimensions=(h, 1.6, 4.0),
        location=(x, 1.6, z),
        rotation_y=0.0,
        frame=frame,
        track_id=tid,
    )


def straight(speed, n=6, tid=0, x1=100.0, x=0.0):
    """A car driving away along z at ``speed`` m/s, 10 Hz."""
    return {f: [obj(f, tid, x=x, z=20.0 + speed * 0.1 * f, x1=x1)] for f in range(n)}


def test_track_velocities_central_and_one_sided():
    gt = {0: [obj(0, 0, z=20.0)], 1: [obj(1, 0, z=21.0)], 2: [obj(2, 0, z=23.0)]}
    v = track_velocities(gt)
    assert v[(0, 0)] == pytest.approx([0.0, 10.0])  # forward
    assert v[(1, 0)] == pytest.approx([0.0, 15.0])  # central: 3 m over 0.2 s
    assert v[(2, 0)] == pytest.approx([0.0, 20.0])  # backward
    # frame stamps instead of 10 Hz
    v = track_velocities(gt, stamps={0: 0.0, 1: 0.2, 2: 0.4})
    assert v[(1, 0)] == pytest.approx([0.0, 7.5])
    # centre of mass on the ground plane: the box height does not matter
    tall = {f: [obj(f, 0, h=1.0 + f)] for f in range(3)}
    assert track_velocities(tall)[(1, 0)] == pytest.approx([0.0, 0.0])


def test_velocity_error_exact_and_biased():
    gt = straight(12.0)
    same = velocity_errors(gt, straight(12.0, tid=7))
    assert same["n"] == 6 and same["rmse"] == pytest.approx(0.0, abs=1e-9)
    # a tracker reporting 13 m/s on the same boxes: 1 m/s error in the >10 m/s bucket
    pv = {(f, 7): (0.0, 13.0) for f in range(6)}
    r = velocity_errors(gt, straight(12.0, tid=7), pred_velocities=pv)
    assert r["rmse"] == pytest.approx(1.0) and r["speed_rmse"] == pytest.approx(1.0)
    top = r["buckets"][-1]
    assert (top["lo"], top["hi"], top["n"]) == (10.0, math.inf, 6)
    assert top["relative"] == pytest.approx(1 / 12)
    assert [b["n"] for b in r["buckets"][:-1]] == [0, 0, 0]
    # a slow car (1 m/s) estimated at 0 m/s lands in the first bucket with relative error 1
    slow = straight(1.0)
    still = {f: [obj(f, 3, z=20.0)] for f in range(6)}
    r = velocity_errors(slow, still)
    assert r["buckets"][0]["n"] == 6 and r["buckets"][0]["relative"] == pytest.approx(1.0)


def test_velocity_error_needs_association():
    gt = straight(12.0)
    # the prediction's 2D box does not overlap the ground truth's: no pair, no error sample
    r = velocity_errors(gt, straight(12.0, tid=7, x1=600.0))
    assert r["n"] == 0 and math.isnan(r["rmse"])


def test_jitter_and_stability():
    gt = straight(10.0)
    zig = {f: [obj(f, 5, x=0.1 * (f % 2), z=20.0 + f)] for f in range(6)}
    assert jitter(gt)["rms_m"] == pytest.approx(0.0, abs=1e-12)
    j = jitter(zig)
    assert j["n"] == 4 and j["rms_m"] == pytest.approx(0.2)  # |0.1 - 2*0 + 0.1|
    gt_zig = {f: [obj(f, 0, x=0.05 * (f % 2), z=20.0 + f)] for f in range(6)}
    s = stability(gt_zig, zig)
    assert s["ratio"] == pytest.approx(2.0)
    assert s["pred_rms_mps2"] == pytest.approx(0.2 / 0.01)
    assert math.isnan(stability(gt, zig)["ratio"])


def test_matched_jitter_leaves_out_false_tracks():
    """A false track far from every car jitters wildly; the matched-car ratio ignores it (the
    all-tracks ratio does not), and counts the matched car's own triplets only."""
    gt_zig = {f: [obj(f, 0, x=0.05 * (f % 2), z=20.0 + f)] for f in range(6)}
    zig = {f: [obj(f, 5, x=0.1 * (f % 2), z=20.0 + f)] for f in range(6)}
    ghost = {f: zig[f] + [obj(f, 9, x=3.0 * (f % 2), z=60.0, x1=900.0)] for f in range(6)}
    m = matched_jitter(gt_zig, ghost)
    assert m["n"] == 4 and m["ratio"] == pytest.approx(2.0)
    assert stability(gt_zig, ghost)["ratio"] > 10.0
    assert stability(gt_zig, ghost)["matched"]["ratio"] == pytest.approx(2.0)


def test_labels_against_themselves(kitti_tracking_root):
    gt = read_tracking_labels(kitti_tracking_root / "label_02" / "0012.txt")
    r = velocity_errors(gt, gt)
    assert r["n"] > 0 and r["rmse"] == 0.0
    s = stability(gt, gt)
    assert s["n_gt"] > 0 and s["ratio"] == pytest.approx(1.0)
