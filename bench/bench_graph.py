"""The whole graph at camera rate and in lockstep: frames tracked, latency, CPU per node.

Usage: python bench/bench_graph.py [--synthetic-frames 100] [--no-real] [--windows 1,2]
       [--real-frames N] [--overload [FACTORS] | --rate-multiplier X] [--cpus LIST]
       [-p NODE.PARAM:=VALUE ...] [--json FILE] [--profile] [--compare-tree PATH [--repeat N]]

Runs the graph of the demo (player, CNN detector, stereo depth, tracker, recorder; separate
processes, the shipped parameter file) on real KITTI tracking 0005 (../shared/kitti, 16 frames)
and on a synthetic sequence (rendered once into output/bench_graph/synthetic). ``--real-frames N``
(N > 16) plays a longer real sequence made of 0005's pairs forth and back (0..15, 14..0, 1..15,
...; links to the shared images under output/bench_graph, labels renumbered), the length of a
longer real drive at the same image content: its timing figures, not its tracking accuracy (the
camera turns back at each end).

- ``realtime``: the player at 10 Hz (x ``--rate-multiplier``) without lockstep, as a camera:
  frames published, frames that reached /vehicles/tracks, latency image -> tracks (p50 / p95 /
  max: the player's /clock message of a frame, published just before its images, to the tracks
  of that stamp, both seen by a probe node in this process), the per-stage share of it (-> 2D
  detections -> 3D detections -> tracks), each node's frames in / out / dropped (its
  /diagnostics report) and CPU (% of one core, from /proc, over the playback).
- ``lockstep K``: the player as fast as the graph goes with at most K unacknowledged frames;
  throughput in frames/s (first /clock to last tracks).

Issue #33's three bars, printed for each dataset and measured in the same run:

- frames tracked at camera rate against the lockstep capacity, ``frames x min(1, lockstep
  frames/s / camera rate)`` (bar >= 0.9), and the mean latency against lockstep's (<= 1.25);
- CPU per frame: the CPU of every node process in the lockstep run (window 1) minus that of a
  4-frame lockstep run (both from the first frame's clock until the graph is idle after the
  last), over the frames between them, per process and thread (the player's PNG decoding is
  outside: it decodes the sequence before the first clock); divided by the fixed reference
  workload ``../shared/tools/cpu_reference.py``: the median of three runs, two before and one
  after (4 of 18 runs read 35-50 % slow on this machine, RESULTS 30) (bar <= 1.0);
- the tracking quality (tracks 3D AP @1.5 m, MOTA, HOTA) on the frames that got through, at
  camera rate and in lockstep.

Overload (issue #39): ``--overload 2,3`` measures each dataset's capacity C with lockstep 1, then
plays it as a camera at 2 x C and 3 x C without lockstep (runs ``camera 2x``, ``camera 3x``),
then runs lockstep 1 again (``lockstep 1 after``): the capacity and lockstep's latency are the
mean of the two lockstep runs, which bracket the camera runs in time (a shared machine's speed
drifts between runs; each ratio is also printed against either lockstep run alone). Each
camera run against that C: frames tracked against what C allows, mean latency against
lockstep's, the tracking quality on the frames tracked, and what every published frame costs
whether tracked or not (the player's CPU and the nodes' executors',
``process_cpu.camera_budget``: its share of one CPU at the camera's rate; with every node on one
CPU, the ceiling that share leaves on the frames tracked and the floor on a frame's time);
``--rate-multiplier X`` plays at 10 Hz x X, ``--cpus LIST`` runs every node on those CPUs
(``cpu_affinity``; "0": one core).
``--compare-tree PATH`` runs this bench alternately with another checkout's ``.venv`` (today's
tree) and this tree's (``--repeat`` pairs) and prints the CPU ratios new / old.

Every run also traces each frame through the nodes (``vehicle_common.frame_trace``, the
environment variable ``VEHICLE_TRACE_DIR`` set to the run's ``trace`` folder): when the player
published the images, when each node received them, started and ended each step of its work (the
CNN, the scene's block-matching map, the disparity map, the odometry, the ranging and its check)
and published; printed as a median timeline after the player's clock event, and each step's wall
/ own-thread CPU time in the graph against the same step alone (``offline_stage_times``: the
median over the sequence's frames of the same work, inputs and settings in this process).

Prints one table; ``uptime``'s load average is printed with it (the machine may be shared).
``--profile`` samples every node process with py-spy during the 10 Hz runs and prints, per
process, the functions its CPU time goes to.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import threading
import time
from pathlib import Path

os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(101, 200)))

import numpy as np  # noqa: E402
from tracking_bringup.environment import PARAMS_FILE, apply_graph_environment  # noqa: E402
from tracking_bringup.launcher import GraphLauncher, graph_processes  # noqa: E402
from tracking_bringup.process_cpu import (  # noqa: E402
    camera_budget,
    cpu_seconds,
    profile_summary,
    start_profilers,
    thread_cpu_seconds,
)
from tracking_bringup.supervision import LaunchError  # noqa: E402
from vehicle_common.frame_trace import TRACE_ENV, read_traces, span_ms  # noqa: E402

from tracking_bringup import graph  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
REAL_ROOT = REPO.parent / "shared" / "kitti" / "tracking" / "training"
OUT = REPO / "output" / "bench_graph"
PROBED = (graph.CLOCK, graph.DETECTIONS_2D, graph.DETECTIONS_3D, graph.TRACKS)


class Probe:
    """Arrival time (monotonic) of every message on the probed topics, by stamp."""

    def __init__(self):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rosgraph_msgs.msg import Clock
        from stereo_vehicle_msgs.msg import (
            TrackedVehicleArray,
            VehicleDetection2DArray,
            VehicleDetection3DArray,
        )

        self.times: dict[str, dict[int, float]] = {t: {} for t in PROBED}
        self._ctx = Context()
        rclpy.init(context=self._ctx, args=[])
        self._node = rclpy.create_node("bench_graph_probe", context=self._ctx)
        types = (Clock, VehicleDetection2DArray, VehicleDetection3DArray, TrackedVehicleArray)
        for topic, cls in zip(PROBED, types, strict=True):
            self._node.create_subscription(cls, topic, self._recorder(topic), 100)
        self._executor = SingleThreadedExecutor(context=self._ctx)
        self._executor.add_node(self._node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _recorder(self, topic):
        def on_msg(msg):
            now = time.monotonic()
            stamp = msg.clock if topic == graph.CLOCK else msg.header.stamp
            self.times[topic].setdefault(stamp.sec * 10**9 + stamp.nanosec, now)

        return on_msg

    def _spin(self):
        while not self._stop.is_set():
            self._executor.spin_once(timeout_sec=0.05)

    def close(self):
        self._stop.set()
        self._thread.join(5)
        self._executor.shutdown()
        self._node.destroy_node()
        self._ctx.try_shutdown()


def run_case(
    root: Path,
    sequence: str,
    lockstep: bool,
    window: int,
    overrides,
    logs: Path,
    profile: Path | None = None,
):
    """One run of the graph; returns its figures (with ``profile``: py-spy samples of every
    node process over the run, in that folder)."""
    probe = Probe()
    params = [
        f"kitti_player.dataset_root:={root}",
        f"kitti_player.sequence:='{sequence}'",
        f"kitti_player.lockstep:={'true' if lockstep else 'false'}",
        f"kitti_player.lockstep_window:={window}",
        f"kitti_player.rate_multiplier:={0 if lockstep else 1.0}",
        "kitti_player.exit_when_done:=true",
        f"bag_recorder.output:={logs / 'bag'}",
        *overrides,
    ]
    extra = dict.fromkeys(PROBED, 1)  # the probe's subscriptions are edges too
    processes = graph_processes(graph.PIPELINE, PARAMS_FILE, params, extra_subscriptions=extra)
    trace_dir = logs / "trace"  # every node's per-frame trace points (frame_trace)
    launcher = GraphLauncher(
        processes, logs, ready_timeout=180, env={**os.environ, TRACE_ENV: str(trace_dir)}
    )
    cpu0, cpu1, threads0, threads1 = {}, {}, {}, {}
    t_cpu0 = t_cpu1 = 0.0
    profilers: list = []
    try:
        launcher.start()
        pids = {n: r.proc.pid for n, r in launcher.running.items()}
        while not probe.times[graph.CLOCK]:  # playback starts once every edge is matched
            launcher.spin_reports(0.05)
        cpu0, t_cpu0 = {n: cpu_seconds(p) for n, p in pids.items()}, time.monotonic()
        cpu1 = dict(cpu0)
        threads0 = {n: thread_cpu_seconds(p) for n, p in pids.items()}
        threads1 = dict(threads0)
        profilers = start_profilers(pids, profile) if profile is not None else []

        def sample():  # the last reading of each process (the player exits at the end)
            for n, p in pids.items():
                c = cpu_seconds(p)
                if c == c:  # not nan
                    cpu1[n] = c
                    threads1[n] = thread_cpu_seconds(p) or threads1[n]

        player = launcher.running[graph.PLAYER.name].proc
        while player.poll() is None:
            sample()
            launcher.spin_reports(0.1)
        # the player is done; the last frames may still be in flight
        end = time.monotonic() + 10
        while time.monotonic() < end:
            sample()
            launcher.spin_reports(0.1)
            if all(r.idle for n, r in launcher.reports.items() if n != graph.PLAYER.name):
                break
        t_cpu1 = time.monotonic()
    finally:
        launcher.shutdown()
        time.sleep(0.3)
        probe.close()
        for prof in profilers:
            try:
                prof.wait(timeout=20)
            except Exception:  # noqa: BLE001 - a profiler that hangs is killed, not fatal
                prof.kill()
    figures = _figures(probe.times, launcher.reports, cpu0, cpu1, t_cpu1 - t_cpu0)
    # CPU seconds of each node process from the first frame's clock until the graph was idle
    # after the last (start-up and shutdown left out)
    figures["cpu_s"] = {n: cpu1[n] - cpu0[n] for n in cpu1}
    figures["thread_cpu_s"] = {
        n: {t: c - threads0[n].get(t, 0.0) for t, c in threads1[n].items()} for n in threads1
    }
    figures["trace"] = trace_breakdown(read_traces(trace_dir))
    return figures


# a frame's trace points, in the order they happen (vehicle_common.frame_trace; the events'
# node: player, detector, stereo_depth, tracker)
TIMELINE = (
    ("player", ("left_published", "right_published")),
    ("detector", ("image_received", "detect_start", "detect_end", "detections_published")),
    (
        "stereo",
        (
            "left_received",
            "right_received",
            "detections_received",
            "pair_start",
            "scene_start",
            "scene_end",
            "odometry_start",
            "disparity_start",
            "disparity_end",
            "pair_end",
            "ranging_start",
            "odometry_end",
            "road_start",
            "road_end",
            "ranging_end",
            "detections_3d_published",
        ),
    ),
    ("tracker", ("tracks_published",)),
)
# the steps of a frame's work in the graph, timed between two events of one thread, and the
# key of the same work alone (offline_stage_times)
STEPS = (
    ("CNN", "detect_start", "detect_end", "detect"),
    ("scene map", "scene_start", "scene_end", "scene map"),
    ("disparity map", "disparity_start", "disparity_end", "disparity ("),
    ("odometry", "odometry_start", "odometry_end", "odometry"),
    ("road map", "road_start", "road_end", "road map"),
    ("ranging + check", "ranging_start", "ranging_end", "ranging + check"),
)


_MISSING = object()


def alone_ms(alone: dict[str, float], prefix: str, default=_MISSING) -> float:
    """The time alone of the step whose label starts with ``prefix`` (the labels carry the
    thread counts: "detect (CNN, 1 thread)"); ``default`` when there is none."""
    for k, v in alone.items():
        if k.startswith(prefix):
            return v
    if default is _MISSING:
        raise KeyError(prefix)
    return default


def trace_breakdown(frames: dict) -> dict:
    """Medians over the tracked frames of the nodes' trace points: ``timeline`` (ms after the
    player's clock event, per event) and ``steps`` (wall, CPU of the thread) ms of each step
    of a frame's work in the graph."""
    frames = {s: ev for s, ev in frames.items() if "clock" in ev and "tracks_published" in ev}
    timeline = {}
    for _, events in TIMELINE:
        for e in events:
            v = span_ms(frames, "clock", e)
            if v:
                timeline[e] = float(np.median(v))
    steps = {}
    for name, a, b, _ in STEPS:
        wall, cpu = span_ms(frames, a, b), span_ms(frames, a, b, cpu=True)
        if wall:
            steps[name] = (float(np.median(wall)), float(np.median(cpu)))
    return {"frames": len(frames), "timeline": timeline, "steps": steps}


