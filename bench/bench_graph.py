"""The whole graph at camera rate and in lockstep: frames tracked, latency, CPU per node.

Usage: python bench/bench_graph.py [--synthetic-frames 100] [--no-real] [--windows 1,2]
       [--real-frames N] [-p NODE.PARAM:=VALUE ...] [--json FILE] [--profile]

Runs the graph of the demo (player, CNN detector, stereo depth, tracker, recorder; separate
processes, the shipped parameter file) on real KITTI tracking 0005 (../shared/kitti, 16 frames)
and on a synthetic sequence (rendered once into output/bench_graph/synthetic). ``--real-frames N``
(N > 16) plays a longer real sequence made of 0005's pairs forth and back (0..15, 14..0, 1..15,
...; links to the shared images under output/bench_graph, labels renumbered), the length of a
longer real drive at the same image content: its timing figures, not its tracking accuracy (the
camera turns back at each end).

- ``realtime``: the player at 10 Hz without lockstep, as a camera: frames published, frames
  that reached /vehicles/tracks, latency image -> tracks (p50 / p95 / max: the player's /clock
  message of a frame, published just before its images, to the tracks of that stamp, both seen
  by a probe node in this process), the per-stage share of it (-> 2D detections -> 3D
  detections -> tracks), each node's frames in / out / dropped (its /diagnostics report) and
  CPU (% of one core, from /proc, over the playback).
- ``lockstep K``: the player as fast as the graph goes with at most K unacknowledged frames;
  throughput in frames/s (first /clock to last tracks).

Every run also traces each frame through the nodes (``vehicle_common.frame_trace``, the
environment variable ``VEHICLE_TRACE_DIR`` set to the run's ``trace`` folder): when the player
published the images, when each node received them, started and ended each step of its work (the
CNN, the disparity map, the odometry, the ranging and its check) and published; printed as a
median timeline after the player's clock event, and each step's wall / own-thread CPU time in the
graph against the same step alone (``offline_stage_times``: the median over the sequence's frames
of the same work, inputs and settings in this process).

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


def _cpu_seconds(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _start_profilers(pids: dict[str, int], out: Path, rate: int = 200) -> list:
    """``py-spy record`` on every node process (on-CPU samples of its Python threads, raw
    collapsed stacks into ``out/<node>.txt``); stops when the process exits."""
    import shutil
    import subprocess

    exe = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(exe).is_file():
        print("[bench] --profile: py-spy not installed (pip install py-spy)", file=sys.stderr)
        return []
    out.mkdir(parents=True, exist_ok=True)
    procs = []
    for name, pid in pids.items():
        cmd = [exe, "record", "--pid", str(pid), "--rate", str(rate), "--format", "raw"]
        cmd += ["--output", str(out / f"{name}.txt"), "--nonblocking", "--threads"]
        with open(out / f"{name}.log", "w") as log:  # the child keeps its own descriptor
            procs.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log))
    return procs


def profile_summary(folder: Path, rate: int = 200, top: int = 6) -> str:
    """Per node: CPU seconds sampled, split by thread, and the functions with the most self
    time (the innermost Python frame of each sample: time in a C extension such as OpenCV,
    ONNX Runtime or numpy is booked on the Python line that called it)."""
    lines = []
    for f in sorted(folder.glob("*.txt")):
        self_time: dict[str, int] = {}
        threads: dict[str, int] = {}
        total = 0
        for row in f.read_text().splitlines():
            stack, _, count = row.rpartition(" ")
            if not stack or not count.isdigit():
                continue
            n = int(count)
            frames = stack.split(";")
            total += n
            thread = frames[0].split(" (")[0] if frames[0].startswith(("thread", "process")) else ""
            threads[thread] = threads.get(thread, 0) + n
            leaf = frames[-1]
            fn, _, where = leaf.partition(" (")
            if len(frames) == 1 and thread:  # a sample without a Python frame
                key = "(native code, no Python frame)"
            else:
                key = f"{fn} ({Path(where.split(':')[0]).name})" if where else fn
            self_time[key] = self_time.get(key, 0) + n
        if not total:
            continue
        lines.append(f"  {f.stem}: {total} samples ({total / rate:.2f} thread-s, all threads)")
        for k, n in sorted(self_time.items(), key=lambda kv: -kv[1])[:top]:
            lines.append(f"    {100 * n / total:5.1f} %  {k}")
    return "\n".join(lines)


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
    cpu0, cpu1 = {}, {}
    t_cpu0 = t_cpu1 = 0.0
    profilers: list = []
    try:
        launcher.start()
        pids = {n: r.proc.pid for n, r in launcher.running.items()}
        while not probe.times[graph.CLOCK]:  # playback starts once every edge is matched
            launcher.spin_reports(0.05)
        cpu0, t_cpu0 = {n: _cpu_seconds(p) for n, p in pids.items()}, time.monotonic()
        cpu1 = dict(cpu0)
        profilers = _start_profilers(pids, profile) if profile is not None else []

        def sample():  # the last reading of each process (the player exits at the end)
            for n, p in pids.items():
                c = _cpu_seconds(p)
                if c == c:  # not nan
                    cpu1[n] = c

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
            "pair_start",
            "disparity_start",
            "disparity_end",
            "pair_end",
            "detections_received",
            "ranging_start",
            "odometry_start",
            "ranging_end",
            "odometry_end",
            "detections_3d_published",
        ),
    ),
    ("tracker", ("tracks_published",)),
)
# the steps of a frame's work in the graph, timed between two events of one thread, and the
# key of the same work alone (offline_stage_times)
STEPS = (
    ("CNN", "detect_start", "detect_end", "detect"),
    ("disparity map", "disparity_start", "disparity_end", "disparity ("),
    ("odometry", "odometry_start", "odometry_end", "odometry"),
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
    same core functions, thread
    counts, match band, malloc policy and inputs as the graph's nodes (``-p NODE.PARAM:=VALUE``
    overrides included). The baseline the graph's stages are compared with. The odometry of
    frame k runs from frame k-1 (its disparity map and the previous frame's CNN boxes, as the
    node keeps them); "ranging + check" ranges the CNN's boxes with their orientation bins and
    angles and checks them against the frame's road plane, as the node does before it
    publishes the 3D array."""
    import dataclasses

    import cv2
    import torch
    import yaml
    from detector_node.inference import CnnDetector
    from stereo_depth_node.disparity import DisparityParams, compute_disparity, match_band
    from stereo_depth_node.plausibility import GroundEstimator, PlausibilityParams, check_boxes
    from stereo_depth_node.ranging import (
        RangingParams,
        RangingSetup,
        disparity_bias_at,
        observation_angles_of,
        range_boxes,
    )
    from stereo_depth_node.region_matching import to_gray
    from stereo_depth_node.reprojection import StereoGeometry
    from stereo_depth_node.visual_odometry import estimate_camera_motion, reference_corners
    from vehicle_common.camera_settings import CameraModel, stereo_settings
    from vehicle_common.image_conversion import image_to_rgb, numpy_to_image
    from vehicle_common.kitti import TrackingSequence
    from vehicle_common.malloc_policy import keep_freed_memory

    seq = TrackingSequence.open(root, sequence)
    frames = seq.frame_ids[:max_frames]

    def stereo_param(name: str, default):
        ovs = graph.node_overrides(overrides, graph.STEREO.name)
        value = graph.parameter_value(PARAMS_FILE, ovs, graph.STEREO.name, name, default)
        return yaml.safe_load(value) if isinstance(value, str) else value

    def threads(node: str) -> int:
        ovs = graph.node_overrides(overrides, node)
        return int(graph.parameter_value(PARAMS_FILE, ovs, node, "num_threads", 2))

    det_threads, cv_threads = threads(graph.DETECTOR.name), threads(graph.STEREO.name)
    torch.set_num_threads(det_threads)
    detector = CnnDetector.from_checkpoint("", "cpu")
    cv2.setNumThreads(cv_threads)
    # the stereo node's settings: its defaults are the parameter file's, plus the file's match
    # band and malloc policy (a node keeps freed memory for reuse: keep_freed_memory)
    pairs = [seq.read_stereo(f) for f in frames]
    left0, right0 = pairs[0]
    # the camera-dependent settings as the node derives them (vehicle_common.camera_settings)
    camera = CameraModel.from_projections(
        left0.shape[1], left0.shape[0], seq.calib.P2, seq.calib.P3
    )
    derived = stereo_settings(
        camera,
        int(stereo_param("num_disparities", 0)),
        tuple(int(v) for v in stereo_param("match_rows", [-1, -1])),
    )
    band, _ = match_band(derived.match_rows, left0.shape[0], DisparityParams())  # as the node does
    params = dataclasses.replace(
        DisparityParams(), num_disparities=derived.num_disparities, row_band=band
    )
    if stereo_param("keep_freed_memory", True):
        keep_freed_memory()
    geometry = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    ranging = RangingSetup.from_params(RangingParams())
    plausibility = PlausibilityParams()
    ground = GroundEstimator(plausibility, ranging.params.ground_height)
    bias = np.asarray(disparity_bias_at(np.arange(left0.shape[1]), geometry, ranging.params))
    fb = geometry.fx * geometry.baseline

    def timed(fn, clock=time.perf_counter):
        t0 = clock()
        out = fn()
        return out, (clock() - t0) * 1e3

    for _ in range(3):  # warm-up (first allocations, caches)
        detector.detect(left0)
        compute_disparity(left0, right0, params)
    times: dict[str, list[float]] = {}

    def add(key: str, ms: float) -> None:
        times.setdefault(key, []).append(ms)

    previous = None  # (gray, disparity, CNN boxes) of the frame before
    for left, right in pairs:
        dets, ms = timed(lambda left=left: detector.detect(left))
        add(f"detect (CNN, {det_threads} thread)", ms)
        c0 = time.process_time()
        disp, ms = timed(lambda left=left, right=right: compute_disparity(left, right, params))
        add(f"disparity ({cv_threads} thread{'s' if cv_threads > 1 else ''})", ms)
        add("disparity CPU", (time.process_time() - c0) * 1e3)  # all its threads
        gray, gray_r = to_gray(left), to_gray(right)
        boxes = [d.box for d in dets]
        if previous is not None:
            # as the node: the reference's corners found ahead (in idle time after its 3D
            # array), then the estimate on the frame's path
            g0, d0, b0 = previous
            ref, ms = timed(lambda g0=g0, d0=d0, b0=b0: reference_corners(g0, d0, b0))
            add("corners ahead (odometry)", ms)
            _, ms = timed(
                lambda g0=g0, d0=d0, b0=b0, gray=gray, ref=ref: estimate_camera_motion(
                    g0, d0, gray, geometry, b0, None, bias, ref
                )
            )
            add("odometry", ms)
        bins = [d.orientation_bin for d in dets]
        alphas = observation_angles_of(
            [d.observation_angle for d in dets], [d.observation_angle_variance for d in dets]
        )

        def range_and_check(
            disp=disp, boxes=boxes, bins=bins, alphas=alphas, images=(gray, gray_r)
        ):
            if not boxes:  # the node ranges and checks nothing then
                return []
            results = range_boxes(disp, boxes, geometry, ranging, bins, images, alphas)
            plane = ground.update(disp, geometry, bias)
            depths = [fb / r.disparity if r is not None else None for r in results]
            return check_boxes(disp, boxes, depths, geometry, plane, plausibility)

        _, ms = timed(range_and_check)
        add("ranging + check", ms)
        previous = (gray, disp, boxes)

    def median_ms(fn, repeats: int = 5) -> float:
        for _ in range(2):
            fn()
        return float(np.median([timed(fn)[1] for _ in range(repeats)]))

    out = {
        "frames": float(len(pairs)),
        "read pair (2 PNG)": median_ms(lambda: seq.read_stereo(frames[-1])),
        "image message, build + convert": median_ms(
            lambda: image_to_rgb(numpy_to_image(left0, "rgb8"))
        ),
        "image message from bytes (before)": median_ms(lambda: _image_from_bytes(left0)),
    }
    out.update({k: float(np.median(v)) for k, v in times.items()})
    return out


