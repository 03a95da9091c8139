"""Centre correction: surface-to-centre geometry against box3d, and ranging of rendered boxes."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from stereo_depth_node.disparity import INVALID_DISPARITY
from stereo_depth_node.ranging import (
    RangingParams,
    bin_centre_offsets,
    centre_depth_behind_surface,
    range_boxes,
)
from stereo_depth_node.reprojection import StereoGeometry
from vehicle_common.box3d import box_corners
from vehicle_common.kitti import rotation_y_from_alpha
from vehicle_common.orientation_bins import alpha_to_bin

GEO = StereoGeometry(721.5377, 721.5377, 609.5593, 172.854, 0.5371)
FB = GEO.fx * GEO.baseline
DIMS = (1.5, 1.6, 3.9)  # h, w, l
ALPHAS = np.radians([-170.0, -135.0, -100.0, -90.0, -60.0, -20.0, 0.0, 30.0, 45.0, 90.0, 150.0])


def box_axes(rotation_y: float):
    """Unit length and width axes (x, z) of a KITTI box, read off box_corners."""
    c = box_corners((1.0, 2.0, 4.0), (0.0, 0.0, 0.0), rotation_y)[:, [0, 2]]
    length_axis = (c[0] - c[3]) / 4.0  # corners 0 -> 3: back to front along the length
    width_axis = (c[0] - c[1]) / 2.0  # corners 0 -> 1: across the width
    return length_axis, width_axis


@pytest.mark.parametrize("alpha", ALPHAS)
def test_nearest_model_is_the_box_extent_along_the_ray(alpha):
    x, z = 6.0, 25.0
    ry = rotation_y_from_alpha(float(alpha), x, z)
    corners = box_corners(DIMS, (x, 0.75, z), ry)[:, [0, 2]]  # centre at camera height
    centre = np.array([x, z])
    ray = centre / np.linalg.norm(centre)
    extent = float(np.max((centre - corners) @ ray))
    expected = centre_depth_behind_surface(alpha, DIMS[2], DIMS[1], "nearest")
    assert extent == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("alpha", ALPHAS)
def test_visible_model_is_the_mean_depth_of_the_visible_faces(alpha):
    """Parallel rays, evenly spaced across the box's image width: mean depth of the first hit."""
    x, z = -4.0, 30.0
    ry = rotation_y_from_alpha(float(alpha), x, z)
    length_axis, width_axis = box_axes(ry)
    ray = np.array([x, z]) / math.hypot(x, z)
    perp = np.array([ray[1], -ray[0]])
    a, b = DIMS[2] / 2, DIMS[1] / 2
    half_width = a * abs(perp @ length_axis) + b * abs(perp @ width_axis)
    depths = []
    for s in np.linspace(-half_width, half_width, 20001)[1:-1]:
        entry = -np.inf
        for axis, half in ((length_axis, a), (width_axis, b)):
            o, d = s * (perp @ axis), ray @ axis  # ray point s*perp + t*ray in box coordinates
            if abs(d) < 1e-12:
                continue
            entry = max(entry, min((-half - o) / d, (half - o) / d))
        depths.append(-entry)  # depth of the hit in front of the centre
    expected = centre_depth_behind_surface(alpha, DIMS[2], DIMS[1], "visible")
    assert np.mean(depths) == pytest.approx(expected, rel=2e-3)


def test_bin_offsets_side_rear_and_diagonal():
    vis = bin_centre_offsets(3.9, 1.6, "visible")
    near = bin_centre_offsets(3.9, 1.6, "nearest")
    diag = 1.95 * 0.8 * math.sqrt(2) / 2.75  # a b / ((a + b) / sqrt 2)
    assert vis[:4] == pytest.approx([0.8, diag, 1.95, diag])
    assert near[:4] == pytest.approx([0.8, 2.75 / math.sqrt(2), 1.95, 2.75 / math.sqrt(2)])
    assert vis[4] == pytest.approx(np.mean(vis[:4]))
    spread = bin_centre_offsets(3.9, 1.6, "visible", spread=1.0)
    assert spread[2] < vis[2] and spread[0] < vis[0]  # side faces seen off the bin centre


def render_box_disparity(location, rotation_y: float, background: float = 80.0):
    """Exact disparity of a (h, w, l) = DIMS box in front of a wall at ``background`` metres."""
    h, w = 375, 1242
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    dirs = np.stack(
        [(u - GEO.cx) / GEO.fx, (v - GEO.cy) / GEO.fy, np.ones_like(u)], axis=-1
    )  # rays with z = 1: the hit parameter t is the depth
    corners = box_corners(DIMS, location, rotation_y)
    centre = corners.mean(axis=0)
    axes = [corners[0] - corners[3], corners[4] - corners[0], corners[0] - corners[1]]
    t_in = np.full((h, w), -np.inf)
    t_out = np.full((h, w), np.inf)
    for ax in axes:
        half = np.linalg.norm(ax) / 2
        ax = ax / np.linalg.norm(ax)
        o, d = -centre @ ax, dirs @ ax
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - o) / d, (half - o) / d
        t_in = np.maximum(t_in, np.minimum(t1, t2))
        t_out = np.minimum(t_out, np.maximum(t1, t2))
    hit = (t_in <= t_out) & (t_in > 0)
    depth = np.where(hit, t_in, background)
    disp = (FB / depth).astype(np.float32)
    return disp, corners, centre


@pytest.mark.parametrize(
    ("alpha_deg", "x", "z", "max_err"),
    # rear and side views: the visible face is flat, the correction is exact; diagonal: the
    # robust mode of the box core sits nearer than the faces' mean (toward the nearest corner)
    [(-90.0, 1.5, 20.0, 0.3), (-45.0, -3.0, 15.0, 0.9), (0.0, 4.0, 25.0, 0.3)],
)
def test_corrected_estimate_is_nearer_the_centre_of_mass(alpha_deg, x, z, max_err):
    alpha = math.radians(alpha_deg)
    ry = rotation_y_from_alpha(alpha, x, z)
    disp, corners, centre = render_box_disparity((x, 1.65, z), ry)
    rng = np.random.default_rng(5)
    disp += rng.normal(0.0, 0.1, disp.shape).astype(np.float32)
    disp[rng.random(disp.shape) < 0.05] = INVALID_DISPARITY
    pts = np.stack(
        [
            GEO.fx * corners[:, 0] / corners[:, 2] + GEO.cx,
            GEO.fy * corners[:, 1] / corners[:, 2] + GEO.cy,
        ],
        axis=1,
    )
    box = (*pts.min(axis=0), *pts.max(axis=0))
    b = alpha_to_bin(alpha)
    # rendered disparities: no real-camera bias; a box, not a rounded car: no inset
    exact = RangingParams(disparity_bias=0.0, disparity_bias_column=0.0, surface_inset=0.0)
    on = range_boxes(disp, [box], GEO, exact, [b])[0]
    off = range_boxes(disp, [box], GEO, replace(exact, centre_correction=False), [b])[0]
    err_on = np.linalg.norm(on.position - centre)
    err_off = np.linalg.norm(off.position - centre)
    assert err_on < err_off - 0.5
    assert err_on < max_err
