"""kitti_player node in-process: stamps, camera info, ground truth, lockstep, exit codes."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from vehicle_common.kitti import KittiObject

from tests.ros_helpers import spin_until as _spin_until
from vehicle_common import kitti

N_FRAMES = 5


def _write_tiny_sequence(root, n=N_FRAMES):
    """A 5-frame KITTI-layout sequence 0002: labels on frames 0, 1, 3 (frame 2 and 4 empty)."""
    rng = np.random.default_rng(0)
    for i in range(n):
        img = rng.integers(0, 255, size=(24, 40, 3)).astype(np.uint8)
        kitti.write_png(root / "image_02" / "0002" / f"{i:06d}.png", img)
        kitti.write_png(root / "image_03" / "0002" / f"{i:06d}.png", np.roll(img, -3, axis=1))
    calib = kitti.stereo_calibration(50.0, 51.0, 20.0, 12.0, 0.54, left_offset_x=0.06)
    kitti.write_calib(root / "calib" / "0002.txt", calib)
    car = KittiObject("Car", 0.0, 1, -1.2, (5, 6, 20, 18), (1.5, 1.7, 4.1), (1.0, 1.6, 15.0), -1.1)
    rows = [car.with_(frame=0, track_id=3), car.with_(frame=1, track_id=3)]
    rows += [KittiObject("DontCare", frame=1, track_id=-1), car.with_(frame=3, track_id=4)]
    kitti.write_tracking_labels(root / "label_02" / "0002.txt", rows)
    return calib


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class _Collector:
    """A test node recording every player topic."""

    TOPICS = {
        "left": ("/stereo/left/image_rect", "Image"),
        "right": ("/stereo/right/image_rect", "Image"),
        "left_info": ("/stereo/left/camera_info", "CameraInfo"),
        "right_info": ("/stereo/right/camera_info", "CameraInfo"),
        "gt": ("/kitti/ground_truth", "KittiFrameLabels"),
        "clock": ("/clock", "Clock"),
    }

    def __init__(self, context):
        from rclpy.node import Node
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import CameraInfo, Image
        from stereo_vehicle_msgs.msg import KittiFrameLabels

        types = {
            "Image": Image,
            "CameraInfo": CameraInfo,
            "KittiFrameLabels": KittiFrameLabels,
            "Clock": Clock,
        }
        self.node = Node("player_test_collector", context=context)
        self.got = {k: [] for k in self.TOPICS}
        for key, (topic, t) in self.TOPICS.items():
            self.node.create_subscription(
                types[t], topic, lambda m, k=key: self.got[k].append((time.monotonic(), m)), 10
            )


def _player(context, root, **params):
    from kitti_player_node.node import KittiPlayerNode
    from rclpy.parameter import Parameter

    values = {"dataset_root": str(root), "sequence": "0002", "rate_multiplier": 10.0}
    values.update(params)
    return KittiPlayerNode(
        context=context, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()]
    )


def _play(context, root, n_expected, timeout=20.0, matched=lambda player: True, **params):
    """Run the player until it is done, once its publishers matched the collector (and
    ``matched(player)`` holds); returns (player, collector)."""
    from rclpy.executors import SingleThreadedExecutor

    col = _Collector(context)
    player = _player(context, root, **params)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(col.node)
    assert _spin_until(
        ex,
        lambda: (
            all(p.get_subscription_count() > 0 for p in player.publishers_list) and matched(player)
        ),
        10,
    ), "player publishers did not match the collector"
    ex.add_node(player)
    assert _spin_until(ex, lambda: player.done, timeout), "player did not finish"
    player.flush(2.0)
    assert _spin_until(ex, lambda: all(len(v) >= n_expected for v in col.got.values()), 5)
    ex.shutdown()
    col.node.destroy_node()  # a live subscription would leak into the next test's graph
    return player, col


def _check_frames(col, seq, frames, start_time):
    fx, B = seq.calib.fx, seq.calib.baseline
    for key in col.got:
        assert len(col.got[key]) == len(frames), key
    for i, frame in enumerate(frames):
        stamp = round(start_time * 1e9) + frame * 100_000_000
        msgs = {k: v[i][1] for k, v in col.got.items()}
        assert all(_stamp(m) == stamp for k, m in msgs.items() if k != "clock")
        clock = msgs["clock"].clock
        assert clock.sec * 1_000_000_000 + clock.nanosec == stamp
        assert msgs["left"].header.frame_id == "left_camera_optical_frame"
        assert msgs["right_info"].header.frame_id == "right_camera_optical_frame"
        left, right = seq.read_stereo(frame)
        assert msgs["left"].encoding == "rgb8" and msgs["left"].width == left.shape[1]
        assert bytes(msgs["left"].data) == left.tobytes()
        assert bytes(msgs["right"].data) == right.tobytes()
        Pl = np.array(msgs["left_info"].p).reshape(3, 4)
        Pr = np.array(msgs["right_info"].p).reshape(3, 4)
        np.testing.assert_allclose(Pl, np.hstack([seq.calib.K, np.zeros((3, 1))]))
        assert Pr[0, 3] == pytest.approx(-fx * B)
        np.testing.assert_allclose(Pr[:, :3], seq.calib.K)
        assert (
            msgs["left_info"].width == left.shape[1] and msgs["left_info"].height == left.shape[0]
        )
        gt = msgs["gt"]
        assert gt.sequence == seq.sequence and gt.frame_index == frame
        np.testing.assert_allclose(gt.left_camera_offset, seq.calib.left_camera_offset)
        want = seq.objects(frame)
        assert [(o.type, o.track_id) for o in gt.objects] == [(o.type, o.track_id) for o in want]
        for o, w in zip(gt.objects, want, strict=True):
            assert (o.x_min, o.y_max) == pytest.approx((w.bbox[0], w.bbox[3]))
            assert (o.location.z, o.height) == pytest.approx((w.location[2], w.dimensions[0]))


def test_player_on_tiny_sequence(rclpy_context, tmp_path):
    _write_tiny_sequence(tmp_path)
    player, col = _play(rclpy_context, tmp_path, N_FRAMES, start_time=3.0)
    seq = kitti.TrackingSequence.open(tmp_path, "0002")
    _check_frames(col, seq, list(range(N_FRAMES)), 3.0)
    assert [len(m.objects) for _, m in col.got["gt"]] == [1, 2, 0, 1, 0]  # empty ones too
    assert player.scheduler.stats.published == N_FRAMES
    player.destroy_node()


def test_player_waits_for_subscribers(rclpy_context, tmp_path):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    _write_tiny_sequence(tmp_path)
    probe = Node("player_test_probe", context=rclpy_context)
    # subscriptions other tests of this process may have left on the topic
    others = probe.count_subscribers("/stereo/left/image_rect")
    probe.destroy_node()
    player = _player(rclpy_context, tmp_path, wait_for_subscribers=others + 1, rate=0.0)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(player)
    _spin_until(ex, lambda: False, 0.3)
    assert player.scheduler.stats.published == 0 and not player.done
    col = _Collector(rclpy_context)
    ex.add_node(col.node)
    assert _spin_until(ex, lambda: player.done, 10)
    assert player.scheduler.stats.published == N_FRAMES
    ex.shutdown()
    player.destroy_node()
    col.node.destroy_node()


def test_player_on_real_0005(rclpy_context, kitti_tracking_root):
    frames = [2, 3, 4]
    player, col = _play(
        rclpy_context,
        kitti_tracking_root,
        len(frames),
        sequence="0005",
        first_frame=2,
        last_frame=4,
    )
    seq = kitti.TrackingSequence.open(kitti_tracking_root, "0005")
    _check_frames(col, seq, frames, 1.0)
    assert any(o.type == "DontCare" for _, m in col.got["gt"] for o in m.objects)
    player.destroy_node()


def _play_behind_slow_tracker(context, root, node_name, delay_s, **params):
    """Play the tiny sequence in lockstep behind a tracker that answers each left image on
    /vehicles/tracks ``delay_s`` after it arrives (blocking its own executor); returns
    (player, collector, tracker node)."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import Image
    from stereo_vehicle_msgs.msg import TrackedVehicleArray

    _write_tiny_sequence(root)
    slow = Node(node_name, context=context)
    answers = slow.create_publisher(TrackedVehicleArray, "/vehicles/tracks", 10)

    def on_image(msg):
        time.sleep(delay_s)
        answers.publish(TrackedVehicleArray(header=msg.header))

    slow_sub = slow.create_subscription(Image, "/stereo/left/image_rect", on_image, 10)
    slow_ex = SingleThreadedExecutor(context=context)
    slow_ex.add_node(slow)
    thread = threading.Thread(target=slow_ex.spin, daemon=True)
    thread.start()
    try:
        player, col = _play(
            context,
            root,
            N_FRAMES,
            matched=lambda p: (
                slow_sub.get_publisher_count() > 0 and answers.get_subscription_count() > 0
            ),
            lockstep=True,
            lockstep_timeout=5.0,
            **params,
        )
    finally:
        slow_ex.shutdown()
        thread.join(5)
    return player, col, slow


