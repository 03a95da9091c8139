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
