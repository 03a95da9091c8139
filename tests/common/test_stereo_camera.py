"""A stereo camera that is not KITTI: the CameraInfo checks give one line naming what is wrong
(missing P or Tx, sizes, rows not aligned, swapped sides, image/camera_info mismatches), and the
disparity range follows from fx * baseline."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.image_conversion import camera_info_from_projection
from vehicle_common.stereo_camera import (
    StereoCameraError,
    check_stereo_images,
    check_stereo_infos,
    num_disparities_for,
)

FX, W, H, B = 700.0, 1280, 720, 0.12


def _infos(tx_right=-FX * B, right_p=None, size=(W, H), right_size=None):
    K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1.0]])
    left = camera_info_from_projection(np.hstack([K, np.zeros((3, 1))]), *size)
    pr = right_p if right_p is not None else np.hstack([K, [[tx_right], [0], [0]]])
    right = camera_info_from_projection(pr, *(right_size or size))
    left.header.frame_id, right.header.frame_id = "left_optical", "right_optical"
    return left, right


def test_a_rectified_720p_pair_passes_with_its_baseline():
    assert check_stereo_infos(*_infos()) == pytest.approx(B)
    # kitti2bag: P_rect_02 / P_rect_03, Tx of both relative to camera 0, small y/z offsets
    kitti = [
        np.array([[721.5, 0, 609.6, 44.86], [0, 721.5, 172.9, 0.2164], [0, 0, 1, 0.002746]]),
        np.array([[721.5, 0, 609.6, -339.5], [0, 721.5, 172.9, 2.199], [0, 0, 1, 0.002370]]),
    ]
    left, right = (camera_info_from_projection(p, 1242, 375) for p in kitti)
    assert check_stereo_infos(left, right) == pytest.approx(384.36 / 721.5)


@pytest.mark.parametrize(
    ("infos", "message"),
    [
        (_infos(tx_right=0.0), r"right camera_info: P\[0,3\] \(Tx\) is 0: no baseline"),
        (_infos(right_p=np.zeros((3, 4))), "right camera_info: P is missing"),
        (_infos(tx_right=FX * B), "left and right swapped"),
        (_infos(right_size=(1242, 375)), "camera_info sizes differ: left 1280x720, right 1242x375"),
    ],
)
def test_bad_pairs_are_named_in_one_line(infos, message):
    with pytest.raises(StereoCameraError, match=message) as err:
        check_stereo_infos(*infos)
    assert "\n" not in str(err.value)


def test_unrectified_pair_is_refused():
    K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1.0]])
    K2 = K.copy()
    K2[1, 2] += 12.0  # rows not aligned: two cameras calibrated separately
    right = np.hstack([K2, [[-FX * B], [0], [0]]])
    with pytest.raises(StereoCameraError, match="P cy differs .* not rectified together"):
        check_stereo_infos(*_infos(right_p=right))
    tilted = np.hstack([K, [[-FX * B], [0.3 * FX * B], [0]]])  # right camera 3.6 cm higher
    with pytest.raises(StereoCameraError, match="not a horizontally rectified pair"):
        check_stereo_infos(*_infos(right_p=tilted))


def _image_msg(frame_id):
    from sensor_msgs.msg import Image

    m = Image()
    m.header.frame_id = frame_id
    return m


def test_images_must_fit_each_other_and_their_camera_infos():
    left_info, right_info = _infos()
    big, small = np.zeros((H, W, 3), np.uint8), np.zeros((375, 1242, 3), np.uint8)
    ok = (_image_msg("left_optical"), _image_msg("right_optical"))
    check_stereo_images(*ok, big, big, left_info, right_info)
    with pytest.raises(StereoCameraError, match="left 1280x720 and right 1242x375 image sizes"):
        check_stereo_images(*ok, big, small, left_info, right_info)
    with pytest.raises(StereoCameraError, match="left image is 1242x375 but its camera_info says"):
        check_stereo_images(*ok, small, small, left_info, right_info)
    wrong = (_image_msg("left_optical"), _image_msg("camera_color_right"))
    with pytest.raises(
        StereoCameraError, match="right image frame_id 'camera_color_right' differs"
    ):
        check_stereo_images(*wrong, big, big, left_info, right_info)


def test_disparity_range_for_the_nearest_depth():
    assert num_disparities_for(721.5, 0.5327, 4.05) == 96  # KITTI: the default reaches 4.05 m
    assert num_disparities_for(FX, B, 2.6) == 48  # 84 px*m / 2.6 m = 32.3 -> 48
    assert num_disparities_for(FX, B, 4.0) == 32
    assert num_disparities_for(FX, B, 100.0) == 16  # never below OpenCV's 16


def test_a_non_finite_value_in_p_is_named_not_called_missing():
    """A nan in the right P (a calibration file with `nan`) was reported as "P is missing (all
    zeros)"; it names the element now."""
    K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1.0]])
    right = np.hstack([K, [[np.nan], [0], [0]]])
    with pytest.raises(StereoCameraError) as err:
        check_stereo_infos(*_infos(right_p=right))
    assert str(err.value) == (
        "right camera_info: P[0,3] is nan: the calibration holds a non-finite value"
    )
