"""The camera's pose integrated in odom (vehicle_common.odometry): exact on known trajectories,
REP-103/105 frames, frames without a motion (extrapolated, then replaced by a bridging motion),
covariance growth, twist, and the base frame of a camera mount."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.camera_motion import CameraMotion, rotation_from_vector
from vehicle_common.odometry import (
    BODY_FROM_OPTICAL,
    UNKNOWN_VARIANCE,
    CameraMount,
    OdometryIntegrator,
    OdometryNoise,
    Pose,
    base_odometry,
    rpy_rotation,
)

DT = 0.1
NS = 100_000_000  # 0.1 s


def _motion(before: Pose, after: Pose, dt: float = DT) -> CameraMotion:
    """The static-point motion between two camera poses (X_after = R X_before + t)."""
    rel = after.inverse().compose(before)
    return CameraMotion(rel.rotation, rel.translation, dt)


def _turning_drive(n: int, speed: float = 15.0, yaw_rate: float = 0.2) -> list[Pose]:
    """Camera poses in odom (optical frame) of a camera driving forward while turning left."""
    poses, pose = [], CameraMount().pose
    step = Pose(rotation_from_vector([0.0, -yaw_rate * DT, 0.0]), [0.0, 0.0, speed * DT])
    for _ in range(n):
        poses.append(pose)
        pose = pose.compose(step)  # optical -y is up: a left turn
    return poses


def test_frames_follow_rep_103_and_rep_105():
    """odom starts at the camera, x forward, y left, z up: driving along the optical axis is
    odom +x, the optical frame's x (right) is odom -y."""
    assert np.allclose(BODY_FROM_OPTICAL @ [0, 0, 1], [1, 0, 0])
    assert np.allclose(BODY_FROM_OPTICAL @ [1, 0, 0], [0, -1, 0])
    assert np.allclose(BODY_FROM_OPTICAL @ [0, 1, 0], [0, 0, -1])
    odo = OdometryIntegrator()
    first = odo.update(0, None)
    assert np.allclose(first.pose.translation, 0) and np.allclose(first.covariance, 0)
    forward = CameraMotion(np.eye(3), np.array([0.0, 0.0, -1.5]), DT)  # static points come closer
    s = odo.update(NS, forward)
    assert np.allclose(s.pose.translation, [1.5, 0.0, 0.0])
    assert np.allclose(s.linear_velocity, [0.0, 0.0, 15.0])  # camera (optical) axes
    assert s.measured


def test_a_turning_drive_is_integrated_exactly():
    truth = _turning_drive(30)
    odo = OdometryIntegrator()
    odo.update(0, None)
    for k in range(1, 30):
        s = odo.update(k * NS, _motion(truth[k - 1], truth[k]))
        assert np.allclose(s.pose.rotation, truth[k].rotation, atol=1e-9)
        assert np.allclose(s.pose.translation, truth[k].translation, atol=1e-9)
    # it turned left: odom +y, and its yaw rate about odom z is +0.2 rad/s
    assert truth[-1].translation[1] > 5.0
    assert np.allclose(s.angular_velocity, [0.0, -0.2, 0.0])  # about the optical -y (up)
    # the steps go straight, then turn: seen from half a turn on, the chord points right (+x)
    assert np.linalg.norm(s.linear_velocity) == pytest.approx(15.0)
    assert np.allclose(s.linear_velocity, [0.15, 0.0, 15.0], atol=1e-3)


def test_a_frame_without_motion_is_extrapolated_then_bridged():
    """Frame 3 has no motion: extrapolated with the last twist, flagged, with a larger
    covariance step; frame 4's motion spans 2 -> 4 (the odometry bridges the lost frame) and
    gives the exact pose, not the extrapolation plus a step."""
    truth = _turning_drive(6)
    odo = OdometryIntegrator()
    odo.update(0, None)
    s1 = odo.update(1 * NS, _motion(truth[0], truth[1]))
    s2 = odo.update(2 * NS, _motion(truth[1], truth[2]))
    s3 = odo.update(3 * NS, None)
    assert not s3.measured and s3.extrapolated_frames == 1
    assert np.allclose(s3.pose.translation, truth[3].translation, atol=1e-9)  # constant twist
    measured_growth = np.trace(s2.covariance) - np.trace(s1.covariance)
    assert np.trace(s3.covariance) - np.trace(s2.covariance) > measured_growth
    s4 = odo.update(4 * NS, _motion(truth[2], truth[4], 2 * DT))
    assert s4.measured and s4.extrapolated_frames == 0
    assert np.allclose(s4.pose.translation, truth[4].translation, atol=1e-9)
    # the bridged step compounds from frame 2's covariance, not from frame 3's extrapolation:
    # as if frame 3 had never been there
    never = OdometryIntegrator()
    never.update(0, None)
    never.update(1 * NS, _motion(truth[0], truth[1]))
    never.update(2 * NS, _motion(truth[1], truth[2]))
    direct = never.update(4 * NS, _motion(truth[2], truth[4], 2 * DT))
    assert np.allclose(s4.covariance, direct.covariance, rtol=1e-12, atol=0)
    # a wrong extrapolation is replaced, not added to: a camera that braked hard at frame 3
    odo2 = OdometryIntegrator()
    odo2.update(0, None)
    odo2.update(NS, CameraMotion(np.eye(3), np.array([0.0, 0.0, -1.5]), DT))
    odo2.update(2 * NS, None)  # extrapolated to 3.0 m
    s = odo2.update(3 * NS, CameraMotion(np.eye(3), np.array([0.0, 0.0, -0.5]), 2 * DT))
    assert np.allclose(s.pose.translation, [2.0, 0.0, 0.0])


