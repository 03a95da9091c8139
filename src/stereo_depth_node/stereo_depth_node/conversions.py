"""Message conversions of stereo_depth: disparity image, point cloud and 3D detection arrays.

Shared by the ``stereo_depth`` node and offline tools; message packages are imported when a
message is built, no rclpy.
"""

from __future__ import annotations

import numpy as np
from vehicle_common.frame_messages import xyxy_to_bbox
from vehicle_common.image_conversion import byte_array, numpy_to_image

from .disparity import DisparityParams, disparity_range
from .reprojection import StereoGeometry


def build_point_cloud(points: np.ndarray, colours: np.ndarray | None, header):
    """sensor_msgs/PointCloud2 of (N, 3) float32 points (+ packed rgb float32 when given)."""
    from sensor_msgs.msg import PointCloud2, PointField

    fields = [
        PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
        for i, n in enumerate("xyz")
    ]
    cols = [points.astype(np.float32)]
    if colours is not None:
        fields.append(PointField(name="rgb", offset=12, datatype=PointField.FLOAT32, count=1))
        c = colours.astype(np.uint32)
        packed = ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).astype(np.uint32)
        cols.append(packed.view(np.float32)[:, None])
    data = np.ascontiguousarray(np.hstack(cols), dtype=np.float32)
    msg = PointCloud2()
    msg.header = header
    msg.height, msg.width = 1, int(data.shape[0])
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = 4 * data.shape[1]
    msg.row_step = msg.point_step * msg.width
    msg.is_dense = True
    msg.data = byte_array(data)
    return msg


def disparity_message(
    disparity: np.ndarray, geometry: StereoGeometry, params: DisparityParams, header
):
    """stereo_msgs/DisparityImage of a disparity map (invalid pixels -1.0), valid window set."""
    from stereo_msgs.msg import DisparityImage

    msg = DisparityImage()
    msg.header = header
    msg.image = numpy_to_image(disparity, "32FC1", header)
    msg.f = float(geometry.fx)
    msg.t = float(geometry.baseline)
    lo, hi = disparity_range(params)
    msg.min_disparity, msg.max_disparity = float(lo), float(hi)
    msg.delta_d = 1.0 / 16.0 if params.use_wls else params.downscale / 16.0
    valid = disparity > 0
    if valid.any():
        rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
        msg.valid_window.x_offset, msg.valid_window.y_offset = int(cols[0]), int(rows[0])
        msg.valid_window.width = int(cols[-1] - cols[0] + 1)
        msg.valid_window.height = int(rows[-1] - rows[0] + 1)
    return msg


def detection_3d_message(det2d, result, check=None, score: float | None = None):
    """stereo_vehicle_msgs/VehicleDetection3D of a 2D detection message and its ranging result
    (:class:`.ranging.RangeResult`: position, covariance, disparity, valid pixel fraction),
    with its plausibility check (:class:`.plausibility.Plausibility`; None: fields left at 0,
    ``plausible`` false) and ``score`` (None: the 2D detection's)."""
    from stereo_vehicle_msgs.msg import BoundingBox2D, VehicleDetection3D

    m = VehicleDetection3D()
    m.id, m.class_id = det2d.id, det2d.class_id
    m.score = float(det2d.score if score is None else score)
    m.position.x, m.position.y, m.position.z = (float(v) for v in result.position)
    m.position_covariance = [float(v) for v in result.covariance.ravel()]
    m.bbox = det2d.bbox
    if getattr(result, "box", None) is not None:  # extended to an occluded car's full extent
        m.bbox = BoundingBox2D()
        xyxy_to_bbox(result.box, m.bbox)
    m.orientation_bin = det2d.orientation_bin
    m.orientation_probs = [float(v) for v in det2d.orientation_probs]
    m.disparity = float(result.disparity)
    m.valid_pixel_fraction = float(result.valid_pixel_fraction)
    if check is not None:
        c = check.measures
        m.metric_height, m.metric_width = float(c.height), float(c.width)
        m.bottom_height, m.ground_fraction = float(c.bottom_height), float(c.ground_fraction)
        m.plausibility, m.plausible = float(check.plausibility), bool(check.plausible)
    return m
