"""bench/real_motion.py ``keep_every`` (``bench_tracker.py real --keep-every K``): the camera's
motion composed over the frames dropped, the tracker's stamps, the frames scored; and the
unrounded figures of ``--json`` (``summary_figures``) with their keyed velocity rows.

Synthetic (no KITTI data): a camera driving and turning past three cars, perfect detections.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))
import real_motion as rm  # noqa: E402
from tracker_node.config import TrackerConfig  # noqa: E402
from tracker_node.offline import result_rows  # noqa: E402
from tracker_node.tracker import DetectionBatch, Tracker  # noqa: E402
from vehicle_common.bags.recorded_run import OUTPUT_STATES, RANKED_STATES  # noqa: E402
from vehicle_common.box3d import projected_bbox  # noqa: E402
from vehicle_common.camera_motion import rotation_from_vector  # noqa: E402
from vehicle_common.kitti import KittiObject, alpha_from_rotation_y  # noqa: E402

P2 = np.array([[720.0, 0.0, 620.0, 0.0], [0.0, 720.0, 187.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
OFFSET = np.array([0.06, -0.01, 0.003])  # camera 0 in the left camera's frame
N_FRAMES = 12


def _poses(n: int = N_FRAMES, seed: int = 0):
    """Left-camera poses (``X_first = R X_k + t``): driving forward ~8 m/s while turning and
    pitching a little, with some noise."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        rv = np.array([0.004, 0.03, -0.002]) * k + rng.normal(scale=0.003, size=3)
        t = np.array([0.1 * k, 0.02 * k, 0.8 * k]) + rng.normal(scale=0.02, size=3)
        out.append((rotation_from_vector(rv), t))
    return out


def _sequence() -> rm.SequenceData:
    """Three cars (two moving in the world, one parked), seen by the camera of :func:`_poses`,
    each detected exactly at its labelled centre in every frame."""
    poses = _poses()
    starts = [np.array([-4.0, 1.7, 15.0]), np.array([3.5, 1.7, 25.0]), np.array([-2.0, 1.7, 35.0])]
    vel = [np.array([0.0, 0.0, 10.0]), np.array([0.5, 0.0, 6.0]), np.zeros(3)]  # m/s, world
    dims = (1.5, 1.6, 3.9)
    gt, frames, ids, raw = {}, [], [], {}
    for k, (R, t) in enumerate(poses):
        objs, pos = [], []
        for i, (x0, v) in enumerate(zip(starts, vel, strict=True)):
            xw = x0 + v * k * rm.FRAME_PERIOD  # bottom centre, first left camera's frame
            loc = R.T @ (xw - t) - OFFSET  # camera 0, frame k
            box = projected_bbox(P2, dims, loc, -np.pi / 2, (1242, 375))
            o = KittiObject(
                type="Car",
                alpha=alpha_from_rotation_y(-np.pi / 2, loc[0], loc[2]),
                bbox=box,
                dimensions=dims,
                location=tuple(float(c) for c in loc),
                rotation_y=-np.pi / 2,
                frame=k,
                track_id=i,
            )
            objs.append(o)
            pos.append(o.centre_of_mass)
        gt[k] = objs
        batch = DetectionBatch.create(
            np.array(pos),
            covariance=np.tile(np.diag([0.05, 0.05, 0.3]), (len(pos), 1, 1)),
            bbox=np.array([o.bbox for o in objs]),
            score=np.full(len(pos), 0.9),
        )
        frames.append(batch)
        ids.append(np.arange(len(objs)))
        raw[k] = rm._to_objects(batch, k)
    data = rm.SequenceData("synthetic", gt, P2, frames, ids, raw, [])
    # each car's velocity over the ground in frame k's camera axes
    ground = {(k, i): R.T @ v for k, (R, _) in enumerate(poses) for i, v in enumerate(vel)}
    return replace(data, motions=rm.camera_motions(poses, OFFSET), ground_velocity=ground)


def test_composed_motion_is_the_direct_pose_difference():
    poses = _poses()
    motions = rm.camera_motions(poses, OFFSET)
    rng = np.random.default_rng(1)
    for K in (2, 3):
        for k in range(K, N_FRAMES):
            got = rm.compose_motions(motions[k - K + 1 : k + 1])
            direct = rm.camera_motions([poses[k - K], poses[k]], OFFSET)[1]
            np.testing.assert_allclose(got.rotation, direct.rotation, atol=1e-12)
            np.testing.assert_allclose(got.translation, direct.translation, atol=1e-12)
            assert got.dt == pytest.approx(K * rm.FRAME_PERIOD)
            # and it takes a static point's camera-0 coordinates at k - K to those at k
            (Ra, ta), (Rb, tb) = poses[k - K], poses[k]
            xw = rng.normal(size=3) * 10
            xa, xb = Ra.T @ (xw - ta) - OFFSET, Rb.T @ (xw - tb) - OFFSET
            np.testing.assert_allclose(got.rotation @ xa + got.translation, xb, atol=1e-9)
    assert rm.compose_motions(motions[3:4]) is motions[3]  # one frame: the motion itself
    assert rm.compose_motions(motions[0:2]) is None  # frame 0's motion is unknown


