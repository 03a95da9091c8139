"""CPU affinity of a node process: which cores its threads may run on (Linux).

On a small computer the graph's compute nodes compete for the same cores; giving each its own
(as a robot's deployment pins its real-time processes, ``taskset`` / cpusets) keeps one node's
work from stretching another's. The setting is the ``cpu_affinity`` parameter of every node of
the graph (:func:`vehicle_common.node_runtime.apply_process_settings`, the first step of each
node's construction), written as ``taskset -c`` writes CPU
lists: ``"1"``, ``"0,2"``, ``"0-3"``; empty = every CPU the process was started with (no
change). Every thread of the process is moved (the middleware's and the worker threads that
already exist); threads started later inherit it. No rclpy here.
"""

from __future__ import annotations

import os


def parse_cpu_list(text: str) -> frozenset[int]:
    """CPUs of a ``taskset -c`` style list (``"0"``, ``"0,2"``, ``"1-3,6"``; empty -> empty
    set); ValueError naming what is wrong."""
    cpus: set[int] = set()
    for part in str(text).replace(" ", "").split(","):
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise ValueError(f"{part!r} is not a CPU number or range (e.g. '1' or '0-3')") from None
        if a < 0 or b < a:
            raise ValueError(f"{part!r} is not a CPU number or range (e.g. '1' or '0-3')")
        cpus.update(range(a, b + 1))
    return frozenset(cpus)


def available_cpus() -> frozenset[int]:
    """The CPUs this process may use now (all CPUs where affinity is not supported)."""
    if hasattr(os, "sched_getaffinity"):
        return frozenset(os.sched_getaffinity(0))
    return frozenset(range(os.cpu_count() or 1))


def usable_threads(requested: int) -> int:
    """A worker-thread count for a library's pool (ONNX Runtime, OpenCV, PyTorch):
    ``requested`` but at most the CPUs this process may use now (after ``cpu_affinity`` or
    ``taskset``), at least 1; more threads than CPUs only wait on each other."""
    return max(1, min(int(requested), len(available_cpus())))


def check_cpu_list(text: str) -> frozenset[int]:
    """The CPUs of ``text`` (empty: none requested), each one this process may use;
    ValueError naming the CPUs that are not."""
    cpus = parse_cpu_list(text)
    missing = sorted(cpus - available_cpus())
    if missing:
        have = ",".join(str(c) for c in sorted(available_cpus()))
        raise ValueError(
            f"CPU {','.join(str(c) for c in missing)} not available to this process "
            f"(it may use {have})"
        )
    return cpus


def thread_ids() -> list[int]:
    """The ids of this process's threads (0, the calling thread, where /proc is missing)."""
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def pin_process(cpus: frozenset[int]) -> int:
    """Move every thread of this process onto ``cpus`` (no-op when empty). Returns the number
    of threads moved; RuntimeError where the platform cannot set affinities."""
    if not cpus:
        return 0
    if not hasattr(os, "sched_setaffinity"):
        raise RuntimeError("CPU affinity is not supported on this platform")
    moved = 0
    for tid in thread_ids():
        try:
            os.sched_setaffinity(tid, cpus)
            moved += 1
        except ProcessLookupError:  # a thread that ended meanwhile
            continue
    return moved
