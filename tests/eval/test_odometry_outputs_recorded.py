"""Odometry and TF in bags: the recorder gets /tf_static published before it started
(TRANSIENT_LOCAL, as tf2's static broadcaster); bag_player replays it latched; the odometry
check's reference path, label scale and parked-car spread on known data."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.odometry import CameraMount, Pose

from tests.ros_helpers import spin_until

pytest.importorskip("tf2_msgs.msg")


def test_recorder_records_a_static_transform_sent_before_it_started(tmp_path, rclpy_context):
    import rclpy
    from eval_node.recorder import BagRecorderNode
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from rosbags.highlevel import AnyReader
    from tf2_msgs.msg import TFMessage
    from vehicle_common.odometry_messages import OdometryFrames, rig_static_tf

    pub_node = rclpy.create_node("static_tf_pub", context=rclpy_context)
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub = pub_node.create_publisher(TFMessage, "/tf_static", latched)
    pub.publish(rig_static_tf(5, "left", "right", 0.54, OdometryFrames()))  # nobody listening
    bag = tmp_path / "bag"
    recorder = BagRecorderNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter("output", value=str(bag)),
            Parameter("topics", value=["tf_static:tf2_msgs/msg/TFMessage"]),
        ],
    )
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(recorder)
    ex.add_node(pub_node)
    try:
        assert spin_until(ex, lambda: recorder.message_count() == 1, timeout=15.0)
    finally:
        recorder.close()
        ex.shutdown()
        recorder.destroy_node()
        pub_node.destroy_node()
    with AnyReader([bag]) as reader:
        (msg,) = [reader.deserialize(r, c.msgtype) for c, _, r in reader.messages()]
    assert msg.transforms[0].child_frame_id == "right"


def test_bag_player_replays_tf_static_latched():
    from kitti_player_node.bag_player import QOS, _qos
    from rclpy.qos import DurabilityPolicy

    assert _qos("/rig2/tf_static").durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert _qos("/tf").durability == DurabilityPolicy.VOLATILE and _qos("/tf") is QOS


def test_odometry_check_on_a_known_drive():
    """A camera driving 2 m per frame with a 0.1 rad turn; two parked cars and one that drives
    with it: the label scale is the labels' step over the reference's, the path error of an
    odometry 3 % short is 3 % at the end, a parked car's track spread is measured."""
    from eval_node.odometry_check import (
        OdometryFrame,
        label_scale,
        parked_car_spreads,
        path_agreement,
    )
    from vehicle_common.camera_motion import rotation_from_vector

    step = Pose(rotation_from_vector([0, -0.01, 0]), [0, 0, 2.0])
    truth = [Pose()]
    for _ in range(10):
        truth.append(truth[-1].compose(step))
    # the reference says 2.1 m per frame (5 % long), the labels say 2.0
    ref_step = Pose(step.rotation, [0, 0, 2.1])
    reference = [Pose()]
    for _ in range(10):
        reference.append(reference[-1].compose(ref_step))
    world = {1: np.array([-3.0, 1.0, 30.0]), 2: np.array([4.0, 1.0, 45.0])}
    labels = {}
    for k, cam in enumerate(truth):
        seen = [(i, cam.inverse().apply(p)) for i, p in world.items()]
        seen.append((3, np.array([0.0, 1.0, 15.0])))  # drives ahead at the camera's speed
        labels[k] = seen
    scale, pairs = label_scale(labels, reference)
    assert pairs == 10 and scale == pytest.approx(2.0 / 2.1, rel=1e-9)
    first = CameraMount().pose  # odom <- camera at frame 0
    odom = {
        k: first.compose(Pose(c.rotation, 0.97 * c.translation)).translation
        for k, c in enumerate(truth)
    }
    exact = path_agreement(odom, first, reference, scale)
    end = np.linalg.norm(truth[-1].translation)
    assert exact["end_error_m"] == pytest.approx(0.03 * end, rel=1e-6)
    assert exact["length_ratio"] == pytest.approx(0.97, rel=1e-6)
    raw = path_agreement(odom, first, reference)
    assert raw["max_error_pct"] > exact["max_error_pct"] + 4.0
    # parked cars: car 1's track wanders 0.5 m in odom; the car driving with the camera is not
    # parked; tracks in the camera frame are refused
    frames = []
    for k, cam in enumerate(truth):
        pose = first.compose(cam)
        f = OdometryFrame(k, k, camera_pose=pose, tracks_frame="odom")
        f.labels = [(i, "Car", c, 4.0) for i, c in labels[k]]
        wobble = np.array([0.5 * (k % 2), 0.0, 0.0])
        f.tracks = [(7, 1, first.apply(world[1]) + wobble)]  # car 1 in odom, wobbling
        frames.append(f)
    spreads = {c["label"]: c for c in parked_car_spreads(frames)}
    assert set(spreads) == {1, 2}
    assert spreads[1]["tracks"] == [7] and spreads[1]["spread_m"] == pytest.approx(0.5)
    # the wobble's second difference is 1 m every frame; the labels, taken to odom by an exact
    # odometry, stand still
    assert spreads[1]["jitter_xy_m"] == pytest.approx(1.0)
    assert spreads[1]["label_jitter_xy_m"] == pytest.approx(0.0, abs=1e-9)
    # an odometry whose yaw swings back and forth by 0.2 deg moves car 1's labels (30 m away)
    # back and forth by about 0.1 m (second difference about 0.2 m); its track stays as it was
    shaken = []
    for f in frames:
        yaw = np.radians(0.2) * (f.frame % 2)
        shake = Pose(rotation_from_vector([0.0, 0.0, yaw]), [0.0, 0.0, 0.0])
        g = OdometryFrame(f.frame, f.stamp_ns, camera_pose=shake.compose(f.camera_pose))
        g.labels, g.tracks_frame, g.tracks = f.labels, "odom", f.tracks
        shaken.append(g)
    moved = {c["label"]: c for c in parked_car_spreads(shaken)}[1]
    assert 0.15 < moved["label_jitter_xy_m"] < 0.3
    assert moved["jitter_xy_m"] == pytest.approx(1.0)
    assert spreads[2]["frames"] == 0
    frames[3].tracks_frame = "left_camera_optical_frame"
    with pytest.raises(ValueError, match="not 'odom'"):
        parked_car_spreads(frames)


