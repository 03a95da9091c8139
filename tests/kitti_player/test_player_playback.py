"""Playback core of the KITTI player: stamps, SNR noise, drops, pacing and lockstep."""

from __future__ import annotations

import math

import numpy as np
import pytest
from kitti_player_node.playback import (
    PlaybackScheduler,
    add_snr_noise,
    frame_noise_rng,
    noise_std,
    select_frames,
    snr_enabled,
    stamp_ns,
)
from vehicle_common.frame_messages import stereo_projections

from vehicle_common import kitti


def test_stamps_are_dataset_time():
    assert stamp_ns(1.0, 0) == 1_000_000_000
    assert stamp_ns(1.0, 7) == 1_700_000_000
    # a second loop pass of a 16-frame sequence continues the time line
    assert stamp_ns(1.0, 0, loop_pass=1, frames_per_pass=16) == 2_600_000_000


def test_select_frames():
    ids = list(range(10))
    assert select_frames(ids, 3, -1) == list(range(3, 10))
    assert select_frames(ids, 2, 4) == [2, 3, 4]
    with pytest.raises(ValueError, match="no frame"):
        select_frames(ids, 12, -1)


def test_stereo_projections_follow_ros_convention():
    calib = kitti.stereo_calibration(700.0, 690.0, 600.0, 180.0, 0.54, left_offset_x=0.06)
    left, right = stereo_projections(calib)
    np.testing.assert_allclose(left[:, :3], calib.K)
    np.testing.assert_allclose(left[:, 3], 0.0)
    assert right[0, 3] == pytest.approx(-700.0 * 0.54)
    np.testing.assert_allclose(right[1:, 3], 0.0)


@pytest.mark.parametrize("snr_db", [5.0, 10.0, 20.0])
def test_snr_noise_std_ratio(snr_db):
    rng = np.random.default_rng(3)
    img = rng.integers(60, 196, size=(200, 300, 3)).astype(np.uint8)
    noisy = add_snr_noise(img, snr_db, frame_noise_rng(0, 5))
    ratio = (noisy.astype(float) - img).std() / img.std()
    # rounding to integers adds variance 1/12; negligible against std >= 3.9 here
    assert ratio == pytest.approx(10 ** (-snr_db / 20), rel=0.03)
    assert noise_std(10.0, 10.0) == pytest.approx(10.0 / math.sqrt(10))
    # seeded: the same frame gives the same noise, another frame another
    assert np.array_equal(noisy, add_snr_noise(img, snr_db, frame_noise_rng(0, 5)))
    assert not np.array_equal(noisy, add_snr_noise(img, snr_db, frame_noise_rng(0, 6)))


def test_snr_disabled_values():
    img = np.full((4, 4, 3), 100, np.uint8)
    for snr in (0.0, -3.0, math.inf):
        assert not snr_enabled(snr)
        assert add_snr_noise(img, snr, frame_noise_rng(0, 0)) is img
    assert snr_enabled(10.0)


def _run(sched, t=0.0, dt=0.01, until=100.0, ack=None):
    events = []
    while not sched.finished and t < until:
        ev = sched.poll(t)
        if ev is not None:
            events.append((t, ev))
            if ack is not None and not ev.dropped:
                ack(t, ev)
        t += dt
    return events, t


def test_drop_probability_is_seeded_and_near_expected():
    n, p = 2000, 0.25
    counts = []
    for seed in (0, 1):
        sched = PlaybackScheduler(list(range(n)), 1.0, 0.0, drop_probability=p, seed=seed)
        events, _ = _run(sched)
        assert len(events) == n
        counts.append(sum(ev.dropped for _, ev in events))
        assert sched.stats.dropped == counts[-1] and sched.stats.published == n - counts[-1]
    sd = math.sqrt(n * p * (1 - p))
    assert all(abs(c - n * p) < 4 * sd for c in counts)
    again = PlaybackScheduler(list(range(n)), 1.0, 0.0, drop_probability=p, seed=0)
    assert sum(ev.dropped for _, ev in _run(again)[0]) == counts[0]
    assert counts[0] != counts[1]


