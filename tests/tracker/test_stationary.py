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


def _lead_car(cfg: TrackerConfig, n: int = 8, seed: int = 1, speed_err: bool = False):
    """Reported position errors (n,) [m] (``speed_err``: and velocity-over-the-ground errors
    [m/s]) of a car driving ahead of the camera at the camera's speed (it keeps its place in
    the image, as real 0005's lead car), first seen in the first frame, before the camera's
    motion is known; its detections carry its yaw (driving away: -pi/2)."""
    trk = Tracker(cfg)
    rng = np.random.default_rng(seed)
    R = np.diag([0.05**2, 0.05**2, DEPTH_STD**2])
    motion = CameraMotion(np.eye(3), np.array([0.0, 0.0, -EGO * DT]), DT)
    lead = np.array([0.0, 1.0, 35.0])  # in every camera frame
    err, verr = [], []
    for k in range(n):
        z = lead + rng.normal(0.0, np.sqrt(np.diag(R)))
        ts = trk.step(
            DetectionBatch.create(z[None], covariance=R[None], yaw=np.array([-np.pi / 2])),
            stamp=k * DT,
            camera_motion=motion if k else None,
        )
        err.append(float(np.linalg.norm(ts.position[0] - lead)))
        verr.append(float(np.linalg.norm(ts.velocity_over_ground[0] - [0.0, 0.0, EGO])))
    return (np.array(err), np.array(verr)) if speed_err else np.array(err)


def test_moving_car_is_not_reported_at_its_parked_estimate_while_young():
    """Real 0005's lead car (18 m/s, the camera's speed) lost the 1.5 m match at its third
    frame: the parked prior (0.8) had it reported 74 % at its parked estimate, which lags a
    moving car by its speed times the frames. The parked estimate is blended only once it has
    taken ``stationary_min_updates`` detections (the evidence has moved ``mu`` off the
    prior); a young moving car is reported where the motion filter has it."""
    base = dict(min_hits=1, world_process_noise=0.5)
    off = _lead_car(TrackerConfig(**base))
    on = _lead_car(TrackerConfig(**base, stationary_prior=0.8, stationary_min_updates=3))
    old = _lead_car(TrackerConfig(**base, stationary_prior=0.8))  # blended from the start
    # frames 1-2: the evidence is not in yet; reported where the motion filter has the car
    np.testing.assert_allclose(on[:3], off[:3], atol=0.05)  # the IMM mixing aside
    assert old[1:3].max() > 2.0 * on[1:3].max()


