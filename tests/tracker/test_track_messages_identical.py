"""The tracker node's outputs (tracks, vision tracks, RViz markers) built the cheaper way (issue
#39 item 3: message copies of a template, arrays converted at once, one geometry per frame) are
the messages the field-by-field builders made before, every bit of every field
(``field_bits``): on synthetic track sets with the awkward values (NaN boxes and velocities,
-0.0, unknown states, a pose into odom) and on the graph's tracks of real KITTI 0005
(PointRCNN detections, ORB-SLAM3's camera motion; skipped without ../shared). The reference
builders below are the code before the change, kept as the oracle."""

from __future__ import annotations

import math

import numpy as np
import pytest

GRAPH_PARAMS = "src/tracking_bringup/config/pipeline.params.yaml"


# ------------------------------------------------------------- the builders before the change


def _reference_tracks(tracks, header, pose=None):
    from stereo_vehicle_msgs.msg import TrackedVehicle, TrackedVehicleArray
    from tracker_node.conversions import TrackGeometry
    from vehicle_common.frame_messages import xyxy_to_bbox

    geo = TrackGeometry(tracks, pose)
    out = TrackedVehicleArray()
    out.header = header
    for i in range(len(tracks)):
        v = TrackedVehicle()
        v.track_id = int(tracks.track_id[i])
        v.class_id = tracks.class_id[i]
        v.state = int(tracks.state[i])
        v.confidence = float(np.clip(tracks.score[i], 0.0, 1.0))
        v.position.x, v.position.y, v.position.z = (float(a) for a in geo.position[i])
        v.position_covariance = [float(a) for a in geo.position_cov[i].ravel()]
        v.velocity.x, v.velocity.y, v.velocity.z = (float(a) for a in geo.velocity[i])
        v.velocity_covariance = [float(a) for a in geo.velocity_cov[i].ravel()]
        g = geo.ground[i]
        v.velocity_over_ground.x, v.velocity_over_ground.y, v.velocity_over_ground.z = (
            float(a) for a in g
        )
        if np.isfinite(g).all():
            v.velocity_over_ground_covariance = [float(a) for a in geo.ground_cov[i].ravel()]
        else:
            v.velocity_over_ground_covariance = [-1.0] + [0.0] * 8
        v.size.x, v.size.y, v.size.z = (float(a) for a in tracks.size[i])
        v.yaw = float(geo.yaw[i])
        v.orientation_bin = int(tracks.orientation_bin[i])
        b = tracks.bbox[i]
        if np.isfinite(b).all():
            xyxy_to_bbox(b, v.bbox)
        v.age = int(tracks.age[i])
        v.frames_since_update = int(tracks.frames_since_update[i])
        out.vehicles.append(v)
    return out


def _reference_vision(tracks, header, pose=None):
    from tracker_node.conversions import VISION_STATES, box_rotations
    from vehicle_common.vision_messages import detection_3d
    from vision_msgs.msg import Detection3DArray

    position = np.asarray(tracks.position, float).reshape(-1, 3)
    cov = np.asarray(tracks.position_cov, float).reshape(-1, 3, 3)
    rot = box_rotations(np.asarray(tracks.yaw, float))
    if pose is not None:
        R = pose.rotation
        position, cov, rot = pose.apply(position), R @ cov @ R.T, R @ rot
    out = Detection3DArray(header=header)
    for i in range(len(tracks)):
        if int(tracks.state[i]) not in VISION_STATES:
            continue
        out.detections.append(
            detection_3d(
                str(int(tracks.track_id[i])),
                tracks.class_id[i],
                float(np.clip(tracks.score[i], 0.0, 1.0)),
                position[i],
                rot[i],
                tracks.size[i],
                cov[i],
                header,
            )
        )
    return out


