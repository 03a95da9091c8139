"""ROS messages of one KITTI frame: stereo CameraInfo pair and KittiFrameLabels ground truth.

Message packages are imported lazily, so the module loads without a ROS installation; the
inverse conversion (:func:`kitti_objects_from_message`) serves consumers such as the evaluator.
"""

from __future__ import annotations

import math

import numpy as np

from .image_conversion import camera_info_from_projection
from .kitti import Calibration, KittiObject

LEFT_FRAME = "left_camera_optical_frame"
RIGHT_FRAME = "right_camera_optical_frame"


def header(stamp_ns: int, frame_id: str):
    """std_msgs/Header with a stamp given in nanoseconds."""
    from std_msgs.msg import Header

    h = Header(frame_id=frame_id)
    h.stamp.sec, h.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return h


def stamp_ns(header) -> int:
    """The stamp of a std_msgs/Header (or any object with ``stamp.sec``/``stamp.nanosec``,
    such as a message read back by rosbags) in nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def bbox_to_xyxy(bbox) -> tuple[float, float, float, float]:
    """(x1, y1, x2, y2) [px] of a stereo_vehicle_msgs/BoundingBox2D (centre + size)."""
    hx, hy = bbox.size_x / 2.0, bbox.size_y / 2.0
    return (
        float(bbox.center_x - hx),
        float(bbox.center_y - hy),
        float(bbox.center_x + hx),
        float(bbox.center_y + hy),
    )


def xyxy_to_bbox(box, bbox) -> None:
    """Fill a stereo_vehicle_msgs/BoundingBox2D from (x1, y1, x2, y2) [px] (size >= 0)."""
    x1, y1, x2, y2 = (float(v) for v in box)
    bbox.center_x, bbox.center_y = (x1 + x2) / 2.0, (y1 + y2) / 2.0
    bbox.size_x, bbox.size_y = max(0.0, x2 - x1), max(0.0, y2 - y1)


def stereo_projections(calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """ROS-convention projection matrices of the rectified pair in the left optical frame:
    left ``[K | 0]``, right ``[K | (-fx * B, 0, 0)]`` with ``B = calib.baseline``."""
    K = calib.K
    left = np.hstack([K, np.zeros((3, 1))])
    right = left.copy()
    right[0, 3] = -calib.fx * calib.baseline
    return left, right


def stereo_camera_infos(calib: Calibration, width: int, height: int, stamp_ns: int):
    """(left, right) sensor_msgs/CameraInfo: left P = [K|0], right P[0,3] = -fx * baseline."""
    P_left, P_right = stereo_projections(calib)
    left = camera_info_from_projection(P_left, width, height, header(stamp_ns, LEFT_FRAME))
    right = camera_info_from_projection(P_right, width, height, header(stamp_ns, RIGHT_FRAME))
    return left, right


def kitti_object_message(obj: KittiObject):
    """stereo_vehicle_msgs/KittiObject of one label row, values as in the label file."""
    from stereo_vehicle_msgs.msg import KittiObject as KittiObjectMsg

    m = KittiObjectMsg()
    m.track_id = int(obj.track_id)
    m.type = obj.type
    m.truncated = float(obj.truncated)
    m.occluded = int(obj.occluded)
    m.alpha = float(obj.alpha)
    m.x_min, m.y_min, m.x_max, m.y_max = (float(v) for v in obj.bbox)
    m.height, m.width, m.length = (float(v) for v in obj.dimensions)
    m.location.x, m.location.y, m.location.z = (float(v) for v in obj.location)
    m.rotation_y = float(obj.rotation_y)
    return m


def ground_truth_message(
    sequence: str, frame: int, calib: Calibration, objects: list[KittiObject], stamp_ns: int
):
    """stereo_vehicle_msgs/KittiFrameLabels of a frame (every row, DontCare included)."""
    from stereo_vehicle_msgs.msg import KittiFrameLabels

    m = KittiFrameLabels()
    m.header = header(stamp_ns, LEFT_FRAME)
    m.sequence = str(sequence)
    m.frame_index = int(frame)
    m.left_camera_offset = [float(v) for v in calib.left_camera_offset]
    m.objects = [kitti_object_message(o) for o in objects]
    return m


def kitti_objects_from_message(msg) -> list[KittiObject]:
    """The label rows of a KittiFrameLabels message as :class:`KittiObject` (frame filled in)."""
    return [
        KittiObject(
            type=str(o.type),
            truncated=float(o.truncated),
            occluded=int(o.occluded),
            alpha=float(o.alpha),
            bbox=(float(o.x_min), float(o.y_min), float(o.x_max), float(o.y_max)),
            dimensions=(float(o.height), float(o.width), float(o.length)),
            location=(float(o.location.x), float(o.location.y), float(o.location.z)),
            rotation_y=float(o.rotation_y),
            frame=int(msg.frame_index),
            track_id=int(o.track_id),
        )
        for o in msg.objects
    ]


def quaternion_from_matrix(rotation) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a 3x3 rotation matrix, w >= 0."""
    M = np.asarray(rotation, float).reshape(3, 3).tolist()
    # Shepperd's method: branch on the largest of w, x, y, z for a stable square root. In
    # Python floats: the IEEE operations numpy's scalars did before (2026-11-29), in the same
    # order (the trace summed left to right as np.trace does; the first of equal candidates,
    # a NaN trace first, as np.argmax), the same bits at a sixth of the CPU
    diagonal = (M[0][0], M[1][1], M[2][2])
    tr = diagonal[0] + diagonal[1] + diagonal[2]
    candidates = (tr, *diagonal)
    k = 0
    for j in (1, 2, 3):
        if candidates[j] > candidates[k]:
            k = j
    if k == 0:
        s = 2.0 * _sqrt(1.0 + tr)
        q = (0.25 * s, (M[2][1] - M[1][2]) / s, (M[0][2] - M[2][0]) / s, (M[1][0] - M[0][1]) / s)
    else:
        i, j, m = (k - 1, k % 3, (k + 1) % 3)
        s = 2.0 * _sqrt(1.0 + M[i][i] - M[j][j] - M[m][m])
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (M[j][i] + M[i][j]) / s
        v[m] = (M[m][i] + M[i][m]) / s
        q = ((M[m][j] - M[j][m]) / s, *v)
    sign = 1.0 if q[0] >= 0 else -1.0
    w, x, y, z = (c * sign for c in q)
    return w, x, y, z


