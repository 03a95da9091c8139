"""Disparity and reprojection core: synthetic pairs with known disparity, Q, KITTI baseline."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from stereo_depth_node.disparity import (
    INVALID_DISPARITY,
    DisparityParams,
    block_matching_disparity,
    box_regions,
    coarse_disparity,
    compute_disparity,
    compute_disparity_in_boxes,
    d1_error,
    interpolate_background,
)
from stereo_depth_node.reprojection import StereoGeometry, decimated_points, reproject

# KITTI tracking 0005 (camera 2/3): fx, fy, cx, cy and the 0.54 m baseline
KITTI = StereoGeometry(721.5377, 721.5377, 609.5593, 172.854, 0.5371)


def textured_pair(disparity: int, height: int = 120, width: int = 320, seed: int = 0):
    """A random-texture RGB pair whose right image is the left one shifted by ``disparity``."""
    rng = np.random.default_rng(seed)
    big = rng.integers(0, 256, (height, width + disparity, 3), dtype=np.uint8)
    big = cv2.GaussianBlur(big, (3, 3), 0)
    left = np.ascontiguousarray(big[:, :width])  # left pixel x shows what right shows at x - d
    right = np.ascontiguousarray(big[:, disparity:])
    return left, right


@pytest.mark.parametrize(
    "params",
    [
        DisparityParams(num_disparities=64, use_wls=False),
        DisparityParams(num_disparities=64, use_wls=True),
        DisparityParams(num_disparities=64, use_wls=True, downscale=2),
        DisparityParams(num_disparities=64, use_wls=True, pad_left=False),
    ],
    ids=["sgbm", "wls", "wls-half", "wls-nopad"],
)
def test_constant_disparity_is_recovered(params):
    left, right = textured_pair(24)
    disp = compute_disparity(left, right, params)
    assert disp.shape == left.shape[:2] and disp.dtype == np.float32
    valid = disp > 0
    assert np.all(disp[~valid] == INVALID_DISPARITY)
    inner = disp[10:-10, 80:-10]  # away from the borders
    assert (inner > 0).mean() > 0.9
    assert abs(float(np.median(inner[inner > 0])) - 24.0) < 0.5
    assert np.mean(np.abs(inner[inner > 0] - 24.0) < 1.0) > 0.9


def test_left_padding_recovers_the_left_border():
    left, right = textured_pair(16, width=256)
    padded = compute_disparity(left, right, DisparityParams(num_disparities=64, use_wls=False))
    plain = compute_disparity(
        left, right, DisparityParams(num_disparities=64, use_wls=False, pad_left=False)
    )
    border_p, border_n = padded[10:-10, 20:60], plain[10:-10, 20:60]
    assert (border_n > 0).mean() < 0.1  # SGBM leaves the first num_disparities columns empty
    assert (border_p > 0).mean() > 0.9
    assert abs(float(np.median(border_p[border_p > 0])) - 16.0) < 0.5


def test_row_band_only_fills_its_rows():
    left, right = textured_pair(20)
    p = DisparityParams(num_disparities=48, use_wls=True, row_band=(40, 100))
    disp = compute_disparity(left, right, p)
    assert np.all(disp[:40] == INVALID_DISPARITY) and np.all(disp[100:] == INVALID_DISPARITY)
    band = disp[45:95, 80:-10]
    assert abs(float(np.median(band[band > 0])) - 20.0) < 0.5


def test_map_in_the_boxes_is_the_band_map_there_and_invalid_elsewhere():
    """compute_disparity_in_boxes: the band's map inside each box (the same matcher on a crop
    with context; on this planar scene the same values), nothing outside the boxes."""
    left, right = textured_pair(20, height=200, width=640)
    p = DisparityParams(num_disparities=48, row_band=(20, 190))
    band = compute_disparity(left, right, p)
    boxes = [(300, 60, 380, 120), (560, 100, 639.5, 150), (10, 150, 60, 199)]
    got = compute_disparity_in_boxes(left, right, boxes, p)
    inside = np.zeros(band.shape, bool)
    for x1, y1, x2, y2 in boxes:
        r = (slice(int(y1), min(190, int(np.ceil(y2)) + 1)), slice(int(x1), int(np.ceil(x2)) + 1))
        inside[r] = True
        a, b = band[r], got[r]
        assert (b > 0).mean() > 0.8 and abs((b > 0).mean() - (a > 0).mean()) < 0.05
        both = (a > 0) & (b > 0)
        assert np.median(np.abs(a[both] - b[both])) <= 0.0625  # one step of the filter
        assert abs(float(np.median(b[b > 0])) - 20.0) < 0.5
    assert np.all(got[~inside] == INVALID_DISPARITY)
    # crops start on the band's half-resolution grid, overlapping crops are matched together
    regions = box_regions(boxes, band.shape, p)
    for r in regions:
        assert r.crop[0] % 2 == 0 and (r.crop[1] - 20) % 2 == 0 and r.crop[3] <= 190
    assert sorted(len(r.outputs) for r in regions) == [1, 2]
    assert box_regions([], band.shape, p) == []


def test_map_in_boxes_covering_most_of_the_band_is_the_band_map():
    left, right = textured_pair(20, height=120, width=320)
    p = DisparityParams(num_disparities=48)
    whole = compute_disparity_in_boxes(left, right, [(0, 0, 319, 119)], p)
    np.testing.assert_array_equal(whole, compute_disparity(left, right, p))


def test_block_matching_and_coarse_maps_recover_the_disparity():
    """The odometry's block-matching map and the road plane's coarse map of a planar scene:
    the right disparity on most of the band, nothing outside it."""
    left, right = textured_pair(24, height=160, width=480)
    p = DisparityParams(num_disparities=64, row_band=(20, 150))
    gray_l, gray_r = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY), cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)
    for disp in (block_matching_disparity(gray_l, gray_r, p), coarse_disparity(left, right, p)):
        assert disp.shape == gray_l.shape and disp.dtype == np.float32
        assert np.all(disp[:20] == INVALID_DISPARITY) and np.all(disp[150:] == INVALID_DISPARITY)
        inner = disp[30:140, 40:-10]
        assert (inner > 0).mean() > 0.6
        assert abs(float(np.median(inner[inner > 0])) - 24.0) < 1.0
    with pytest.raises(ValueError):
        block_matching_disparity(left, right, p)  # gray images only


def test_bad_settings_and_shapes_raise():
    left, right = textured_pair(8)
    with pytest.raises(ValueError):
        compute_disparity(left, right, DisparityParams(block_size=4))
    with pytest.raises(ValueError):
        compute_disparity(left, right[:, :-2], DisparityParams())


def test_d1_error_counts_bad_and_missing_pixels():
    gt = np.full((4, 5), 20.0, np.float32)
    gt[0, 0] = 0.0  # no ground truth: ignored
    est = gt.copy()
    est[1, 1] = 24.0  # bad (4 px and 20 %)
    est[1, 2] = 22.0  # within 3 px: good
    est[2, 2] = INVALID_DISPARITY  # hole
    e = d1_error(est, gt)
    assert e["n_gt"] == 19
    assert e["d1_all"] == pytest.approx(2 / 19)
    assert e["d1_valid"] == pytest.approx(1 / 18)
    assert e["density"] == pytest.approx(18 / 19)


def test_interpolate_background_takes_the_smaller_neighbour():
    d = np.array([[-1, 10, -1, -1, 30, -1]], np.float32)
    filled = interpolate_background(d)
    np.testing.assert_allclose(filled, [[10, 10, 10, 10, 30, 30]])


def test_reprojection_gives_kitti_depth():
    # 38.75 px disparity at the KITTI baseline: z = f B / d = 10.0 m
    d = KITTI.fx * KITTI.baseline / 10.0
    disp = np.full((375, 1242), d, np.float32)
    disp[0, 0] = INVALID_DISPARITY
    pts, valid = reproject(disp, KITTI)
    assert not valid[0, 0] and np.all(np.isnan(pts[0, 0]))
    np.testing.assert_allclose(pts[valid][:, 2], 10.0, rtol=1e-5)
    u, v = 1000, 300
    np.testing.assert_allclose(
        pts[v, u], [(u - KITTI.cx) * 10 / KITTI.fx, (v - KITTI.cy) * 10 / KITTI.fy, 10.0], rtol=1e-5
    )
    # same points as OpenCV's reprojection with our Q
    cv_pts = cv2.reprojectImageTo3D(disp, KITTI.q_matrix.astype(np.float32))
    np.testing.assert_allclose(cv_pts[v, u], pts[v, u], rtol=1e-4)
    assert KITTI.depth(d) == pytest.approx(10.0)


def test_geometry_from_camera_infos_builds_q():
    from vehicle_common.image_conversion import camera_info_from_projection

    K = np.array([[700.0, 0, 600], [0, 710.0, 180], [0, 0, 1]])
    Pl = np.hstack([K, np.zeros((3, 1))])
    Pr = np.hstack([K, np.array([[-700.0 * 0.5], [0], [0]])])
    geo = StereoGeometry.from_camera_infos(
        camera_info_from_projection(Pl, 1200, 360), camera_info_from_projection(Pr, 1200, 360)
    )
    assert (geo.fx, geo.fy, geo.cx, geo.cy) == (700.0, 710.0, 600.0, 180.0)
    assert geo.baseline == pytest.approx(0.5)
    X = geo.q_matrix @ np.array([650.0, 200.0, 35.0, 1.0])
    np.testing.assert_allclose(X[:3] / X[3], [50 * 10 / 700, 20 * 10 / 710, 10.0])


def test_decimated_points_subsample_and_clip_depth():
    disp = np.full((40, 60), KITTI.fx * KITTI.baseline / 20.0, np.float32)
    disp[:, :30] = KITTI.fx * KITTI.baseline / 100.0  # beyond max_depth
    rgb = np.zeros((40, 60, 3), np.uint8)
    rgb[..., 1] = 200
    pts, cols = decimated_points(disp, KITTI, step=4, rgb=rgb, max_depth=80.0)
    assert pts.shape == (10 * 7, 3) and cols.shape == (70, 3)  # columns 32..56
    np.testing.assert_allclose(pts[:, 2], 20.0, rtol=1e-5)
    assert np.all(cols[:, 1] == 200)


def test_match_rows_against_the_image_height():
    """`match_rows` [400, 500] on a 375-row image used to match nothing (MOTA 0, no word) and
    [500, 100] was read as the whole image. The one check of the band against an image:"""
    from stereo_depth_node.disparity import (
        RowBandError,
        check_match_rows,
        match_band,
        min_band_rows,
    )

    p = DisparityParams()  # block 3 at half resolution: 12 rows at least
    assert min_band_rows(p) == 12
    assert match_band([0, 0], 375, p) == (None, None)  # every row
    assert match_band([94, 375], 375, p) == ((94, 375), None)  # the KITTI graph's band
    band, note = match_band([94, 375], 370, p)  # a 1224x370 KITTI frame: cut, and said so
    assert band == (94, 370)
    assert note == "match_rows: [94, 375] reaches below the 370-row image: rows 94..369 are matched"
    with pytest.raises(RowBandError) as err:
        match_band([400, 500], 375, p)
    assert str(err.value) == (
        "match_rows: [400, 500] lies below the 375-row image (rows 0..374); the matcher needs "
        "at least 12 rows: nothing could be ranged"
    )
    with pytest.raises(RowBandError, match=r"\[370, 400\] keeps 5 rows of the 375-row image"):
        match_band([370, 400], 375, p)
    for rows in ([500, 100], [5, 5], [-1, 10]):
        with pytest.raises(ValueError, match=rf"^match_rows: \[{rows[0]}, {rows[1]}\]: expected"):
            check_match_rows(rows)
