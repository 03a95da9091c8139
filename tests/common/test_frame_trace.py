"""frame_trace: the nodes' per-frame trace points (VEHICLE_TRACE_DIR)."""

from __future__ import annotations

import threading
import time

from vehicle_common.frame_trace import (
    TRACE_ENV,
    FileTracer,
    frame_tracer,
    read_traces,
    span_ms,
)


def test_off_without_the_variable(tmp_path):
    trace = frame_tracer("stereo_depth", environ={})
    trace("pair_start", 1)
    assert not isinstance(trace, FileTracer)
    assert list(tmp_path.iterdir()) == []


def test_events_of_several_threads_read_back_per_frame(tmp_path):
    trace = frame_tracer("stereo_depth", environ={TRACE_ENV: str(tmp_path / "trace")})
    assert isinstance(trace, FileTracer) and trace.path.parent == tmp_path / "trace"
    trace("disparity_start", 100)
    busy = time.thread_time() + 0.01
    while time.thread_time() < busy:  # 10 ms of this thread's CPU
        pass
    trace("disparity_end", 100)

    def other():
        trace("odometry_start", 100)
        time.sleep(0.02)  # waiting, not working
        trace("odometry_end", 100)

    t = threading.Thread(target=other)
    t.start()
    t.join()
    trace("disparity_start", 200)
    trace("disparity_start", 200)  # twice: the first counts
    trace.close()
    frames = read_traces(tmp_path / "trace")
    assert sorted(frames) == [100, 200]
    assert set(frames[100]) == {
        "disparity_start",
        "disparity_end",
        "odometry_start",
        "odometry_end",
    }
    (work,) = span_ms(frames, "disparity_start", "disparity_end", cpu=True)
    assert work >= 9.0
    (wall,) = span_ms(frames, "odometry_start", "odometry_end")
    (cpu,) = span_ms(frames, "odometry_start", "odometry_end", cpu=True)
    assert wall >= 19.0 and cpu < 5.0
    # the busy loop's wall span holds its CPU time (more when another process had the core)
    (busy_wall,) = span_ms(frames, "disparity_start", "disparity_end")
    assert busy_wall >= work - 0.5
    assert span_ms(frames, "pair_start", "pair_end") == []


def test_cut_and_malformed_lines_are_skipped(tmp_path):
    (tmp_path / "detector_1.trace").write_text(
        "detect_start 5 1000000 10\ndetect_end 5 4000000 20\ndetect_start 6 70\nnoise x y z\n"
    )
    (tmp_path / "notes.txt").write_text("detect_start 7 1 1\n")  # not a trace file
    frames = read_traces(tmp_path)
    assert list(frames) == [5]
    assert span_ms(frames, "detect_start", "detect_end") == [3.0]