class _Recorder(Tracker):
    calls: list = []

    def step(self, batch, stamp, motion=None):
        _Recorder.calls.append((stamp, motion))
        return super().step(batch, stamp, motion)


def test_keep_every_1_is_the_every_frame_path_and_k_steps_on_kept_frames(monkeypatch):
    data = _sequence()
    cfg = TrackerConfig()
    # today's path, written out: every frame, stamp k x period, that frame's motion
    trk = Tracker(cfg, projection=data.P2)
    ref_ranked, ref_out = {}, {}
    for k, batch in enumerate(data.frames):
        ts = trk.step(batch, k * rm.FRAME_PERIOD, data.motions[k])
        ref_ranked[k] = result_rows(ts, k, np.zeros(3), RANKED_STATES, mean_hwl=rm.MEAN_HWL)
        ref_out[k] = result_rows(ts, k, np.zeros(3), OUTPUT_STATES, mean_hwl=rm.MEAN_HWL)
    ranked, out = rm.run_tracker(data, cfg, None)
    assert ranked == ref_ranked and out == ref_out
    assert any(out.values())  # the cars are tracked: the comparison is not of empty outputs

    monkeypatch.setattr(rm, "Tracker", _Recorder)
    poses = _poses()
    for K in (1, 2, 3):
        _Recorder.calls = []
        ranked, out = rm.run_tracker(replace(data, keep_every=K), cfg, None)
        kept = list(range(0, N_FRAMES, K))
        assert sorted(out) == kept and sorted(ranked) == kept
        stamps = [s for s, _ in _Recorder.calls]
        np.testing.assert_allclose(stamps, [k * rm.FRAME_PERIOD for k in kept])
        assert _Recorder.calls[0][1] is None
        for k, (_, m) in zip(kept[1:], _Recorder.calls[1:], strict=True):
            if K == 1:
                assert m is data.motions[k]
            direct = rm.camera_motions([poses[k - K], poses[k]], OFFSET)[1]
            np.testing.assert_allclose(m.rotation, direct.rotation, atol=1e-12)
            np.testing.assert_allclose(m.translation, direct.translation, atol=1e-12)
            assert m.dt == pytest.approx(K * rm.FRAME_PERIOD)


def test_figures_are_scored_on_the_kept_frames_only():
    data = _sequence()
    cfg = TrackerConfig()
    for K in (1, 2, 3):
        kept = range(0, N_FRAMES, K)
        _, stats, _ = rm.evaluate_split([replace(data, keep_every=K)], cfg, ["kalman"])
        st = stats["kalman"]
        assert st.frames == len(kept)
        n_labels = sum(len(data.gt[k]) for k in kept)
        a = st.mot["all_rows"]
        assert a["tp"] + a["fn"] == n_labels  # the dropped frames' labels are not scored
        assert a["tp"] > 0
        # matched rows of the velocity statistics come from kept frames only
        assert 0 < len(st.pos_err) <= n_labels


def test_summary_figures_key_every_velocity_row_once():
    """``--json``'s figures: the velocity RMSE over the ground is that of the keyed rows (what a
    like-for-like comparison of two runs recomputes on the rows both matched), one row per
    (sequence, frame, labelled car)."""
    data = _sequence()
    for K in (1, 2):
        _, stats, _ = rm.evaluate_split([replace(data, keep_every=K)], TrackerConfig(), ["kalman"])
        fig = rm.summary_figures(stats["kalman"])
        rows = fig["velocity_rows_keyed"]
        assert len(rows) == fig["velocity_rows"] > 0
        keys = {(r[0], r[1], r[2]) for r in rows}
        assert len(keys) == len(rows)
        assert {r[1] for r in rows} <= set(range(0, N_FRAMES, K))  # kept frames only
        rmse = float(np.sqrt(np.mean(np.square([r[4] for r in rows]))))
        assert rmse == pytest.approx(fig["velocity_rmse_ground"], abs=1e-4)
        assert sum(r[3] for r in rows) == fig["accel_rows"]
        # constant speeds over the ground: none accelerates, though the camera turns
        assert fig["accel_rows"] == 0
        assert 0 < fig["mota_all_rows"] <= 100 and fig["idsw"] >= 0
        # parked (< 1 m/s) and moving (> 3 m/s) rows by the car's true speed over the ground
        st = stats["kalman"]
        ge, gs = np.array(st.ground_err), np.array(st.ground_speed)
        moving = gs > 3.0
        assert moving.any() and not moving.all()
        assert fig["velocity_rmse_moving"] == pytest.approx(np.sqrt(np.mean(ge[moving] ** 2)))


