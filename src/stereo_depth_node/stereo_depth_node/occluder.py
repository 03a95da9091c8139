"""Box sides hidden by a nearer object: the "occluder cut" (issue #41 item 2).

Pure core. A detector boxes the visible part of a car that a nearer object (a car parked in
front of it, a post) partly hides; KITTI labels its full extent. :func:`occluder_sides` finds the
hidden sides in the disparity map: a strip just outside the box's left, right or bottom edge whose
valid, non-road pixels are mostly nearer than the car's surface by a margin. The ranging
(:mod:`.ranging`) then treats such a side like one cut by the image border (the centre from the
visible part, the un-hidden edge kept), and :func:`extend_hidden_sides` extends the 2D box on the
hidden sides only to the full-extent projection (:func:`full_extent_box`) of the fitted car.
"""

from __future__ import annotations

import math

import numpy as np

from .reprojection import StereoGeometry

#: fewest valid, non-road strip pixels a side is judged on
MIN_STRIP_PIXELS = 10
#: [px] narrowest strip beside the box
MIN_STRIP_WIDTH = 3


def _strip_rects(box, strip: float) -> tuple[tuple[int, int, int, int], ...]:
    """(row0, row1, col0, col1) of the strips left of, right of and below ``box`` (x1, y1, x2,
    y2): ``strip`` x the box's width (height), at least :data:`MIN_STRIP_WIDTH` px."""
    x1, y1, x2, y2 = (float(v) for v in box)
    sw = max(MIN_STRIP_WIDTH, int(round(strip * (x2 - x1))))
    sh = max(MIN_STRIP_WIDTH, int(round(strip * (y2 - y1))))
    r0, r1 = int(math.floor(y1)), int(math.ceil(y2))
    c0, c1 = int(math.floor(x1)), int(math.ceil(x2))
    return (r0, r1, c0 - sw, c0), (r0, r1, c1, c1 + sw), (r1, r1 + sh, c0, c1)


def _solid_nearer(
    disparity, r0, r1, c0, c1, z_near, geometry, ground_height, ground_margin, axis=None
):
    """(valid non-road pixels, those nearer than ``z_near`` [m]) of the map's rectangle rows
    [r0, r1) x columns [c0, c1) (clipped): totals, or per column (``axis`` 0) / row (1)."""
    h, w = disparity.shape
    r0, r1, c0, c1 = max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)
    if r1 <= r0 or c1 <= c0 or z_near <= 0:
        return (0, 0) if axis is None else (np.zeros(0, int), np.zeros(0, int))
    fb = geometry.fx * geometry.baseline
    patch = disparity[r0:r1, c0:c1]
    valid = patch > 0
    rows = np.arange(r0, r1, dtype=float)[:, None]
    y = (rows - geometry.cy) * fb / (geometry.fy * np.where(valid, patch, 1.0))
    solid = valid & ~(y > ground_height - ground_margin)
    nearer = solid & (patch > fb / z_near)
    return solid.sum(axis=axis), nearer.sum(axis=axis)


def occluder_sides(
    disparity: np.ndarray,
    box,
    d_car: float,
    geometry: StereoGeometry,
    strip: float,
    margin: float,
    share: float,
    ground_height: float,
    ground_margin: float,
    skip=(False, False, False),
) -> tuple[bool, bool, bool]:
    """(left, right, bottom): whether each side of ``box`` is hidden by a nearer object. A
    side's strip (:func:`_strip_rects`; sides in ``skip``, e.g. cut by the image border, and
    strips outside the map are not judged) is hidden when at least ``share`` of its valid pixels
    that are not road (3D height below the camera <= ``ground_height - ground_margin`` [m], as
    the ranging's ground rejection) lie more than ``margin`` [m] nearer than the car's surface
    at disparity ``d_car`` [px], with at least :data:`MIN_STRIP_PIXELS` of them."""
    if not (np.isfinite(d_car) and d_car > 0):
        return False, False, False
    z_near = geometry.fx * geometry.baseline / d_car - margin
    out = []
    for skipped, rect in zip(skip, _strip_rects(box, strip), strict=True):
        n, nearer = _solid_nearer(disparity, *rect, z_near, geometry, ground_height, ground_margin)
        out.append(not skipped and n >= MIN_STRIP_PIXELS and nearer >= share * n)
    return out[0], out[1], out[2]