def test_covariance_grows_and_follows_the_heading_uncertainty():
    """Never shrinks; with rotation noise the lateral (odom y) variance grows faster than the
    along-track one (the heading's uncertainty swings the position sideways); the step noise
    is the documented fraction of the step."""
    noise = OdometryNoise(translation_fraction=0.0, translation_floor=0.0, rotation=0.001)
    odo = OdometryIntegrator(noise=noise)
    odo.update(0, None)
    forward = CameraMotion(np.eye(3), np.array([0.0, 0.0, -1.5]), DT)
    traces = []
    for k in range(1, 40):
        s = odo.update(k * NS, forward)
        traces.append(np.trace(s.covariance))
    assert all(b >= a for a, b in zip(traces, traces[1:], strict=False))
    assert s.covariance[1, 1] > 100 * max(s.covariance[0, 0], 1e-12)
    # a yaw std of sqrt(39) mrad after 39 steps; lateral std about that x the lever arm
    assert np.sqrt(s.covariance[5, 5]) == pytest.approx(0.001 * np.sqrt(39), rel=1e-6)
    cov = OdometryNoise().step_covariance(forward)
    assert np.sqrt(cov[0, 0]) == pytest.approx(np.hypot(0.02 * 1.5, 0.005))
    assert np.sqrt(cov[3, 3]) == pytest.approx(0.0003)
    # symmetric and positive definite after many steps
    assert np.allclose(s.covariance, s.covariance.T)
    assert np.linalg.eigvalsh(s.covariance + np.eye(6) * 1e-12).min() > 0


def test_before_any_motion_the_camera_is_held_with_an_unknown_twist():
    odo = OdometryIntegrator()
    odo.update(0, None)
    s = odo.update(NS, None)
    assert np.allclose(s.pose.translation, 0) and not s.measured
    assert s.twist_covariance[0, 0] >= UNKNOWN_VARIANCE
    assert s.covariance[0, 0] >= UNKNOWN_VARIANCE  # where it is is not known either


def test_stamps_come_in_order():
    odo = OdometryIntegrator()
    odo.update(5 * NS, None)
    again = odo.update(5 * NS, CameraMotion(np.eye(3), np.zeros(3), DT))
    assert again.stamp_ns == 5 * NS and not again.measured  # the same frame, unchanged
    with pytest.raises(ValueError, match="before the last"):
        odo.update(4 * NS, None)


def test_a_camera_mount_gives_the_base_frames_odometry():
    """A camera 1.5 m ahead of the base and 1.6 m up, pitched down 5 deg: odom -> base starts at
    identity (REP-105), the base moves as the camera does, and a turn on the spot moves the
    camera (lever arm) but not the base."""
    mount = CameraMount((1.5, 0.0, 1.6), (0.0, np.radians(5.0), 0.0))
    assert np.allclose(mount.pose.rotation @ [0, 0, 1], rpy_rotation(0, np.radians(5), 0)[:, 0])
    odo = OdometryIntegrator(initial=mount.pose)
    first = odo.update(0, None)
    base, *_ = base_odometry(first, mount.pose)
    assert np.allclose(base.rotation, np.eye(3)) and np.allclose(base.translation, 0)
    # the base turns on the spot about its z axis at 0.5 rad/s
    turn = Pose(rpy_rotation(0, 0, 0.05), np.zeros(3))
    camera_after = turn.compose(mount.pose)
    s = odo.update(NS, _motion(mount.pose, camera_after))
    base, _, v, w, _ = base_odometry(s, mount.pose)
    assert np.allclose(base.translation, 0, atol=1e-12)
    assert np.allclose(base.rotation, turn.rotation)
    assert np.allclose(w, [0, 0, 0.5], atol=1e-9)
    assert np.allclose(v, 0, atol=1e-3)  # the camera moved 7.5 cm/step sideways, the base not
    assert np.linalg.norm(s.linear_velocity) > 0.7


def test_anchoring_keeps_a_consumer_on_the_publishers_pose():
    """A consumer (the tracker) sets the pose /tf gives and carries on from it with the
    motions when a frame's transform is missing."""
    truth = _turning_drive(4)
    shifted = [Pose(p.rotation, p.translation + [100.0, 0, 0]) for p in truth]
    odo = OdometryIntegrator()
    odo.update(0, None)
    odo.anchor(0, shifted[0])
    odo.update(NS, _motion(truth[0], truth[1]))
    odo.anchor(NS, shifted[1])
    s = odo.update(2 * NS, _motion(truth[1], truth[2]))  # no /tf for this frame
    assert np.allclose(s.pose.translation, shifted[2].translation, atol=1e-9)
