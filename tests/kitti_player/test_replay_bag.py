"""bag_player: reading rosbag2-layout and bare MCAP bags, pacing, and byte-exact replay."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from vehicle_common.bags.reader import BagError, open_reader
from vehicle_common.bags.replay import (
    BagMessage,
    iter_bag,
    output_types,
    paced,
    parse_remaps,
    parse_topics,
)
from vehicle_common.kitti import KittiFormatError

from tests.ros_helpers import spin_until as _spin_until

MSG_DIR = Path(__file__).resolve().parents[2] / "msg_defs" / "msg"
T0 = 1_700_000_000_000_000_000


def _typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for f in sorted(MSG_DIR.glob("*.msg")):
        types.update(get_types_from_msg(f.read_text(), f"stereo_vehicle_msgs/msg/{f.stem}"))
    ts.register(types)
    return ts


def _messages() -> list[BagMessage]:
    """A few serialized messages on three topics, 20 ms apart."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String
    from stereo_vehicle_msgs.msg import KittiFrameLabels, KittiObject, TrackedVehicleArray

    out = []
    for i in range(8):
        t = T0 + i * 20_000_000
        if i % 3 == 0:
            out.append(
                BagMessage(
                    "/chatter", "std_msgs/msg/String", t, serialize_message(String(data=f"m{i}"))
                )
            )
        elif i % 3 == 1:
            gt = KittiFrameLabels(sequence="0005", frame_index=i, left_camera_offset=[0.06, 0, 0])
            gt.header.stamp.sec, gt.header.frame_id = i, "left_camera_optical_frame"
            gt.objects = [KittiObject(track_id=i, type="Car", x_min=1.5 * i, height=1.4)]
            out.append(
                BagMessage(
                    "/kitti/ground_truth",
                    "stereo_vehicle_msgs/msg/KittiFrameLabels",
                    t,
                    serialize_message(gt),
                )
            )
        else:
            tr = TrackedVehicleArray()
            tr.header.stamp.sec = i
            out.append(
                BagMessage(
                    "/vehicles/tracks",
                    "stereo_vehicle_msgs/msg/TrackedVehicleArray",
                    t,
                    serialize_message(tr),
                )
            )
    return out


def _write_rosbag2(path: Path, messages: list[BagMessage]) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = _typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for m in messages:
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, m.type_name, typestore=ts)
            writer.write(conns[m.topic], m.timestamp_ns, m.data)
    return path


def _write_bare_mcap(path: Path, messages: list[BagMessage]) -> Path:
    """A bare .mcap as rosbag2 writes it: ros2 profile, ros2msg schemas, cdr messages."""
    from mcap.writer import Writer

    ts = _typestore()
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        channels = {}
        for m in messages:
            if m.topic not in channels:
                text, _ = ts.generate_msgdef(m.type_name, ros_version=2)
                schema = w.register_schema(m.type_name, "ros2msg", text.encode())
                channels[m.topic] = w.register_channel(m.topic, "cdr", schema)
            w.add_message(channels[m.topic], m.timestamp_ns, m.data, m.timestamp_ns)
        w.finish()
    return path


def test_rosbag2_mcap_reads_back_exactly(tmp_path):
    msgs = _messages()
    bag = _write_rosbag2(tmp_path / "bag", msgs)
    assert (bag / "metadata.yaml").is_file()
    assert list(iter_bag(bag)) == msgs
    # selection and remapping
    sel = list(iter_bag(bag, topics=["/chatter"], remap={"/chatter": "/talk"}))
    assert [m.data for m in sel] == [m.data for m in msgs if m.topic == "/chatter"]
    assert {m.topic for m in sel} == {"/talk"}
    assert output_types(bag, ["/vehicles/tracks"], {"/vehicles/tracks": "/t"}) == {
        "/t": "stereo_vehicle_msgs/msg/TrackedVehicleArray"
    }
    with pytest.raises(BagError, match="/nope not in bag"):
        list(iter_bag(bag, topics=["/nope"]))


