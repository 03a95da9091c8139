"""A frame's work that needs no boxes begun while the detector runs (issue #39: the stereo node's
early start, stereo_depth_node.early_start and StereoPipeline.begin): the same outputs, to the
bit, as the frame path without it; only frames the detector announced are worked on; and a
frame worked on ahead but never used does not become the odometry's reference."""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
import pytest
from stereo_depth_node.early_start import EarlyStart
from stereo_depth_node.intake import FrameIntake
from stereo_depth_node.parameters import stereo_config_from_values
from stereo_depth_node.pipeline import FrameBoxes, StereoPipeline
from test_stereo_road_map import P_LEFT, P_RIGHT, H, road_pair
from vehicle_common.frame_accounting import FrameCounter
from vehicle_common.input_usage import InputUsage
from vehicle_common.kitti import TrackingSequence

from stereo_depth_node import offline


def _outputs(result) -> list:
    """Every output of one frame, to the bit: kept detections and the camera motion."""
    out = []
    for i, r, c, score in result.kept:
        out.append((i, r.position.tobytes(), r.covariance.tobytes(), r.disparity, score))
        out.append((c.plausibility, c.measures.height, c.measures.bottom_height))
    m = result.motion
    out.append(None if m is None else (m.rotation.tobytes(), m.translation.tobytes(), m.dt))
    return out


def _frame_path(frames, early: str, executor=None) -> list:
    """``frames``: (stamp, left, right, boxes, projections, used). ``early``: "none" (the
    path without early work), "ahead" (:meth:`begin` just before each frame, as the node does
    while the CNN runs) or "stale" (each frame's early work begun before the previous frame
    was processed: against the reference before, so its odometry must be done again). A frame
    not ``used`` gets its early work only (a frame the stereo node never got boxes for)."""
    pipe = StereoPipeline.from_config(stereo_config_from_values({}), executor=executor)
    out, next_ahead = [], None
    for k, (stamp, left, right, boxes, projections, used) in enumerate(frames):
        if pipe.settings is None:
            pipe.camera_from_projections(left, *projections)
        geometry, settings = pipe.camera()
        params = pipe.disparity_params_for(left.shape[0], settings)
        ahead = None
        if early == "ahead":
            ahead = pipe.begin(stamp, left, right)
        elif early == "stale":
            ahead, after = next_ahead, frames[k + 1] if k + 1 < len(frames) else None
            next_ahead = pipe.begin(*after[:3]) if after is not None else None
        if not used:
            continue
        r = pipe.process(stamp, left, right, geometry, params, boxes, early=ahead)
        out.append(_outputs(r))
        pipe.frame_done(boxes.boxes)
    return out


def _road_frames(n: int = 3, skipped: tuple = ()) -> list:
    left, right = road_pair()
    boxes = FrameBoxes([(500.0, 150.0, 600.0, 200.0)], [0], [np.nan], [-1.0], [0.9], ["0"])
    return [
        (i * 100_000_000, left, right, boxes, (P_LEFT, P_RIGHT), i not in skipped) for i in range(n)
    ]


def test_early_work_gives_the_same_outputs_on_a_synthetic_road():
    frames = _road_frames(4)
    plain = _frame_path(frames, "none")
    assert len(plain) == 4 and plain[1][-1] is not None  # motions from the second frame
    assert _frame_path(frames, "ahead") == plain
    with ThreadPoolExecutor(1) as pool:
        assert _frame_path(frames, "ahead", pool) == plain


def test_early_work_of_a_frame_never_used_is_not_the_odometrys_reference():
    """Frame 1 is worked on ahead but its 2D array never comes: frame 2's motion spans the
    0.2 s from frame 0, the previous frame the tracker got."""
    out = _frame_path(_road_frames(3, skipped=(1,)), "ahead")
    assert len(out) == 2 and out[1][-1][2] == pytest.approx(0.2)
    assert out == _frame_path(_road_frames(3, skipped=(1,)), "none")