def _reference_markers(tracks, header, ended_ids, lifetime_s=0.5, pose=None):
    from builtin_interfaces.msg import Duration
    from geometry_msgs.msg import Point
    from tracker_node.conversions import _EDGE_CORNERS
    from vehicle_common.box3d import box_corners
    from vehicle_common.camera_frames import kitti_from_centre
    from vehicle_common.odometry import Pose
    from visualization_msgs.msg import Marker, MarkerArray

    colours = {0: (1.0, 1.0, 0.0), 1: (0.0, 1.0, 0.0), 2: (1.0, 0.5, 0.0)}
    arr = MarkerArray()
    clear = Marker()
    clear.header, clear.action = header, Marker.DELETEALL
    arr.markers.append(clear)
    sec = int(lifetime_s)
    lifetime = Duration(sec=sec, nanosec=int(round((lifetime_s - sec) * 1e9)))
    move = pose or Pose()

    def points(ps) -> list:
        ps = np.reshape(np.asarray(ps, float), (-1, 3))
        moved = move.apply(ps) if pose is None else np.array([move.apply(p) for p in ps])
        return [Point(x=x, y=y, z=z) for x, y, z in moved.tolist()]

    def base(ns, mid, kind):
        m = Marker()
        m.header = header
        m.ns, m.id, m.type, m.action = ns, mid, kind, Marker.ADD
        m.pose.orientation.w = 1.0
        m.lifetime = lifetime
        return m

    for i in range(len(tracks)):
        mid = int(tracks.track_id[i]) % 2**31
        r, g, b = colours.get(int(tracks.state[i]), (1.0, 1.0, 1.0))
        l, w, h = (float(a) for a in tracks.size[i])
        c = tracks.position[i]
        corners = box_corners((h, w, l), kitti_from_centre(c, h), float(tracks.yaw[i]))
        box = base("boxes", mid, Marker.LINE_LIST)
        box.scale.x = 0.05
        box.color.r, box.color.g, box.color.b, box.color.a = r, g, b, 1.0
        box.points = points(corners[_EDGE_CORNERS])
        text = base("labels", mid, Marker.TEXT_VIEW_FACING)
        text.pose.position = points((c[0], c[1] - h / 2 - 0.3, c[2]))[0]
        text.scale.z = 0.6
        text.color.r = text.color.g = text.color.b = text.color.a = 1.0
        text.text = f"{int(tracks.track_id[i])}"
        arrow = base("velocity", mid, Marker.ARROW)
        v = tracks.velocity_over_ground[i]
        if not np.isfinite(v).all():
            v = tracks.velocity[i]
        arrow.points = points([c, np.asarray(c, float) + v])
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.1, 0.2, 0.3
        arrow.color.r, arrow.color.g, arrow.color.b, arrow.color.a = r, g, b, 1.0
        arr.markers += [box, text, arrow]
    for tid in ended_ids:
        for ns in ("boxes", "labels", "velocity"):
            m = Marker()
            m.header = header
            m.ns, m.id, m.action = ns, int(tid) % 2**31, Marker.DELETE
            arr.markers.append(m)
    return arr


# ------------------------------------------------------------------------------- the checks


def _assert_identical(tracks, header, ended, pose=None) -> None:
    """The three outputs, as the node builds them now, against the builders before."""
    from tracker_node.conversions import (
        TrackGeometry,
        markers_for,
        tracks_to_msg,
        vision_tracks_message,
    )
    from vehicle_common.frame_messages import field_bits

    geometry = TrackGeometry(tracks, pose)
    pairs = {
        "tracks": (tracks_to_msg(tracks, header, geometry=geometry), _reference_tracks),
        "tracks (own geometry)": (tracks_to_msg(tracks, header, pose), _reference_tracks),
        "vision": (vision_tracks_message(tracks, header, geometry=geometry), _reference_vision),
    }
    for name, (new, reference) in pairs.items():
        assert field_bits(new) == field_bits(reference(tracks, header, pose)), name
    new = markers_for(tracks, header, ended, pose=pose)
    assert field_bits(new) == field_bits(_reference_markers(tracks, header, ended, pose=pose))


