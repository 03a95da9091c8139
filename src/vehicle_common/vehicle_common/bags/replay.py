"""Replay core (no rclpy): open a bag (rosbag2 layout with MCAP or sqlite3 storage, a bare
``.mcap``, or a ROS 1 ``.bag`` such as ``kitti2bag`` writes), read it as a stream of (topic, ROS 2
type name, timestamp, CDR bytes) with topic selection and remapping, and pace it.

ROS 1 messages are converted to the CDR of their ROS 2 type as they are read
(:func:`vehicle_common.message_definitions.ros1_to_cdr_converter`); a type without a ROS 2
definition here is refused with one line before anything is published.

Used by the ``bag_player`` node (:mod:`kitti_player_node.bag_player`), which publishes the bytes
as they are; bags are opened with :func:`.reader.open_reader`.
"""

from __future__ import annotations

import bisect
import dataclasses
import importlib
import struct
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from ..message_definitions import (
    MessageDefinitions,
    UnknownMessageType,
    ros1_to_cdr_converter,
    ros2_type_name,
)
from .reader import BagError, bag_messages, open_reader


@dataclass(frozen=True)
class BagMessage:
    """One stored message: output topic (after remapping), ROS 2 type name such as
    ``std_msgs/msg/String``, receive timestamp in ns and the serialized CDR bytes (converted
    from ROS 1 for a ``.bag``)."""

    topic: str
    type_name: str
    timestamp_ns: int
    data: bytes


def parse_remaps(items: Iterable[str]) -> dict[str, str]:
    """``["/old:=/new", ...]`` -> ``{"/old": "/new"}``."""
    remap = {}
    for item in items:
        old, sep, new = item.partition(":=")
        if not sep or not old or not new:
            raise BagError(f"--remap: {item!r} is not of the form /old:=/new")
        remap[old] = new
    return remap


def parse_topics(items: Iterable[str]) -> list[str] | None:
    """Comma-separated (and/or repeated) topic lists -> one list, or None for all topics."""
    topics = [t.strip() for item in items for t in item.split(",") if t.strip()]
    return topics or None


def _check_topics(available: Iterable[str], topics: Iterable[str] | None, path) -> None:
    """Raise BagError when a requested topic is not among the bag's ``available`` topics."""
    if topics is not None:
        missing = sorted(set(topics) - set(available))
        if missing:
            raise BagError(f"--topics: {', '.join(missing)} not in bag {path}")


def _cdr_converters(reader, conns, path) -> dict[int, Callable[[bytes], bytes]]:
    """Per connection id of a ROS 1 bag, the ROS 1 -> CDR converter (empty for a ROS 2 bag,
    whose messages are CDR already); BagError naming the topic for a type that has none."""
    if reader.is2:
        return {}
    defs = MessageDefinitions()
    out = {}
    for c in conns:
        try:
            out[c.id] = ros1_to_cdr_converter(reader.typestore, c.msgtype, defs)
        except UnknownMessageType as exc:
            raise BagError(
                f"{path}: {c.topic}: ROS 1 messages cannot be converted to ROS 2 ({exc})"
            ) from None
    return out


def iter_bag(
    path: str | Path,
    topics: Iterable[str] | None = None,
    remap: dict[str, str] | None = None,
) -> Iterator[BagMessage]:
    """The bag's messages in timestamp order, restricted to ``topics`` (all when None), with
    topic names remapped. Unknown topics in ``topics`` raise BagError."""
    remap = remap or {}
    reader = open_reader(path)
    try:
        _check_topics((c.topic for c in reader.connections), topics, path)
        if topics is not None:
            conns = [c for c in reader.connections if c.topic in set(topics)]
        else:
            conns = list(reader.connections)
        if not conns:
            return
        convert = _cdr_converters(reader, conns, path)
        for conn, timestamp, data in bag_messages(reader, path, conns):
            try:
                raw = convert[conn.id](data) if convert else bytes(data)
            except BagError:
                raise
            except Exception as exc:
                raise BagError(f"{path}: cannot read bag ({exc})") from None
            yield BagMessage(
                remap.get(conn.topic, conn.topic),
                ros2_type_name(conn.msgtype),
                int(timestamp),
                raw,
            )
    finally:
        reader.close()