def test_lockstep_behind_slow_subscriber(rclpy_context, tmp_path):
    """A consumer answering on /vehicles/tracks 0.3 s after each frame: no frame is lost."""
    # rate 100 Hz: without lockstep all frames would go out within 50 ms
    player, col, slow = _play_behind_slow_tracker(
        rclpy_context, tmp_path, "slow_tracker", 0.3, rate=100.0
    )
    assert [m.frame_index for _, m in col.got["gt"]] == list(range(N_FRAMES))
    times = [t for t, _ in col.got["left"]]
    assert np.all(np.diff(times) > 0.25)
    assert player.scheduler.stats.lockstep_timeouts == 0
    assert player.scheduler.stats.published == N_FRAMES
    player.destroy_node()
    slow.destroy_node()


def test_unpaced_lockstep_fills_its_window_at_once(rclpy_context, tmp_path):
    """Unpaced lockstep with a window of 2 (``rate_multiplier`` 0): the first two frames go out
    in the same tick and each answer releases the next frame itself; the player's timer only
    starts playback (a slow tick, not 500 wakes a second)."""
    from kitti_player_node.playback import LOCKSTEP_TICK_S

    player, col, slow = _play_behind_slow_tracker(
        rclpy_context,
        tmp_path,
        "slow_tracker_window",
        0.2,
        lockstep_window=2,
        rate_multiplier=0.0,
    )
    assert player.timer.timer_period_ns == round(LOCKSTEP_TICK_S * 1e9)
    times = [t for t, _ in col.got["left"]]
    assert len(times) == N_FRAMES
    assert times[1] - times[0] < 0.75 * LOCKSTEP_TICK_S  # one tick, not two
    assert np.all(np.diff(times[1:]) > 0.15)  # then one frame per answer
    assert player.scheduler.stats.lockstep_timeouts == 0
    player.destroy_node()
    slow.destroy_node()


