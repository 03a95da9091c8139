"""Cars partly hidden by a nearer car (issue #41 item 2): the occluder cut.

A car parked behind another shows only part of itself; a detector boxes that part, KITTI labels
the full extent. The side hidden by the nearer car is found in the disparity map beside the box,
the centre is fitted from the visible part with the other edge kept, and the box is extended on
the hidden side only to the fitted car's full-extent projection.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from plausibility_scenes import GEO, Car, Road, _car_hit, corners, label_box, render
from stereo_depth_node.occluder import map_boxes
from stereo_depth_node.ranging import RangingParams, range_boxes

H, W = 375, 1242
EXACT = RangingParams(refine="none", disparity_bias=0.0, disparity_bias_column=0.0)
# rows of cars 6-7 m apart: beside the far car's box the strip shows the nearer car's side face,
# only 2-3 m nearer, so a margin of 2 m (the shipped-off default, 3 m, chosen on the tuning
# keyframes by a tie-break, misses these; docs/stereo_depth.md section 12)
CUT = replace(EXACT, occluder_cut=True, occluder_margin=2.0, occluder_share=0.5)


def iou(a, b) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def visible_box(car: Car, others: list[Car], road: Road):
    """The detector's box of ``car``: the bounds of its pixels no other car hides."""
    v, u = np.mgrid[0:H, 0:W]
    a, b = (u - GEO.cx) / GEO.fx, (v - GEO.cy) / GEO.fy
    hit = _car_hit(car, road, a, b)
    seen = np.isfinite(hit)
    for o in others:
        seen &= hit < _car_hit(o, road, a, b)
    rows, cols = np.nonzero(seen)
    return (float(cols.min()), float(rows.min()), float(cols.max() + 1), float(rows.max() + 1))


def alpha_of(car: Car) -> float:
    """KITTI observation angle of a scene car (scene yaw 0: heading along +z)."""
    return (car.yaw - math.pi / 2) - math.atan2(car.x, car.z)


def centre_of(car: Car, road: Road) -> np.ndarray:
    return corners(car, road).mean(axis=0)


def ranged(road: Road, cars: list[Car], boxes, params):
    disp = render(road, cars, map_boxes(boxes, params.occluder_strip))
    alphas = [alpha_of(c) for c in cars[: len(boxes)]]
    return range_boxes(disp, boxes, GEO, params, observation_angles=alphas)


@pytest.mark.parametrize(
    ("far", "near", "side"),
    [
        # parked on the right, its right part hidden by a taller car (a van)
        (Car(3.0, 35.0), Car(3.7, 29.0, height=1.8), 2),
        (Car(-3.2, 32.0), Car(-4.0, 26.0), 0),  # on the left, its left part hidden
        (Car(4.0, 40.0, yaw=0.3), Car(4.0, 33.0, yaw=0.3), 2),  # parked at an angle
    ],
)
def test_hidden_side_is_found_and_the_box_extended_to_the_full_extent(far, near, side):
    road = Road()
    full = label_box(far, road)
    box = visible_box(far, [near], road)
    assert iou(box, full) < 0.8  # a good part of it hidden
    r = ranged(road, [far, near], [box, label_box(near, road)], CUT)
    out = r[0].box
    assert out is not None
    assert out[side] == pytest.approx(full[side], abs=4.0)  # the hidden side: the full extent
    kept = 2 - side  # the visible side and the top and bottom: the detector's
    assert out[kept] == box[kept] and out[1] == box[1] and out[3] == box[3]
    assert iou(out, full) > iou(box, full) + 0.1
    # the centre from the visible part with the visible edge kept: no worse than before
    old = ranged(road, [far, near], [box, label_box(near, road)], EXACT)[0]
    err = np.linalg.norm((r[0].position - centre_of(far, road))[[0, 2]])
    err_old = np.linalg.norm((old.position - centre_of(far, road))[[0, 2]])
    assert err < 1.0 and err <= err_old + 0.1
    # the nearer car, in front of the other: nothing of it is hidden
    assert r[1].box is None


@pytest.mark.parametrize("car", [Car(3.0, 35.0), Car(-2.5, 20.0, yaw=0.6), Car(0.2, 50.0)])
def test_an_unoccluded_car_is_not_extended(car):
    road = Road()
    box = label_box(car, road)
    r = ranged(road, [car], [box], CUT)[0]
    assert r is not None and r.box is None
    # beside a farther car (the strip is behind it): not extended either
    farther = Car(car.x + math.copysign(1.5, car.x), car.z + 7.0)
    r2 = ranged(road, [car, farther], [box], CUT)[0]
    assert r2.box is None


def test_extension_stops_where_the_nearer_object_ends():
    """The full-extent box of a mean car may overshoot (a wrong angle, a shorter car): the
    hidden part of a car lies behind the nearer object, so the box grows no farther."""
    from stereo_depth_node.occluder import hidden_reach

    disp = np.full((120, 300), 5.0, np.float32)  # background at 77 m
    disp[40:90, 100:140] = 14.0  # the car's visible part at 27.7 m
    disp[30:100, 80:100] = 30.0  # a post 12.9 m away, hiding the car's left part
    box = (100.0, 40.0, 140.0, 90.0)
    args = (14.0, GEO, 0.0, 0.3, 1.65, 0.3)
    reach = hidden_reach(disp, box, (60.0, 40.0, 140.0, 90.0), *args)
    assert reach == (80.0, 40.0, 140.0, 90.0)  # the background from column 79 on
    assert hidden_reach(disp, box, (88.0, 40.0, 140.0, 90.0), *args)[0] == 88.0


def test_the_published_box_is_the_extended_one():
    msgs = pytest.importorskip("stereo_vehicle_msgs.msg")
    from stereo_depth_node.conversions import detection_3d_message
    from stereo_depth_node.ranging import RangeResult
    from vehicle_common.frame_messages import bbox_to_xyxy, xyxy_to_bbox

    det = msgs.VehicleDetection2D()
    xyxy_to_bbox((100.0, 40.0, 140.0, 90.0), det.bbox)
    r = RangeResult(np.zeros(3), np.eye(3), 10.0, 0.5, 0.3, (80.0, 40.0, 140.0, 90.0))
    assert bbox_to_xyxy(detection_3d_message(det, r).bbox) == (80.0, 40.0, 140.0, 90.0)
    plain = RangeResult(np.zeros(3), np.eye(3), 10.0, 0.5, 0.3)
    assert bbox_to_xyxy(detection_3d_message(det, plain).bbox) == (100.0, 40.0, 140.0, 90.0)
    assert bbox_to_xyxy(det.bbox) == (100.0, 40.0, 140.0, 90.0)  # the input left as it was