def header_stamp(data: bytes) -> int:
    """The header stamp [ns] of a serialized message whose first field is a std_msgs/Header
    (little-endian CDR: 4 bytes of encapsulation, then int32 sec, uint32 nanosec)."""
    if len(data) < 12 or data[:2] != b"\x00\x01":
        raise BagError("--sync-stamps: a message is not little-endian CDR")
    sec, nanosec = struct.unpack_from("<iI", data, 4)
    return sec * 1_000_000_000 + nanosec


def with_header_stamp(data: bytes, stamp_ns: int) -> bytes:
    """``data`` with its header stamp set to ``stamp_ns`` (see :func:`header_stamp`)."""
    out = bytearray(data)
    struct.pack_into("<iI", out, 4, *divmod(int(stamp_ns), 1_000_000_000))
    return bytes(out)


def check_stamped(types: dict[str, str], topics: Iterable[str]) -> None:
    """BagError unless every topic's type (``types``: bag topic -> ROS 2 type) starts with a
    std_msgs/Header, as --sync-stamps needs."""
    defs = MessageDefinitions(BagError)
    for topic in topics:
        if topic not in types:
            raise BagError(f"--sync-stamps: {topic} not in the bag")
        defs.get(types[topic])
        first = defs.typestore.fielddefs[types[topic]][1][0]
        if first[0] != "header" or first[1][1] != "std_msgs/msg/Header":
            raise BagError(f"--sync-stamps: {topic} ({types[topic]}) has no header")


@dataclasses.dataclass
class StampSync:
    """Gives the messages of ``topics`` (output names) the header stamp of the nearest message
    of the reference topic (``reference``: its sorted header stamps [ns]) when it is within
    ``tolerance_ns``: a stereo pair stamped by two clocks (kitti2bag stamps each camera from its
    own timestamps.txt) becomes the exact-stamp pair stereo depth matches."""

    reference: list[int]
    topics: set[str]
    tolerance_ns: int
    restamped: int = 0
    unmatched: int = 0

    def __call__(self, messages: Iterable[BagMessage]) -> Iterator[BagMessage]:
        for msg in messages:
            if msg.topic in self.topics and self.reference:
                stamp = header_stamp(msg.data)
                i = bisect.bisect_left(self.reference, stamp)
                near = min(self.reference[max(i - 1, 0) : i + 1], key=lambda r: abs(r - stamp))
                if abs(near - stamp) > self.tolerance_ns:
                    self.unmatched += 1
                elif near != stamp:
                    self.restamped += 1
                    msg = dataclasses.replace(msg, data=with_header_stamp(msg.data, near))
            yield msg


def stamp_sync(path, topics: list[str], remap: dict[str, str], tolerance_s: float) -> StampSync:
    """The :class:`StampSync` of ``topics`` (bag names, the first the reference) in the bag."""
    if len(topics) < 2:
        raise BagError("--sync-stamps: give the reference topic and at least one other")
    if not tolerance_s > 0:
        raise BagError(f"--sync-tolerance: {tolerance_s} must be > 0")
    reference = sorted(header_stamp(m.data) for m in iter_bag(path, topics[:1]))
    followers = {remap.get(t, t) for t in topics[1:]}
    return StampSync(reference, followers, round(tolerance_s * 1e9))