def breakdown_lines(trace: dict, alone: dict[str, float] | None) -> list[str]:
    """The printed form of :func:`trace_breakdown`, with each step's ratio to its time alone."""
    t = trace["timeline"]
    lines = []
    for node, events in TIMELINE:
        cells = [f"{e} {t[e]:.1f}" for e in events if e in t]
        if cells:
            lines.append(f"    {node}: " + ", ".join(cells))
    cells = []
    for name, _, _, key in STEPS:
        if name not in trace["steps"]:
            continue
        wall, cpu = trace["steps"][name]
        ref = alone_ms(alone or {}, key, None)
        cell = f"{name} {wall:.1f} / {cpu:.1f}"
        if ref and ref >= 0.5:  # (no ratio of nothing: the synthetic CNN ranges no box)
            cell += f" vs {ref:.1f} = {wall / ref:.2f}x"
        cells.append(cell)
    if cells:
        lines.append(
            "    each step in the graph (wall / CPU of its thread, ms) vs alone: "
            + "; ".join(cells)
        )
    return lines


def _figures(times, reports, cpu0, cpu1, wall) -> dict:
    clock, tracks = times[graph.CLOCK], times[graph.TRACKS]
    stamps = sorted(clock)
    tracked = [s for s in stamps if s in tracks]
    lat = np.array([tracks[s] - clock[s] for s in tracked]) * 1e3
    d2, d3 = times[graph.DETECTIONS_2D], times[graph.DETECTIONS_3D]
    stage = {
        "detect": [d2[s] - clock[s] for s in tracked if s in d2],
        "range": [d3[s] - max(d2[s], clock[s]) for s in tracked if s in d2 and s in d3],
        "track": [tracks[s] - d3[s] for s in tracked if s in d3],
    }
    span = (tracks[tracked[-1]] - clock[stamps[0]]) if tracked else float("nan")
    return {
        "published": len(stamps),
        "tracked": len(tracked),
        "tracked_pct": 100.0 * len(tracked) / max(1, len(stamps)),
        "latency_ms": {
            "mean": float(lat.mean()) if lat.size else float("nan"),
            "p50": float(np.percentile(lat, 50)) if lat.size else float("nan"),
            "p95": float(np.percentile(lat, 95)) if lat.size else float("nan"),
            "max": float(lat.max()) if lat.size else float("nan"),
        },
        "stage_ms_p50": {
            k: float(np.median(v) * 1e3) if v else float("nan") for k, v in stage.items()
        },
        "throughput_fps": len(tracked) / span if tracked and span > 0 else float("nan"),
        "nodes": {
            n: {
                "in": r.counts.received,
                "out": r.counts.published,
                "dropped": r.counts.dropped,
                # the node's worker per frame (median over its last 100 frames): wall, CPU
                "processing_ms": list(r.processing_ms) if r.processing_ms else None,
            }
            for n, r in reports.items()
        },
        "cpu_pct": {
            n: 100.0 * (cpu1[n] - cpu0[n]) / wall if wall > 0 else float("nan") for n in cpu1
        },
    }


