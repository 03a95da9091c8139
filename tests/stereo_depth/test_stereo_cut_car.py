"""Cars cut by the image border (issue #34 part 2): ranged from their visible part.

A car beside the camera whose box the left or right image border cuts shows only part of
itself: seen from behind and to the side, often its far end (the near end is out of view). Its
centre is the footprint that keeps the box's inner edge and gives the measured surface
(``centre_fit.fit_cut_box``), not the visible surface plus a whole car's offset; and a near one,
beyond the disparity map's range, is matched at full resolution on its box.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from stereo_depth_node.centre_fit import footprint_columns, surface_depths
from stereo_depth_node.disparity import DisparityParams, compute_disparity
from stereo_depth_node.ranging import RangingParams, range_boxes
from stereo_depth_node.reprojection import StereoGeometry
from vehicle_common.box3d import projected_bbox
from vehicle_common.kitti import alpha_from_rotation_y

GEO = StereoGeometry(721.5377, 721.5377, 609.5593, 172.854, 0.5327)
P = np.array([[GEO.fx, 0, GEO.cx, 0], [0, GEO.fy, GEO.cy, 0], [0, 0, 1, 0]], float)
W, H = 1242, 375
HWL = (1.5, 1.6, 3.9)  # the ranging's mean car
EXACT = RangingParams(refine="none", disparity_bias=0.0, disparity_bias_column=0.0)


def box_surface(x: float, z: float, ry: float, shape=(H, W)) -> np.ndarray:
    """Exact disparity map of a KITTI box (bottom centre x, 1.65, z; yaw ry): the depth where
    each pixel's ray enters it, -1 elsewhere."""
    h, w, length = HWL
    vs, us = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
    c, s = math.cos(ry), math.sin(ry)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # box frame -> camera
    d = np.stack([(us - GEO.cx) / GEO.fx, (vs - GEO.cy) / GEO.fy, np.ones_like(us)], -1)
    o = rot.T @ -np.array([x, 1.65, z])
    db = d @ rot
    lo, hi = np.array([-length / 2, -h, -w / 2]), np.array([length / 2, 0.0, w / 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - o) / db, (hi - o) / db
    t_in = np.nanmax(np.minimum(t1, t2), axis=-1)
    t_out = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (t_in <= t_out) & (t_in > 0)
    return np.where(hit, GEO.fx * GEO.baseline / np.where(hit, t_in, 1.0), -1.0).astype(np.float32)


def cut_car(x: float, z: float, heading_deg: float):
    """(disparity map, clipped 2D box, observation angle, centre of mass) of a mean car."""
    ry = math.radians(heading_deg)
    box = projected_bbox(P, HWL, (x, 1.65, z), ry, (W, H))
    alpha = alpha_from_rotation_y(ry, x, z)
    return box_surface(x, z, ry), box, alpha, np.array([x, 1.65 - HWL[0] / 2, z])


@pytest.mark.parametrize(
    ("x", "z", "heading_deg"),
    [
        (-6.0, 4.5, -90.0),  # parked on the left, heading away: only its front is in view
        (-4.5, 3.5, -70.0),
        (-3.5, 7.0, -90.0),  # more of it in view, its rear still cut
        (4.5, 3.5, -70.0),  # on the right, heading away
        (6.0, 4.5, 90.0),  # on the right, oncoming
    ],
)
def test_centre_of_a_car_cut_by_the_image_border(x, z, heading_deg):
    disp, box, alpha, com = cut_car(x, z, heading_deg)
    assert box[0] == 0.0 or box[2] == W - 1.0  # cut by the border
    r = range_boxes(disp, [box], GEO, EXACT, observation_angles=[alpha])[0]
    assert r is not None
    err = r.position - com
    # the rendered box has no rounded surface: the inset (0.2 m) is the expected offset
    assert abs(err[2]) < 0.45 and abs(err[0]) < 0.45, err
    # the previous step (visible surface + a whole car's offset on the box-centre ray) put such
    # a car metres too far and off to the side
    old = range_boxes(disp, [box], GEO, replace(EXACT, cut_box_fit=False), None, None, [alpha])
    assert np.linalg.norm(old[0].position - com) > 2 * np.linalg.norm(err)


def test_surface_depths_are_the_footprint_seen_per_column():
    centre = np.array([-3.0, 0.9, 10.0])
    alpha = math.radians(60.0)
    lo, hi = footprint_columns(centre, alpha, 3.9, 1.6, GEO)
    us = np.arange(math.floor(lo) - 5, math.ceil(hi) + 5) + 0.5
    z = surface_depths(us, centre, alpha, 3.9, 1.6, GEO)
    inside = (us > lo) & (us < hi)
    assert np.isfinite(z[inside]).all() and not np.isfinite(z[(us < lo - 1) | (us > hi + 1)]).any()
    # the nearest of them is the footprint's nearest corner
    ry = alpha + math.atan2(centre[0], centre[2])
    dx, dz = np.array([1, 1, -1, -1]) * 1.95, np.array([1, -1, -1, 1]) * 0.8
    corners_z = centre[2] - math.sin(ry) * dx + math.cos(ry) * dz
    assert np.nanmin(z) == pytest.approx(corners_z.min(), abs=0.05)


def test_near_cut_car_beyond_the_maps_range_is_matched_on_its_box():
    """A car 3.2-4 m away at the right border: disparity 96-120 px, beyond the default map's 96;
    the map has no valid estimate of it, the box's full-resolution match does."""
    rng = np.random.default_rng(3)
    d_bg, d_car = 20, 110
    # a random texture, smoothed a little (SGBM's block matching wants some correlation)
    left = rng.integers(0, 255, size=(H, W)).astype(np.float32)
    left = ((left + np.roll(left, 1, 1) + np.roll(left, 1, 0)) / 3).astype(np.uint8)
    car_rows, car_cols = slice(120, H), slice(1000, W)
    # right(u - d) = left(u): the background at 20 px, the car (in front) at 110 px
    right = np.zeros_like(left)
    right[:, : W - d_bg] = left[:, d_bg:]
    right[car_rows, 1000 - d_car : W - d_car] = left[car_rows, car_cols]
    rgb = lambda g: np.repeat(g[:, :, None], 3, axis=2)  # noqa: E731
    disp = compute_disparity(rgb(left), rgb(right), DisparityParams())
    box = (1000.0, 120.0, W - 1.0, H - 1.0)
    images = (left, right)
    params = replace(RangingParams(), disparity_bias=0.0, disparity_bias_column=0.0)
    r = range_boxes(disp, [box], GEO, params, [2], images)[0]
    assert r is not None and r.disparity == pytest.approx(d_car, abs=2.0)
    old = range_boxes(disp, [box], GEO, replace(params, cut_box_fit=False), [2], images)[0]
    assert old is None or abs(old.disparity - d_car) > 10.0
