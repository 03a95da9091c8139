"""Message conversions of the detector: detections -> VehicleDetection2DArray, and that as
vision_msgs/Detection2DArray (mapping: :mod:`vehicle_common.vision_messages`).

Shared by the ``vehicle_detector`` node and offline tools; the message package is imported when a
message is built, no rclpy (and no torch).
"""

from __future__ import annotations

from vehicle_common.frame_messages import bbox_to_xyxy, xyxy_to_bbox
from vehicle_common.orientation_bins import bin_to_alpha, fold_alpha_signed
from vehicle_common.vision_messages import detection_2d


def detections_message(header, detections) -> object:
    """VehicleDetection2DArray with ``header`` of :class:`.inference.Detection`-like objects
    (``box``, ``score``, ``orientation_bin``, ``orientation_probs``, and optionally
    ``observation_angle`` / ``observation_angle_variance``): centre/size boxes, ids "0", "1", ...
    An object without a continuous angle (none, or a variance < 0) publishes its bin centre with
    variance -1 (not provided)."""
    from stereo_vehicle_msgs.msg import VehicleDetection2D, VehicleDetection2DArray

    msg = VehicleDetection2DArray(header=header)
    for i, d in enumerate(detections):
        m = VehicleDetection2D()
        m.id = str(i)
        m.class_id = "car"
        m.score = float(d.score)
        xyxy_to_bbox(d.box, m.bbox)
        m.orientation_bin = int(d.orientation_bin)
        m.orientation_probs = [float(p) for p in d.orientation_probs]
        angle = getattr(d, "observation_angle", None)
        var = float(getattr(d, "observation_angle_variance", -1.0))
        if angle is None or var < 0:  # no continuous angle: the bin centre, not provided
            angle, var = bin_to_alpha(int(d.orientation_bin)), -1.0
        m.observation_angle = float(fold_alpha_signed(float(angle)))
        m.observation_angle_variance = var
        msg.detections.append(m)
    return msg


def vision_detections_message(msg) -> object:
    """vision_msgs/Detection2DArray of a VehicleDetection2DArray: same header, one Detection2D
    per detection (box, class and score; the orientation stays on the project's message)."""
    from vision_msgs.msg import Detection2DArray

    out = Detection2DArray(header=msg.header)
    for d in msg.detections:
        out.detections.append(detection_2d(bbox_to_xyxy(d.bbox), d.class_id, d.score, msg.header))
    return out