def test_a_keep_every_below_1_is_one_line_and_a_non_zero_exit():
    import subprocess

    run = subprocess.run(
        [sys.executable, str(REPO / "bench" / "bench_tracker.py"), "real", "--keep-every", "0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode != 0
    assert run.stderr.strip() == "error: --keep-every: 0 is not a positive integer"


def test_breakdown_partitions_the_velocity_rows_and_the_jitter_triplets():
    """``bench_tracker.py real --breakdown``: the age x depth groups and the speed classes
    each cover every velocity row and every jitter triplet once; "every row" gives the
    summary's velocity RMSE and jitter ratio."""
    data = _sequence()
    _, stats, _ = rm.evaluate_split([data], TrackerConfig(), ["kalman"])
    st = stats["kalman"]
    fig = rm.summary_figures(st)
    b = rm.breakdown(st)
    for key, whole in (("velocity", fig["velocity_rmse_ground"]), ("jitter", fig["jitter_ratio"])):
        rows = {name: (share, val, sq) for name, share, val, sq in b[key]}
        assert rows["every row"][0] == pytest.approx(1.0)
        assert rows["every row"][1] == pytest.approx(whole)
        by_age = [r for n, r in rows.items() if "first" in n or "older" in n]
        by_speed = [r for n, r in rows.items() if n.startswith("cars ")]
        for part in (by_age, by_speed):
            assert sum(r[0] for r in part) == pytest.approx(1.0)
            assert sum(r[2] for r in part) == pytest.approx(1.0)
    # the triplets are matched_jitter's, with the track's age known for each
    assert len(st.jitter_rows) == st.jitter[2] > 0
    assert all(r[1] >= 0 for r in st.jitter_rows)
    keyed = fig["velocity_rows_keyed"]
    assert all(len(r) == 8 and r[6] >= 0 for r in keyed)


def test_second_differences_over_the_ground_take_the_camera_motion_out():
    """``--breakdown``'s jitter over the ground: cars at constant velocity over the ground seen
    from a turning, pitching camera, detected exactly. Carried into the middle frame by the camera
    motion, the labels' second differences nearly vanish (what is left is the labelled centre's
    height offset turning with the camera: millimetres), where those in the camera frame hold the
    camera's turn; the tracks' are taken the same way; with kept frames too; none without the
    camera's motion."""
    data = _sequence()
    for K in (1, 2):
        _, stats, _ = rm.evaluate_split([replace(data, keep_every=K)], TrackerConfig(), ["kalman"])
        st = stats["kalman"]
        assert len(st.jitter_ground) == len(st.jitter_rows) > 0
        speed, tracks, labels = np.array(st.jitter_ground, float).T
        camera = np.array(st.jitter_rows, float)[:, 4]
        assert np.isfinite(tracks).all() and np.isfinite(labels).all()
        assert labels.max() < 0.02
        assert np.sqrt(np.mean(camera**2)) > 10 * np.sqrt(np.mean(labels**2))
        np.testing.assert_array_equal(speed, np.array(st.jitter_rows, float)[:, 0])
        b = rm.breakdown(st)
        assert [row[0] for row in b["jitter_ground"]] == ["parked < 1 m/s", "moving > 3 m/s"]
        shares = [share for _, share in b["jitter_tail"]]
        assert shares == sorted(shares) and 0 < shares[0] <= shares[-1] <= 1
    _, stats, _ = rm.evaluate_split([data], TrackerConfig(), ["kalman"], use_camera_motion=False)
    assert stats["kalman"].jitter_ground == [] and stats["kalman"].jitter_rows


def test_ground_second_difference_of_one_triplet_written_out():
    data = _sequence()
    gt = data.gt
    out = {k: [replace(o, track_id=10 + o.track_id) for o in objs] for k, objs in gt.items()}
    m = data.motions
    got = rm.ground_second_differences(gt, out, [(5, 12, 2, None, 0.0, 0.0)], m)
    a, b, c = (np.asarray(gt[k][2].centre_of_mass) for k in (4, 5, 6))
    want = m[6].rotation.T @ (c - m[6].translation) - 2 * b + m[5].rotation @ a + m[5].translation
    assert got == [(pytest.approx(np.linalg.norm(want[[0, 2]])),) * 2]
    # an unknown motion (the first frame's) gives NaN
    got = rm.ground_second_differences(gt, out, [(0, 12, 2, None, 0.0, 0.0)], m)
    assert all(np.isnan(x) for x in got[0])
