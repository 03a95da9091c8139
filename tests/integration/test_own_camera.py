"""A user's own stereo camera through the launcher (issue #42): a publisher written here
(``own_camera.py``) sends real KITTI 0005 (or a synthetic sequence) as camera drivers do:
BEST_EFFORT, ``bgra8``, the right image 1-5 ms after the left one. At least 15 of 16 frames must
be tracked and the run scored against the labels as the KITTI player's run is; unusable input
must end the run with one line naming the node and the cause, and a non-zero exit."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from vehicle_common.topics import resolve

from tracking_bringup import graph

pytestmark = pytest.mark.slow

HERE = Path(__file__).parent
NODES = "vehicle_detector,stereo_depth,vehicle_tracker,bag_recorder"


def _run(root: Path, sequence: str, out: Path, *camera_args: str, frames: int = 16):
    """(launcher exit code, its console, the publisher's console) of one run: the graph
    started without the player, the publisher until its last frame, then Ctrl-C."""
    out.mkdir(parents=True, exist_ok=True)
    from tracking_bringup.environment import graph_environment

    env = graph_environment()  # the camera on the graph's host, with its Fast DDS profile
    launcher = subprocess.Popen(
        [sys.executable, "-m", "tracking_bringup.launcher", "--nodes", NODES]
        + ["-p", f"bag_recorder.output:={out / 'bag'}", "--log-dir", str(out / "logs")]
        # the camera is tested here, not the watchdog: a loaded machine may starve a node
        + ["--stall-timeout", "60"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        camera = subprocess.run(
            [sys.executable, str(HERE / "own_camera.py"), "--root", str(root)]
            + ["--sequence", sequence, "--frames", str(frames), *camera_args],
            capture_output=True,
            text=True,
            timeout=600,
            env=env,
        )
    finally:
        launcher.send_signal(signal.SIGINT)
        console, _ = launcher.communicate(timeout=120)
    return launcher.returncode, console, camera.stdout + camera.stderr


def _tracked_frames(bag: Path) -> int:
    """Frames whose tracks array holds at least one track."""
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == resolve(graph.TRACKS)]
        for conn, _, raw in reader.messages(connections=conns):
            n += bool(reader.deserialize(raw, conn.msgtype).vehicles)
    return n


def _score(bag: Path, tmp: Path) -> dict:
    from eval_node.cli import main as evaluate

    out = tmp / "metrics.json"
    assert evaluate(["bag", str(bag), "--json", str(out), "--no-filters", "--no-progress"]) == 0
    return json.loads(out.read_text())


def test_best_effort_unsynced_bgra8_camera_on_kitti_0005(kitti_tracking_root, tmp_path):
    """The issue's bar: 15 of 16 frames tracked at least, scored against the labels."""
    code, console, camera = _run(kitti_tracking_root, "0005", tmp_path / "run")
    assert code == 0, console
    assert "published 16 frames" in camera, camera
    assert "the run tracked nothing" not in console
    assert _tracked_frames(tmp_path / "run" / "bag") >= 15, console
    metrics = _score(tmp_path / "run" / "bag", tmp_path)
    assert metrics["gt_source"] in ("ground_truth", "bag"), metrics.get("gt_source")
    mota = metrics["tracking"]["mota"]
    print(f"0005, own camera (BEST_EFFORT, bgra8, 1-5 ms): MOTA {mota}")
    # the KITTI player's lockstep run of 0005 with the CNN: MOTA 74.5 (docs/RELIABILITY.md);
    # measured here 74.5 (2026-11-28, load ~30): the same frames, paired and tracked alike
    assert mota >= 0.70, metrics["tracking"]


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory):
    from kitti_player_node.synthetic import generate_sequence

    root = tmp_path_factory.mktemp("own_camera")
    generate_sequence(root, "0000", frames=8, seed=3)
    return root


@pytest.mark.parametrize(
    "camera_args, node, cause",
    [
        (["--info", "zeros"], "stereo_depth", "camera_info"),
        (["--info", "size"], "stereo_depth", "but its camera_info says 1280x720"),
        (["--encoding", "bayer_rggb8"], "vehicle_detector", "unsupported image encoding"),
    ],
)
def test_unusable_camera_is_named_and_fails(synthetic_root, tmp_path, camera_args, node, cause):
    """Issue #42 item 4: camera_info all zeros, of another size, an encoding the graph does
    not read: one line naming the node and the cause, and exit 1 (before: 0 and nothing)."""
    code, console, camera = _run(
        synthetic_root, "0000", tmp_path / "run", *camera_args, "--timeout", "4", frames=4
    )
    assert code == 1, console
    lines = [ln for ln in console.splitlines() if "the run tracked nothing" in ln]
    assert any(f"{node}: 0 of " in ln and cause in ln for ln in lines), console


def test_restarted_camera_resets_odometry_and_tracks(synthetic_root, tmp_path):
    """Issue #42 item 8: stamps that go back 1.7 s mid-run (a restarted camera source): the
    stereo node's odometry and the tracker's tracks start afresh, one warning line each."""
    code, console, camera = _run(
        synthetic_root, "0000", tmp_path / "run", "--restart-at", "4", frames=8
    )
    assert code == 0, console
    assert "published 8 frames" in camera, camera
    logs = tmp_path / "run" / "logs"
    for node, what in (("stereo_depth", "odometry"), ("vehicle_tracker", "tracks ended")):
        text = (logs / f"{node}.log").read_text()
        lines = [ln for ln in text.splitlines() if "time went back" in ln]
        assert len(lines) == 1 and what in lines[0], (node, lines)
