"""Tracking metrics: rotated 3D IoU, CLEAR-MOT under the KITTI devkit rules, sAMOTA, HOTA."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eval_node.tracking_metrics import (
    HOTA_ALPHAS,
    evaluate_tracking,
    evaluate_tracking_dirs,
    iou_3d,
    match_tracks,
)
from vehicle_common.box3d import projected_bbox
from vehicle_common.kitti import (
    KittiFormatError,
    KittiObject,
    stereo_calibration,
    write_calib,
    write_tracking_labels,
)


def box(
    frame,
    tid,
    x1=100.0,
    y1=100.0,
    w=100.0,
    h=50.0,
    score=None,
    type="Car",
    occ=0,
    trunc=0.0,
    loc=(0.0, 1.6, 20.0),
):
    return KittiObject(
        type=type,
        truncated=trunc,
        occluded=occ,
        alpha=0.0,
        bbox=(x1, y1, x1 + w, y1 + h),
        dimensions=(1.5, 1.6, 4.0),
        location=loc,
        rotation_y=0.0,
        frame=frame,
        track_id=tid,
        score=score,
    )


def box3d(dims=(1.5, 1.6, 4.0), loc=(1.0, 1.5, 10.0), ry=0.3):
    return KittiObject("Car", dimensions=dims, location=loc, rotation_y=ry)


# ----------------------------------------------------------------------------- 3D IoU


def test_iou_3d_known_boxes():
    a = box3d()
    assert iou_3d(a, a) == 1.0  # exactly, not slightly below as in the reference code
    # the same box turned by 90 deg: footprints 4 x 1.6 crossing -> 1.6^2 / (2*6.4 - 1.6^2)
    assert iou_3d(a, a.with_(rotation_y=0.3 + math.pi / 2)) == pytest.approx(0.25)
    # turned by 180 deg: the same box
    assert iou_3d(a, a.with_(rotation_y=0.3 + math.pi)) == pytest.approx(1.0)
    # shifted by half its length along its own axis: 1/3
    c, s = math.cos(0.3), math.sin(0.3)
    shifted = a.with_(location=(1.0 + 2.0 * c, 1.5, 10.0 - 2.0 * s))
    assert iou_3d(a, shifted) == pytest.approx(1 / 3)
    # shifted down by half its height: 1/3
    assert iou_3d(a, a.with_(location=(1.0, 1.5 + 0.75, 10.0))) == pytest.approx(1 / 3)
    # a 2 x 2 footprint and itself turned by 45 deg: a regular octagon, IoU = 1/sqrt(2)
    sq = box3d(dims=(1.0, 2.0, 2.0), ry=0.0)
    assert iou_3d(sq, sq.with_(rotation_y=math.pi / 4)) == pytest.approx(1 / math.sqrt(2))
    # disjoint, stacked, invalid size
    assert iou_3d(a, a.with_(location=(10.0, 1.5, 10.0))) == 0.0
    assert iou_3d(a, a.with_(location=(1.0, 1.5 - 1.5, 10.0))) == 0.0
    assert iou_3d(a, a.with_(dimensions=(-1.0, -1.0, -1.0))) == 0.0


# ----------------------------------------------------------------------------- CLEAR-MOT


def id_switch_and_fragment_sequence(fp_score=None, score=None):
    """Two ground-truth cars over 6 frames. Car 0 is tracked as id 10 in frames 0-2 and id 11 in
    frames 3-5 with a 20 px offset (IoU 80/120 = 2/3); car 1 is tracked exactly as id 20, missed
    in frame 2. Frame 4 has a false positive (id 30)."""
    gt, pred = {}, {}
    for f in range(6):
        gt[f] = [box(f, 0), box(f, 1, x1=500.0)]
        pred[f] = [box(f, 10 if f < 3 else 11, x1=120.0, score=score)]
        if f != 2:
            pred[f].append(box(f, 20, x1=500.0, score=score))
        if f == 4:
            pred[f].append(box(f, 30, x1=900.0, score=fp_score))
    return gt, pred


def test_clear_mot_id_switch_and_fragmentation():
    gt, pred = id_switch_and_fragment_sequence()
    m = evaluate_tracking(gt, pred)
    # TP 6 + 5, FN 1 (frame 2), FP 1; the devkit counts the id switch 10 -> 11 as an ID switch
    # and a fragmentation, and the gap of car 1 as a fragmentation
    assert (m["tp"], m["fn"], m["fp"], m["idsw"], m["frag"]) == (11, 1, 1, 1, 2)
    assert m["mota"] == pytest.approx(1 - 3 / 12)
    assert m["motp"] == pytest.approx((6 * 2 / 3 + 5 * 1.0) / 11)
    assert (m["mt"], m["pt"], m["ml"]) == (2, 0, 0)  # 6/6 and 5/6 > 80 %
    assert m["recall"] == pytest.approx(11 / 12) and m["precision"] == pytest.approx(11 / 12)
    # all scores equal: 11 TP scores -> 11 sample thresholds, the first dropped: 10 recall
    # points r = 1/40 .. 10/40, each with 3 errors: sMOTA_r = clip(1 - (3 - (1-r) 12)/(12 r)) = 1
    assert m["samota"] == pytest.approx(10 / 40)
    assert m["amota"] == pytest.approx(10 * 0.75 / 40)
    assert m["amotp"] == pytest.approx(10 * m["motp"] / 40)


def test_score_threshold_drops_low_scoring_false_positive():
    gt, pred = id_switch_and_fragment_sequence(fp_score=0.1, score=0.9)
    m = evaluate_tracking(gt, pred)
    assert m["all_rows"]["mota"] == pytest.approx(0.75)
    assert m["score_threshold"] == 0.9
    assert (m["fp"], m["fn"], m["idsw"]) == (0, 1, 1)
    assert m["mota"] == pytest.approx(1 - 2 / 12)


def test_track_mean_scores_and_rows_without_id():
    """A false track with row scores 0.95 and 0.05 has the mean 0.5: the threshold 0.9 (all TP
    scores) drops it whole under AB3DMOT's rule, but keeps its 0.95 row with row scores."""
    gt = {f: [box(f, 0)] for f in range(4)}
    pred = {f: [box(f, 1, score=0.9)] for f in range(4)}
    pred[0].append(box(0, 2, x1=600.0, score=0.95))
    pred[1].append(box(1, 2, x1=600.0, score=0.05))
    pred[2].append(box(2, -1, x1=900.0, score=0.99))  # no track id: dropped
    m = evaluate_tracking(gt, pred, hota=False)
    assert (m["score_threshold"], m["fp"], m["mota"]) == (0.9, 0, 1.0)
    assert m["all_rows"]["fp"] == 2
    m = evaluate_tracking(gt, pred, hota=False, score_mode="row")
    assert (m["score_threshold"], m["fp"], m["mota"]) == (0.9, 1, 0.75)


