"""CPU per frame of the tracker node and the bag recorder on a recorded graph run, A/B.

    python bench/bench_tracker_node.py RUN/bag [--old-tree PATH] [--repeats 5] [--frames N]

Replays a recorded graph run (``make demo`` / ``bench_graph.py``'s ``bag``) to two processes
started as the graph starts them (``vehicle_tracker`` and ``bag_recorder``, the shipped
parameter file): this process publishes every recorded message except the tracker's outputs
(the player's, the detector's, the stereo node's) in their recorded order, in lockstep (after
each 3D detection array it waits for the tracks of that stamp), and the recorder records the
13 topics of the graph as in a demo (the tracks, markers and vision tracks the tracker
publishes now included). Each process's CPU (``/proc``, all threads, and per thread) is read
once both are ready and again once the last frame's tracks are in and the recorder has taken
every message; divided by the frames. Startup is outside.

``--old-tree PATH`` (a checkout, e.g. ``git worktree add /tmp/base main``) runs the same with
that tree's ``src`` packages, alternated with this tree's (``--repeats`` pairs), and prints the
medians and the ratios new / old; the tracks, markers and vision tracks of every run are
compared field by field, every bit (``vehicle_common.frame_messages.field_bits``), and any
difference is printed (exit code 1).``--profile``: py-spy samples both processes in
the last run (the functions their CPU goes to); ``BENCH_CPROFILE_DIR=DIR`` in the environment
runs both under cProfile (wall time) into DIR.
Timing is only comparable within one run: other work on the machine moves both; the load
average is printed with it.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tracking_bringup.environment import PARAMS_FILE as PARAMS

from vehicle_common import topics

REPO = Path(__file__).resolve().parent.parent
TRACKER_OUT = tuple(
    topics.resolve(t) for t in (topics.TRACKS, topics.TRACK_MARKERS, topics.VISION_TRACKS)
)
DETECTIONS = topics.resolve(topics.DETECTIONS_3D)
LEFT_INFO = topics.resolve(topics.LEFT_INFO)


def read_inputs(bag: Path, frames: int = 0) -> list[tuple[str, str, bytes]]:
    """(topic, type, CDR bytes) of the recorded messages the graph's other nodes published,
    in recorded order (up to the ``frames``-th 3D detection array when > 0)."""
    from vehicle_common.bags.reader import bag_messages, open_reader

    out, count = [], 0
    reader = open_reader(bag)
    try:
        conns = [c for c in reader.connections if c.topic not in TRACKER_OUT]
        for conn, _, raw in bag_messages(reader, bag, conns):
            if conn.topic == DETECTIONS:
                if frames and count == frames:
                    break
                count += 1
            out.append((conn.topic, conn.msgtype, bytes(raw)))
    finally:
        reader.close()
    return out


def proc_cpu(pid: int) -> dict[str, float]:
    """CPU seconds of a process: ``total`` and per thread name (``main``: the executor's)."""
    from tracking_bringup.process_cpu import thread_cpu_seconds

    threads = thread_cpu_seconds(pid)
    return {"total": sum(threads.values()), **threads}


def _env(tree: Path) -> dict[str, str]:
    env = dict(os.environ)
    src = sorted(str(p) for p in (tree / "src").iterdir() if p.is_dir())
    env["PYTHONPATH"] = os.pathsep.join(src + [env.get("PYTHONPATH", "")])
    env.pop("VEHICLE_TRACE_DIR", None)
    return env


def _start(tree: Path, module: str, name: str, extra: list[str], log: Path) -> subprocess.Popen:
    prof = os.environ.get("BENCH_CPROFILE_DIR")  # a cProfile of each node process, for study
    launch = ["-m", "cProfile", "-o", f"{prof}/{name}.prof"] if prof else []
    launch += ["-m", module]
    cmd = [sys.executable, *launch, "--ros-args", "-r", f"__node:={name}"]
    cmd += ["--params-file", str(PARAMS)] + extra
    return subprocess.Popen(
        cmd, env=_env(tree), stdout=log.open("w"), stderr=subprocess.STDOUT, start_new_session=True
    )


def run_once(tree: Path, inputs, workdir: Path, profile: bool = False) -> dict:
    """One replay with ``tree``'s nodes: CPU per frame of each process and the digests of
    the tracker's outputs as the recorder recorded them."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from stereo_vehicle_msgs.msg import TrackedVehicleArray, VehicleDetection3DArray
    from vehicle_common.bags.replay import message_class

    bag = workdir / "bag"
    tracker = _start(tree, "tracker_node.node", "vehicle_tracker", [], workdir / "tracker.log")
    recorder = _start(
        tree,
        "eval_node.recorder",
        "bag_recorder",
        ["-p", f"output:={bag}"],
        workdir / "recorder.log",
    )
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("bench_tracker_feed", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        pubs = {}
        for topic, msgtype, _ in inputs:
            if topic in pubs:
                continue
            latched = topic == "/tf_static"
            qos = QoSProfile(
                depth=100,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=(
                    DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
                ),
            )
            pubs[topic] = node.create_publisher(message_class(msgtype), topic, qos)
        got: list[int] = []

        def on_tracks(msg) -> None:
            got.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)

        node.create_subscription(TrackedVehicleArray, TRACKER_OUT[0], on_tracks, 100)

        def spin_until(cond, timeout=30.0) -> bool:
            end = time.monotonic() + timeout
            while not cond() and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.01)
            return cond()

        # ready: the tracker subscribes to the 3D arrays and the recorder to every topic
        ready = spin_until(
            lambda: (
                all(p.get_subscription_count() >= 1 for p in pubs.values())
                and pubs[DETECTIONS].get_subscription_count() >= 2
                and pubs[LEFT_INFO].get_subscription_count() >= 2
                and node.count_publishers(TRACKER_OUT[0]) >= 1
                and node.count_subscribers(TRACKER_OUT[0]) >= 2
            ),
            60.0,
        )
        if not ready:
            raise RuntimeError(f"nodes not ready, see {workdir}")
        time.sleep(1.0)  # discovery traffic settles
        profilers = []
        if profile:  # py-spy on both processes (on-CPU samples), outside the timed replay
            from tracking_bringup.process_cpu import start_profilers

            pids = {"vehicle_tracker": tracker.pid, "bag_recorder": recorder.pid}
            profilers = start_profilers(pids, workdir / "profile")
            time.sleep(1.0)
        cpu0 = {"tracker": proc_cpu(tracker.pid), "recorder": proc_cpu(recorder.pid)}
        t0 = time.monotonic()
        frames = 0
        for topic, _, raw in inputs:
            pubs[topic].publish(raw)
            if topic == DETECTIONS:
                frames += 1
                msg = deserialize_message(raw, VehicleDetection3DArray)
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                if not spin_until(lambda s=stamp: s in got):
                    raise RuntimeError(f"no tracks for frame {frames}, see {workdir}")
        wall = time.monotonic() - t0
        time.sleep(0.5)  # the recorder takes what is queued
        cpu1 = {"tracker": proc_cpu(tracker.pid), "recorder": proc_cpu(recorder.pid)}
    finally:
        executor.shutdown()
        node.destroy_node()
        ctx.try_shutdown()
        for proc in (tracker, recorder):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        for proc in (tracker, recorder):
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
    out = {"frames": frames, "wall_s": wall}
    for name in cpu0:
        out[name] = {
            k: 1e3 * (cpu1[name].get(k, 0.0) - cpu0[name].get(k, 0.0)) / frames for k in cpu1[name]
        }
    for proc in profilers:
        proc.wait(timeout=30)
    out["digests"] = recorded_digests(bag)
    return out


def recorded_digests(bag: Path) -> dict[str, str]:
    """sha256 of every field of each tracker output topic's messages, in recorded order."""
    from rclpy.serialization import deserialize_message
    from vehicle_common.bags.reader import bag_messages, open_reader
    from vehicle_common.bags.replay import message_class
    from vehicle_common.frame_messages import field_bits

    hashes = {t: hashlib.sha256() for t in TRACKER_OUT}
    counts = dict.fromkeys(TRACKER_OUT, 0)
    reader = open_reader(bag)
    try:
        conns = [c for c in reader.connections if c.topic in hashes]
        for conn, _, raw in bag_messages(reader, bag, conns):
            msg = deserialize_message(bytes(raw), message_class(conn.msgtype))
            hashes[conn.topic].update(field_bits(msg))
            counts[conn.topic] += 1
    finally:
        reader.close()
    return {t: f"{counts[t]} messages, sha256 {h.hexdigest()[:16]}" for t, h in hashes.items()}


def _median(runs: list[dict], proc: str, key: str) -> float:
    return statistics.median(r[proc].get(key, 0.0) for r in runs)


def report(results: dict[str, list[dict]]) -> list[str]:
    """Median CPU per frame of each process (total and its main thread), per tree, and the
    ratio new / old when both ran."""
    lines = []
    for proc in ("tracker", "recorder"):
        for key in ("total", "main"):
            row = [f"{proc} {key}:"]
            for tree, runs in results.items():
                vals = ", ".join(f"{r[proc].get(key, 0.0):.2f}" for r in runs)
                row.append(f"{tree} {_median(runs, proc, key):.2f} ms/frame ({vals})")
            if len(results) == 2:
                old, new = (_median(r, proc, key) for r in results.values())
                row.append(f"new/old {new / old:.2f}" if old > 0 else "")
            lines.append("  ".join(row))
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bag", type=Path, help="a recorded graph run's bag")
    ap.add_argument("--old-tree", type=Path, help="a checkout to compare with (A/B)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--frames", type=int, default=0, help="first N frames only (0: all)")
    ap.add_argument("--profile", action="store_true", help="py-spy both nodes (last run)")
    ap.add_argument("--keep", type=Path, help="keep each run's bag and logs in this folder")
    args = ap.parse_args(argv)
    inputs = read_inputs(args.bag, args.frames)
    trees = {"new": REPO}
    if args.old_tree:
        trees = {"old": args.old_tree.resolve(), "new": REPO}
    results: dict[str, list[dict]] = {name: [] for name in trees}
    with tempfile.TemporaryDirectory(prefix="bench_tracker_node_") as tmp:
        tmp = args.keep or tmp
        for k in range(args.repeats):
            for name, tree in trees.items():
                work = Path(tmp) / f"{name}{k}"
                work.mkdir(parents=True)
                last = k == args.repeats - 1
                res = run_once(tree, inputs, work, args.profile and last)
                if args.profile and last:
                    from tracking_bringup.process_cpu import profile_summary

                    print(profile_summary(work / "profile", top=25))
                results[name].append(res)
                print(
                    f"{name} #{k}: tracker {res['tracker']['total']:.2f} ms/frame (main "
                    f"{res['tracker'].get('main', 0):.2f}), recorder "
                    f"{res['recorder']['total']:.2f}, {res['frames']} frames in "
                    f"{res['wall_s']:.1f} s; load {Path('/proc/loadavg').read_text().strip()}",
                    flush=True,
                )
    for line in report(results):
        print(line)
    digests = {
        (name, k): r["digests"] for name, runs in results.items() for k, r in enumerate(runs)
    }
    first = next(iter(digests.values()))
    same = all(d == first for d in digests.values())
    for topic, digest in first.items():
        print(f"{topic}: {digest}")
    print("outputs identical in every run" if same else "OUTPUTS DIFFER between runs:")
    if not same:
        for key, d in digests.items():
            print(f"  {key}: {d}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
