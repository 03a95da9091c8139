"""Raw or compressed images on the graph's image topics (image_transport's convention).

The player publishes sensor_msgs/Image on ``stereo/{left,right}/image_rect`` (``image_transport``
"raw", the default) or sensor_msgs/CompressedImage on ``.../image_rect/compressed`` ("png",
lossless, or "jpeg" with ``jpeg_quality``). The detector and stereo nodes subscribe through
:func:`subscribe_image`, which gives them an ``image_transport`` parameter ("raw" or
"compressed"); :func:`vehicle_common.image_conversion.image_to_rgb` decodes either message, so
the nodes' processing is the same for both. The launchers set the consumers' parameter from the
player's (tracking_bringup.graph.plan).

Reliability (parameter ``camera_reliability``, issue #42): a camera driver publishes RELIABLE or
BEST_EFFORT (the sensor-data QoS of most drivers). "auto", the default, does what rosbag2 does:
the subscription follows the topic's publishers, RELIABLE while every one is RELIABLE (a lost
fragment of a large image is then sent again: a BEST_EFFORT subscription to a RELIABLE camera
would lose it, and with it the frame), BEST_EFFORT as soon as one is BEST_EFFORT (which a
RELIABLE subscription cannot match). It starts with the publishers there are (RELIABLE when
none: the graph's player is never raced by a re-creation) and is re-created when their
reliability changes (checked every 0.5 s; a BEST_EFFORT camera's first half second is lost).
The launchers set "reliable" when the graph's own player is the camera (lockstep loses no
frame). A QoS
incompatibility with a publisher (a TRANSIENT_LOCAL-only writer, say) is reported once per
topic through ``on_incompatible``.
``subscribe_image(..., serialized=True)`` takes the images as the middleware's bytes
(:class:`SerializedImage`: the header is read at once, the image only when a node uses it): a
node that skips most frames under overload (the latest-frame policy, the detector's
back-pressure) then does not pay rclpy's conversion of the frames it skips (about 2.4 ms of CPU
for a 1242x375 rgb8 image, against 0.3 ms for the bytes; issue #39).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from vehicle_common import topics

from .node_parameters import declare_config, param

#: what the player can send
PLAYER_TRANSPORTS = ("raw", "png", "jpeg")
#: what a subscriber can take ("compressed": PNG or JPEG, as the message's format says)
SUBSCRIBER_TRANSPORTS = ("raw", "compressed")
#: the image and camera_info subscriptions' reliability
RELIABILITIES = ("auto", "best_effort", "reliable")
#: s between two looks at a topic's publishers (camera_reliability "auto")
ADAPT_PERIOD_S = 0.5


def subscriber_transport(player_transport: str) -> str:
    """The subscribers' ``image_transport`` for the player's."""
    return "raw" if player_transport == "raw" else "compressed"


@dataclass
class ImageTransportParameters:
    """The parameter :func:`subscribe_image` declares on a node."""

    # "raw": sensor_msgs/Image on the image topics; "compressed": sensor_msgs/CompressedImage
    # on <image topic>/compressed (PNG or JPEG)
    image_transport: str = param("raw", choices=SUBSCRIBER_TRANSPORTS)
    # reliability of the image and camera_info subscriptions: "auto" follows the publishers
    # (RELIABLE while all are, else BEST_EFFORT: any camera); "best_effort" matches any;
    # "reliable" (set by the launchers for their own player) makes the publisher resend a
    # lost fragment, so that lockstep loses nothing
    camera_reliability: str = param("auto", choices=RELIABILITIES)


def _parameter(node, name: str):
    if not node.has_parameter(name):
        declare_config(node, ImageTransportParameters)
    return node.get_parameter(name).value


def camera_qos(depth: int, reliability: str):
    """KEEP_LAST ``depth``, VOLATILE, ``reliability`` ("reliable" or "best_effort")."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    policy = ReliabilityPolicy.BEST_EFFORT
    if reliability == "reliable":
        policy = ReliabilityPolicy.RELIABLE
    return QoSProfile(depth=int(depth), reliability=policy)


def publishers_reliability(policies) -> str | None:
    """The reliability that receives the most from publishers of these reliability policies
    (``rclpy.qos.ReliabilityPolicy``): "reliable" when every one is RELIABLE, "best_effort"
    when one is BEST_EFFORT, None when there are none (keep what there is)."""
    from rclpy.qos import ReliabilityPolicy

    policies = list(policies)
    if not policies:
        return None
    return "reliable" if all(p == ReliabilityPolicy.RELIABLE for p in policies) else "best_effort"


class CameraSubscription:
    """A subscription with the node's ``camera_reliability``; with "auto", re-created with the
    publishers' reliability when it changes (module docstring)."""

    def __init__(self, node, msg_type, topic, callback, depth, events, raw: bool = False):
        self.node, self._args, self._raw = node, (msg_type, topic, callback), raw
        self._depth, self._events = depth, events
        mode = _parameter(node, "camera_reliability")
        self.reliability = mode
        if mode == "auto":
            self._topic = node.resolve_topic_name(topic)
            self.reliability = self._publishers() or "reliable"
            node.create_timer(ADAPT_PERIOD_S, self.adapt)
        self.subscription = self._create()

    def _publishers(self) -> str | None:
        infos = self.node.get_publishers_info_by_topic(self._topic)
        return publishers_reliability(i.qos_profile.reliability for i in infos)

    def _create(self):
        msg_type, topic, callback = self._args
        qos = camera_qos(self._depth, self.reliability)
        return self.node.create_subscription(
            msg_type, topic, callback, qos, event_callbacks=self._events, raw=self._raw
        )

    def adapt(self) -> None:
        want = self._publishers()
        if want is None or want == self.reliability:
            return
        self.node.destroy_subscription(self.subscription)
        self.reliability = want
        self.subscription = self._create()
        self.node.get_logger().info(
            f"{self._topic}: subscribed {want.upper()}, as its publishers (camera_reliability auto)"
        )