def offline_stage_times(
    root: Path, sequence: str, max_frames: int = 40, overrides: list[str] = ()
) -> dict[str, float]:
    """Median ms per frame of each stage run alone in this process, over the sequence's first
    ``max_frames`` frames (successive, as the odometry sees them; all 16 of real 0005): the
    stereo node's own frame path (``stereo_depth_node.pipeline.StereoPipeline`` with the
    parameter file's ``stereo_depth`` section, ``-p NODE.PARAM:=VALUE`` overrides included),
    its side work run in order in this thread (``SerialExecutor``) and timed by its trace
    points; the CNN of the detector node, thread counts and malloc policy as the graph's nodes
    (``tracking_bringup.offline_stages``). The baseline the graph's stages are compared with.
    The odometry of frame k runs from frame k-1 (its scene map and the previous frame's CNN
    boxes; its corners found ahead after frame k-1's output: "corners ahead"); "ranging +
    check" ranges the CNN's boxes with their orientation bins and angles and checks them
    against the frame's road plane."""
    from tracking_bringup.offline_stages import graph_stages
    from vehicle_common.kitti import TrackingSequence

    seq = TrackingSequence.open(root, sequence)
    frames = seq.frame_ids[:max_frames]
    stages = graph_stages(overrides)
    pairs = [seq.read_stereo(f) for f in frames]
    out = {"frames": float(len(pairs))}
    out.update(_message_costs(seq, frames[-1], pairs[0][0]))
    times = _frame_path_times(stages, seq, frames, pairs)
    out.update({k: float(np.median(v)) for k, v in times.items()})
    return out


def _timed(fn, clock=time.perf_counter):
    """(``fn()``, its ms)."""
    t0 = clock()
    out = fn()
    return out, (clock() - t0) * 1e3


def _median_ms(fn, repeats: int = 5) -> float:
    for _ in range(2):
        fn()
    return float(np.median([_timed(fn)[1] for _ in range(repeats)]))


def _message_costs(seq, frame: int, left0) -> dict[str, float]:
    """The player's read of a pair and an image message's conversions (median ms)."""
    from vehicle_common.image_conversion import image_to_rgb, numpy_to_image

    return {
        "read pair (2 PNG)": _median_ms(lambda: seq.read_stereo(frame)),
        "image message, build + convert": _median_ms(
            lambda: image_to_rgb(numpy_to_image(left0, "rgb8"))
        ),
        "image message from bytes (before)": _median_ms(lambda: _image_from_bytes(left0)),
    }


def _frame_path_times(stages, seq, frames, pairs) -> dict[str, list[float]]:
    """Each frame through the CNN and the stereo node's pipeline, in order: ms per step."""
    from stereo_depth_node.disparity import block_matching_disparity, compute_disparity
    from stereo_depth_node.offline import FRAME_NS
    from stereo_depth_node.pipeline import FrameBoxes
    from stereo_depth_node.region_matching import to_gray

    points: dict[str, tuple[float, float]] = {}  # trace point -> (wall, CPU) [s], this frame

    def trace(point: str, stamp: int) -> None:
        points[point] = (time.perf_counter(), time.process_time())

    left0, right0 = pairs[0]
    pipeline = stages.pipeline(trace)
    pipeline.camera_from_projections(left0, seq.calib.P2, seq.calib.P3)
    geometry, settings = pipeline.camera()
    params = pipeline.disparity_params_for(left0.shape[0], settings)
    detector = stages.detector
    for _ in range(3):  # warm-up (first allocations, caches)
        detector.detect(left0)
        compute_disparity(left0, right0, params)
        block_matching_disparity(to_gray(left0), to_gray(right0), params)
    times: dict[str, list[float]] = {}

    def add(key: str, ms: float) -> None:
        times.setdefault(key, []).append(ms)

    def span(start: str, end: str, cpu: bool = False) -> float:
        return (points[end][cpu] - points[start][cpu]) * 1e3

    cv_threads = stages.stereo_config.node.num_threads
    label = f"disparity ({cv_threads} thread{'s' if cv_threads > 1 else ''})"
    for k, (left, right) in enumerate(pairs):
        dets, ms = _timed(lambda left=left: detector.detect(left))
        add(f"detect (CNN, {stages.detector_threads} thread)", ms)
        boxes = FrameBoxes.from_detections(dets)
        points.clear()
        pipeline.process(frames[k] * FRAME_NS, left, right, geometry, params, boxes)
        add(label, span("disparity_start", "disparity_end"))
        cpu = span("disparity_start", "disparity_end", cpu=True)
        if "scene_start" in points:  # the map in the boxes: with the scene's block matching
            add("scene map (block matching)", span("scene_start", "scene_end"))
            cpu += span("scene_start", "scene_end", cpu=True)
        add("disparity CPU", cpu)  # all its threads, with the scene
        if k > 0:
            add("odometry", span("odometry_start", "odometry_end"))
        if "road_start" in points:  # the road plane's map at half the resolution
            add("road map (coarse)", span("road_start", "road_end"))
        add("ranging + check", span("ranging_start", "ranging_end"))
        # the next frame's corners, found ahead (in idle time after the 3D array)
        _, ms = _timed(lambda b=boxes.boxes: pipeline.frame_done(b))
        if k + 1 < len(pairs):
            add("corners ahead (odometry)", ms)
    return times


