"""Settings that follow from a camera that is not KITTI's: the CNN sees it at its training
scale (not squeezed), the disparity range reaches KITTI's nearest depth; KITTI itself keeps the
shipped defaults."""

from __future__ import annotations

from tracking_bringup.camera import camera_overrides, checkpoint_input_size, detector_input_size

SHIPPED = (832, 256)  # the tiny YOLO checkpoint's input (the geometry tests below use it)


def test_shipped_checkpoint_input():
    # centernet_kitti.pt, the node's default: 896x224 below the top 25 % = 896x298.7 for the
    # whole image
    w, h = checkpoint_input_size("")
    assert w == 896 and abs(h - 224 / 0.75) < 1e-9
    assert checkpoint_input_size("tiny_kitti") == SHIPPED


def test_kitti_keeps_the_shipped_settings():
    assert detector_input_size(1242, 375, 721.5377, SHIPPED) == SHIPPED
    assert camera_overrides(1242, 375, 721.5377, 0.5327, SHIPPED) == [
        "vehicle_detector.input_width:=832",
        "vehicle_detector.input_height:=256",
        "vehicle_detector.roi_top:=0.0",
        "stereo_depth.match_rows:=[0, 0]",
        "stereo_depth.num_disparities:=96",
    ]


def test_720p_short_baseline_camera():
    # 1280x720, f 700 px: same pixels per metre as in training, aspect kept (832x256 would
    # squeeze the height 2.2x more than the width)
    w, h = detector_input_size(1280, 720, 700.0, SHIPPED)
    assert (w, h) == (896, 512)
    assert abs((w / 1280) / (h / 720) - 1.0) < 0.05
    assert (
        camera_overrides(1280, 720, 700.0, 0.12, SHIPPED)[4] == "stereo_depth.num_disparities:=32"
    )


def test_demo_derives_the_camera_settings_for_the_checkpoint_it_loads():
    """On synthetic data the demo runs tiny_kitti: the input size must be derived from its
    832x256, not from the shipped CenterNet's 1024x320 (1088x640 at 720p, 2D AP 45 vs 76)."""
    from tracking_bringup.demo import detector_checkpoint
    from tracking_bringup.environment import PARAMS_FILE

    assert detector_checkpoint(PARAMS_FILE, [], synthetic=True) == "tiny_kitti"
    assert detector_checkpoint(PARAMS_FILE, [], synthetic=False) == ""
    mine = ["vehicle_detector.checkpoint:=centernet_kitti"]
    assert detector_checkpoint(PARAMS_FILE, mine, synthetic=True) == "centernet_kitti"
    size = checkpoint_input_size(detector_checkpoint(PARAMS_FILE, [], synthetic=True))
    assert detector_input_size(1280, 720, 700.0, size) == (896, 512)
