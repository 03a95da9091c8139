"""vision_msgs (4.x) messages of the graph's detections and tracks, beside its own messages.

The field mapping (README, "Subscribing to the tracked vehicles"; docs/ARCHITECTURE.md):

- ``Detection2D`` (the detector's boxes, ``vehicles/vision/detections_2d``): ``header`` = the
  image's; ``bbox.center.position`` = the box centre [px], ``theta`` 0 (axis-aligned),
  ``size_x`` / ``size_y`` [px]; ``results`` = one ``ObjectHypothesisWithPose`` with
  ``hypothesis.class_id`` ("car") and ``hypothesis.score``, its ``pose`` unused (zeros, as 2D
  detectors leave it); ``id`` empty (vision_msgs reserves it for ids that persist across
  messages; a detection's id is its index in one array).
- ``Detection3D`` (the tracks, ``vehicles/vision/tracks``): ``header`` = the tracks' (stamp of
  the frame; the camera's optical frame or ``odom``); ``id`` = the track id (decimal, stable
  over the track's life, never reused in a run); ``results`` = one hypothesis: class id and the
  track's confidence, ``pose.pose`` = the vehicle's centre and the box orientation below,
  ``pose.covariance`` = the position covariance [m^2] in the top-left 3x3 and
  :data:`UNKNOWN_ROTATION_VARIANCE` on the rotation diagonal (the heading's uncertainty is not
  estimated); ``bbox.center`` = the same pose, ``bbox.size`` = (length, width, height) [m] along
  the box axes. Box axes: x along the vehicle's heading, y to its left, z up (REP-103 body
  axes of the vehicle).

Message packages are imported inside the functions (no rclpy here).
"""

from __future__ import annotations

import numpy as np

from .frame_messages import write_pose

#: Variance [rad^2] on the rotation diagonal of a track's pose covariance: the tracker does not
#: estimate its heading's uncertainty (a value large enough that weighting ignores it).
UNKNOWN_ROTATION_VARIANCE = 1.0e6


def _hypothesis(class_id: str, score: float):
    from vision_msgs.msg import ObjectHypothesisWithPose

    h = ObjectHypothesisWithPose()
    h.hypothesis.class_id = str(class_id)
    h.hypothesis.score = float(score)
    return h


def detection_2d(box_xyxy, class_id: str, score: float, header):
    """vision_msgs/Detection2D of an axis-aligned image box (x1, y1, x2, y2) [px]."""
    from vision_msgs.msg import Detection2D

    x1, y1, x2, y2 = (float(v) for v in box_xyxy)
    d = Detection2D(header=header)
    d.bbox.center.position.x, d.bbox.center.position.y = (x1 + x2) / 2.0, (y1 + y2) / 2.0
    d.bbox.center.theta = 0.0
    d.bbox.size_x, d.bbox.size_y = max(0.0, x2 - x1), max(0.0, y2 - y1)
    d.results.append(_hypothesis(class_id, score))
    return d


def detection_3d(
    object_id: str,
    class_id: str,
    score: float,
    centre,
    rotation,
    size,
    position_covariance,
    header,
):
    """vision_msgs/Detection3D of a 3D box: ``centre`` (3,) [m], ``rotation`` (3x3: the box
    axes in the header's frame), ``size`` (length, width, height) [m], ``position_covariance``
    (3x3) [m^2]."""
    from vision_msgs.msg import Detection3D

    d = Detection3D(header=header, id=str(object_id))
    h = _hypothesis(class_id, score)
    write_pose(rotation, centre, h.pose.pose)
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.asarray(position_covariance, float).reshape(3, 3)
    cov[3:, 3:] = np.eye(3) * UNKNOWN_ROTATION_VARIANCE
    h.pose.covariance = cov.ravel()  # float64[36]: the same values as a list of floats
    d.results.append(h)
    d.bbox.center = h.pose.pose
    d.bbox.size.x, d.bbox.size.y, d.bbox.size.z = (float(v) for v in size)
    return d
