"""The CenterNet's output layout and its sparse part in numpy (pure: no torch).

The dense part (the graph's head feature and the heat / box heads) runs on ONNX Runtime
(:mod:`detector_node.onnx_backend`); what follows it -- the heat-map peaks, the orientation head
evaluated at the peaks' boxes, the decoding to :class:`~detector_node.detection.Detection` --
is written here with numpy and OpenCV, step for step as the PyTorch module does it
(:meth:`detector_node.centernet.CenterNetDetector.raw_from_features` and
:func:`detector_node.centernet.decode_centernet`), so that the detector node runs without
importing PyTorch (``tests/detector/test_onnx_cache.py`` checks the two agree on real frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from vehicle_common.orientation_bins import NUM_BINS, bin_residual_to_alpha

from .boxes import nms
from .detection import Detection

STRIDE = 4
ORIENTATION_POINTS = 3  # per box side: 3x3 sample points
ORIENTATION_PEAKS = 100
#: raw output channels
HEAT, BOX, BINS, RESIDUALS, LOGVAR = 0, slice(1, 5), slice(5, 9), slice(9, 13), 13
OUT_CHANNELS = 14
#: largest residual [rad] (reaches the neighbouring bin centres)
MAX_RESIDUAL = math.pi / 4
LOGVAR_RANGE = (-9.0, 2.0)


def decode_orientation(bin_logits: np.ndarray, residual_raw: np.ndarray, logvar: np.ndarray):
    """(probs (N, 4), bin (N,), folded angle (N,) [rad], variance (N,) [rad^2]) of raw head
    values: bin = argmax of the softmax; angle = bin centre + pi/4 tanh(residual of that bin),
    folded into [-pi/2, pi/2); variance = exp(log-variance)."""
    z = bin_logits - bin_logits.max(axis=1, keepdims=True)
    p = np.exp(z)
    p /= p.sum(axis=1, keepdims=True)
    b = np.argmax(p, axis=1)
    res = MAX_RESIDUAL * np.tanh(np.take_along_axis(residual_raw, b[:, None], 1)[:, 0])
    angle = np.asarray(bin_residual_to_alpha(b, res), dtype=float).reshape(-1)
    var = np.exp(np.clip(logvar, *LOGVAR_RANGE))
    return p, b, angle, var


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Logistic function in the array's precision."""
    one = np.ones((), x.dtype)
    return one / (one + np.exp(-x))