def _synthetic_tracks(n: int, rng):
    from tracker_node.tracker import TrackSet

    ground = rng.normal(0.0, 3.0, (n, 3))
    ground[::3] = np.nan  # no camera motion yet
    bbox = rng.uniform(0.0, 600.0, (n, 4))
    bbox[1::4] = np.nan  # a coasting track without a camera matrix: no box
    position = rng.normal([0.0, 1.5, 25.0], [8.0, 0.5, 10.0], (n, 3))
    position[::5, 0] = -0.0  # signed zeros survive (or not) the same way
    A = rng.normal(size=(n, 3, 3))
    return TrackSet(
        track_id=np.arange(1, n + 1) * 7,
        state=rng.integers(0, 4, n),  # 3: no state of the message, drawn white
        confidence=rng.uniform(0.0, 1.0, n),
        position=position,
        position_cov=A @ A.transpose(0, 2, 1),
        velocity=rng.normal(0.0, 5.0, (n, 3)),
        velocity_cov=A.transpose(0, 2, 1) @ A,
        size=rng.uniform([3.0, 1.4, 1.3], [5.0, 2.0, 2.0], (n, 3)),
        yaw=rng.uniform(-math.pi, math.pi, n),
        orientation_bin=rng.integers(0, 4, n),
        bbox=bbox,
        age=rng.integers(1, 50, n),
        frames_since_update=rng.integers(0, 4, n),
        score=rng.uniform(-0.2, 1.3, n),  # clipped to [0, 1]
        class_id=["car", "van"] * (n // 2) + ["car"] * (n % 2),
        det_index=np.arange(n),
        velocity_over_ground=ground,
        velocity_over_ground_cov=np.where(np.isnan(ground)[:, :, None], np.nan, A @ A.mT),
    )


def test_outputs_identical_on_synthetic_track_sets():
    from std_msgs.msg import Header
    from vehicle_common.odometry import Pose, rpy_rotation

    rng = np.random.default_rng(39)
    header = Header(frame_id="left_camera_optical_frame")
    header.stamp.sec, header.stamp.nanosec = 12, 300_000_000
    odom = Pose(rpy_rotation(-math.pi / 2, 0.01, -math.pi / 2 + 0.2), np.array([5.0, -2.0, 1.6]))
    for n in (0, 1, 7, 16):
        tracks = _synthetic_tracks(n, rng)
        _assert_identical(tracks, header, ended=[3, 2**31 + 5])
        _assert_identical(tracks, Header(frame_id="odom"), ended=[], pose=odom)


def test_markers_of_one_array_share_nothing_that_changes():
    """Markers are copies of per-array templates: building a second array leaves the first
    one's fields as they were (nothing shared across arrays is changed afterwards)."""
    from std_msgs.msg import Header
    from tracker_node.conversions import markers_for
    from vehicle_common.frame_messages import field_bits

    rng = np.random.default_rng(1)
    first = markers_for(_synthetic_tracks(5, rng), Header(frame_id="a"), ended_ids=[9])
    bits = field_bits(first)
    markers_for(_synthetic_tracks(6, rng), Header(frame_id="b"), ended_ids=[4])
    assert field_bits(first) == bits
    labels = [m for m in first.markers if m.ns == "labels"]
    assert len({id(m.pose) for m in labels}) == len(labels)  # each label its own position


def test_rotate_covariances_equals_kron_bit_for_bit():
    """The block-diagonal rotation built without np.kron: the same products, signed zeros
    included, so the same rotated covariances."""
    from tracker_node.ego_motion import rotate_covariances

    rng = np.random.default_rng(5)
    for k in (1, 2, 3):
        for _ in range(50):
            R = rng.normal(size=(3, 3))
            cov = rng.normal(size=(4, 3 * k, 3 * k))
            cov[:2] = np.kron(np.eye(k), cov[0, :3, :3])  # zero blocks: the zeros' signs too
            A = np.kron(np.eye(k), R)
            assert (rotate_covariances(cov, R)).tobytes() == (A @ cov @ A.T).tobytes()


def _real_0005_tracks(shared_kitti, frames: int):
    """Per frame of real 0005: the graph's tracker (pipeline.params.yaml) on the PointRCNN
    detections (scores scaled into [0, 1], orientation bins), in the world frame with
    ORB-SLAM3's camera motion, with the left camera's matrix: (TrackSet, ended ids)."""
    from pathlib import Path

    from tracker_node.config import TrackerConfig
    from tracker_node.detection_files import read_detection_file
    from tracker_node.offline import CAR_TYPE_ID, detections_for_frame
    from tracker_node.tracker import Tracker
    from vehicle_common.camera_motion import CameraMotion
    from vehicle_common.kitti import read_calib
    from vehicle_common.orientation_bins import alpha_to_bin

    root = shared_kitti / "tracking/training"
    rows = read_detection_file(shared_kitti / "detections/pointrcnn_Car_val/0005.txt")
    rows = rows.select(rows.type_id == CAR_TYPE_ID)
    calib = read_calib(root / "calib/0005.txt")
    poses = np.loadtxt(root / "poses_orbslam3/0005.txt").reshape(-1, 3, 4)
    cfg = TrackerConfig.from_yaml(Path(__file__).parents[2] / GRAPH_PARAMS)
    tracker = Tracker(cfg, np.hstack([calib.K, np.zeros((3, 1))]))
    out, shown = [], set()
    for f in range(min(frames, len(poses))):
        sel = np.nonzero(rows.frame == f)[0]
        dets = detections_for_frame(rows, sel, calib.left_camera_offset)
        dets.score = np.clip(rows.score[sel] / 20.0, 0.0, 1.0)
        dets.orientation_bin = np.asarray(alpha_to_bin(rows.alpha[sel]), int).reshape(-1)
        dets.yaw = np.full(len(sel), np.nan)  # the stereo graph's detections carry bins only
        motion = None
        if f:
            R0, t0, R1, t1 = (
                poses[f - 1][:, :3],
                poses[f - 1][:, 3],
                poses[f][:, :3],
                poses[f][:, 3],
            )
            motion = CameraMotion(R1.T @ R0, R1.T @ (t0 - t1), 0.1)
        tracks = tracker.step(dets, f * 0.1, motion)
        ids = {int(t) for t in tracks.track_id}
        out.append((tracks, sorted(shown - ids)))
        shown = ids
    return out


def test_outputs_identical_on_real_0005(shared_kitti):
    from std_msgs.msg import Header
    from vehicle_common.odometry import Pose, rpy_rotation

    frames = _real_0005_tracks(shared_kitti, 120)
    assert sum(len(t) for t, _ in frames) > 200  # the sequence's cars, tracked
    assert any(np.isfinite(t.velocity_over_ground).all() and len(t) for t, _ in frames)
    odom = Pose(rpy_rotation(-math.pi / 2, 0.0, -math.pi / 2), np.array([0.3, 0.0, 1.65]))
    for k, (tracks, ended) in enumerate(frames):
        header = Header(frame_id="left_camera_optical_frame")
        header.stamp.sec, header.stamp.nanosec = k // 10, (k % 10) * 100_000_000
        _assert_identical(tracks, header, ended)
        if k % 10 == 0:
            _assert_identical(tracks, Header(frame_id="odom"), ended, pose=odom)


@pytest.mark.parametrize("subscribed", [False, True])
def test_node_builds_markers_only_for_a_subscriber(rclpy_context, monkeypatch, subscribed):
    """Without a marker subscriber the node builds no marker array (nobody could receive it);
    the tracks go out the same and the list of shown tracks is kept for a later subscriber."""
    from rclpy.node import Node
    from stereo_vehicle_msgs.msg import VehicleDetection3D, VehicleDetection3DArray
    from tracker_node.node import VehicleTrackerNode
    from visualization_msgs.msg import MarkerArray

    from tests.ros_helpers import spin_until
    from tracker_node import node as node_module

    built = []
    real = node_module.markers_for
    monkeypatch.setattr(
        node_module, "markers_for", lambda *a, **k: built.append(1) or real(*a, **k)
    )
    node = VehicleTrackerNode(context=rclpy_context)
    helper = Node("marker_probe", context=rclpy_context)
    try:
        if subscribed:
            helper.create_subscription(MarkerArray, "/vehicles/track_markers", lambda m: None, 10)
            from rclpy.executors import SingleThreadedExecutor

            ex = SingleThreadedExecutor(context=rclpy_context)
            ex.add_node(helper)
            assert spin_until(ex, lambda: node.marker_pub.get_subscription_count() > 0)
            ex.shutdown()
        msg = VehicleDetection3DArray()
        msg.header.frame_id = "left_camera_optical_frame"
        for k in range(2):
            msg.header.stamp.sec = k
            msg.detections = [VehicleDetection3D(score=0.9)]
            msg.detections[0].position.z = 20.0
            node.on_detections(msg)
        assert len(built) == (2 if subscribed else 0)
        assert node.shown_ids == {1}
    finally:
        helper.destroy_node()
        node.destroy_node()


def _reference_quaternion(rotation):
    """vehicle_common.frame_messages.quaternion_from_matrix before 2026-11-29 (numpy
    scalars)."""
    R = np.asarray(rotation, float).reshape(3, 3)
    tr = np.trace(R)
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = (0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s)
    else:
        i, j, m = (k - 1, k % 3, (k + 1) % 3)
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[m, m])
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (R[j, i] + R[i, j]) / s
        v[m] = (R[m, i] + R[i, m]) / s
        q = ((R[m, j] - R[j, m]) / s, *v)
    w, x, y, z = np.asarray(q) * (1.0 if q[0] >= 0 else -1.0)
    return float(w), float(x), float(y), float(z)


