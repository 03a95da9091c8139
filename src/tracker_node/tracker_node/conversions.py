"""Message conversions of the tracker: VehicleDetection3DArray -> DetectionBatch, TrackSet ->
TrackedVehicleArray, vision_msgs/Detection3DArray and RViz MarkerArray, in the camera's frame or
moved into another one (``pose``: the camera's pose there, e.g. in ``odom``). Shared by the
``vehicle_tracker`` node and the offline tools that re-run the tracker on recorded messages
(eval_node.filter_comparison). Message packages are imported when a message is built; no rclpy.
"""

from __future__ import annotations

import copy
import functools
import math

import numpy as np
from vehicle_common.box3d import box_corners, box_edges
from vehicle_common.camera_frames import kitti_from_centre
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.frame_messages import bbox_to_xyxy, read_transform, xyxy_to_bbox
from vehicle_common.odometry import Pose
from vehicle_common.vision_messages import detection_3d

from .tracker import DetectionBatch, TrackSet


def detections_from_msg(msg) -> tuple[DetectionBatch, list[str]]:
    """A DetectionBatch from a VehicleDetection3DArray, and warnings for skipped detections."""
    pos, cov, bbox, bins, score, cls, problems = [], [], [], [], [], [], []
    plaus = []
    for k, d in enumerate(msg.detections):
        p = (d.position.x, d.position.y, d.position.z)
        if not all(math.isfinite(v) for v in p):
            problems.append(f"detection {k} (id {d.id!r}): non-finite position, skipped")
            continue
        c = np.asarray(d.position_covariance, float).reshape(3, 3)
        if not np.isfinite(c).all() or not np.any(c):
            c = np.full((3, 3), np.nan)  # unknown: the configured measurement noise is used
        b = d.bbox
        if b.size_x > 0 and b.size_y > 0 and math.isfinite(b.center_x + b.center_y):
            box = bbox_to_xyxy(b)
        else:
            box = (math.nan,) * 4
        pos.append(p)
        cov.append(c)
        bbox.append(box)
        bins.append(int(d.orientation_bin) if d.orientation_bin <= 3 else -1)
        score.append(float(d.score) if math.isfinite(d.score) else 0.0)
        cls.append(d.class_id or "car")
        plaus.append(_plausibility(d))
    if not pos:
        return DetectionBatch.empty(), problems
    batch = DetectionBatch.create(
        np.array(pos),
        covariance=np.array(cov),
        orientation_bin=np.array(bins),
        bbox=np.array(bbox),
        score=np.array(score),
        class_id=cls,
        plausibility=np.array(plaus),
    )
    return batch, problems


def _plausibility(d) -> float:
    """A detection's stereo plausibility in [0, 1] when the message carries it (a float
    ``plausibility`` score, else a bool ``plausible`` flag), NaN otherwise (older messages)."""
    value = getattr(d, "plausibility", None)
    if value is None:
        flag = getattr(d, "plausible", None)
        return math.nan if flag is None else float(bool(flag))
    value = float(value)
    return min(max(value, 0.0), 1.0) if math.isfinite(value) else math.nan


def camera_motion_from_msg(msg) -> tuple[CameraMotion | None, list[str]]:
    """The camera's motion a VehicleDetection3DArray carries (None when ``camera_motion_dt`` is
    0, or the message predates the field), and a warning when it is malformed (then None)."""
    dt = float(getattr(msg, "camera_motion_dt", 0.0) or 0.0)
    if dt == 0.0:
        return None, []
    if not (math.isfinite(dt) and dt > 0):
        return None, [f"camera_motion_dt: {dt} is not a positive time, camera motion ignored"]
    try:
        R, t = read_transform(msg.camera_motion)
    except ValueError as exc:
        return None, [f"camera_motion: {exc}, ignored"]
    return CameraMotion(R, t, dt), []


