"""Detection metrics: KITTI-devkit AP (centre distance and 2D IoU), VOC07 AP, orientation bins.

Hand computation of the devkit's sampled AP used below: with N ground truths, one per frame, and
the true positives' scores all distinct, every TP score becomes a sample threshold (recall step
1/N >= 1/40), so sample i holds the precision with the i+1 best-scoring TPs kept; samples past the
last TP are 0. ap_r41 = mean of the 41 samples, ap_r11 = mean of samples 0, 4, .., 40,
ap_r40 = mean of samples 1..40. With N = 41 every one of the 41 samples is a TP threshold for a
perfect detector (with N = 40 the devkit leaves the last sample empty).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from eval_node.detection_metrics import (
    box_iou_2d,
    box_overlap_over_first,
    centre_distances,
    detection_ap_2d,
    localisation_ap,
    orientation_accuracy,
    precision_recall,
    voc07_ap,
)
from vehicle_common.kitti import KittiObject, read_tracking_labels


def car(
    frame=0,
    x1=100.0,
    y1=100.0,
    w=100.0,
    h=50.0,
    loc=(0.0, 1.6, 20.0),
    dims=(1.5, 1.6, 4.0),
    score=None,
    type="Car",
    occ=0,
    trunc=0.0,
    alpha=0.0,
    tid=-1,
):
    return KittiObject(
        type=type,
        truncated=trunc,
        occluded=occ,
        alpha=alpha,
        bbox=(x1, y1, x1 + w, y1 + h),
        dimensions=dims,
        location=loc,
        rotation_y=0.0,
        frame=frame,
        track_id=tid,
        score=score,
    )


def far(frame, score):
    """A prediction nowhere near any ground truth (3D and 2D)."""
    return car(frame, x1=900.0, loc=(30.0, 1.6, 60.0), score=score)


N = 41


def gt_one_per_frame():
    return {f: [car(f)] for f in range(N)}


def test_geometry_helpers():
    a = np.array([[0, 0, 10, 10]], float)
    b = np.array([[5, 0, 15, 10], [0, 0, 5, 5], [20, 20, 30, 30]], float)
    np.testing.assert_allclose(box_iou_2d(a, b), [[50 / 150, 25 / 100, 0.0]])
    np.testing.assert_allclose(box_overlap_over_first(b, a)[:, 0], [0.5, 1.0, 0.0])
    d = centre_distances([car(loc=(3.0, 1.6, 24.0))], [car()])
    assert d[0, 0] == pytest.approx(5.0)


def test_perfect_predictions_ap_is_one():
    gt = gt_one_per_frame()
    pred = {f: [car(f, score=0.5 + 0.01 * f)] for f in range(N)}
    for res in (localisation_ap(gt, pred), detection_ap_2d(gt, pred)):
        for by_thr in res.values():
            for r in by_thr.values():
                assert (r["ap_r41"], r["ap_r11"], r["ap_r40"]) == (1.0, 1.0, 1.0)
                assert r["num_gt"] == N
    assert voc07_ap(gt, pred) == pytest.approx(1.0)


def test_all_wrong_ap_is_zero_and_no_gt_is_nan():
    gt = gt_one_per_frame()
    pred = {f: [far(f, 0.9)] for f in range(N)}
    pr = precision_recall(gt, pred, criterion="centre_distance", threshold=10.0)
    assert pr.ap_r41 == 0.0 and pr.ap_r40 == 0.0 and pr.num_gt == N
    assert voc07_ap(gt, pred) == 0.0
    assert math.isnan(precision_recall({}, pred).ap_r41)


def half_right(fp_score):
    """Frames 0..20: a correct prediction (scores 0.90, 0.89, ..); frames 21..40: a wrong one."""
    pred = {f: [car(f, score=0.9 - 0.01 * f)] for f in range(21)}
    pred.update({f: [far(f, fp_score)] for f in range(21, N)})
    return pred


def test_half_right_false_positives_below_true_positives():
    pr = precision_recall(gt_one_per_frame(), half_right(0.1), threshold=1.5)
    # samples 0..20 have precision 1 (no FP above any threshold), 21..40 are 0
    np.testing.assert_array_equal(pr.precision, [1.0] * 21 + [0.0] * 20)
    assert pr.ap_r41 == pytest.approx(21 / 41)
    assert pr.ap_r11 == pytest.approx(6 / 11)
    assert pr.ap_r40 == pytest.approx(20 / 40)
    # raw counts per threshold: TP i+1, FP 0, FN N-i-1 (the devkit's recall is then made
    # monotone from the right like precision)
    np.testing.assert_array_equal(pr.tp_fp_fn[:, 0], np.arange(21) + 1)
    np.testing.assert_array_equal(pr.tp_fp_fn[:, 1:].T, [[0] * 21, N - 1 - np.arange(21)])
    assert pr.max_recall == pytest.approx(21 / N)
    np.testing.assert_allclose(pr.recall, np.arange(41) / 40)  # the recall sample points
    # VOC07: recall reaches 21/41 > 0.5 at precision 1 -> points 0, 0.1, .., 0.5
    assert voc07_ap(gt_one_per_frame(), half_right(0.1)) == pytest.approx(6 / 11)


def test_half_right_false_positives_above_true_positives():
    pr = precision_recall(gt_one_per_frame(), half_right(0.95), threshold=1.5)
    # at sample i: TP i+1, FP 20 -> (i+1)/(i+21); made monotone from the right: 21/41
    np.testing.assert_allclose(pr.precision[:21], 21 / 41)
    assert pr.ap_r41 == pytest.approx(21 * 21 / 41 / 41)


def test_ties_in_score():
    pred = {f: [car(f, score=0.5)] for f in range(21)}
    pred.update({f: [far(f, 0.5)] for f in range(21, N)})
    pr = precision_recall(gt_one_per_frame(), pred, threshold=1.5)
    # every threshold is 0.5 and keeps all predictions: precision 21/41 at 21 samples
    assert pr.thresholds == [0.5] * 21
    assert pr.ap_r41 == pytest.approx(21 * 21 / 41 / 41)


def test_dontcare_region_ignores_predictions():
    gt = {f: [car(f), car(f, x1=800.0, w=200.0, h=100.0, type="DontCare")] for f in range(N)}
    inside = {
        f: [car(f, score=0.5), car(f, x1=850.0, loc=(9, 1.6, 50), score=0.9)] for f in range(N)
    }
    for crit, thr in (("centre_distance", 1.5), ("iou2d", 0.5), ("iou2d", 0.7)):
        assert precision_recall(gt, inside, criterion=crit, threshold=thr).ap_r41 == 1.0
    # the same false positives without the DontCare rows halve the precision
    gt_plain = {f: [car(f)] for f in range(N)}
    assert precision_recall(gt_plain, inside).ap_r41 == pytest.approx(0.5)
    # mostly outside the DontCare box (intersection over its own area 0.25): a false positive
    outside = {
        f: [car(f, score=0.5), car(f, x1=950.0, loc=(9, 1.6, 50), score=0.9)] for f in range(N)
    }
    assert precision_recall(gt, outside).ap_r41 == pytest.approx(0.5)


def test_difficulty_filtering():
    # an easy car and a car that is only moderate (occluded 1, 30 px high) per frame
    gt = {f: [car(f), car(f, x1=400.0, h=30.0, occ=1, loc=(8.0, 1.6, 30.0))] for f in range(N)}
    pred = {
        f: [car(f, score=0.5 + 0.01 * f), car(f, x1=400.0, h=30.0, loc=(8.0, 1.6, 30.0), score=0.9)]
        for f in range(N)
    }
    easy = precision_recall(gt, pred, difficulty="easy")
    moderate = precision_recall(gt, pred, difficulty="moderate")
    assert easy.num_gt == N and moderate.num_gt == 2 * N
    assert easy.ap_r41 == 1.0 and moderate.ap_r41 == 1.0
    # missing the moderate-only car costs nothing in easy, half the recall in moderate
    only_easy = {f: [pred[f][0]] for f in range(N)}
    assert precision_recall(gt, only_easy, difficulty="easy").ap_r41 == 1.0
    half = precision_recall(gt, only_easy, difficulty="moderate")
    # recall reaches 41/82 = 0.5 at precision 1: the samples at recall 0, 1/40, .., 20/40
    assert half.max_recall == 0.5
    np.testing.assert_array_equal(half.precision, [1.0] * 21 + [0.0] * 20)
    # a 50 px car with occlusion 1 / truncation 0.2 is outside easy: matching it is no FP there
    gt2 = {
        f: [
            car(f),
            car(f, x1=400.0, occ=1, loc=(8.0, 1.6, 30.0)),
            car(f, x1=600.0, trunc=0.2, loc=(16.0, 1.6, 30.0)),
        ]
        for f in range(N)
    }
    pred2 = {
        f: [
            car(f, score=0.5),
            car(f, x1=400.0, loc=(8.0, 1.6, 30.0), score=0.9),
            car(f, x1=600.0, loc=(16.0, 1.6, 30.0), score=0.9),
        ]
        for f in range(N)
    }
    r = precision_recall(gt2, pred2, difficulty="easy", criterion="iou2d", threshold=0.7)
    assert r.num_gt == N and r.ap_r41 == 1.0
    assert precision_recall(gt2, pred2, difficulty="hard").num_gt == 3 * N
    # the server code (evaluate_object.cpp) ignores gt exactly at the minimum height (<=):
    # 40 px is not easy, 40.5 px is; 25 px is not moderate
    assert precision_recall({0: [car(h=40.0)]}, {}, difficulty="easy").num_gt == 0
    assert precision_recall({0: [car(h=40.5)]}, {}, difficulty="easy").num_gt == 1
    assert precision_recall({0: [car(h=25.0)]}, {}, difficulty="moderate").num_gt == 0
    # a prediction exactly at the minimum height still counts (< for predictions): a 40 px
    # false positive lowers the easy precision
    gt3 = {0: [car(h=50.0)]}
    pred3 = {0: [car(h=50.0, score=0.5), car(x1=400.0, h=40.0, score=0.9)]}
    r3 = precision_recall(gt3, pred3, difficulty="easy", criterion="iou2d", threshold=0.7)
    assert r3.tp_fp_fn.tolist() == [[1, 1, 0]]


def test_van_ignored_other_class_not():
    gt = {f: [car(f), car(f, x1=400.0, loc=(8.0, 1.6, 30.0), type="Van")] for f in range(N)}
    pred = {
        f: [car(f, score=0.5), car(f, x1=400.0, loc=(8.0, 1.6, 30.0), score=0.9)] for f in range(N)
    }
    assert precision_recall(gt, pred).num_gt == N
    assert precision_recall(gt, pred).ap_r41 == 1.0
    truck = {f: [car(f), car(f, x1=400.0, loc=(8.0, 1.6, 30.0), type="Truck")] for f in range(N)}
    assert precision_recall(truck, pred).ap_r41 == pytest.approx(0.5)
    # predictions of another class are not evaluated at all
    ped = {f: [car(f, score=0.5), far(f, 0.9).with_(type="Pedestrian")] for f in range(N)}
    assert precision_recall(gt_one_per_frame(), ped).ap_r41 == 1.0


def test_centre_of_mass_convention():
    """A prediction whose centre of mass sits at the ground truth's bottom centre (h = 2 m) is
    1 m away: it fails at d = 0.5 m and passes at d >= h/2."""
    gt = {f: [car(f, loc=(0.0, 2.0, 20.0), dims=(2.0, 1.8, 5.0))] for f in range(N)}
    pred = {f: [car(f, loc=(0.0, 3.0, 20.0), dims=(2.0, 1.8, 5.0), score=0.5)] for f in range(N)}
    assert centre_distances(pred[0], gt[0])[0, 0] == pytest.approx(1.0)
    res = localisation_ap(gt, pred, distances=(0.5, 1.0, 1.5), difficulties=("moderate",))
    aps = {d: r["ap_r41"] for d, r in res["moderate"].items()}
    assert aps == {0.5: 0.0, 1.0: 1.0, 1.5: 1.0}
    # the same prediction reported with its true bottom centre passes at 0.5 m
    ok = {f: [car(f, loc=(0.0, 2.0, 20.0), dims=(2.0, 1.8, 5.0), score=0.5)] for f in range(N)}
    assert localisation_ap(gt, ok, distances=(0.5,))["moderate"][0.5]["ap_r41"] == 1.0


def test_iou_thresholds():
    gt = gt_one_per_frame()
    # shifted by 25 px: IoU = 75 * 50 / (2 * 5000 - 75 * 50) = 0.6
    pred = {f: [car(f, x1=125.0, score=0.5)] for f in range(N)}
    res = detection_ap_2d(gt, pred, difficulties=("moderate",))["moderate"]
    assert res[0.5]["ap_r41"] == 1.0 and res[0.7]["ap_r41"] == 0.0
    assert voc07_ap(gt, pred, iou=0.5) == pytest.approx(1.0)
    assert voc07_ap(gt, pred, iou=0.7) == 0.0


def test_voc07_duplicates_are_false_positives():
    gt = gt_one_per_frame()
    pred = {f: [car(f, score=0.9), car(f, x1=102.0, score=0.1)] for f in range(N)}
    # all 40 TPs rank first (recall 1 at precision 1): duplicates come after
    assert voc07_ap(gt, pred) == pytest.approx(1.0)
    pred = {f: [car(f, score=0.1), car(f, x1=102.0, score=0.9)] for f in range(N)}
    assert voc07_ap(gt, pred) == pytest.approx(1.0)  # the duplicate is the TP now


def test_orientation_accuracy_and_confusion():
    q = math.pi / 4
    gt = {
        0: [
            car(0, alpha=0.0),
            car(0, x1=300, alpha=2 * q),
            car(0, x1=500, alpha=q),
            car(0, x1=700, alpha=3.1),
        ]
    }
    pred = {
        0: [
            car(0, alpha=0.1, score=1),
            car(0, x1=300, alpha=-2 * q, score=1),
            car(0, x1=500, alpha=3 * q, score=1),
            car(0, x1=700, alpha=-0.05, score=1),
            car(0, x1=1000, alpha=0.0, score=1),
        ]
    }  # the last one matches nothing
    res = orientation_accuracy(gt, pred)
    assert res.n_pairs == 4
    assert res.accuracy == pytest.approx(3 / 4)
    expected = np.zeros((4, 4), int)
    expected[0, 0] = 2  # 0 -> 0.1 and 3.1 (folds near pi: bin 0) -> -0.05
    expected[2, 2] = 1  # pi/2 and -pi/2 fold to the same bin
    expected[1, 3] = 1
    np.testing.assert_array_equal(res.confusion, expected)
    # a label without an angle (KITTI's -10: 2D-only labels) is matched, not counted
    gt[0].append(car(0, x1=1000, alpha=-10.0))
    res = orientation_accuracy(gt, pred)
    assert res.n_pairs == 4 and res.accuracy == pytest.approx(3 / 4)
    np.testing.assert_array_equal(res.confusion, expected)


def test_labels_against_themselves(kitti_tracking_root):
    """AP 1 on real labels scored against themselves. At 10 m the devkit's file-order greedy
    matching lets a ground truth take a neighbouring car's prediction (an ignored Van's, or one
    outside the difficulty), so 10 m only has to come close to 1."""
    gt = read_tracking_labels(kitti_tracking_root / "label_02" / "0006.txt")
    far = localisation_ap(gt, gt, distances=(10.0,))
    for diff, by_thr in far.items():
        assert by_thr[10.0]["ap_r41"] >= 0.9, diff
    for res in (
        localisation_ap(gt, gt, distances=(1.5, 3.0, 5.0)),
        detection_ap_2d(gt, gt),
    ):
        for diff, by_thr in res.items():
            for thr, r in by_thr.items():
                assert r["num_gt"] > 0, diff
                assert (r["ap_r41"], r["ap_r11"], r["ap_r40"]) == (1.0, 1.0, 1.0), (diff, thr)
    assert orientation_accuracy(gt, gt).accuracy == 1.0
