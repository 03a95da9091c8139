"""The stereo node's odometry outputs: one nav_msgs/Odometry and one /tf per 3D array, with its
stamp, before it; frames odom -> camera (or base_link with a mount); the rig on /tf_static for
late subscribers (TRANSIENT_LOCAL); a lost frame extrapolated with a growing covariance."""

from __future__ import annotations

import numpy as np
import pytest

from tests.stereo_depth.test_stereo_node import B
from tests.stereo_depth.test_stereo_node import Harness as _Harness

pytest.importorskip("tf2_msgs.msg")

CAMERA = "left_camera_optical_frame"
RIGHT = "right_camera_optical_frame"


class Harness(_Harness):
    """The stereo node's test harness with the right camera in its own frame."""

    def send_frame(self, sec, bad_step=False):
        from vehicle_common.image_conversion import numpy_to_image

        left_hdr, right_hdr = self.header(sec), self.header(sec)
        right_hdr.frame_id = RIGHT
        for name, info, hdr in zip(
            ("linfo", "rinfo"), self.infos, (left_hdr, right_hdr), strict=True
        ):
            info.header = hdr
            self.pubs[name].publish(info)
        self.spin_until(lambda: self.node.left_info is not None, 2.0)
        left = numpy_to_image(self.left, "rgb8", left_hdr)
        if bad_step:
            left.step = left.step - 3  # inconsistent with width * 3
        self.pubs["left"].publish(left)
        self.pubs["right"].publish(numpy_to_image(self.right, "rgb8", right_hdr))


def _listen(h, odom, tf, order):
    from nav_msgs.msg import Odometry
    from stereo_vehicle_msgs.msg import VehicleDetection3DArray
    from tf2_msgs.msg import TFMessage

    def note(kind, store):
        def cb(msg):
            store.append(msg)
            order.append(kind)

        return cb

    h.io.create_subscription(Odometry, "/stereo/odometry", note("odom", odom), 10)
    h.io.create_subscription(TFMessage, "/tf", note("tf", tf), 100)
    h.io.create_subscription(
        VehicleDetection3DArray, "/vehicles/detections_3d", lambda m: order.append("3d"), 10
    )
    assert h.spin_until(
        lambda: (
            h.node.odometry_pubs.odometry.get_subscription_count() > 0
            and h.node.odometry_pubs.tf.get_subscription_count() > 0
        )
    )


def _latched_rig(h):
    """What a subscriber that joins late gets on /tf_static."""
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from tf2_msgs.msg import TFMessage

    got = []
    qos = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    h.io.create_subscription(TFMessage, "/tf_static", got.append, qos)
    assert h.spin_until(lambda: len(got) == 1)
    return {(t.header.frame_id, t.child_frame_id): t for t in got[0].transforms}


def test_odometry_tf_and_rig_of_each_frame(rclpy_context):
    from vehicle_common.frame_messages import read_transform, stamp_ns

    h = Harness(rclpy_context, sync_cache_size=3)
    odom, tf, order = [], [], []
    try:
        _listen(h, odom, tf, order)
        for sec in (1, 2):  # the same images twice: the camera stands still
            h.send_frame(sec)
            h.send_detections(sec, [(150, 30, 250, 90)])
            assert h.spin_until(lambda s=sec: len(h.det3d) == s and len(odom) == s)
        h.send_frame(3, bad_step=True)  # lost: no motion for 3, none for 4 (no reference)
        h.send_detections(3, [])
        h.send_frame(4)
        h.send_detections(4, [])
        assert h.spin_until(lambda: len(h.det3d) == 4 and len(odom) == 4 and len(tf) == 4)
        assert h.spin_until(lambda: order.count("3d") == 4)
        for a, o, t in zip(h.det3d, odom, tf, strict=True):
            assert stamp_ns(o.header) == stamp_ns(a.header)
            assert o.header.frame_id == "odom" and o.child_frame_id == CAMERA
            (link,) = t.transforms
            assert (link.header.frame_id, link.child_frame_id) == ("odom", CAMERA)
            assert stamp_ns(link.header) == stamp_ns(a.header)
        # each frame's odometry and transform go out before its 3D array
        for _ in range(4):
            end = order.index("3d")
            assert sorted(order[:end]) == ["odom", "tf"], order
            del order[: end + 1]
        # standing still: odom's origin, the optical axis along odom x
        R, t = read_transform(tf[1].transforms[0].transform)
        assert np.allclose(t, 0, atol=0.01) and np.allclose(R @ [0, 0, 1], [1, 0, 0], atol=1e-3)
        cov = [np.asarray(o.pose.covariance).reshape(6, 6) for o in odom]
        assert np.allclose(cov[0], 0)
        step = np.trace(cov[1]) - np.trace(cov[0])
        assert step > 0
        # the lost frames are extrapolated: their covariance grows by more than a measured step
        assert np.trace(cov[2]) - np.trace(cov[1]) > step
        assert np.trace(cov[3]) > np.trace(cov[2])
        assert h.node.odometry_pubs.out.frames_extrapolated == 2
        rig = _latched_rig(h)
        assert set(rig) == {(CAMERA, RIGHT)}
        R, t = read_transform(rig[(CAMERA, RIGHT)].transform)
        assert np.allclose(t, [B, 0, 0]) and np.allclose(R, np.eye(3))
    finally:
        h.close()


def test_a_base_frame_with_a_camera_mount(rclpy_context):
    from vehicle_common.frame_messages import read_transform

    h = Harness(
        rclpy_context,
        sync_cache_size=3,
        base_frame="base_link",
        camera_mount_xyz=[1.0, 0.0, 1.6],
    )
    odom, tf, order = [], [], []
    try:
        _listen(h, odom, tf, order)
        h.send_frame(1)
        h.send_detections(1, [])
        assert h.spin_until(lambda: len(odom) == 1 and len(tf) == 1)
        assert odom[0].child_frame_id == "base_link"
        (link,) = tf[0].transforms
        assert (link.header.frame_id, link.child_frame_id) == ("odom", "base_link")
        R, t = read_transform(link.transform)
        assert np.allclose(R, np.eye(3)) and np.allclose(t, 0)  # REP-105: odom at the start
        rig = _latched_rig(h)
        assert set(rig) == {("base_link", CAMERA), (CAMERA, RIGHT)}
        R, t = read_transform(rig[("base_link", CAMERA)].transform)
        assert np.allclose(t, [1.0, 0.0, 1.6]) and np.allclose(R @ [0, 0, 1], [1, 0, 0])
    finally:
        h.close()


def test_no_odometry_outputs_without_the_visual_odometry(rclpy_context):
    h = Harness(rclpy_context, visual_odometry=False)
    try:
        assert h.node.odometry_pubs.odometry is None and h.node.odometry_pubs.tf is None
        assert h.node.odometry_pubs.tf_static is None
    finally:
        h.close()


def test_a_bad_odometry_parameter_is_named(rclpy_context):
    from vehicle_common.node_parameters import ParameterError

    with pytest.raises(ParameterError, match="base_frame: must differ from odom_frame"):
        Harness(rclpy_context, base_frame="odom")
    with pytest.raises(ParameterError, match="camera_mount_xyz: expected 3 values"):
        Harness(rclpy_context, camera_mount_xyz=[1.0, 2.0])
