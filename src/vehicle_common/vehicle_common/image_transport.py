"""Raw or compressed images on the graph's image topics (image_transport's convention).

The player publishes sensor_msgs/Image on ``stereo/{left,right}/image_rect`` (``image_transport``
"raw", the default) or sensor_msgs/CompressedImage on ``.../image_rect/compressed`` ("png",
lossless, or "jpeg" with ``jpeg_quality``). The detector and stereo nodes subscribe through
:func:`subscribe_image`, which gives them an ``image_transport`` parameter ("raw" or
"compressed"); :func:`vehicle_common.image_conversion.image_to_rgb` decodes either message, so
the nodes' processing is the same for both. The launchers set the consumers' parameter from the
player's (tracking_bringup.graph.plan).
"""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common import topics

from .node_parameters import declare_config, param

#: what the player can send
PLAYER_TRANSPORTS = ("raw", "png", "jpeg")
#: what a subscriber can take ("compressed": PNG or JPEG, as the message's format says)
SUBSCRIBER_TRANSPORTS = ("raw", "compressed")


def subscriber_transport(player_transport: str) -> str:
    """The subscribers' ``image_transport`` for the player's."""
    return "raw" if player_transport == "raw" else "compressed"


@dataclass
class ImageTransportParameters:
    """The parameter :func:`subscribe_image` declares on a node."""

    # "raw": sensor_msgs/Image on the image topics; "compressed": sensor_msgs/CompressedImage
    # on <image topic>/compressed (PNG or JPEG)
    image_transport: str = param("raw", choices=SUBSCRIBER_TRANSPORTS)


def subscribe_image(node, topic: str, callback, qos):
    """Subscribe ``node`` to the image ``topic`` with the transport of its ``image_transport``
    parameter (declared at the first call; a bad value raises ParameterError naming it). The
    callback gets a sensor_msgs/Image or CompressedImage (``image_to_rgb`` reads both)."""
    from sensor_msgs.msg import CompressedImage, Image

    if node.has_parameter("image_transport"):
        transport = node.get_parameter("image_transport").value
    else:
        transport = declare_config(node, ImageTransportParameters).image_transport
    cls = Image if transport == "raw" else CompressedImage
    return node.create_subscription(cls, topics.image_topic(topic, transport), callback, qos)