def path_alone(alone: dict[str, float]) -> float:
    """The stereo node's critical path alone, as if each step had cores of its own: the CNN
    (a frame is processed once its 2D array is there), then the scene's block-matching map
    (when the map is only computed in the boxes), then the helper thread's odometry and road
    map beside the map in the boxes and the ranging with its check (with the whole band's map,
    the odometry and the ranging wait for it)."""
    det = alone_ms(alone, "detect")
    disp = alone_ms(alone, "disparity (")
    odo, rng = alone["odometry"], alone["ranging + check"]
    scene = alone_ms(alone, "scene map", None)
    if scene is None:
        return det + disp + max(odo, rng)
    return det + scene + max(odo + alone_ms(alone, "road map", 0.0), disp + rng)


def stage_ratios(figures: dict, alone: dict[str, float]) -> dict[str, tuple[float, float]]:
    """In-graph time (p50) against the same work alone, per stage: ``{stage: (in graph ms,
    alone ms)}``. detect: image -> 2D detections vs the CNN alone; image -> 3D detections vs
    the stereo node's critical path alone (:func:`path_alone`); tracks: image -> tracks vs the
    same path (the tracker's own step is well under a millisecond)."""
    det = alone_ms(alone, "detect")
    path = path_alone(alone)
    st = figures["stage_ms_p50"]
    to_3d = st["detect"] + st["range"]
    return {
        "image -> 2D": (st["detect"], det),
        "image -> 3D": (to_3d, path),
        "image -> tracks": (figures["latency_ms"]["p50"], path),
    }


def cores_bound_3d(alone: dict[str, float], cores: int) -> float:
    """The earliest image -> 3D detections a machine of ``cores`` cores allows with no graph
    overhead at all: the frame's CPU work up to its 3D array (the CNN, the maps' CPU over all
    their threads, the odometry, the ranging and its check) spread perfectly over the cores,
    but no sooner than the longest chain (:func:`path_alone`)."""
    det = alone_ms(alone, "detect")
    work = det + alone["disparity CPU"] + alone["odometry"] + alone["ranging + check"]
    work += alone_ms(alone, "road map", 0.0)
    return max(path_alone(alone), work / max(1, cores))


def node_work(figures: dict, alone: dict[str, float]) -> dict[str, tuple[float, float, float]]:
    """Per compute node: (wall, CPU) ms its worker spent per frame in the graph and the same
    work alone. detector: the CNN on a converted image; stereo_depth: a frame's conversion,
    maps, ranging and check (its odometry runs in another thread), alone: the maps, the ranging
    and the check. CPU counts the worker thread only (OpenCV's own threads are not in it)."""
    det = alone_ms(alone, "detect")
    stereo = (
        alone_ms(alone, "scene map", 0.0)
        + alone_ms(alone, "disparity (")
        + alone["ranging + check"]
    )
    out = {}
    for node, label, ref in (
        (graph.DETECTOR.name, "detect", det),
        (graph.STEREO.name, "stereo frame", stereo),
    ):
        work = figures["nodes"].get(node, {}).get("processing_ms")
        if work:
            out[label] = (work[0], work[1], ref)
    return out


def _image_from_bytes(rgb: np.ndarray):
    """How images were built before: ``data = bytes`` (copied once more by the setter)."""
    from sensor_msgs.msg import Image

    msg = Image(height=rgb.shape[0], width=rgb.shape[1], encoding="rgb8", step=rgb.shape[1] * 3)
    msg.data = rgb.tobytes()
    return msg


def pingpong_frames(count: int, frames: int) -> list[int]:
    """``frames`` source frame indices going forth and back over ``count`` frames without
    repeating the turning frame (0..n-1, n-2..0, 1..n-1, ...)."""
    if count < 2:
        return [0] * frames
    cycle = list(range(count)) + list(range(count - 2, 0, -1))
    return [cycle[k % len(cycle)] for k in range(frames)]


def _prepare_real_pingpong(frames: int) -> tuple[Path, str]:
    """A ``frames``-long sequence "0005" of real 0005's pairs forth and back (links to the
    shared images; calibration linked; labels renumbered to the new frame indices)."""
    seq = "0005"
    root = OUT / f"real_0005_x{frames}"
    src_ids = sorted(int(p.stem) for p in (REAL_ROOT / "image_02" / seq).glob("*.png"))
    order = [src_ids[i] for i in pingpong_frames(len(src_ids), frames)]
    for cam in ("image_02", "image_03"):
        folder = root / cam / seq
        folder.mkdir(parents=True, exist_ok=True)
        for k, f in enumerate(order):
            link = folder / f"{k:06d}.png"
            if not link.is_symlink():
                link.symlink_to(REAL_ROOT / cam / seq / f"{f:06d}.png")
    (root / "calib").mkdir(exist_ok=True)
    calib = root / "calib" / f"{seq}.txt"
    if not calib.is_symlink():
        calib.symlink_to(REAL_ROOT / "calib" / f"{seq}.txt")
    rows: dict[int, list[str]] = {}
    for line in (REAL_ROOT / "label_02" / f"{seq}.txt").read_text().splitlines():
        if line.strip():
            frame, rest = line.split(" ", 1)
            rows.setdefault(int(frame), []).append(rest)
    (root / "label_02").mkdir(exist_ok=True)
    (root / "label_02" / f"{seq}.txt").write_text(
        "".join(f"{k} {rest}\n" for k, f in enumerate(order) for rest in rows.get(f, []))
    )
    return root, seq


def _prepare_synthetic(frames: int) -> tuple[Path, str]:
    from kitti_player_node.synthetic import generate_sequence

    root = OUT / "synthetic"
    generate_sequence(root, sequence="0000", frames=frames, seed=0)
    return root, "0000"


SHORT = {
    graph.PLAYER.name: "player",
    graph.DETECTOR.name: "det",
    graph.STEREO.name: "stereo",
    graph.TRACKER.name: "tracker",
    graph.RECORDER.name: "rec",
}


