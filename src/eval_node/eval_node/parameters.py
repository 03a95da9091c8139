"""The recorder node's parameters, defined once (no rclpy): :class:`RecorderParameters` (ROS
names, defaults, allowed values, one-line meanings). ``bag_recorder`` declares them; the
launchers read their defaults from here."""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common.bags.writer import COMPRESSION_MODES, FLUSH_MESSAGES
from vehicle_common.image_transport import SUBSCRIBER_TRANSPORTS
from vehicle_common.node_parameters import param

from vehicle_common import topics as graph_topics

#: The pipeline's topics (docs/ARCHITECTURE.md) recorded by default. Their types are given so
#: that the recorder subscribes at start-up (before any publisher exists) and misses nothing.
PIPELINE_TOPICS = [f"{t}:{graph_topics.TYPES[t]}" for t in graph_topics.RECORDED]


@dataclass
class RecorderParameters:
    """The node's parameters (ROS names and defaults) with their allowed values."""

    output: str = ""  # "" = output/bags/run_<time>
    topics: list = param(PIPELINE_TOPICS)  # "topic" or "topic:pkg/msg/Type"
    include_images: bool = False  # also record the images, stereo/disparity and stereo/points
    # where the images travel ("raw" | "compressed": <image topic>/compressed); the launchers
    # set it from the player's image_transport, as on the other image subscribers
    image_transport: str = param("raw", choices=SUBSCRIBER_TRANSPORTS)
    compression: str = param("none", choices=("none", "zstd"))  # MCAP compression
    # with zstd: "storage" (chunk compression, every MCAP tool reads it), "message", "file"
    compression_mode: str = param("storage", choices=tuple(COMPRESSION_MODES))
    max_bag_size: int = param(0, low=0)  # bytes per .mcap file; 0 = no splitting
    qos_depth: int = param(100, low=1)  # queue depth of each subscription
    discovery_period: float = param(0.5, low=0.0, low_open=True)  # [s]
    flush_period: float = param(1.0, low=0.0, low_open=True)  # [s]
    # a chunk is written out once it holds this many messages (or is flush_period old)
    flush_messages: int = param(FLUSH_MESSAGES, low=1)