def test_id_switch_across_gap_is_fragmentation_only():
    gt = {f: [box(f, 0)] for f in range(5)}
    pred = {f: [box(f, 1 if f < 2 else 2)] for f in (0, 1, 3, 4)}
    m = evaluate_tracking(gt, pred, hota=False)
    assert (m["idsw"], m["frag"], m["fn"], m["tp"]) == (0, 1, 1, 4)
    # tracked in 1 frame of 5 (20 %: partly tracked, ML needs < 20 %) and 1 of 6 (mostly lost)
    pred = {0: [box(0, 1)]}
    m = evaluate_tracking(gt, pred, hota=False)
    assert (m["mt"], m["pt"], m["ml"]) == (0, 1, 0)
    gt[5] = [box(5, 0)]
    m = evaluate_tracking(gt, pred, hota=False)
    assert (m["mt"], m["pt"], m["ml"]) == (0, 0, 1)


def test_ignore_rules():
    gt = {
        0: [
            box(0, 0),  # counted
            box(0, 1, x1=300.0, type="Van"),  # neighbouring class
            box(0, 2, x1=500.0, occ=3),  # too occluded (unmatched: no FN)
            box(0, 3, x1=700.0, trunc=0.1),  # truncated (matched: no TP, no FP)
            box(0, 4, x1=900.0, h=25.0),  # 25 px: counted by the devkit, not by gt_min_height=25
            box(0, -1, x1=1000.0, y1=200.0, w=200.0, h=100.0, type="DontCare"),
            box(0, 5, x1=1100.0, y1=20.0, type="Pedestrian"),
        ]
    }
    pred = {
        0: [
            box(0, 10),  # TP
            box(0, 11, x1=300.0),  # on the Van
            box(0, 13, x1=700.0),  # on the truncated car
            box(0, 14, x1=900.0, h=25.0),  # on the small car (a TP, or ignored with the limit)
            box(0, 15, x1=1050.0, y1=220.0),  # inside the DontCare box
            box(0, 16, x1=300.0, y1=250.0, h=20.0),  # unmatched and 20 px high
            box(0, 17, x1=500.0, y1=300.0, type="Van"),  # unmatched tracker Van
            box(0, 18, x1=1100.0, y1=20.0),  # on the pedestrian: a false positive for Car
        ]
    }
    m = evaluate_tracking(gt, pred)
    assert (m["tp"], m["fp"], m["fn"], m["n_gt"]) == (2, 1, 0, 2)
    assert m["mota"] == 0.5
    assert m["hota"] == pytest.approx(math.sqrt(2 / 3))  # DetA 2/3 (TP 2, FP 1), AssA 1
    m = evaluate_tracking(gt, pred, gt_min_height=25.0)
    assert (m["tp"], m["fp"], m["fn"], m["n_gt"]) == (1, 1, 0, 1)
    assert m["mota"] == 0.0
    assert m["hota"] == pytest.approx(math.sqrt(0.5))  # DetA 1/2 (TP 1, FP 1), AssA 1


