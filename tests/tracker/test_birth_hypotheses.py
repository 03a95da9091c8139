"""Velocity hypotheses at a track's birth (issue 23: velocity over the ground of oncoming cars):
a new track in the world frame carries parked / moving-both-ways Kalman copies, weighted by
their detections' likelihood, until it keeps the most probable one (birth_hypotheses.py)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from tracker_node.birth_hypotheses import (
    BirthHypotheses,
    gaussian_loglik,
    heading_axis,
    hypothesis_speeds,
)
from tracker_node.config import TrackerConfig
from tracker_node.kalman import BatchedKalmanFilter
from tracker_node.scene_motion import known_scene_var
from tracker_node.tracker import DetectionBatch, Tracker
from vehicle_common.camera_motion import CameraMotion

GRAPH = Path(__file__).resolve().parents[2] / "src/tracking_bringup/config/pipeline.params.yaml"
DT = 0.1
EGO = 10.0  # [m/s] the camera drives forward along z
STD = np.array([0.05, 0.03, 0.5])  # [m] stereo noise at ~30 m: lateral, vertical, depth


def _graph(**kw) -> TrackerConfig:
    return replace(TrackerConfig.from_yaml(GRAPH), **kw)


def _errors(cfg: TrackerConfig, v_ground: float, n: int = 8, seeds: int = 20) -> np.ndarray:
    """Velocity-over-the-ground errors (seeds, n) of a car at z 30 m, x -3 m, moving at
    ``v_ground`` along z over the ground (negative: oncoming), seen from the driving camera
    with stereo noise, orientation bin 2 (heading along z up to 180 degrees); NaN before the
    track is output."""
    motion = CameraMotion(np.eye(3), np.array([0.0, 0.0, -EGO * DT]), DT)
    out = np.full((seeds, n), np.nan)
    for s in range(seeds):
        rng = np.random.default_rng(s)
        trk = Tracker(cfg)
        for k in range(n):
            truth = np.array([-3.0, 1.0, 30.0 + (v_ground - EGO) * DT * k])
            z = truth + rng.normal(0.0, STD)
            dets = DetectionBatch.create(
                z[None],
                covariance=np.diag(STD**2)[None],
                orientation_bin=np.array([2]),
                score=np.array([0.9]),
            )
            ts = trk.step(dets, stamp=k * DT, camera_motion=motion)
            if len(ts):
                err = ts.velocity_over_ground[0] - np.array([0.0, 0.0, v_ground])
                out[s, k] = np.linalg.norm(err[[0, 2]])
    return out


def test_graph_config_enables_the_hypotheses_and_the_node_default_leaves_them_off():
    assert _graph().birth_max_speed > 0
    assert TrackerConfig().birth_max_speed == 0
    assert Tracker(TrackerConfig()).filter.hypotheses is None
    assert Tracker(_graph()).filter.hypotheses is not None


def _rms(errors: np.ndarray, frames: slice) -> float:
    return float(np.sqrt(np.nanmean(errors[:, frames] ** 2)))


def test_an_oncoming_car_reaches_its_speed_over_the_ground_faster():
    # an oncoming car at 12 m/s seen from a camera driving at 10 m/s (22 m/s closing), frames
    # 3-5 (hits 4-6; confirmed at 3): RMSE over 20 noise draws
    new = _rms(_errors(_graph(), -12.0), slice(3, 6))
    old = _rms(_errors(_graph(birth_max_speed=0.0), -12.0), slice(3, 6))
    assert new < 2.0, new
    assert new < 0.9 * old, (new, old)


def test_a_parked_car_stays_parked():
    new = _rms(_errors(_graph(), 0.0), slice(2, 6))
    old = _rms(_errors(_graph(birth_max_speed=0.0), 0.0), slice(2, 6))
    assert new < 1.3, new
    assert new < 0.75 * old, (new, old)


def test_a_car_driving_ahead_is_found_along_its_heading():
    new = _rms(_errors(_graph(), 15.0), slice(2, 6))
    old = _rms(_errors(_graph(birth_max_speed=0.0), 15.0), slice(2, 6))
    assert new < 0.8 * old, (new, old)


def test_without_camera_motion_the_hypotheses_change_nothing():
    rng = np.random.default_rng(3)
    cfgs = [_graph(), _graph(birth_max_speed=0.0)]
    trackers = [Tracker(c) for c in cfgs]
    for k in range(6):
        z = np.array([[-3.0, 1.0, 30.0 - 2.0 * k], [4.0, 1.0, 20.0]]) + rng.normal(0, 0.2, (2, 3))
        outs = [t.step(DetectionBatch.create(z), stamp=k * DT) for t in trackers]
        np.testing.assert_array_equal(outs[0].velocity, outs[1].velocity)
    assert not len(trackers[0].filter.hypotheses)


def test_hypothesis_speeds_and_heading_axis():
    np.testing.assert_allclose(hypothesis_speeds(15.0, 3), [0, 5, -5, 10, -10, 15, -15])
    axis = heading_axis(np.array([-np.pi / 2, 0.0, np.nan]), 3)
    np.testing.assert_allclose(axis, [[0, 0, 1], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_gaussian_loglik_matches_scipy():
    from scipy.stats import multivariate_normal

    S = np.array([[2.0, 0.3, 0.1], [0.3, 1.0, 0.0], [0.1, 0.0, 0.5]])
    d = np.array([0.4, -1.0, 0.2])
    want = multivariate_normal(np.zeros(3), S).logpdf(d)
    assert gaussian_loglik(d[None], S[None])[0] == pytest.approx(want)


def _bank(n_tracks: int) -> BirthHypotheses:
    h = BirthHypotheses(BatchedKalmanFilter(0.5), 10.0, 1, 0.2, known_scene_var(4.0), 3)
    x = np.zeros((n_tracks, 6))
    x[:, 2] = 20.0 + 10.0 * np.arange(n_tracks)
    P = np.repeat(np.diag([0.1, 0.1, 0.5, 4.0, 0.17, 4.0])[None], n_tracks, axis=0)
    h.start(np.arange(n_tracks), x, P, heading_axis(None, n_tracks))
    return h


def test_mixture_moments_and_the_most_likely_hypothesis():
    h = _bank(2)
    assert len(h) == 6
    x, P = h.mixture(np.array([0, 1]))
    # prior weights 0.8 / 0.1 / 0.1 at vz 0 / +10 / -10: mean 0, variance 4 + 0.2 * 100
    np.testing.assert_allclose(x[:, 5], 0.0, atol=1e-12)
    np.testing.assert_allclose(P[:, 5, 5], 4.0 + 20.0)
    # track 1 is seen moving at +10 m/s along z for a few frames; track 0 stands
    rng = np.random.default_rng(0)
    for k in range(1, 4):
        h.bank.predict(DT)
        z = np.array([[0.0, 0.0, 20.0], [0.0, 0.0, 30.0 + 10.0 * DT * k]])
        h.update(
            np.array([0, 1]),
            z + rng.normal(0, 0.05, (2, 3)),
            np.repeat(np.eye(3)[None] * 0.01, 2, 0),
        )
    best_x, _ = h.resolve(np.array([0, 1]))
    assert abs(best_x[0, 5]) < 1.0
    assert best_x[1, 5] == pytest.approx(10.0, abs=1.0)
    assert len(h) == 0


def test_dropping_tracks_keeps_each_bank_with_its_track():
    h = _bank(3)
    mask = np.array([True, False, True])
    h.keep(mask)
    assert sorted(set(h.owner.tolist())) == [0, 1]
    # the bank of the former track 2 (z 40 m) is now track 1's
    np.testing.assert_allclose(h.bank.x[h.owner == 1][:, 2], 40.0)


def test_hypotheses_are_velocities_over_the_ground_even_in_traffic():
    # established tracks driving at 15 m/s make the single prior's mean (their median) 15 m/s;
    # the hypotheses stay parked (the static world) and +-5, 10, 15 m/s along the heading
    kf = BatchedKalmanFilter(0.5, init_velocity="scene", birth_max_speed=15.0)
    z = np.array([[0.0, 1.0, 20.0], [3.0, 1.0, 30.0], [-3.0, 1.0, 40.0]])
    kf.add(z, np.repeat(np.eye(3)[None], 3, axis=0))
    kf.hypotheses.drop(np.arange(3))  # (no bank: not born in the world frame)
    kf.x[:, 5] = 15.0
    kf.updates[:] = 3
    kf.add(np.array([[-3.0, 1.0, 50.0]]), np.eye(3)[None], static_velocity=np.zeros((1, 3)))
    np.testing.assert_allclose(
        np.sort(kf.hypotheses.bank.x[:, 5]), [-15, -10, -5, 0, 5, 10, 15], atol=1e-12
    )
    assert kf.x[3, 5] == pytest.approx(0.0, abs=1e-9)  # the mixture's mean: symmetric
