"""Box overlaps used as association costs: 2D IoU with shape similarity, and 3D GIoU of boxes
with size and yaw (the geometry is :mod:`vehicle_common.box3d`'s).

3D boxes here are ``(cx, cy, cz, l, w, h, yaw)``: the centre of the box (camera frame, y down),
length/width/height, yaw about the camera y axis (KITTI rotation_y; length along +x at yaw 0).
"""

from __future__ import annotations

import numpy as np
from vehicle_common.box2d import iou_2d
from vehicle_common.box3d import giou_3d as box3d_giou
from vehicle_common.camera_frames import kitti_from_centre


def shape_similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise shape similarity ``exp(-(|w_a - w_b| / (w_a + w_b) + |h_a - h_b| / (h_a + h_b)))``
    of 2D boxes (N, 4) and (M, 4): 1 for equal sizes."""
    wa, ha = (a[:, 2] - a[:, 0])[:, None], (a[:, 3] - a[:, 1])[:, None]
    wb, hb = (b[:, 2] - b[:, 0])[None, :], (b[:, 3] - b[:, 1])[None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.abs(wa - wb) / (wa + wb) + np.abs(ha - hb) / (ha + hb)
    return np.nan_to_num(np.exp(-d))


def covered_by_tracks(det_boxes: np.ndarray, track_boxes: np.ndarray, max_iou: float) -> np.ndarray:
    """Which detection boxes (N, 4) overlap a track's box (M, 4) by a 2D IoU above ``max_iou``
    (bool (N,)): a birth there would be a second track on a car a track already holds (issue
    #41: duplicates). ``max_iou`` >= 1: none."""
    if max_iou >= 1.0 or len(det_boxes) == 0 or len(track_boxes) == 0:
        return np.zeros(len(det_boxes), bool)
    iou = np.nan_to_num(iou_2d(np.asarray(det_boxes, float), np.asarray(track_boxes, float)))
    return (iou > max_iou).any(axis=1)


def kitti_box(
    box: np.ndarray,
) -> tuple[tuple[float, float, float], tuple[float, float, float], float]:
    """A box ``(cx, cy, cz, l, w, h, yaw)`` as the KITTI ``(dimensions (h, w, l), bottom-centre
    location, rotation_y)`` of :mod:`vehicle_common.box3d` (y down: bottom = cy + h / 2)."""
    cx, cy, cz, l, w, h, yaw = (float(v) for v in box)
    x, y, z = (float(v) for v in kitti_from_centre((cx, cy, cz), h))
    return (h, w, l), (x, y, z), yaw


def giou_3d(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(3D IoU, 3D GIoU) of two boxes ``(cx, cy, cz, l, w, h, yaw)``
    (:func:`vehicle_common.box3d.giou_3d`)."""
    return box3d_giou(kitti_box(a), kitti_box(b))


def giou_3d_matrix(
    a: np.ndarray, b: np.ndarray, candidates: np.ndarray | None = None
) -> np.ndarray:
    """Pairwise 3D GIoU of boxes (N, 7) and (M, 7); pairs not in ``candidates`` (bool (N, M))
    get -1 (the minimum of GIoU)."""
    out = np.full((len(a), len(b)), -1.0)
    pairs = np.nonzero(candidates if candidates is not None else out < 0)
    for i, j in zip(*pairs, strict=True):
        out[i, j] = giou_3d(a[i], b[j])[1]
    return out
