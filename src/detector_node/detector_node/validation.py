"""A simple 2D AP (VOC all-point interpolation) and orientation accuracy, for the per-epoch
validation of ``detector_train``. Detections whose best match is a DontCare region (intersection
over detection area > 0.5) are ignored. The project-wide evaluator with KITTI's difficulty rules
is eval_node.detection_metrics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from vehicle_common.box2d import overlap_over_first

from .boxes import iou_matrix


@dataclass
class FrameResult:
    """Detections and ground truth of one frame (same pixel frame)."""

    det_boxes: np.ndarray  # (N, 4)
    det_scores: np.ndarray  # (N,)
    det_bins: np.ndarray  # (N,)
    gt_boxes: np.ndarray  # (M, 4)
    gt_bins: np.ndarray  # (M,)
    dontcare: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))


@dataclass
class ApResult:
    """AP at one IoU threshold, orientation accuracy of matched detections, 4x4 confusion
    (rows = true bin, columns = predicted bin)."""

    ap: float
    iou_threshold: float
    num_gt: int
    num_det: int
    orientation_accuracy: float
    confusion: np.ndarray


def evaluate_frames(frames: list[FrameResult], iou_threshold: float = 0.5) -> ApResult:
    """Greedy matching per frame by descending score, then AP over all frames."""
    records = []  # (score, tp, ignored)
    confusion = np.zeros((4, 4), dtype=np.int64)
    num_gt = 0
    for f in frames:
        num_gt += len(f.gt_boxes)
        order = np.argsort(-f.det_scores, kind="stable")
        ious = iou_matrix(f.det_boxes, f.gt_boxes) if len(f.gt_boxes) else np.zeros((len(order), 0))
        ioa = overlap_over_first(f.det_boxes, f.dontcare)
        taken = np.zeros(len(f.gt_boxes), bool)
        for i in order:
            best, best_iou = -1, iou_threshold
            for j in range(len(f.gt_boxes)):
                if not taken[j] and ious[i, j] >= best_iou:
                    best, best_iou = j, ious[i, j]
            if best >= 0:
                taken[best] = True
                records.append((f.det_scores[i], 1, 0))
                confusion[int(f.gt_bins[best]), int(f.det_bins[i])] += 1
            elif ioa.shape[1] and ioa[i].max() > 0.5:
                continue  # on a DontCare region: neither TP nor FP
            else:
                records.append((f.det_scores[i], 0, 0))
    if not records or num_gt == 0:
        ap = 0.0
    else:
        rec = sorted(records, key=lambda r: -r[0])
        tp = np.cumsum([r[1] for r in rec])
        fp = np.cumsum([1 - r[1] for r in rec])
        recall = tp / num_gt
        precision = tp / np.maximum(tp + fp, 1e-9)
        mrec = np.concatenate([[0.0], recall, [1.0]])
        mpre = np.concatenate([[0.0], precision, [0.0]])
        for k in range(len(mpre) - 2, -1, -1):
            mpre[k] = max(mpre[k], mpre[k + 1])
        idx = np.nonzero(mrec[1:] != mrec[:-1])[0]
        ap = float(np.sum((mrec[idx + 1] - mrec[idx]) * mpre[idx + 1]))
    matched = confusion.sum()
    acc = float(np.trace(confusion) / matched) if matched else 0.0
    return ApResult(ap, iou_threshold, num_gt, len(records), acc, confusion)
