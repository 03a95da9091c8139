"""Box geometry for the detector: IoU, YOLOv2 encoding/decoding and class-agnostic NMS.

Boxes are (x1, y1, x2, y2) in pixels. The network predicts, per grid cell (gx, gy) and anchor
(aw, ah) [input px], raw values (tx, ty, tw, th): centre = ((sigmoid(tx) + gx) * stride_x,
(sigmoid(ty) + gy) * stride_y), size = (aw * exp(tw), ah * exp(th)).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from vehicle_common.box2d import iou_2d as iou_matrix

if TYPE_CHECKING:  # torch only where tensors are decoded: nms runs without it
    import torch


def iou_matrix_torch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Torch version of :func:`vehicle_common.box2d.iou_2d` (no gradients needed)."""
    import torch

    lt = torch.maximum(a[:, None, :2], b[None, :, :2])
    rb = torch.minimum(a[:, None, 2:], b[None, :, 2:])
    wh = (rb - lt).clamp(min=0)
    inter = wh[..., 0] * wh[..., 1]
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / (area_a[:, None] + area_b[None, :] - inter).clamp(min=1e-9)


def shape_iou(wh: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """IoU of boxes (N, 2) and anchors (K, 2) given by width/height only (centres aligned)."""
    wh = np.asarray(wh, dtype=float).reshape(-1, 2)
    anchors = np.asarray(anchors, dtype=float).reshape(-1, 2)
    inter = np.minimum(wh[:, None, 0], anchors[None, :, 0]) * np.minimum(
        wh[:, None, 1], anchors[None, :, 1]
    )
    union = (wh[:, 0] * wh[:, 1])[:, None] + (anchors[:, 0] * anchors[:, 1])[None, :] - inter
    return inter / np.maximum(union, 1e-12)


def encode_box(
    box: np.ndarray, anchor: np.ndarray, stride: tuple[float, float]
) -> tuple[int, int, np.ndarray]:
    """Target of one box for one anchor: grid cell (gx, gy) and (off_x, off_y, tw, th).

    ``off_*`` in [0, 1) is the centre's position inside the cell (what sigmoid(t) must reach);
    ``tw, th`` are log size ratios to the anchor.
    """
    x1, y1, x2, y2 = (float(v) for v in box)
    cx, cy = (x1 + x2) / 2 / stride[0], (y1 + y2) / 2 / stride[1]
    gx, gy = int(np.floor(cx)), int(np.floor(cy))
    tw = np.log(max(x2 - x1, 1e-6) / anchor[0])
    th = np.log(max(y2 - y1, 1e-6) / anchor[1])
    return gx, gy, np.array([cx - gx, cy - gy, tw, th])


def decode_raw(
    raw: torch.Tensor, anchors: torch.Tensor, stride: tuple[float, float]
) -> torch.Tensor:
    """Decode raw box outputs (B, A, 4, H, W) into boxes (B, A, H, W, 4) (x1, y1, x2, y2) px."""
    import torch

    _, _, _, h, w = raw.shape
    gy, gx = torch.meshgrid(
        torch.arange(h, device=raw.device, dtype=raw.dtype),
        torch.arange(w, device=raw.device, dtype=raw.dtype),
        indexing="ij",
    )
    cx = (torch.sigmoid(raw[:, :, 0]) + gx) * stride[0]
    cy = (torch.sigmoid(raw[:, :, 1]) + gy) * stride[1]
    bw = anchors[None, :, 0, None, None] * torch.exp(raw[:, :, 2].clamp(max=8.0))
    bh = anchors[None, :, 1, None, None] * torch.exp(raw[:, :, 3].clamp(max=8.0))
    return torch.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], dim=-1)


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Class-agnostic greedy non-maximum suppression; indices kept, by descending score."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    order = np.argsort(-np.asarray(scores, dtype=float), kind="stable")
    keep: list[int] = []
    while order.size:
        i = int(order[0])
        keep.append(i)
        if order.size == 1:
            break
        ious = iou_matrix(boxes[i : i + 1], boxes[order[1:]])[0]
        order = order[1:][ious <= iou_threshold]
    return np.array(keep, dtype=np.int64)
