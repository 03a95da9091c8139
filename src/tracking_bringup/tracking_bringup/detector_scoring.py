"""A 2D detector scored on labelled frames, as the benchmarks report it: KITTI devkit AP|R40 per
difficulty and per occlusion level, the all-boxes VOC AP, precision and recall at the node's
score threshold, orientation accuracy (4 bins) with its baselines, and the continuous angle's
error. Shared by ``bench/bench_detector.py`` (the reporting split), ``bench/detector_cv.py`` (the
cross-validation folds), ``bench/bench_detector_cpu.py`` and ``bench/zero_shot_detectors.py``.

It composes the detector package's frame sources and the evaluation package's metrics, so it
lives here, where packages meet (node packages do not import each other). ``detector`` is any
object with ``detect(rgb) -> detections`` and a ``config.positive_types``.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from detector_node.dataset import frames_from_source, label_bin
from detector_node.validation import FrameResult, evaluate_frames
from vehicle_common.kitti import KittiObject, read_png
from vehicle_common.orientation_bins import fold_alpha_signed

from .parameters import graph_values

#: the detector node's ``score_threshold`` in the graph (its parameter file's value)
NODE_SCORE_THRESHOLD = graph_values("vehicle_detector")["score_threshold"]


def _detect_frames(detector, refs) -> tuple[dict, dict, list[FrameResult]]:
    """Run the detector on each frame: (labels, detections as KITTI objects, per frame; the
    frames for the all-boxes VOC AP)."""
    gt, pred, simple = {}, {}, []
    types = detector.config.positive_types
    for i, ref in enumerate(refs):
        dets = detector.detect(read_png(ref.image_path))
        gt[i] = ref.objects
        pred[i] = [
            KittiObject(
                "Car",
                alpha=d.observation_angle,
                bbox=d.box,
                score=d.score,
            )
            for d in dets
        ]
        pos = [o for o in ref.objects if o.type in types]
        simple.append(
            FrameResult(
                det_boxes=np.array([d.box for d in dets]).reshape(-1, 4),
                det_scores=np.array([d.score for d in dets]),
                det_bins=np.array([d.orientation_bin for d in dets], dtype=np.int64),
                gt_boxes=np.array([o.bbox for o in pos]).reshape(-1, 4),
                gt_bins=np.array([label_bin(o.alpha) for o in pos], dtype=np.int64),
                dontcare=np.array([o.bbox for o in ref.objects if o.is_dontcare]).reshape(-1, 4),
            )
        )
    return gt, pred, simple


def _print_ap(kitti: dict, by_occl: dict, op: dict, own: dict) -> None:
    for diff in ("easy", "moderate", "hard"):
        row = kitti[diff]
        print(
            f"  KITTI 2D AP_R40 {diff:8s} IoU0.5 {100 * row[0.5]['ap_r40']:5.1f} %   "
            f"IoU0.7 {100 * row[0.7]['ap_r40']:5.1f} %   (counted GT {row[0.5]['num_gt']})"
        )
    for k, row in by_occl.items():
        print(
            f"  KITTI 2D AP_R40 occlusion {k}   IoU0.5 {100 * row['0.5']:5.1f} %   "
            f"IoU0.7 {100 * row['0.7']:5.1f} %   (counted GT {row['num_gt']}; hard's height "
            "and truncation limits, Cars of other occlusion ignored)"
        )
    print(
        f"  at the node's score threshold {NODE_SCORE_THRESHOLD}: precision "
        f"{100 * op['precision']:5.1f} % ({op['tp']} TP, {op['fp']} FP), recall "
        f"{100 * op['recall']:5.1f} % (IoU > 0.5, KITTI hard rules)"
    )
    print(
        f"  all-boxes VOC AP (Car+Van positives): IoU0.5 {100 * own[0.5].ap:5.1f} %   "
        f"IoU0.7 {100 * own[0.7].ap:5.1f} %"
    )


def _orientation_scores(ori, angle_err) -> tuple[float, float, float]:
    """Print the orientation figures: (majority-bin baseline, balanced accuracy, median
    continuous-angle error [deg])."""
    print(
        f"  orientation accuracy (Car, matched IoU>=0.5): {100 * ori.accuracy:5.1f} % "
        f"over {ori.n_pairs} pairs (paper: 76.8 %)"
    )
    cm = ori.confusion
    rows = cm.sum(axis=1)
    majority = rows.max() / max(cm.sum(), 1)
    balanced = float(np.mean([cm[i, i] / rows[i] for i in range(4) if rows[i]])) if cm.sum() else 0
    print(
        f"  baseline 'always the most frequent true bin': {100 * majority:5.1f} %;  "
        f"balanced accuracy (mean per-bin recall): {100 * balanced:5.1f} %"
    )
    med = float(np.degrees(np.median(angle_err))) if len(angle_err) else math.nan
    print(
        f"  continuous angle (folded mod 180 deg): median error {med:5.1f} deg over "
        f"{len(angle_err)} pairs (bin-only checkpoints: the bin centre)"
    )
    print("  confusion (rows true 0/45/90/135, cols predicted):")
    for r in ori.confusion:
        print("    " + " ".join(f"{v:5d}" for v in r))
    return majority, balanced, med


def evaluate(detector, specs: list[str], label: str) -> dict:
    """Run the detector over every frame of some data sources and score it."""
    from eval_node.detection_metrics import detection_ap_2d, orientation_accuracy

    refs = [r for spec in specs for r in frames_from_source(spec)]
    spec = " + ".join(specs)
    gt, pred, simple = _detect_frames(detector, refs)
    kitti = detection_ap_2d(gt, pred)
    ori = orientation_accuracy(gt, pred, iou=0.5)
    angle_err = angle_errors(gt, pred)
    own = {t: evaluate_frames(simple, t) for t in (0.5, 0.7)}
    by_occl = occlusion_ap(gt, pred)
    op = precision_at_threshold(gt, pred, NODE_SCORE_THRESHOLD)
    n_car = sum(1 for objs in gt.values() for o in objs if o.type == "Car")
    print(f"\n== {label}: {len(refs)} frames, {n_car} Car labels ({spec})")
    _print_ap(kitti, by_occl, op, own)
    majority, balanced, med = _orientation_scores(ori, angle_err)
    return {
        "frames": len(refs),
        "kitti_ap_r40": {d: {str(t): kitti[d][t]["ap_r40"] for t in (0.5, 0.7)} for d in kitti},
        "voc_ap_all": {str(t): own[t].ap for t in own},
        "kitti_ap_r40_by_occlusion": by_occl,
        "at_node_threshold": op,
        "orientation_accuracy": ori.accuracy,
        "orientation_pairs": ori.n_pairs,
        "confusion": ori.confusion.tolist(),
        "orientation_majority_baseline": float(majority),
        "orientation_balanced_accuracy": balanced,
        "median_angle_error_deg": med,
    }


def occlusion_ap(gt: dict, pred: dict, levels=(0, 1, 2)) -> dict[int, dict]:
    """KITTI 2D AP|R40 (Car, IoU 0.5 and 0.7) per KITTI occlusion level: the Cars of level k
    counted under the hard level's height (25 px) and truncation (0.5) limits, the Cars of any
    other occlusion ignored (matching one is neither a true nor a false positive, as a Van).
    ``{k: {"0.5": ap, "0.7": ap, "num_gt": n}}`` (NaN without counted ground truth)."""
    from eval_node.detection_metrics import detection_ap_2d
    from eval_node.difficulty import HARD, Difficulty

    out = {}
    for k in levels:
        level = Difficulty(f"occlusion {k}", HARD.min_height, 2, HARD.max_truncation)
        gt_k = {
            f: [replace(o, type="Van") if o.type == "Car" and o.occluded != k else o for o in objs]
            for f, objs in gt.items()
        }
        row = detection_ap_2d(gt_k, pred, difficulties=[level])[level]
        out[k] = {str(t): row[t]["ap_r40"] for t in (0.5, 0.7)} | {"num_gt": row[0.5]["num_gt"]}
    return out


def precision_at_threshold(gt: dict, pred: dict, threshold: float, iou: float = 0.5) -> dict:
    """Precision and recall of the detections scoring >= ``threshold`` (the node's operating
    point) under the KITTI devkit's rules at the hard level, 2D IoU > ``iou``: a detection on a
    Van, a DontCare region or a Car outside the level, or under 25 px, is neither true nor false."""
    from eval_node.detection_metrics import precision_recall

    kept = {
        f: [replace(o, score=1.0) for o in d if (o.score or 0.0) >= threshold]
        for f, d in pred.items()
    }
    pr = precision_recall(gt, kept, criterion="iou2d", threshold=iou, difficulty="hard")
    if not len(pr.tp_fp_fn):  # no true positive: the devkit samples no threshold
        return {
            "threshold": threshold,
            "tp": 0,
            "fp": -1,
            "fn": pr.num_gt,
            "precision": math.nan,
            "recall": 0.0,
        }
    tp, fp, fn = (int(v) for v in pr.tp_fp_fn[0])
    return {
        "threshold": threshold,
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "precision": tp / (tp + fp) if tp + fp else math.nan,
        "recall": tp / (tp + fn) if tp + fn else math.nan,
    }


def angle_errors(gt: dict, pred: dict) -> np.ndarray:
    """|folded alpha error| [rad] (modulo pi, in [0, pi/2]) of the Car labels with a known alpha
    matched to a detection (2D IoU >= 0.5, Hungarian per frame, as the orientation accuracy)."""
    from eval_node.detection_metrics import match_2d

    errs = []
    for k, objs in gt.items():
        g = [o for o in objs if o.type == "Car"]
        for gi, pi, _ in match_2d(g, pred.get(k, []), 0.5):
            if g[gi].alpha >= -math.pi:
                errs.append(abs(fold_alpha_signed(pred[k][pi].alpha - g[gi].alpha)))
    return np.array(errs)
