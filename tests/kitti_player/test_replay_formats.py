"""bag_player on the bags people have: a kitti2bag-style ROS 1 ``.bag``, a rosbag2 sqlite3 bag
and an MCAP bag, all written here by rosbags' writers with the same stereo frames; a subscriber
receives the same field values from each. Truncated and corrupt files: one line, exit 2."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from tests.ros_helpers import spin_until

T0 = 1_700_000_000_000_000_000
W, H = 24, 8
#: kitti2bag's topics -> the graph's (docs/bags.md)
KITTI2BAG_REMAP = {
    "/kitti/camera_color_left/image_raw": "/stereo/left/image_rect",
    "/kitti/camera_color_right/image_raw": "/stereo/right/image_rect",
    "/kitti/camera_color_left/camera_info": "/stereo/left/camera_info",
    "/kitti/camera_color_right/camera_info": "/stereo/right/camera_info",
}
IMAGE = "sensor_msgs/msg/Image"
INFO = "sensor_msgs/msg/CameraInfo"
#: KITTI's rectified colour cameras as kitti2bag writes them (P_rect_02, P_rect_03: Tx relative
#: to camera 0, so the left P has a non-zero Tx too)
P_LEFT = [721.5, 0.0, 609.6, 44.86, 0.0, 721.5, 172.9, 0.2164, 0.0, 0.0, 1.0, 0.002746]
P_RIGHT = [721.5, 0.0, 609.6, -339.5, 0.0, 721.5, 172.9, 2.2e-4, 0.0, 0.0, 1.0, 0.00297]


def _pixels(frame: int, side: int) -> np.ndarray:
    rng = np.random.default_rng(10 * frame + side)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8)


def _frames(ts, ros1: bool, right_offset_ns: int = 0):
    """(topic, type, timestamp, message) of 3 stereo frames as kitti2bag writes them (bgr8
    images, CameraInfo with D/K/R/P), built with typestore ``ts``; the right camera's stamps
    ``right_offset_ns`` later (two clocks)."""
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    Image = ts.types[IMAGE]
    Info = ts.types[INFO]
    Roi = ts.types["sensor_msgs/msg/RegionOfInterest"]
    out = []
    for k in range(3):
        for side, name in ((0, "left"), (1, "right")):
            t = T0 + k * 100_000_000 + side * right_offset_ns
            frame_id = f"camera_color_{name}"
            stamp = Time(sec=t // 10**9, nanosec=t % 10**9)
            header = Header(seq=k, stamp=stamp, frame_id=frame_id) if ros1 else None
            header = header or Header(stamp=stamp, frame_id=frame_id)
            img = Image(header, H, W, "bgr8", 0, W * 3, _pixels(k, side).reshape(-1))
            p = P_LEFT if side == 0 else P_RIGHT
            d = np.array([-0.37, 0.2, 0.0, 0.0, 0.0])
            kk = np.array([p[0], 0, p[2], 0, p[5], p[6], 0, 0, 1.0])
            r = np.eye(3).reshape(-1)
            roi = Roi(0, 0, 0, 0, False)
            info = Info(header, H, W, "plumb_bob", d, kk, r, np.array(p), 0, 0, roi)
            base = f"/kitti/camera_color_{name}"
            out.append((f"{base}/image_raw", IMAGE, t, img))
            out.append((f"{base}/camera_info", INFO, t, info))
    return out


def write_bag(path: Path, fmt: str, right_offset_ns: int = 0) -> Path:
    """The frames of :func:`_frames` in ``fmt``: "ros1" (.bag), "sqlite3" or "mcap" (rosbag2)."""
    from rosbags.typesys import Stores, get_typestore

    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        ts = get_typestore(Stores.ROS1_NOETIC)
        path = path.with_suffix(".bag")
        writer, serialize = Writer(path), ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        ts = get_typestore(Stores.ROS2_JAZZY)
        plugin = StoragePlugin.SQLITE3 if fmt == "sqlite3" else StoragePlugin.MCAP
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), ts.serialize_cdr
    with writer:
        conns = {}
        for topic, type_name, t, msg in _frames(ts, fmt == "ros1", right_offset_ns):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, type_name, typestore=ts)
            writer.write(conns[topic], t, serialize(msg, type_name))
    return path


def _run_player(context, argv: list[str]):
    """bag_player's main(argv) in a thread, typed subscribers on the graph's four topics in
    ``context``; returns (exit code, {topic: [messages]})."""
    from kitti_player_node.bag_player import main
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image

    node = Node("replay_formats_sub", context=context)
    got: dict[str, list] = {t: [] for t in KITTI2BAG_REMAP.values()}
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    for topic in got:
        cls = Image if topic.endswith("image_rect") else CameraInfo
        node.create_subscription(cls, topic, lambda m, t=topic: got[t].append(m), qos)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("rc", main(argv)))
    thread.start()
    try:
        spin_until(ex, lambda: not thread.is_alive(), 30)
        spin_until(ex, lambda: all(len(v) == 3 for v in got.values()), 2)
        thread.join(5)
        return result.get("rc"), got
    finally:
        ex.shutdown()
        node.destroy_node()


def _remap_args() -> list[str]:
    return [a for old, new in KITTI2BAG_REMAP.items() for a in ("--remap", f"{old}:={new}")]


@pytest.mark.parametrize("fmt", ["ros1", "sqlite3", "mcap"])
def test_kitti2bag_style_bag_replays_with_same_field_values(rclpy_context, tmp_path, fmt):
    """The same 3 stereo frames from a ROS 1 .bag (converted to CDR), a sqlite3 and an MCAP
    rosbag2: every image and CameraInfo field the graph reads arrives as written."""
    from vehicle_common.image_conversion import image_to_rgb

    bag = write_bag(tmp_path / "kitti", fmt)
    rc, got = _run_player(rclpy_context, [str(bag), "--rate", "0", *_remap_args()])
    assert rc == 0
    for side, name in ((0, "left"), (1, "right")):
        images = got[f"/stereo/{name}/image_rect"]
        infos = got[f"/stereo/{name}/camera_info"]
        assert len(images) == 3 and len(infos) == 3, fmt
        for k, (img, info) in enumerate(zip(images, infos, strict=True)):
            t = T0 + k * 100_000_000
            for header in (img.header, info.header):
                assert (header.stamp.sec, header.stamp.nanosec) == divmod(t, 10**9)
                assert header.frame_id == f"camera_color_{name}"
            assert (img.height, img.width, img.encoding, img.step) == (H, W, "bgr8", W * 3)
            np.testing.assert_array_equal(image_to_rgb(img), _pixels(k, side)[:, :, ::-1])
            assert (info.height, info.width, info.distortion_model) == (H, W, "plumb_bob")
            np.testing.assert_array_equal(info.p, P_LEFT if side == 0 else P_RIGHT)
            np.testing.assert_array_equal(info.d, [-0.37, 0.2, 0.0, 0.0, 0.0])
            assert info.k[0] == P_LEFT[0] and list(info.r) == list(np.eye(3).reshape(-1))


def test_sync_stamps_pairs_a_stereo_pair_stamped_by_two_clocks(rclpy_context, tmp_path, capsys):
    """kitti2bag stamps each camera from its own timestamps.txt: with --sync-stamps the right
    camera's images and infos take the left image's stamp (stereo depth pairs exact stamps);
    a topic without a header is refused in one line."""
    from kitti_player_node.bag_player import main

    bag = write_bag(tmp_path / "kitti", "ros1", right_offset_ns=400_000)  # 0.4 ms later
    argv = [str(bag), "--rate", "0", *_remap_args()]
    _, got = _run_player(rclpy_context, argv)
    stamps = {t: [(m.header.stamp.sec, m.header.stamp.nanosec) for m in v] for t, v in got.items()}
    assert stamps["/stereo/left/image_rect"] != stamps["/stereo/right/image_rect"]
    sync = "/kitti/camera_color_left/image_raw,/kitti/camera_color_right/image_raw,"
    sync += "/kitti/camera_color_left/camera_info,/kitti/camera_color_right/camera_info"
    rc, got = _run_player(rclpy_context, [*argv, "--sync-stamps", sync])
    assert rc == 0
    stamps = {t: [(m.header.stamp.sec, m.header.stamp.nanosec) for m in v] for t, v in got.items()}
    left = [divmod(T0 + k * 100_000_000, 10**9) for k in range(3)]
    assert all(s == left for s in stamps.values()), stamps
    right = got["/stereo/right/image_rect"][2]  # the rest of the message is untouched
    np.testing.assert_array_equal(np.asarray(right.data), _pixels(2, 1).reshape(-1))
    # too far apart for the tolerance: left as they are, and counted
    rc, got = _run_player(rclpy_context, [*argv, "--sync-stamps", sync, "--sync-tolerance", "1e-4"])
    assert (
        rc == 0 and got["/stereo/right/image_rect"][0].header.stamp.nanosec == 400_000 + T0 % 10**9
    )
    capsys.readouterr()
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    plain = tmp_path / "plain.bag"
    with Writer(plain) as w:
        c = w.add_connection("/count", "std_msgs/msg/Int32", typestore=ts)
        w.write(c, T0, ts.serialize_ros1(ts.types["std_msgs/msg/Int32"](3), "std_msgs/msg/Int32"))
        c2 = w.add_connection("/count2", "std_msgs/msg/Int32", typestore=ts)
        w.write(c2, T0, ts.serialize_ros1(ts.types["std_msgs/msg/Int32"](4), "std_msgs/msg/Int32"))
    assert main([str(plain), "--sync-stamps", "/count,/count2", "--immediate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: --sync-stamps: /count (std_msgs/msg/Int32) has no header"]


def test_ros1_type_without_ros2_definition_is_refused(tmp_path, capsys):
    """A ROS 1 type with no ROS 2 counterpart here: one line naming topic and type, exit 2,
    nothing published."""
    from kitti_player_node.bag_player import main
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg("int32 value", "legacy_msgs/msg/Counter"))
    Counter = ts.types["legacy_msgs/msg/Counter"]
    bag = tmp_path / "legacy.bag"
    with Writer(bag) as w:
        c = w.add_connection("/counter", "legacy_msgs/msg/Counter", typestore=ts)
        w.write(c, T0, ts.serialize_ros1(Counter(3), "legacy_msgs/msg/Counter"))
    assert main([str(bag), "--rate", "0", "--immediate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"error: {bag}: /counter: ROS 1 messages cannot be converted")
    assert "legacy_msgs/msg/Counter" in err[0]


def _damaged(bag: Path, how: str) -> Path:
    """A copy of the bag's data file (ROS 1 .bag or sqlite3 .db3) cut in half ("truncated") or
    with its contents after the first 16 bytes overwritten ("corrupt")."""
    src = bag if bag.is_file() else next(bag.glob("*.db3"))
    data = src.read_bytes()
    out = bag.parent / f"{how}{src.suffix}"
    if how == "truncated":
        out.write_bytes(data[: len(data) // 2])
    else:
        rng = np.random.default_rng(1)
        out.write_bytes(data[:16] + rng.integers(0, 256, len(data) - 16, np.uint8).tobytes())
    return out


@pytest.mark.parametrize("fmt", ["ros1", "sqlite3"])
@pytest.mark.parametrize("how", ["truncated", "corrupt"])
def test_damaged_bag_one_line_error(tmp_path, fmt, how):
    """bag_player and `evaluate bag` on a truncated or corrupt file: one line naming it, exit
    2, no traceback."""
    import subprocess
    import sys

    bad = _damaged(write_bag(tmp_path / "kitti", fmt), how)
    for argv in (
        ["-m", "kitti_player_node.bag_player", str(bad), "--rate", "0", "--immediate"],
        ["-m", "eval_node.cli", "bag", str(bad), "--json", str(tmp_path / "m.json")],
    ):
        p = subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=60)
        lines = p.stderr.strip().splitlines()
        assert p.returncode == 2, (argv, p.stderr)
        errors = [ln for ln in lines if ln.startswith("error: ")]
        assert len(errors) == 1 and str(bad) in errors[0], (argv, p.stderr)
        assert "Traceback" not in p.stderr and len(lines) == 1, (argv, p.stderr)


def _mcap_without_a_message(folder: Path, how: str) -> Path:
    """An ``.mcap`` (or a bag folder) from which nothing can be read or played."""
    from vehicle_common.bags.mcap_scan import MAGIC
    from vehicle_common.bags.writer import BagWriter

    folder.mkdir(parents=True, exist_ok=True)
    if how == "zero bytes":
        (folder / "zero.mcap").write_bytes(b"")
        return folder / "zero.mcap"
    if how == "zero bytes in a bag folder":
        (folder / "bag").mkdir()
        (folder / "bag" / "bag_0.mcap").write_bytes(b"")
        return folder / "bag"
    if how == "garbage":
        (folder / "garbage.mcap").write_bytes(np.random.default_rng(2).bytes(5000))
        return folder / "garbage.mcap"
    if how == "magic and garbage":  # a recording cut before its first chunk, or damaged
        (folder / "cut.mcap").write_bytes(MAGIC + np.random.default_rng(3).bytes(5000))
        return folder / "cut.mcap"
    writer = BagWriter(folder / "empty")  # complete and valid, no message recorded
    writer.add_topic("/vehicles/tracks", "stereo_vehicle_msgs/msg/TrackedVehicleArray")
    writer.close()
    return folder / "empty"


@pytest.mark.parametrize(
    ("how", "message"),
    [
        ("zero bytes", "empty file (0 bytes): nothing was recorded"),
        ("zero bytes in a bag folder", "bag_0.mcap is empty (0 bytes)"),
        ("garbage", "cannot read bag (not an MCAP file: bad magic)"),
        ("magic and garbage", "no message can be read: the recording has no complete chunk"),
        ("no message", "no message to play (1 topics, 0 messages in the bag)"),
    ],
)
def test_a_bag_with_nothing_to_play_is_one_line_and_exit_2(tmp_path, capsys, how, message):
    """A 0-byte or garbage `.mcap` used to play with exit code 0 ("done: 0 messages
    published"), after a warning that `bag_recover` would repair it; a random file's error
    named a temporary copy instead of the file."""
    from eval_node.cli import main as evaluate
    from kitti_player_node.bag_player import main as play

    bag = _mcap_without_a_message(tmp_path, how)
    assert play([str(bag), "--rate", "0", "--immediate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {bag}: {message}"), err
    assert "bag_read_" not in err[0]  # the user's file, not the reader's temporary copy
    assert evaluate(["bag", str(bag), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {bag}: "), err  # no warning line first
