"""Overlap of axis-aligned 2D boxes ``(x1, y1, x2, y2)`` in pixels (continuous coordinates).

Shared by the detector (NMS, validation), the tracker (2D IoU association cost) and the
evaluator (KITTI matching and DontCare rules). Degenerate boxes have area 0; boxes with NaN
coordinates overlap nothing.
"""

from __future__ import annotations

import numpy as np


def _intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    iw = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    ih = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    return np.clip(iw, 0.0, None) * np.clip(ih, 0.0, None)


def _area(a: np.ndarray) -> np.ndarray:
    return np.clip(a[:, 2] - a[:, 0], 0.0, None) * np.clip(a[:, 3] - a[:, 1], 0.0, None)


def iou_2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise intersection over union (N, M) of boxes ``a`` (N, 4) and ``b`` (M, 4)."""
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    inter = _intersection(a, b)
    union = _area(a)[:, None] + _area(b)[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0.0, inter / union, 0.0)


def overlap_over_first(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise intersection over the area of the *first* box (N, M): the KITTI devkits'
    DontCare criterion (a box lies in a DontCare region when this exceeds 0.5)."""
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    inter = _intersection(a, b)
    area = _area(a)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(area > 0.0, inter / area, 0.0)