def test_quaternion_in_python_floats_equals_numpy_bit_for_bit():
    """The quaternion of the vision tracks' (and the odometry's) rotations, now computed in
    Python floats: the same bits as numpy's scalars gave, on box axes with their exact and
    signed zeros, random rotations, both composed, the axis flips and non-finite matrices."""
    import struct

    from tracker_node.conversions import box_rotations
    from vehicle_common.frame_messages import quaternion_from_matrix
    from vehicle_common.odometry import rpy_rotation

    rng = np.random.default_rng(11)
    yaws = np.concatenate([[0.0, -0.0, math.pi / 2, -math.pi / 2, math.pi, -math.pi, 1e-300]])
    mats = list(box_rotations(np.concatenate([yaws, rng.uniform(-4.0, 4.0, 1500)])))
    for _ in range(1500):
        mats.append(rpy_rotation(*rng.uniform(-4.0, 4.0, 3)))
        mats.append(mats[-1] @ box_rotations(np.array([rng.uniform(-4.0, 4.0)]))[0])
    mats += [np.diag(d) for d in ([1.0, -1, -1], [-1.0, 1, -1], [-1.0, -1, 1], [1.0, -0.0, -0.0])]
    mats += [np.full((3, 3), np.nan), np.diag([np.inf, 1.0, 1.0]), np.diag([-5.0, -5.0, -5.0])]
    with np.errstate(invalid="ignore"):
        for R in mats:
            got, want = quaternion_from_matrix(R), _reference_quaternion(R)
            assert struct.pack("<4d", *got) == struct.pack("<4d", *want), R