def _table(rows: list[tuple[str, str, dict]]) -> str:
    head = (
        f"{'data':<16} {'mode':<11} {'frames':>6} {'tracked':>12} {'mean ms':>7} {'p50 ms':>7} "
        f"{'p95 ms':>7} "
        f"{'max ms':>7} {'fps':>6}  {'det/ste/trk ms p50':>18}  {'dropped det/ste':>15}  CPU % "
        + "/".join(SHORT[n] for n in SHORT)
    )
    lines = [head, "-" * len(head)]
    for data, mode, f in rows:
        lat, st, nodes = f["latency_ms"], f["stage_ms_p50"], f["nodes"]
        drops = "/".join(
            str(nodes.get(n, {}).get("dropped", "-"))
            for n in (graph.DETECTOR.name, graph.STEREO.name)
        )
        cpu = "/".join(f"{f['cpu_pct'].get(n, float('nan')):.0f}" for n in SHORT)
        lines.append(
            f"{data:<16} {mode:<11} {f['published']:>6} "
            f"{f['tracked']:>4} ({f['tracked_pct']:5.1f}%) {lat['mean']:>7.0f} {lat['p50']:>7.0f} "
            f"{lat['p95']:>7.0f} "
            f"{lat['max']:>7.0f} {f['throughput_fps']:>6.1f}  "
            f"{st['detect']:>6.0f}/{st['range']:>4.0f}/{st['track']:>4.0f}     {drops:>15}  {cpu}"
        )
    return "\n".join(lines)


REFERENCE = REPO.parent / "shared" / "tools" / "cpu_reference.py"
SHORT_RUN = 4  # frames of the short lockstep run whose CPU is subtracted (start-up cancels)
#: --overload: the lockstep run after the camera runs (the capacity brackets them in time)
LOCKSTEP_AFTER = "lockstep 1 after"


def reference_ms() -> float | None:
    """The fixed reference workload (``../shared/tools/cpu_reference.py``: OpenCV SGBM on a
    0005 pair plus a float32 matrix product, thread-CPU ms per round) timed now, in a fresh
    process of this interpreter; None without it or without the real data."""
    import subprocess

    if not REFERENCE.is_file() or not (REAL_ROOT / "image_02" / "0005").is_dir():
        return None
    out = subprocess.run(
        [sys.executable, str(REFERENCE), str(REAL_ROOT)],
        capture_output=True,
        text=True,
        cwd=REPO,
        check=False,
    )
    try:
        return float(out.stdout.split()[-1])
    except (IndexError, ValueError):
        return None


def cpu_per_frame(long: dict, short: dict) -> dict[str, float]:
    """CPU ms per frame of each node process: the CPU of a long lockstep run minus that of a
    short one (both from the first frame's clock until the graph was idle after the last, so
    start-up, first-frame and shutdown costs cancel), over the frames between them."""
    frames = long["published"] - short["published"]
    if frames <= 0:
        return {}
    return {
        n: 1e3 * (long["cpu_s"][n] - short["cpu_s"].get(n, 0.0)) / frames
        for n in long.get("cpu_s", {})
    }


def thread_cpu_per_frame(long: dict, short: dict) -> dict[str, dict[str, float]]:
    """:func:`cpu_per_frame` per thread name of each node process."""
    frames = long["published"] - short["published"]
    if frames <= 0:
        return {}
    out = {}
    for n, threads in long.get("thread_cpu_s", {}).items():
        other = short.get("thread_cpu_s", {}).get(n, {})
        out[n] = {t: 1e3 * (c - other.get(t, 0.0)) / frames for t, c in threads.items()}
    return out


def capacity_figures(realtime: dict, lockstep: dict, camera_hz: float) -> dict[str, float]:
    """What a run at ``camera_hz`` made of the capacity its lockstep run (window 1, same
    machine, same settings) shows: frames tracked against ``published x min(1, lockstep
    frames/s / camera rate)`` (the bar: >= 0.9) and mean latency against lockstep's (<= 1.25)."""
    fps = lockstep["throughput_fps"]
    capacity = realtime["published"] * min(1.0, fps / camera_hz) if fps == fps else float("nan")
    lat_rt, lat_ls = realtime["latency_ms"]["mean"], lockstep["latency_ms"]["mean"]
    return {
        "camera_hz": camera_hz,
        "lockstep_fps": fps,
        "capacity": capacity,
        "tracked": realtime["tracked"],
        "frames_ratio": realtime["tracked"] / capacity if capacity else float("nan"),
        "latency_ms": lat_rt,
        "lockstep_latency_ms": lat_ls,
        "latency_ratio": lat_rt / lat_ls if lat_ls else float("nan"),
    }


def tracked_quality(bag: Path) -> dict[str, float] | None:
    """Tracking quality of a recorded run on the frames that got through (frames with tracks;
    ground truth from the bag): tracks 3D AP @1.5 m (moderate, AP|R40, and at the actual
    recall), MOTA (2D IoU 0.5) and HOTA (2D IoU). None when the bag cannot be read or holds
    no ground truth."""
    from eval_node.bag_evaluation import evaluate_bag
    from vehicle_common.bags.recorded_run import TRACKS_TOPIC, read_run

    try:
        run = read_run(bag)
    except Exception:  # noqa: BLE001 - a run without a readable bag has no quality figure
        return None
    run.frames = [f for f in run.frames if TRACKS_TOPIC in f.receive_ns]
    if not run.frames or not any(f.gt for f in run.frames):
        return None
    res = evaluate_bag(bag, run=run, run_filters=False)
    return {
        "frames": len(run.frames),
        "tracks_ap_1.5m_moderate": 100 * res["tracks_3d"]["1.5"]["moderate"],
        "tracks_ap_1.5m_moderate_actual_recall": 100
        * res["tracks_3d"]["1.5"].get("moderate_actual_recall", float("nan")),
        "moderate_boxes": res["tracks_3d"]["1.5"].get("moderate_num_gt", 0),
        "mota": 100 * res["tracking"]["mota"],
        "hota": 100 * res["tracking"]["hota"],
    }


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--synthetic-frames", type=int, default=100)
    parser.add_argument("--no-real", action="store_true", help="skip KITTI 0005")
    parser.add_argument(
        "--real-frames",
        type=int,
        default=0,
        help="also play 0005's pairs forth and back for this many frames (timing only)",
    )
    parser.add_argument("--no-synthetic", action="store_true")
    parser.add_argument("--windows", default="1,2", help="lockstep windows to run")
    parser.add_argument("--no-realtime", action="store_true")
    parser.add_argument(
        "--rate-multiplier",
        type=float,
        default=1.0,
        help="the camera-rate runs play at 10 Hz x this (a faster camera: overload)",
    )
    parser.add_argument(
        "--cpus",
        default="",
        help="run every node on these CPUs (cpu_affinity, 'taskset -c' list: '0' = one core)",
    )
    parser.add_argument(
        "--overload",
        nargs="?",
        const="2,3",
        default="",
        metavar="FACTORS",
        help="after each dataset's lockstep run (window 1: the capacity C, frames/s), play it "
        "as a camera at each of these multiples of C, without lockstep (default 2,3)",
    )
    parser.add_argument(
        "--no-cpu",
        action="store_true",
        help="skip the short lockstep runs of the CPU-per-frame figure and the reference",
    )
    parser.add_argument(
        "--no-quality", action="store_true", help="skip the tracking quality of each run"
    )
    parser.add_argument(
        "--compare-tree",
        metavar="PATH",
        help="run this bench alternately with PATH's .venv (another checkout: today's tree) "
        "and this tree's, and print the ratios",
    )
    parser.add_argument("--repeat", type=int, default=1, help="--compare-tree: pairs of runs")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NODE.PARAM:=VALUE")
    parser.add_argument("--json", help="write the figures to this file")
    parser.add_argument("--no-offline", action="store_true", help="skip the per-stage baseline")
    parser.add_argument(
        "--profile",
        action="store_true",
        help="py-spy every node process in the 10 Hz runs and print where its CPU time goes",
    )
    return parser


