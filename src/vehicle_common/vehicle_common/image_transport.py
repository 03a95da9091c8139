"""Raw or compressed images on the graph's image topics (image_transport's convention).

The player publishes sensor_msgs/Image on ``stereo/{left,right}/image_rect`` (``image_transport``
"raw", the default) or sensor_msgs/CompressedImage on ``.../image_rect/compressed`` ("png",
lossless, or "jpeg" with ``jpeg_quality``). The detector and stereo nodes subscribe through
:func:`subscribe_image`, which gives them an ``image_transport`` parameter ("raw" or
"compressed"); :func:`vehicle_common.image_conversion.image_to_rgb` decodes either message, so
the nodes' processing is the same for both. The launchers set the consumers' parameter from the
player's (tracking_bringup.graph.plan).

Reliability (parameter ``camera_reliability``, issue #42): a camera driver publishes RELIABLE or
BEST_EFFORT (the sensor-data QoS of most drivers). The image and camera_info subscriptions are
BEST_EFFORT by default, which matches both; the launchers set "reliable" when the graph's own
player or bag player is the source, so that lockstep loses no fragment of an image (a lost
BEST_EFFORT fragment would be a lost frame). A QoS incompatibility with a publisher (a
TRANSIENT_LOCAL-only writer, say) is reported once per topic through ``on_incompatible``.
"""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common import topics

from .node_parameters import declare_config, param

#: what the player can send
PLAYER_TRANSPORTS = ("raw", "png", "jpeg")
#: what a subscriber can take ("compressed": PNG or JPEG, as the message's format says)
SUBSCRIBER_TRANSPORTS = ("raw", "compressed")
#: the image and camera_info subscriptions' reliability
RELIABILITIES = ("best_effort", "reliable")


def subscriber_transport(player_transport: str) -> str:
    """The subscribers' ``image_transport`` for the player's."""
    return "raw" if player_transport == "raw" else "compressed"


@dataclass
class ImageTransportParameters:
    """The parameter :func:`subscribe_image` declares on a node."""

    # "raw": sensor_msgs/Image on the image topics; "compressed": sensor_msgs/CompressedImage
    # on <image topic>/compressed (PNG or JPEG)
    image_transport: str = param("raw", choices=SUBSCRIBER_TRANSPORTS)
    # reliability of the image and camera_info subscriptions: "best_effort" takes a RELIABLE
    # and a BEST_EFFORT camera alike; "reliable" (set by the launchers for their own player)
    # makes the publisher resend a lost fragment, so that lockstep loses nothing
    camera_reliability: str = param("best_effort", choices=RELIABILITIES)


def _parameter(node, name: str):
    if not node.has_parameter(name):
        declare_config(node, ImageTransportParameters)
    return node.get_parameter(name).value


def camera_qos(node, depth: int):
    """KEEP_LAST ``depth``, VOLATILE, with the node's ``camera_reliability``."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    reliability = _parameter(node, "camera_reliability")
    policy = ReliabilityPolicy.BEST_EFFORT
    if reliability == "reliable":
        policy = ReliabilityPolicy.RELIABLE
    return QoSProfile(depth=int(depth), reliability=policy)


def subscribe_camera(node, msg_type, topic: str, callback, depth: int, on_incompatible=None):
    """Subscribe ``node`` to a camera topic (image or camera_info) with :func:`camera_qos`;
    ``on_incompatible(line)`` is called with one line naming the topic and the QoS policy when
    a publisher's QoS cannot match (once per topic)."""
    from rclpy.event_handler import SubscriptionEventCallbacks

    reported = []

    def incompatible(event) -> None:
        if reported:
            return
        reported.append(True)
        policy = getattr(event.last_policy_kind, "name", str(event.last_policy_kind))
        policy = policy.removeprefix("RMW_QOS_POLICY_")
        line = (
            f"{node.resolve_topic_name(topic)}: a publisher's QoS is incompatible with this "
            f"subscription ({policy}); no message of it arrives"
        )
        node.get_logger().warning(line)
        if on_incompatible is not None:
            on_incompatible(line)

    events = SubscriptionEventCallbacks(incompatible_qos=incompatible)
    qos = camera_qos(node, depth)
    return node.create_subscription(msg_type, topic, callback, qos, event_callbacks=events)


def subscribe_image(node, topic: str, callback, depth: int, on_incompatible=None):
    """Subscribe ``node`` to the image ``topic`` with the transport of its ``image_transport``
    parameter and the reliability of its ``camera_reliability`` (declared at the first call; a
    bad value raises ParameterError naming it), KEEP_LAST ``depth``. The callback gets a
    sensor_msgs/Image or CompressedImage (``image_to_rgb`` reads both)."""
    from sensor_msgs.msg import CompressedImage, Image

    transport = _parameter(node, "image_transport")
    cls = Image if transport == "raw" else CompressedImage
    name = topics.image_topic(topic, transport)
    return subscribe_camera(node, cls, name, callback, depth, on_incompatible)
