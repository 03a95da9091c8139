"""Geometry of KITTI 3D boxes: corners, projection into an image, projected 2D boxes.

A KITTI box is given by its dimensions (h, w, l), its bottom-centre location (x, y, z) in camera
coordinates (x right, y down, z forward) and its yaw ``rotation_y`` about the camera y axis; at
yaw 0 the box's length runs along +x.

Overlaps of two such boxes (bird's-eye footprint, convex polygon clipping and hull, 3D IoU and
GIoU) live here too, for the evaluation and the tracker alike.
"""

from __future__ import annotations

import math

import numpy as np


def box_corners(dimensions, location, rotation_y: float) -> np.ndarray:
    """The 8 corners (8, 3) of a box. Order: bottom face 0-3, top face 4-7 (same x/z order),
    corners 0, 1, 4, 5 on the front (+x in the box frame)."""
    h, w, l = (float(v) for v in dimensions)
    x = np.array([l, l, -l, -l, l, l, -l, -l]) / 2.0
    y = np.array([0, 0, 0, 0, -h, -h, -h, -h], dtype=float)
    z = np.array([w, -w, -w, w, w, -w, -w, w]) / 2.0
    c, s = np.cos(rotation_y), np.sin(rotation_y)
    # rotation about y: x' = c x + s z, z' = -s x + c z
    xr = c * x + s * z
    zr = -s * x + c * z
    return np.stack([xr, y, zr], axis=1) + np.asarray(location, dtype=float)


