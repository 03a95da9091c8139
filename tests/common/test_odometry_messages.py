"""The odometry's messages (nav_msgs/Odometry, /tf, /tf_static) and the tf buffer consumers
use: fields, frames, stamps, covariance layout."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.frame_messages import read_transform, rotation_from_quaternion, stamp_ns
from vehicle_common.odometry import (
    BODY_FROM_OPTICAL,
    CameraMount,
    OdometryIntegrator,
    Pose,
    rpy_rotation,
)
from vehicle_common.odometry_messages import (
    OdometryFrames,
    TransformTree,
    odometry_message,
    odometry_tf,
    rig_static_tf,
    transforms_from_tf,
)

pytest.importorskip("nav_msgs.msg")
pytest.importorskip("tf2_msgs.msg")

LEFT, RIGHT = "left_camera_optical_frame", "right_camera_optical_frame"
T0 = 1_700_000_000_123_456_789


def _two_frames(initial: Pose):
    odo = OdometryIntegrator(initial)
    odo.update(T0, None)
    # forward 1.5 m and a left turn of 0.01 rad about the optical -y (up)
    # (static points rotate about the optical y, down, by +0.01: the camera by -0.01, i.e.
    # about up by +0.01)
    motion = CameraMotion(rpy_rotation(0.0, 0.01, 0.0), np.array([0.0, 0.0, -1.5]), 0.1)
    return odo.update(T0 + 100_000_000, motion)


def _cov(values) -> np.ndarray:
    assert len(values) == 36
    return np.asarray(values, float).reshape(6, 6)


def test_odometry_message_of_the_camera():
    s = _two_frames(CameraMount().pose)
    msg = odometry_message(s, LEFT, OdometryFrames())
    assert msg.header.frame_id == "odom" and msg.child_frame_id == LEFT
    assert stamp_ns(msg.header) == T0 + 100_000_000
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    assert (p.x, p.y, p.z) == pytest.approx(tuple(s.pose.translation))
    assert p.x == pytest.approx(1.5, abs=1e-3) and 0 < p.y < 0.02  # forward, turning left
    R = rotation_from_quaternion(q.w, q.x, q.y, q.z)
    assert np.allclose(R, s.pose.rotation) and q.w >= 0
    # row-major 6x6, (x, y, z, rot x, rot y, rot z), odom axes: the state's covariance
    cov = _cov(msg.pose.covariance)
    assert np.allclose(cov, s.covariance) and np.allclose(cov, cov.T)
    assert cov[0, 0] > 0 and cov[5, 5] > 0
    # twist in the child (optical) axes: forward is +z, the yaw rate about -y
    t = msg.twist.twist
    assert t.linear.z == pytest.approx(15.0, rel=1e-3) and abs(t.linear.x) < 0.1
    assert t.angular.y == pytest.approx(-0.1, rel=1e-6)
    assert np.allclose(_cov(msg.twist.covariance), s.twist_covariance)


def test_odometry_and_tf_of_a_base_frame_with_a_mount():
    mount = CameraMount((1.2, 0.0, 1.65), (0.0, 0.0, 0.0))
    frames = OdometryFrames("odom", "base_link", mount.pose)
    s = _two_frames(mount.pose)
    msg = odometry_message(s, LEFT, frames)
    assert msg.child_frame_id == "base_link"
    p = msg.pose.pose.position
    # the base went 1.5 m forward (odom x) and stays on the ground (z 0), not at camera height
    assert p.x == pytest.approx(1.5, abs=0.02) and abs(p.z) < 1e-9
    assert msg.twist.twist.angular.z == pytest.approx(0.1, rel=1e-6)  # base axes: z up
    tf = odometry_tf(s, LEFT, frames)
    (t,) = tf.transforms
    assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
    assert stamp_ns(t.header) == s.stamp_ns
    R, tv = read_transform(t.transform)
    assert np.allclose(tv, (p.x, p.y, p.z))
    static = rig_static_tf(T0, LEFT, RIGHT, 0.54, frames)
    links = {(x.header.frame_id, x.child_frame_id): x for x in static.transforms}
    assert set(links) == {("base_link", LEFT), (LEFT, RIGHT)}
    R, tv = read_transform(links[("base_link", LEFT)].transform)
    assert np.allclose(tv, [1.2, 0.0, 1.65]) and np.allclose(R, BODY_FROM_OPTICAL)
    R, tv = read_transform(links[(LEFT, RIGHT)].transform)
    assert np.allclose(tv, [0.54, 0, 0]) and np.allclose(R, np.eye(3))


def test_camera_tf_and_static_without_a_base_frame():
    s = _two_frames(CameraMount().pose)
    (t,) = odometry_tf(s, LEFT, OdometryFrames()).transforms
    assert (t.header.frame_id, t.child_frame_id) == ("odom", LEFT)
    (link,) = rig_static_tf(T0, LEFT, RIGHT, 0.54, OdometryFrames()).transforms
    assert (link.header.frame_id, link.child_frame_id) == (LEFT, RIGHT)


def test_transform_tree_chains_static_and_dynamic_links_at_exact_stamps():
    mount = CameraMount((1.2, 0.0, 1.65))
    frames = OdometryFrames("odom", "base_link", mount.pose)
    s = _two_frames(mount.pose)
    tree = TransformTree()
    tree.add_message(rig_static_tf(T0, LEFT, RIGHT, 0.54, frames), static=True)
    tree.add_message(odometry_tf(s, LEFT, frames))
    pose = tree.lookup("odom", LEFT, s.stamp_ns)
    assert np.allclose(pose.rotation, s.pose.rotation)
    assert np.allclose(pose.translation, s.pose.translation)
    right = tree.lookup("odom", RIGHT, s.stamp_ns)
    assert np.allclose(right.translation, s.pose.apply([0.54, 0.0, 0.0]))
    inverse = tree.lookup(LEFT, "odom", s.stamp_ns)
    assert np.allclose(inverse.compose(pose).translation, 0, atol=1e-12)
    assert tree.lookup("odom", LEFT, s.stamp_ns + 1) is None  # no transform at that stamp
    assert tree.lookup("map", LEFT, s.stamp_ns) is None  # not connected
    assert tree.lookup(LEFT, LEFT, 0).translation.tolist() == [0, 0, 0]


def test_a_malformed_transform_is_named():
    s = _two_frames(CameraMount().pose)
    msg = odometry_tf(s, LEFT, OdometryFrames())
    msg.transforms[0].transform.rotation.w = float("nan")
    with pytest.raises(ValueError, match=r"transform 0 \(odom -> left_camera_optical_frame\)"):
        transforms_from_tf(msg)
    msg.transforms[0].child_frame_id = ""
    with pytest.raises(ValueError, match="transform 0: frames"):
        TransformTree().add_message(msg)