def test_pacing_follows_period_and_stamps():
    sched = PlaybackScheduler([4, 5, 6, 7], start_time=2.0, period_s=0.1)
    events, _ = _run(sched, dt=0.001)
    times = [t for t, _ in events]
    np.testing.assert_allclose(np.diff(times), 0.1, atol=0.0015)
    assert [ev.stamp_ns for _, ev in events] == [2_400_000_000 + k * 100_000_000 for k in range(4)]


def test_lockstep_waits_for_acknowledgement_and_counts_timeouts():
    sched = PlaybackScheduler(list(range(5)), 1.0, period_s=0.1, lockstep_timeout=1.0)
    pending = []

    def ack_late(t, ev):
        pending.append((t + 0.35, ev.stamp_ns))  # a slow consumer: 0.35 s per frame

    t, events = 0.0, []
    while not sched.finished and t < 10:
        while pending and pending[0][0] <= t:
            sched.acknowledge(pending.pop(0)[1])
        ev = sched.poll(t)
        if ev is not None:
            events.append((t, ev))
            ack_late(t, ev)
        t += 0.005
    assert [ev.frame for _, ev in events] == list(range(5))
    assert np.all(np.diff([t for t, _ in events]) >= 0.35 - 1e-9)
    assert sched.stats.lockstep_timeouts == 0
    # nobody answers: every published frame times out once (the last one too)
    silent = PlaybackScheduler(list(range(3)), 1.0, period_s=0.0, lockstep_timeout=0.5)
    events, t_end = _run(silent, dt=0.01)
    assert [ev.frame for _, ev in events] == [0, 1, 2]
    assert silent.stats.lockstep_timeouts == 3
    assert t_end == pytest.approx(1.5, abs=0.03)
    # an old stamp does not release the frame
    old = PlaybackScheduler([0, 1], 1.0, period_s=0.0, lockstep_timeout=5.0)
    first = old.poll(0.0)
    assert not old.acknowledge(first.stamp_ns - 1) and old.poll(0.1) is None
    assert old.acknowledge(first.stamp_ns) and old.poll(0.2).frame == 1


def test_lockstep_does_not_wait_for_dropped_frames():
    sched = PlaybackScheduler(
        list(range(40)), 1.0, period_s=0.0, lockstep_timeout=5.0, drop_probability=0.5, seed=4
    )
    events, _ = _run(sched, ack=lambda t, ev: sched.acknowledge(ev.stamp_ns))
    assert len(events) == 40 and sched.stats.lockstep_timeouts == 0
    assert 0 < sched.stats.dropped < 40


def test_loop_continues_stamps():
    sched = PlaybackScheduler([0, 1, 2], 1.0, period_s=0.0, loop=True)
    stamps = [sched.poll(i).stamp_ns for i in range(7)]
    assert stamps == [1_000_000_000 + k * 100_000_000 for k in range(7)]
    assert not sched.finished


def test_lockstep_window_keeps_frames_in_flight():
    """A window of K lets K unacknowledged frames into the graph; an acknowledgement releases
    every frame up to its stamp; the oldest frame's timeout frees its place."""
    sched = PlaybackScheduler(
        list(range(6)), 1.0, period_s=0.0, lockstep_timeout=1.0, lockstep_window=3
    )
    first = [sched.poll(0.0) for _ in range(4)]
    assert [e.frame for e in first[:3]] == [0, 1, 2] and first[3] is None
    assert sched.in_flight == 3
    assert sched.acknowledge(first[1].stamp_ns)  # tracks of frame 1: frames 0 and 1 done
    assert sched.in_flight == 1
    assert [sched.poll(0.1).frame, sched.poll(0.1).frame, sched.poll(0.1)] == [3, 4, None]
    assert sched.poll(1.05).frame == 5  # frame 2 (published at 0.0) timed out
    assert sched.stats.lockstep_timeouts == 1
    assert not sched.finished
    assert sched.acknowledge(stamp_ns(1.0, 5))
    assert sched.finished
    with pytest.raises(ValueError, match="lockstep_window"):
        PlaybackScheduler([0], 1.0, 0.0, lockstep_timeout=1.0, lockstep_window=0)


