"""Reliability of the whole graph as separate processes, on real KITTI 0005 (16 frames) with the
oracle detector (fast start-up): the frame in flight drained at Ctrl-C, no traceback on SIGTERM,
no frame lost silently (every edge ready before frame 0 when all nodes start at once:
test_namespaced_graph.py)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.launcher import GraphLauncher, graph_processes

from tests.ros_helpers import bag_counts
from tracking_bringup import graph

pytestmark = pytest.mark.slow

FRAMES_0005 = 16


def _overrides(root: Path, bag: Path, *extra: str) -> list[str]:
    return [
        f"kitti_player.dataset_root:={root}",
        "kitti_player.sequence:='0005'",
        "vehicle_detector.backend:=oracle",
        f"bag_recorder.output:={bag}",
        *extra,
    ]


def _wait_for(path: Path, text: str, timeout: float = 90.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.is_file() and text in path.read_text(errors="replace"):
            return
        time.sleep(0.1)
    raise AssertionError(f"{text!r} not in {path} after {timeout} s")


def test_sigint_drains_the_frame_in_flight(kitti_tracking_root, tmp_path):
    """Ctrl-C mid-run: the player stops first, the frame in flight reaches the tracker and the
    recorder, then the rest stops: the bag has as many tracks as ground-truth frames."""
    bag = tmp_path / "bag"
    logs = tmp_path / "logs"
    cmd = [str(Path(sys.executable).with_name("stereo_tracking_launch")), "--log-dir", str(logs)]
    # lockstep as fast as the graph goes, looping: there is always a frame in flight
    extra = (
        "kitti_player.lockstep:=true",
        "kitti_player.rate_multiplier:=0",
        "kitti_player.loop:=true",
    )
    for ov in _overrides(kitti_tracking_root, bag, *extra):
        cmd += ["-p", ov]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    ready = threading.Event()

    def read_output():  # the launcher's stdout, until it exits; "graph ready" sets the event
        for line in proc.stdout:
            lines.append(line)
            if "graph ready" in line:
                ready.set()

    reader = threading.Thread(target=read_output, daemon=True)
    reader.start()
    try:
        _wait_for(logs / "kitti_player.log", "every edge of the graph matched")
        # the launcher's own readiness, else a signal counts as Ctrl-C during start-up
        assert ready.wait(60), "".join(lines)
        time.sleep(1.5)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
        reader.join(10)
        output = "".join(lines)
    finally:
        proc.kill()
    assert proc.returncode == 0, output
    assert "frames still in flight" not in output
    counts = bag_counts(bag)
    inputs = counts.get(graph.GROUND_TRUTH, 0)
    assert inputs >= 1, counts
    for topic in (graph.DETECTIONS_2D, graph.DETECTIONS_3D, graph.TRACKS):
        assert counts.get(topic) == inputs, (topic, counts)


def test_sigterm_mid_stream_no_traceback_and_frames_accounted(kitti_tracking_root, tmp_path):
    """SIGTERM to the CNN detector and to stereo while frames stream in at camera rate: the
    callback in progress finishes, no RCLError traceback, exit code 0 and the exit line; every
    node's report accounts for every frame (in = out + dropped, nothing pending)."""
    bag = tmp_path / "bag"
    overrides = _overrides(
        kitti_tracking_root,
        bag,
        "kitti_player.lockstep:=false",
        "kitti_player.loop:=true",
        "vehicle_detector.backend:=cnn",
    )
    processes = graph_processes(graph.PIPELINE, PARAMS_FILE, overrides)
    launcher = GraphLauncher(processes, tmp_path / "logs", ready_timeout=120)
    with launcher:
        end = time.monotonic() + 60
        while time.monotonic() < end:
            launcher.spin_reports(0.2)
            stereo = launcher.reports.get(graph.STEREO.name)
            if stereo is not None and stereo.counts.received >= 5:
                break
        victims = {n: launcher.running[n] for n in (graph.DETECTOR.name, graph.STEREO.name)}
        for run in victims.values():
            run.proc.send_signal(signal.SIGTERM)
        codes = {n: run.proc.wait(timeout=30) for n, run in victims.items()}
        # their final reports (a slow detector drains its frame in hand and the one waiting
        # first, so the last report may come a few seconds after SIGTERM)
        end = time.monotonic() + 10
        launcher.spin_reports(1.0)
        while time.monotonic() < end and any(launcher.reports[n].counts.pending for n in victims):
            launcher.spin_reports(0.5)
        player = launcher.reports[graph.PLAYER.name].counts
    assert codes == {graph.DETECTOR.name: 0, graph.STEREO.name: 0}
    for name in victims:
        log = (tmp_path / "logs" / f"{name}.log").read_text()
        assert "Traceback" not in log and "RCLError" not in log, log[-2000:]
        assert "frames in " in log  # the exit line
    detector = launcher.reports[graph.DETECTOR.name].counts
    assert detector.received >= 5 and detector.pending == 0
    assert detector.published + detector.dropped == detector.received
    assert player.published >= detector.received


