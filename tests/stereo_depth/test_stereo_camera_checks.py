"""stereo_depth names what is wrong with a camera pair in one line and keeps running: a right
CameraInfo without Tx, images whose size or frame id do not match their CameraInfos."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.image_conversion import camera_info_from_projection, numpy_to_image

from tests.stereo_depth.test_stereo_node import FX, H, Harness, W

BOX = [(150, 30, 250, 90)]


@pytest.fixture
def harness(rclpy_context):
    h = Harness(rclpy_context, disparity_bias=0.0, disparity_bias_column=0.0, lateral_fit=False)
    yield h
    h.close()


def test_missing_tx_is_named(harness):
    K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1]])
    harness.infos = (
        harness.infos[0],
        camera_info_from_projection(np.hstack([K, np.zeros((3, 1))]), W, H),
    )
    harness.send_frame(1)
    harness.send_detections(1, BOX)
    assert harness.spin_until(lambda: len(harness.det3d) == 1)
    assert harness.node.pipeline.geometry is None and harness.det3d[0].detections == []
    assert (
        "right camera_info: P[0,3] (Tx) is 0: no baseline" in harness.node.pipeline.geometry_error
    )


def _send_pair(harness, sec, left_frame, right_frame, info_size=(W, H)):
    hdr = harness.header(sec)
    for name, info in zip(("linfo", "rinfo"), harness.infos, strict=True):
        info.header = hdr
        info.width, info.height = info_size
        harness.pubs[name].publish(info)
    harness.spin_until(lambda: harness.node.left_info is not None, 2.0)
    for side, img, frame in (
        ("left", harness.left, left_frame),
        ("right", harness.right, right_frame),
    ):
        h = harness.header(sec)
        h.frame_id = frame
        harness.pubs[side].publish(numpy_to_image(img, "rgb8", h))
    harness.send_detections(sec, BOX)


def test_images_that_do_not_fit_their_camera_infos_are_skipped(harness):
    ok = "left_camera_optical_frame"  # the harness's CameraInfos carry this frame id
    _send_pair(harness, 1, ok, ok)
    assert harness.spin_until(lambda: len(harness.det3d) == 1)
    assert len(harness.det3d[0].detections) == 1 and harness.node.frames_failed == 0
    _send_pair(harness, 2, ok, "camera_color_right")  # right image of another camera
    assert harness.spin_until(lambda: len(harness.det3d) == 2)
    assert harness.node.frames_failed == 1 and harness.det3d[1].detections == []
    _send_pair(harness, 3, ok, ok, info_size=(2 * W, 2 * H))  # calibration of another size
    assert harness.spin_until(lambda: len(harness.det3d) == 3)
    assert harness.node.frames_failed == 2 and harness.det3d[2].detections == []
    _send_pair(harness, 4, ok, ok)  # and it keeps working
    assert harness.spin_until(lambda: len(harness.det3d) == 4)
    assert len(harness.det3d[3].detections) == 1