def heading_vectors(yaw: np.ndarray) -> np.ndarray:
    """Unit heading vectors (N, 3) in the camera's optical frame of KITTI-convention yaws
    (rotation about the camera's y axis, 0 = along x): ``(cos yaw, 0, -sin yaw)``."""
    yaw = np.asarray(yaw, float)
    return np.stack([np.cos(yaw), np.zeros_like(yaw), -np.sin(yaw)], axis=-1)


def box_rotations(yaw: np.ndarray) -> np.ndarray:
    """Box axes (N, 3, 3) in the camera's optical frame: x along the heading, y to the vehicle's
    left, z up (the optical frame's -y)."""
    x = heading_vectors(yaw)
    z = np.broadcast_to([0.0, -1.0, 0.0], x.shape)
    return np.stack([x, np.cross(z, x), z], axis=-1)


class TrackGeometry:
    """A TrackSet's geometry in the frame the camera's ``pose`` places it in (None: the camera's
    optical frame, unchanged): positions, velocities (relative to the camera, and over the
    ground), their covariances, box axes and yaw. In another frame the vectors are rotated and
    positions moved; the yaw is the heading's angle about that frame's z axis (REP-103 frames
    such as ``odom``: z up, 0 along x, counter-clockwise), in the optical frame it stays KITTI's
    rotation about the camera's y axis. Built once per frame for the tracks and the vision
    tracks; the box axes (only the vision tracks use them) on first use."""

    def __init__(self, tracks: TrackSet, pose: Pose | None = None):
        self.pose = pose
        self.position = np.asarray(tracks.position, float).reshape(-1, 3)
        self.position_cov = np.asarray(tracks.position_cov, float).reshape(-1, 3, 3)
        self.velocity = np.asarray(tracks.velocity, float).reshape(-1, 3)
        self.velocity_cov = np.asarray(tracks.velocity_cov, float).reshape(-1, 3, 3)
        self.ground = np.asarray(tracks.velocity_over_ground, float).reshape(-1, 3)
        self.ground_cov = np.asarray(tracks.velocity_over_ground_cov, float).reshape(-1, 3, 3)
        self.yaw = np.asarray(tracks.yaw, float).reshape(-1)
        self._camera_yaw = self.yaw  # KITTI's yaw in the camera's optical frame
        if pose is None:
            return
        R = pose.rotation
        self.position = pose.apply(self.position)
        self.position_cov = R @ self.position_cov @ R.T
        self.velocity = self.velocity @ R.T
        self.velocity_cov = R @ self.velocity_cov @ R.T
        self.ground = self.ground @ R.T  # NaN (unknown) stays NaN
        self.ground_cov = R @ self.ground_cov @ R.T
        heading = heading_vectors(self.yaw) @ R.T
        self.yaw = np.arctan2(heading[:, 1], heading[:, 0])

    @functools.cached_property
    def box_rotation(self) -> np.ndarray:
        """Box axes (N, 3, 3) in the frame (:func:`box_rotations`, rotated by the pose)."""
        axes = box_rotations(self._camera_yaw)
        return axes if self.pose is None else self.pose.rotation @ axes


