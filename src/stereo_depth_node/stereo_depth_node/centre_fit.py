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
    cut: tuple[bool, bool] | None = None,
) -> np.ndarray:
    """``centre`` (x, y, z) [m] moved along x (depth kept) so that the projected footprint
    (:func:`footprint_columns`) matches the 2D ``box`` (x1, y1, x2, y2): centres aligned; a box
    edge within ``border`` px of the image border is not used (truncation), nor one of the
    (left, right) sides ``cut`` names when given (e.g. hidden by a nearer object); a box cut on
    both sides is returned unchanged."""
    x1, _, x2, _ = (float(v) for v in box)
    cut_left, cut_right = cut or (x1 <= border, x2 >= image_width - 1 - border)
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


def surface_depths(
    us, centre: np.ndarray, alpha: float, length: float, width: float, geometry: StereoGeometry
) -> np.ndarray:
    """Depth [m] at which the viewing ray of each image column ``us`` enters the upright prism
    over the footprint of a ``length`` x ``width`` car centred at ``centre`` (x, y, z) [m] and
    seen at ``alpha`` (the car's visible surface, as a box, per column); nan where it misses."""
    x, z = float(centre[0]), float(centre[2])
    ry = alpha + np.arctan2(x, z)
    c, s = np.cos(ry), np.sin(ry)
    # the ray (a t, t), a = (u - cx) / fx, in the footprint's frame: length axis (c, -s),
    # width axis (s, c), origin at the centre
    a = (np.asarray(us, float) - geometry.cx) / geometry.fx
    o_l, o_w = -(x * c - z * s), -(x * s + z * c)
    d_l, d_w = a * c - s, a * s + c
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-0.5 * length - o_l) / d_l, (0.5 * length - o_l) / d_l
        t3, t4 = (-0.5 * width - o_w) / d_w, (0.5 * width - o_w) / d_w
    t_in = np.maximum(np.minimum(t1, t2), np.minimum(t3, t4))
    t_out = np.minimum(np.maximum(t1, t2), np.maximum(t3, t4))
    return np.where((t_in <= t_out) & (t_in > 0), t_in, np.nan)


def fit_cut_box(
    statistic,
    target: float,
    columns: np.ndarray,
    box,
    alpha: float,
    length: float,
    width: float,
    geometry: StereoGeometry,
    image_width: int,
    start: np.ndarray,
    border: float = 2.0,
    iterations: int = 8,
    cut: tuple[bool, bool] | None = None,
) -> np.ndarray | None:
    """Centre (x, y, z) [m] of a car whose 2D ``box`` is cut by the left or right image border,
    from its visible part: the ``length`` x ``width`` footprint at ``alpha`` whose projection
    keeps the box's inner edge (:func:`footprint_columns`) and whose visible surface over the
    image ``columns`` the car was measured on (:func:`surface_depths`) gives the measured
    surface depth: ``statistic(depths)`` (the ranging's estimator applied to the model's
    depths [m] per column of ``columns``, nan where the model misses it) equals ``target``
    [m]. Gauss-Newton on (x, z) from ``start`` (y kept). ``cut``: the (left, right) sides cut
    when given (also a side hidden by a nearer object), else those within ``border`` px of the
    image border. None when the box is cut on both sides or on neither, or no solution is
    found."""
    x1, _, x2, _ = (float(v) for v in box)
    cut_left, cut_right = cut or (x1 <= border, x2 >= image_width - 1 - border)
    if cut_left == cut_right or not len(columns):
        return None

    def residual(p):
        c = np.array([p[0], start[1], p[1]])
        lo, hi = footprint_columns(c, alpha, length, width, geometry)
        edge = (hi - x2 if cut_left else lo - x1) * p[1] / geometry.fx  # px -> m at depth
        z = surface_depths(columns, c, alpha, length, width, geometry)
        if not np.isfinite(z).any():  # the model misses the measured columns: move it there
            return np.array([edge, p[1] - target + 0.5 * width])
        return np.array([edge, statistic(z) - target])

    p = np.array([float(start[0]), float(start[2])])
    for _ in range(iterations):
        r = residual(p)
        if not np.all(np.isfinite(r)):
            return None
        if np.max(np.abs(r)) < 0.01:
            break
        J = np.empty((2, 2))
        for j in range(2):
            q = p.copy()
            q[j] += 0.02
            J[:, j] = (residual(q) - r) / 0.02
        if not np.all(np.isfinite(J)) or abs(np.linalg.det(J)) < 1e-6:
            return None
        step = np.linalg.solve(J, -r)
        step *= min(1.0, 1.0 / max(float(np.linalg.norm(step)), 1e-12))  # at most 1 m a step
        p = p + step
        if p[1] <= 0.5:
            return None
    if np.max(np.abs(residual(p))) > 0.25:
        return None
    return np.array([p[0], float(start[1]), p[1]])
