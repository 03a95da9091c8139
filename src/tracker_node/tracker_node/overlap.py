"""Box overlaps used as association costs: 2D IoU with shape similarity, and 3D GIoU of boxes
with size and yaw (bird's-eye-view polygon intersection times the vertical overlap).

3D boxes here are ``(cx, cy, cz, l, w, h, yaw)``: the centre of the box (camera frame, y down),
length/width/height, yaw about the camera y axis (KITTI rotation_y; length along +x at yaw 0).
"""

from __future__ import annotations

import numpy as np


def iou_2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU of boxes ``a`` (N, 4) and ``b`` (M, 4), (x1, y1, x2, y2) -> (N, M)."""
    a = np.asarray(a, float)[:, None, :]
    b = np.asarray(b, float)[None, :, :]
    iw = np.clip(np.minimum(a[..., 2], b[..., 2]) - np.maximum(a[..., 0], b[..., 0]), 0, None)
    ih = np.clip(np.minimum(a[..., 3], b[..., 3]) - np.maximum(a[..., 1], b[..., 1]), 0, None)
    inter = iw * ih
    area_a = (a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
    area_b = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    union = area_a + area_b - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / union, 0.0)
    return np.nan_to_num(iou)


def shape_similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise shape similarity ``exp(-(|w_a - w_b| / (w_a + w_b) + |h_a - h_b| / (h_a + h_b)))``
    of 2D boxes (N, 4) and (M, 4): 1 for equal sizes."""
    wa, ha = (a[:, 2] - a[:, 0])[:, None], (a[:, 3] - a[:, 1])[:, None]
    wb, hb = (b[:, 2] - b[:, 0])[None, :], (b[:, 3] - b[:, 1])[None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.abs(wa - wb) / (wa + wb) + np.abs(ha - hb) / (ha + hb)
    return np.nan_to_num(np.exp(-d))


def bev_corners(box: np.ndarray) -> np.ndarray:
    """The 4 footprint corners (4, 2) in (x, z), counter-clockwise in the x-z plane."""
    cx, _, cz, l, w, _, yaw = (float(v) for v in box)
    c, s = np.cos(yaw), np.sin(yaw)
    xs = np.array([l, -l, -l, l]) / 2.0
    zs = np.array([w, w, -w, -w]) / 2.0
    # same rotation as kitti_player_node.box3d.box_corners: x' = c x + s z, z' = -s x + c z
    pts = np.stack([cx + c * xs + s * zs, cz - s * xs + c * zs], axis=1)
    return _ccw(pts)


def _ccw(poly: np.ndarray) -> np.ndarray:
    area2 = np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    return poly if area2 >= 0 else poly[::-1]


def polygon_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return float(abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)) / 2.0)


def clip_convex(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """Intersection of two convex counter-clockwise polygons (Sutherland-Hodgman)."""
    out = [tuple(p) for p in subject]
    n = len(clip)
    for i in range(n):
        if not out:
            break
        ax, ay = clip[i]
        bx, by = clip[(i + 1) % n]
        inp, out = out, []

        def side(p, ax=ax, ay=ay, bx=bx, by=by):
            return (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax)

        for j in range(len(inp)):
            p, q = inp[j], inp[(j + 1) % len(inp)]
            sp, sq = side(p), side(q)
            if sp >= 0:
                out.append(p)
            if (sp >= 0) != (sq >= 0):
                t = sp / (sp - sq)
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    return np.array(out, dtype=float).reshape(-1, 2)


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (monotone chain), counter-clockwise."""
    pts = sorted(set(map(tuple, np.asarray(points, float))))
    if len(pts) <= 2:
        return np.array(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def giou_3d(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(3D IoU, 3D GIoU) of two boxes ``(cx, cy, cz, l, w, h, yaw)``."""
    pa, pb = bev_corners(a), bev_corners(b)
    inter_area = polygon_area(clip_convex(pa, pb))
    ya0, ya1 = a[1] - a[5] / 2.0, a[1] + a[5] / 2.0
    yb0, yb1 = b[1] - b[5] / 2.0, b[1] + b[5] / 2.0
    ih = max(0.0, min(ya1, yb1) - max(ya0, yb0))
    inter = inter_area * ih
    va, vb = a[3] * a[4] * a[5], b[3] * b[4] * b[5]
    union = va + vb - inter
    hull = polygon_area(convex_hull(np.vstack([pa, pb]))) * (max(ya1, yb1) - min(ya0, yb0))
    iou = inter / union if union > 0 else 0.0
    giou = iou - (hull - union) / hull if hull > 0 else iou
    return float(iou), float(giou)


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
