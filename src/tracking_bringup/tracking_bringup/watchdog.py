"""The launcher's half of the watchdog: a node that stops making progress while the graph runs
ends the run naming it. :class:`vehicle_common.graph_readiness.ProgressWatch` judges its
/diagnostics reports (none for ``stall_timeout`` s, or a frame in process without progress);
:class:`ProcessWatchdog` adds what /proc says of its process: stopped (state T: SIGSTOP, a
debugger) for as long is a stall too, since the launcher's DDS participant sometimes never
receives one node's reports (the other nodes do: seen in 3 of 16 runs here, and once in CI),
which left a stopped node unnoticed; silent or busy but only waiting for a CPU
(:func:`starved_not_frozen`) is not, for up to ``STARVED_LIMIT`` times the limit.
"""

from __future__ import annotations

import collections
import os
from collections.abc import Mapping
from pathlib import Path

from vehicle_common.graph_readiness import NodeReport, ProgressWatch

#: a node silent on /diagnostics whose process waits for a CPU is given this many
#: ``stall_timeout`` before it counts as stalled all the same
STARVED_LIMIT = 6.0


class ProcessWatchdog:
    """Which running nodes stopped making progress: their reports (``progress``) and their
    processes' states and CPU use, sampled from /proc at every check."""

    def __init__(self, progress: ProgressWatch):
        self.progress = progress
        self.stopped_since: dict[str, float] = {}  # node -> when its process was seen stopped
        #: node -> recent (time, main thread state, main thread CPU s) samples of its process
        self.samples: dict[str, collections.deque] = {}
        #: node -> recent (time, "R" when one of its other threads was runnable else "S", CPU s
        #: of the whole process) samples, taken while it reports a frame in process
        self.worker_samples: dict[str, collections.deque] = {}

    def stalled(
        self, now: float, pids: Mapping[str, int], reports: Mapping[str, NodeReport]
    ) -> dict[str, str]:
        """Node -> why, for the nodes alive (``pids``: node -> process id) that stopped making
        progress; empty when none."""
        alive = list(pids)
        window = self.progress.timeout_s
        states = {}  # node -> its process's state letter (its main thread's, in /proc)
        for name in alive:
            sample = main_thread_sample(pids[name])
            if sample is not None:
                states[name] = sample[0]
                samples = self.samples.setdefault(name, collections.deque(maxlen=200))
                samples.append((now, *sample))
            report = reports.get(name)
            if report is not None and report.busy:  # its frame worker's threads, too
                sample = worker_threads_sample(pids[name])
                if sample is not None:
                    workers = self.worker_samples.setdefault(name, collections.deque(maxlen=200))
                    workers.append((now, *sample))
        stalled = self.progress.stalled(now, alive)
        for name, why in list(stalled.items()):
            silent = self.progress.silent_s(name, now)
            if (
                why.startswith("no report")
                and silent < STARVED_LIMIT * window
                and starved_not_frozen(self.samples.get(name, ()), now, window)
            ):
                del stalled[name]  # waiting for a CPU (a loaded machine, nice 10), not frozen
            elif (
                why.startswith("a frame in process")
                and self.progress.busy_s(name, now) < STARVED_LIMIT * window
                and starved_not_frozen(self.worker_samples.get(name, ()), now, window)
            ):
                # its frame's worker waits for a CPU: stereo_depth (nice 10) took over 5 s for
                # its first frame of real 0005 on a 2-core machine at load 30, and was killed
                del stalled[name]
        for name in alive:
            if states.get(name) in ("T", "t"):
                since = self.stopped_since.setdefault(name, now)
                if now - since >= self.progress.timeout_s and name not in stalled:
                    stalled[name] = f"its process has been stopped for {now - since:.1f} s"
            else:
                self.stopped_since.pop(name, None)
        return stalled


def main_thread_sample(pid: int) -> tuple[str, float] | None:
    """(state letter, CPU seconds) of a process's main thread (the executor's, which runs the
    report timer), from /proc (Linux); None when unreadable."""
    try:
        fields = Path(f"/proc/{pid}/task/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return fields[0], (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def worker_threads_sample(pid: int) -> tuple[str, float] | None:
    """("R" when a thread other than the main one is runnable, else "S"; CPU seconds of the
    whole process), from /proc (Linux); None when unreadable. A frame worker that computes is
    R (waiting for a CPU or on one), a deadlocked one sleeps."""
    try:
        runnable = False
        for task in Path(f"/proc/{pid}/task").iterdir():
            if task.name != str(pid):
                state = (task / "stat").read_text().rsplit(")", 1)[1].split()[0]
                runnable = runnable or state == "R"
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None
    return ("R" if runnable else "S"), cpu


def starved_not_frozen(samples, now: float, window: float) -> bool:
    """Whether a node silent on /diagnostics for ``window`` s is only short of CPU: its main
    thread was runnable (state R) at least once in that window and used under half a core
    (a stopped process is T, a deadlocked one sleeps, S, a callback spinning forever keeps its
    thread busy). Under two busy loops at nice 0 the graph's stereo_depth, at nice 10, went 5 s
    without a report while working, and the watchdog killed it (a fresh-clone suite run).
    ``samples``: (time, state, main-thread CPU s), oldest first."""
    recent = [s for s in samples if s[0] >= now - window]
    if len(recent) < 2:
        return False
    span = recent[-1][0] - recent[0][0]
    if span < 0.5 * window:
        return False
    runnable = any(state == "R" for _, state, _ in recent)
    cpu = recent[-1][2] - recent[0][2]
    return runnable and cpu < 0.5 * span


def process_state(pid: int) -> str:
    """``stopped (T)``, ``running (R)``, ... of a process, from /proc (Linux)."""
    names = {
        "R": "running",
        "S": "sleeping",
        "D": "in uninterruptible wait",
        "T": "stopped",
        "t": "stopped by a debugger",
    }
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return "state unknown"
    return f"{names.get(state, 'state')} ({state})"
