"""The tracker's outputs beside its own message: vision_msgs/Detection3DArray (field mapping,
covariance layout, box orientation) and the tracks, markers and vision tracks in another frame
(``tracks_frame``: odom); the detector's vision_msgs/Detection2DArray; and the evaluator
reading tracks in odom back into the camera's frame."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.frame_messages import header, rotation_from_quaternion, stamp_ns
from vehicle_common.odometry import CameraMount, Pose, rpy_rotation

pytest.importorskip("vision_msgs.msg")

CAMERA = "left_camera_optical_frame"
STAMP = 1_000_000_123


def _tracks(states=(1, 2, 0)):
    from tracker_node.tracker import TrackSet

    n = len(states)
    cov = np.array([[0.1, 0.01, 0.02], [0.01, 0.2, 0.03], [0.02, 0.03, 0.9]])
    return TrackSet(
        track_id=np.array([7, 11, 12][:n]),
        state=np.array(states),
        confidence=np.full(n, 0.8),
        # a car 20 m ahead and 3 m to the right, facing right (KITTI yaw 0), and others
        position=np.array([[3.0, 1.0, 20.0], [-4.0, 0.8, 30.0], [0.0, 1.0, 50.0]][:n]),
        position_cov=np.tile(cov, (n, 1, 1)),
        velocity=np.tile([0.0, 0.0, -12.0], (n, 1)),
        velocity_cov=np.tile(np.eye(3) * 4.0, (n, 1, 1)),
        size=np.tile([4.2, 1.7, 1.5], (n, 1)),
        yaw=np.array([0.0, -np.pi / 2, 1.0][:n]),
        orientation_bin=np.zeros(n, int),
        bbox=np.tile([10.0, 10.0, 50.0, 40.0], (n, 1)),
        age=np.full(n, 4),
        frames_since_update=np.zeros(n, int),
        score=np.array([0.9, 0.7, 0.4][:n]),
        class_id=["car", "van", "car"][:n],
        det_index=np.arange(n),
        velocity_over_ground=np.array([[0.0, 0.0, 0.5], [np.nan] * 3, [1.0, 0.0, 0.0]][:n]),
        velocity_over_ground_cov=np.tile(np.eye(3), (n, 1, 1)),
    )


def test_vision_tracks_field_mapping_in_the_camera_frame():
    from tracker_node.conversions import vision_tracks_message
    from vehicle_common.vision_messages import UNKNOWN_ROTATION_VARIANCE

    tracks = _tracks()
    h = header(STAMP, CAMERA)
    msg = vision_tracks_message(tracks, h)
    assert msg.header.frame_id == CAMERA and stamp_ns(msg.header) == STAMP
    assert [d.id for d in msg.detections] == ["7", "11"]  # tentative track 12 left out
    d = msg.detections[0]
    assert d.header.frame_id == CAMERA and stamp_ns(d.header) == STAMP
    (hyp,) = d.results
    assert hyp.hypothesis.class_id == "car" and hyp.hypothesis.score == pytest.approx(0.9)
    p = hyp.pose.pose.position
    assert (p.x, p.y, p.z) == (3.0, 1.0, 20.0)
    cov = np.asarray(hyp.pose.covariance).reshape(6, 6)  # row-major (x, y, z, rx, ry, rz)
    assert np.allclose(cov[:3, :3], tracks.position_cov[0])
    assert np.allclose(np.diag(cov)[3:], UNKNOWN_ROTATION_VARIANCE)
    assert np.allclose(cov[:3, 3:], 0) and np.allclose(cov, cov.T)
    assert d.bbox.center == hyp.pose.pose
    assert (d.bbox.size.x, d.bbox.size.y, d.bbox.size.z) == (4.2, 1.7, 1.5)
    # box axes: x along the heading (KITTI yaw 0: the optical +x), z up (optical -y)
    q = d.bbox.center.orientation
    R = rotation_from_quaternion(q.w, q.x, q.y, q.z)
    assert np.allclose(R[:, 0], [1, 0, 0]) and np.allclose(R[:, 2], [0, -1, 0])
    assert np.allclose(R[:, 1], [0, 0, 1])  # the vehicle's left: away from the camera
    # yaw -pi/2 (KITTI): heading along the optical z (driving away)
    q = msg.detections[1].bbox.center.orientation
    assert np.allclose(rotation_from_quaternion(q.w, q.x, q.y, q.z)[:, 0], [0, 0, 1])
    assert msg.detections[1].results[0].hypothesis.class_id == "van"


def test_tracks_markers_and_vision_tracks_in_odom():
    """The camera 10 m along odom x, turned 90 deg left: a car 20 m ahead of it is at odom
    (10, 20); vectors and covariances are rotated; the yaw is about odom's z."""
    from tracker_node.conversions import markers_for, tracks_to_msg, vision_tracks_message
    from visualization_msgs.msg import Marker

    turn = rpy_rotation(0.0, 0.0, np.pi / 2)
    pose = Pose(turn @ CameraMount().pose.rotation, [10.0, 0.0, 1.6])
    tracks = _tracks((1,))
    h = header(STAMP, "odom")
    msg = tracks_to_msg(tracks, h, pose)
    assert msg.header.frame_id == "odom" and stamp_ns(msg.header) == STAMP
    (v,) = msg.vehicles
    assert (v.position.x, v.position.y, v.position.z) == pytest.approx((13.0, 20.0, 0.6))
    R = pose.rotation
    cov = np.asarray(v.position_covariance).reshape(3, 3)
    assert np.allclose(cov, R @ tracks.position_cov[0] @ R.T)
    assert (v.velocity.x, v.velocity.y, v.velocity.z) == pytest.approx((0.0, -12.0, 0.0))
    g = v.velocity_over_ground
    assert (g.x, g.y, g.z) == pytest.approx((0.0, 0.5, 0.0))
    # KITTI yaw 0 = facing the camera's right = odom +x after the left turn: yaw 0 about z
    assert v.yaw == pytest.approx(0.0, abs=1e-12)
    assert v.track_id == 7 and v.size.x == 4.2  # the rest as in the camera frame
    # the same vehicle through the other outputs
    (d,) = vision_tracks_message(tracks, h, pose).detections
    p = d.results[0].pose.pose.position
    assert (p.x, p.y, p.z) == pytest.approx((13.0, 20.0, 0.6))
    q = d.bbox.center.orientation
    box = rotation_from_quaternion(q.w, q.x, q.y, q.z)
    assert np.allclose(box, np.eye(3), atol=1e-12)  # heading odom x, left odom y, up odom z
    markers = markers_for(tracks, h, [], pose=pose)
    (label,) = [m for m in markers.markers if m.ns == "labels"]
    assert label.header.frame_id == "odom"
    assert label.pose.position.x == pytest.approx(13.0) and label.pose.position.y == 20.0
    (box_marker,) = [m for m in markers.markers if m.type == Marker.LINE_LIST]
    zs = [pt.z for pt in box_marker.points]
    assert min(zs) == pytest.approx(0.6 - 0.75) and max(zs) == pytest.approx(0.6 + 0.75)


