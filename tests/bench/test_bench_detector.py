"""tracking_bringup.detector_scoring (bench/bench_detector.py's scores): AP by KITTI occlusion level
and precision at the node's threshold."""

from __future__ import annotations

import math

from vehicle_common.kitti import KittiObject

from tracking_bringup import detector_scoring as bd


def _car(x: float, occluded: int = 0, kind: str = "Car") -> KittiObject:
    return KittiObject(kind, occluded=occluded, alpha=0.0, bbox=(x, 100.0, x + 80.0, 160.0))


def _det(x: float, score: float) -> KittiObject:
    return KittiObject("Car", alpha=0.0, bbox=(x, 100.0, x + 80.0, 160.0), score=score)


N = 40  # frames: AP|R40 needs 40 counted cars to reach every recall sample


def test_occlusion_ap_counts_each_level_alone():
    # the occluded car's detection scores higher; at level 0 it must be neither TP nor FP
    gt = {f: [_car(100, occluded=0), _car(400, occluded=1)] for f in range(N)}
    pred = {f: [_det(400, 0.9), _det(100, 0.5), _det(800, 0.4)] for f in range(N)}
    ap = bd.occlusion_ap(gt, pred)
    # N counted cars each; the false positives at 800 score below every true positive
    assert ap[0]["num_gt"] == N and ap[1]["num_gt"] == N and ap[2]["num_gt"] == 0
    # (the devkit's R40 booking of N equal-score hits gives 0.975; a false positive per true
    # one would give at most 0.5)
    assert ap[0]["0.7"] > 0.95 and ap[1]["0.7"] > 0.95
    assert math.isnan(ap[2]["0.7"])
    # the level-1 cars missed: level 1 drops to 0, level 0 unchanged
    ap = bd.occlusion_ap(gt, {f: [_det(100, 0.5)] for f in range(N)})
    assert ap[0]["0.5"] > 0.95 and ap[1]["0.5"] == 0.0


def test_precision_at_threshold_uses_only_detections_above_it():
    gt = {0: [_car(100), _car(400, kind="Van"), _car(700)]}
    pred = {
        0: [
            _det(100, 0.8),  # true positive
            _det(1000, 0.5),  # false positive (nothing there)
            _det(400, 0.9),  # on the Van: ignored
            _det(700, 0.2),  # would be a true positive, but below the threshold
        ]
    }
    op = bd.precision_at_threshold(gt, pred, 0.3)
    assert (op["tp"], op["fp"], op["fn"]) == (1, 1, 1)
    assert op["precision"] == 0.5 and op["recall"] == 0.5
    op = bd.precision_at_threshold(gt, pred, 0.1)
    assert (op["tp"], op["fp"], op["fn"]) == (2, 1, 0)