def bracketed(before: dict, after: dict | None) -> dict:
    """The lockstep figures :func:`capacity_figures` reads (frames/s, mean latency) as the mean
    of the lockstep runs before and after the camera runs (``after`` None: ``before``)."""
    if after is None:
        return before
    return {
        "throughput_fps": 0.5 * (before["throughput_fps"] + after["throughput_fps"]),
        "latency_ms": {"mean": 0.5 * (before["latency_ms"]["mean"] + after["latency_ms"]["mean"])},
    }


def summarise(rows, short_runs, references, camera_hz, quality) -> dict:
    """Per dataset: the camera-rate run against its lockstep run (window 1), the CPU per frame
    of each node process (long lockstep run minus the short one) against the reference
    workload, and the tracking quality of each run on the frames that got through."""
    refs = [r for r in references if r]
    ref = float(np.median(refs)) if refs else float("nan")
    out: dict[str, dict] = {}
    for label in dict.fromkeys(d for d, _, _ in rows):
        runs = {m: f for d, m, f in rows if d == label}
        entry: dict = {"reference_ms": ref, "references_ms": refs}
        if "realtime" in runs and "lockstep 1" in runs:
            entry["capacity"] = capacity_figures(runs["realtime"], runs["lockstep 1"], camera_hz)
        if "lockstep 1" in runs:  # --overload: each camera factor against the same capacity
            after = runs.get(LOCKSTEP_AFTER)
            lockstep = bracketed(runs["lockstep 1"], after)
            entry["overload"] = {
                m: {
                    **capacity_figures(f, lockstep, f["camera_hz"]),
                    "budget": camera_budget(
                        runs["lockstep 1"], f, f["camera_hz"], graph.PLAYER.name
                    ),
                    **(
                        {
                            "against": {
                                k: capacity_figures(f, ls, f["camera_hz"])
                                for k, ls in (("before", runs["lockstep 1"]), ("after", after))
                            }
                        }
                        if after is not None
                        else {}
                    ),
                }
                for m, f in runs.items()
                if m.startswith("camera")
            }
        if label in short_runs and "lockstep 1" in runs:
            per_node = cpu_per_frame(runs["lockstep 1"], short_runs[label])
            graph_ms = sum(v for n, v in per_node.items() if n != graph.PLAYER.name)
            entry["cpu_ms_per_frame"] = per_node
            entry["thread_cpu_ms_per_frame"] = thread_cpu_per_frame(
                runs["lockstep 1"], short_runs[label]
            )
            entry["cpu_graph_ms_per_frame"] = graph_ms  # every node but the player
            entry["cpu_vs_reference"] = graph_ms / ref if ref == ref else float("nan")
        entry["quality"] = {m: q for (d, m), q in quality.items() if d == label}
        out[label] = entry
    return out


def budget_line(label: str, b: dict, camera_hz: float, one_cpu: bool) -> str:
    """The printed form of :func:`tracking_bringup.process_cpu.camera_budget` for one camera
    run (the one-CPU ceiling only when every node ran on one CPU)."""
    line = (
        f"  {label}: every published frame, tracked or not, costs the camera "
        f"{b['camera_ms']:.1f} ms + the nodes' executors {b['receipt_ms']:.1f} ms of CPU: "
        f"{100 * b['share']:.0f} % of one CPU at {camera_hz:.1f} Hz; a tracked frame "
        f"{b['tracked_ms']:.0f} ms (lockstep)"
    )
    if one_cpu:
        line += (
            f"; on this one CPU that leaves at most {b['one_cpu_frames']:.2f}x the capacity's "
            f"frames, and a frame's work {b['one_cpu_latency']:.2f}x lockstep's time (before "
            "its wait for the graph)"
        )
    return line


def on_one_cpu(args) -> bool:
    """Whether ``--cpus`` put every node on one CPU."""
    from vehicle_common.cpu_affinity import parse_cpu_list

    return bool(args.cpus) and len(parse_cpu_list(args.cpus)) == 1