def test_motp_includes_ignored_pairs_as_devkit():
    # devkit: MOTP = total_cost / tp, both over every matched pair (ignored ground truth too)
    gt = {0: [box(0, 0), box(0, 1, x1=300.0, type="Van")]}
    pred = {0: [box(0, 10, x1=120.0), box(0, 11, x1=300.0)]}  # IoU 4000/6000 and 1
    m = evaluate_tracking(gt, pred, hota=False)
    assert (m["tp"], m["itp"], m["fp"], m["fn"], m["n_gt"]) == (1, 1, 0, 0, 1)
    assert m["motp"] == pytest.approx((2 / 3 + 1.0) / 2)
    assert m["mota"] == 1.0


def test_3d_similarity_and_match_tracks():
    gt = {0: [box(0, 0)], 1: [box(1, 0)]}
    # same 2D box, 1 m along the box's length (x at yaw 0)
    moved = {f: [box(f, 7, loc=(1.0, 1.6, 20.0))] for f in (0, 1)}
    m2 = evaluate_tracking(gt, moved, hota=False)
    m3 = evaluate_tracking(gt, moved, similarity="iou3d", hota=False)
    assert m2["tp"] == 2 and m2["motp"] == 1.0
    assert m3["tp"] == 2 and m3["motp"] == pytest.approx(3 / 5)  # 3 m of 4 overlap: 3 / (8-3)
    far = {f: [box(f, 7, loc=(2.5, 1.6, 20.0))] for f in (0, 1)}  # 1.5 / 6.5 < 0.25
    assert evaluate_tracking(gt, far, similarity="iou3d", hota=False)["tp"] == 0
    pairs = match_tracks(gt, moved)
    assert [(g.track_id, p.track_id) for g, p in pairs[1]] == [(0, 7)]


# ----------------------------------------------------------------------------- HOTA


def test_hota_identity_split():
    """One car over 4 frames tracked perfectly as id 1 then id 2: DetA 1, AssA 1/2 at every
    alpha (each match's association IoU 2 / (4 + 2 - 2)), HOTA = sqrt(1/2)."""
    gt = {f: [box(f, 0)] for f in range(4)}
    pred = {f: [box(f, 1 if f < 2 else 2)] for f in range(4)}
    m = evaluate_tracking(gt, pred)
    assert m["deta"] == pytest.approx(1.0)
    assert m["assa"] == pytest.approx(0.5)
    assert m["hota"] == pytest.approx(math.sqrt(0.5))
    assert m["loca"] == pytest.approx(1.0)


def test_hota_localisation():
    """IoU 2/3 everywhere: matches count for the 13 alphas 0.05 .. 0.65 only."""
    gt = {f: [box(f, 0)] for f in range(4)}
    pred = {f: [box(f, 1, x1=120.0)] for f in range(4)}
    m = evaluate_tracking(gt, pred)
    n_ok = int((HOTA_ALPHAS <= 2 / 3).sum())
    assert n_ok == 13
    assert m["hota"] == pytest.approx(13 / 19)
    assert m["deta"] == pytest.approx(13 / 19)
    np.testing.assert_allclose(m["hota_per_alpha"], [1.0] * 13 + [0.0] * 6)
    assert m["loca"] == pytest.approx((13 * 2 / 3 + 6 * 1.0) / 19)  # TrackEval: 1 without TP


def test_hota_false_positive_and_negative():
    """A second, never-matched tracker id and an untracked second car: TP 4, FN 4, FP 4 at every
    alpha -> DetA 1/3; AssA 1 -> HOTA sqrt(1/3)."""
    gt = {f: [box(f, 0), box(f, 1, x1=500.0)] for f in range(4)}
    pred = {f: [box(f, 5), box(f, 6, x1=900.0)] for f in range(4)}
    m = evaluate_tracking(gt, pred)
    assert m["hota"] == pytest.approx(math.sqrt(1 / 3))
    assert (m["tp"], m["fp"], m["fn"]) == (4, 4, 4)


