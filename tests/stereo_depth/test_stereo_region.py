"""Box-region matcher: full-resolution disparity and box-level shift on a synthetic pair."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from stereo_depth_node.region_matching import RegionParams, box_disparity, refine_shift

CAR = (560, 160, 620, 190)  # x1, y1, x2, y2 of a far car (8.3 px of disparity)


def textured_pair(d_car: float = 8.3, d_background: float = 4.0):
    """Left/right gray images: smooth random texture; the car box at ``d_car``, the rest at
    ``d_background`` (right(u - d) = left(u), sub-pixel by linear interpolation)."""
    rng = np.random.default_rng(3)
    h, w = 375, 1242
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 1.2)
    disp = np.full((h, w), d_background, np.float32)
    disp[CAR[1] : CAR[3], CAR[0] - 10 : CAR[2] + 10] = d_car
    # right image: for each right pixel x, the left pixel x + d (d of the surface seen there)
    xs = np.arange(w, dtype=np.float32)[None, :] + disp
    ys = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w))
    right = cv2.remap(tex, xs, np.ascontiguousarray(ys), cv2.INTER_LINEAR)
    return tex.clip(0, 255).astype(np.uint8), right.clip(0, 255).astype(np.uint8)


@pytest.mark.parametrize("estimator", [box_disparity, refine_shift])
def test_region_estimators_recover_a_sub_pixel_car_disparity(estimator):
    left, right = textured_pair()
    d, n = estimator(left, right, CAR, 8.0)  # coarse start 0.3 px off
    assert n >= RegionParams().min_pixels
    assert d == pytest.approx(8.3, abs=0.12)


def test_region_estimators_give_up_without_a_usable_start():
    left, right = textured_pair()
    assert np.isnan(box_disparity(left, right, CAR, float("nan"))[0])
    assert np.isnan(refine_shift(left, right, (5, 5, 6, 6), 8.0)[0])  # box too small


def test_range_boxes_refines_far_boxes_on_the_pair_and_subtracts_the_bias():
    from dataclasses import replace

    from stereo_depth_node.ranging import RangingParams, range_boxes
    from stereo_depth_node.reprojection import StereoGeometry

    left, right = textured_pair()
    geo = StereoGeometry(721.5, 721.5, 609.6, 172.9, 0.5327)
    coarse = np.full(left.shape, 8.0, np.float32)  # a map 0.3 px off on the car
    params = RangingParams(
        centre_correction=False, lateral_fit=False, reject_ground=False, disparity_bias_column=0.0
    )
    plain = range_boxes(coarse, [CAR], geo, replace(params, disparity_bias=0.0))[0]
    refined = range_boxes(
        coarse, [CAR], geo, replace(params, disparity_bias=0.0), None, (left, right)
    )[0]
    biased = range_boxes(
        coarse, [CAR], geo, replace(params, disparity_bias=-0.5), None, (left, right)
    )[0]
    assert plain.disparity == pytest.approx(8.0, abs=1e-3)
    assert refined.disparity == pytest.approx(8.3, abs=0.12)
    assert biased.disparity == pytest.approx(refined.disparity + 0.5, abs=1e-6)
    assert refined.position[2] == pytest.approx(geo.fx * geo.baseline / refined.disparity)
    off = replace(params, refine="none", disparity_bias=0.0)
    assert range_boxes(coarse, [CAR], geo, off, None, (left, right))[0].disparity == pytest.approx(
        8.0, abs=1e-3
    )


def test_disparity_bias_grows_toward_the_image_borders():
    from stereo_depth_node.ranging import RangingParams, disparity_bias_at
    from stereo_depth_node.reprojection import StereoGeometry

    geo = StereoGeometry(700.0, 700.0, 600.0, 170.0, 0.54)
    p = RangingParams(disparity_bias=-0.3, disparity_bias_column=-1.8)
    assert disparity_bias_at(600.0, geo, p) == pytest.approx(-0.3)
    assert disparity_bias_at([250.0, 950.0], geo, p) == pytest.approx([-0.75, -0.75])


def test_refined_far_boxes_report_the_refined_disparity_spread():
    # the depth std of a far box refined at full resolution follows sigma_d_far (measured
    # region spread 0.18 px), of an unrefined one sigma_d
    from stereo_depth_node.ranging import RangingParams, range_boxes
    from stereo_depth_node.reprojection import StereoGeometry

    left, right = textured_pair()
    geo = StereoGeometry(721.5, 721.5, 609.6, 172.9, 0.5327)
    coarse = np.full(left.shape, 8.0, np.float32)
    params = RangingParams(
        centre_correction=False,
        lateral_fit=False,
        reject_ground=False,
        disparity_bias=0.0,
        disparity_bias_column=0.0,
        depth_offset_std=0.0,
        sigma_d=0.3,
        sigma_d_far=0.15,
    )
    fb = geo.fx * geo.baseline
    for images, sd in ((None, 0.3), ((left, right), 0.15)):
        r = range_boxes(coarse, [CAR], geo, params, None, images)[0]
        z = r.position[2]
        assert np.sqrt(r.covariance[2, 2]) == pytest.approx(z * z * sd / fb, rel=1e-6)
