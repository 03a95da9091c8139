"""Ranging core: occluded synthetic boxes, median baseline, covariance model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from stereo_depth_node.disparity import INVALID_DISPARITY
from stereo_depth_node.ranging import (
    RangingParams,
    RangingSetup,
    position_covariance,
    range_boxes,
)
from stereo_depth_node.reprojection import StereoGeometry

GEO = StereoGeometry(721.5377, 721.5377, 609.5593, 172.854, 0.5371)
FB = GEO.fx * GEO.baseline
# the visible-surface estimate alone, on exact synthetic disparities (no real-camera bias)
SURFACE = RangingParams(
    centre_correction=False, disparity_bias=0.0, disparity_bias_column=0.0, lateral_fit=False
)


def scene_with_occluded_car():
    """Background at 60 m; a car at 20 m (box 500..640 x 140..220, height ~1.5 m at 20 m);
    a nearer car at 8 m covering the left 60 % of the far car's box (two thirds of its core)."""
    h, w = 375, 1242
    rng = np.random.default_rng(1)
    disp = np.full((h, w), FB / 60.0, np.float32)
    car = (500, 150, 640, 204)  # x1, y1, x2, y2; 54 px tall = 1.5 m at 20 m
    disp[car[1] : car[3], car[0] : car[2]] = FB / 20.0
    occluder = (420, 120, 584, 260)
    disp[occluder[1] : occluder[3], occluder[0] : occluder[2]] = FB / 8.0
    disp += rng.normal(0, 0.2, disp.shape).astype(np.float32)
    holes = rng.random(disp.shape) < 0.1
    disp[holes] = INVALID_DISPARITY
    return disp, car


def test_robust_ranging_returns_the_occluded_car_not_the_occluder():
    disp, car = scene_with_occluded_car()
    robust = range_boxes(disp, [car], GEO, SURFACE)[0]
    median = range_boxes(disp, [car], GEO, replace(SURFACE, method="median"))[0]
    assert robust is not None and median is not None
    assert robust.position[2] == pytest.approx(20.0, abs=1.0)
    assert median.position[2] < 12.0  # the baseline's known weakness: the occluder wins
    assert 0.85 < robust.valid_pixel_fraction < 0.95
    assert robust.disparity == pytest.approx(FB / 20.0, rel=0.05)


def test_unoccluded_box_range_and_lateral_position():
    disp = np.full((375, 1242), FB / 15.0, np.float32)
    box = (800.0, 150.0, 900.0, 222.0)
    r = range_boxes(disp, [box], GEO, SURFACE)[0]
    u, v = 850.0, 186.0
    np.testing.assert_allclose(r.position, GEO.backproject(u, v, 15.0), rtol=1e-4)


def test_depth_offset_moves_along_the_ray_per_orientation_bin():
    disp = np.full((375, 1242), FB / 15.0, np.float32)
    box = (900.0, 150.0, 1000.0, 222.0)
    p = replace(SURFACE, depth_offset=(0.0, 0.0, 2.0, 0.0))
    r0, r2 = range_boxes(disp, [box, box], GEO, p, orientation_bins=[0, 2])
    step = r2.position - r0.position
    assert np.linalg.norm(step) == pytest.approx(2.0, rel=1e-6)
    ray = GEO.backproject(950.0, 186.0, 1.0)
    np.testing.assert_allclose(step / 2.0, ray / np.linalg.norm(ray), rtol=1e-6)


def test_boxes_without_depth_are_none():
    disp = np.full((375, 1242), INVALID_DISPARITY, np.float32)
    disp[:, :600] = FB / 10.0
    out = range_boxes(
        disp, [(700, 100, 800, 200), (100, 100, 200, 200), (10, 10, 5, 20)], GEO, RangingParams()
    )
    assert out[0] is None and out[1] is not None and out[2] is None
    assert range_boxes(disp, np.zeros((0, 4)), GEO) == []


def test_covariance_follows_the_stereo_error_model():
    p = RangingParams(sigma_d=0.5, sigma_pixel=2.0, depth_offset_std=0.0)
    for z in (10.0, 40.0):
        cov = position_covariance(GEO.cx, GEO.cy, z, GEO, p)
        assert np.sqrt(cov[2, 2]) == pytest.approx(z * z * 0.5 / FB)
        assert np.sqrt(cov[0, 0]) == pytest.approx(2.0 * z / GEO.fx)
        assert cov[0, 2] == pytest.approx(0.0)
    off = position_covariance(GEO.cx + 300, GEO.cy, 20.0, GEO, p)
    assert off[0, 2] > 0 and np.allclose(off, off.T)
    assert np.all(np.linalg.eigvalsh(off) > 0)