# ----------------------------------------------------------------------------- files


def test_evaluate_tracking_dirs_per_sequence_and_total(tmp_path):
    gt_a, pred_a = id_switch_and_fragment_sequence()
    gt_b = {f: [box(f, 0)] for f in range(3)}
    labels, results = tmp_path / "labels", tmp_path / "results"
    write_tracking_labels(labels / "0000.txt", [o for v in gt_a.values() for o in v])
    write_tracking_labels(labels / "0001.txt", [o for v in gt_b.values() for o in v])
    write_tracking_labels(results / "0000.txt", [o for v in pred_a.values() for o in v])
    write_tracking_labels(results / "0001.txt", [o for v in gt_b.values() for o in v])
    r = evaluate_tracking_dirs(results, labels)
    assert set(r["per_sequence"]) == {"0000", "0001"}
    assert r["per_sequence"]["0001"]["mota"] == 1.0
    assert r["per_sequence"]["0000"]["mota"] == pytest.approx(0.75)
    t = r["total"]
    assert (t["tp"], t["fn"], t["fp"], t["idsw"], t["frag"]) == (14, 1, 1, 1, 2)
    assert t["mota"] == pytest.approx(1 - 3 / 15)
    # a listed sequence without a result file is an empty output
    (labels / "0002.txt").write_text("")
    r = evaluate_tracking_dirs(results, labels, seqs=["0001", 2])
    assert r["total"]["mota"] == 1.0 and r["total"]["n_gt"] == 3
    with pytest.raises(KittiFormatError, match="missing"):
        evaluate_tracking_dirs(tmp_path / "missing", labels)
    (results / "0001.txt").write_text("0 1 Car 0 0\n")
    with pytest.raises(KittiFormatError, match="0001.txt"):
        evaluate_tracking_dirs(results, labels)


def test_labels_against_themselves(kitti_tracking_root):
    labels = kitti_tracking_root / "label_02"
    r = evaluate_tracking_dirs(labels, labels, seqs=[12, 6])
    for m in (*r["per_sequence"].values(), r["total"]):
        assert m["n_gt"] > 0
        assert (m["mota"], m["motp"], m["idsw"], m["frag"], m["fp"], m["fn"]) == (
            1.0,
            1.0,
            0,
            0,
            0,
            0,
        )
        assert m["hota"] == pytest.approx(1.0) and m["samota"] == pytest.approx(1.0)
    r3 = evaluate_tracking_dirs(labels, labels, seqs=[12], similarity="iou3d", hota=False)
    assert r3["total"]["mota"] == 1.0 and r3["total"]["motp"] == pytest.approx(1.0)


def test_calib_dir_fills_missing_2d_boxes(tmp_path):
    """Result rows without a 2D box get their 3D box's projection (P2) when calib_dir is given;
    without it they are unmatched and, 0 px high, ignored (the devkit's behaviour)."""
    calib = stereo_calibration(700.0, 700.0, 620.0, 187.0, 0.54)
    write_calib(tmp_path / "calib" / "0000.txt", calib)
    dims, loc, ry = (1.5, 1.6, 4.0), (1.0, 1.6, 15.0), 0.2
    bbox = projected_bbox(calib.P2, dims, loc, ry, (1242, 375))
    gt = [
        KittiObject(
            "Car", bbox=bbox, dimensions=dims, location=loc, rotation_y=ry, frame=f, track_id=0
        )
        for f in range(3)
    ]
    res = [o.with_(bbox=(0.0, 0.0, 0.0, 0.0), track_id=4, score=0.8) for o in gt]
    write_tracking_labels(tmp_path / "labels" / "0000.txt", gt)
    write_tracking_labels(tmp_path / "results" / "0000.txt", res)
    bare = evaluate_tracking_dirs(tmp_path / "results", tmp_path / "labels")["total"]
    assert (bare["tp"], bare["fp"], bare["fn"]) == (0, 0, 3)
    filled = evaluate_tracking_dirs(
        tmp_path / "results", tmp_path / "labels", calib_dir=tmp_path / "calib"
    )["total"]
    assert (filled["tp"], filled["fp"], filled["fn"], filled["mota"]) == (3, 0, 0, 1.0)
    assert filled["motp"] == pytest.approx(1.0, abs=1e-5)  # rows are written with 6 decimals
