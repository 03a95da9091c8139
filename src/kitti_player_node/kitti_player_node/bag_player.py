"""``bag_player``: replay an MCAP bag (rosbag2 layout or a bare ``.mcap``) into the ROS graph.

The stored CDR bytes are published as they are (no deserialisation), with the original timing
scaled by ``--rate`` (0 = as fast as possible), optional topic selection, remapping and looping.
Reading and pacing live in :mod:`.bag_replay`.
"""

from __future__ import annotations

import argparse
import sys
import time

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from vehicle_common.bag_files import BagError

from .bag_replay import (
    BagMessage,
    iter_bag,
    message_class,
    output_types,
    paced,
    parse_remaps,
    parse_topics,
)

QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
)


class BagPlayerNode(Node):
    """Publishes bag messages as raw CDR on one reliable publisher per output topic."""

    def __init__(self, types: dict[str, str], **kwargs):
        """``types``: ``{output topic: type name}`` of everything that will be published."""
        super().__init__("bag_player", **kwargs)
        self.pubs = {
            topic: self.create_publisher(message_class(t), topic, QOS) for topic, t in types.items()
        }
        self.published = 0

    def publish(self, msg: BagMessage) -> None:
        self.pubs[msg.topic].publish(msg.data)
        self.published += 1

    def wait_for_subscribers(self, count: int, timeout_s: float) -> bool:
        """Wait until every publisher has ``count`` subscriptions (True) or the timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(p.get_subscription_count() >= count for p in self.pubs.values()):
                return True
            time.sleep(0.02)
        return False

    def wait_for_acks(self, timeout_s: float) -> bool:
        """Wait until reliable subscribers acknowledged everything (True) or the timeout."""
        return all(p.wait_for_all_acked(Duration(seconds=timeout_s)) for p in self.pubs.values())


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="bag_player", description=__doc__.splitlines()[0])
    ap.add_argument("bag", help="rosbag2 directory (metadata.yaml + .mcap) or a .mcap file")
    ap.add_argument("--rate", type=float, default=1.0, help="speed factor, 0 = fast as possible")
    ap.add_argument("--topics", action="append", default=[], help="topics to play, a,b,...")
    ap.add_argument("--remap", action="append", default=[], help="/old:=/new (repeatable)")
    ap.add_argument("--loop", action="store_true", help="play the bag again and again")
    ap.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        help="wait until every topic has this many subscriptions before playing",
    )
    ap.add_argument("--wait-timeout", type=float, default=10.0, help="limit of that wait [s]")
    ap.add_argument(
        "--discovery-time",
        type=float,
        default=0.5,
        help="without --wait-for-subscribers: seconds to let discovery match first",
    )
    ap.add_argument("--ack-timeout", type=float, default=5.0, help="wait for acks at end [s]")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Console script ``bag_player``; returns the exit code (2 on bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(remove_ros_args(["bag_player", *argv])[1:])
    try:
        remap = parse_remaps(args.remap)
        topics = parse_topics(args.topics)
        types = output_types(args.bag, topics, remap)
        for type_name in types.values():
            message_class(type_name)
    except BagError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rclpy.init(args=["bag_player", *argv])
    node = None
    try:
        node = BagPlayerNode(types)
        log = node.get_logger()
        if args.wait_for_subscribers > 0:
            if not node.wait_for_subscribers(args.wait_for_subscribers, args.wait_timeout):
                log.warning(
                    f"not every topic has {args.wait_for_subscribers} subscriptions after "
                    f"{args.wait_timeout} s; playing anyway"
                )
        elif args.discovery_time > 0:
            time.sleep(args.discovery_time)
        log.info(f"playing {args.bag}: {len(types)} topics at rate {args.rate}")
        while True:
            for msg in paced(iter_bag(args.bag, topics, remap), args.rate):
                if not rclpy.ok():
                    break
                node.publish(msg)
            if not args.loop or not rclpy.ok():
                break
        if not node.wait_for_acks(args.ack_timeout):
            log.warning(f"not all messages acknowledged within {args.ack_timeout} s")
        log.info(f"done: {node.published} messages published")
        return 0
    except BagError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