def project_points(P: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Project (N, 3) camera points with a 3x4 matrix P to (N, 2) pixels (z must be > 0)."""
    pts = np.asarray(points, dtype=float)
    hom = np.hstack([pts, np.ones((len(pts), 1))]) @ np.asarray(P, dtype=float).T
    return hom[:, :2] / hom[:, 2:3]


def projected_bbox(
    P: np.ndarray,
    dimensions,
    location,
    rotation_y: float,
    image_size: tuple[int, int] | None = None,
    near: float = 0.1,
) -> tuple[float, float, float, float] | None:
    """2D box (x1, y1, x2, y2) enclosing the projection of a 3D box, clipped to the image
    (``image_size`` = (width, height)) when given. The box is clipped at the near plane
    ``z = near`` first; returns None when it lies wholly behind it or outside the image."""
    corners = box_corners(dimensions, location, rotation_y)
    pts = _clip_box_near(corners, near)
    if pts is None:
        return None
    uv = project_points(P, pts)
    x1, y1 = uv.min(axis=0)
    x2, y2 = uv.max(axis=0)
    if image_size is not None:
        w, h = image_size
        x1, x2 = max(x1, 0.0), min(x2, w - 1.0)
        y1, y2 = max(y1, 0.0), min(y2, h - 1.0)
        if x2 <= x1 or y2 <= y1:
            return None
    return float(x1), float(y1), float(x2), float(y2)


_EDGES = [
    (0, 1),
    (1, 2),
    (2, 3),
    (3, 0),
    (4, 5),
    (5, 6),
    (6, 7),
    (7, 4),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
]


def box_edges() -> list[tuple[int, int]]:
    """The 12 edges of a box as pairs of corner indices (for drawing wireframes)."""
    return list(_EDGES)


def _clip_box_near(corners: np.ndarray, near: float) -> np.ndarray | None:
    """Corners in front of the near plane plus the edge intersections with it."""
    front = corners[:, 2] >= near
    if front.all():
        return corners
    if not front.any():
        return None
    pts = [corners[front]]
    for a, b in _EDGES:
        if front[a] != front[b]:
            pa, pb = corners[a], corners[b]
            t = (near - pa[2]) / (pb[2] - pa[2])
            pts.append((pa + t * (pb - pa))[None, :])
    return np.vstack(pts)


# ----------------------------------------------------------------------------- overlaps
# Boxes below are ``(dimensions, location, rotation_y)`` triples in the KITTI convention of this
# module: dimensions (h, w, l) in metres, bottom-centre location (x, y, z) in camera coordinates
# (y down, so a box spans [y - h, y] vertically), yaw about the camera y axis.


def bev_corners(dimensions, location, rotation_y: float) -> np.ndarray:
    """Bird's-eye footprint (4, 2) of a KITTI box in (x, z), counter-clockwise in that plane
    (positive signed area with x as the first and z as the second coordinate)."""
    _, w, l = (float(v) for v in dimensions)
    x = np.array([l, -l, -l, l]) / 2.0
    z = np.array([w, w, -w, -w]) / 2.0
    c, s = math.cos(rotation_y), math.sin(rotation_y)
    # the rotation of box_corners: x' = c x + s z, z' = -s x + c z
    pts = np.stack([c * x + s * z + location[0], -s * x + c * z + location[2]], axis=1)
    signed = 0.5 * float(
        np.dot(pts[:, 0], np.roll(pts[:, 1], -1)) - np.dot(pts[:, 1], np.roll(pts[:, 0], -1))
    )
    return pts if signed >= 0 else pts[::-1].copy()


def clip_convex_polygon(subject, clip) -> list[tuple[float, float]]:
    """Sutherland-Hodgman: the part of polygon ``subject`` inside the convex counter-clockwise
    polygon ``clip`` (both (N, 2) arrays or sequences of 2D points), as a list of (x, y)."""
    out = [tuple(p) for p in (subject.tolist() if isinstance(subject, np.ndarray) else subject)]
    clip = clip.tolist() if isinstance(clip, np.ndarray) else list(clip)
    n = len(clip)
    for i in range(n):
        if not out:
            break
        ax, ay = clip[i]
        bx, by = clip[(i + 1) % n]
        ex, ey = bx - ax, by - ay
        inp, out = out, []
        m = len(inp)
        for j in range(m):
            px, py = inp[j]
            qx, qy = inp[(j + 1) % m]
            sp = ex * (py - ay) - ey * (px - ax)  # >= 0: inside (left of the edge)
            sq = ex * (qy - ay) - ey * (qx - ax)
            if sp >= 0.0:
                out.append((px, py))
            if (sp >= 0.0) != (sq >= 0.0):
                t = sp / (sp - sq)
                out.append((px + t * (qx - px), py + t * (qy - py)))
    return out


def polygon_area(poly) -> float:
    """Area of a simple polygon ((N, 2) array or sequence of 2D points; 0 below 3 points)."""
    if len(poly) < 3:
        return 0.0
    p = np.asarray(poly, dtype=float)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def convex_hull(points) -> np.ndarray:
    """Convex hull (K, 2) of 2D points (monotone chain), counter-clockwise, no repeated point."""
    pts = sorted(set(map(tuple, np.asarray(points, dtype=float).tolist())))
    if len(pts) <= 2:
        return np.array(pts, dtype=float).reshape(-1, 2)

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
    return np.array(lower[:-1] + upper[:-1], dtype=float)


def iou_3d(box_a, box_b) -> float:
    """3D IoU of two KITTI boxes ``(dimensions (h, w, l), bottom-centre location, rotation_y)``:
    bird's-eye polygon intersection times the vertical overlap, over the union volume. In
    [0, 1]; 1 for identical boxes; 0 when a size is not positive."""
    (da, loc_a, ry_a), (db, loc_b, ry_b) = box_a, box_b
    ha, wa, la = da
    hb, wb, lb = db
    if min(ha, wa, la, hb, wb, lb) <= 0.0:
        return 0.0
    y_overlap = min(loc_a[1], loc_b[1]) - max(loc_a[1] - ha, loc_b[1] - hb)
    if y_overlap <= 0.0:
        return 0.0
    pa = bev_corners(da, loc_a, ry_a)
    pb = bev_corners(db, loc_b, ry_b)
    inter = polygon_area(clip_convex_polygon(pa, pb)) * y_overlap
    union = ha * wa * la + hb * wb * lb - inter
    return float(min(1.0, max(0.0, inter / union))) if union > 0 else 0.0


def giou_3d(box_a, box_b) -> tuple[float, float]:
    """(3D IoU, 3D GIoU) of two KITTI boxes ``(dimensions (h, w, l), bottom-centre location,
    rotation_y)``. GIoU = IoU - (hull - union) / hull, the hull being the bird's-eye convex hull
    of both footprints times the vertical extent of both boxes: in (-1, 1], negative for
    separated boxes."""
    (da, loc_a, ry_a), (db, loc_b, ry_b) = box_a, box_b
    ha, wa, la = (float(v) for v in da)
    hb, wb, lb = (float(v) for v in db)
    pa = bev_corners(da, loc_a, ry_a)
    pb = bev_corners(db, loc_b, ry_b)
    inter_area = polygon_area(clip_convex_polygon(pa, pb))
    ya0, ya1 = loc_a[1] - ha, loc_a[1]
    yb0, yb1 = loc_b[1] - hb, loc_b[1]
    inter = inter_area * max(0.0, min(ya1, yb1) - max(ya0, yb0))
    union = la * wa * ha + lb * wb * hb - inter
    hull = polygon_area(convex_hull(np.vstack([pa, pb]))) * (max(ya1, yb1) - min(ya0, yb0))
    iou = inter / union if union > 0 else 0.0
    giou = iou - (hull - union) / hull if hull > 0 else iou
    return float(iou), float(giou)
