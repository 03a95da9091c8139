"""YOLOv2 training loss with orientation classes and DontCare-aware background term."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch.nn import functional as F

from .boxes import decode_raw, encode_box, iou_matrix_torch, shape_iou
from .model import DetectorConfig, split_output


@dataclass
class LossWeights:
    """Weights of the loss terms."""

    coord: float = 5.0
    obj: float = 5.0
    noobj: float = 1.0
    orientation: float = 1.0
    ignore_iou: float = 0.6
    #: optional per-bin weights of the orientation cross-entropy (e.g. against class imbalance)
    orientation_bin_weights: tuple[float, float, float, float] | None = None


def build_targets(samples_boxes, samples_bins, config: DetectorConfig):
    """Assign every box to the cell of its centre and the anchor of best shape IoU.

    Returns (mask (B, A, H, W) bool, box targets (B, A, H, W, 4) (off_x, off_y, tw, th),
    scale weights (B, A, H, W) = 2 - w*h/(W*H), orientation targets (B, A, H, W) long, -1 =
    unknown orientation, ignored by the loss).
    """
    gh, gw = config.grid
    a = config.num_anchors
    b = len(samples_boxes)
    anchors = np.array(config.anchors)
    stride = (config.input_width / gw, config.input_height / gh)
    mask = np.zeros((b, a, gh, gw), bool)
    tbox = np.zeros((b, a, gh, gw, 4), np.float32)
    wscale = np.zeros((b, a, gh, gw), np.float32)
    tbin = np.zeros((b, a, gh, gw), np.int64)
    area = config.input_width * config.input_height
    for i, (boxes, bins) in enumerate(zip(samples_boxes, samples_bins, strict=True)):
        if not len(boxes):
            continue
        wh = np.stack([boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]], 1)
        best = np.argmax(shape_iou(wh, anchors), axis=1)
        for box, k, obin in zip(boxes, best, bins, strict=True):
            gx, gy, t = encode_box(box, anchors[k], stride)
            gx, gy = min(max(gx, 0), gw - 1), min(max(gy, 0), gh - 1)
            t[0], t[1] = np.clip(t[0], 0.0, 1.0), np.clip(t[1], 0.0, 1.0)
            mask[i, k, gy, gx] = True
            tbox[i, k, gy, gx] = t
            wscale[i, k, gy, gx] = 2.0 - (box[2] - box[0]) * (box[3] - box[1]) / area
            tbin[i, k, gy, gx] = obin
    return mask, tbox, wscale, tbin


@torch.no_grad()
def _ignored(out, anchors, stride, samples_boxes, samples_dontcare, ignore_iou: float):
    """(B, A, H, W) True for the anchors whose predicted box overlaps a ground-truth box with
    IoU > ``ignore_iou`` or whose predicted centre lies in a DontCare region."""
    dev = out.device
    pred = decode_raw(out[:, :, :4].detach(), anchors, stride)  # (B, A, H, W, 4)
    ignore = torch.zeros(pred.shape[:-1], dtype=torch.bool, device=dev)
    for i in range(out.shape[0]):
        p = pred[i].reshape(-1, 4)
        flags = torch.zeros(p.shape[0], dtype=torch.bool, device=dev)
        if len(samples_boxes[i]):
            gt = torch.as_tensor(samples_boxes[i], dtype=p.dtype, device=dev)
            flags |= iou_matrix_torch(p, gt).max(dim=1).values > ignore_iou
        if len(samples_dontcare[i]):
            dc = torch.as_tensor(samples_dontcare[i], dtype=p.dtype, device=dev)
            cx, cy = (p[:, 0] + p[:, 2]) / 2, (p[:, 1] + p[:, 3]) / 2
            inside = (
                (cx[:, None] >= dc[None, :, 0])
                & (cx[:, None] <= dc[None, :, 2])
                & (cy[:, None] >= dc[None, :, 1])
                & (cy[:, None] <= dc[None, :, 3])
            )
            flags |= inside.any(dim=1)
        ignore[i] = flags.view(ignore[i].shape)
    return ignore


def _positive_losses(sel, tb, ws, tbin, bin_weights, b: int):
    """(xy, wh, objectness, orientation) losses of the responsible anchors' outputs ``sel``
    (N, 9) against their targets, each summed and divided by the batch size ``b``."""
    l_xy = (((torch.sigmoid(sel[:, :2]) - tb[:, :2]) ** 2).sum(1) * ws).sum() / b
    l_wh = (((sel[:, 2:4] - tb[:, 2:4]) ** 2).sum(1) * ws).sum() / b
    l_obj = (
        F.binary_cross_entropy_with_logits(sel[:, 4], torch.ones_like(sel[:, 4]), reduction="sum")
        / b
    )
    bw = (
        torch.tensor(bin_weights, dtype=sel.dtype, device=sel.device)
        if bin_weights is not None
        else None
    )
    l_ori = F.cross_entropy(sel[:, 5:], tbin, weight=bw, ignore_index=-1, reduction="sum") / b
    return l_xy, l_wh, l_obj, l_ori


def detection_loss(
    raw: torch.Tensor,
    samples_boxes: list[np.ndarray],
    samples_bins: list[np.ndarray],
    samples_dontcare: list[np.ndarray],
    config: DetectorConfig,
    weights: LossWeights | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Loss of a batch, summed over anchors and averaged over images; also its terms.

    Background (objectness -> 0) is not penalised for anchors whose predicted box overlaps a
    ground-truth box with IoU > ``ignore_iou`` or whose predicted centre lies in a DontCare region.
    """
    w = weights or LossWeights()
    dev = raw.device
    out = split_output(raw, config.num_anchors)  # (B, A, 9, H, W)
    b = out.shape[0]
    gh, gw = config.grid
    stride = (config.input_width / gw, config.input_height / gh)
    mask, tbox, wscale, tbin = build_targets(samples_boxes, samples_bins, config)
    mask_t = torch.from_numpy(mask).to(dev)
    tbox_t = torch.from_numpy(tbox).to(dev)
    wscale_t = torch.from_numpy(wscale).to(dev)
    tbin_t = torch.from_numpy(tbin).to(dev)
    anchors = torch.tensor(config.anchors, dtype=raw.dtype, device=dev)

    obj_logit = out[:, :, 4]
    ignore = _ignored(out, anchors, stride, samples_boxes, samples_dontcare, w.ignore_iou)
    noobj_mask = ~mask_t & ~ignore
    zeros = torch.zeros_like(obj_logit)
    l_noobj = F.binary_cross_entropy_with_logits(obj_logit, zeros, reduction="none")
    l_noobj = (l_noobj * noobj_mask).sum() / b
    if mask_t.any():
        sel = out.permute(0, 1, 3, 4, 2)[mask_t]  # (N, 9)
        l_xy, l_wh, l_obj, l_ori = _positive_losses(
            sel, tbox_t[mask_t], wscale_t[mask_t], tbin_t[mask_t], w.orientation_bin_weights, b
        )
    else:
        l_xy = l_wh = l_obj = l_ori = raw.sum() * 0.0
    total = w.coord * (l_xy + l_wh) + w.obj * l_obj + w.noobj * l_noobj + w.orientation * l_ori
    terms = {
        "box": float((l_xy + l_wh).detach()),
        "obj": float(l_obj.detach()),
        "noobj": float(l_noobj.detach()),
        "ori": float(l_ori.detach()),
    }
    return total, terms
