"""Lateral placement of a car's centre of mass from its 2D box (the box-to-centre step).

Pure core. The ranging step (:mod:`.ranging`) puts the centre on the viewing ray of the 2D box's
centre pixel, behind the visible surface. That ray misses the car's centre when the car is seen
obliquely and near (the projected box of a 3D box is not centred on the projection of its centre)
and when the box is truncated at the image border (the box's centre pixel is the centre of the
visible part only). :func:`fit_lateral` keeps the depth and moves the centre sideways until the
projected footprint of a ``length`` x ``width`` car at the orientation bin's angle spans the 2D
box: its centre on the box's centre, or, for a box cut by the left (right) image border, its
right (left) edge on the box's remaining edge.
"""

from __future__ import annotations

import numpy as np

from .reprojection import StereoGeometry


def footprint_columns(
    centre: np.ndarray, alpha: float, length: float, width: float, geometry: StereoGeometry
) -> tuple[float, float]:
    """Image columns (u_min, u_max) spanned by the footprint corners of a ``length`` x ``width``
    car centred at ``centre`` (x, y, z) [m] (left optical frame) and seen at observation angle
    ``alpha`` (KITTI: rotation_y = alpha + atan2(x, z)). inf when a corner is behind the camera."""
    x, z = float(centre[0]), float(centre[2])
    ry = alpha + np.arctan2(x, z)
    c, s = np.cos(ry), np.sin(ry)
    dx = np.array([1, 1, -1, -1]) * 0.5 * length
    dz = np.array([1, -1, -1, 1]) * 0.5 * width
    xs = x + c * dx + s * dz
    zs = z - s * dx + c * dz
    if np.any(zs <= 0.1):
        return float("-inf"), float("inf")
    u = geometry.fx * xs / zs + geometry.cx
    return float(u.min()), float(u.max())


def fit_lateral(
    centre: np.ndarray,
    box,
    alpha: float,
    length: float,
    width: float,
    geometry: StereoGeometry,
    image_width: int,
    border: float = 2.0,
    iterations: int = 4,
) -> np.ndarray:
    """``centre`` (x, y, z) [m] moved along x (depth kept) so that the projected footprint
    (:func:`footprint_columns`) matches the 2D ``box`` (x1, y1, x2, y2): centres aligned; a box
    edge within ``border`` px of the image border is not used (truncation); a box cut on both
    sides is returned unchanged."""
    x1, _, x2, _ = (float(v) for v in box)
    cut_left, cut_right = x1 <= border, x2 >= image_width - 1 - border
    if cut_left and cut_right:
        return np.asarray(centre, float).copy()
    out = np.asarray(centre, float).copy()
    for _ in range(iterations):
        lo, hi = footprint_columns(out, alpha, length, width, geometry)
        if not np.isfinite(lo + hi):
            break
        if cut_left:
            du = x2 - hi
        elif cut_right:
            du = x1 - lo
        else:
            du = 0.5 * (x1 + x2) - 0.5 * (lo + hi)
        out[0] += du * out[2] / geometry.fx  # columns -> metres at the centre's depth
        if abs(du) < 0.05:
            break
    return out