def subscribe_camera(
    node, msg_type, topic: str, callback, depth: int, on_incompatible=None, raw: bool = False
):
    """Subscribe ``node`` to a camera topic (image or camera_info) with the reliability of its
    ``camera_reliability`` (:class:`CameraSubscription`), KEEP_LAST ``depth``;
    ``on_incompatible(line)`` is called with one line naming the topic and the QoS policy when
    a publisher's QoS cannot match (once per topic)."""
    from rclpy.event_handler import SubscriptionEventCallbacks

    reported = []
    adapts = _parameter(node, "camera_reliability") == "auto"

    def incompatible(event) -> None:
        policy = getattr(event.last_policy_kind, "name", str(event.last_policy_kind))
        policy = policy.removeprefix("RMW_QOS_POLICY_")
        if reported or (adapts and policy == "RELIABILITY"):
            return  # said once; "auto" follows a BEST_EFFORT publisher within 0.5 s
        reported.append(True)
        line = (
            f"{node.resolve_topic_name(topic)}: a publisher's QoS is incompatible with this "
            f"subscription ({policy}); no message of it arrives"
        )
        node.get_logger().warning(line)
        if on_incompatible is not None:
            on_incompatible(line)

    events = SubscriptionEventCallbacks(incompatible_qos=incompatible)
    return CameraSubscription(node, msg_type, topic, callback, depth, events, raw)


def subscribe_image(
    node, topic: str, callback, depth: int, on_incompatible=None, serialized: bool = False
):
    """Subscribe ``node`` to the image ``topic`` with the transport of its ``image_transport``
    parameter and the reliability of its ``camera_reliability`` (declared at the first call; a
    bad value raises ParameterError naming it), KEEP_LAST ``depth``. The callback gets a
    sensor_msgs/Image or CompressedImage (``image_to_rgb`` reads both), or with ``serialized``
    a :class:`SerializedImage` of one (a message whose header cannot be read is warned about
    and not passed on)."""
    from sensor_msgs.msg import CompressedImage, Image

    transport = _parameter(node, "image_transport")
    cls = Image if transport == "raw" else CompressedImage
    name = topics.image_topic(topic, transport)
    if not serialized:
        return subscribe_camera(node, cls, name, callback, depth, on_incompatible)

    def on_bytes(data: bytes) -> None:
        try:
            image = SerializedImage(data, cls)
        except ValueError as exc:
            node.get_logger().warning(f"{name}: {exc}; message ignored", throttle_duration_sec=5.0)
            return
        callback(image)

    return subscribe_camera(node, cls, name, on_bytes, depth, on_incompatible, raw=True)


def cdr_header(data: bytes) -> tuple[int, int, str]:
    """(sec, nanosec, frame_id) of the std_msgs/Header a serialized message starts with (CDR,
    either byte order, after the 4-byte encapsulation); ValueError for bytes that are not."""
    if len(data) < 16 or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError("not a CDR-serialized message")
    order = "<" if data[1] == 1 else ">"
    sec, nanosec, length = struct.unpack_from(order + "iII", data, 4)
    if length < 1 or 16 + length > len(data) or data[15 + length] != 0 or nanosec >= 10**9:
        raise ValueError("its header cannot be read")
    try:
        frame_id = data[16 : 15 + length].decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError("its header's frame_id is not UTF-8") from None
    return sec, nanosec, frame_id


class SerializedImage:
    """An image message as the middleware's bytes: ``header`` (a std_msgs/Header) read at once,
    :meth:`message` converted on first use."""

    __slots__ = ("data", "cls", "header", "_message")

    def __init__(self, data: bytes, cls) -> None:
        from std_msgs.msg import Header

        sec, nanosec, frame_id = cdr_header(data)
        self.data, self.cls = data, cls
        self.header = Header(frame_id=frame_id)
        self.header.stamp.sec, self.header.stamp.nanosec = sec, nanosec
        self._message = None

    def message(self):
        """The sensor_msgs/Image or CompressedImage (ImageConversionError when the bytes are
        not one)."""
        if self._message is None:
            from rclpy.serialization import deserialize_message

            from .image_conversion import ImageConversionError

            try:
                self._message = deserialize_message(self.data, self.cls)
            except Exception as exc:  # noqa: BLE001 - rclpy raises several kinds
                raise ImageConversionError(f"cannot deserialize the image: {exc}") from None
            self.data = b""  # converted: the bytes are no longer needed
        return self._message


def as_message(msg):
    """``msg`` itself, or the message a :class:`SerializedImage` holds."""
    return msg.message() if isinstance(msg, SerializedImage) else msg