def test_begin_waits_for_the_first_frame_and_a_camera_change():
    pipe = StereoPipeline.from_config(stereo_config_from_values({}))
    left, right = road_pair()
    assert pipe.begin(1, left, right) is None  # no camera yet
    pipe.camera_from_projections(left, P_LEFT, P_RIGHT)
    assert pipe.begin(1, left, right) is None  # the match band not settled by a frame yet
    geometry, settings = pipe.camera()
    pipe.disparity_params_for(H, settings)
    assert pipe.begin(1, left, right) is not None
    pipe._camera_generation += 1  # a new CameraInfo, not yet taken by a frame
    assert pipe.begin(2, left, right) is None
    band = StereoPipeline.from_config(stereo_config_from_values({"map_area": "band"}))
    band.camera_from_projections(left, P_LEFT, P_RIGHT)
    band.disparity_params_for(H, band.camera()[1])
    assert band.begin(1, left, right) is None  # the band's map needs no early start


def test_real_0005_outputs_are_bit_identical_with_early_work(kitti_tracking_root):
    """0005's 16 stereo frames with the labels' boxes: the same 3D detections, checks and
    camera motions, to the bit, with each frame's work begun ahead, and with stale work (made
    against the previous reference: its odometry done again)."""
    seq = TrackingSequence.open(kitti_tracking_root, "0005")
    projections = (seq.calib.P2, seq.calib.P3)
    frames = []
    for f in seq.frame_ids:
        left, right = seq.read_stereo(f)
        boxes = offline.oracle_boxes(seq, f, ("Car", "Van"))
        frames.append((f * offline.FRAME_NS, left, right, boxes, projections, True))
    plain = _frame_path(frames, "none")
    assert sum(len(x) for x in plain) >= 80 + 16
    with ThreadPoolExecutor(1) as pool:
        assert _frame_path(frames, "ahead", pool) == plain
    assert _frame_path(frames, "stale") == plain


class _Pool:
    """An executor that runs nothing until told: its jobs' futures stay pending."""

    def __init__(self):
        self.jobs: list[tuple[Future, tuple]] = []

    def submit(self, fn, *args):
        future: Future = Future()
        self.jobs.append((future, args))
        return future

    def run(self, i: int) -> Future:
        future, args = self.jobs[i]
        assert future.set_running_or_notify_cancel()
        future.set_result(args)
        return future


def _early(pairs: dict) -> tuple[EarlyStart, _Pool]:
    pool = _Pool()
    return EarlyStart(pool, lambda *a: a, pairs.get), pool


def test_work_starts_when_both_the_announcement_and_the_images_are_here():
    pairs = {}
    early, pool = _early(pairs)
    early.announce(5)
    assert pool.jobs == []  # no images yet
    pairs[5] = ("L5", "R5")
    early.pair_ready(5)
    assert [a for _, a in pool.jobs] == [(5, "L5", "R5")]
    early.pair_ready(5)  # told twice: started once
    pairs[6] = ("L6", "R6")
    early.pair_ready(6)  # not announced (the detector skipped it): nothing
    assert len(pool.jobs) == 1
    pool.run(0)
    assert early.take(5).result() == (5, "L5", "R5")
    assert early.take(5) is None  # taken once


def test_images_first_then_the_announcement_and_a_camera_restarted():
    early, pool = _early({7: ("L7", "R7"), 1: ("L1", "R1")})
    early.announce(7)
    early.announce(7)  # a repeat: nothing more
    assert [a[0] for _, a in pool.jobs] == [7]
    pool.run(0)
    early.announce(1)  # time went back (a restarted camera or bag): its frames go on
    assert [a[0] for _, a in pool.jobs] == [7, 1]
    assert early.take(1) is None  # not run yet: cancelled, the worker does it all


def test_a_newer_frame_cancels_work_not_started_and_take_keeps_newer_work():
    early, pool = _early({1: ("L", "R"), 2: ("L", "R")})
    early.announce(1)
    early.announce(2)
    assert pool.jobs[0][0].cancelled() and early.cancelled == 1
    pool.run(1)
    assert early.take(1) is None  # frame 1's own work was cancelled; frame 2's is kept
    assert early.take(2).result()[0] == 2


