"""Raw or compressed images on the graph's image topics (image_transport's convention).

The player publishes sensor_msgs/Image on ``stereo/{left,right}/image_rect`` (``image_transport``
"raw", the default) or sensor_msgs/CompressedImage on ``.../image_rect/compressed`` ("png",
lossless, or "jpeg" with ``jpeg_quality``). The detector and stereo nodes subscribe through
:func:`subscribe_image`, which gives them an ``image_transport`` parameter ("raw" or
"compressed"); :func:`vehicle_common.image_conversion.image_to_rgb` decodes either message, so
the nodes' processing is the same for both. The launchers set the consumers' parameter from the
player's (tracking_bringup.graph.plan).

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


def subscriber_transport(player_transport: str) -> str:
    """The subscribers' ``image_transport`` for the player's."""
    return "raw" if player_transport == "raw" else "compressed"


@dataclass
class ImageTransportParameters:
    """The parameter :func:`subscribe_image` declares on a node."""

    # "raw": sensor_msgs/Image on the image topics; "compressed": sensor_msgs/CompressedImage
    # on <image topic>/compressed (PNG or JPEG)
    image_transport: str = param("raw", choices=SUBSCRIBER_TRANSPORTS)


def subscribe_image(node, topic: str, callback, qos, serialized: bool = False):
    """Subscribe ``node`` to the image ``topic`` with the transport of its ``image_transport``
    parameter (declared at the first call; a bad value raises ParameterError naming it). The
    callback gets a sensor_msgs/Image or CompressedImage (``image_to_rgb`` reads both), or with
    ``serialized`` a :class:`SerializedImage` of one (a message whose header cannot be read is
    warned about and not passed on)."""
    from sensor_msgs.msg import CompressedImage, Image

    if node.has_parameter("image_transport"):
        transport = node.get_parameter("image_transport").value
    else:
        transport = declare_config(node, ImageTransportParameters).image_transport
    cls = Image if transport == "raw" else CompressedImage
    name = topics.image_topic(topic, transport)
    if not serialized:
        return node.create_subscription(cls, name, callback, qos)

    def on_bytes(data: bytes) -> None:
        try:
            image = SerializedImage(data, cls)
        except ValueError as exc:
            node.get_logger().warning(f"{name}: {exc}; message ignored", throttle_duration_sec=5.0)
            return
        callback(image)

    return node.create_subscription(cls, name, on_bytes, qos, raw=True)


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
