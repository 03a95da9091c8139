"""nice: the niceness every node takes, set on all threads and on the session group it leads."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest
from vehicle_common.process_priority import autogroup_nice, check_nice

LINUX = sys.platform.startswith("linux") and hasattr(os, "setpriority")


def test_a_niceness_outside_the_range_is_named():
    assert check_nice(0) == 0 and check_nice(19) == 19 and check_nice(-20) == -20
    for bad in (20, -21, 100):
        with pytest.raises(ValueError, match=r"is not a niceness \(-20..19\)"):
            check_nice(bad)


def _child(code: str, new_session: bool) -> list[str]:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
        start_new_session=new_session,
    ).stdout.split()


CHILD = """
    import os, threading, time
    from vehicle_common.process_priority import autogroup_nice, set_process_nice
    ev = threading.Event()
    before = threading.Thread(target=ev.wait)
    before.start()
    done, group = set_process_nice(7)
    after = threading.Thread(target=ev.wait)
    after.start()
    time.sleep(0.05)
    tasks = os.listdir('/proc/self/task')  # counted while both threads still wait
    nice = {os.getpriority(os.PRIO_PROCESS, int(t)) for t in tasks}
    ev.set()
    print(done, len(tasks), sorted(nice), group, autogroup_nice())
"""


@pytest.mark.skipif(not LINUX, reason="Linux only")
def test_every_thread_gets_the_niceness_and_new_threads_inherit_it():
    """In a child that leads its own session (as the launchers start nodes): the threads
    started before and after the call are all at 7, and so is its session group where the
    kernel has session groups."""
    done, tasks, nice, group, autogroup = _child(CHILD, new_session=True)
    assert int(done) >= 2 and int(tasks) >= 3
    assert nice == "[7]"
    if os.path.exists("/proc/self/autogroup"):
        assert group == "True" and autogroup == "7"


@pytest.mark.skipif(not os.path.exists("/proc/self/autogroup"), reason="no session groups")
def test_a_process_inside_another_session_leaves_the_group_alone():
    """Started in the caller's session (a terminal's): its threads are set, the session's
    group (the caller's too) is not."""
    ours = autogroup_nice()
    done, _, nice, group, autogroup = _child(CHILD, new_session=False)
    assert int(done) >= 2 and nice == "[7]"
    assert group == "False" and autogroup == str(ours)
    assert autogroup_nice() == ours