def summary_lines(summary: dict, one_cpu: bool = False) -> list[str]:
    """The printed form of :func:`summarise`: the three bars of issue #33 per dataset (and,
    per camera run of ``--overload``, what its frames cost whether tracked or not; the ceiling
    that leaves when ``one_cpu``: every node ran on one CPU)."""
    lines = []
    for label, e in summary.items():
        runs = ([("", e["capacity"])] if e.get("capacity") else []) + [
            (f" ({m})", c) for m, c in e.get("overload", {}).items()
        ]
        for mode, c in runs:
            lines.append(
                f"  {label}{mode}: camera {c['camera_hz']:.1f} Hz, lockstep "
                f"{c['lockstep_fps']:.1f} "
                f"frames/s -> capacity {c['capacity']:.1f} frames; tracked {c['tracked']} = "
                f"{c['frames_ratio']:.2f}x capacity (bar >= 0.9); mean latency "
                f"{c['latency_ms']:.0f} ms vs lockstep {c['lockstep_latency_ms']:.0f} ms = "
                f"{c['latency_ratio']:.2f}x (bar <= 1.25)"
                + (
                    " (against the lockstep run before / after alone: "
                    f"{c['against']['before']['frames_ratio']:.2f}x / "
                    f"{c['against']['after']['frames_ratio']:.2f}x, "
                    f"{c['against']['before']['latency_ratio']:.2f}x / "
                    f"{c['against']['after']['latency_ratio']:.2f}x; lockstep "
                    f"{c['against']['before']['lockstep_fps']:.1f} / "
                    f"{c['against']['after']['lockstep_fps']:.1f} frames/s)"
                    if c.get("against")
                    else ""
                )
            )
            if c.get("budget"):
                lines.append(budget_line(f"{label}{mode}", c["budget"], c["camera_hz"], one_cpu))
        per_node = e.get("cpu_ms_per_frame")
        if per_node:
            cells = ", ".join(f"{SHORT.get(n, n)} {v:.1f}" for n, v in per_node.items())
            lines.append(
                f"  {label}: CPU per frame (lockstep 1, long run minus {SHORT_RUN} frames) "
                f"{e['cpu_graph_ms_per_frame']:.1f} ms without the player ({cells}); "
                f"reference workload {e['reference_ms']:.1f} ms "
                f"({', '.join(f'{r:.1f}' for r in e['references_ms'])}) -> "
                f"{e['cpu_vs_reference']:.2f}x the reference (bar <= 0.6, issue #39)"
            )
        for n, threads in e.get("thread_cpu_ms_per_frame", {}).items():
            top = sorted(threads.items(), key=lambda kv: -kv[1])[:5]
            lines.append(
                f"    {SHORT.get(n, n)} by thread: "
                + ", ".join(f"{t} {v:.1f}" for t, v in top if v >= 0.05)
            )
        for mode, q in e.get("quality", {}).items():
            lines.append(
                f"  {label}, {mode}: on the {q['frames']} frames tracked: tracks 3D AP @1.5 m "
                f"(moderate, AP|R40) {q['tracks_ap_1.5m_moderate']:.1f}"
                + (
                    f" (at the actual recall {q['tracks_ap_1.5m_moderate_actual_recall']:.1f}: "
                    f"{q['moderate_boxes']} boxes cap AP|R40)"
                    if 0 < q.get("moderate_boxes", 40) < 40
                    and np.isfinite(q["tracks_ap_1.5m_moderate_actual_recall"])
                    else ""
                )
                + f", MOTA {q['mota']:.1f}, HOTA (2D IoU) {q['hota']:.1f}"
            )
    if lines:
        lines.insert(0, "issues #33 / #39's bars (ratios measured in this run):")
    return lines


def compare_trees(args, argv: list[str]) -> int:
    """Run this bench ``--repeat`` times alternately with the other tree's interpreter (its
    ``.venv``: its nodes, parameters and packages; this script) and this tree's, and print
    each run's bars and the new/old ratios of CPU per frame."""
    import subprocess

    other = Path(args.compare_tree).resolve()
    python = other / ".venv" / "bin" / "python"
    if not python.is_file():
        print(f"error: --compare-tree: {python} not found", file=sys.stderr)
        return 2
    child = []
    skip = False
    for a in argv:  # the same arguments without --compare-tree / --repeat / --json
        if skip:
            skip = False
            continue
        if a in ("--compare-tree", "--repeat", "--json"):
            skip = True
            continue
        if a.startswith(("--compare-tree=", "--repeat=", "--json=")):
            continue
        child.append(a)
    if "--no-offline" not in child:  # the offline baseline calls this tree's core functions
        child.append("--no-offline")
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("FASTRTPS_DEFAULT_PROFILES_FILE", "RMW_IMPLEMENTATION")
    }
    OUT.mkdir(parents=True, exist_ok=True)
    results: list[tuple[str, dict]] = []
    for k in range(args.repeat):
        for name, exe in (("old", str(python)), ("new", sys.executable)):
            out = OUT / f"compare_{time.strftime('%Y%m%d_%H%M%S')}_{name}{k}.json"
            print(f"[bench] {name} tree ({exe}), run {k + 1} ...", file=sys.stderr, flush=True)
            code = subprocess.run(
                [exe, __file__, *child, "--json", str(out)], env=env, check=False
            ).returncode
            if code != 0 or not out.is_file():
                print(f"error: the {name} tree's run failed (exit {code})", file=sys.stderr)
                return 1
            results.append((name, json.loads(out.read_text())))
    print(f"\n== comparison: old = {other}, new = {REPO}, {args.repeat} pair(s), alternated ==")
    for name, res in results:
        print(f"{name}: load {' '.join(res['load_before'])} before, {' '.join(res['load'])} after")
        for line in summary_lines(res["summary"], on_one_cpu(args)):
            print(f"  {line}")
    for label in results[0][1]["summary"]:
        old = [r["summary"][label] for n, r in results if n == "old"]
        new = [r["summary"][label] for n, r in results if n == "new"]
        ratios = [
            b["cpu_graph_ms_per_frame"] / a["cpu_graph_ms_per_frame"]
            for a, b in zip(old, new, strict=True)
            if "cpu_graph_ms_per_frame" in a and "cpu_graph_ms_per_frame" in b
        ]
        if ratios:
            print(
                f"  {label}: CPU per frame new / old, each pair: "
                + ", ".join(f"{r:.2f}x" for r in ratios)
                + " (bar <= 0.6)"
            )
    if args.json:
        Path(args.json).write_text(json.dumps([{"tree": n, **r} for n, r in results], indent=1))
    return 0


def _datasets(args) -> list[tuple[str, Path, str]]:
    """(label, KITTI root, sequence) of each data set to run: real 0005 (and its ping-pong
    extension), the synthetic sequence."""
    datasets = []
    if not args.no_real:
        if (REAL_ROOT / "image_02" / "0005").is_dir():
            datasets.append(("real 0005", REAL_ROOT, "0005"))
            if args.real_frames > 0:
                root, seq = _prepare_real_pingpong(args.real_frames)
                datasets.append((f"real 0005 x{args.real_frames}", root, seq))
        else:
            print(f"[bench] {REAL_ROOT}: no KITTI 0005, real data skipped", file=sys.stderr)
    if not args.no_synthetic:
        root, seq = _prepare_synthetic(args.synthetic_frames)
        datasets.append((f"synthetic {args.synthetic_frames}", root, seq))
    return datasets


def _run_modes(args, label, root, seq, modes, overrides, stamp, camera_hz, results) -> None:
    """Run the graph on one data set in each mode; ``results``: (rows, quality, profiles) to
    add to."""
    rows, quality, profiles = results
    capacity_fps = float("nan")
    for mode, lockstep, window in modes:
        logs = OUT / "runs" / stamp / f"{label.replace(' ', '_')}_{mode.replace(' ', '')}"
        prof = logs / "profile" if args.profile and not lockstep else None
        rate = [] if lockstep else [f"kitti_player.rate_multiplier:={args.rate_multiplier}"]
        hz = camera_hz
        if mode.startswith("camera"):  # window: the factor of the capacity
            if not capacity_fps > 0:
                print(f"[bench] {label}: no capacity measured, {mode} skipped", file=sys.stderr)
                continue
            hz = window * capacity_fps
            rate = [f"kitti_player.rate:={hz:.3f}", "kitti_player.rate_multiplier:=1.0"]
            window = 1
        print(f"[bench] {label}, {mode} ...", file=sys.stderr, flush=True)
        figures = run_case(root, seq, lockstep, window, rate + overrides, logs, prof)
        figures["camera_hz"] = None if lockstep else hz
        if mode == "lockstep 1":
            capacity_fps = figures["throughput_fps"]
        rows.append((label, mode, figures))
        if not args.no_quality:
            q = tracked_quality(logs / "bag")
            if q is not None:
                quality[(label, mode)] = q
        if prof is not None:
            profiles.append((label, mode, prof))


