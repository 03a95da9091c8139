"""The launcher's half of the watchdog (tracking_bringup.watchdog): a node's process state and
CPU use from /proc, and which nodes stopped making progress. The launcher's use of it (a stopped
process ends the run) is in test_launcher.py."""

import collections
import os
import signal
import subprocess
import sys
import time

from tracking_bringup.watchdog import (
    ProcessWatchdog,
    main_thread_sample,
    process_state,
    starved_not_frozen,
    worker_threads_sample,
)
from vehicle_common.frame_accounting import FrameCounts
from vehicle_common.graph_readiness import NodeReport, ProgressWatch


def test_a_silent_node_short_of_cpu_is_not_a_stall_a_frozen_or_spinning_one_is():
    """The watchdog's excuse for a node silent on /diagnostics: its main thread was runnable (R)
    and used under half a core (a fresh-clone suite beside two busy loops once had the graph's
    stereo_depth, at nice 10, killed while it worked: no report for 5.1 s, process running)."""

    def samples(states, cpu_per_s):
        return [(t * 0.2, states[t % len(states)], t * 0.2 * cpu_per_s) for t in range(26)]

    now, window = 5.0, 5.0
    assert starved_not_frozen(samples("RSRS", 0.05), now, window)  # waits for a CPU, works
    assert starved_not_frozen(samples("SSSSR", 0.01), now, window)
    assert not starved_not_frozen(samples("T", 0.0), now, window)  # SIGSTOP
    assert not starved_not_frozen(samples("S", 0.001), now, window)  # deadlocked
    assert not starved_not_frozen(samples("R", 0.98), now, window)  # a callback spinning
    assert not starved_not_frozen(samples("R", 0.05)[:3], now, window)  # too few samples
    assert not starved_not_frozen([], now, window)


def test_a_frame_worker_short_of_cpu_is_seen_runnable_a_deadlocked_one_is_not():
    """The excuse for a node with a frame in process and no progress uses its other threads:
    a worker computing is runnable (R), one blocked on a lock sleeps; the whole process's CPU
    is counted (stereo_depth, nice 10, took over 5 s for its first frame at load 30 and was
    killed as frozen)."""
    code = (
        "import threading, time\n"
        "def spin():\n    while True: pass\n"
        "def block():\n    threading.Lock().acquire(); lock = threading.Lock(); lock.acquire();"
        " lock.acquire()\n"
        "threading.Thread(target={}, daemon=True).start(); time.sleep(60)\n"
    )
    spinning = subprocess.Popen([sys.executable, "-c", code.format("spin")])
    blocked = subprocess.Popen([sys.executable, "-c", code.format("block")])
    try:
        for proc in (spinning, blocked):  # started (slow on a loaded machine)
            deadline = time.monotonic() + 30
            while len(os.listdir(f"/proc/{proc.pid}/task")) < 2 and time.monotonic() < deadline:
                time.sleep(0.05)
        time.sleep(0.2)
        seen = [worker_threads_sample(spinning.pid)[0] for _ in range(20)]
        assert "R" in seen
        states = {worker_threads_sample(blocked.pid)[0] for _ in range(20)}
        assert states == {"S"}
        assert worker_threads_sample(spinning.pid)[1] > 0.0
    finally:
        for proc in (spinning, blocked):
            proc.kill()
            proc.wait(10)
    assert worker_threads_sample(spinning.pid) is None  # gone


def _sleeper() -> subprocess.Popen:
    """A child process that sleeps, returned once it does: a child sampled right after its
    start may still be reading its interpreter's modules from disk (state D: a fresh-clone
    suite once failed here), which is neither what these tests look at nor a stop."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "import time; print('ready', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().strip() == "ready"
    proc.stdout.close()
    deadline = time.monotonic() + 10
    while (main_thread_sample(proc.pid) or ("?",))[0] != "S" and time.monotonic() < deadline:
        time.sleep(0.01)
    return proc


def _report(name, received=0, published=0, busy=False):
    return NodeReport(name, FrameCounts(received, published, 0), busy)


def test_a_stopped_process_is_named_with_its_state_a_running_one_is_not():
    """ProcessWatchdog: a node whose process is stopped (state T) for ``timeout_s`` is stalled
    even while its reports look fresh; once it runs again its count starts afresh."""
    sleeper = _sleeper()
    try:
        watch = ProcessWatchdog(ProgressWatch(timeout_s=1.0))
        pids = {"sleeper": sleeper.pid}
        assert main_thread_sample(sleeper.pid)[0] in ("S", "R")
        assert process_state(sleeper.pid) in ("sleeping (S)", "running (R)")
        for t in (0.0, 0.5, 2.0):
            watch.progress.seen("sleeper", _report("sleeper"), t)
            assert watch.stalled(t, pids, {}) == {}
        os.kill(sleeper.pid, signal.SIGSTOP)
        deadline = time.monotonic() + 10
        while main_thread_sample(sleeper.pid)[0] != "T" and time.monotonic() < deadline:
            time.sleep(0.02)
        assert process_state(sleeper.pid) == "stopped (T)"
        watch.progress.seen("sleeper", _report("sleeper"), 3.0)
        assert watch.stalled(3.0, pids, {}) == {}  # stopped, not for long yet
        watch.progress.seen("sleeper", _report("sleeper"), 4.0)
        why = watch.stalled(4.5, pids, {})["sleeper"]
        assert why == "its process has been stopped for 1.5 s"
        os.kill(sleeper.pid, signal.SIGCONT)
        deadline = time.monotonic() + 10
        while main_thread_sample(sleeper.pid)[0] == "T" and time.monotonic() < deadline:
            time.sleep(0.02)
        watch.progress.seen("sleeper", _report("sleeper"), 5.0)
        assert watch.stalled(5.0, pids, {}) == {}
        assert "sleeper" not in watch.stopped_since
        assert isinstance(watch.samples["sleeper"], collections.deque)
    finally:
        sleeper.kill()
        sleeper.wait(10)
    assert main_thread_sample(sleeper.pid) is None
    assert process_state(sleeper.pid) == "state unknown"


def test_a_silent_node_whose_process_sleeps_is_stalled():
    """Silent on /diagnostics while another node reports and its process sleeps (a deadlock):
    no excuse of a CPU shortage, the watchdog names it."""
    sleeper = _sleeper()
    try:
        watch = ProcessWatchdog(ProgressWatch(timeout_s=1.0))
        pids = {"sleeper": sleeper.pid}
        watch.progress.seen("sleeper", _report("sleeper"), 0.0)
        stalled = {}
        for step in range(1, 31):
            t = step * 0.1
            watch.progress.seen("other", _report("other", step, step), t)
            stalled = watch.stalled(t, pids, {})
            time.sleep(0.01)
        assert stalled["sleeper"].startswith("no report on /diagnostics for")
    finally:
        sleeper.kill()
        sleeper.wait(10)
