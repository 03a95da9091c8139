"""The detector node frames the images for the camera of its left CameraInfo: derived at run
time (an image that comes before the first CameraInfo waits for it), derived again when the
CameraInfo changes mid-run, and the parameters win when given."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from tests.ros_helpers import spin_until  # noqa: E402

KITTI_P = [721.5377, 0.0, 609.5593, 0.0, 0.0, 721.5377, 172.854, 0.0, 0.0, 0.0, 1.0, 0.0]
ZED_P = [700.0, 0.0, 640.0, 0.0, 0.0, 700.0, 360.0, 0.0, 0.0, 0.0, 1.0, 0.0]


class Rig:
    """A detector node and a test node publishing the left image and CameraInfo."""

    def __init__(self, ctx, **params):
        from detector_node.node import VehicleDetectorNode
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import CameraInfo, Image
        from stereo_vehicle_msgs.msg import VehicleDetection2DArray

        params = {"num_threads": 1, **params}
        self.det = VehicleDetectorNode(
            context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
        )
        self.io = Node("detector_camera_test", context=ctx)
        self.got = []
        self.io.create_subscription(
            VehicleDetection2DArray, "/vehicles/detections_2d", self.got.append, 10
        )
        self.image = self.io.create_publisher(Image, "/stereo/left/image_rect", 5)
        self.info = self.io.create_publisher(CameraInfo, "/stereo/left/camera_info", 5)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.det)
        self.ex.add_node(self.io)
        assert spin_until(
            self.ex,
            lambda: (
                self.image.get_subscription_count() > 0
                and self.info.get_subscription_count() > 0
                and self.det.pub.get_subscription_count() > 0
            ),
        )

    def send(self, sec: int, size: tuple[int, int], p: list[float] | None, info_first=True):
        from sensor_msgs.msg import CameraInfo
        from vehicle_common.frame_messages import header
        from vehicle_common.image_conversion import numpy_to_image

        hdr = header(sec * 1_000_000_000, "left_camera_optical_frame")
        w, h = size
        image = numpy_to_image(np.zeros((h, w, 3), np.uint8), "rgb8", hdr)
        info = CameraInfo(header=hdr, width=w, height=h, p=p) if p is not None else None
        n = len(self.got)
        if info is not None and info_first:
            self.info.publish(info)
        self.image.publish(image)
        if info is not None and not info_first:
            spin_until(self.ex, lambda: False, 0.2)  # the image arrives alone and waits
            self.info.publish(info)
        assert spin_until(self.ex, lambda: len(self.got) > n, 60), "no detections array"

    def framing(self):
        c = self.det.cnn.config
        return (c.input_width, c.input_height, round(self.det.cnn.roi_top, 6))

    def close(self):
        self.ex.shutdown()
        self.det.destroy_node()
        self.io.destroy_node()


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("VEHICLE_DETECTOR_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_framing_is_derived_from_the_camera_info_and_follows_a_change(rclpy_context, cache, capfd):
    rig = Rig(rclpy_context)
    try:
        assert rig.det.cnn.runtime == "onnxruntime"
        assert rig.framing() == (896, 224, 0.25)  # the checkpoint's until a camera is known
        # a 1280x720, 700 px camera: the image (sent before its CameraInfo) waits for it and
        # is detected at the training's pixel scale, the whole image searched
        rig.send(1, (1280, 720), ZED_P, info_first=False)
        assert rig.framing() == (960, 576, 0.0)
        assert (576, 960) in rig.det.cnn._sessions  # the waiting image ran at that size
        # the camera changes to KITTI's: the checkpoint's framing again
        rig.send(2, (1242, 375), KITTI_P)
        assert rig.framing() == (896, 224, 0.25)
        rig.send(3, (1242, 375), KITTI_P)  # the same camera again: nothing is derived
        assert [m.header.stamp.sec for m in rig.got] == [1, 2, 3]
    finally:
        rig.close()
    err = capfd.readouterr().err
    assert err.count("camera 1280x720, fx 700.0 px: input 960x576") == 1
    assert err.count("camera_info changed (was 960x576, whole image)") == 1
    assert "camera 1242x375, fx 721.5 px: input 896x224 (the checkpoint's" in err
    # both graphs were cached, keyed by the checkpoint's content and the input size
    assert len(list(cache.glob("*-onnx960x576.npz"))) == 1
    assert len(list(cache.glob("*-onnx896x224.npz"))) == 1


def test_given_framing_wins_over_the_camera(rclpy_context, cache, capfd):
    rig = Rig(
        rclpy_context, checkpoint="tiny_kitti", input_width=640, input_height=384, roi_top=0.1
    )
    try:
        rig.send(1, (1280, 720), ZED_P)
        assert rig.framing() == (640, 384, 0.1)
        rig.send(2, (1242, 375), KITTI_P)
        assert rig.framing() == (640, 384, 0.1)
    finally:
        rig.close()
    err = capfd.readouterr().err
    assert "input 640x384 (parameter), searched: below the top 10 % (parameter)" in err
    assert "camera_info changed" not in err


def test_an_image_without_any_camera_info_is_detected_after_the_wait(rclpy_context, cache, capfd):
    rig = Rig(rclpy_context, checkpoint="tiny_kitti", camera_info_wait=0.3)
    try:
        rig.send(1, (1242, 375), None)
        assert rig.framing() == (832, 256, 0.0)  # the checkpoint's
    finally:
        rig.close()
    assert "no CameraInfo on stereo/left/camera_info within 0.3 s" in capfd.readouterr().err