def test_main_exit_codes(tmp_path, capsys):
    from kitti_player_node.node import main

    assert main(["--ros-args", "-p", f"dataset_root:={tmp_path / 'none'}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "none" in err[0]
    _write_tiny_sequence(tmp_path)
    (tmp_path / "image_02" / "0002" / "000003.png").write_bytes(b"broken")
    args = ["--ros-args", "-p", f"dataset_root:={tmp_path}", "-p", "sequence:=0002"]
    assert main([*args, "-p", "rate:=0.0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"error: {tmp_path}/image_02/0002/000003.png: unreadable image (not a valid PNG)"
    ]
    assert main([*args, "-p", "rate:=0", "-p", "last_frame:=2", "-p", "drop_probability:=0.5"]) == 0
    assert main([*args, "-p", "first_frame:=9"]) == 2
    assert "first_frame/last_frame" in capsys.readouterr().err


def _real_0005_with(tmp_path, kitti_tracking_root, calib_text=None, labels=None):
    """A tracking root with real 0005's images (linked) and its calibration and labels copied,
    optionally replaced."""
    root = tmp_path / "kitti"
    for cam in ("image_02", "image_03"):
        (root / cam).mkdir(parents=True)
        (root / cam / "0005").symlink_to(kitti_tracking_root / cam / "0005")
    for sub, new in (("calib", calib_text), ("label_02", labels)):
        (root / sub).mkdir()
        src = (kitti_tracking_root / sub / "0005.txt").read_bytes()
        (root / sub / "0005.txt").write_bytes(src if new is None else new)
    return root


def test_bad_calibration_or_labels_stop_the_player_with_one_line(
    tmp_path, kitti_tracking_root, capsys
):
    """Real 0005 with a `nan` in P3's Tx: the player used to publish a NaN baseline, and every
    frame was skipped downstream as "P is missing (all zeros)" with exit code 0. Binary calib
    and label files gave a UnicodeDecodeError traceback; a calibration whose P3 gives no
    baseline ran and tracked nothing."""
    from kitti_player_node.node import main

    calib = (kitti_tracking_root / "calib" / "0005.txt").read_text()
    p3 = calib.splitlines()[3].split()
    nan_tx = calib.replace(" ".join(p3), " ".join([*p3[:4], "nan", *p3[5:]]))
    no_baseline = calib.replace(" ".join(p3[1:]), " ".join(calib.splitlines()[2].split()[1:]))
    cases = [
        (dict(calib_text=nan_tx.encode()), "calib/0005.txt:4: P3[0,3]: non-finite value nan"),
        (dict(calib_text=b"\xff\xfe\x80 binary"), "calib/0005.txt: not a text file"),
        (dict(labels=b"\xff\xfe\x80 binary"), "label_02/0005.txt: not a text file"),
        (dict(calib_text=no_baseline.encode()), "calib/0005.txt: P2[0,3] - P3[0,3] = 0"),
    ]
    for k, (files, message) in enumerate(cases):
        root = _real_0005_with(tmp_path / str(k), kitti_tracking_root, **files)
        rc = main(["--ros-args", "-p", f"dataset_root:={root}", "-p", "sequence:=0005"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2, err
        assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
