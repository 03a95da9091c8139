"""``bag_player``: replay a bag (rosbag2 MCAP or sqlite3, bare ``.mcap``, ROS 1 ``.bag``) into
the ROS graph.

The stored CDR bytes of a ROS 2 bag are published as they are (no deserialisation); the messages
of a ROS 1 bag (e.g. from ``kitti2bag``) are converted to CDR first, and a type that cannot be
converted is refused with one line. Original timing scaled by ``--rate`` (0 = as fast as
possible), optional topic selection, remapping (kitti2bag's topics onto the graph's: docs/bags.md)
and looping. Reading, conversion and pacing live in :mod:`vehicle_common.bags.replay`.

By default the replay starts once every topic's subscribers are matched, so that a subscriber
already running gets every message: at once when every topic has a matched subscriber, else
after ``--discovery-time`` seconds (7: a running participant may announce itself only that late,
see :data:`DISCOVERY_TIME`), and never before every subscriber the graph knows is matched.
``--wait-for-subscribers N`` waits instead for N subscriptions on every topic, and
``--wait-for-topics TOPIC:N,...`` for N on each TOPIC, a replayed one or one that another node
publishes (from that node's report on /diagnostics, as the KITTI player waits for the graph's
edges): a tracker's tracks reaching a recorder, a subscriber outside the graph; in both every
subscriber the graph knows on a replayed topic is matched as well (``--wait-timeout`` bounds
the wait). ``--immediate`` starts at once, as ``ros2 bag play`` does (it loses what is
published before its publishers are matched; its ``--delay`` is the fixed wait).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from vehicle_common.bags.reader import BagError
from vehicle_common.bags.replay import (
    BagMessage,
    StampSync,
    bag_types,
    check_stamped,
    iter_bag,
    message_class,
    output_types,
    paced,
    parse_remaps,
    parse_topics,
    ready_to_play,
    required_counts,
    stamp_sync,
)
from vehicle_common.graph_readiness import NodeReport, parse_topic_counts, unready_topics
from vehicle_common.node_runtime import DIAGNOSTICS_TOPIC, reports_from_message
from vehicle_common.option_checks import first_problem, number_problem

from vehicle_common import topics

QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
)


def _qos(topic: str) -> QoSProfile:
    """The replay QoS of a topic: :data:`QOS`, TRANSIENT_LOCAL for /tf_static (as tf2's static
    broadcaster: a late subscriber still gets the rig's transforms)."""
    if topic.rsplit("/", 1)[-1] in topics.TRANSIENT_LOCAL:
        return QoSProfile(
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            history=HistoryPolicy.KEEP_LAST,
            depth=1,
        )
    return QOS


#: Default wait [s] for a subscriber on a topic that none is known to subscribe to. A running
#: Fast DDS participant answers a newly started one only with its next periodic announcement
#: (every 3 s by default): measured here, a running subscriber saw each new player exactly at
#: its own 3.000 s ticks, so discovery took 0-3 s, and more than 3 s on a loaded machine (the
#: former 3 s wait lost the first messages in 4 of 8 runs under load). Two periods and a second.
DISCOVERY_TIME = 7.0


class BagPlayerNode(Node):
    """Publishes bag messages as raw CDR on one reliable publisher per output topic."""

    def __init__(self, types: dict[str, str], **kwargs):
        """``types``: ``{output topic: type name}`` of everything that will be published."""
        super().__init__("bag_player", **kwargs)
        self.pubs = {
            topic: self.create_publisher(message_class(t), topic, _qos(topic))
            for topic, t in types.items()
        }
        self.published = 0
        #: the other nodes' reports on /diagnostics (matched subscriptions of what they
        #: publish), read while waiting for ``--wait-for-topics``
        self.reports: dict[str, NodeReport] = {}
        self._report_sub = None

    def publish(self, msg: BagMessage) -> None:
        self.pubs[msg.topic].publish(msg.data)
        self.published += 1

    def unready(self, each: int, declared: dict[str, int]) -> list[str]:
        """Topics not yet matched as :func:`required_counts` says, ``"topic (have/want)"``:
        the replayed ones from their publishers, the others from the reports of the nodes
        that publish them (``--wait-for-topics``)."""
        matched = {t: p.get_subscription_count() for t, p in self.pubs.items()}
        known = {t: self.count_subscribers(t) for t in self.pubs}
        want = required_counts(known, each, declared)
        return unready_topics(want, matched, self.reports.values())

    def wait_for_subscribers(
        self, count: int, timeout_s: float, declared: dict[str, int] | None = None
    ) -> list[str]:
        """Wait until every replayed topic has ``count`` matched subscriptions, every topic of
        ``declared`` its count (other nodes' topics: from their reports on /diagnostics) and
        every subscription the ROS graph knows of on a replayed topic is matched, or the
        timeout; returns what is still unmatched (empty: ready)."""
        declared = {self.resolve_topic_name(t): n for t, n in (declared or {}).items()}
        if set(declared) - set(self.pubs) and self._report_sub is None:
            self._report_sub = self.create_subscription(
                DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_reports, 50
            )
        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(self)
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                unready = self.unready(count, declared)
                if not unready or time.monotonic() >= deadline:
                    return unready
                executor.spin_once(timeout_sec=0.02)
        finally:
            executor.remove_node(self)
            executor.shutdown(timeout_sec=0)
            if self._report_sub is not None:
                self.destroy_subscription(self._report_sub)
                self._report_sub = None

    def _on_reports(self, msg) -> None:
        for report in reports_from_message(msg):
            self.reports[report.node] = report

    def wait_for_matching(self, discovery_s: float, timeout_s: float) -> dict[str, int]:
        """Wait until :func:`ready_to_play` (or ``timeout_s``); returns the matched
        subscriptions per output topic."""
        start = time.monotonic()
        while True:
            elapsed = time.monotonic() - start
            matched = {t: p.get_subscription_count() for t, p in self.pubs.items()}
            known = {t: self.count_subscribers(t) for t in self.pubs}
            if ready_to_play(matched, known, elapsed, discovery_s) or elapsed >= timeout_s:
                return matched
            time.sleep(0.02)

    def wait_for_acks(self, timeout_s: float) -> bool:
        """Wait until reliable subscribers acknowledged everything (True) or the timeout."""
        return all(p.wait_for_all_acked(Duration(seconds=timeout_s)) for p in self.pubs.values())


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="bag_player", description=__doc__.splitlines()[0])
    ap.add_argument(
        "bag", help="rosbag2 directory (metadata.yaml + .mcap/.db3), a .mcap or a ROS 1 .bag file"
    )
    ap.add_argument("--rate", type=float, default=1.0, help="speed factor, 0 = fast as possible")
    ap.add_argument("--topics", action="append", default=[], help="topics to play, a,b,...")
    ap.add_argument("--remap", action="append", default=[], help="/old:=/new (repeatable)")
    ap.add_argument("--loop", action="store_true", help="play the bag again and again")
    ap.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        help="wait until every topic has this many subscriptions before playing (and every "
        "subscription the ROS graph knows of is matched)",
    )
    ap.add_argument(
        "--wait-for-topics",
        default="",
        metavar="TOPIC:N,...",
        help="wait until each TOPIC has N matched subscriptions before playing: a replayed topic "
        "(its publisher here) or one another node of the graph publishes (as that node reports "
        "on /diagnostics), e.g. a subscriber outside the graph on the tracks",
    )
    ap.add_argument("--wait-timeout", type=float, default=10.0, help="limit of that wait [s]")
    ap.add_argument(
        "--discovery-time",
        type=float,
        default=DISCOVERY_TIME,
        help="without --wait-for-subscribers: wait up to this long [s] for a subscriber on "
        "every topic before playing (all subscribers the graph knows are always matched first; "
        "a running DDS participant may announce itself only 3 s after this one starts)",
    )
    ap.add_argument(
        "--immediate",
        action="store_true",
        help="start playing at once, without waiting for subscribers (as `ros2 bag play`)",
    )
    ap.add_argument("--ack-timeout", type=float, default=5.0, help="wait for acks at end [s]")
    ap.add_argument(
        "--sync-stamps",
        action="append",
        default=[],
        help="REF,TOPIC,...: give the TOPICs' messages the header stamp of REF's nearest message "
        "(a stereo pair stamped by two clocks, e.g. kitti2bag's cameras; bag topic names)",
    )
    ap.add_argument(
        "--sync-tolerance", type=float, default=0.01, help="largest stamp difference synced [s]"
    )
    return ap