def test_take_cancels_work_still_queued_so_the_worker_does_it_itself():
    early, pool = _early({3: ("L", "R")})
    early.announce(3)
    assert early.take(3) is None and pool.jobs[0][0].cancelled()


def test_intake_tells_when_a_frame_has_both_images_and_waits_for_its_boxes():
    told, submitted = [], []
    intake = FrameIntake(
        5, 0.0, FrameCounter(), InputUsage(), submitted.append, print, on_pair=told.append
    )
    intake.add("left", 10, "L")
    assert told == [] and intake.pair_of(10) is None
    intake.add_right(10, "R")
    assert told == [10] and intake.pair_of(10) == ("L", "R")
    intake.add("detections", 10, "D")
    assert submitted == [("L", "R", "D")] and intake.pair_of(10) is None
    intake.add("detections", 20, "D20")  # boxes first: told when the pair completes
    intake.add("left", 20, "L20")
    assert told == [10]
    intake.add_right(20, "R20")
    assert told == [10] and submitted[-1] == ("L20", "R20", "D20")


def _node_run(ctx, announce: bool) -> list:
    """Frames 1-3 through the node (:class:`test_stereo_node.Harness`), with ``early_start``
    and frames 2 and 3 announced as the detector does (frame 1 settles the match band) when
    ``announce``: each 3D array's camera motion span and detections' positions."""
    from std_msgs.msg import Header
    from test_stereo_node import Harness

    # no disparity image: it needs the whole band's map, and then nothing is begun ahead
    h = Harness(
        ctx,
        sync_cache_size=3,
        plausibility_action="flag",
        publish_disparity=False,
        early_start=announce,
    )
    started = h.io.create_publisher(Header, "/vehicles/detections_2d/started", 5)
    h.spin_until(lambda: started.get_subscription_count() > 0)
    try:
        for sec in (1, 2, 3):
            h.send_frame(sec)
            if announce and sec > 1:
                started.publish(h.header(sec))
                assert h.spin_until(lambda s=sec: h.node.early.started == s - 1)
                assert h.spin_until(h.node.early._job[1].done)
            h.send_detections(sec, [(150, 30, 250, 90)])
            assert h.spin_until(lambda s=sec: len(h.det3d) == s)
        assert h.node.early.cancelled == 0
        return [
            (a.camera_motion_dt, [(d.position.x, d.position.z) for d in a.detections])
            for a in h.det3d
        ]
    finally:
        h.close()


def test_the_node_begins_an_announced_frame_in_its_helper_thread(rclpy_context, monkeypatch):
    """The node given the detector's announcement of frames 2 and 3 maps their scenes in its
    helper thread before their 2D arrays arrive, and publishes what it publishes without the
    announcements."""
    import threading

    from stereo_depth_node import pipeline as pipeline_module

    threads = []
    real = pipeline_module.block_matching_maps

    def traced(*args, **kwargs):
        threads.append(threading.current_thread().name)
        return real(*args, **kwargs)

    monkeypatch.setattr(pipeline_module, "block_matching_maps", traced)
    announced = _node_run(rclpy_context, True)
    assert threads == ["stereo", "stereo-helper_0", "stereo-helper_0"]
    assert announced == _node_run(rclpy_context, False)
    assert threads[3:] == ["stereo"] * 3
    assert announced[1][0] == pytest.approx(1.0) and len(announced[2][1]) == 1


def test_the_early_start_is_off_when_the_node_may_use_one_cpu(rclpy_context, monkeypatch):
    """On one CPU the early work would take it from the CNN (measured: one-core lockstep
    capacity 6.2 -> 5.4 frames/s, docs/stereo_depth.md section 17): asked for, it stays off."""
    from rclpy.parameter import Parameter
    from stereo_depth_node.node import StereoDepthNode

    from stereo_depth_node import node as node_module

    for cpus, expected in (({0}, False), ({0, 1}, True)):
        monkeypatch.setattr(node_module, "available_cpus", lambda c=cpus: frozenset(c))
        node = StereoDepthNode(
            context=rclpy_context, parameter_overrides=[Parameter("early_start", value=True)]
        )
        try:
            assert node.early_start is expected
        finally:
            node.destroy_node()
