"""numpy <-> sensor_msgs/Image, CompressedImage and CameraInfo conversion (what cv_bridge and
image_transport's compressed plugin would do).

The player owns the image topics, so the conversion every node needs lives here once.
Supported encodings: rgb8, bgr8, rgba8, bgra8, mono8, 8UC1, 8UC3, 8UC4, mono16, 16UC1, 32FC1
and the 4:2:2 YUV ones (``yuv422`` = UYVY, as ROS's image_encodings; ``uyvy``; ``yuv422_yuy2``
and ``yuyv`` = YUYV). Compressed images (PNG, lossless, or JPEG) follow
compressed_image_transport's ``format`` convention (``"rgb8; png compressed bgr8"``).
:func:`image_to_rgb` takes either message type and is where every camera's image becomes the
RGB uint8 array the nodes compute on: converted once, at the edge.
"""

from __future__ import annotations

import array

import numpy as np

_ENCODINGS = {
    "rgb8": (np.uint8, 3),
    "bgr8": (np.uint8, 3),
    "8UC3": (np.uint8, 3),
    "rgba8": (np.uint8, 4),
    "bgra8": (np.uint8, 4),
    "8UC4": (np.uint8, 4),
    "mono8": (np.uint8, 1),
    "8UC1": (np.uint8, 1),
    "mono16": (np.uint16, 1),
    "16UC1": (np.uint16, 1),
    "32FC1": (np.float32, 1),
    # 4:2:2 YUV, two bytes a pixel (an (H, W, 2) array)
    "yuv422": (np.uint8, 2),
    "uyvy": (np.uint8, 2),
    "yuv422_yuy2": (np.uint8, 2),
    "yuyv": (np.uint8, 2),
}
#: 4:2:2 YUV encodings -> OpenCV's conversion to RGB (ROS's "yuv422" is UYVY)
_YUV422 = {
    "yuv422": "COLOR_YUV2RGB_UYVY",
    "uyvy": "COLOR_YUV2RGB_UYVY",
    "yuv422_yuy2": "COLOR_YUV2RGB_YUYV",
    "yuyv": "COLOR_YUV2RGB_YUYV",
}


class ImageConversionError(ValueError):
    """A sensor_msgs/Image cannot be interpreted (bad encoding, size or step)."""