def heat_peaks(heat_logit: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Top-``k`` local maxima (3x3, edges over the cells inside the map) of one heat map
    (logits, (H, W)): (scores (k,), flat cell indices (k,)), by descending score."""
    heat = sigmoid(np.ascontiguousarray(heat_logit, np.float32))
    keep = heat == cv2.dilate(heat, np.ones((3, 3), np.uint8))
    flat = (heat * keep).reshape(-1)
    k = min(k, flat.size)
    idx = np.argsort(-flat, kind="stable")[:k]
    return flat[idx], idx


def bilinear_sample(feature: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Values (N, C) of a feature map (C, H, W) at cell coordinates (x, y) (N,): bilinear,
    zero outside the map (``grid_sample`` with ``align_corners=False``, zero padding)."""
    c, h, w = feature.shape
    x0, y0 = np.floor(x), np.floor(y)
    x1, y1 = x0 + 1, y0 + 1
    out = np.zeros((len(x), c), np.float32)
    for cx, cy, wgt in (
        (x0, y0, (x1 - x) * (y1 - y)),
        (x1, y0, (x - x0) * (y1 - y)),
        (x0, y1, (x1 - x) * (y - y0)),
        (x1, y1, (x - x0) * (y - y0)),
    ):
        inside = (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)
        xi = np.clip(cx, 0, w - 1).astype(np.int64)
        yi = np.clip(cy, 0, h - 1).astype(np.int64)
        vals = feature[:, yi, xi].T  # (N, C)
        out += np.where(inside[:, None], vals * wgt[:, None], np.float32(0))
    return out


@dataclass(frozen=True)
class OrientationHead:
    """The orientation head's weights (Linear, ReLU, Linear) as numpy arrays."""

    w1: np.ndarray  # (hidden, C * P * P + 3)
    b1: np.ndarray
    w2: np.ndarray  # (2 * NUM_BINS + 1, hidden)
    b2: np.ndarray

    def __call__(self, x: np.ndarray) -> np.ndarray:
        h = np.maximum(x @ self.w1.T + self.b1, np.float32(0))
        return h @ self.w2.T + self.b2

    def arrays(self) -> dict[str, np.ndarray]:
        return {"w1": self.w1, "b1": self.b1, "w2": self.w2, "b2": self.b2}

    @classmethod
    def from_arrays(cls, arrays) -> OrientationHead:
        return cls(*(np.ascontiguousarray(arrays[k], np.float32) for k in ("w1", "b1", "w2", "b2")))


def orientation_at(
    feature: np.ndarray, boxes: np.ndarray, head: OrientationHead, geo=None
) -> np.ndarray:
    """Orientation values (N, 9) of boxes (N, 4) [input px] of one image's head feature
    (C, H/4, W/4): the feature at 3x3 points inside each box and the box geometry (log aspect
    ratio, normalised centre; ``geo`` maps another framing onto the training's, see
    :func:`detector_node.config.geo_frame`) through the head."""
    if not len(boxes):
        return np.zeros((0, 2 * NUM_BINS + 1), np.float32)
    c, gh, gw = feature.shape
    n = ORIENTATION_POINTS
    frac = (np.arange(n, dtype=np.float32) + np.float32(0.5)) / np.float32(n)
    x1, y1, x2, y2 = (boxes[:, i] for i in range(4))
    px = x1[:, None] + (x2 - x1)[:, None] * frac[None]  # (N, P)
    py = y1[:, None] + (y2 - y1)[:, None] * frac[None]
    # the module's grid_sample coordinates: normalised, then back to cells (align_corners off)
    gx = (2 * (px / STRIDE) + 1) / gw - 1
    gy = (2 * (py / STRIDE) + 1) / gh - 1
    ix = ((gx + 1) * gw - 1) / 2
    iy = ((gy + 1) * gh - 1) / 2
    xs = np.broadcast_to(ix[:, None, :], (len(boxes), n, n)).reshape(-1)  # row-major (y, x)
    ys = np.broadcast_to(iy[:, :, None], (len(boxes), n, n)).reshape(-1)
    sampled = bilinear_sample(feature, xs, ys).reshape(len(boxes), n * n, c)
    sampled = sampled.transpose(0, 2, 1).reshape(len(boxes), c * n * n)  # (N, C * P * P)
    w = np.maximum(x2 - x1, np.float32(1))
    h = np.maximum(y2 - y1, np.float32(1))
    ax, bx, ay, by, aspect = geo or (1 / (STRIDE * gw), 0.0, 1 / (STRIDE * gh), 0.0, 0.0)
    geometry = np.stack(
        [
            np.log(w / h) + np.float32(aspect),
            (x1 + x2) / 2 * np.float32(ax) + np.float32(bx) - np.float32(0.5),
            (y1 + y2) / 2 * np.float32(ay) + np.float32(by) - np.float32(0.5),
        ],
        axis=1,
    )
    return head(np.concatenate([sampled, geometry.astype(np.float32)], axis=1))


def decode_dense(
    feature: np.ndarray,
    dense: np.ndarray,
    head: OrientationHead,
    input_size: tuple[int, int],
    score_threshold: float,
    nms_iou: float,
    scale: tuple[float, float] = (1.0, 1.0),
    geo=None,
    max_detections: int = ORIENTATION_PEAKS,
) -> list[Detection]:
    """Detections of one image from the dense outputs (``feature`` (1, C, H/4, W/4), ``dense``
    (1, 5, H/4, W/4): heat logit and (l, t, r, b) [input px]) of an ``input_size`` (width,
    height) input, in original px (input px divided by ``scale``): heat-map peaks >=
    ``score_threshold``, boxes from the distances, the orientation head at the peaks' boxes,
    class-agnostic NMS."""
    f, d = feature[0], np.asarray(dense[0], np.float32)
    gw = d.shape[2]
    scores, cells = heat_peaks(d[HEAT], max_detections)
    keep = scores >= score_threshold
    scores, cells = scores[keep], cells[keep]
    dist = d[BOX].reshape(4, -1)[:, cells].T  # (N, 4) float32
    cx, cy = (cells % gw) * STRIDE, (cells // gw) * STRIDE  # integers
    # the orientation head's boxes in float32, at least one input px wide and tall
    cxf, cyf = cx.astype(np.float32), cy.astype(np.float32)
    head_box = np.stack([cxf - dist[:, 0], cyf - dist[:, 1], cxf + dist[:, 2], cyf + dist[:, 3]], 1)
    head_box = np.maximum(
        head_box,
        np.stack([head_box[:, 0], head_box[:, 1], head_box[:, 0] + 1, head_box[:, 1] + 1], 1),
    )
    ori = orientation_at(f, head_box, head, geo)
    s = np.array([scale[0], scale[1], scale[0], scale[1]])
    bx = np.stack([cx - dist[:, 0], cy - dist[:, 1], cx + dist[:, 2], cy + dist[:, 3]], 1) / s
    bx[:, [0, 2]] = np.clip(bx[:, [0, 2]], 0, input_size[0] / scale[0])
    bx[:, [1, 3]] = np.clip(bx[:, [1, 3]], 0, input_size[1] / scale[1])
    valid = (bx[:, 2] > bx[:, 0]) & (bx[:, 3] > bx[:, 1])
    bx, scores, ori = bx[valid], scores[valid], ori[valid]
    probs, bins, angle, var = decode_orientation(
        ori[:, 0:NUM_BINS], ori[:, NUM_BINS : 2 * NUM_BINS], ori[:, 2 * NUM_BINS]
    )
    order = nms(bx, scores, nms_iou)[:max_detections]
    return [
        Detection(
            box=tuple(float(v) for v in bx[j]),
            score=float(scores[j]),
            orientation_bin=int(bins[j]),
            orientation_probs=tuple(float(p) for p in probs[j]),
            observation_angle=float(angle[j]),
            observation_angle_variance=float(var[j]),
        )
        for j in order
    ]