def test_bare_mcap_reads_back_exactly(tmp_path):
    msgs = _messages()
    bag = _write_bare_mcap(tmp_path / "plain.mcap", msgs)
    assert list(iter_bag(bag)) == msgs
    from rclpy.serialization import deserialize_message
    from stereo_vehicle_msgs.msg import KittiFrameLabels

    gt = deserialize_message(next(iter_bag(bag, ["/kitti/ground_truth"])).data, KittiFrameLabels)
    assert gt.frame_index == 1 and gt.objects[0].type == "Car" and gt.objects[0].height == 1.4


def test_folder_with_one_mcap_and_no_metadata_opens(tmp_path):
    msgs = _messages()
    folder = tmp_path / "run"
    folder.mkdir()
    _write_bare_mcap(folder / "run_0.mcap", msgs)
    assert list(iter_bag(folder)) == msgs
    reader = open_reader(folder)
    try:
        assert {c.topic for c in reader.connections} == {m.topic for m in msgs}
    finally:
        reader.close()
    # two files named as rosbag2 splits of this bag (an interrupted recording): one bag
    _write_bare_mcap(folder / "run_1.mcap", msgs)
    assert sorted(m.data for m in iter_bag(folder)) == sorted(m.data for m in msgs * 2)
    other = tmp_path / "other"
    other.mkdir()
    _write_bare_mcap(other / "a.mcap", msgs)
    _write_bare_mcap(other / "b.mcap", msgs)
    with pytest.raises(BagError, match="no metadata.yaml and 2 .mcap files") as err:
        open_reader(other)
    assert isinstance(err.value, KittiFormatError)