def tracks_to_msg(tracks: TrackSet, header, pose: Pose | None = None, geometry=None):
    """A TrackedVehicleArray with ``header`` from a TrackSet (``pose``: the camera's pose in the
    header's frame when that is not the camera's, :class:`TrackGeometry`; ``geometry``: that
    TrackGeometry when the caller has it already).

    Each vehicle is a copy of one default TrackedVehicle whose every field is then set (a
    vehicle without a box keeps the default, shared, box): the same message as one built field
    by field, at a third of the CPU."""
    from geometry_msgs.msg import Point, Vector3
    from stereo_vehicle_msgs.msg import BoundingBox2D, TrackedVehicle, TrackedVehicleArray

    geo = TrackGeometry(tracks, pose) if geometry is None else geometry
    out = TrackedVehicleArray()
    out.header = header
    n = len(tracks)
    if not n:
        return out
    template = TrackedVehicle()
    confidence = np.clip(tracks.score, 0.0, 1.0).tolist()  # detection score x track conf.
    position, velocity = geo.position.tolist(), geo.velocity.tolist()
    ground, size = geo.ground.tolist(), np.asarray(tracks.size, float).tolist()
    ground_known = np.isfinite(geo.ground).all(axis=1).tolist()
    box_known = np.isfinite(tracks.bbox).all(axis=1).tolist()
    position_cov = geo.position_cov.reshape(-1, 9)
    velocity_cov = geo.velocity_cov.reshape(-1, 9)
    ground_cov = geo.ground_cov.reshape(-1, 9)
    unknown_cov = [-1.0] + [0.0] * 8  # no camera motion yet: sensor_msgs' convention
    yaw = geo.yaw.tolist()
    vehicles = out.vehicles
    for i in range(n):
        v = copy.copy(template)
        v.track_id = int(tracks.track_id[i])
        v.class_id = tracks.class_id[i]
        v.state = int(tracks.state[i])
        v.confidence = confidence[i]
        x, y, z = position[i]
        v.position = Point(x=x, y=y, z=z)
        v.position_covariance = position_cov[i]
        x, y, z = velocity[i]
        v.velocity = Vector3(x=x, y=y, z=z)
        v.velocity_covariance = velocity_cov[i]
        x, y, z = ground[i]
        v.velocity_over_ground = Vector3(x=x, y=y, z=z)
        v.velocity_over_ground_covariance = ground_cov[i] if ground_known[i] else unknown_cov
        x, y, z = size[i]
        v.size = Vector3(x=x, y=y, z=z)
        v.yaw = yaw[i]
        v.orientation_bin = int(tracks.orientation_bin[i])
        if box_known[i]:
            v.bbox = BoundingBox2D()
            xyxy_to_bbox(tracks.bbox[i], v.bbox)
        v.age = int(tracks.age[i])
        v.frames_since_update = int(tracks.frames_since_update[i])
        vehicles.append(v)
    return out


#: Track states published as vision_msgs detections (tentative tracks stay on the project's
#: topic, with their state: vision_msgs has no field for it)
VISION_STATES = (1, 2)  # TrackedVehicle.STATE_CONFIRMED, STATE_COASTING


def vision_tracks_message(tracks: TrackSet, header, pose: Pose | None = None, geometry=None):
    """vision_msgs/Detection3DArray of the confirmed and coasting tracks, with ``header``
    (mapping: :mod:`vehicle_common.vision_messages`; ``pose`` and ``geometry`` as in
    :func:`tracks_to_msg`)."""
    from vision_msgs.msg import Detection3DArray

    geo = TrackGeometry(tracks, pose) if geometry is None else geometry
    out = Detection3DArray(header=header)
    score = np.clip(tracks.score, 0.0, 1.0).tolist()
    for i in range(len(tracks)):
        if int(tracks.state[i]) not in VISION_STATES:
            continue
        out.detections.append(
            detection_3d(
                str(int(tracks.track_id[i])),
                tracks.class_id[i],
                score[i],
                geo.position[i],
                geo.box_rotation[i],
                tracks.size[i],
                geo.position_cov[i],
                header,
            )
        )
    return out


#: the corners of a box's 12 edges, in LINE_LIST order (pairs)
_EDGE_CORNERS = [k for edge in box_edges() for k in edge]

#: Marker colour (r, g, b) of each track state (tentative, confirmed, coasting; white otherwise)
_MARKER_COLOURS = {0: (1.0, 1.0, 0.0), 1: (0.0, 1.0, 0.0), 2: (1.0, 0.5, 0.0)}

#: Marker lifetime [s]: five frame periods of the KITTI camera (10 Hz), so that boxes vanish
#: soon after the tracker stops publishing instead of staying in RViz for ever.
MARKER_LIFETIME_S = 0.5


