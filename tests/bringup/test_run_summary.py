"""The launcher's console never lets a run end silently with no tracks (issue #42 item 4):
the node and the cause its report carries are said, once per cause while the graph runs, and a
run that used no frame exits non-zero."""

from tracking_bringup.run_summary import EXIT_NOTHING_USED, RunSummary, usage_line
from vehicle_common.frame_accounting import FrameCounts
from vehicle_common.graph_readiness import NodeReport

SIZE = "left image is 1242x375 but its camera_info says 1280x720"


def _report(node, received, used, problem=""):
    return NodeReport(node, FrameCounts(received, received, 0), used=used, problem=problem)


def test_report_carries_used_and_problem_over_diagnostics():
    r = _report("stereo_depth", 48, 0, SIZE)
    back = NodeReport.from_values("/stereo_depth", r.values())
    assert back.used == 0 and back.problem == SIZE
    assert NodeReport.from_values("x", _report("x", 1, None).values()).used is None


def test_final_names_the_node_and_cause_and_fails():
    lines = []
    summary = RunSummary(lines.append)
    reports = {
        "vehicle_detector": _report("vehicle_detector", 48, 48),
        "stereo_depth": _report("stereo_depth", 48, 0, SIZE),
        "vehicle_tracker": _report("vehicle_tracker", 48, None),
    }
    assert summary.final(reports) == EXIT_NOTHING_USED
    assert lines == [f"error: the run tracked nothing: stereo_depth: 0 of 48 frames used: {SIZE}"]


def test_final_is_quiet_when_frames_were_used():
    lines = []
    reports = {"stereo_depth": _report("stereo_depth", 16, 15, "one right image lost")}
    assert RunSummary(lines.append).final(reports) == 0 and lines == []


def test_no_input_is_said():
    line = usage_line("vehicle_detector", _report("vehicle_detector", 0, 0))
    assert line.startswith("vehicle_detector: no input frame received")


def test_live_graph_says_it_once_per_cause_and_keeps_running():
    lines = []
    summary = RunSummary(lines.append, silent_s=5.0)
    for t in range(0, 30):
        summary.check({"stereo_depth": _report("stereo_depth", 10 * t, 0, SIZE)}, float(t))
    assert lines == [f"warning: stereo_depth: 0 of the last 50 frames used: {SIZE}"]
    cause = "unsupported image encoding 'bayer_rggb8'"
    for t in range(30, 40):
        summary.check({"stereo_depth": _report("stereo_depth", 10 * t, 0, cause)}, float(t))
    assert len(lines) == 2 and lines[1].endswith(cause)


def test_live_graph_with_no_input_and_a_qos_problem():
    lines = []
    summary = RunSummary(lines.append, silent_s=5.0)
    qos = "/stereo/left/image_rect: a publisher's QoS is incompatible (DURABILITY)"
    for t in range(0, 12):
        summary.check({"vehicle_detector": _report("vehicle_detector", 0, 0, qos)}, float(t))
    assert lines == [f"warning: vehicle_detector: no input frame received in 5 s: {qos}"]


def test_a_working_node_is_never_reported():
    lines = []
    summary = RunSummary(lines.append, silent_s=1.0)
    for t in range(0, 20):
        summary.check({"stereo_depth": _report("stereo_depth", t, t)}, float(t))
    assert lines == []


def test_frames_still_in_process_are_not_reported():
    """A slow node holding its first frame (a loaded machine) has used none yet: not said."""
    lines = []
    summary = RunSummary(lines.append, silent_s=5.0)
    for t in range(0, 20):
        report = NodeReport("stereo_depth", FrameCounts(1, 0, 0), used=0)
        summary.check({"stereo_depth": report}, float(t))
    assert lines == []


def test_one_superseded_frame_without_a_cause_is_not_a_fault():
    lines = []
    summary = RunSummary(lines.append, silent_s=5.0)
    for t in range(0, 20):
        report = NodeReport("vehicle_detector", FrameCounts(2, 1, 0), used=0)
        summary.check({"vehicle_detector": report}, float(t))
    assert lines == []
    for t in range(20, 40):
        report = NodeReport("vehicle_detector", FrameCounts(5, 4, 0), used=0)
        summary.check({"vehicle_detector": report}, float(t))
    assert lines == ["warning: vehicle_detector: 0 of the last 3 frames used"]
