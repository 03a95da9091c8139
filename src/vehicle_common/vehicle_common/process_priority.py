"""Scheduling priority of a node process: its niceness, as ``nice -n`` gives it (Linux).

On a small computer the graph's compute nodes run at the same moment on the same cores. The
detector's one thread is the long serial step of a frame, while the matcher's work splits over
threads: when the stereo process yields to the detector, the 2D detections come out nearer the
detector's time alone (on real 0005: 41-44 ms after the image against 46-52) and the 3D ones a
little later (tracks 2-3 ms; docs/ARCHITECTURE.md). The setting is
the ``nice`` parameter of every node (:func:`vehicle_common.node_runtime.apply_process_settings`,
the first step of each node's construction): 0 = the priority the process was started with (no
change), 1..19 = lower, negative = higher (needs ``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` that
allows it).

Linux's niceness belongs to each thread: every thread of the process is set (the middleware's
and the worker threads that already exist); threads started later inherit it. Where the kernel
groups the CPU time by session (``/proc/sys/kernel/sched_autogroup_enabled`` = 1, the default
of desktop and many server kernels), a thread's niceness only orders it against the threads of
its own session, and the sessions share the CPU by the niceness of their group: a process that
leads its own session (as the project's launchers start every node) sets that group's
niceness too (``/proc/self/autogroup``). A process started inside a terminal's session leaves
the group alone (it would renice the shell and everything else started from it). No rclpy here.
"""

from __future__ import annotations

import os
from pathlib import Path

from .cpu_affinity import thread_ids

NICE_MIN, NICE_MAX = -20, 19
_AUTOGROUP = Path("/proc/self/autogroup")


def check_nice(value: int) -> int:
    """``value`` as a niceness; ValueError naming the range when it is outside -20..19."""
    n = int(value)
    if not NICE_MIN <= n <= NICE_MAX:
        raise ValueError(f"{n} is not a niceness ({NICE_MIN}..{NICE_MAX})")
    return n


def leads_own_session() -> bool:
    """True when this process leads its session (started with setsid / start_new_session)."""
    return hasattr(os, "getsid") and os.getsid(0) == os.getpid()


def set_process_nice(nice: int) -> tuple[int, bool]:
    """Give every thread of this process the niceness ``nice`` (0: no change) and, when the
    process leads its own session under the kernel's session groups, that group too. Returns
    (threads set, whether the session group was set). PermissionError with a message saying
    why when the priority would be raised without the right to; RuntimeError where the platform
    has no per-thread priorities."""
    nice = check_nice(nice)
    if nice == 0:
        return 0, False
    if not hasattr(os, "setpriority"):
        raise RuntimeError("process priorities are not supported on this platform")
    done = 0
    for tid in thread_ids():
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
            done += 1
        except ProcessLookupError:  # a thread that ended meanwhile
            continue
        except PermissionError:
            raise PermissionError(
                f"niceness {nice} is a higher priority than this process may take "
                f"(now {os.getpriority(os.PRIO_PROCESS, 0)}; needs CAP_SYS_NICE or RLIMIT_NICE)"
            ) from None
    group = False
    if leads_own_session() and _AUTOGROUP.exists():
        try:
            _AUTOGROUP.write_text(str(nice))
            group = True
        except OSError:  # no right to raise the group's priority: the threads are set
            group = False
    return done, group


def autogroup_nice() -> int | None:
    """The niceness of this process's session group (None without session groups)."""
    try:
        text = _AUTOGROUP.read_text()
    except OSError:
        return None
    _, _, value = text.strip().rpartition("nice ")
    return int(value) if value.lstrip("-").isdigit() else None
