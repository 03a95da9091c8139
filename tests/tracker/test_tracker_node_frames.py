"""In-process vehicle_tracker with ``tracks_frame: odom``: tracks, markers and vision tracks in
odom from /tf (+ /tf_static), with the same stamps; a frame whose transform is missing is
placed with the array's camera motion; before any transform the tracks stay in the camera's
frame. Vision tracks (vision_msgs) carry the track ids."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.parameter import Parameter

from tests.ros_helpers import spin_until

pytest.importorskip("tf2_msgs.msg")
pytest.importorskip("vision_msgs.msg")

CAMERA = "left_camera_optical_frame"


def _array(k: int, with_motion: bool):
    from stereo_vehicle_msgs.msg import VehicleDetection3D, VehicleDetection3DArray
    from vehicle_common.frame_messages import write_transform

    msg = VehicleDetection3DArray()
    msg.header.frame_id = CAMERA
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100, k * 100_000_000
    d = VehicleDetection3D()
    d.id, d.class_id, d.score = "0", "car", 0.9
    # a parked car: 30 m ahead at frame 0, 1.5 m closer every frame (camera at 15 m/s)
    d.position.x, d.position.y, d.position.z = 2.0, 1.0, 30.0 - 1.5 * k
    d.position_covariance = [0.04, 0, 0, 0, 0.04, 0, 0, 0, 0.25]
    d.bbox.center_x, d.bbox.center_y, d.bbox.size_x, d.bbox.size_y = 700.0, 190.0, 80.0, 60.0
    msg.detections.append(d)
    if with_motion and k > 0:
        msg.camera_motion_dt = 0.1
        write_transform(np.eye(3), [0.0, 0.0, -1.5], msg.camera_motion)
    return msg


def test_tracks_in_odom_from_tf_and_camera_motion(rclpy_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from stereo_vehicle_msgs.msg import TrackedVehicleArray, VehicleDetection3DArray
    from tf2_msgs.msg import TFMessage
    from tracker_node.node import VehicleTrackerNode
    from vehicle_common.odometry import CameraMount, Pose
    from vehicle_common.odometry_messages import OdometryFrames, rig_static_tf, transform_stamped
    from vision_msgs.msg import Detection3DArray

    node = VehicleTrackerNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter("tracks_frame", value="odom"),
            Parameter("min_hits", value=1),
        ],
    )
    helper = Node("tracker_frames_helper", context=rclpy_context)
    pub = helper.create_publisher(VehicleDetection3DArray, "/vehicles/detections_3d", 10)
    tf = helper.create_publisher(TFMessage, "/tf", 100)
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    tf_static = helper.create_publisher(TFMessage, "/tf_static", latched)
    got, vision = [], []
    helper.create_subscription(TrackedVehicleArray, "/vehicles/tracks", got.append, 10)
    helper.create_subscription(Detection3DArray, "/vehicles/vision/tracks", vision.append, 10)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(node)
    ex.add_node(helper)
    # the camera is mounted on base_link 1.65 m up; odom -> base_link drives along x
    mount = CameraMount((0.0, 0.0, 1.65)).pose
    frames = OdometryFrames("odom", "base_link", mount)
    try:
        assert spin_until(
            ex,
            lambda: (
                pub.get_subscription_count() > 0
                and tf.get_subscription_count() > 0
                and tf_static.get_subscription_count() > 0
                and node.pub.get_subscription_count() > 0
                and node.vision_pub.get_subscription_count() > 0
            ),
        )
        # frame 0: no transform yet -> camera frame (warned once)
        pub.publish(_array(0, True))
        assert spin_until(ex, lambda: len(got) == 1)
        assert got[0].header.frame_id == CAMERA
        tf_static.publish(rig_static_tf(0, CAMERA, "right_camera_optical_frame", 0.5, frames))
        spin_until(ex, lambda: False, timeout=0.3)
        for k in range(1, 6):
            stamp = 100 * 10**9 + k * 100_000_000
            if k != 4:  # frame 4's /tf is lost: placed with its camera motion
                base = Pose(np.eye(3), [1.5 * k, 0.0, 0.0])
                tf.publish(
                    TFMessage(transforms=[transform_stamped("odom", "base_link", stamp, base)])
                )
                spin_until(ex, lambda: False, timeout=0.1)
            pub.publish(_array(k, True))
            assert spin_until(ex, lambda k=k: len(got) == k + 1), f"no tracks for frame {k}"
            out = got[-1]
            assert out.header.frame_id == "odom"
            assert (out.header.stamp.sec, out.header.stamp.nanosec) == (100, k * 100_000_000)
            (v,) = out.vehicles
            # the parked car stands still in odom: 30 m ahead of the start, 2 m right, ~0.65 up
            assert v.position.x == pytest.approx(30.0, abs=0.3), k
            assert v.position.y == pytest.approx(-2.0, abs=0.1)
            assert v.position.z == pytest.approx(0.65, abs=0.1)
        assert node.frames_without_tf == 2  # frame 0 (before any) and frame 4
        assert spin_until(ex, lambda: len(vision) == 6)  # one per array, frame 0 in the camera
        last = vision[-1]
        assert last.header.frame_id == "odom" and last.header.stamp == got[-1].header.stamp
        assert [d.id for d in last.detections] == [str(got[-1].vehicles[0].track_id)]
        p = last.detections[0].results[0].pose.pose.position
        assert p.x == pytest.approx(got[-1].vehicles[0].position.x)
    finally:
        ex.shutdown()
        node.destroy_node()
        helper.destroy_node()
