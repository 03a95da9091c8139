"""Message conversions of the detector: detections -> VehicleDetection2DArray.

Shared by the ``vehicle_detector`` node and offline tools; the message package is imported when a
message is built, no rclpy (and no torch).
"""

from __future__ import annotations

from vehicle_common.frame_messages import xyxy_to_bbox


def detections_message(header, detections) -> object:
    """VehicleDetection2DArray with ``header`` of :class:`.inference.Detection`-like objects
    (``box``, ``score``, ``orientation_bin``, ``orientation_probs``): centre/size boxes, ids
    "0", "1", ..."""
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
        msg.detections.append(m)
    return msg
