"""Repeated frame stamps: the sign that a recording mixes two runs.

Every node of the graph publishes one message per frame with that frame's stamp, and the player
never publishes a stamp twice (looping continues the time line). Two graphs on one ROS domain
without their own namespaces publish on the same topics, with the same stamps (frame k of a
sequence has the stamp ``start_time + k * 0.1 s`` in both): their frames, detections and tracks
mix in each other's nodes and bags (issue #35: ``evaluate bag`` then gave MOTA 9.8 with no
warning). A stamp seen twice on one of the graph's per-frame topics reveals it: the recorder
warns while recording, and the evaluator refuses such a bag. Pure core (no rclpy).
"""

from __future__ import annotations

import struct
from collections import deque

from .. import topics

#: the per-frame topics checked (relative names): one message per frame and stamp each
FRAME_TOPICS = (topics.GROUND_TRUTH, topics.DETECTIONS_2D, topics.DETECTIONS_3D, topics.TRACKS)


def mixed_runs_hint() -> str:
    """What to do about a mixed recording (the end of the one-line messages)."""
    return (
        "two graphs on one ROS domain without their own namespaces? give each its own "
        "--namespace (or ROS_DOMAIN_ID) and record each run in its own bag"
    )


def header_stamp(cdr: bytes) -> int | None:
    """The stamp [ns] of a serialized message whose first field is a ``std_msgs/Header``
    (CDR: 4-byte encapsulation, then int32 sec, uint32 nanosec), None when too short."""
    if len(cdr) < 12:
        return None
    order = "<" if cdr[1] & 1 else ">"
    sec, nanosec = struct.unpack(order + "iI", cdr[4:12])
    return sec * 1_000_000_000 + nanosec


class RepeatedStamps:
    """Per topic, whether a stamp arrives a second time (the last ``keep`` stamps of each topic
    are remembered: a recording of hours stays small)."""

    def __init__(self, keep: int = 2000) -> None:
        self._keep = keep
        self._seen: dict[str, tuple[deque[int], set[int]]] = {}
        #: topic -> repeated stamps counted so far
        self.repeats: dict[str, int] = {}

    def add(self, topic: str, stamp_ns: int) -> bool:
        """Note a message; True when ``stamp_ns`` was already seen on ``topic``."""
        order, seen = self._seen.setdefault(topic, (deque(), set()))
        if stamp_ns in seen:
            self.repeats[topic] = self.repeats.get(topic, 0) + 1
            return True
        order.append(stamp_ns)
        seen.add(stamp_ns)
        if len(order) > self._keep:
            seen.discard(order.popleft())
        return False