def _sqrt(value: float) -> float:
    """math.sqrt, or numpy's NaN (with its warning) for a negative or NaN argument (a matrix
    that is no rotation), as before."""
    return math.sqrt(value) if value >= 0 else float(np.sqrt(value))


def _write_quaternion(rotation, q) -> None:
    q.w, q.x, q.y, q.z = quaternion_from_matrix(rotation)


def write_transform(rotation, translation, transform) -> None:
    """Fill a geometry_msgs/Transform from a 3x3 rotation matrix and a translation (3,) [m]
    (the quaternion with w >= 0)."""
    _write_quaternion(rotation, transform.rotation)
    t = transform.translation
    t.x, t.y, t.z = (float(v) for v in np.asarray(translation, float).reshape(3))


def write_pose(rotation, translation, pose) -> None:
    """Fill a geometry_msgs/Pose (orientation w >= 0) as :func:`write_transform` does a
    Transform."""
    _write_quaternion(rotation, pose.orientation)
    p = pose.position
    p.x, p.y, p.z = (float(v) for v in np.asarray(translation, float).reshape(3))


def rotation_from_quaternion(w: float, x: float, y: float, z: float) -> np.ndarray:
    """3x3 rotation of a quaternion (normalised here). ValueError when it is not finite or has
    zero norm."""
    q = np.array([w, x, y, z], float)
    n = float(np.linalg.norm(q))
    if not np.isfinite(q).all() or n == 0.0:
        raise ValueError("quaternion is not finite or zero")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def read_transform(transform) -> tuple[np.ndarray, np.ndarray]:
    """(3x3 rotation, translation (3,)) of a geometry_msgs/Transform; the quaternion is
    normalised. ValueError when it is not finite or has zero norm."""
    r, t = transform.rotation, transform.translation
    tv = np.array([t.x, t.y, t.z], float)
    if not np.isfinite(tv).all():
        raise ValueError("transform is not finite or its quaternion is zero")
    try:
        R = rotation_from_quaternion(r.w, r.x, r.y, r.z)
    except ValueError:
        raise ValueError("transform is not finite or its quaternion is zero") from None
    return R, tv


def field_bits(msg) -> bytes:
    """Every field of a ROS message, recursively, as bytes: floats as their IEEE-754 bits
    (-0.0 and NaN payloads told apart), integers, bools and strings as written, arrays with
    their type. Two messages with equal ``field_bits`` serialise to the same data. (Their CDR
    bytes cannot be compared as such: the padding after a bool, such as a Marker's
    ``frame_locked``, is left uninitialised by the serialiser and differs between runs.)"""
    import array
    import struct

    if hasattr(msg, "get_fields_and_field_types"):
        inner = b",".join(field_bits(getattr(msg, f)) for f in msg.get_fields_and_field_types())
        return b"{" + inner + b"}"
    if isinstance(msg, float):
        return struct.pack("<d", msg)
    if isinstance(msg, (bool, int)):
        return repr(msg).encode()
    if isinstance(msg, str):
        return msg.encode() + b"\0"
    if isinstance(msg, (bytes, bytearray)):
        return bytes(msg)
    if isinstance(msg, np.ndarray):
        return msg.dtype.str.encode() + msg.tobytes()
    if isinstance(msg, array.array):
        return msg.typecode.encode() + msg.tobytes()
    if isinstance(msg, (list, tuple)):
        return b"[" + b",".join(field_bits(v) for v in msg) + b"]"
    raise TypeError(f"field of type {type(msg).__name__}")
