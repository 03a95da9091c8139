"""``bag_recorder`` node: records the pipeline's topics into a rosbag2/MCAP bag.

Subscriptions are raw (CDR bytes, no deserialisation) and RELIABLE with a deep queue; topic
types are discovered from the ROS graph every ``discovery_period`` seconds (a topic whose
publisher appears late is picked up) unless given as ``topic:pkg/msg/Type``. Every message is
written with its receive time (ns, as rosbag2 does) through
:class:`vehicle_common.bags.writer.BagWriter`.
SIGINT/SIGTERM stop the node cleanly: pending messages are taken and written, the bag is closed
and the message count of each topic is logged. Topic names are relative: they are resolved in
the node's namespace and recorded under their resolved names (``/rig2/vehicles/tracks``).
"""

from __future__ import annotations

import importlib
import sys
import time
from datetime import datetime
from pathlib import Path

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from vehicle_common.bags.repeated_stamps import (
    FRAME_TOPICS,
    RepeatedStamps,
    header_stamp,
    mixed_runs_hint,
)
from vehicle_common.bags.writer import BagWriter, BagWriterError
from vehicle_common.node_parameters import (
    EXIT_BAD_PARAMETER,
    ParameterError,
    check_overrides,
    declare_config,
    parameter_error_line,
)
from vehicle_common.node_runtime import (
    StopRequest,
    apply_process_settings,
    init_rclpy,
    make_executor,
)

from eval_node.parameters import RecorderParameters
from vehicle_common import topics as graph_topics

NODE_NAME = "bag_recorder"


def image_topics(transport: str = "raw") -> list[str]:
    """``topic:type`` of the image-like topics recorded with ``include_images``: the camera
    images where they travel with ``transport`` ("raw": sensor_msgs/Image on the image topics,
    "compressed": sensor_msgs/CompressedImage on ``<image topic>/compressed``, as the player's
    png/jpeg send them), the disparity and the point cloud."""
    out = []
    for t in graph_topics.RECORDED_IMAGES:
        if t in graph_topics.CAMERA_IMAGES:
            t = graph_topics.image_topic(t, transport)
        out.append(f"{t}:{graph_topics.TYPES[t]}")
    return out


def default_output() -> str:
    """A timestamped bag directory under ./output/bags."""
    return str(Path("output") / "bags" / datetime.now().strftime("run_%Y%m%d_%H%M%S"))


def parse_topics(
    entries: list[str], include_images: bool, image_transport: str = "raw"
) -> dict[str, str | None]:
    """``['a', '/b:pkg/msg/T']`` -> ``{'a': None, '/b': 'pkg/msg/T'}`` (None: discover), plus
    the :func:`image_topics` of ``image_transport`` with ``include_images``."""
    topics: dict[str, str | None] = {}
    for entry in entries:
        entry = entry.strip()
        if not entry:
            continue
        name, _, msgtype = entry.partition(":")
        topics[name] = msgtype or None
    if include_images:
        for entry in image_topics(image_transport):
            name, _, msgtype = entry.partition(":")
            topics.setdefault(name, msgtype or None)
    return topics


