"""Lateral footprint fit of the box-to-centre step, against projected KITTI 3D boxes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from stereo_depth_node.centre_fit import fit_lateral
from stereo_depth_node.reprojection import StereoGeometry
from vehicle_common.box3d import projected_bbox
from vehicle_common.kitti import rotation_y_from_alpha

GEO = StereoGeometry(721.5377, 721.5377, 609.5593, 172.854, 0.5327)
P = np.array([[GEO.fx, 0, GEO.cx, 0], [0, GEO.fy, GEO.cy, 0], [0, 0, 1, 0]], float)
W, H = 1242, 375
DIMS = (1.5, 1.6, 3.9)  # h, w, l


def car_box(x: float, z: float, alpha: float, clip: bool = True):
    ry = rotation_y_from_alpha(alpha, x, z)
    return projected_bbox(P, DIMS, (x, 1.65, z), ry, (W, H) if clip else None)


@pytest.mark.parametrize(
    ("x", "z", "alpha_deg"),
    [(-4.0, 8.0, 45.0), (3.0, 7.0, 135.0), (-6.0, 6.5, 90.0), (5.5, 12.0, 0.0)],
)
def test_fit_moves_a_wrongly_placed_centre_onto_the_true_lateral_position(x, z, alpha_deg):
    alpha = math.radians(alpha_deg)
    box = car_box(x, z, alpha)
    centre = np.array([x, 1.65 - 0.75, z])
    start = centre + np.array([1.0, 0.0, 0.0])  # 1 m off sideways, right depth
    got = fit_lateral(start, box, alpha, DIMS[2], DIMS[1], GEO, W)
    assert got[2] == start[2] and got[1] == start[1]
    assert got[0] == pytest.approx(x, abs=0.05)


def test_truncated_box_uses_its_inner_edge_only():
    alpha = math.radians(90.0)
    x, z = -4.6, 5.0  # the left part of the car is out of the image
    full = car_box(x, z, alpha, clip=False)
    box = car_box(x, z, alpha)
    assert full[0] < 0 and box[0] == 0.0
    start = np.array([x + 1.2, 0.9, z])
    got = fit_lateral(start, box, alpha, DIMS[2], DIMS[1], GEO, W)
    assert got[0] == pytest.approx(x, abs=0.05)
    # both sides cut: nothing to fit
    both = (0.0, 100.0, W - 1.0, 300.0)
    assert np.array_equal(fit_lateral(start, both, alpha, DIMS[2], DIMS[1], GEO, W), start)