def test_frame_prefetcher_reads_ahead_and_falls_back():
    import threading

    from kitti_player_node.playback import FramePrefetcher

    reads, threads = [], []

    def read(frame):
        if frame == 9:
            raise OSError("frame 9: unreadable")
        reads.append(frame)
        threads.append(threading.current_thread().name)
        return frame * 10

    pre = FramePrefetcher(read)
    pre.prefetch(1)
    assert pre.get(1) == 10 and threads[-1].startswith("prefetch")
    pre.prefetch(2)
    assert pre.get(3) == 30 and threads[-1] == threading.current_thread().name  # not prefetched
    pre.prefetch(9)
    with pytest.raises(OSError, match="frame 9"):
        pre.get(9)
    pre.close()
    assert sorted(reads) == [1, 2, 3]


def test_frame_prefetcher_preloads_within_budget_and_keeps_errors_at_their_frame():
    import threading

    from kitti_player_node.playback import FramePrefetcher

    reads = []

    def read(frame):
        if frame == 4:
            raise OSError("frame 4: unreadable")
        reads.append((frame, threading.current_thread().name))
        return np.full((2, 3), frame, np.uint8), np.zeros((2, 3), np.uint8)  # 12 bytes a pair

    pre = FramePrefetcher(read)
    pre.preload([0, 1, 2, 1, 3], budget_bytes=48)  # 4 distinct frames x 12 bytes: fits
    assert pre.get(2)[0][0, 0] == 2  # waits for the preload
    assert pre.preloaded and pre.preload_result() == (4, 48)
    assert all(name.startswith("prefetch") for _, name in reads) and len(reads) == 4
    pre.prefetch(3)  # held: nothing read again
    assert pre.get(3)[0][0, 0] == 3 and pre.get(0)[0][0, 0] == 0 and len(reads) == 4
    pre.close()

    reads.clear()
    small = FramePrefetcher(read)
    small.preload([0, 1, 2, 3], budget_bytes=47)  # does not fit: nothing held
    assert small.preload_result() == (0, 0) and small.get(1)[0][0, 0] == 1
    small.close()

    broken = FramePrefetcher(read)
    broken.preload([3, 4, 5], budget_bytes=10**6)  # stops at the unreadable frame
    assert broken.preload_result() == (1, 12)
    assert broken.get(3)[0][0, 0] == 3
    with pytest.raises(OSError, match="frame 4"):
        broken.get(4)
    assert broken.get(5)[0][0, 0] == 5  # read when asked for
    broken.close()


def test_frame_prefetcher_close_stops_a_running_preload():
    """Ctrl-C while a long sequence is being read into memory: close() returns after the frame in
    hand, not after the whole sequence."""
    import time

    from kitti_player_node.playback import FramePrefetcher

    def read(frame):
        time.sleep(0.05)
        return np.zeros((2, 2), np.uint8)

    pre = FramePrefetcher(read)
    pre.preload(list(range(200)), budget_bytes=10**9)  # 10 s of reading
    time.sleep(0.12)
    t0 = time.monotonic()
    pre.close()
    assert time.monotonic() - t0 < 1.0
    assert pre.preloaded and pre.preload_result()[0] < 10


def test_lockstep_answers_reveal_a_second_graph():
    """One answer per published frame: a second answer for a stamp, or one for a frame this
    player never published, is another graph's tracker on the lockstep topic."""
    from kitti_player_node.playback import LockstepAnswers

    answers = LockstepAnswers(keep=3)
    for stamp in (10, 20, 30):
        answers.published(stamp)
    assert answers.answer(10) is None and answers.answer(20) is None
    assert "a second answer for the frame stamped" in answers.answer(20)
    assert "a frame this player did not publish" in answers.answer(25)
    answers.published(40)  # 10 is forgotten; an answer older than what is kept is not judged
    assert answers.answer(5) is None
    assert answers.answer(40) is None