def _message_class(msgtype: str):
    pkg, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class BagRecorderNode(Node):
    """Raw subscriptions to the wanted topics (resolved in the node's namespace), each message
    written with its receive time through :class:`BagWriter`; new topics' types are discovered
    every ``discovery_period``; a chunk is written out at ``flush_messages`` messages or
    ``flush_period`` of age, and the writer's thread fsyncs the bag every ``flush_period``."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        p = declare_config(self, RecorderParameters)
        check_overrides(self)  # every parameter is declared: refuse one the node has not
        self.output = p.output or default_output()
        # flush_period: a writer thread puts chunks on disk (fsync off the executor thread)
        self.writer = BagWriter(
            self.output,
            p.compression,
            p.compression_mode,
            p.max_bag_size,
            flush_period=p.flush_period,
            flush_messages=p.flush_messages,
        )
        if self.writer.replaced_empty:
            self.get_logger().info(
                f"bag {self.output}: replaced an empty bag (no message recorded) left there by "
                "a start that failed"
            )
        self.wanted = {
            self.resolve_topic_name(name): msgtype
            for name, msgtype in parse_topics(p.topics, p.include_images, p.image_transport).items()
        }
        self.qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=p.qos_depth,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        # /tf_static's publisher keeps its last message (TRANSIENT_LOCAL): ask for it too, so
        # that the rig's transforms published before the recorder matched are recorded
        self.latched = {self.resolve_topic_name(t) for t in graph_topics.TRANSIENT_LOCAL}
        self.latched_qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=p.qos_depth,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        self.subs = {}
        self._last_ns = 0
        #: the OSError that stopped the recording (ENOSPC: a full disk); main() exits 1 on it
        self.failed: OSError | None = None
        #: the per-frame topics (resolved) whose stamps must not repeat
        self.frame_topics = {self.resolve_topic_name(t) for t in FRAME_TOPICS}
        self.stamps = RepeatedStamps()
        self.discover()
        self.create_timer(p.discovery_period, self.discover)
        self.get_logger().info(f"bag {self.output}: waiting for {len(self.wanted)} topics")

    def subscribe(self, topic: str, msgtype: str) -> None:
        try:
            cls = _message_class(msgtype)
            self.writer.add_topic(topic, msgtype)
        except (ImportError, AttributeError, ValueError, BagWriterError) as exc:
            self.get_logger().warning(f"{topic}: cannot record type {msgtype}: {exc}")
            self.wanted.pop(topic, None)
            return

        frame_topic = topic in self.frame_topics

        def callback(data: bytes, topic: str = topic) -> None:
            if self.failed is not None:
                return  # the bag cannot be written (a full disk): the node is stopping
            now = max(time.time_ns(), self._last_ns)
            self._last_ns = now
            try:
                self.writer.write(topic, data, now)
            except OSError as exc:
                self.failed = exc
                return
            if frame_topic:
                self._check_stamp(topic, data)

        qos = self.latched_qos if topic in self.latched else self.qos
        self.subs[topic] = self.create_subscription(cls, topic, callback, qos, raw=True)
        self.get_logger().info(f"recording {topic} [{msgtype}]")

    def _check_stamp(self, topic: str, data: bytes) -> None:
        """Warn (once per topic) when a frame's stamp arrives twice: another graph publishes
        on this topic (:mod:`vehicle_common.bags.repeated_stamps`)."""
        stamp = header_stamp(bytes(data[:12]))
        if stamp is None or not self.stamps.add(topic, stamp) or self.stamps.repeats[topic] > 1:
            return
        self.get_logger().warning(
            f"{topic}: a second message stamped {stamp * 1e-9:.3f} s "
            f"({self.count_publishers(topic)} publishers): this bag mixes runs and `evaluate "
            f"bag` will refuse it; {mixed_runs_hint()}"
        )

    def discover(self) -> None:
        pending = [t for t in self.wanted if t not in self.subs]
        if not pending:
            return
        graph = dict(self.get_topic_names_and_types())
        for topic in pending:
            msgtype = self.wanted[topic] or (graph.get(topic) or [None])[0]
            if msgtype:
                self.subscribe(topic, msgtype)

    def message_count(self) -> int:
        return sum(self.writer.counts.values())

    def write_error(self) -> OSError | None:
        """The error that stopped the recording (a message's write or the flush thread's)."""
        return self.failed or self.writer.error

    def failure_line(self, exc: OSError) -> str:
        """One line naming the node, the bag and the cause (a full disk: ENOSPC)."""
        why = exc.strerror or str(exc)
        return (
            f"error: {NODE_NAME}: cannot write the bag {self.output}: {why} (errno "
            f"{exc.errno}); recording stopped; the bag holds what was flushed before "
            f"(evaluate and bag_player read it; `bag_recover {self.output}` repairs it)"
        )

    def close(self) -> None:
        """Close the bag and log the message count of each topic. A bag that cannot be closed
        (the disk is full) is left as a crashed recorder leaves it: readable up to its last
        complete chunk."""
        log = self.get_logger()
        try:
            counts = self.writer.close()
        except OSError as exc:
            self.failed = self.failed or exc
            return
        for topic in self.writer.types:
            log.info(f"{topic}: {counts.get(topic, 0)} messages")
        log.info(
            f"bag {self.output} closed: {sum(counts.values())} messages in "
            f"{len(self.writer.files)} file(s)"
        )


def main(args: list[str] | None = None) -> int:
    """Run the recorder until SIGINT/SIGTERM; exit code 2 for a bad parameter or output."""
    if not init_rclpy(args, NODE_NAME):
        return EXIT_BAD_PARAMETER
    # armed from the start: a signal while the recorder subscribes (its first discovery imports
    # every topic's type support, seconds on a cold disk) lets it finish, then what its
    # subscriptions already hold is drained into the bag (before: KeyboardInterrupt, a
    # traceback and those messages lost)
    stop = StopRequest.install()
    stop.arm()
    try:
        node = BagRecorderNode()
    except ParameterError as exc:
        print(parameter_error_line(NODE_NAME, exc), file=sys.stderr)
        rclpy.try_shutdown()
        return EXIT_BAD_PARAMETER
    except (BagWriterError, OSError) as exc:
        print(f"error: {NODE_NAME}: cannot record: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2

    # the node's ``executor`` parameter (EventsExecutor by default: its per-message cost is in
    # C++, ARCHITECTURE.md "CPU per frame")
    executor = make_executor(node.executor_kind, node.context)
    executor.add_node(node)
    try:
        while stop.requested is None and node.write_error() is None:
            executor.spin_once(timeout_sec=0.1)
        # Drain: take what is still queued in the subscriptions before closing.
        idle_since = time.monotonic()
        before = node.message_count()
        while time.monotonic() - idle_since < 0.3 and node.write_error() is None:
            executor.spin_once(timeout_sec=0.05)
            now = node.message_count()
            if now != before:
                before, idle_since = now, time.monotonic()
    finally:
        node.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    error = node.write_error()
    if error is not None:  # one line, no traceback (before: chained OSError tracebacks)
        print(node.failure_line(error), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
