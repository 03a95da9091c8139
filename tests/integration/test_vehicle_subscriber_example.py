"""examples/vehicle_subscriber.py (rclpy, vision_msgs, nav_msgs, tf2_msgs only) beside the whole
graph on real KITTI 0005 with ``tracks_frame: odom``: it receives tracks whose ids are stable
across frames, odometry whose path agrees with the reference poses, and odom -> camera on /tf;
the parked cars stand still in odom (less than their length) in the recorded tracks."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
import pytest

from tests.ros_helpers import start_script
from tracking_bringup import demo

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "vehicle_subscriber.py"
CAMERA = "left_camera_optical_frame"
#: the bars: the odometry's path within 3 % of the distance travelled of the reference, ORB-SLAM3
#: rescaled to the labelled parked cars' motion (docs/RESULTS.md: ORB-SLAM3 itself steps 4.8 %
#: longer than the labels there, so against it as it is the bar is 5 %)
PATH_PCT = 3.0
PATH_PCT_RAW_ORBSLAM3 = 5.0


def _wait_subscribed(topics: list[str], timeout: float = 30.0) -> None:
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("example_probe", context=ctx)
    try:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if all(node.count_subscribers(t) > 0 for t in topics):
                return
            time.sleep(0.1)
        raise AssertionError(f"the example never subscribed to {topics}")
    finally:
        node.destroy_node()
        ctx.try_shutdown()


def _stamp_ns(text: str) -> int:
    sec, nsec = text.split(".")
    return int(sec) * 10**9 + int(nsec)


def test_example_subscriber_on_0005(kitti_tracking_root, tmp_path):
    from eval_node.odometry_check import (
        label_centres,
        label_scale,
        parked_car_spreads,
        path_agreement,
        read_odometry_run,
        read_reference_poses,
    )
    from vehicle_common.odometry import CameraMount

    proc, lines, reader = start_script(EXAMPLE)
    try:
        _wait_subscribed(["/vehicles/vision/tracks", "/stereo/odometry", "/tf"])
        out = tmp_path / "run"
        code = demo.main(
            [
                "--kitti-root",
                str(kitti_tracking_root),
                "--sequence",
                "0005",
                "--output",
                str(out),
                "--no-eval",
                "-p",
                "vehicle_tracker.tracks_frame:=odom",
                "-p",
                # frame 0 waits until the nodes publishing these topics report the example's
                # match (a settle time of 1 s lost the first 4 frames in a suite run here)
                "kitti_player.external_subscribers:=vehicles/vision/tracks:1,"
                "stereo/odometry:1,tf:1",
            ]
        )
        assert code == 0
        deadline = time.monotonic() + 20
        while sum(x.startswith("tracks ") for x in lines) < 16 and time.monotonic() < deadline:
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(20) == 0
        reader.join(5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = "".join(lines)
    assert "Traceback" not in text, text
    rows = [x.split() for x in lines]
    tracks = [r for r in rows if r and r[0] == "tracks"]
    odometry = [r for r in rows if r and r[0] == "odometry"]
    tf = [r for r in rows if r and r[0] == "tf"]
    assert len(tracks) == len(odometry) == len(tf) == 16, text[-2000:]

    # /tf from odom to the camera, one per frame, with the frames' stamps
    assert all(r[2:4] == ["odom", CAMERA] for r in tf)
    assert [r[1] for r in tf] == [r[1] for r in odometry] == [r[1] for r in tracks]

    # tracks in odom with stable ids: the same car (nearest within 3 m from one frame to the
    # next) keeps its id, and the cars seen longest keep theirs for 10 frames or more
    assert all(r[2] == "odom" for r in tracks)
    frames = [
        {c.split(":")[0]: np.array(c.split(":")[1].split(","), float) for c in r[3:]}
        for r in tracks
    ]
    switches, lifetime = 0, {}
    for before, after in zip(frames, frames[1:], strict=False):
        for tid, p in after.items():
            lifetime[tid] = lifetime.get(tid, 0) + 1
            near = [t for t, q in before.items() if np.linalg.norm(p - q) < 3.0]
            switches += bool(near) and tid not in near
    assert switches == 0, frames
    assert sum(n >= 10 for n in lifetime.values()) >= 2, lifetime

    # the odometry's path against the reference poses
    run = read_odometry_run(out / "bag")
    frame_of = {f.stamp_ns: f.frame for f in run}
    positions = {
        frame_of[_stamp_ns(r[1])]: np.array(r[4:7], float) for r in odometry if r[3] == CAMERA
    }
    assert np.allclose(positions[0], 0.0)  # odom starts at the camera (REP-105)
    reference = read_reference_poses(kitti_tracking_root / "poses_orbslam3" / "0005.txt")
    scale, pairs = label_scale(label_centres(run), reference)
    assert pairs >= 10 and 0.9 < scale < 1.0
    first = CameraMount().pose  # the camera's pose in odom at the first frame
    scaled = path_agreement(positions, first, reference, scale)
    raw = path_agreement(positions, first, reference)
    assert scaled["max_error_pct"] < PATH_PCT, scaled
    assert raw["max_error_pct"] < PATH_PCT_RAW_ORBSLAM3, raw
    assert scaled["distance_m"] > 20.0  # 0005 drives about 27 m in these 16 frames

    # parked cars stand still in odom: each moves less than its length
    spreads = [c for c in parked_car_spreads(run) if c["frames"] >= 5]
    assert len(spreads) >= 2, spreads
    for car in spreads:
        assert car["spread_m"] < car["length_m"], car
        assert len(car["tracks"]) == 1, car  # one track id all along
