"""Geometry of KITTI 3D boxes: corners, projection into an image, projected 2D boxes.

A KITTI box is given by its dimensions (h, w, l), its bottom-centre location (x, y, z) in camera
coordinates (x right, y down, z forward) and its yaw ``rotation_y`` about the camera y axis; at
yaw 0 the box's length runs along +x.
"""

from __future__ import annotations

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