def hidden_reach(
    disparity: np.ndarray,
    box,
    target,
    d_car: float,
    geometry: StereoGeometry,
    margin: float,
    share: float,
    ground_height: float,
    ground_margin: float,
) -> tuple[float, float, float, float]:
    """``target`` (x1, y1, x2, y2), a box extended from ``box`` on hidden sides, cut back on
    each extended side to the columns (rows below) that the nearer object covers, counted
    outward from ``box``'s edge: the extension stops at the first column (row) with at least
    2 valid non-road pixels of which fewer than ``share`` are ``margin`` [m] nearer than the car
    at disparity ``d_car`` [px] (a hidden part of the car lies behind the occluder, not beside
    it; the ranging uses margin 0: the occluder's side face may be within the cut's margin)."""
    z_near = geometry.fx * geometry.baseline / d_car - margin
    x1, y1, x2, y2 = (float(v) for v in box)
    t1, t2, t4 = float(target[0]), float(target[2]), float(target[3])
    r0, r1 = int(math.floor(y1)), int(math.ceil(y2))
    args = (z_near, geometry, ground_height, ground_margin)

    def reach(n, nearer, edges):  # the outermost edge before the first open line
        ok = (n < 2) | (nearer >= share * n)
        stop = int(np.argmin(ok)) if not ok.all() else len(ok)
        return edges[stop] if stop < len(edges) else None

    out = [x1, y1, x2, y2]
    if t1 < x1:  # columns [floor(t1), floor(x1)), from the edge outward
        c0, c1 = int(math.floor(t1)), int(math.floor(x1))
        n, near = _solid_nearer(disparity, r0, r1, c0, c1, *args, axis=0)
        e = reach(n[::-1], near[::-1], np.arange(c1, c0 - 1, -1, dtype=float))
        out[0] = max(t1, e) if e is not None else t1
    if t2 > x2:
        c0, c1 = int(math.ceil(x2)), int(math.ceil(t2))
        n, near = _solid_nearer(disparity, r0, r1, c0, c1, *args, axis=0)
        e = reach(n, near, np.arange(c0, c1 + 1, dtype=float))
        out[2] = min(t2, e) if e is not None else t2
    if t4 > y2:
        q0, q1 = int(math.ceil(y2)), int(math.ceil(t4))
        c0, c1 = int(math.floor(x1)), int(math.ceil(x2))
        n, near = _solid_nearer(disparity, q0, q1, c0, c1, *args, axis=1)
        e = reach(n, near, np.arange(q0, q1 + 1, dtype=float))
        out[3] = min(t4, e) if e is not None else t4
    return out[0], out[1], out[2], out[3]


def map_boxes(boxes, strip: float) -> list:
    """``boxes`` widened by their strips (:func:`_strip_rects`) on each judged side: where a
    map computed only in the boxes must hold values for :func:`occluder_sides`."""
    out = []
    for box in np.asarray(boxes, float).reshape(-1, 4):
        left, right, below = _strip_rects(box, strip)
        out.append((float(left[2]), float(box[1]), float(right[3]), float(below[1])))
    return out


def full_extent_box(
    centre, alpha: float, length: float, width: float, height: float, geometry: StereoGeometry
) -> tuple[float, float, float, float] | None:
    """(u1, v1, u2, v2): the projection of a ``length`` x ``width`` x ``height`` car whose
    footprint is centred at ``centre`` (x, z) with its bottom at ``centre``'s y [m] (left
    optical frame; KITTI's box location) seen at observation angle ``alpha`` (rotation_y =
    alpha + atan2(x, z)); None when a corner is behind the camera."""
    x, yb, z = (float(v) for v in centre)
    ry = alpha + math.atan2(x, z)
    c, s = math.cos(ry), math.sin(ry)
    dx = np.array([1, 1, -1, -1] * 2) * 0.5 * length
    dz = np.array([1, -1, -1, 1] * 2) * 0.5 * width
    xs, zs = x + c * dx + s * dz, z - s * dx + c * dz
    ys = np.array([yb] * 4 + [yb - height] * 4)
    if np.any(zs <= 0.1):
        return None
    u = geometry.fx * xs / zs + geometry.cx
    v = geometry.fy * ys / zs + geometry.cy
    return float(u.min()), float(v.min()), float(u.max()), float(v.max())


def extend_hidden_sides(box, hidden, full, size) -> tuple[float, float, float, float]:
    """``box`` (x1, y1, x2, y2) moved outward on its ``hidden`` (left, right, bottom) sides to
    the ``full`` extent box (never inward; the visible edges kept), within the (height, width)
    ``size`` of the image."""
    x1, y1, x2, y2 = (float(v) for v in box)
    left, right, bottom = hidden
    if left:
        x1 = max(min(x1, full[0]), 0.0)
    if right:
        x2 = min(max(x2, full[2]), float(size[1] - 1))
    if bottom:
        y2 = min(max(y2, full[3]), float(size[0] - 1))
    return x1, y1, x2, y2
