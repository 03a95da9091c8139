"""bench/bench_graph.py: a bad -p override is one line and exit 2, before any node starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_a_wrong_node_name_in_an_override_is_one_line_and_exit_2():
    run = subprocess.run(
        [sys.executable, str(REPO / "bench" / "bench_graph.py"), "--no-offline", "--no-cpu"]
        + ["--windows", "1", "-p", "detector.score_threshold:=0.5"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert lines[-1].startswith("error: bad parameter override 'detector.score_threshold:=0.5'")
    assert "did you mean vehicle_detector?" in lines[-1]
    assert "Traceback" not in run.stderr and "[bench]" not in run.stderr


def _run(published, tracked, fps, per_published_ms, per_tracked_ms):
    """Figures of a run whose processes cost exactly these CPU ms per published frame and per
    tracked frame (``{process: {thread: ms}}``; the player's are its whole process)."""
    cpu, threads = {}, {}
    for proc in set(per_published_ms) | set(per_tracked_ms):
        ts = {}
        for t in set(per_published_ms.get(proc, {})) | set(per_tracked_ms.get(proc, {})):
            a = per_published_ms.get(proc, {}).get(t, 0.0)
            b = per_tracked_ms.get(proc, {}).get(t, 0.0)
            ts[t] = (published * a + tracked * b) / 1e3
        threads[proc], cpu[proc] = ts, sum(ts.values())
    return {
        "published": published,
        "tracked": tracked,
        "throughput_fps": fps,
        "cpu_s": cpu,
        "thread_cpu_s": threads,
    }


def test_camera_budget_tells_every_frames_cost_from_a_tracked_frames():
    from tracking_bringup.process_cpu import camera_budget

    # the camera 10 ms per published frame; the detector's and stereo node's executors 3 and
    # 4 ms per published frame (+ 1 and 2 ms per tracked one); their workers 80 and 100 ms
    every = {"player": {"main": 10.0}, "det": {"main": 3.0}, "stereo": {"main": 4.0}}
    tracked = {"det": {"main": 1.0, "worker": 80.0}, "stereo": {"main": 2.0, "worker": 100.0}}
    lockstep = _run(100, 100, 5.0, every, tracked)  # 200 ms a frame: one CPU's 5 frames/s
    camera = _run(100, 40, None, every, tracked)
    b = camera_budget(lockstep, camera, 10.0, "player")
    assert abs(b["camera_ms"] - 10.0) < 1e-9 and abs(b["receipt_ms"] - 7.0) < 1e-9
    assert abs(b["tracked_ms"] - 183.0) < 1e-9
    assert abs(b["share"] - 0.17) < 1e-9  # 10 Hz x 17 ms
    # one CPU: (1 - 0.17) s of each second for 183 ms frames = 4.54 frames/s over lockstep's 5
    assert abs(b["one_cpu_frames"] - 0.83 / 0.183 / 5.0) < 1e-9
    assert abs(b["one_cpu_latency"] - 1 / 0.83) < 1e-9
    # a camera run that skipped almost nothing cannot tell the two apart
    assert camera_budget(lockstep, _run(100, 95, None, every, tracked), 10.0, "player") is None
    # nor runs too short for the CPU clocks' 10 ms ticks
    short = _run(20, 20, 5.0, every, tracked), _run(20, 8, None, every, tracked)
    assert camera_budget(*short, 10.0, "player") is None
    # nor one without the camera's figures
    assert camera_budget(lockstep, {**camera, "cpu_s": {}}, 10.0, "player") is None


def test_overload_capacity_is_the_mean_of_the_lockstep_runs_before_and_after():
    """The machine's speed drifts between runs: the capacity of ``--overload`` brackets the
    camera runs with a lockstep run before and one after, and each ratio is also given against
    either alone."""
    sys.path.insert(0, str(REPO / "bench"))
    import bench_graph as bg

    every = {"player": {"main": 10.0}, "det": {"main": 3.0}}
    tracked = {"det": {"main": 1.0, "worker": 80.0}}

    def with_latency(run, ms):
        return {**run, "latency_ms": {"mean": ms}}

    before = with_latency(_run(100, 100, 12.0, every, tracked), 80.0)
    after = with_latency(_run(100, 100, 8.0, every, tracked), 120.0)
    camera = {**with_latency(_run(100, 45, None, every, tracked), 110.0), "camera_hz": 20.0}
    rows = [("x", "lockstep 1", before), ("x", "camera 2x", camera)]
    one = bg.summarise(rows, {}, [], 10.0, {})["x"]["overload"]["camera 2x"]
    assert one["capacity"] == 60.0 and one["latency_ratio"] == 110.0 / 80.0
    assert "against" not in one
    rows.append(("x", bg.LOCKSTEP_AFTER, after))
    both = bg.summarise(rows, {}, [], 10.0, {})["x"]["overload"]["camera 2x"]
    assert both["lockstep_fps"] == 10.0 and both["capacity"] == 50.0  # 100 x 10 / 20
    assert both["frames_ratio"] == 45 / 50.0 and both["latency_ratio"] == 110.0 / 100.0
    assert both["against"]["before"]["frames_ratio"] == 45 / 60.0
    assert both["against"]["after"]["frames_ratio"] == 45 / 40.0
    line = bg.summary_lines({"x": {"overload": {"camera 2x": both}}})[1]
    assert "0.90x capacity" in line and "before / after alone: 0.75x / 1.12x" in line