def path_alone(alone: dict[str, float]) -> float:
    """The stereo node's critical path alone, as if each step had cores of its own: the later
    of the CNN, the disparity map and the odometry (which needs only the pair's left image and
    the previous map, so could start with the pair), then the ranging and its check."""
    det = alone_ms(alone, "detect")
    disp = alone_ms(alone, "disparity (")
    return max(det, disp, alone["odometry"]) + alone["ranging + check"]


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
    overhead at all: the frame's CPU work up to its 3D array (the CNN, the disparity map's CPU
    over all its threads, the odometry, the ranging and its check) spread perfectly over the
    cores, but no sooner than the longest chain (the later of the CNN and the map, then the
    ranging)."""
    det = alone_ms(alone, "detect")
    disp = alone_ms(alone, "disparity (")
    rng = alone["ranging + check"]
    work = det + alone["disparity CPU"] + alone["odometry"] + rng
    return max(max(det, disp) + rng, work / max(1, cores))


def node_work(figures: dict, alone: dict[str, float]) -> dict[str, tuple[float, float, float]]:
    """Per compute node: (wall, CPU) ms its worker spent per frame in the graph and the same
    work alone. detector: the CNN on a converted image; stereo_depth: a pair's conversion and
    disparity map (its odometry then runs in another thread), alone: the disparity map. CPU
    counts the worker thread only (OpenCV's own threads are not in it)."""
    det = alone_ms(alone, "detect")
    disp = alone_ms(alone, "disparity (")
    out = {}
    for node, label, ref in (
        (graph.DETECTOR.name, "detect", det),
        (graph.STEREO.name, "stereo pair", disp),
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


def main(argv=None) -> int:
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
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NODE.PARAM:=VALUE")
    parser.add_argument("--json", help="write the figures to this file")
    parser.add_argument("--no-offline", action="store_true", help="skip the per-stage baseline")
    parser.add_argument(
        "--profile",
        action="store_true",
        help="py-spy every node process in the 10 Hz runs and print where its CPU time goes",
    )
    args = parser.parse_args(argv)
    apply_graph_environment()
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
    windows = [int(w) for w in args.windows.split(",") if w]
    modes = ([] if args.no_realtime else [("realtime", False, 1)]) + [
        (f"lockstep {w}", True, w) for w in windows
    ]
    offline: dict[str, dict[str, float]] = {}  # per dataset label
    if not args.no_offline:
        for label, root, seq in datasets:
            print(f"[bench] offline stage times, {label} ...", file=sys.stderr, flush=True)
            offline[label] = offline_stage_times(root, seq, overrides=args.param)
    rows, stamp, profiles = [], time.strftime("%Y%m%d_%H%M%S"), []
    for label, root, seq in datasets:
        for mode, lockstep, window in modes:
            logs = OUT / "runs" / stamp / f"{label.replace(' ', '_')}_{mode.replace(' ', '')}"
            print(f"[bench] {label}, {mode} ...", file=sys.stderr, flush=True)
            prof = logs / "profile" if args.profile and not lockstep else None
            figures = run_case(root, seq, lockstep, window, args.param, logs, prof)
            rows.append((label, mode, figures))
            if prof is not None:
                profiles.append((label, mode, prof))
    load = Path("/proc/loadavg").read_text().split()[:3]
    print(f"machine: {os.cpu_count()} CPUs, load average {' '.join(load)} (1/5/15 min)")
    if args.param:
        print("parameters: " + " ".join(args.param))
    for label, times in offline.items():
        print(
            f"each stage alone, {label} (median ms over {times.get('frames', 0):.0f} frames): "
            + ", ".join(f"{k} {v:.1f}" for k, v in times.items() if k != "frames")
        )
    print(_table(rows))
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
    for data, mode, folder in profiles:
        print(f"where each process's CPU time goes ({data}, {mode}; py-spy, {folder}):")
        print(profile_summary(folder))
    if args.json:
        out = {"offline_ms": offline, "load": load, "parameters": args.param}
        out["runs"] = [{"data": d, "mode": m, **f} for d, m, f in rows]
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