def numpy_to_image(array: np.ndarray, encoding: str, header=None):
    """Build a sensor_msgs/Image from an (H, W) or (H, W, C) array in ``encoding``."""
    from sensor_msgs.msg import Image

    if encoding not in _ENCODINGS:
        raise ImageConversionError(f"unsupported encoding {encoding!r}")
    dtype, channels = _ENCODINGS[encoding]
    arr = np.ascontiguousarray(array, dtype=dtype)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] != channels:
        raise ImageConversionError(f"array of shape {array.shape} does not fit encoding {encoding}")
    msg = Image()
    if header is not None:
        msg.header = header
    msg.height, msg.width = int(arr.shape[0]), int(arr.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = int(arr.shape[1] * channels * arr.itemsize)
    msg.data = byte_array(arr)
    return msg


def byte_array(arr: np.ndarray) -> array.array:
    """The bytes of a contiguous array as ``array.array('B')``, the type a ``uint8[]`` message
    field holds: the setter takes it as it is, where ``bytes`` (``arr.tobytes()``) would be
    copied once more into a new array (one copy of the image instead of two)."""
    out = array.array("B")
    out.frombytes(np.ascontiguousarray(arr).reshape(-1).view(np.uint8).data)
    return out


def image_to_numpy(msg) -> np.ndarray:
    """View a sensor_msgs/Image as an array (H, W, C) or (H, W) for one channel.

    Raises ImageConversionError for an unknown encoding or inconsistent size/step/data.
    """
    if msg.encoding not in _ENCODINGS:
        raise ImageConversionError(f"unsupported image encoding {msg.encoding!r}")
    dtype, channels = _ENCODINGS[msg.encoding]
    row = msg.width * channels * np.dtype(dtype).itemsize
    if msg.height == 0 or msg.width == 0:
        raise ImageConversionError("image has zero width or height")
    if msg.step < row:
        raise ImageConversionError(f"image step {msg.step} < width*channels*itemsize {row}")
    data = msg.data
    buf = np.frombuffer(data.tobytes() if hasattr(data, "tobytes") else bytes(data), np.uint8)
    if buf.size != msg.step * msg.height:
        raise ImageConversionError(
            f"image data has {buf.size} bytes, expected step*height = {msg.step * msg.height}"
        )
    rows = buf.reshape(msg.height, msg.step)[:, :row]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    arr = np.ascontiguousarray(rows).view(dt).reshape(msg.height, msg.width, channels)
    arr = arr.astype(dtype, copy=False)
    return arr[:, :, 0] if channels == 1 else arr


#: compressed formats: name -> OpenCV file extension
COMPRESSED_FORMATS = {"png": ".png", "jpeg": ".jpg"}
#: PNG compression level (0-9): 1 (OpenCV's default) encodes KITTI 0005 ~10x faster than 9 for
#: a stream 7 % larger (docs/bags_and_cameras.md, bench/bench_image_transport.py)
PNG_LEVEL = 1


def numpy_to_compressed(rgb: np.ndarray, fmt: str, jpeg_quality: int = 90, header=None):
    """A sensor_msgs/CompressedImage of an RGB uint8 (H, W, 3) or mono8 (H, W) image: ``fmt``
    "png" (lossless) or "jpeg" (``jpeg_quality`` 1-100). ``format`` as image_transport writes it
    (``"rgb8; jpeg compressed bgr8"``, ``"mono8; png compressed mono8"``)."""
    import cv2
    from sensor_msgs.msg import CompressedImage

    if fmt not in COMPRESSED_FORMATS:
        raise ImageConversionError(f"compressed format {fmt!r} is not png or jpeg")
    arr = np.asarray(rgb)
    if arr.dtype != np.uint8 or not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise ImageConversionError(f"cannot compress an array of shape {arr.shape} ({arr.dtype})")
    mono = arr.ndim == 2
    opts = [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL]
    if fmt == "jpeg":
        opts = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
    ok, buf = cv2.imencode(COMPRESSED_FORMATS[fmt], arr if mono else arr[:, :, ::-1], opts)
    if not ok:
        raise ImageConversionError(f"OpenCV could not encode the image as {fmt}")
    msg = CompressedImage()
    if header is not None:
        msg.header = header
    msg.format = "mono8; {} compressed mono8" if mono else "rgb8; {} compressed bgr8"
    msg.format = msg.format.format(fmt)
    msg.data = byte_array(buf)
    return msg


def compressed_to_rgb(msg) -> np.ndarray:
    """The RGB uint8 (H, W, 3) image of a sensor_msgs/CompressedImage (PNG or JPEG, colour or
    mono); raises ImageConversionError naming the format for anything else or corrupt data."""
    import cv2

    fmt = str(msg.format).lower()
    if not any(k in fmt for k in ("png", "jpeg", "jpg")) and fmt.strip():
        raise ImageConversionError(f"unsupported compressed image format {msg.format!r}")
    data = msg.data
    buf = np.frombuffer(data.tobytes() if hasattr(data, "tobytes") else bytes(data), np.uint8)
    arr = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if arr is None:
        raise ImageConversionError(f"compressed image ({msg.format!r}) cannot be decoded")
    if arr.dtype != np.uint8:
        raise ImageConversionError(f"compressed image ({msg.format!r}) is not 8-bit")
    if arr.ndim == 2:
        return np.repeat(arr[:, :, None], 3, axis=2)
    if arr.shape[2] == 4:
        arr = arr[:, :, :3]
    return np.ascontiguousarray(arr[:, :, ::-1])  # OpenCV decodes to BGR whatever the format


def is_compressed(msg) -> bool:
    """Whether ``msg`` is a sensor_msgs/CompressedImage (its ``format`` instead of ``encoding``)."""
    return hasattr(msg, "format") and not hasattr(msg, "encoding")


def image_size(msg) -> tuple[int, int] | None:
    """(width, height) of an Image, or of a CompressedImage (decoded; None when it cannot be:
    the caller then does without, as the oracle detector's box clipping)."""
    if is_compressed(msg):
        try:
            h, w = compressed_to_rgb(msg).shape[:2]
        except ImageConversionError:
            return None
        return int(w), int(h)
    return int(msg.width), int(msg.height)


def image_to_rgb(msg) -> np.ndarray:
    """Any supported colour or mono image, raw (sensor_msgs/Image) or compressed
    (sensor_msgs/CompressedImage), as RGB uint8 (H, W, 3): alpha dropped, BGR and YUV 4:2:2
    converted, mono repeated in the three channels (16-bit mono scaled to 8 bits by
    :func:`mono16_to_mono8`). Raises ImageConversionError naming the encoding otherwise."""
    if is_compressed(msg):
        return compressed_to_rgb(msg)
    arr = image_to_numpy(msg)
    enc = msg.encoding
    if enc in _YUV422:
        import cv2

        return cv2.cvtColor(arr, getattr(cv2, _YUV422[enc]))
    if enc in ("bgr8", "bgra8"):
        return np.ascontiguousarray(arr[:, :, 2::-1])
    if arr.ndim == 3 and arr.shape[2] == 4:  # rgba8, 8UC4
        return np.ascontiguousarray(arr[:, :, :3])
    if arr.ndim == 2:
        if arr.dtype == np.uint16:
            arr = mono16_to_mono8(arr)
        if arr.dtype != np.uint8:
            raise ImageConversionError(f"cannot show {enc} image as RGB")
        return np.repeat(arr[:, :, None], 3, axis=2)
    return arr


def mono16_to_mono8(arr: np.ndarray) -> np.ndarray:
    """A 16-bit mono image as 8 bits: its significant bits (those of its maximum; a 12-bit
    sensor's data in 16 bits keeps its contrast) shifted down to 8. A power-of-two scale, so
    a stereo pair of one sensor type is scaled alike whatever each image holds."""
    bits = int(arr.max()).bit_length() if arr.size else 0
    return (arr >> max(bits - 8, 0)).astype(np.uint8)


def camera_info_from_projection(P: np.ndarray, width: int, height: int, header=None):
    """sensor_msgs/CameraInfo of a rectified camera with 3x4 projection ``P``.

    For a rectified stereo pair, the left camera has ``P[0,3] = 0`` and the right one
    ``P[0,3] = -fx * baseline`` (ROS convention); R is identity, D empty (plumb_bob, zeros).
    """
    from sensor_msgs.msg import CameraInfo

    P = np.asarray(P, dtype=float)
    msg = CameraInfo()
    if header is not None:
        msg.header = header
    msg.width, msg.height = int(width), int(height)
    msg.distortion_model = "plumb_bob"
    msg.d = [0.0] * 5
    msg.k = [float(v) for v in P[:, :3].ravel()]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [float(v) for v in P.ravel()]
    return msg