def test_recorder_records_the_vision_msgs_outputs_by_default(tmp_path, rclpy_context):
    """The default recorder (no ``topics`` given) records /vehicles/vision/detections_2d and
    /vehicles/vision/tracks (vision_msgs) beside the project's messages (issue #42: the README
    says every output is recorded, and these were not)."""
    import rclpy
    from eval_node.recorder import BagRecorderNode
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rosbags.highlevel import AnyReader
    from vision_msgs.msg import Detection2DArray, Detection3DArray

    pub_node = rclpy.create_node("vision_pub", context=rclpy_context)
    pubs = {
        "/vehicles/vision/detections_2d": pub_node.create_publisher(
            Detection2DArray, "/vehicles/vision/detections_2d", 10
        ),
        "/vehicles/vision/tracks": pub_node.create_publisher(
            Detection3DArray, "/vehicles/vision/tracks", 10
        ),
    }
    bag = tmp_path / "bag"
    recorder = BagRecorderNode(
        context=rclpy_context, parameter_overrides=[Parameter("output", value=str(bag))]
    )
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(recorder)
    ex.add_node(pub_node)
    try:
        assert spin_until(
            ex, lambda: all(p.get_subscription_count() for p in pubs.values()), timeout=15.0
        )
        for topic, pub in pubs.items():
            msg = pub.msg_type()
            msg.header.frame_id = topic
            pub.publish(msg)
        assert spin_until(ex, lambda: recorder.message_count() == 2, timeout=15.0)
    finally:
        recorder.close()
        ex.shutdown()
        recorder.destroy_node()
        pub_node.destroy_node()
    with AnyReader([bag]) as reader:
        got = {c.topic: reader.deserialize(r, c.msgtype) for c, _, r in reader.messages()}
    assert {t: m.header.frame_id for t, m in got.items()} == {t: t for t in pubs}