def test_the_evaluator_reads_tracks_in_odom_back_into_the_camera_frame():
    from tracker_node.conversions import tracks_to_msg
    from vehicle_common.bags.recorded_run import tracks_in_camera_frame

    pose = Pose(rpy_rotation(0.01, -0.02, 0.7) @ CameraMount().pose.rotation, [5.0, -2.0, 1.0])
    tracks = _tracks((1, 2))
    camera = tracks_to_msg(tracks, header(STAMP, CAMERA))
    back = tracks_in_camera_frame(tracks_to_msg(tracks, header(STAMP, "odom"), pose), pose)
    for a, b in zip(camera.vehicles, back, strict=True):
        assert (b.position.x, b.position.y, b.position.z) == pytest.approx(
            (a.position.x, a.position.y, a.position.z)
        )
        assert (b.velocity.x, b.velocity.z) == pytest.approx((a.velocity.x, a.velocity.z))
        # the yaw comes back up to the camera's small pitch and roll (a heading in odom's
        # x-y plane stands for it)
        assert b.yaw == pytest.approx(a.yaw, abs=0.03)
        assert b.track_id == a.track_id and b.state == a.state


def test_detector_vision_detections_field_mapping():
    from detector_node.conversions import detections_message, vision_detections_message

    class Det:
        def __init__(self, box, score):
            self.box, self.score = box, score
            self.orientation_bin, self.orientation_probs = 2, [0.1, 0.1, 0.7, 0.1]

    h = header(STAMP, CAMERA)
    own = detections_message(h, [Det((100.0, 150.0, 180.0, 210.0), 0.85), Det((1, 2, 3, 4), 0.4)])
    msg = vision_detections_message(own)
    assert msg.header.frame_id == CAMERA and stamp_ns(msg.header) == STAMP
    assert len(msg.detections) == 2
    d = msg.detections[0]
    assert stamp_ns(d.header) == STAMP and d.header.frame_id == CAMERA
    assert (d.bbox.center.position.x, d.bbox.center.position.y) == (140.0, 180.0)
    assert (d.bbox.size_x, d.bbox.size_y, d.bbox.center.theta) == (80.0, 60.0, 0.0)
    (hyp,) = d.results
    assert hyp.hypothesis.class_id == "car" and hyp.hypothesis.score == pytest.approx(0.85)
    assert d.id == ""  # a detection's id is only its index in one array