def paced(
    messages: Iterable[BagMessage],
    rate: float = 1.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[BagMessage]:
    """Yield ``messages`` at their recorded spacing divided by ``rate`` (``rate <= 0``: at once).

    Message i is released at ``t0 + (stamp_i - stamp_0) / rate`` wall seconds, so small delays in
    publishing do not accumulate.
    """
    t0 = first = None
    for msg in messages:
        if rate > 0:
            if t0 is None:
                t0, first = clock(), msg.timestamp_ns
            delay = t0 + (msg.timestamp_ns - first) * 1e-9 / rate - clock()
            if delay > 0:
                sleep(delay)
        yield msg


def ready_to_play(
    matched: dict[str, int], known: dict[str, int], elapsed_s: float, discovery_s: float
) -> bool:
    """Whether a replay may start without losing messages to subscribers already running.

    ``matched``: subscriptions matched per output topic; ``known``: subscriptions the ROS graph
    knows per topic (discovery can know of one before its publisher has matched it). Ready when
    every known subscription is matched and every topic has one; after ``discovery_s`` seconds
    topics nobody subscribes to no longer hold the start back. A running Fast DDS participant
    answers a newcomer only with its next periodic announcement (every 3 s by default), so a
    subscriber that runs before the replay can stay unknown for that long, and longer on a loaded
    machine: ``discovery_s`` must cover it (``bag_player.DISCOVERY_TIME``)."""
    if any(matched.get(t, 0) < n for t, n in known.items()):
        return False
    return all(n > 0 for n in matched.values()) or elapsed_s >= discovery_s


def required_counts(
    known: dict[str, int], each: int = 0, declared: dict[str, int] | None = None
) -> dict[str, int]:
    """The subscriptions to wait for per topic with ``--wait-for-subscribers`` (``each``: on
    every replayed topic of ``known``) or ``--wait-for-topics`` (``declared``: any topic of the
    graph, the replayed ones and those other nodes publish): never fewer, on a replayed topic,
    than the subscriptions the ROS graph already knows of (``known``), so that a replay starts
    only once every subscriber of every topic it replays is matched (a count reached with one
    subscriber while another one is still unmatched lost that one the first messages)."""
    out = dict(declared or {})
    for topic, n in known.items():
        out[topic] = max(out.get(topic, 0), each, n)
    return out


def message_class(type_name: str):
    """The Python message class of ``pkg/msg/Name`` (or ``pkg/Name``)."""
    parts = type_name.split("/")
    if len(parts) not in (2, 3) or not all(parts):
        raise BagError(f"{type_name}: not a ROS message type name")
    try:
        return getattr(importlib.import_module(parts[0] + ".msg"), parts[-1])
    except (ImportError, AttributeError):
        raise BagError(f"{type_name}: message type not available in this installation") from None


def bag_types(path: str | Path) -> dict[str, str]:
    """``{bag topic: ROS 2 type name}``."""
    reader = open_reader(path)
    try:
        return {c.topic: ros2_type_name(c.msgtype) for c in reader.connections}
    finally:
        reader.close()


def output_types(path: str | Path, topics: list[str] | None, remap: dict[str, str]):
    """``{output topic: ROS 2 type name}`` of the selected topics after remapping; BagError
    when they hold no message at all (nothing to play: an empty recording, or topics that
    never got a message) and, for a ROS 1 bag, when one of them cannot be converted (before
    anything is published)."""
    reader = open_reader(path)
    try:
        types = {c.topic: ros2_type_name(c.msgtype) for c in reader.connections}
        _check_topics(types, topics, path)
        selected = [c for c in reader.connections if c.topic in (topics or types)]
        if not sum(int(c.msgcount or 0) for c in selected):
            where = f" on {', '.join(topics)}" if topics else ""
            raise BagError(
                f"{path}: no message to play{where} ({len(types)} topics, "
                f"{sum(int(c.msgcount or 0) for c in reader.connections)} messages in the bag)"
            )
        _cdr_converters(reader, selected, path)
    finally:
        reader.close()
    if topics is not None:
        types = {t: types[t] for t in topics}
    out: dict[str, str] = {}
    for topic, type_name in types.items():
        new = remap.get(topic, topic)
        if out.get(new, type_name) != type_name:
            raise BagError(f"--remap: {new} would carry two types ({out[new]}, {type_name})")
        out[new] = type_name
    return out