def check_options(args) -> str | None:
    """One line for the first numeric option that cannot be used (a negative, NaN or infinite
    --rate was accepted), else None."""
    seconds = ("--wait-timeout", "--discovery-time", "--ack-timeout", "--sync-tolerance")
    return first_problem(
        number_problem("--rate", args.rate, minimum=0.0, why="speed factor, 0 = fast as possible"),
        number_problem("--wait-for-subscribers", args.wait_for_subscribers, minimum=0),
        *(
            number_problem(option, getattr(args, option[2:].replace("-", "_")), minimum=0.0)
            for option in seconds
        ),
    )


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """(own arguments, ROS arguments): the ROS ones are those between ``--ros-args`` and ``--``
    (or the end). rclpy's ``remove_ros_args`` is not used for this, as it also takes
    ``/old:=/new`` (a remapping rule for rcl) out of ``--remap /old:=/new``."""
    own, ros, inside = [], [], False
    for a in argv:
        if a == "--ros-args":
            inside = True
        elif inside and a == "--":
            inside = False
            continue
        (ros if inside else own).append(a)
    return own, ros


@dataclass
class ReplayPlan:
    """What ``bag_player`` plays, checked before rclpy starts: the subscriptions to wait for
    (``--wait-for-topics``), remapping, topic selection, the output types, the stamp sync."""

    declared: dict[str, int]
    remap: dict[str, str]
    topics: list[str] | None
    types: dict[str, str]
    sync: StampSync | None


