"""Start-up: the time from ``stereo_tracking_launch`` to the first tracks, and the time to
restart one node, against another checkout (today's tree) in the same run.

Usage: python bench/bench_startup.py --baseline ../base [--runs 4] [--kitti-root ROOT]
       [--sequence 0005] [--restart vehicle_detector,stereo_depth,vehicle_tracker]
       [--cold-runs 1] [--no-launch] [--json FILE]

Both trees run alternately (baseline, this tree, baseline, ...), ``--runs`` times each, after
one warm-up run of each that is not counted (files and compiled modules in the OS cache, the
detector's ONNX cache filled). ``--baseline`` is the path of the other checkout (with its own
``.venv``, ``make setup`` done); each tree runs its own console scripts and parameter file.

- **launch**: ``<tree>/.venv/bin/stereo_tracking_launch`` on a KITTI tracking sequence (real
  0005 by default, ../shared/kitti), the parameter file's graph (player in lockstep, CNN
  detector, stereo depth, tracker, recorder), no camera settings given. Times from the moment
  the launcher process is started: ``ready`` (the launcher prints "graph ready"), ``playing``
  (the player logs that every edge is matched and publishes frame 0), ``first tracks`` (the
  tracker publishes the first ``/vehicles/tracks``: its trace point ``tracks_published``,
  ``VEHICLE_TRACE_DIR``, on the machine's monotonic clock). The launcher is then stopped
  (SIGINT); ``CPU s`` is the CPU time of all its processes from start to exit.
- **restart**: one node's process started alone while this process feeds it its inputs at
  10 Hz (KITTI frame 0: the left image and CameraInfo for the detector; both images, both
  CameraInfos and an empty 2D array for stereo depth; an empty 3D array and the CameraInfo
  for the tracker): the time from its start to its first output message here (what a graph
  waits when that node restarts: imports, model, DDS discovery, first frame).
- ``--cold-runs K``: K more launches of this tree with an empty detector cache (its first
  start on a machine: the ONNX graph is built and cached).

Prints, per figure, the median and range of each tree and the ratio this / baseline of the
medians, with the load average before and after (the machine may be shared: run it under
``flock -x /tmp/cpu.lock`` on a shared machine). Needs ROS_DOMAIN_ID set to a free domain.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REAL_ROOT = REPO.parent / "shared" / "kitti" / "tracking" / "training"
RESTARTABLE = ("vehicle_detector", "stereo_depth", "vehicle_tracker")
PARAMS = Path("src/tracking_bringup/config/pipeline.params.yaml")


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def _ros_time(line: str) -> float | None:
    """The wall-clock time of a ROS log line ``[INFO] [1795783198.379646366] [node]: ...``."""
    try:
        return float(line.split("] [", 1)[1].split("]", 1)[0])
    except (IndexError, ValueError):
        return None


def _log_time(path: Path, text: str) -> float | None:
    if not path.is_file():
        return None
    for line in path.read_text(errors="replace").splitlines():
        if text in line:
            return _ros_time(line)
    return None


def _first_trace(folder: Path, event: str) -> int | None:
    """Monotonic ns of the earliest ``event`` in the trace files of ``folder``."""
    times = []
    for path in folder.glob("*.trace"):
        for line in path.read_text(errors="replace").splitlines():
            parts = line.split()
            if len(parts) == 4 and parts[0] == event:
                times.append(int(parts[2]))
    return min(times) if times else None


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def launch_once(tree: Path, root: Path, sequence: str, work: Path, env: dict) -> dict:
    """One ``stereo_tracking_launch`` of ``tree``: seconds to ready, playing, first tracks."""
    trace, logs = work / "trace", work / "logs"
    trace.mkdir(parents=True)
    cmd = [
        str(tree / ".venv" / "bin" / "stereo_tracking_launch"),
        "--log-dir",
        str(logs),
        "-p",
        f"kitti_player.dataset_root:={root}",
        "-p",
        f"kitti_player.sequence:='{sequence}'",
        "-p",
        f"bag_recorder.output:={work / 'bag'}",
    ]
    cpu0 = _children_cpu()
    wall0, t0 = time.time(), time.monotonic_ns()
    proc = subprocess.Popen(
        cmd,
        cwd=tree,
        env={**env, "VEHICLE_TRACE_DIR": str(trace)},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    ready: list[float] = []

    def read() -> None:
        for line in proc.stdout:
            if line.startswith("graph ready") and not ready:
                ready.append((time.monotonic_ns() - t0) / 1e9)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    first = None
    deadline = time.monotonic() + 120
    while first is None and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
        first = _first_trace(trace, "tracks_published")
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)  # the launcher stops the graph cleanly
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    reader.join(timeout=5)
    first = first or _first_trace(trace, "tracks_published")
    playing = _log_time(logs / "kitti_player.log", "every edge of the graph matched")
    return {
        "ready_s": ready[0] if ready else None,
        "playing_s": None if playing is None else playing - wall0,
        "first_tracks_s": None if first is None else (first - t0) / 1e9,
        "cpu_s": _children_cpu() - cpu0,
    }


class Feeder:
    """Publishes a node's inputs at 10 Hz (KITTI frame 0, stamps advancing) and records when
    its first output arrives."""

    def __init__(self, root: Path, sequence: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import CameraInfo, Image
        from stereo_vehicle_msgs.msg import (
            TrackedVehicleArray,
            VehicleDetection2DArray,
            VehicleDetection3DArray,
        )
        from vehicle_common.frame_messages import stereo_camera_infos
        from vehicle_common.image_conversion import numpy_to_image
        from vehicle_common.kitti import TrackingSequence

        from tracking_bringup import graph

        seq = TrackingSequence.open(root, sequence)
        left, right = seq.read_stereo(seq.frame_ids[0])
        self.infos = stereo_camera_infos(seq.calib, left.shape[1], left.shape[0], 0)
        self.images = (
            numpy_to_image(left, "rgb8", self.infos[0].header),
            numpy_to_image(right, "rgb8", self.infos[1].header),
        )
        self.msgs = {
            "2d": VehicleDetection2DArray(),
            "3d": VehicleDetection3DArray(),
        }
        self.ctx = Context()
        rclpy.init(context=self.ctx, args=[])
        node = self.node = rclpy.create_node("bench_startup_feeder", context=self.ctx)
        pub = node.create_publisher
        self.pubs = {
            "left": pub(Image, graph.LEFT_IMAGE, 5),
            "right": pub(Image, graph.RIGHT_IMAGE, 5),
            "linfo": pub(CameraInfo, graph.LEFT_INFO, 5),
            "rinfo": pub(CameraInfo, graph.RIGHT_INFO, 5),
            "2d": pub(VehicleDetection2DArray, graph.DETECTIONS_2D, 10),
            "3d": pub(VehicleDetection3DArray, graph.DETECTIONS_3D, 10),
        }
        self.first: dict[str, int] = {}
        for key, (topic, kind) in {
            "vehicle_detector": (graph.DETECTIONS_2D, VehicleDetection2DArray),
            "stereo_depth": (graph.DETECTIONS_3D, VehicleDetection3DArray),
            "vehicle_tracker": (graph.TRACKS, TrackedVehicleArray),
        }.items():
            node.create_subscription(kind, topic, self._receiver(key), 10)
        self.feeding: str | None = None
        self.k = 0
        node.create_timer(0.1, self._tick)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _receiver(self, key: str):
        def got(_msg) -> None:
            if key == self.feeding and key not in self.first:
                self.first[key] = time.monotonic_ns()

        return got

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def _tick(self) -> None:
        """One frame of the inputs of the node being timed."""
        if self.feeding is None:
            return
        self.k += 1
        ns = 1_000_000_000 + self.k * 100_000_000
        for m in (*self.infos, *self.images, *self.msgs.values()):
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(ns, 1_000_000_000)
        p = self.pubs
        p["linfo"].publish(self.infos[0])
        if self.feeding == "vehicle_tracker":
            p["3d"].publish(self.msgs["3d"])
            return
        if self.feeding == "stereo_depth":
            p["rinfo"].publish(self.infos[1])
            p["right"].publish(self.images[1])
            p["2d"].publish(self.msgs["2d"])
        p["left"].publish(self.images[0])

    def restart_once(self, tree: Path, name: str, work: Path, env: dict) -> dict:
        """Start ``name`` of ``tree`` alone; seconds to its first output here."""
        self.first.pop(name, None)
        self.feeding = name
        cmd = [
            str(tree / ".venv" / "bin" / name),
            "--ros-args",
            "-r",
            f"__node:={name}",
            "--params-file",
            str(tree / PARAMS),
        ]
        work.mkdir(parents=True, exist_ok=True)
        cpu0 = _children_cpu()
        t0 = time.monotonic_ns()
        with open(work / f"{name}.log", "wb") as log:
            proc = subprocess.Popen(cmd, cwd=tree, env=env, stdout=log, stderr=subprocess.STDOUT)
            deadline = time.monotonic() + 120
            while name not in self.first and proc.poll() is None:
                if time.monotonic() > deadline:
                    break
                time.sleep(0.02)
            first = self.first.get(name)
            self.feeding = None
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return {
            "first_output_s": None if first is None else (first - t0) / 1e9,
            "cpu_s": _children_cpu() - cpu0,
        }

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        self.ctx.try_shutdown()


def _figures(run: dict) -> str:
    return json.dumps({k: round(v, 3) for k, v in run.items() if k.endswith("_s") and v})


def _summary(values: list) -> tuple[float | None, str]:
    vals = [v for v in values if v is not None]
    if not vals:
        return None, "-"
    med = statistics.median(vals)
    missing = len(values) - len(vals)
    text = f"{med:6.2f} ({min(vals):.2f}-{max(vals):.2f})"
    return med, text + (f" {missing} missing" if missing else "")


def print_table(title: str, rows: dict[str, dict[str, list]], trees: tuple[str, str]) -> None:
    base, new = trees
    print(f"\n{title}")
    print(f"  {'figure':<28} {base + ' median (range)':>26} {new + ' median (range)':>26} ratio")
    for figure, per_tree in rows.items():
        b, bt = _summary(per_tree.get(base, []))
        n, nt = _summary(per_tree.get(new, []))
        ratio = f"{n / b:5.2f}" if b and n is not None else "  -"
        print(f"  {figure:<28} {bt:>26} {nt:>26} {ratio}")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", required=True, type=Path, help="the other checkout")
    parser.add_argument("--runs", type=int, default=4, help="runs of each tree, alternated")
    parser.add_argument("--kitti-root", type=Path, default=REAL_ROOT)
    parser.add_argument("--sequence", default="0005")
    parser.add_argument(
        "--restart",
        default=",".join(RESTARTABLE),
        help="nodes whose restart is timed ('' = none)",
    )
    parser.add_argument("--cold-runs", type=int, default=1, help="launches with an empty cache")
    parser.add_argument("--no-launch", action="store_true", help="time the restarts only")
    parser.add_argument("--json", type=Path, help="write every run's figures here")
    return parser


def _problem(args, trees: dict[str, Path], restart: list[str]) -> str | None:
    """The one line for an unusable option or environment, else None."""
    if "ROS_DOMAIN_ID" not in os.environ:
        return "set ROS_DOMAIN_ID to a free domain"
    for tree in trees.values():
        if not (tree / ".venv" / "bin" / "stereo_tracking_launch").is_file():
            return f"{tree}: no .venv/bin/stereo_tracking_launch (make setup)"
    unknown = [n for n in restart if n not in RESTARTABLE]
    if unknown:
        return f"--restart: {', '.join(unknown)} not one of {RESTARTABLE}"
    if not (args.kitti_root / "image_02" / args.sequence).is_dir():
        return f"{args.kitti_root}: no sequence {args.sequence}"
    return None


def _time_launches(args, trees, order, work: Path, env) -> list[dict]:
    """The launches of each tree in ``order``, then ``--cold-runs`` with an empty cache."""
    runs = []
    for i, name in enumerate(order):
        r = launch_once(trees[name], args.kitti_root, args.sequence, work / f"l{i}", env)
        r.update(kind="launch", tree=name, warmup=i < len(trees))
        runs.append(r)
        print(f"  launch {name:<8} {_figures(r)}", flush=True)
    for i in range(args.cold_runs):
        cold_env = {**env, "VEHICLE_DETECTOR_CACHE": str(work / f"cache{i}")}
        r = launch_once(REPO, args.kitti_root, args.sequence, work / f"c{i}", cold_env)
        r.update(kind="launch", tree="this, empty cache", warmup=False)
        runs.append(r)
        print(f"  launch cold    {_figures(r)}", flush=True)
    return runs


def _time_restarts(args, trees, order, restart: list[str], work: Path, env) -> list[dict]:
    """Each node of ``restart`` restarted alone with its inputs fed, each tree in ``order``."""
    runs = []
    feeder = Feeder(args.kitti_root, args.sequence)
    try:
        time.sleep(1.0)  # the feeder's participant is discovered before the first start
        for i, name in enumerate(order):
            for node in restart:
                r = feeder.restart_once(trees[name], node, work / f"r{i}", env)
                r.update(kind=f"restart {node}", tree=name, warmup=i < len(trees))
                runs.append(r)
                print(f"  restart {name:<8} {node:<17} {r['first_output_s']}", flush=True)
    finally:
        feeder.close()
    return runs


def _print_tables(args, runs: list[dict], restart: list[str]) -> None:
    counted = [r for r in runs if not r["warmup"]]

    def column(kind: str, key: str) -> dict[str, list]:
        out: dict[str, list] = {}
        for r in counted:
            if r["kind"] == kind:
                out.setdefault(r["tree"], []).append(r[key])
        return out

    names = ("baseline", "this")
    if not args.no_launch:
        print_table(
            f"stereo_tracking_launch on {args.sequence} [s from the launcher's start]",
            {
                "graph ready (launcher)": column("launch", "ready_s"),
                "player plays frame 0": column("launch", "playing_s"),
                "first /vehicles/tracks": column("launch", "first_tracks_s"),
                "CPU s, all processes": column("launch", "cpu_s"),
            },
            names,
        )
        cold = column("launch", "first_tracks_s").get("this, empty cache", [])
        if cold:
            print(f"  first /vehicles/tracks with an empty detector cache: {_summary(cold)[1]}")
    if restart:
        print_table(
            "restart of one node, alone, inputs at 10 Hz [s from its start to its first output]",
            {f"{node}": column(f"restart {node}", "first_output_s") for node in restart}
            | {f"{node} CPU s": column(f"restart {node}", "cpu_s") for node in restart},
            names,
        )


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    trees = {"baseline": args.baseline.resolve(), "this": REPO}
    restart = [n for n in args.restart.split(",") if n]
    problem = _problem(args, trees, restart)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2

    from tracking_bringup.environment import apply_graph_environment, graph_environment

    apply_graph_environment()
    env = graph_environment()
    work = Path(tempfile.mkdtemp(prefix="bench_startup_"))
    order = [t for _ in range(args.runs + 1) for t in trees]  # the first pair: warm-up
    load0 = _load()
    print(
        f"bench_startup {datetime.now():%Y-%m-%d %H:%M}: baseline {trees['baseline']}, this "
        f"{REPO}; {args.runs} runs each alternated (+1 warm-up each); load average {load0}",
        flush=True,
    )
    runs: list[dict] = []
    if not args.no_launch:
        runs += _time_launches(args, trees, order, work, env)
    if restart:
        runs += _time_restarts(args, trees, order, restart, work, env)
    load1 = _load()
    _print_tables(args, runs, restart)
    print(f"\nload average before {load0}, after {load1} (2 cores: nproc {os.cpu_count()})")
    if args.json:
        args.json.write_text(
            json.dumps({"load_before": load0, "load_after": load1, "runs": runs}, indent=1)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
