"""Frame accounting and the latest-frame policy (pure core), node reports and edge readiness."""

import threading
import time

import pytest
from vehicle_common.frame_accounting import FrameCounter, FrameCounts, LatestFrameWorker
from vehicle_common.graph_readiness import (
    NodeReport,
    format_topic_counts,
    graph_quiescent,
    parse_topic_counts,
    unready_topics,
)


def test_counter_pending_and_summary():
    c = FrameCounter()
    c.received(5)
    c.published(3)
    c.dropped()
    snap = c.snapshot()
    assert snap == FrameCounts(5, 3, 1)
    assert snap.pending == 1
    assert snap.summary() == "frames in 5, out 3, dropped 1"


def test_slow_worker_processes_the_newest_frame_and_counts_the_skipped():
    """A camera faster than the node: the queue never grows, the newest frame is processed and
    every skipped frame is counted (in = out + dropped once drained)."""
    counter = FrameCounter()
    done, skipped = [], []
    gate = threading.Event()

    def process(frame):
        gate.wait(5)  # the first frame blocks until the test has submitted the rest
        done.append(frame)

    worker = LatestFrameWorker(process, counter, skip=skipped.append)
    for frame in range(6):
        counter.received()
        worker.submit(frame)
        time.sleep(0.01)  # frame 0 is taken before the next ones arrive
    assert worker.busy
    gate.set()
    assert worker.wait_idle(5)
    worker.stop()
    assert done == [0, 5]  # the one in hand, then the newest
    assert skipped == [1, 2, 3, 4]
    counter.published(len(done))
    snap = counter.snapshot()
    assert snap.dropped == 4 and snap.pending == 0


def test_other_items_are_never_skipped_and_keep_their_order():
    order = []
    gate = threading.Event()

    def process(item):
        gate.wait(5)
        order.append(item)

    worker = LatestFrameWorker(process, skip=lambda item: order.append(("skip", item)))
    worker.submit("f0")
    time.sleep(0.02)
    worker.submit("d0", frame=False)
    worker.submit("f1")
    worker.submit("d1", frame=False)
    worker.submit("f2")
    gate.set()
    worker.stop()
    assert order == ["f0", "d0", ("skip", "f1"), "d1", "f2"]


def test_stop_drains_what_is_waiting_and_errors_do_not_kill_the_worker():
    errors, done = [], []

    def process(item):
        if item == "bad":
            raise ValueError("broken frame")
        done.append(item)

    worker = LatestFrameWorker(process, on_error=lambda exc, item: errors.append((str(exc), item)))
    worker.submit("bad", frame=False)
    worker.submit("a", frame=False)
    worker.submit("b")
    assert worker.stop(5)
    assert errors == [("broken frame", "bad")]
    assert done == ["a", "b"]
    assert not worker.busy


def test_report_round_trip_and_idle():
    report = NodeReport("stereo_depth", FrameCounts(4, 3, 0), False, {"/vehicles/detections_3d": 2})
    back = NodeReport.from_values("/stereo_depth", report.values())
    assert back == report
    assert not back.idle  # one frame received, not out yet
    assert NodeReport("x", FrameCounts(4, 3, 1)).idle
    assert not NodeReport("x", FrameCounts(4, 3, 1), busy=True).idle
    assert graph_quiescent([NodeReport("a"), NodeReport("b", FrameCounts(2, 2, 0))])
    with pytest.raises(ValueError, match="report of n"):
        NodeReport.from_values("n", [("frames_in", "x")])


def test_every_edge_is_checked_not_only_the_callers():
    expected = parse_topic_counts("/image:2,/detections_3d:2,/tracks:3")
    own = {"/image": 2}
    stereo = NodeReport("stereo", matched={"/detections_3d": 2})
    tracker = NodeReport("tracker", matched={"/tracks": 2})
    assert unready_topics(expected, own, [stereo, tracker]) == ["/tracks (2/3)"]
    # a topic nobody reported yet counts as unmatched
    assert unready_topics(expected, own, [stereo]) == ["/tracks (0/3)"]
    tracker = NodeReport("tracker", matched={"/tracks": 3})
    assert unready_topics(expected, own, [stereo, tracker]) == []
    # the caller's own count is authoritative for its own topics
    assert unready_topics({"/image": 2}, {"/image": 1}, [NodeReport("x", matched={"/image": 5})])


def test_topic_counts_parse_and_format():
    assert parse_topic_counts(" /a:2, /b/c:10 ,") == {"/a": 2, "/b/c": 10}
    assert format_topic_counts({"/a": 2, "/b": 0}) == "/a:2"
    with pytest.raises(ValueError, match="'/a'"):
        parse_topic_counts("/a")


def test_max_waiting_keeps_that_many_newest_frames():
    """Lockstep with K frames in flight: K frames may wait, none is skipped; one more is."""
    gate = threading.Event()
    done, skipped = [], []

    def process(frame):
        gate.wait(5)
        done.append(frame)

    worker = LatestFrameWorker(process, skip=skipped.append, max_waiting=2)
    worker.submit(0)
    time.sleep(0.02)
    worker.submit(1)
    worker.submit(2)  # two waiting: kept
    gate.set()
    worker.wait_idle(5)
    assert done == [0, 1, 2] and skipped == []
    gate.clear()
    worker.submit(3)
    time.sleep(0.02)
    for frame in (4, 5, 6):  # three waiting: the oldest is skipped
        worker.submit(frame)
    gate.set()
    worker.stop()
    assert done == [0, 1, 2, 3, 5, 6] and skipped == [4]
    with pytest.raises(ValueError, match="max_waiting"):
        LatestFrameWorker(process, max_waiting=0)


def test_worker_times_the_frames_it_processes_wall_and_cpu():
    """The worker books each processed frame's wall and thread-CPU time on the counter (not the
    skipped frames, not the other items); the report carries the medians."""
    counter = FrameCounter()
    assert counter.processing_ms() is None

    def process(item):
        if item == "sleep":
            time.sleep(0.03)  # waits: wall time, no CPU
        elif item == "spin":
            t = time.thread_time()
            while time.thread_time() - t < 0.03:  # computes: wall and CPU
                pass

    worker = LatestFrameWorker(process, counter, max_waiting=10)
    for item in ("sleep", "spin", "sleep"):
        worker.submit(item)
    worker.submit("not a frame", frame=False)
    worker.stop()
    wall, cpu = counter.processing_ms()
    assert 29 <= wall < 80  # median of 30 / 30 / 30 ms (+ scheduling)
    assert cpu < 10  # median of ~0 / 30 / ~0 ms: the sleeping frames took no CPU
    report = NodeReport("detector", FrameCounts(3, 3, 0), processing_ms=(wall, cpu))
    back = NodeReport.from_values("/detector", report.values())
    assert back.processing_ms == pytest.approx((wall, cpu), abs=0.01)
    assert NodeReport.from_values("x", NodeReport("x").values()).processing_ms is None
    with pytest.raises(ValueError, match="report of x"):
        NodeReport.from_values("x", [("processing_ms_p50", "1.0")])  # the CPU figure missing
