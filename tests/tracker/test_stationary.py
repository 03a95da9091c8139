"""The stationary model beside the motion filter (issue #41 item 4): in the world frame a parked
car's reported position is the mean of its noisy detections (it does not jump with each
correction of the filter's velocity), its velocity over the ground ~0; a moving car leaves the
parked estimate within a few frames."""

from __future__ import annotations

import numpy as np
from tracker_node.config import TrackerConfig
from tracker_node.tracker import DetectionBatch, Tracker
from vehicle_common.camera_motion import CameraMotion

DT = 0.1
EGO = 15.0  # [m/s] the camera drives straight ahead
PARKED = np.array([-4.0, 1.0, 40.0])  # in the first camera frame
MOVER = np.array([4.0, 1.0, 30.0])  # drives ahead at MOVER_V over the ground
MOVER_V = 10.0
DEPTH_STD = 0.6  # [m] stereo depth noise at 30-40 m


def _run(prior: float, n: int = 40, seed: int = 0):
    cfg = TrackerConfig(min_hits=1, world_process_noise=0.5, stationary_prior=prior)
    trk = Tracker(cfg)
    rng = np.random.default_rng(seed)
    R = np.diag([0.05**2, 0.05**2, DEPTH_STD**2])
    motion = CameraMotion(np.eye(3), np.array([0.0, 0.0, -EGO * DT]), DT)
    pos = {1: [], 2: []}
    vel = {1: [], 2: []}
    for k in range(n):
        cam = np.array([0.0, 0.0, EGO * DT * k])
        truth = [PARKED - cam, MOVER + np.array([0, 0, MOVER_V * DT * k]) - cam]
        z = np.array([t + rng.normal(0.0, np.sqrt(np.diag(R))) for t in truth])
        ts = trk.step(
            DetectionBatch.create(z, covariance=np.stack([R, R])),
            stamp=k * DT,
            camera_motion=motion if k else None,
        )
        for i, tid in enumerate(ts.track_id):
            pos[int(tid)].append(ts.position[i] + cam)  # back in the world
            vel[int(tid)].append(ts.velocity_over_ground[i])
    return {t: np.array(p) for t, p in pos.items()}, {t: np.array(v) for t, v in vel.items()}


def _jitter(p: np.ndarray) -> float:
    d2 = p[2:] - 2 * p[1:-1] + p[:-2]
    return float(np.sqrt(np.mean(np.sum(d2[:, [0, 2]] ** 2, axis=1))))


def test_parked_car_stands_still_with_the_stationary_model():
    off, _ = _run(0.0)
    on, v_on = _run(0.8)
    # after the start-up transient
    assert _jitter(on[1][5:]) < 0.5 * _jitter(off[1][5:])
    assert np.linalg.norm(np.median(v_on[1][5:], axis=0)) < 0.3


def test_moving_car_leaves_the_parked_estimate():
    off, v_off = _run(0.0)
    on, v_on = _run(0.8)
    # the mover's velocity over the ground is the motion filter's within a few frames
    assert abs(v_on[2][-1][2] - MOVER_V) < 1.0
    late = slice(8, None)
    err_on = np.abs(v_on[2][late, 2] - MOVER_V).mean()
    err_off = np.abs(v_off[2][late, 2] - MOVER_V).mean()
    assert err_on < err_off + 0.2


def test_off_without_the_world_frame():
    """No camera motion: the model stays inactive and the tracker reports the filter's state."""
    cfg = TrackerConfig(min_hits=1, stationary_prior=0.8)
    trk = Tracker(cfg)
    ref = Tracker(TrackerConfig(min_hits=1))
    for k in range(5):
        z = DetectionBatch.create(np.array([[1.0, 1.0, 20.0 + 0.3 * k]]))
        a, b = trk.step(z, stamp=k * DT), ref.step(z, stamp=k * DT)
        np.testing.assert_allclose(a.position, b.position)
    assert not trk.stationary.active