def test_option_parsing_and_bad_bags(tmp_path):
    assert parse_remaps(["/a:=/b", "/c:=/d"]) == {"/a": "/b", "/c": "/d"}
    assert parse_topics(["/a,/b", "/c"]) == ["/a", "/b", "/c"] and parse_topics([]) is None
    with pytest.raises(BagError, match="--remap"):
        parse_remaps(["/a=/b"])
    with pytest.raises(BagError, match="bag not found"):
        list(iter_bag(tmp_path / "missing"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="no metadata.yaml"):
        list(iter_bag(tmp_path / "empty"))
    (tmp_path / "junk.mcap").write_bytes(b"\x00" * 64)
    with pytest.raises(BagError, match="junk.mcap: cannot read bag"):
        list(iter_bag(tmp_path / "junk.mcap"))


def test_paced_keeps_recorded_spacing():
    msgs = [
        BagMessage("/a", "std_msgs/msg/String", T0 + d, b"") for d in (0, 100_000_000, 400_000_000)
    ]
    now = [10.0]
    waits = []

    def sleep(s):
        waits.append(s)
        now[0] += s

    out = list(paced(msgs, rate=2.0, clock=lambda: now[0], sleep=sleep))
    assert out == msgs and waits == pytest.approx([0.05, 0.15])
    waits.clear()
    assert list(paced(msgs, rate=0.0, clock=lambda: now[0], sleep=sleep)) == msgs and waits == []


def _raw_subscriber(context, topics: dict[str, str]):
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from vehicle_common.bags.replay import message_class

    node = Node("replay_test_sub", context=context)
    got: list[tuple[str, bytes]] = []
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    for topic, type_name in topics.items():
        node.create_subscription(
            message_class(type_name), topic, lambda d, t=topic: got.append((t, d)), qos, raw=True
        )
    return node, got


@pytest.mark.parametrize("layout", ["rosbag2", "bare"])
def test_replay_is_byte_exact(rclpy_context, tmp_path, layout):
    from kitti_player_node.bag_player import BagPlayerNode
    from rclpy.executors import SingleThreadedExecutor

    msgs = _messages()
    if layout == "rosbag2":
        bag = _write_rosbag2(tmp_path / "bag", msgs)
    else:
        bag = _write_bare_mcap(tmp_path / "b.mcap", msgs)
    remap = {"/chatter": "/replayed/chatter"}
    types = output_types(bag, None, remap)
    player = BagPlayerNode(types, context=rclpy_context)
    sub, got = _raw_subscriber(rclpy_context, types)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(sub)
    assert _spin_until(
        ex, lambda: all(p.get_subscription_count() > 0 for p in player.pubs.values()), 10
    )
    for m in paced(iter_bag(bag, remap=remap), rate=4.0):
        player.publish(m)
    assert _spin_until(ex, lambda: len(got) == len(msgs), 10)
    expected = [(remap.get(m.topic, m.topic), m.data) for m in msgs]
    for topic in types:  # order is guaranteed per topic
        assert [d for t, d in got if t == topic] == [d for t, d in expected if t == topic]
    assert player.published == len(msgs) and player.wait_for_acks(1.0)
    ex.shutdown()
    player.destroy_node()
    sub.destroy_node()


def test_main_replays_into_graph_and_rejects_bad_input(rclpy_context, tmp_path, capsys):
    from kitti_player_node.bag_player import main

    assert main([str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0] == f"error: {tmp_path / 'none'}: bag not found"
    msgs = _messages()
    bag = _write_rosbag2(tmp_path / "bag", msgs)
    assert main([str(bag), "--topics", "/x"]) == 2
    assert "--topics: /x not in bag" in capsys.readouterr().err

    argv = [str(bag), "--topics", "/chatter", "--rate", "0", "--wait-for-subscribers", "1"]
    want = [m.data for m in msgs if m.topic == "/chatter"]
    assert _main_delivers(rclpy_context, argv, "/chatter", "std_msgs/msg/String", want) == want


def _main_delivers(
    context, argv: list[str], topic: str, type_name: str, want: list[bytes]
) -> list[bytes]:
    """Run bag_player's main(argv) in a thread (its own context) with a raw subscriber on
    ``topic`` in ``context``; returns what arrived once main() returned 0 (main waits until
    the reliable subscriber acknowledged everything, so the executor is only spun until
    ``len(want)`` messages were taken, or 10 s)."""
    from kitti_player_node.bag_player import main
    from rclpy.executors import SingleThreadedExecutor

    sub, got = _raw_subscriber(context, {topic: type_name})
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(sub)
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("rc", main(argv)))
    thread.start()
    try:
        _spin_until(ex, lambda: not thread.is_alive(), 30)
        _spin_until(ex, lambda: len(got) >= len(want), 10)
        thread.join(5)
        assert result.get("rc") == 0
        return [d for _, d in got]
    finally:
        ex.shutdown()
        sub.destroy_node()


def test_readme_remap_command_line(rclpy_context, tmp_path):
    """`bag_player BAG --remap /vehicles/tracks:=/replayed/tracks --rate 0` as written in the
    README (a separate argument, not only --remap=...)."""
    from kitti_player_node.bag_player import split_ros_args

    assert split_ros_args(["B", "--remap", "/a:=/b", "--ros-args", "-r", "x:=y", "--", "-v"]) == (
        ["B", "--remap", "/a:=/b", "-v"],
        ["--ros-args", "-r", "x:=y"],
    )
    msgs = _messages()
    bag = _write_rosbag2(tmp_path / "bag", msgs)
    argv = [str(bag), "--remap", "/vehicles/tracks:=/replayed/tracks", "--rate", "0"]
    argv += ["--topics", "/vehicles/tracks"]
    want = [m.data for m in msgs if m.topic == "/vehicles/tracks"]
    type_name = "stereo_vehicle_msgs/msg/TrackedVehicleArray"
    assert _main_delivers(rclpy_context, argv, "/replayed/tracks", type_name, want) == want


def test_ready_to_play_policy():
    from vehicle_common.bags.replay import ready_to_play

    # a subscriber the graph knows of but not yet matched holds the start back, always
    assert not ready_to_play({"/a": 0, "/b": 1}, {"/a": 1, "/b": 1}, 9.0, 3.0)
    # every topic matched: go at once
    assert ready_to_play({"/a": 1, "/b": 2}, {"/a": 1, "/b": 2}, 0.0, 3.0)
    # a topic nobody subscribes to: wait for discovery, then go
    assert not ready_to_play({"/a": 1, "/b": 0}, {"/a": 1, "/b": 0}, 2.9, 3.0)
    assert ready_to_play({"/a": 1, "/b": 0}, {"/a": 1, "/b": 0}, 3.0, 3.0)
    # the default wait covers two of Fast DDS's default 3 s announcement periods
    from kitti_player_node.bag_player import DISCOVERY_TIME

    assert DISCOVERY_TIME > 2 * 3.0


def test_required_counts_never_below_the_known_subscribers():
    from vehicle_common.bags.replay import required_counts

    known = {"/a": 2, "/b": 0}
    # --wait-for-subscribers 1: one on every replayed topic, and every known one
    assert required_counts(known, 1) == {"/a": 2, "/b": 1}
    # --wait-for-topics: the declared counts (other nodes' topics too), raised to the known
    assert required_counts(known, 0, {"/a": 1, "/tracks": 1}) == {"/a": 2, "/b": 0, "/tracks": 1}


def test_wait_for_topics_waits_for_another_nodes_edge(rclpy_context):
    """--wait-for-topics on a topic the player does not publish: it waits until the node
    publishing it reports on /diagnostics a matched subscription (a tracker's tracks reaching a
    recorder), and names the edge when the wait times out."""
    from kitti_player_node.bag_player import BagPlayerNode
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import String
    from vehicle_common.frame_accounting import FrameCounter
    from vehicle_common.node_runtime import NodeHealth

    reporter = Node("flaky_reporter", context=rclpy_context)
    reporter.create_publisher(String, "/flaky_edge", 10)
    NodeHealth(reporter, FrameCounter(), period_s=0.2)
    player = BagPlayerNode({"/flaky_in": "std_msgs/msg/String"}, context=rclpy_context)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(reporter)
    thread = threading.Thread(target=ex.spin, daemon=True)
    thread.start()
    listener = None
    try:
        assert player.wait_for_subscribers(0, 1.5, {"/flaky_edge": 1}) == ["/flaky_edge (0/1)"]
        listener = Node("flaky_listener", context=rclpy_context)
        listener.create_subscription(String, "/flaky_edge", lambda m: None, 10)
        assert player.wait_for_subscribers(0, 20.0, {"/flaky_edge": 1}) == []
    finally:
        ex.shutdown()
        thread.join(5)
        for node in (listener, player, reporter):
            if node is not None:
                node.destroy_node()


def _timed_bag(
    tmp_path, n: int = 20, period_ns: int = 100_000_000, unheard: bool = True
) -> tuple[Path, list[bytes]]:
    """``n`` String messages on /chatter, ``period_ns`` apart, and (``unheard``) one on
    /unheard."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    data = [serialize_message(String(data=f"m{i}")) for i in range(n)]
    msgs = [
        BagMessage("/chatter", "std_msgs/msg/String", T0 + i * period_ns, d)
        for i, d in enumerate(data)
    ]
    if unheard:
        msgs.append(BagMessage("/unheard", "std_msgs/msg/String", T0, data[0]))
    return _write_rosbag2(tmp_path / "timed", sorted(msgs, key=lambda m: m.timestamp_ns)), data


def _player_process(bag, *extra):
    import os
    import subprocess
    import sys

    return subprocess.Popen(
        [sys.executable, "-m", "kitti_player_node.bag_player", str(bag), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ),
    )


def _collect(proc, lines: list[str]) -> threading.Thread:
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    return reader


def _wait_for_line(lines: list[str], text: str, proc, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not any(text in line for line in lines):
        assert time.monotonic() < deadline and proc.poll() is None, "".join(lines)
        time.sleep(0.02)


def _stop(*procs) -> None:
    for proc in procs:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("late", [False, True])
def test_default_replay_loses_nothing_to_a_running_subscriber(rclpy_context, tmp_path, late):
    """A player process at rate 1.0 with default options delivers every message to a subscriber
    that runs before it starts (late=False) or whose subscription appears once the player is
    waiting (late=True: its participant runs before, the subscription comes during the wait);
    the player says it matched /chatter before playing, and /unheard, which nobody subscribes
    to, holds the replay back only for the discovery wait."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    bag, data = _timed_bag(tmp_path)
    ex = SingleThreadedExecutor(context=rclpy_context)
    # this process takes part in the graph before the player starts (its participant exists)
    anchor = Node("replay_test_anchor", context=rclpy_context)
    sub = got = None
    if not late:
        sub, got = _raw_subscriber(rclpy_context, {"/chatter": "std_msgs/msg/String"})
        ex.add_node(sub)
    proc = _player_process(bag)
    lines: list[str] = []
    reader = _collect(proc, lines)
    try:
        if late:
            _wait_for_line(lines, "waiting up to", proc)
            sub, got = _raw_subscriber(rclpy_context, {"/chatter": "std_msgs/msg/String"})
            ex.add_node(sub)
        _spin_until(ex, lambda: len(got) == len(data) and proc.poll() is not None, 40)
        assert proc.wait(10) == 0
        reader.join(5)
        texts = [deserialize_message(d, String).data for _, d in got]  # (DDS pads the CDR)
        assert texts == [f"m{i}" for i in range(len(data))], "".join(lines)
        log = "".join(lines)
        assert "subscribers matched after" in log and "/chatter (1)" in log, log
        assert log.index("/chatter (1)") < log.index("playing ")
        assert "no subscriber on /unheard; playing anyway" in log
    finally:
        _stop(proc)
        ex.shutdown()
        anchor.destroy_node()
        if sub is not None:
            sub.destroy_node()


def test_replay_waits_for_a_subscriber_that_announces_itself_late(tmp_path):
    """Issue #35's failure, made deterministic: a subscriber process runs before the player, and
    its DDS participant announces itself every 6 s instead of Fast DDS's default 3 s (as a
    loaded machine delays the 3 s announcements). A running participant answers a new one only
    with its next periodic announcement, so the player is told of the subscriber 3-5 s after it
    starts (the former 3 s discovery wait logged 'no subscriber on /chatter; playing anyway' and
    the subscriber got nothing); with default options every message must arrive, in order."""
    import contextlib
    import os
    import subprocess
    import sys

    project_profile = Path(os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"]).read_text()
    anchor = "<useBuiltinTransports>false</useBuiltinTransports>"
    assert anchor in project_profile
    slow = project_profile.replace(
        anchor,
        anchor + "<builtin><discovery_config><leaseAnnouncement><sec>6</sec></leaseAnnouncement>"
        "</discovery_config></builtin>",
    )
    (tmp_path / "slow.xml").write_text(slow)
    bag, data = _timed_bag(tmp_path, n=10, unheard=False)
    env = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(tmp_path / "slow.xml"))
    listener = subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("raw_listener.py")), "/chatter", "10"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    heard: list[str] = []
    player = None
    try:
        _collect(listener, heard)
        _wait_for_line(heard, "ready", listener)
        player = _player_process(bag)
        lines: list[str] = []
        _collect(player, lines)
        assert player.wait(40) == 0, "".join(lines)
        with contextlib.suppress(subprocess.TimeoutExpired):  # all acknowledged: seconds at most
            listener.wait(10)
        _stop(listener)
        log = "".join(lines)
        got = [line.split("heard: ", 1)[1].strip() for line in heard if "heard: " in line]
        assert got == [f"m{i}" for i in range(10)], log
        assert "subscribers matched after" in log and "no subscriber" not in log, log
    finally:
        _stop(player, listener)