def _braking_car(cfg: TrackerConfig, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Reported position errors [m] and velocity-over-the-ground errors [m/s] of a car ahead
    that drives at 12 m/s, brakes at 6 m/s^2 from frame 15 and stands from frame 17 on, seen
    from the camera driving at EGO (frames 10-40)."""
    trk = Tracker(cfg)
    rng = np.random.default_rng(seed)
    R = np.diag([0.05**2, 0.05**2, DEPTH_STD**2])
    motion = CameraMotion(np.eye(3), np.array([0.0, 0.0, -EGO * DT]), DT)
    x, v, pos_err, vel_err = 30.0, 12.0, [], []
    for k in range(40):
        cam = np.array([0.0, 0.0, EGO * DT * k])
        truth = np.array([3.5, 1.0, x]) - cam
        z = truth + rng.normal(0.0, np.sqrt(np.diag(R)))
        ts = trk.step(
            DetectionBatch.create(z[None], covariance=R[None]),
            stamp=k * DT,
            camera_motion=motion if k else None,
        )
        if k >= 10 and truth[2] > 3.0:
            pos_err.append(float(np.linalg.norm(ts.position[0] - truth)))
            vel_err.append(abs(float(ts.velocity_over_ground[0][2]) - v))
        a = 6.0 if k >= 15 and v > 0 else 0.0
        x += v * DT - 0.5 * a * DT**2 * (v > 0)
        v = max(v - a * DT, 0.0)
    return np.array(pos_err), np.array(vel_err)


def test_braking_car_is_followed_as_without_the_parked_model():
    """A car that brakes to a stop: the reported position and velocity follow it as closely
    as without the parked model (the velocity is the motion filter's; the parked estimate
    takes over only once the car stands)."""
    on_p, on_v, off_p, off_v = [], [], [], []
    for seed in range(10):
        p, v = _braking_car(TrackerConfig(min_hits=1, stationary_prior=0.8), seed)
        on_p.append(p), on_v.append(v)
        p, v = _braking_car(TrackerConfig(min_hits=1), seed)
        off_p.append(p), off_v.append(v)
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))  # noqa: E731
    assert rms(on_p) <= rms(off_p) * 1.05
    assert rms(on_v) <= rms(off_v) + 0.05


def test_tracks_seen_before_the_world_frame_get_velocity_hypotheses():
    """A car seen once before the camera's motion arrives (every car of the first frame) takes
    the birth hypotheses when the world frame begins, as a car born then would: real 0005's
    lead car (18 m/s, born in the first frame) had one narrow prior about parked instead, and
    its velocity over the ground took 8 frames to reach 15 m/s."""
    base = dict(min_hits=1, world_process_noise=0.5, birth_max_speed=15.0)
    err = {}
    for flag in (False, True):
        cfg = TrackerConfig(**base, world_entry_hypotheses=flag)
        v = np.array([_lead_car(cfg, seed=s, speed_err=True)[1] for s in range(10)])
        err[flag] = v[:, 3:].mean()
    assert err[True] < 0.8 * err[False]


def _outlier_kick(
    k: float, jump: float = 3.0, n: int = 6, noise: float = 1.0, models: str = "both"
):
    """A parked car (world frame, stationary model on) with one depth outlier of ``jump`` m at
    frame ``n``: how far the reported position and the velocity over the ground move."""
    cfg = TrackerConfig(
        min_hits=1,
        world_process_noise=0.5,
        stationary_prior=0.8,
        robust_update_k=k,
        robust_update_models=models,
    )
    trk = Tracker(cfg)
    rng = np.random.default_rng(3)
    R = np.diag([0.05**2, 0.05**2, DEPTH_STD**2])
    motion = CameraMotion(np.eye(3), np.array([0.0, 0.0, -EGO * DT]), DT)
    out = []
    for j in range(n + 1):
        cam = np.array([0.0, 0.0, EGO * DT * j])
        z = PARKED - cam + noise * rng.normal(0.0, np.sqrt(np.diag(R)))
        if j == n:
            z[2] += jump
        ts = trk.step(
            DetectionBatch.create(z[None], covariance=R[None]),
            stamp=j * DT,
            camera_motion=motion if j else None,
        )
        assert len(ts) == 1
        out.append((ts.position[0] + cam, ts.velocity_over_ground[0]))
    (p0, v0), (p1, v1) = out[-2], out[-1]
    return float(np.linalg.norm(p1 - p0)), float(np.linalg.norm(v1 - v0))


def test_robust_update_resists_one_depth_outlier():
    """robust_update_k: one detection 3 m too far (about 4 standard deviations of a young
    track's innovation, still inside the association gate) moves a parked track's reported
    position much less than the plain update (0.52 -> 0.27 m); with ``robust_update_models:
    both`` its velocity too (2.5 -> 1.7 m/s); without the outlier (noise-free detections)
    nothing changes."""
    dp_plain, dv_plain = _outlier_kick(0.0)
    dp_parked, _ = _outlier_kick(2.0, models="parked")
    dp_both, dv_both = _outlier_kick(2.0, models="both")
    assert dp_parked < 0.6 * dp_plain
    assert dp_both < 0.6 * dp_plain
    assert dv_both < 0.75 * dv_plain
    for models in ("parked", "both"):
        quiet = _outlier_kick(2.0, jump=0.0, noise=0.0, models=models)
        assert quiet == _outlier_kick(0.0, jump=0.0, noise=0.0)


def _oncoming(report_rate: float, seed: int, n: int = 20):
    """A far oncoming car (first seen at 70 m, 13 m/s toward a camera driving at 10 m/s, depth
    std 2.5 m as the ranging's beyond 60 m) beside a near parked car, tracked with the graph's
    tracker values (confirmation off): (second differences [m] of its reported position in the
    world frame, its position errors [m]), x and z."""
    import dataclasses

    from tracking_bringup.parameters import graph_values

    names = {f.name for f in dataclasses.fields(TrackerConfig)}
    values = {k: v for k, v in graph_values("vehicle_tracker").items() if k in names}
    values.update(min_hits=1, min_hits_span=0.0, birth_score=0.0, coast_min_score=0.0)
    values["stationary_report_rate"] = report_rate
    trk = Tracker(TrackerConfig(**values))
    rng = np.random.default_rng(seed)
    far, near = np.diag([0.05**2, 0.05**2, 2.5**2]), np.diag([0.05**2, 0.05**2, 0.3**2])
    ego = 10.0
    motion = CameraMotion(np.eye(3), np.array([0.0, 0.0, -ego * DT]), DT)
    reported, truths = [], []
    for k in range(n):
        cam = np.array([0.0, 0.0, ego * DT * k])
        z, R = [np.array([-5.0, 1.0, 20.0]) - cam], [near]
        if k >= 3:
            truth = np.array([3.0, 1.0, 70.0 - 13.0 * DT * (k - 3)]) - cam
            z.append(truth + rng.normal(0.0, np.sqrt(np.diag(far))))
            R.append(far)
        ts = trk.step(
            DetectionBatch.create(np.array(z), covariance=np.stack(R)),
            stamp=k * DT,
            camera_motion=motion if k else None,
        )
        if k >= 3:
            i = int(np.argmin(np.abs(ts.position[:, 0] - 3.0)))
            reported.append(ts.position[i] + cam)
            truths.append(truth + cam)
    p, t = np.array(reported)[:, [0, 2]], np.array(truths)[:, [0, 2]]
    d2 = p[2:] - 2 * p[1:-1] + p[:-2]
    return np.linalg.norm(d2, axis=1), np.linalg.norm(p - t, axis=1)


def test_report_rate_spreads_the_catch_up_of_a_car_first_taken_for_parked():
    """A far oncoming car is first taken for parked (the prior, and a depth noise that hides
    its motion for a few frames); when ``mu`` collapses, its reported position caught up by
    metres in one frame. ``stationary_report_rate`` r lets the parked weight change by at most
    r per frame: the catch-up is spread over frames (smaller second differences, a little more
    position error meanwhile); r = 1 reports what the model reports without the limit."""
    from tracker_node.stationary import StationaryModel

    base = dict(min_hits=1, world_process_noise=0.5, stationary_prior=0.8)
    ref = _lead_car(TrackerConfig(**base), n=12)
    same = _lead_car(TrackerConfig(**base, stationary_report_rate=1.0), n=12)
    np.testing.assert_array_equal(ref, same)

    runs = {r: [_oncoming(r, seed) for seed in range(8)] for r in (1.0, 0.3)}
    rms = {r: np.sqrt(np.mean(np.concatenate([d for d, _ in v]) ** 2)) for r, v in runs.items()}
    worst = {r: np.mean([d.max() for d, _ in v]) for r, v in runs.items()}
    err = {r: np.mean(np.concatenate([e for _, e in v])) for r, v in runs.items()}
    assert rms[0.3] < 0.8 * rms[1.0] and worst[0.3] < 0.8 * worst[1.0]
    assert err[0.3] < 1.15 * err[1.0]

    # the weight itself: follows mu, at most r per frame, 0 until min_updates
    m = StationaryModel(0.8, 0.003, 0.01, min_updates=1, report_rate=0.25)
    m.start(np.zeros((1, 3)), np.eye(3)[None])
    assert m.weight.tolist() == [0.0]  # no detection taken yet
    m.updates[:] = 1
    m.mu[:] = 0.9
    m.settle()
    assert m.weight.tolist() == [0.25]
    for _ in range(3):
        m.settle()
    assert m.weight.tolist() == [0.9]
    m.mu[:] = 0.0  # collapsed: it comes down a quarter per frame
    m.settle()
    assert np.isclose(m.weight[0], 0.65)
    blended = m.blend(np.array([0]), np.array([[4.0, 0.0, 0.0]]))
    np.testing.assert_allclose(blended, [[0.35 * 4.0, 0.0, 0.0]])
    m.add(np.ones((1, 3)), np.eye(3)[None])  # a new track: not blended before min_updates
    m.keep(np.array([False, True]))
    assert m.weight.tolist() == [0.0]