def plan_replay(args) -> ReplayPlan:
    """The :class:`ReplayPlan` of the parsed options; BagError (one line) for an option or a
    bag that cannot be played."""
    try:
        declared = parse_topic_counts(args.wait_for_topics)
    except ValueError as exc:
        raise BagError(f"--wait-for-topics: {exc}") from None
    remap = parse_remaps(args.remap)
    topics = parse_topics(args.topics)
    types = output_types(args.bag, topics, remap)
    for type_name in types.values():
        message_class(type_name)
    sync = None
    if args.sync_stamps:
        sync_topics = parse_topics(args.sync_stamps)
        check_stamped(bag_types(args.bag), sync_topics)
        sync = stamp_sync(args.bag, sync_topics, remap, args.sync_tolerance)
    return ReplayPlan(declared, remap, topics, types, sync)


def wait_before_playing(node: BagPlayerNode, args, plan: ReplayPlan) -> None:
    """Wait for the subscribers as the options say (none with ``--immediate``), logging who
    was matched and who was not."""
    log = node.get_logger()
    if args.wait_for_subscribers > 0 or plan.declared:
        unready = node.wait_for_subscribers(
            args.wait_for_subscribers, args.wait_timeout, plan.declared
        )
        if unready:
            log.warning(
                f"not matched after {args.wait_timeout} s: {', '.join(unready)}; playing anyway"
            )
    elif not args.immediate:
        log.info(
            f"waiting up to {args.discovery_time} s for a subscriber on each of "
            f"{len(plan.types)} topics (--immediate: start at once)"
        )
        start = time.monotonic()
        limit = max(args.wait_timeout, args.discovery_time)
        matched = node.wait_for_matching(args.discovery_time, limit)
        waited = time.monotonic() - start
        heard = [f"{t} ({n})" for t, n in sorted(matched.items()) if n]
        if heard:
            log.info(f"subscribers matched after {waited:.1f} s: {', '.join(heard)}")
        unheard = sorted(t for t, n in matched.items() if n == 0)
        if unheard:
            log.info(f"no subscriber on {', '.join(unheard)}; playing anyway")


def play(node: BagPlayerNode, args, plan: ReplayPlan) -> None:
    """Publish the bag (again and again with ``--loop``) at ``--rate``, then wait for the
    subscribers' acknowledgements and log what was done."""
    log = node.get_logger()
    sync = plan.sync
    log.info(f"playing {args.bag}: {len(plan.types)} topics at rate {args.rate}")
    while True:
        messages = iter_bag(args.bag, plan.topics, plan.remap)
        for msg in paced(sync(messages) if sync else messages, args.rate):
            if not rclpy.ok():
                break
            node.publish(msg)
        if not args.loop or not rclpy.ok():
            break
    if not node.wait_for_acks(args.ack_timeout):
        log.warning(f"not all messages acknowledged within {args.ack_timeout} s")
    if sync is not None:
        log.info(
            f"--sync-stamps: {sync.restamped} messages restamped, {sync.unmatched} without a "
            f"reference stamp within {args.sync_tolerance} s"
        )
    log.info(f"done: {node.published} messages published")


def main(argv: list[str] | None = None) -> int:
    """Console script ``bag_player``; returns the exit code (2 on bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    own, ros_args = split_ros_args(argv)
    args = _parser().parse_args(own)
    problem = check_options(args)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        plan = plan_replay(args)
    except BagError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rclpy.init(args=["bag_player", *ros_args])
    node = None
    try:
        node = BagPlayerNode(plan.types)
        wait_before_playing(node, args, plan)
        play(node, args, plan)
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