def _print_stage_comparisons(rows, offline: dict) -> None:
    """Each stage in the graph against alone, the cores' bound and the nodes' own work."""
    print("in graph (p50) / alone, per stage (1.0 = no overhead beyond the work itself):")
    for data, mode, f in rows:
        ratios = stage_ratios(f, offline[data])
        cells = ", ".join(
            f"{k} {g:.0f} / {a:.0f} ms = {g / a:.2f}x" for k, (g, a) in ratios.items()
        )
        print(f"  {data:<16} {mode:<11} {cells}")
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    for label, times in offline.items():
        bound = cores_bound_3d(times, cores)
        path = path_alone(times)
        print(
            f"  {label}: on {cores} cores image -> 3D cannot come sooner than {bound:.0f} ms "
            f"= {bound / path:.2f}x its time alone (the CPU work of a frame up to its 3D "
            "array spread perfectly over the cores, no graph overhead)"
        )
    print(
        "each compute node's own work per frame in the graph (its /diagnostics report: "
        "median wall / CPU ms of its worker thread) against the same work alone:"
    )
    for data, mode, f in rows:
        cells = ", ".join(
            f"{k} {w:.0f} / {c:.0f} ms vs {a:.0f} = {w / a:.2f}x wall, {c / a:.2f}x CPU"
            for k, (w, c, a) in node_work(f, offline[data]).items()
        )
        print(f"  {data:<16} {mode:<11} {cells}")


def _print_report(args, rows, offline: dict, summary: dict, profiles) -> None:
    """The per-stage times alone, the runs' table, the summary and where the time goes."""
    if args.param:
        print("parameters: " + " ".join(args.param))
    for label, times in offline.items():
        print(
            f"each stage alone, {label} (median ms over {times.get('frames', 0):.0f} frames): "
            + ", ".join(f"{k} {v:.1f}" for k, v in times.items() if k != "frames")
        )
    print(_table(rows))
    for line in summary_lines(summary, on_one_cpu(args)):
        print(line)
    print(
        "where a frame's time goes (the nodes' trace points, VEHICLE_TRACE_DIR; median ms "
        "after the player's clock event):"
    )
    for data, mode, f in rows:
        tr = f.get("trace") or {}
        if tr.get("frames"):
            print(f"  {data}, {mode} ({tr['frames']} frames):")
            for line in breakdown_lines(tr, offline.get(data)):
                print(line)
    if offline:
        _print_stage_comparisons(rows, offline)
    for data, mode, folder in profiles:
        print(f"where each process's CPU time goes ({data}, {mode}; py-spy, {folder}):")
        print(profile_summary(folder))


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        factors = [float(f) for f in args.overload.split(",") if f.strip()]
        if any(not f > 0 for f in factors):
            raise ValueError
    except ValueError:
        print(f"error: --overload: {args.overload!r}: factors > 0, e.g. 2,3", file=sys.stderr)
        return 2
    if factors and "1" not in args.windows.split(","):
        args.windows = ",".join(["1", *(w for w in args.windows.split(",") if w)])
    if args.compare_tree:
        return compare_trees(args, list(sys.argv[1:] if argv is None else argv))
    apply_graph_environment()
    overrides = list(args.param)
    if args.cpus:
        overrides = [f"{n.name}.cpu_affinity:={args.cpus}" for n in graph.PIPELINE] + overrides
    try:  # a bad -p (node name, value) is one line before any node starts
        graph_processes(graph.PIPELINE, PARAMS_FILE, overrides)
    except (LaunchError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    datasets = _datasets(args)
    windows = [int(w) for w in args.windows.split(",") if w]
    modes = ([] if args.no_realtime or factors else [("realtime", False, 1)]) + [
        (f"lockstep {w}", True, w) for w in windows
    ]
    # overload: a camera at each factor x the capacity measured by lockstep 1 in this run, then
    # lockstep 1 again (the capacity: both lockstep runs, bracketing the camera runs in time)
    modes += [(f"camera {f:g}x", False, f) for f in factors]
    modes += [(LOCKSTEP_AFTER, True, 1)] if factors else []
    offline: dict[str, dict[str, float]] = {}  # per dataset label
    if not args.no_offline:
        for label, root, seq in datasets:
            print(f"[bench] offline stage times, {label} ...", file=sys.stderr, flush=True)
            offline[label] = offline_stage_times(root, seq, overrides=overrides)
    camera_hz = 10.0 * args.rate_multiplier
    do_cpu = not args.no_cpu and 1 in windows
    # the reference workload: two runs now, one after; their median (some runs read slow)
    references = [reference_ms(), reference_ms()] if do_cpu else []
    rows, stamp, profiles = [], time.strftime("%Y%m%d_%H%M%S"), []
    short_runs: dict[str, dict] = {}
    quality: dict[tuple[str, str], dict] = {}
    load_before = Path("/proc/loadavg").read_text().split()[:3]
    try:
        for label, root, seq in datasets:
            results = (rows, quality, profiles)
            _run_modes(args, label, root, seq, modes, overrides, stamp, camera_hz, results)
            if do_cpu:
                logs = OUT / "runs" / stamp / f"{label.replace(' ', '_')}_short"
                print(f"[bench] {label}, lockstep 1, {SHORT_RUN} frames ...", file=sys.stderr)
                short = [f"kitti_player.last_frame:={SHORT_RUN - 1}", *overrides]
                short_runs[label] = run_case(root, seq, True, 1, short, logs)
    except LaunchError as exc:  # a node refused its parameters or died: its one line
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    if do_cpu:
        references.append(reference_ms())
    load = Path("/proc/loadavg").read_text().split()[:3]
    print(
        f"machine: {os.cpu_count()} CPUs, load average {' '.join(load_before)} before, "
        f"{' '.join(load)} after (1/5/15 min)"
    )
    if args.cpus or args.rate_multiplier != 1.0 or factors:
        rates = [f"{f:g} x the capacity" for f in factors] or [f"{camera_hz:g} Hz"]
        print(
            f"overload: camera at {', '.join(rates)}"
            + (f", every node on CPUs {args.cpus}" if args.cpus else "")
        )
    summary = summarise(rows, short_runs, references, camera_hz, quality)
    _print_report(args, rows, offline, summary, profiles)
    if args.json:
        out = {"offline_ms": offline, "load": load, "load_before": load_before}
        out["parameters"] = args.param
        out["runs"] = [{"data": d, "mode": m, **f} for d, m, f in rows]
        out["summary"] = summary
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
