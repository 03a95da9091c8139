"""Box overlaps of vehicle_common.box3d: footprint, clipping, area, hull, 3D IoU / GIoU."""

from __future__ import annotations

import math

import numpy as np
import pytest
from vehicle_common.box3d import (
    bev_corners,
    box_corners,
    clip_convex_polygon,
    convex_hull,
    giou_3d,
    iou_3d,
    polygon_area,
)


def _signed_area(p: np.ndarray) -> float:
    return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


def _cube(x=0.0, y=0.0, z=10.0, ry=0.0, dims=(2.0, 2.0, 2.0)):
    return dims, (x, y, z), ry


@pytest.mark.parametrize("ry", [0.0, 0.3, math.pi / 2, -2.0, math.pi])
def test_bev_corners_are_the_bottom_face_counter_clockwise(ry):
    dims, loc = (1.5, 1.6, 4.0), (1.0, 1.5, 10.0)
    p = bev_corners(dims, loc, ry)
    assert _signed_area(p) == pytest.approx(1.6 * 4.0)
    bottom = box_corners(dims, loc, ry)[:4][:, [0, 2]]
    assert sorted(map(tuple, np.round(p, 9))) == sorted(map(tuple, np.round(bottom, 9)))


def test_bev_corners_turned_by_90_degrees_swap_extents():
    p = bev_corners((1.0, 2.0, 4.0), (0.0, 0.0, 0.0), math.pi / 2)
    np.testing.assert_allclose(p.min(axis=0), [-1.0, -2.0], atol=1e-12)
    np.testing.assert_allclose(p.max(axis=0), [1.0, 2.0], atol=1e-12)


def test_polygon_area_clip_and_hull():
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    assert polygon_area(square) == 4.0
    assert polygon_area([(0.0, 0.0), (3.0, 0.0), (0.0, 1.0)]) == 1.5
    assert polygon_area(square[:2]) == 0.0
    inter = clip_convex_polygon(square, square + [1.0, 1.0])
    assert polygon_area(inter) == pytest.approx(1.0)
    assert sorted(inter) == [(1.0, 1.0), (1.0, 2.0), (2.0, 1.0), (2.0, 2.0)]
    assert clip_convex_polygon(square, square + [5.0, 0.0]) == []
    pts = np.vstack([square, [[1.0, 1.0], [0.5, 1.5], [2.0, 2.0]]])
    hull = convex_hull(pts)
    assert sorted(map(tuple, hull.tolist())) == sorted(map(tuple, square.tolist()))
    assert _signed_area(hull) == 4.0  # counter-clockwise


def test_iou_and_giou_of_identical_boxes():
    a = ((1.5, 1.6, 4.0), (1.0, 1.5, 10.0), 0.3)
    assert iou_3d(a, a) == 1.0
    iou, giou = giou_3d(a, a)
    assert iou == pytest.approx(1.0) and giou == pytest.approx(1.0)


def test_square_footprint_turned_by_90_degrees_is_the_same_box():
    a = _cube(ry=0.2)
    b = _cube(ry=0.2 + math.pi / 2)
    assert iou_3d(a, b) == pytest.approx(1.0)
    assert giou_3d(a, b) == pytest.approx((1.0, 1.0))


def test_rectangle_turned_by_90_degrees():
    # 4 x 1.6 footprints crossing: 1.6^2 / (2 * 6.4 - 1.6^2) = 0.25; hull: an octagon, the
    # 4 x 4 square less four 1.2 x 1.2 corner triangles
    a = ((1.5, 1.6, 4.0), (0.0, 1.5, 10.0), 0.0)
    b = ((1.5, 1.6, 4.0), (0.0, 1.5, 10.0), math.pi / 2)
    assert iou_3d(a, b) == pytest.approx(0.25)
    union, hull = 2 * 6.4 * 1.5 - 2.56 * 1.5, (4.0 * 4.0 - 4 * 1.2 * 1.2 / 2) * 1.5
    assert giou_3d(a, b) == pytest.approx((0.25, 0.25 - (hull - union) / hull))


def test_hand_computed_partial_overlaps():
    a = _cube()
    # shifted by half its length along x: intersection 1 x 2 x 2 = 4, union 12, hull = union
    assert iou_3d(a, _cube(x=1.0)) == pytest.approx(1 / 3)
    assert giou_3d(a, _cube(x=1.0)) == pytest.approx((1 / 3, 1 / 3))
    # bottom-centre convention: a spans y in [-2, 0], the other [-3, -1]; overlap 1 -> 1/3
    assert iou_3d(a, _cube(y=-1.0)) == pytest.approx(1 / 3)
    assert giou_3d(a, _cube(y=-1.0)) == pytest.approx((1 / 3, 1 / 3))
    # 2 x 2 footprint and itself turned by 45 deg: a regular octagon, IoU = 1/sqrt(2)
    assert iou_3d(a, _cube(ry=math.pi / 4)) == pytest.approx(1 / math.sqrt(2))


def test_disjoint_boxes():
    a = _cube()
    far = _cube(x=4.0)  # footprints [-1, 1] and [3, 5] in x: hull 6 x 2 x 2 = 24, union 16
    assert iou_3d(a, far) == 0.0
    iou, giou = giou_3d(a, far)
    assert iou == 0.0 and giou == pytest.approx(-1 / 3)
    touching = _cube(y=-2.0)  # a spans y in [-2, 0], this one [-4, -2]: they fill their hull
    assert iou_3d(a, touching) == 0.0
    assert giou_3d(a, touching) == pytest.approx((0.0, 0.0))
    above = _cube(y=-3.0)  # [-5, -3]: hull 2 x 2 x 5 = 20, union 16
    assert iou_3d(a, above) == 0.0
    assert giou_3d(a, above) == pytest.approx((0.0, -0.2))
    assert iou_3d(a, _cube(dims=(-1.0, 2.0, 2.0))) == 0.0


def test_tracker_centre_boxes_use_the_same_overlap():
    from tracker_node.overlap import giou_3d as tracker_giou

    # centre (0, -1, 10) with h = 2 is the bottom-centre (0, 0, 10) box
    a = np.array([0.0, -1.0, 10.0, 2.0, 2.0, 2.0, 0.0])
    b = np.array([1.0, -2.0, 10.0, 2.0, 2.0, 2.0, 0.0])
    assert tracker_giou(a, b) == pytest.approx(giou_3d(_cube(), _cube(x=1.0, y=-1.0)))
    assert tracker_giou(a, b)[0] == pytest.approx(1 / 7)  # 1 x 2 x 1 = 2 over 8 + 8 - 2