def test_invalid_method_raises():
    with pytest.raises(ValueError):
        range_boxes(np.ones((10, 10), np.float32), [(0, 0, 5, 5)], GEO, RangingParams(method="x"))


def test_invalid_orientation_bin_uses_the_mean_correction_not_a_wrapped_bin():
    disp = np.full((375, 1242), FB / 15.0, np.float32)
    box = (900.0, 150.0, 1000.0, 222.0)
    p = RangingParams(depth_offset=(0.5, 0.0, 0.0, 0.0))
    none = range_boxes(disp, [box], GEO, p)[0]
    got = range_boxes(disp, [box] * 4, GEO, p, orientation_bins=[4, 0, 255, -1])
    np.testing.assert_allclose(got[0].position, none.position, rtol=1e-12)
    np.testing.assert_allclose(got[2].position, none.position, rtol=1e-12)
    np.testing.assert_allclose(got[3].position, none.position, rtol=1e-12)
    # bin 0 (side view) is nearer than the mean; bin 4 must not have been wrapped onto it
    assert np.linalg.norm(got[1].position) < np.linalg.norm(got[0].position) - 0.1


def test_prepared_setup_gives_the_same_results_and_validates_once():
    disp, car = scene_with_occluded_car()
    boxes, bins = [car, (700, 100, 800, 200)], [2, 1]
    p = RangingParams(correction_bin_spread=0.5, depth_offset=(0.1, 0.2, 0.3, 0.4))
    setup = RangingSetup.from_params(p)
    assert setup.params is p and setup.centre_offsets.shape == (5,)
    a = range_boxes(disp, boxes, GEO, p, bins)
    b = range_boxes(disp, boxes, GEO, setup, bins)
    for ra, rb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ra.position, rb.position)
        np.testing.assert_array_equal(ra.covariance, rb.covariance)
        assert (ra.disparity, ra.valid_pixel_fraction) == (rb.disparity, rb.valid_pixel_fraction)
    with pytest.raises(ValueError):
        RangingSetup.from_params(RangingParams(core_fraction=0.0))
    off = RangingSetup.from_params(RangingParams(centre_correction=False)).centre_offsets
    assert np.all(off == 0.0)


def test_depth_std_on_a_camera_follows_the_error_model_and_its_f_times_baseline():
    """The stereo node's camera line states the depth std a car is ranged with at 20 / 40 /
    60 m: on KITTI's camera 0.5 / 0.9 / 1.7 m (far boxes refined: sigma_d_far); on a camera
    with a quarter of the f x B, larger, as z^2 / (f B) says beyond the offset's floor."""
    from stereo_depth_node.ranging import depth_std_at, precision_line

    p = RangingParams()
    assert [round(depth_std_at(z, GEO, p), 1) for z in (20, 40, 60)] == [0.5, 0.9, 1.7]
    z = 40.0
    expect = np.hypot(z * z * p.sigma_d_far / FB, p.depth_offset_std)
    assert depth_std_at(z, GEO, p) == pytest.approx(expect)
    short = StereoGeometry(GEO.fx, GEO.fy, GEO.cx, GEO.cy, GEO.baseline / 4)
    assert depth_std_at(z, short, p) == pytest.approx(
        np.hypot(4 * z * z * p.sigma_d_far / FB, p.depth_offset_std)
    )
    unrefined = replace(p, refine="none")  # every box at the map's sigma_d
    assert depth_std_at(z, GEO, unrefined) == pytest.approx(
        np.hypot(z * z * p.sigma_d / FB, p.depth_offset_std)
    )
    near = 5.0  # disparity above refine_max_disparity: the map's sigma_d
    assert depth_std_at(near, GEO, p) == pytest.approx(
        np.hypot(near * near * p.sigma_d / FB, p.depth_offset_std)
    )
    line = precision_line(short, p)
    assert line.startswith("ranging depth std ") and "at 20 / 40 / 60 m" in line
    assert f"f x baseline {FB / 4:.0f} px m" in line
