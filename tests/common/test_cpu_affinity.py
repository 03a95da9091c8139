"""cpu_affinity: the taskset-style CPU lists every node takes, and the pinning of all threads
(the node test also checks ``nice``, applied beside it)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest
from vehicle_common.cpu_affinity import available_cpus, check_cpu_list, parse_cpu_list


def test_cpu_lists_parse_as_taskset_writes_them():
    assert parse_cpu_list("") == frozenset()
    assert parse_cpu_list("1") == {1}
    assert parse_cpu_list("0,2") == {0, 2}
    assert parse_cpu_list("1-3, 6") == {1, 2, 3, 6}
    for bad in ("a", "3-1", "-1", "1-", "0;1"):
        with pytest.raises(ValueError, match="not a CPU number or range"):
            parse_cpu_list(bad)


def test_a_cpu_the_process_cannot_use_is_named():
    far = max(available_cpus()) + 64
    with pytest.raises(ValueError, match=f"CPU {far} not available"):
        check_cpu_list(f"{min(available_cpus())},{far}")
    assert check_cpu_list(str(min(available_cpus()))) == {min(available_cpus())}


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux only")
def test_every_thread_is_moved_and_new_threads_inherit():
    """In a child process (pinning this one would slow the suite): threads started before and
    after the call all end up on the chosen CPU."""
    cpu = max(available_cpus())
    code = textwrap.dedent(
        f"""
        import os, threading, time
        from vehicle_common.cpu_affinity import pin_process
        ev = threading.Event()
        before = threading.Thread(target=ev.wait)
        before.start()
        moved = pin_process(frozenset({{{cpu}}}))
        after = threading.Thread(target=ev.wait)
        after.start()
        time.sleep(0.05)
        sets = {{t: sorted(os.sched_getaffinity(int(t))) for t in os.listdir('/proc/self/task')}}
        ev.set()
        print(moved, len(sets), sorted({{tuple(v) for v in sets.values()}}))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    ).stdout.split(maxsplit=2)
    assert int(out[0]) >= 2  # the main thread and the one started before
    assert int(out[1]) >= 3
    assert out[2].strip() == f"[({cpu},)]"


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux only")
def test_a_node_started_with_cpu_affinity_and_nice_runs_every_thread_so(tmp_path):
    """The tracker node with ``-p cpu_affinity:=N -p nice:=6`` (both applied by
    node_runtime.apply_process_settings): all its threads (the middleware's too) are on CPU N
    and at niceness 6 once it says so; it stops cleanly on SIGINT."""
    import signal
    import time

    cpu = max(available_cpus())
    proc = subprocess.Popen(
        [sys.executable, "-m", "tracker_node.node", "--ros-args"]
        + ["-p", f"cpu_affinity:={cpu}", "-p", "nice:=6"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "ROS_DOMAIN_ID": "177", "PYTHONUNBUFFERED": "1"},
        start_new_session=True,  # as the launchers start nodes (its own session group)
    )
    try:
        deadline = time.monotonic() + 60
        said = ""
        while "running at niceness" not in said and time.monotonic() < deadline:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, "node exited before applying its settings"
            said += line
        assert f"running on CPU {cpu}" in said
        assert "running at niceness 6" in said
        tasks = os.listdir(f"/proc/{proc.pid}/task")
        assert len(tasks) >= 2
        assert {frozenset(os.sched_getaffinity(int(t))) for t in tasks} == {frozenset({cpu})}
        assert {os.getpriority(os.PRIO_PROCESS, int(t)) for t in tasks} == {6}
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0


def test_library_threads_follow_the_cpus_the_process_may_use(monkeypatch):
    """More pool threads than CPUs only wait on each other (issue #39): the count asked for,
    at most the CPUs of the process's affinity, at least one."""
    from vehicle_common import cpu_affinity

    monkeypatch.setattr(cpu_affinity, "available_cpus", lambda: frozenset({3}))
    assert cpu_affinity.usable_threads(2) == 1
    monkeypatch.setattr(cpu_affinity, "available_cpus", lambda: frozenset(range(8)))
    assert cpu_affinity.usable_threads(2) == 2
    assert cpu_affinity.usable_threads(0) == 1
