"""ProgressWatch: which node of a graph stopped making progress, from its /diagnostics reports
(every node reports at least once a second)."""

from vehicle_common.frame_accounting import FrameCounts
from vehicle_common.graph_readiness import NodeReport, ProgressWatch


def _report(name, received=0, published=0, busy=False):
    return NodeReport(name, FrameCounts(received, published, 0), busy)


def test_a_silent_node_is_named_once_the_others_keep_reporting():
    watch = ProgressWatch(timeout_s=5.0)
    for t in range(0, 20):  # the detector reports every second; stereo stops at t=3
        watch.seen("vehicle_detector", _report("vehicle_detector", t, t), float(t))
        if t <= 3:
            watch.seen("stereo_depth", _report("stereo_depth", t, t), float(t))
        stalled = watch.stalled(float(t))
        if t < 8:
            assert stalled == {}, t
        else:
            assert list(stalled) == ["stereo_depth"], t
            assert stalled["stereo_depth"].startswith(f"no report on /diagnostics for {t - 3}")
    # a node that is gone (exited) is not watched
    assert watch.stalled(19.0, names=["vehicle_detector"]) == {}
    watch.forget("stereo_depth")
    assert watch.stalled(19.0) == {}


def test_everyone_silent_is_the_watcher_cut_off_not_a_stall():
    watch = ProgressWatch(timeout_s=5.0)
    watch.seen("a", _report("a"), 0.0)
    watch.seen("b", _report("b"), 0.0)
    assert watch.stalled(30.0) == {}


def test_busy_without_progress_is_a_stall_busy_with_progress_is_not():
    watch = ProgressWatch(timeout_s=5.0)
    for t in range(0, 12):
        # the tracker works frame after frame; stereo holds one frame from t=2 on
        watch.seen("vehicle_tracker", _report("vehicle_tracker", t, t, busy=True), float(t))
        watch.seen("stereo_depth", _report("stereo_depth", 2, 1, busy=t >= 2), float(t))
        stalled = watch.stalled(float(t))
        assert ("stereo_depth" in stalled) == (t >= 7), (t, stalled)
        assert "vehicle_tracker" not in stalled
    assert "a frame in process for 9.0 s without progress" in stalled["stereo_depth"]
    assert watch.busy_s("stereo_depth", 11.0) == 9.0  # the same frame since t=2
    assert watch.busy_s("nobody", 11.0) == 0.0
    # idle (nothing in process) for a long time is no stall: the graph waits for frames
    idle = ProgressWatch(timeout_s=5.0)
    for t in range(0, 12):
        idle.seen("x", _report("x", 3, 3), float(t))
        idle.seen("y", _report("y", 3, 3), float(t))
    assert idle.stalled(11.0) == {}


def test_the_launcher_takes_only_its_own_processes_reports(tmp_path):
    """A stray process named like one of the graph's nodes on the same ROS domain (another
    graph, a node left over by an earlier run) keeps reporting: its reports must not keep the
    launcher's own frozen node of that name looking alive. Reports carry the process id; the
    launcher takes those of its children only (a CI run once waited 60 s for a frozen
    stereo_depth that a stray reporter of the same name hid)."""
    import subprocess
    import sys
    from types import SimpleNamespace

    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from tracking_bringup.launcher import GraphLauncher, ProcessSpec, _Running
    from vehicle_common.graph_readiness import REPORT_ID

    spec = ProcessSpec("stereo_depth", [sys.executable, "-c", "pass"])
    launcher = GraphLauncher([spec], tmp_path)
    proc = SimpleNamespace(pid=4242, poll=lambda: None)
    launcher.running["stereo_depth"] = _Running(spec, proc, tmp_path / "l", subprocess.DEVNULL)

    def message(pid):
        values = _report("stereo_depth", 7, 7).values()
        if pid is not None:
            values = [*values, ("pid", str(pid))]
        status = DiagnosticStatus(name="/stereo_depth", hardware_id=REPORT_ID)
        status.values = [KeyValue(key=k, value=v) for k, v in values]
        return DiagnosticArray(status=[status])

    launcher._on_reports(message(999_999))  # the stray one
    assert "stereo_depth" not in launcher.reports
    launcher._on_reports(message(4242))  # its own child
    assert launcher.reports["stereo_depth"].pid == 4242
    assert launcher.reports["stereo_depth"].counts.received == 7
    # a report without a pid (an older node) is still taken
    launcher.reports.clear()
    launcher._on_reports(message(None))
    assert launcher.reports["stereo_depth"].pid is None


def test_a_report_carries_its_process_id():
    report = NodeReport("n", FrameCounts(1, 1, 0), pid=123)
    assert NodeReport.from_values("/n", report.values()).pid == 123
    assert NodeReport.from_values("/n", _report("n").values()).pid is None
