"""The tracker's own evidence for orientation (issue #34 part 5): a moving car's heading is its
direction of travel over the ground. Once a track's velocity over the ground is well determined,
its reported yaw combines that heading with the detector's bin yaw (known only up to 180 deg and
to the bin's +-22.5 deg), and its orientation bin follows the observation angle that yaw
implies; a parked car keeps the detector's yaw."""

from __future__ import annotations

import math

import numpy as np
import pytest
from tracker_node.config import TrackerConfig
from tracker_node.orientation import fuse_heading, motion_heading
from tracker_node.tracker import DetectionBatch, Tracker
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.kitti import alpha_from_rotation_y, wrap_angle
from vehicle_common.orientation_bins import alpha_to_bin

DT = 0.1
EGO = 10.0  # [m/s] the camera drives forward along its z


def _track(car_start, car_velocity, n: int = 25, **cfg):
    """Track one car from a camera driving straight ahead; its detections carry the bin of
    its true observation angle (the detector's 4 bins: +-22.5 deg, 180 deg ambiguous).
    Returns the last TrackSet and the car's true rotation_y and position then."""
    config = TrackerConfig(min_hits=1, measurement_noise=0.2, **cfg)
    trk = Tracker(config)
    motion = CameraMotion(np.eye(3), np.array([0.0, 0.0, -EGO * DT]), DT)
    v = np.asarray(car_velocity, float)
    ry = math.atan2(-v[2], v[0]) if np.linalg.norm(v) > 0 else -math.pi / 2
    rng = np.random.default_rng(1)
    out = None
    for k in range(n):
        world = np.asarray(car_start, float) + v * DT * k
        cam = world - np.array([0.0, 0.0, EGO * DT * k])
        b = alpha_to_bin(alpha_from_rotation_y(ry, cam[0], cam[2]))
        det = DetectionBatch.create(
            (cam + rng.normal(0.0, 0.1, 3))[None], orientation_bin=np.array([b])
        )
        out = trk.step(det, stamp=k * DT, camera_motion=motion if k else None)
    return out, ry, cam


def test_a_moving_cars_yaw_is_its_direction_of_travel():
    # driving away at 8 m/s over the ground, 23 deg off the optical axis, on the right: the
    # bins of its observation angle (near the 90 / 135 deg border) give a yaw 15 deg off
    ry = math.radians(-67.0)
    velocity = (8.0 * math.cos(ry), 0.0, -8.0 * math.sin(ry))
    on, ry, cam = _track((4.0, 0.9, 20.0), velocity, motion_heading_max_std=20.0)
    off, _, _ = _track((4.0, 0.9, 20.0), velocity)
    err_on = abs(wrap_angle(on.yaw[0] - ry))
    err_off = abs(wrap_angle(off.yaw[0] - ry))
    assert err_on < math.radians(2.0) and err_off > math.radians(10.0)
    # its orientation bin is the one of the observation angle the fused yaw implies
    assert on.orientation_bin[0] == alpha_to_bin(alpha_from_rotation_y(ry, cam[0], cam[2]))


def test_a_parked_car_keeps_the_detectors_yaw():
    on, _, _ = _track((4.0, 0.9, 30.0), (0.0, 0.0, 0.0), motion_heading_max_std=20.0)
    off, _, _ = _track((4.0, 0.9, 30.0), (0.0, 0.0, 0.0))
    assert on.yaw[0] == pytest.approx(off.yaw[0])


def test_heading_std_and_fusion_weights():
    v = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 1.0]])
    cov = np.array([np.diag([1.0, 0.1, 4.0])] * 2)
    heading, std, speed = motion_heading(v, cov)
    # across the direction of travel (x) 1 m/s: 0.1 rad at 10 m/s, 1 rad at 1 m/s
    np.testing.assert_allclose(std, [0.1, 1.0])
    np.testing.assert_allclose(speed, [10.0, 1.0])
    np.testing.assert_allclose(heading, -math.pi / 2)
    # a bin yaw pointing the other way is turned to the heading's side first
    fused = fuse_heading(np.array([math.pi / 2 + 0.2]), 0.2, np.array([-math.pi / 2]), 0.2)
    assert fused[0] == pytest.approx(-math.pi / 2 + 0.1)
