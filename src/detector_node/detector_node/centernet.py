"""CenterNet car detector on the pretrained MobileNetV3 CenterNet of ``@vladmandic/human``.

The pretrained graph (TF.js, COCO-80, see :mod:`detector_node.pretrained`) runs through
:class:`~detector_node.tfjs_graph.TfjsGraph` up to its head feature
(``tower_0/CenternetHead/mul``: 128 channels at stride 4). On it sit three heads of the project:

- ``heat``: separable 3x3 conv -> 1 channel, the car centre heat map (logit); initialised from the
  COCO ``car`` channel (index 2) of the graph's class head;
- ``box``: the graph's box head (separable 3x3 conv -> 4 channels, x 16): distances (left, top,
  right, bottom) in input px from the cell position (column x 4, row x 4) to the box edges;
- ``orientation``: a box head (RoI-style): the feature sampled bilinearly at 3x3 points inside a
  box (at 1/6, 3/6, 5/6 of its width and height) plus the box's log aspect ratio and normalised
  centre -> 64 -> ReLU -> 9 values: 4 bin logits (the paper's bins centred on 0/45/90/135 deg),
  4 residuals (one per bin, angle = centre + pi/4 x tanh(residual)) and the log-variance of the
  continuous angle (MultiBin-style, Mousavian et al. 2017); new, zero output at the start.
  Trained on the ground-truth boxes; at inference evaluated on the boxes of the top
  ``ORIENTATION_PEAKS`` heat-map peaks.

Raw output (B, 14, H/4, W/4): [heat logit, l, t, r, b, 4 bin logits, 4 residuals, log-variance];
the 9 orientation values are filled at the evaluated peaks (zero elsewhere).
Input: RGB in [0, 1] (the graph's 0-255 scaling is applied inside).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F
from vehicle_common.orientation_bins import (
    NUM_BINS,
    alpha_to_bin_residual,
    bin_residual_to_alpha,
    fold_alpha_signed,
)

from .centernet_decode import (  # noqa: F401 (the output layout, re-exported)
    BINS,
    BOX,
    HEAT,
    LOGVAR,
    LOGVAR_RANGE,
    MAX_RESIDUAL,
    ORIENTATION_PEAKS,
    ORIENTATION_POINTS,
    OUT_CHANNELS,
    RESIDUALS,
    STRIDE,
    decode_orientation,
)
from .tfjs_graph import TfjsGraph

FEATURE = "tower_0/CenternetHead/mul"
CLS_HEAD = "CenternetHead/centernet_cls_output"
BOX_HEAD = "CenternetHead/centernet_wh_output"
BOX_SCALE = "tower_0/mul/y"
COCO_CAR = 2
FEATURE_CHANNELS = 128
ORIENTATION_HIDDEN = 64


class SeparableHead(nn.Module):
    """Depthwise 3x3 conv (no bias) then pointwise 1x1 conv (TensorFlow's separable_conv2d)."""

    def __init__(self, channels: int, out: int) -> None:
        super().__init__()
        self.depthwise = nn.Conv2d(channels, channels, 3, padding=1, groups=channels, bias=False)
        self.pointwise = nn.Conv2d(channels, out, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.pointwise(self.depthwise(x))

    def load_tf(self, weights: dict[str, np.ndarray], prefix: str, channels=None) -> None:
        """Copy ``prefix``/{depthwise_weights, pointwise_weights, biases} (TF layouts), keeping
        only the output ``channels`` when given."""
        dw = torch.from_numpy(weights[f"{prefix}/depthwise_weights"]).float()
        pw = torch.from_numpy(weights[f"{prefix}/pointwise_weights"]).float()
        b = torch.from_numpy(weights[f"{prefix}/biases"]).float()
        if channels is not None:
            pw, b = pw[..., channels], b[channels]
        with torch.no_grad():
            self.depthwise.weight.copy_(dw.permute(2, 3, 0, 1))
            self.pointwise.weight.copy_(pw.permute(3, 2, 0, 1))
            self.pointwise.bias.copy_(b)


def graph_constants_zero(model: dict) -> dict[str, np.ndarray]:
    """Zero arrays of every constant's declared shape and dtype (to rebuild a graph module whose
    weights then come from a checkpoint's state dict)."""
    out = {}
    for n in model["modelTopology"]["node"]:
        if n["op"] != "Const":
            continue
        t = n["attr"]["value"]["tensor"]
        shape = [int(d["size"]) for d in t.get("tensorShape", {}).get("dim", [])]
        dtype = np.int32 if t.get("dtype") == "DT_INT32" else np.float32
        out[n["name"]] = np.zeros(shape, dtype)
    return out


class CenterNetDetector(nn.Module):
    """The pretrained graph's feature + the car / box / orientation heads (module docstring)."""

    def __init__(self, config, graph_model: dict, weights: dict[str, np.ndarray] | None) -> None:
        super().__init__()
        self.config = config
        zero = weights is None
        if zero:
            weights = graph_constants_zero(graph_model)
        self.graph = TfjsGraph(graph_model, weights, [FEATURE])
        self.topology = {"modelTopology": {"node": self.graph.nodes_used}}
        self.heat = SeparableHead(FEATURE_CHANNELS, 1)
        self.box = SeparableHead(FEATURE_CHANNELS, 4)
        n_in = FEATURE_CHANNELS * ORIENTATION_POINTS**2 + 3
        self.orientation = nn.Sequential(
            nn.Linear(n_in, ORIENTATION_HIDDEN),
            nn.ReLU(inplace=True),
            nn.Linear(ORIENTATION_HIDDEN, 2 * NUM_BINS + 1),
        )
        self.register_buffer("box_scale", torch.tensor(16.0))
        #: (ax, bx, ay, by, log-aspect offset): the orientation head's box geometry for an
        #: input other than the training's (see orientation_at); None = the input is the
        #: training's framing (whole image at the checkpoint's input size)
        self.geo_frame: tuple[float, float, float, float, float] | None = None
        with torch.no_grad():
            self.orientation[-1].weight.zero_()
            self.orientation[-1].bias.zero_()
        if not zero:
            self.heat.load_tf(weights, CLS_HEAD, [COCO_CAR])
            self.box.load_tf(weights, BOX_HEAD)
            self.box_scale.fill_(float(weights[BOX_SCALE]))

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Images (B, 3, H, W) RGB in [0, 1] -> the graph's head feature (B, 128, H/4, W/4)."""
        return self.graph(x * 255.0)[FEATURE]

    def dense(self, f: torch.Tensor) -> torch.Tensor:
        """Feature -> (B, 5, H/4, W/4): heat logit and (l, t, r, b) [input px]."""
        return torch.cat([self.heat(f), self.box(f) * self.box_scale], dim=1)

    def orientation_at(
        self,
        f: torch.Tensor,
        batch: torch.Tensor,
        boxes: torch.Tensor,
        view: torch.Tensor | None = None,
    ):
        """Orientation values (N, 9) of boxes (N, 4) [input px] of images ``batch`` (N,).
        ``view`` (N, 2): where each box was seen, normalised to its frame (training with
        ``--true-view``: a crop moved it in the input, not its viewing ray); None: where it is
        in the input (inference)."""
        if not len(boxes):
            return f.new_zeros((0, 2 * NUM_BINS + 1))
        _, c, gh, gw = f.shape
        frac = (torch.arange(ORIENTATION_POINTS, device=f.device, dtype=f.dtype) + 0.5) / (
            ORIENTATION_POINTS
        )
        x1, y1, x2, y2 = boxes.unbind(1)
        px = x1[:, None] + (x2 - x1)[:, None] * frac[None]  # (N, P)
        py = y1[:, None] + (y2 - y1)[:, None] * frac[None]
        # cell j is at input px STRIDE * j (the box head's convention); normalised for
        # grid_sample with align_corners=False: pixel centre j -> (2j + 1) / size - 1
        gx = (2 * (px / STRIDE) + 1) / gw - 1
        gy = (2 * (py / STRIDE) + 1) / gh - 1
        n = ORIENTATION_POINTS
        grid = torch.stack(
            [gx[:, None, :].expand(-1, n, -1), gy[:, :, None].expand(-1, -1, n)], dim=-1
        ).reshape(-1, n * n, 2)  # (N, P*P, 2), row-major over (y, x) as (P, P)
        # sample each image's boxes from its own feature map (no per-box copy of the map)
        sampled = f.new_empty((len(boxes), c, n * n))
        for i in torch.unique(batch).tolist():
            sel = (batch == i).nonzero()[:, 0]
            out = F.grid_sample(f[i : i + 1], grid[sel][None], align_corners=False)
            sampled[sel] = out[0].permute(1, 0, 2)  # (1, C, Nb, P*P) -> (Nb, C, P*P)
        w, h = (x2 - x1).clamp(min=1), (y2 - y1).clamp(min=1)
        # box geometry as in training: the whole image squashed to the checkpoint's input
        # (normalised centre, log aspect ratio at the training's x / y scale); geo_frame maps
        # another input size or a cropped region of interest onto it (CnnDetector sets it)
        ax, bx, ay, by, aspect = self.geo_frame or (
            1 / (STRIDE * gw),
            0.0,
            1 / (STRIDE * gh),
            0.0,
            0.0,
        )
        if view is None:
            cx, cy = (x1 + x2) / 2 * ax + bx, (y1 + y2) / 2 * ay + by
        else:
            cx, cy = view[:, 0].to(f.dtype), view[:, 1].to(f.dtype)
        geo = torch.stack([torch.log(w / h) + aspect, cx - 0.5, cy - 0.5], dim=1)
        return self.orientation(torch.cat([sampled.flatten(1), geo], dim=1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Images (B, 3, H, W) RGB in [0, 1] -> raw output (B, 14, H/4, W/4), the orientation
        values filled at the top ``ORIENTATION_PEAKS`` heat-map peaks of each image."""
        f = self.features(x)
        return self.raw_from_features(f)

    def raw_from_features(self, f: torch.Tensor, d: torch.Tensor | None = None) -> torch.Tensor:
        """Raw output from the head feature (and its :meth:`dense` output when already
        computed, as the ONNX Runtime backend does)."""
        d = self.dense(f) if d is None else d
        b, _, gh, gw = d.shape
        _, idx = peaks(d, ORIENTATION_PEAKS)  # (B, K)
        k = idx.shape[1]
        batch = torch.arange(b, device=d.device).repeat_interleave(k)
        cells = idx.reshape(-1)
        vals = d.flatten(2)[batch, :, cells]  # (B*K, 5)
        cx, cy = (cells % gw).to(d.dtype) * STRIDE, (cells // gw).to(d.dtype) * STRIDE
        box = torch.stack(
            [cx - vals[:, 1], cy - vals[:, 2], cx + vals[:, 3], cy + vals[:, 4]], dim=1
        )
        box = torch.maximum(
            box, torch.stack([box[:, 0], box[:, 1], box[:, 0] + 1, box[:, 1] + 1], 1)
        )
        ori = self.orientation_at(f, batch, box)  # (B*K, 9)
        extra = d.new_zeros((b, 2 * NUM_BINS + 1, gh * gw))
        extra[batch, :, cells] = ori
        return torch.cat([d, extra.view(b, -1, gh, gw)], dim=1)


# ---------------------------------------------------------------------------------------------
# decoding


def peaks(raw: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Top-``k`` local maxima (3x3) of the heat map of each image: (scores (B, k), flat cell
    indices (B, k))."""
    heat = torch.sigmoid(raw[:, HEAT : HEAT + 1])
    if heat.device.type == "cpu" and not heat.requires_grad:
        # the same 3x3 maximum (edges: over the cells inside the map) 50x faster than max_pool2d
        kernel = np.ones((3, 3), np.uint8)
        maxed = np.stack([cv2.dilate(h, kernel) for h in heat[:, 0].contiguous().numpy()])
        keep = heat == torch.from_numpy(maxed)[:, None]
    else:
        keep = heat == F.max_pool2d(heat, 3, 1, 1)
    flat = (heat * keep).flatten(1)
    k = min(k, flat.shape[1])
    return torch.topk(flat, k, dim=1)


def decode_centernet(
    raw: torch.Tensor,
    config,
    score_threshold: float,
    nms_iou: float,
    scale: tuple[float, float] = (1.0, 1.0),
    max_detections: int = 100,
):
    """Raw output -> :class:`~detector_node.inference.Detection` lists (original px: input px
    divided by ``scale``): heat-map peaks >= ``score_threshold``, boxes from the distances,
    class-agnostic NMS, 4-bin probabilities and the continuous angle with its variance."""
    from .boxes import nms
    from .detection import Detection

    raw = raw.float()
    gw = raw.shape[3]
    scores, idx = peaks(raw, max_detections)
    out = []
    s = np.array([scale[0], scale[1], scale[0], scale[1]])
    for i in range(raw.shape[0]):
        sc = scores[i].cpu().numpy()
        ix = idx[i].cpu().numpy()
        keep = sc >= score_threshold
        sc, ix = sc[keep], ix[keep]
        vals = raw[i].flatten(1)[:, torch.from_numpy(ix).to(raw.device)].T.cpu().numpy()  # (N, 14)
        cx, cy = (ix % gw) * STRIDE, (ix // gw) * STRIDE
        d = vals[:, BOX]
        bx = np.stack([cx - d[:, 0], cy - d[:, 1], cx + d[:, 2], cy + d[:, 3]], 1) / s
        bx[:, [0, 2]] = np.clip(bx[:, [0, 2]], 0, config.input_width / scale[0])
        bx[:, [1, 3]] = np.clip(bx[:, [1, 3]], 0, config.input_height / scale[1])
        valid = (bx[:, 2] > bx[:, 0]) & (bx[:, 3] > bx[:, 1])
        bx, sc, vals = bx[valid], sc[valid], vals[valid]
        probs, bins, angle, var = decode_orientation(
            vals[:, BINS], vals[:, RESIDUALS], vals[:, LOGVAR]
        )
        order = nms(bx, sc, nms_iou)[:max_detections]
        out.append(
            [
                Detection(
                    box=tuple(float(v) for v in bx[j]),
                    score=float(sc[j]),
                    orientation_bin=int(bins[j]),
                    orientation_probs=tuple(float(p) for p in probs[j]),
                    observation_angle=float(angle[j]),
                    observation_angle_variance=float(var[j]),
                )
                for j in order
            ]
        )
    return out


# ---------------------------------------------------------------------------------------------
# training loss


def gaussian_radius(h: float, w: float, min_overlap: float = 0.7) -> float:
    """CenterNet's radius (output cells) within which a shifted box keeps IoU >= min_overlap
    (smallest root of the three corner cases)."""
    b1 = h + w
    c1 = w * h * (1 - min_overlap) / (1 + min_overlap)
    r1 = (b1 + math.sqrt(max(b1**2 - 4 * c1, 0))) / 2
    b2 = 2 * (h + w)
    c2 = (1 - min_overlap) * w * h
    r2 = (b2 + math.sqrt(max(b2**2 - 16 * c2, 0))) / 2
    a3 = 4 * min_overlap
    b3 = -2 * min_overlap * (h + w)
    c3 = (min_overlap - 1) * w * h
    r3 = (b3 + math.sqrt(max(b3**2 - 4 * a3 * c3, 0))) / 2
    return min(r1, r2, r3)


def build_targets(samples_boxes, samples_alphas, samples_dontcare, gh: int, gw: int):
    """Per image: heat target (gh, gw), negative weight (0 inside DontCare / ignore regions),
    and the positives' (cell index, ltrb target (4,), bin (-1 unknown), residual)."""
    b = len(samples_boxes)
    heat = np.zeros((b, gh, gw), np.float32)
    negw = np.ones((b, gh, gw), np.float32)
    cells, ltrb, bins, res, batch = [], [], [], [], []
    ys, xs = np.mgrid[0:gh, 0:gw]
    for i in range(b):
        for dc in samples_dontcare[i].reshape(-1, 4):
            x1, y1 = int(math.floor(dc[0] / STRIDE)), int(math.floor(dc[1] / STRIDE))
            x2, y2 = int(math.ceil(dc[2] / STRIDE)), int(math.ceil(dc[3] / STRIDE))
            negw[i, max(y1, 0) : max(y2, 0), max(x1, 0) : max(x2, 0)] = 0.0
        alphas = samples_alphas[i]
        for box, alpha in zip(samples_boxes[i].reshape(-1, 4), alphas, strict=True):
            cx, cy = (box[0] + box[2]) / 2 / STRIDE, (box[1] + box[3]) / 2 / STRIDE
            gx, gy = min(max(int(cx), 0), gw - 1), min(max(int(cy), 0), gh - 1)
            bw, bh = (box[2] - box[0]) / STRIDE, (box[3] - box[1]) / STRIDE
            r = max(0.0, gaussian_radius(bh, bw))
            sigma = (2 * int(r) + 1) / 6
            g = np.exp(-((xs - gx) ** 2 + (ys - gy) ** 2) / (2 * sigma**2))
            heat[i] = np.maximum(heat[i], g.astype(np.float32))
            heat[i, gy, gx] = 1.0
            negw[i, gy, gx] = 1.0
            px, py = gx * STRIDE, gy * STRIDE
            ltrb.append([px - box[0], py - box[1], box[2] - px, box[3] - py])
            cells.append(gy * gw + gx)
            batch.append(i)
            if np.isfinite(alpha):
                bn, rs = alpha_to_bin_residual(float(alpha))
                bins.append(int(bn))
                res.append(float(rs))
            else:
                bins.append(-1)
                res.append(0.0)
    return (
        heat,
        negw,
        np.array(batch, np.int64),
        np.array(cells, np.int64),
        np.array(ltrb, np.float32).reshape(-1, 4),
        np.array(bins, np.int64),
        np.array(res, np.float32),
    )


def overlap_residual_targets(bins: np.ndarray, residuals: np.ndarray):
    """MultiBin targets with overlapping bins: (residual of the angle to each bin centre (N, 4)
    [rad], folded into [-pi/2, pi/2); mask (N, 4) of the bins whose centre is less than
    ``MAX_RESIDUAL`` away, which are trained) of angles given as (true bin, residual)."""
    alpha = np.asarray(bin_residual_to_alpha(bins, residuals), dtype=float).reshape(-1)
    centres = np.asarray(bin_residual_to_alpha(np.arange(NUM_BINS), 0.0), dtype=float)
    target = np.asarray(fold_alpha_signed(alpha[:, None] - centres[None]), dtype=float)
    mask = np.abs(target) < MAX_RESIDUAL - 1e-6  # the true bin's residual is <= 22.5 deg
    return target.astype(np.float32).reshape(-1, NUM_BINS), mask.reshape(-1, NUM_BINS)


def ltrb_iou(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """IoU of boxes given as distances (l, t, r, b) from the same point."""
    p, t = pred.clamp(min=0), target
    inter = (torch.minimum(p[:, 0], t[:, 0]) + torch.minimum(p[:, 2], t[:, 2])) * (
        torch.minimum(p[:, 1], t[:, 1]) + torch.minimum(p[:, 3], t[:, 3])
    )
    area_p = (p[:, 0] + p[:, 2]) * (p[:, 1] + p[:, 3])
    area_t = (t[:, 0] + t[:, 2]) * (t[:, 1] + t[:, 3])
    return inter / (area_p + area_t - inter).clamp(min=1e-6)


def smoothed_bin_targets(bins: np.ndarray, residuals: np.ndarray, smoothing: float) -> np.ndarray:
    """Soft 4-bin targets (N, 4) of angles given as (bin, residual [rad]): 1 - ``smoothing`` on
    the true bin, ``smoothing`` shared by its two neighbours on the circle of folded angles
    (the bins of 0 and 135 deg are neighbours across the 180-deg fold), the nearer one taking
    more in proportion to the residual: ``smoothing`` x (1/2 +- residual / 45 deg)."""
    n = len(bins)
    t = np.zeros((n, NUM_BINS), np.float32)
    rows = np.arange(n)
    share = np.clip(0.5 + np.asarray(residuals, float) / MAX_RESIDUAL, 0.0, 1.0)
    t[rows, bins] = 1.0 - smoothing
    t[rows, (bins + 1) % NUM_BINS] += smoothing * share
    t[rows, (bins - 1) % NUM_BINS] += smoothing * (1.0 - share)
    return t


def loss_normalisers(
    samples_boxes,
    samples_alphas,
    samples_dontcare,
    gh,
    gw,
    bin_weights=None,
    residual_overlap=False,
) -> dict[str, float]:
    """The denominators of :func:`centernet_loss`'s terms for a batch: positive heat-map cells,
    positive boxes, the summed bin weights of the boxes with a known alpha, and the trained
    residuals. Passed to :func:`centernet_loss` for each micro-batch of the batch, they make
    the micro-batches' losses sum to the whole batch's (``detector_train --micro-batch``)."""
    heat_t, _, _, cells, _, bins, res = build_targets(
        samples_boxes, samples_alphas, samples_dontcare, gh, gw
    )
    return _normalisers(heat_t, cells, bins, res, bin_weights, residual_overlap)


def _normalisers(heat_t, cells, bins, res, bin_weights, residual_overlap) -> dict[str, float]:
    known = bins >= 0
    w = np.ones(NUM_BINS) if bin_weights is None else np.asarray(bin_weights, float)
    if residual_overlap and known.any():
        n_res = float(overlap_residual_targets(bins[known], res[known])[1].sum())
    else:
        n_res = float(known.sum())
    return {
        "heat": float(max(int((heat_t == 1.0).sum()), 1)),
        "box": float(max(len(cells), 1)),
        "bin": float(w[bins[known]].sum()) or 1.0,
        "residual": n_res or 1.0,
    }


def _heat_focal_loss(logit, heat_t, negw):
    """Penalty-reduced focal loss (alpha 2, beta 4) of the heat logits against the target map,
    negatives weighted by ``negw`` (0 inside DontCare / ignore regions); a sum."""
    p = torch.sigmoid(logit).clamp(1e-4, 1 - 1e-4)
    pos = heat_t == 1.0
    pos_loss = -(torch.log(p) * (1 - p) ** 2)[pos].sum()
    neg_loss = -(torch.log(1 - p) * p**2 * (1 - heat_t) ** 4 * negw)[~pos].sum()
    return pos_loss + neg_loss


def _bin_loss(v, tb, bins, res, bin_weights, bin_smoothing):
    """Summed (weighted, optionally smoothed) cross-entropy of the orientation head's bin
    logits ``v[:, :NUM_BINS]`` against the true bins ``tb`` of the known angles."""
    bw = None if bin_weights is None else v.new_tensor(bin_weights)
    if bin_smoothing > 0:
        soft = smoothed_bin_targets(bins[bins >= 0], res[bins >= 0], bin_smoothing)
        ce = -(v.new_tensor(soft) * F.log_softmax(v[:, 0:NUM_BINS], dim=1)).sum(1)
        return (ce if bw is None else ce * bw[tb]).sum()
    return F.cross_entropy(v[:, 0:NUM_BINS], tb, weight=bw, reduction="sum")


def _residual_loss(v, tb, known, bins, res, residual_overlap):
    """Summed Gaussian negative log-likelihood of the true residual(s) with the predicted log
    variance: the true bin's, or with ``residual_overlap`` every bin within MAX_RESIDUAL."""
    res_raw = v[:, NUM_BINS : 2 * NUM_BINS]
    logvar = v[:, 2 * NUM_BINS].clamp(*LOGVAR_RANGE)
    if residual_overlap:
        target, mask = overlap_residual_targets(bins[bins >= 0], res[bins >= 0])
        target, mask = torch.from_numpy(target).to(v.device), torch.from_numpy(mask).to(v.device)
        err = MAX_RESIDUAL * torch.tanh(res_raw) - target
        nll = 0.5 * (err**2 * torch.exp(-logvar)[:, None] + logvar[:, None])
        return nll[mask].sum()
    pred_res = MAX_RESIDUAL * torch.tanh(res_raw.gather(1, tb[:, None])[:, 0])
    err = pred_res - torch.from_numpy(res).to(v.device)[known]
    return (0.5 * (err**2 * torch.exp(-logvar) + logvar)).sum()


def centernet_loss(
    raw,
    samples_boxes,
    samples_alphas,
    samples_dontcare,
    weights=None,
    orientation=None,
    bin_weights=None,
    residual_overlap=False,
    normalisers=None,
    bin_smoothing=0.0,
):
    """CenterNet loss of a batch and its terms: penalty-reduced focal loss on the heat map
    (alpha 2, beta 4; negatives inside DontCare / ignore regions not counted), box L1 (in
    stride units, weight 0.1) + 1 - IoU at the positive cells, orientation cross-entropy over the
    4 bins and Gaussian negative log-likelihood of the true bin's residual with the predicted
    variance (labels with a known alpha only); each normalised by its number of positives.

    ``raw``: the dense output (B, >= 5, H/4, W/4); ``orientation``: a function (batch (N,),
    boxes (N, 4)) -> (N, 9) evaluating the orientation head on the ground-truth boxes (None: no
    orientation terms); ``bin_weights``: per-bin weights of the bin cross-entropy (a weighted
    mean, ``detector_train --balance-orientation``; None: unweighted); ``residual_overlap``:
    MultiBin's overlapping bins (Mousavian et al. 2017): the residual of every bin whose centre
    lies within ``MAX_RESIDUAL`` (45 deg) of the true angle is trained, i.e. the true bin's and
    the nearer neighbour's, so that a box whose bin logit picks the neighbour still decodes to
    the right angle (False: the true bin's residual only). ``normalisers``: the denominators of
    the terms (:func:`loss_normalisers`; None: this batch's own, each term then a mean); with
    those of a whole batch, the losses of its micro-batches sum to the batch's.
    ``bin_smoothing``: the bin cross-entropy against :func:`smoothed_bin_targets` (label
    smoothing to the two neighbouring bins, across the 180-deg fold too; 0 = one-hot)."""
    w = {"heat": 1.0, "l1": 0.1, "iou": 1.0, "bin": 1.0, "residual": 1.0, **(weights or {})}
    dev = raw.device
    b, _, gh, gw = raw.shape
    heat_t, negw, bi, cells, ltrb, bins, res = build_targets(
        samples_boxes, samples_alphas, samples_dontcare, gh, gw
    )
    norm = normalisers or _normalisers(heat_t, cells, bins, res, bin_weights, residual_overlap)
    heat_t = torch.from_numpy(heat_t).to(dev)
    negw = torch.from_numpy(negw).to(dev)
    l_heat = _heat_focal_loss(raw[:, HEAT], heat_t, negw) / norm["heat"]
    zero = raw.sum() * 0.0
    l_l1 = l_iou = l_bin = l_res = zero
    if len(cells):
        bi_t = torch.from_numpy(bi).to(dev)
        cells_t = torch.from_numpy(cells).to(dev)
        vals = raw.flatten(2)[bi_t, :, cells_t]  # (N, 14)
        tgt = torch.from_numpy(ltrb).to(dev)
        l_l1 = (vals[:, BOX] - tgt).abs().sum(1).sum() / STRIDE / norm["box"]
        l_iou = (1 - ltrb_iou(vals[:, BOX], tgt)).sum() / norm["box"]
        known = torch.from_numpy(bins >= 0).to(dev)
        if known.any() and orientation is not None:
            gt_boxes = torch.from_numpy(
                np.concatenate([b_.reshape(-1, 4) for b_ in samples_boxes]).astype(np.float32)
            ).to(dev)
            tb = torch.from_numpy(bins).to(dev)[known]
            v = orientation(bi_t[known], gt_boxes[known])
            l_bin = _bin_loss(v, tb, bins, res, bin_weights, bin_smoothing) / norm["bin"]
            l_res = _residual_loss(v, tb, known, bins, res, residual_overlap) / norm["residual"]
    total = (
        w["heat"] * l_heat
        + w["l1"] * l_l1
        + w["iou"] * l_iou
        + w["bin"] * l_bin
        + w["residual"] * l_res
    )
    terms = {
        "heat": float(l_heat.detach()),
        "l1": float(l_l1.detach()),
        "iou": float(l_iou.detach()),
        "bin": float(l_bin.detach()),
        "res": float(l_res.detach()),
    }
    return total, terms
