"""The camera-dependent settings the nodes derive from CameraInfo
(vehicle_common.camera_settings): KITTI's camera keeps the KITTI graph's hand settings, another
camera gets the training's pixel scale, the whole image and its disparity range; a parameter
given wins; tracking_bringup.camera pins them as overrides."""

from __future__ import annotations

import pytest
from tracking_bringup.camera import KITTI_CAMERA, camera_overrides, checkpoint_framing
from vehicle_common.camera_settings import (
    KITTI_ROI_TOP,
    CameraModel,
    detector_framing,
    stereo_settings,
)

KITTI = CameraModel(1242, 375, 721.5377, 721.5377, 609.5593, 172.854, 0.5327)
ZED = CameraModel(1280, 720, 700.0, 700.0, 640.0, 360.0, 0.12)
#: checkpoint framings: (input, roi_top, training input, training roi_top)
CENTERNET = ((896, 224), 0.25, (896, 224), 0.25)
TINY = ((832, 256), 0.0, (832, 256), 0.0)


def test_shipped_checkpoints_framing():
    assert checkpoint_framing("") == CENTERNET
    assert checkpoint_framing("tiny_kitti") == TINY
    assert CENTERNET[1] == KITTI_ROI_TOP  # the stereo node's rows follow the shipped detector


def test_kitti_camera_keeps_the_kitti_graphs_settings():
    f = detector_framing(KITTI, *CENTERNET)
    assert (f.input_width, f.input_height, f.roi_top) == (0, 0, 0.25)  # the checkpoint's
    assert "896x224 (the checkpoint's, KITTI's camera)" in f.text
    f = detector_framing(KITTI, *TINY)
    assert (f.input_width, f.input_height, f.roi_top) == (0, 0, 0.0)
    s = stereo_settings(KITTI)
    assert (s.num_disparities, s.match_rows, s.ground_height) == (96, (94, 375), 1.65)
    assert s.ground_height_assumed and "assumed" in s.text
    # KITTI's other recording days (1224x370 at 707 px): the same input, rows of its height
    other = CameraModel(1224, 370, 707.0493, 707.0493, 604.08, 180.5, 0.5379)
    f = detector_framing(other, *CENTERNET)
    assert (f.input_width, f.input_height, f.roi_top) == (0, 0, 0.25)
    assert stereo_settings(other).match_rows == (92, 370)


def test_720p_short_baseline_camera():
    # tiny_kitti (the synthetic demo's): 896x512 as tracking_bringup.camera derived before;
    # same pixels per metre as in training, aspect kept (832x256 squeezes the height 2.2x)
    f = detector_framing(ZED, *TINY)
    assert (f.input_width, f.input_height, f.roi_top) == (896, 512, 0.0)
    # the shipped CenterNet: its 896 px for KITTI's 1242 x 721.5 / 700, whole image
    f = detector_framing(ZED, *CENTERNET)
    assert (f.input_width, f.input_height, f.roi_top) == (960, 576, 0.0)
    assert "searched: the whole image (not KITTI's camera" in f.text
    s = stereo_settings(ZED)
    assert (s.num_disparities, s.match_rows) == (32, (0, 0))  # 84 px m / 4.05 m -> 32


def test_given_parameters_win():
    f = detector_framing(ZED, *CENTERNET, given_size=(640, 384), given_roi_top=0.1)
    assert (f.input_width, f.input_height, f.roi_top) == (640, 384, 0.1)
    assert f.text.count("(parameter)") == 2
    # a region of interest given on KITTI's camera: the input keeps the pixel scale
    f = detector_framing(KITTI, *CENTERNET, given_roi_top=0.0)
    assert (f.input_width, f.input_height, f.roi_top) == (896, 288, 0.0)
    s = stereo_settings(KITTI, 128, (0, 0), 1.2)
    assert (s.num_disparities, s.match_rows, s.ground_height) == (128, (0, 0), 1.2)
    assert not s.ground_height_assumed and s.text.count("(parameter)") == 3
    no_camera = detector_framing(None, *CENTERNET)
    assert (no_camera.input_width, no_camera.roi_top) == (0, 0.25)


def test_camera_model_from_camera_info_and_projections():
    import numpy as np
    from vehicle_common.image_conversion import camera_info_from_projection

    K = np.array([[700.0, 0, 640], [0, 700.0, 360], [0, 0, 1]])
    left = camera_info_from_projection(np.hstack([K, np.zeros((3, 1))]), 1280, 720)
    right = camera_info_from_projection(np.hstack([K, [[-700.0 * 0.12], [0], [0]]]), 1280, 720)
    got = CameraModel.from_camera_info(left, right)
    assert got.baseline == pytest.approx(0.12)
    assert (got.width, got.height, got.fx, got.fy, got.cx, got.cy) == (
        1280,
        720,
        700,
        700,
        640,
        360,
    )
    assert CameraModel.from_camera_info(left).baseline == 0.0
    assert CameraModel.from_projections(1280, 720, left.p, right.p).baseline == pytest.approx(0.12)
    right.p[3] = 0.0
    with pytest.raises(ValueError, match="no baseline"):
        CameraModel.from_camera_info(left, right)
    left.p = [0.0] * 12
    with pytest.raises(ValueError, match="not calibrated"):
        CameraModel.from_camera_info(left)


def test_overrides_pin_what_the_nodes_derive():
    assert camera_overrides(KITTI_CAMERA) == [
        "vehicle_detector.input_width:=896",
        "vehicle_detector.input_height:=224",
        "vehicle_detector.roi_top:=0.25",
        "stereo_depth.num_disparities:=96",
        "stereo_depth.match_rows:=[94, 375]",
        "stereo_depth.ground_height:=1.65",
    ]
    assert camera_overrides(ZED, "tiny_kitti")[:5] == [
        "vehicle_detector.input_width:=896",
        "vehicle_detector.input_height:=512",
        "vehicle_detector.roi_top:=0.0",
        "stereo_depth.num_disparities:=32",
        "stereo_depth.match_rows:=[0, 0]",
    ]


def test_demo_uses_the_checkpoint_it_loads():
    """On synthetic data the demo runs tiny_kitti: --no-camera-settings pins KITTI's settings
    of that checkpoint (832x256), not of the shipped CenterNet."""
    from tracking_bringup.demo import detector_checkpoint
    from tracking_bringup.environment import PARAMS_FILE

    assert detector_checkpoint(PARAMS_FILE, [], synthetic=True) == "tiny_kitti"
    assert detector_checkpoint(PARAMS_FILE, [], synthetic=False) == ""
    mine = ["vehicle_detector.checkpoint:=centernet_kitti"]
    assert detector_checkpoint(PARAMS_FILE, mine, synthetic=True) == "centernet_kitti"
    pinned = camera_overrides(KITTI_CAMERA, detector_checkpoint(PARAMS_FILE, [], synthetic=True))
    assert pinned[:2] == ["vehicle_detector.input_width:=832", "vehicle_detector.input_height:=256"]