def _child_pid(parent: int, executable: str) -> int | None:
    """The pid of ``parent``'s child process running ``executable``."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            argv = (d / "cmdline").read_bytes().split(b"\0")
        except (OSError, IndexError, ValueError):
            continue
        if ppid == parent and any(
            Path(a.decode(errors="replace")).name == executable for a in argv
        ):
            return int(d.name)
    return None


def test_frozen_node_is_named_and_fails_the_run(kitti_tracking_root, tmp_path):
    """``kill -STOP`` of stereo_depth while frames flow: the launcher names it within seconds
    (its reports on /diagnostics stop while the other nodes' go on), kills it and exits 1; the
    rest of the graph stops cleanly and the bag is closed. (Before: the launcher ran on through
    lockstep timeouts, 147 s, then SIGKILLed it and exited 0 with 4 of 16 frames tracked.)"""
    bag = tmp_path / "bag"
    logs = tmp_path / "logs"
    cmd = [str(Path(sys.executable).with_name("stereo_tracking_launch")), "--log-dir", str(logs)]
    for ov in _overrides(kitti_tracking_root, bag, "kitti_player.loop:=true"):
        cmd += ["-p", ov]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    ready = threading.Event()

    def read_output():
        for line in proc.stdout:
            lines.append(line)
            if "graph ready" in line:
                ready.set()

    threading.Thread(target=read_output, daemon=True).start()
    stereo = None
    try:
        assert ready.wait(120), "".join(lines)
        _wait_for(logs / "kitti_player.log", "every edge of the graph matched")
        stereo = _child_pid(proc.pid, "stereo_depth")
        assert stereo is not None
        os.kill(stereo, signal.SIGSTOP)
        t0 = time.monotonic()
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            logs_now = {p.name: p.read_text(errors="replace")[-1500:] for p in logs.glob("*.log")}
            raise AssertionError(
                f"no exit 60 s after SIGSTOP:\n{''.join(lines)}\n{logs_now}"
            ) from None
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
        if stereo is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(stereo, signal.SIGKILL)
    output = "".join(lines)
    assert proc.returncode == 1, output
    # its reports stop reaching the launcher, or (when the launcher's DDS participant never got
    # them: it happens) its process is seen stopped
    assert "error: node 'stereo_depth' stopped making progress: " in output
    assert "stopped (T)" in output
    assert took < 30, (took, output)  # 5 s to notice, then the others stop cleanly
    assert not Path(f"/proc/{stereo}").exists() or "Z" in Path(f"/proc/{stereo}/stat").read_text()
    assert "unclean exit" not in output  # every other node stopped cleanly
    assert bag_counts(bag).get(graph.GROUND_TRUTH, 0) >= 1  # closed and readable


def _launch(root: Path, bag: Path, *args: str, cwd: Path, **popen) -> subprocess.Popen:
    cmd = [str(Path(sys.executable).with_name("stereo_tracking_launch")), *args]
    for ov in _overrides(root, bag):
        cmd += ["-p", ov]
    return subprocess.Popen(
        cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **popen
    )


def test_failed_start_then_a_rerun_with_the_same_output(kitti_tracking_root, tmp_path):
    """A misspelled player parameter: the player refuses it at start-up; the launcher prints
    the player's one line, with the closest valid name, and exits 2 (before: the parameter was
    ignored without a word, and a node that stopped at start-up made the launcher exit 1 where
    the README promises 2). The rerun, same output and
    the default log folder: the empty bag the failed start left is replaced (before: 'exists
    already'), each run has its own log folder, and nothing of the first run is in the second's
    logs (before: one folder, appended to). Every process starts at once, so whether the
    recorder opened the bag before the launcher stopped it is a race (the test failed about 1 run
    in 3 after the launcher tests): when it did not, the test leaves the bag a failed start
    leaves, the recorder's writer opened and closed with nothing recorded."""
    bag = tmp_path / "bag"
    first = _launch(kitti_tracking_root, bag, "-p", "kitti_player.lockstep_timout:=5", cwd=tmp_path)
    out = first.communicate(timeout=180)[0]
    assert first.returncode == 2, out
    assert out.strip().splitlines() == [
        "error: kitti_player: parameter lockstep_timout: unknown parameter of this node "
        "(did you mean lockstep_timeout?)"
    ]
    if not bag.is_dir():  # the recorder was stopped before it opened the bag
        from vehicle_common.bags.writer import BagWriter

        BagWriter(bag).close()
    assert bag.is_dir()  # an empty bag, as a failed start leaves it
    second = _launch(kitti_tracking_root, bag, cwd=tmp_path)
    out = second.communicate(timeout=180)[0]
    assert second.returncode == 0, out
    assert bag_counts(bag).get(graph.TRACKS) == FRAMES_0005
    runs = sorted((tmp_path / "output" / "logs").iterdir())
    assert len(runs) == 2, runs
    assert "lockstep_timout" in (runs[0] / "kitti_player.log").read_text()
    for log in runs[1].glob("*.log"):
        assert "lockstep_timout" not in log.read_text(), log
    assert "replaced an empty bag" in (runs[1] / "bag_recorder.log").read_text()
    written = (runs[1] / "parameters.yaml").read_text()  # this run's exact parameters
    assert "/vehicle_tracker:" in written and "min_hits: 3" in written


def test_two_graphs_on_one_domain_without_namespaces_are_caught(kitti_tracking_root, tmp_path):
    """Two graphs on one ROS domain, neither in its own namespace: each graph's nodes take the
    other's frames too. The launchers warn, a lockstep player gets two answers for its frames
    and fails the run naming the cause, and `evaluate bag` refuses every bag, which holds both
    runs (before: both ran to the end and `evaluate bag` gave MOTA 9.8 without a word). Both
    start at once; which graph's answers reach which player first is a race, so a player may
    stop during its launcher's start-up and its bag hold no frame (seen in a fresh-clone CI run
    on a fast machine): that bag is refused for having no frames."""
    procs = {}
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        procs[name] = _launch(kitti_tracking_root, tmp_path / f"bag_{name}", cwd=tmp_path / name)
    outs = {name: p.communicate(timeout=240)[0] for name, p in procs.items()}
    failed = [n for n, p in procs.items() if p.returncode == 1]
    assert failed, outs
    for name in failed:
        # the other graph's answers can reach this player while its launcher still waits for
        # its own nodes (a fast machine): the death is then named as during start-up
        assert any(
            f"error: node 'kitti_player' died{when} (exit code 1): kitti_player: /vehicles/tracks: "
            in outs[name]
            for when in ("", " during start-up")
        ), outs[name]
        assert "another graph publishes on this ROS domain" in outs[name]
    # every bag is refused: it mixes both runs, or (a player stopped before its own graph's
    # first frame was recorded, as the other graph's answers came in first) it holds no frame
    # or was never opened; at least one holds both runs and is named for it. One outcome is
    # not caught (once in four fresh-clone CI runs on 2026-11-30): a player that died before it
    # published anything leaves a bag of the other graph's frames only, in which no stamp came
    # twice; `evaluate bag` then scores those frames (docs/RELIABILITY.md, its row "two graphs
    # on one ROS domain"). That run's launcher failed, naming the cause (above).
    unrecorded = ("no frames", "bag not found", "not a rosbag2 directory")
    mixed = 0
    for name in procs:
        bag = tmp_path / f"bag_{name}"
        result = subprocess.run(
            [sys.executable, "-m", "eval_node.cli", "bag", str(bag)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        logs = list((tmp_path / name / "output" / "logs").glob("*/kitti_player.log"))
        published_none = any("frames in 0, out 0" in log.read_text() for log in logs)
        if result.returncode == 0 and published_none:
            assert name in failed, outs[name]
            continue
        if result.returncode == 0 and procs[name].returncode == 0:
            # the other graph died on its first answer before a stamp reached this recorder
            # twice, and this graph then ran alone to the end (a fresh-clone CI run): a clean
            # run, which evaluate scores; the other's bag must then be the mixed one (below)
            continue
        assert result.returncode == 2, (name, result.stdout, result.stderr, outs)
        this = f"error: {bag}: mixes more than one run" in result.stderr
        assert this or any(f"error: {bag}: {u}" in result.stderr for u in unrecorded), (
            name,
            result.stderr,
        )
        mixed += this
    assert mixed, outs
