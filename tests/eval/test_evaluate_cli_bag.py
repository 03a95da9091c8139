"""evaluate_bag / read_run / the `evaluate` CLI on bags written here from synthetic messages."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from vehicle_common.box3d import projected_bbox
from vehicle_common.kitti import KittiObject, alpha_from_rotation_y, stereo_calibration

CALIB = stereo_calibration(360.0, 360.0, 310.0, 94.0, 0.54, left_offset_x=0.06)
SIZE = (620, 188)  # image width, height
N_FRAMES = 21  # 42 ground-truth boxes: the devkit's 40 recall samples can all be reached
T0 = 1_000_000_000_000


def gt_objects(frame: int) -> list[KittiObject]:
    """Two cars moving in depth, fully visible, tall enough for every difficulty."""
    objs = []
    for tid, (x0, z0, vz, ry) in enumerate([(-2.5, 9.0, 0.15, -1.6), (2.5, 12.0, -0.1, 1.5)]):
        h, w, length = 1.5, 1.6, 3.9
        loc = (x0, 1.6, z0 + vz * frame)
        bbox = projected_bbox(CALIB.P2, (h, w, length), loc, ry, SIZE)
        objs.append(
            KittiObject(
                type="Car",
                alpha=alpha_from_rotation_y(ry, loc[0], loc[2]),
                bbox=bbox,
                dimensions=(h, w, length),
                location=loc,
                rotation_y=ry,
                frame=frame,
                track_id=tid,
            )
        )
    return objs


def make_messages(track_offset_x: float = 0.0, images: bool = False):
    """(topic, msg, receive time) of a recorded run whose outputs equal the ground truth
    (tracks shifted by ``track_offset_x`` metres along x)."""
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import CameraInfo
    from stereo_vehicle_msgs.msg import (
        KittiFrameLabels,
        TrackedVehicle,
        TrackedVehicleArray,
        VehicleDetection2D,
        VehicleDetection2DArray,
        VehicleDetection3D,
        VehicleDetection3DArray,
    )
    from stereo_vehicle_msgs.msg import KittiObject as KittiObjectMsg
    from vehicle_common.image_conversion import numpy_to_image
    from vehicle_common.orientation_bins import alpha_to_bin

    off = CALIB.left_camera_offset
    out = []
    for k in range(N_FRAMES):
        stamp_ns = T0 + k * 100_000_000
        stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        t = 5_000_000_000 + k * 100_000_000
        frame_id = "left_camera_optical_frame"
        info = CameraInfo(width=SIZE[0], height=SIZE[1])
        info.header.stamp, info.header.frame_id = stamp, frame_id
        info.k = CALIB.K.ravel().tolist()
        out.append(("/stereo/left/camera_info", info, t))
        if images:
            img = np.full((SIZE[1], SIZE[0], 3), 60 + 5 * k, np.uint8)
            msg = numpy_to_image(img, "rgb8")
            msg.header.stamp, msg.header.frame_id = stamp, frame_id
            out.append(("/stereo/left/image_rect", msg, t))
        gt = KittiFrameLabels(sequence="0003", frame_index=k, left_camera_offset=off.tolist())
        gt.header.stamp, gt.header.frame_id = stamp, frame_id
        d2 = VehicleDetection2DArray()
        d3 = VehicleDetection3DArray()
        tr = TrackedVehicleArray()
        for m in (d2, d3, tr):
            m.header.stamp, m.header.frame_id = stamp, frame_id
        for i, o in enumerate(gt_objects(k)):
            om = KittiObjectMsg(track_id=o.track_id, type=o.type, alpha=o.alpha)
            om.x_min, om.y_min, om.x_max, om.y_max = o.bbox
            om.height, om.width, om.length = o.dimensions
            om.location.x, om.location.y, om.location.z = o.location
            om.rotation_y = o.rotation_y
            gt.objects.append(om)
            centre = o.centre_of_mass + off
            x1, y1, x2, y2 = o.bbox
            b = alpha_to_bin(o.alpha)
            det2 = VehicleDetection2D(id=str(i), class_id="car", score=0.9, orientation_bin=b)
            det2.bbox.center_x, det2.bbox.center_y = (x1 + x2) / 2, (y1 + y2) / 2
            det2.bbox.size_x, det2.bbox.size_y = x2 - x1, y2 - y1
            probs = [0.0] * 4
            probs[b] = 1.0
            det2.orientation_probs = probs
            d2.detections.append(det2)
            det3 = VehicleDetection3D(id=str(i), class_id="car", score=0.9, orientation_bin=b)
            det3.position.x, det3.position.y, det3.position.z = centre.tolist()
            det3.position_covariance = (np.eye(3) * 0.05).ravel().tolist()
            det3.bbox = det2.bbox
            det3.orientation_probs = probs
            det3.disparity, det3.valid_pixel_fraction = 20.0, 0.9
            d3.detections.append(det3)
            v = TrackedVehicle(track_id=o.track_id + 1, class_id="car", confidence=0.9)
            v.state = TrackedVehicle.STATE_CONFIRMED
            v.position.x = float(centre[0] + track_offset_x)
            v.position.y, v.position.z = float(centre[1]), float(centre[2])
            v.velocity.z = 1.5 if i == 0 else -1.0  # [m/s]: 0.15 / -0.1 m per 0.1 s frame
            v.size.x, v.size.y, v.size.z = o.dimensions[2], o.dimensions[1], o.dimensions[0]
            v.yaw = o.rotation_y
            v.orientation_bin = b
            v.bbox = det2.bbox
            v.age = k + 1
            tr.vehicles.append(v)
        out += [
            ("/kitti/ground_truth", gt, t + 1000),
            ("/vehicles/detections_2d", d2, t + 30_000_000),
            ("/vehicles/detections_3d", d3, t + 50_000_000),
            ("/vehicles/tracks", tr, t + 60_000_000),
        ]
    return out


def make_bag(path, track_offset_x: float = 0.0, images: bool = False):
    from vehicle_common.bags.writer import write_bag

    write_bag(path, make_messages(track_offset_x, images))
    return path


def test_read_run_converts_to_camera0(tmp_path):
    from vehicle_common.bags.recorded_run import read_run

    run = read_run(make_bag(tmp_path / "bag"))
    assert run.sequence == "0003"
    assert [f.frame for f in run.frames] == list(range(N_FRAMES))
    f = run.frames[3]
    gt = gt_objects(3)
    assert len(f.gt) == len(f.det3d) == len(f.tracks) == len(f.det2d) == 2
    for g, d, t in zip(gt, f.det3d, f.tracks, strict=True):
        np.testing.assert_allclose(d.location, g.location, atol=0.05)  # mean size ~ GT size
        np.testing.assert_allclose(t.location, g.location, atol=1e-6)
        assert t.rotation_y == pytest.approx(g.rotation_y)
        assert t.alpha == pytest.approx(g.alpha, abs=1e-6)
    assert run.P_left is not None
    np.testing.assert_allclose(run.P_left, CALIB.P2, atol=1e-9)


def test_evaluate_bag_perfect_outputs(tmp_path):
    from eval_node.bag_evaluation import evaluate_bag

    res = evaluate_bag(make_bag(tmp_path / "bag"), run_filters=False)
    assert res["frames"] == N_FRAMES
    for level in ("easy", "moderate", "hard"):
        assert res["tracks_3d"]["1.5"][level] == pytest.approx(1.0)
        assert res["detections_3d"]["1.5"][level] == pytest.approx(1.0)
        assert res["detections_2d"]["0.7"][level] == pytest.approx(1.0)
    assert res["tracking"]["mota"] == pytest.approx(1.0)
    assert res["tracking"]["idsw"] == 0
    assert res["orientation"]["accuracy"] == pytest.approx(1.0)
    assert res["velocity"]["rmse"] == pytest.approx(0.0, abs=1e-6)
    assert res["velocity"]["n"] == 2 * N_FRAMES
    assert res["velocity"]["velocity_jitter"] == pytest.approx(0.0)


def test_evaluate_bag_offset_tracks_fail_tight_threshold(tmp_path):
    from eval_node.bag_evaluation import evaluate_bag

    res = evaluate_bag(make_bag(tmp_path / "bag", track_offset_x=2.0), run_filters=False)
    assert res["tracks_3d"]["1.5"]["moderate"] == pytest.approx(0.0)
    assert res["tracks_3d"]["3"]["moderate"] == pytest.approx(1.0)
    assert res["detections_3d"]["1.5"]["moderate"] == pytest.approx(1.0)
    assert res["velocity"]["rmse"] == pytest.approx(0.0, abs=1e-6)  # a constant offset


def test_evaluate_bag_velocity_error(tmp_path):
    from eval_node.bag_evaluation import evaluate_bag
    from vehicle_common.bags.writer import write_bag

    msgs = make_messages()
    for topic, m, _t in msgs:
        if topic == "/vehicles/tracks":
            for v in m.vehicles:
                v.velocity.x += 3.0  # 3 m/s sideways error
    write_bag(tmp_path / "bag", msgs)
    res = evaluate_bag(tmp_path / "bag", run_filters=False)
    assert res["velocity"]["rmse"] == pytest.approx(3.0, abs=1e-6)
    assert res["velocity"]["mae"] == pytest.approx(3.0, abs=1e-6)


def test_evaluate_cli_missing_bag_exits_2(tmp_path):
    missing = tmp_path / "nope"
    p = subprocess.run(
        [sys.executable, "-m", "eval_node.cli", "bag", str(missing), "--json", str(tmp_path / "x")],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(missing) in lines[0]


def test_evaluate_cli_bag_json_and_table(tmp_path):
    bag = make_bag(tmp_path / "bag")
    out = tmp_path / "m.json"
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "eval_node.cli",
            "bag",
            str(bag),
            "--json",
            str(out),
            "--no-filters",
            "--lost-cars",
        ],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 0, p.stderr
    res = json.loads(out.read_text())
    assert res["tracking"]["mota"] == pytest.approx(1.0)
    assert "MOTA" in p.stdout and "100.0" in p.stdout
    # issue 34: the per-cause table of missed cars (none missed here)
    assert "why labelled cars were missed" in p.stdout and "recall 1.000" in p.stdout
    assert math.isfinite(res["throughput"]["fps"])


def test_evaluate_bag_with_label_files(tmp_path):
    from eval_node.bag_evaluation import evaluate_bag
    from vehicle_common.kitti import write_tracking_labels

    labels = tmp_path / "label_02"
    rows = [o for k in range(N_FRAMES) for o in gt_objects(k)]
    write_tracking_labels(labels / "0003.txt", rows[: len(rows) // 2])  # first half labelled
    res = evaluate_bag(make_bag(tmp_path / "bag"), labels_dir=labels, run_filters=False)
    assert res["gt_source"] == "labels"
    assert res["tracking"]["fn"] == 0 and res["tracking"]["fp"] == len(rows) - len(rows) // 2
    with pytest.raises(Exception, match="0007.txt"):
        evaluate_bag(tmp_path / "bag", labels_dir=labels, sequence="0007", run_filters=False)


def test_evaluate_refuses_a_bag_that_mixes_two_runs(tmp_path):
    """Two graphs on one ROS domain without namespaces record each other's frames: the same
    stamps twice on every per-frame topic (issue #35: `evaluate bag` scored such a bag, MOTA
    9.8, without a word). One line naming the topic, exit 2; a bag of one run is read."""
    run = make_messages()
    second = make_messages(track_offset_x=3.0)
    from vehicle_common.bags.writer import write_bag

    write_bag(tmp_path / "mixed", sorted(run + second, key=lambda m: m[2]))
    p = subprocess.run(
        [sys.executable, "-m", "eval_node.cli", "bag", str(tmp_path / "mixed")],
        capture_output=True,
        text=True,
    )
    assert p.returncode == 2, p.stdout + p.stderr
    lines = [x for x in p.stderr.splitlines() if x.strip() and "reading bag" not in x]  # progress
    assert len(lines) == 1, p.stderr
    assert lines[0].startswith(f"error: {tmp_path / 'mixed'}: mixes more than one run: ")
    assert f"holds {N_FRAMES} stamp(s) more than once" in lines[0]
    assert "--namespace" in lines[0]
    from vehicle_common.bags.recorded_run import read_run

    assert len(read_run(make_bag(tmp_path / "one")).frames) == N_FRAMES


def test_repeated_stamps_of_serialized_headers():
    from rclpy.serialization import serialize_message
    from stereo_vehicle_msgs.msg import TrackedVehicleArray
    from vehicle_common.bags.repeated_stamps import RepeatedStamps, header_stamp

    msg = TrackedVehicleArray()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 300_000_000
    assert header_stamp(serialize_message(msg)) == 12_300_000_000
    assert header_stamp(b"\x00\x01") is None
    seen = RepeatedStamps(keep=3)
    assert [seen.add("/t", s) for s in (1, 2, 3, 2, 4)] == [False, False, False, True, False]
    assert seen.repeats == {"/t": 1}
    assert not seen.add("/t", 1)  # forgotten: only the last 3 stamps are kept
    assert not seen.add("/other", 2)


def test_run_without_ground_truth_is_scored_by_stamp(tmp_path, capsys):
    """A bag without /kitti/ground_truth whose first frame left no output at all, scored with
    ``--labels --sequence``: each stamp is its frame on the player's grid (``--start-time``),
    frame 0 counts as missed, every other frame matches its labels (before: stamps in order
    numbered frame 1 as 0, and every frame was shifted against its labels)."""
    from eval_node.cli import main
    from vehicle_common.bags.writer import write_bag
    from vehicle_common.kitti import write_tracking_labels

    labels = tmp_path / "label_02"
    write_tracking_labels(labels / "0003.txt", [o for k in range(N_FRAMES) for o in gt_objects(k)])
    kept = [
        (topic, msg, t)
        for topic, msg, t in make_messages()
        if topic != "/kitti/ground_truth"
        and msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec != T0
    ]
    bag = tmp_path / "bag"
    write_bag(bag, kept)
    json_path = tmp_path / "res.json"
    argv = ["bag", str(bag), "--labels", str(labels), "--sequence", "0003", "--no-filters"]
    argv += ["--no-progress", "--json", str(json_path), "--start-time", str(T0 * 1e-9)]
    assert main(argv) == 0, capsys.readouterr().err
    res = json.loads(json_path.read_text())
    assert res["frames"] == N_FRAMES - 1 and res["gt_source"] == "labels"
    tracking = res["tracking"]
    assert tracking["fp"] == 0 and tracking["idsw"] == 0
    assert tracking["fn"] == 0  # frame 0 had no output: not a frame of the run (before its first)

    # a frame in the middle with no output at all is scored as missed (its labels are FN)
    middle = T0 + 5 * 100_000_000
    gap = [m for m in kept if m[1].header.stamp.sec * 10**9 + m[1].header.stamp.nanosec != middle]
    write_bag(tmp_path / "gap", gap)
    argv[1] = str(tmp_path / "gap")
    assert main(argv) == 0
    res = json.loads(json_path.read_text())
    assert res["frames"] == N_FRAMES - 1 and res["tracking"]["fn"] == len(gt_objects(5))
    assert res["tracking"]["fp"] == 0

    # stamps off the player's grid: one line naming --start-time
    argv[-1] = str(T0 * 1e-9 + 0.05)
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not on the KITTI player's frame grid" in err[0]
    assert "--start-time" in err[0]
