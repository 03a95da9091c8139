"""CPU time of a graph's node processes from /proc (Linux), whole and per thread, and py-spy
profiles of them: what ``bench/bench_graph.py`` and ``bench/bench_tracker_node.py`` measure
with (no rclpy)."""

from __future__ import annotations

import os
import sys
from pathlib import Path


def cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system) of a process, NaN when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def thread_cpu_seconds(pid: int) -> dict[str, float]:
    """CPU seconds of a process's threads by name (``main``: the thread that runs the node's
    executor; the others by their kernel name, threads of one name summed)."""
    out: dict[str, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
            name = "main" if task.name == str(pid) else (task / "comm").read_text().strip()
        except OSError:
            continue
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


def start_profilers(pids: dict[str, int], out: Path, rate: int = 200) -> list:
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
    """Per node: thread-seconds sampled and the functions with the most self
    time (the innermost Python frame of each sample: time in a C extension such as OpenCV,
    ONNX Runtime or numpy is booked on the Python line that called it)."""
    lines = []
    for f in sorted(folder.glob("*.txt")):
        self_time: dict[str, int] = {}
        total = 0
        for row in f.read_text().splitlines():
            stack, _, count = row.rpartition(" ")
            if not stack or not count.isdigit():
                continue
            n = int(count)
            frames = stack.split(";")
            total += n
            thread = frames[0].startswith(("thread", "process"))
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


#: a camera run must skip at least this share of its frames, and both runs be at least this
#: many frames long, for :func:`camera_budget` to tell the work of every published frame from
#: that of a tracked one (the CPU clocks tick every 10 ms; a short lockstep run is mostly its
#: first, slow frames)
BUDGET_MIN_SKIPPED = 0.1
BUDGET_MIN_FRAMES = 50


def camera_budget(lockstep: dict, run: dict, camera_hz: float, camera: str) -> dict | None:
    """What a camera's frames cost the graph whether they are tracked or not, from a lockstep
    run (every frame tracked) and a run with the camera at ``camera_hz`` (figures as
    ``bench/bench_graph.py`` records them: ``published``, ``tracked``, ``throughput_fps``,
    ``cpu_s`` per process and ``thread_cpu_s`` per process and thread name); ``camera``: the
    process that plays the camera. Per published frame, tracked or not:

    - ``camera_ms``: the camera process's CPU (in the camera run);
    - ``receipt_ms``: the nodes' ``main`` threads (their executors, which take every message
      of every subscription): per node, lockstep gives ``a + b`` per frame and the camera run
      ``published a + tracked b``; ``a`` is summed over the nodes.

    Then ``tracked_ms``: the rest of lockstep's CPU per frame (every process), the work of a
    tracked frame; ``share``: the part of one CPU the per-published-frame work takes at
    ``camera_hz``; and for a graph on ONE CPU, ``one_cpu_frames``: the most frames it can
    track over lockstep's throughput, ``(1 - share) / (tracked_ms x lockstep fps)`` (a ceiling:
    reached only when a tracked frame costs no more than in lockstep), and
    ``one_cpu_latency``: ``1 / (1 - share)``, how much longer a frame's work takes while that
    share of the core serves the camera (a floor on the latency over lockstep's, before the
    frame's wait for the graph). None when the camera run skipped fewer than
    :data:`BUDGET_MIN_SKIPPED` of its frames (nothing to tell apart), a run is shorter than
    :data:`BUDGET_MIN_FRAMES` or a figure is missing."""
    published, tracked, frames = run["published"], run["tracked"], lockstep["published"]
    if min(published, frames) < BUDGET_MIN_FRAMES or published - tracked < (
        BUDGET_MIN_SKIPPED * published
    ):
        return None
    try:
        camera_s = run["cpu_s"][camera] / published
        receipt_s = 0.0
        for node, threads in lockstep["thread_cpu_s"].items():
            if node == camera:
                continue
            per_frame = threads["main"] / frames  # a + b
            receipt_s += (run["thread_cpu_s"][node]["main"] - tracked * per_frame) / (
                published - tracked
            )
        lockstep_s = sum(lockstep["cpu_s"].values()) / frames
    except (KeyError, TypeError):
        return None
    every_s = camera_s + receipt_s
    tracked_s = lockstep_s - every_s
    share = camera_hz * every_s
    fps = lockstep["throughput_fps"]
    ok = share < 1.0 and tracked_s > 0 and fps > 0
    return {
        "camera_ms": 1e3 * camera_s,
        "receipt_ms": 1e3 * receipt_s,
        "tracked_ms": 1e3 * tracked_s,
        "share": share,
        "one_cpu_frames": (1.0 - share) / (tracked_s * fps) if ok else float("nan"),
        "one_cpu_latency": 1.0 / (1.0 - share) if share < 1.0 else float("inf"),
    }
