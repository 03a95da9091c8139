"""``bag_recorder`` node: records the pipeline's topics into a rosbag2/MCAP bag.

Subscriptions are raw (CDR bytes, no deserialisation) and RELIABLE with a deep queue; topic
types are discovered from the ROS graph every ``discovery_period`` seconds (a topic whose
publisher appears late is picked up) unless given as ``topic:pkg/msg/Type``. Every message is
written with its receive time (ns, as rosbag2 does) through :class:`eval_node.bag_writer.BagWriter`.
SIGINT/SIGTERM stop the node cleanly: pending messages are taken and written, the bag is closed
and the message count of each topic is logged.
"""

from __future__ import annotations

import importlib
import signal
import sys
import time
from datetime import datetime
from pathlib import Path

#: The pipeline's topics (docs/ARCHITECTURE.md) recorded by default. Their types are given so
#: that the recorder subscribes at start-up (before any publisher exists) and misses nothing.
PIPELINE_TOPICS = [
    "/stereo/left/camera_info:sensor_msgs/msg/CameraInfo",
    "/stereo/right/camera_info:sensor_msgs/msg/CameraInfo",
    "/kitti/ground_truth:stereo_vehicle_msgs/msg/KittiFrameLabels",
    "/clock:rosgraph_msgs/msg/Clock",
    "/vehicles/detections_2d:stereo_vehicle_msgs/msg/VehicleDetection2DArray",
    "/vehicles/detections_3d:stereo_vehicle_msgs/msg/VehicleDetection3DArray",
    "/vehicles/tracks:stereo_vehicle_msgs/msg/TrackedVehicleArray",
    "/vehicles/track_markers:visualization_msgs/msg/MarkerArray",
]
#: Large image-like topics, recorded only with ``include_images``.
IMAGE_TOPICS = [
    "/stereo/left/image_rect:sensor_msgs/msg/Image",
    "/stereo/right/image_rect:sensor_msgs/msg/Image",
    "/stereo/disparity:stereo_msgs/msg/DisparityImage",
    "/stereo/points:sensor_msgs/msg/PointCloud2",
]


def default_output() -> str:
    """A timestamped bag directory under ./output/bags."""
    return str(Path("output") / "bags" / datetime.now().strftime("run_%Y%m%d_%H%M%S"))


def parse_topics(entries: list[str], include_images: bool) -> dict[str, str | None]:
    """``['/a', '/b:pkg/msg/T']`` -> ``{'/a': None, '/b': 'pkg/msg/T'}`` (None: discover)."""
    topics: dict[str, str | None] = {}
    for entry in entries:
        entry = entry.strip()
        if not entry:
            continue
        name, _, msgtype = entry.partition(":")
        topics[name] = msgtype or None
    if include_images:
        for entry in IMAGE_TOPICS:
            name, _, msgtype = entry.partition(":")
            topics.setdefault(name, msgtype or None)
    return topics


def _message_class(msgtype: str):
    pkg, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def main(args: list[str] | None = None) -> int:
    """Run the recorder until SIGINT/SIGTERM."""
    import rclpy
    import rclpy.executors
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    from eval_node.bag_writer import BagWriter, BagWriterError

    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("bag_recorder")
    log = node.get_logger()
    output = node.declare_parameter("output", "").value or default_output()
    entries = list(node.declare_parameter("topics", PIPELINE_TOPICS).value)
    include_images = bool(node.declare_parameter("include_images", False).value)
    compression = str(node.declare_parameter("compression", "none").value)
    compression_mode = str(node.declare_parameter("compression_mode", "storage").value)
    max_bag_size = int(node.declare_parameter("max_bag_size", 0).value)
    qos_depth = int(node.declare_parameter("qos_depth", 100).value)
    discovery_period = float(node.declare_parameter("discovery_period", 0.5).value)
    flush_period = float(node.declare_parameter("flush_period", 1.0).value)

    try:
        # flush_period: a writer thread puts chunks on disk (fsync off the executor thread)
        writer = BagWriter(
            output, compression, compression_mode, max_bag_size, flush_period=flush_period
        )
    except (BagWriterError, OSError) as exc:
        log.error(f"cannot record: {exc}")
        node.destroy_node()
        rclpy.try_shutdown()
        return 2

    wanted = parse_topics(entries, include_images)
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=qos_depth, reliability=ReliabilityPolicy.RELIABLE
    )
    subs = {}
    last_ns = [0]

    def subscribe(topic: str, msgtype: str) -> None:
        try:
            cls = _message_class(msgtype)
            writer.add_topic(topic, msgtype)
        except (ImportError, AttributeError, ValueError, BagWriterError) as exc:
            log.warning(f"{topic}: cannot record type {msgtype}: {exc}")
            wanted.pop(topic, None)
            return

        def callback(data: bytes, topic: str = topic) -> None:
            now = max(time.time_ns(), last_ns[0])
            last_ns[0] = now
            writer.write(topic, data, now)

        subs[topic] = node.create_subscription(cls, topic, callback, qos, raw=True)
        log.info(f"recording {topic} [{msgtype}]")

    def discover() -> None:
        pending = [t for t in wanted if t not in subs]
        if not pending:
            return
        graph = dict(node.get_topic_names_and_types())
        for topic in pending:
            msgtype = wanted[topic] or (graph.get(topic) or [None])[0]
            if msgtype:
                subscribe(topic, msgtype)

    discover()
    node.create_timer(discovery_period, discover)
    log.info(f"bag {output}: waiting for {len(wanted)} topics")

    stop = []

    def on_signal(signum, _frame) -> None:
        stop.append(signum)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop:
            executor.spin_once(timeout_sec=0.1)
        # Drain: take what is still queued in the subscriptions before closing.
        idle_since = time.monotonic()
        before = sum(writer.counts.values())
        while time.monotonic() - idle_since < 0.3:
            executor.spin_once(timeout_sec=0.05)
            now = sum(writer.counts.values())
            if now != before:
                before, idle_since = now, time.monotonic()
    finally:
        counts = writer.close()
        for topic in writer.types:
            log.info(f"{topic}: {counts.get(topic, 0)} messages")
        log.info(
            f"bag {output} closed: {sum(counts.values())} messages in {len(writer.files)} file(s)"
        )
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