def markers_for(
    tracks: TrackSet,
    header,
    ended_ids,
    lifetime_s: float = MARKER_LIFETIME_S,
    pose: Pose | None = None,
) -> object:
    """MarkerArray: a DELETEALL first (clears boxes left by an earlier run or a restarted
    tracker), then per track a LINE_LIST box, a TEXT_VIEW_FACING id label and an ARROW for the
    velocity (over the ground when known, else relative to the camera), each living
    ``lifetime_s``; DELETE markers for the tracks in ``ended_ids``. ``pose``: the camera's pose
    in the header's frame when that is not the camera's (every point moved there)."""
    from builtin_interfaces.msg import Duration
    from geometry_msgs.msg import Point, Vector3
    from std_msgs.msg import ColorRGBA
    from visualization_msgs.msg import Marker, MarkerArray

    arr = MarkerArray()
    clear = Marker()
    clear.header, clear.action = header, Marker.DELETEALL
    arr.markers.append(clear)
    sec = int(lifetime_s)
    lifetime = Duration(sec=sec, nanosec=int(round((lifetime_s - sec) * 1e9)))

    move = pose or Pose()
    # every point of the array at once in the camera's frame (the identity moves each
    # coordinate exactly, whatever the grouping); with a pose point by point (each point's
    # own product: the same rounding as before)
    n = len(tracks)
    # per track: 24 box points (its 12 edges), the label's position, the arrow's two ends
    ps = np.empty((n, 27, 3))
    for i in range(n):
        l, w, h = (float(a) for a in tracks.size[i])
        c = tracks.position[i]
        corners = box_corners((h, w, l), kitti_from_centre(c, h), float(tracks.yaw[i]))
        v = tracks.velocity_over_ground[i]  # the car's own motion when known
        if not np.isfinite(v).all():
            v = tracks.velocity[i]
        ps[i, :24] = corners[_EDGE_CORNERS]
        ps[i, 24:] = ((c[0], c[1] - h / 2 - 0.3, c[2]), c, np.asarray(c, float) + v)
    ps = ps.reshape(-1, 3)
    moved = move.apply(ps) if pose is None else np.array([move.apply(p) for p in ps])
    pts = [Point(x=x, y=y, z=z) for x, y, z in moved.tolist()]

    # Each marker is a copy of one of these (its header, pose, scale, colour and lifetime
    # shared with the array's other markers of its kind: none is changed once built); a
    # Marker built from scratch costs six times a copy.
    base = Marker()
    base.header, base.action, base.lifetime = header, Marker.ADD, lifetime
    base.pose.orientation.w = 1.0
    kinds = {}
    for state in (*_MARKER_COLOURS, None):
        r, g, b = _MARKER_COLOURS.get(state, (1.0, 1.0, 1.0))
        box = copy.copy(base)
        box.ns, box.type = "boxes", Marker.LINE_LIST
        box.scale = Vector3(x=0.05)
        box.color = ColorRGBA(r=r, g=g, b=b, a=1.0)
        arrow = copy.copy(base)
        arrow.ns, arrow.type = "velocity", Marker.ARROW
        arrow.scale = Vector3(x=0.1, y=0.2, z=0.3)
        arrow.color = ColorRGBA(r=r, g=g, b=b, a=1.0)
        kinds[state] = box, arrow
    label = copy.copy(base)
    label.ns, label.type = "labels", Marker.TEXT_VIEW_FACING
    label.scale = Vector3(z=0.6)
    label.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)

    for i in range(n):
        tid = int(tracks.track_id[i])
        mid = tid % 2**31
        box_kind, arrow_kind = kinds.get(int(tracks.state[i]), kinds[None])
        mine = pts[27 * i : 27 * (i + 1)]
        box = copy.copy(box_kind)
        box.id = mid
        box.points = mine[:24]
        text = copy.copy(label)
        text.id = mid
        text.pose = copy.copy(base.pose)
        text.pose.position = mine[24]
        text.text = f"{tid}"
        arrow = copy.copy(arrow_kind)
        arrow.id = mid
        arrow.points = mine[25:]
        arr.markers += [box, text, arrow]
    for tid in ended_ids:
        for ns in ("boxes", "labels", "velocity"):
            m = copy.copy(clear)
            m.ns, m.id, m.action = ns, int(tid) % 2**31, Marker.DELETE
            arr.markers.append(m)
    return arr
