"""Message conversions of the tracker: VehicleDetection3DArray -> DetectionBatch, TrackSet ->
TrackedVehicleArray and RViz MarkerArray. Shared by the ``vehicle_tracker`` node and the offline
tools that re-run the tracker on recorded messages (eval_node.filter_comparison). Message
packages are imported when a message is built; no rclpy.
"""

from __future__ import annotations

import math

import numpy as np
from vehicle_common.box3d import box_corners, box_edges
from vehicle_common.camera_frames import kitti_from_centre
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.frame_messages import bbox_to_xyxy, read_transform, xyxy_to_bbox

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


def tracks_to_msg(tracks: TrackSet, header):
    """A TrackedVehicleArray with ``header`` from a TrackSet."""
    from stereo_vehicle_msgs.msg import TrackedVehicle, TrackedVehicleArray

    out = TrackedVehicleArray()
    out.header = header
    for i in range(len(tracks)):
        v = TrackedVehicle()
        v.track_id = int(tracks.track_id[i])
        v.class_id = tracks.class_id[i]
        v.state = int(tracks.state[i])
        v.confidence = float(np.clip(tracks.score[i], 0.0, 1.0))  # detection score x track conf.
        v.position.x, v.position.y, v.position.z = (float(a) for a in tracks.position[i])
        v.position_covariance = [float(a) for a in tracks.position_cov[i].ravel()]
        v.velocity.x, v.velocity.y, v.velocity.z = (float(a) for a in tracks.velocity[i])
        v.velocity_covariance = [float(a) for a in tracks.velocity_cov[i].ravel()]
        g = tracks.velocity_over_ground[i]
        v.velocity_over_ground.x, v.velocity_over_ground.y, v.velocity_over_ground.z = (
            float(a) for a in g
        )
        if np.isfinite(g).all():
            gc = tracks.velocity_over_ground_cov[i].ravel()
            v.velocity_over_ground_covariance = [float(a) for a in gc]
        else:  # unknown (no camera motion yet): sensor_msgs' convention
            v.velocity_over_ground_covariance = [-1.0] + [0.0] * 8
        v.size.x, v.size.y, v.size.z = (float(a) for a in tracks.size[i])
        v.yaw = float(tracks.yaw[i])
        v.orientation_bin = int(tracks.orientation_bin[i])
        b = tracks.bbox[i]
        if np.isfinite(b).all():
            xyxy_to_bbox(b, v.bbox)
        v.age = int(tracks.age[i])
        v.frames_since_update = int(tracks.frames_since_update[i])
        out.vehicles.append(v)
    return out


#: Marker lifetime [s]: five frame periods of the KITTI camera (10 Hz), so that boxes vanish
#: soon after the tracker stops publishing instead of staying in RViz for ever.
MARKER_LIFETIME_S = 0.5


def markers_for(
    tracks: TrackSet, header, ended_ids, lifetime_s: float = MARKER_LIFETIME_S
) -> object:
    """MarkerArray: a DELETEALL first (clears boxes left by an earlier run or a restarted
    tracker), then per track a LINE_LIST box, a TEXT_VIEW_FACING id label and an ARROW for the
    velocity (over the ground when known, else relative to the camera), each living
    ``lifetime_s``; DELETE markers for the tracks in ``ended_ids``."""
    from builtin_interfaces.msg import Duration
    from geometry_msgs.msg import Point
    from visualization_msgs.msg import Marker, MarkerArray

    colours = {0: (1.0, 1.0, 0.0), 1: (0.0, 1.0, 0.0), 2: (1.0, 0.5, 0.0)}
    arr = MarkerArray()
    clear = Marker()
    clear.header, clear.action = header, Marker.DELETEALL
    arr.markers.append(clear)
    sec = int(lifetime_s)
    lifetime = Duration(sec=sec, nanosec=int(round((lifetime_s - sec) * 1e9)))

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
        for a, e in box_edges():
            for k in (a, e):
                box.points.append(
                    Point(x=float(corners[k, 0]), y=float(corners[k, 1]), z=float(corners[k, 2]))
                )
        text = base("labels", mid, Marker.TEXT_VIEW_FACING)
        text.pose.position = Point(x=float(c[0]), y=float(c[1] - h / 2 - 0.3), z=float(c[2]))
        text.scale.z = 0.6
        text.color.r = text.color.g = text.color.b = text.color.a = 1.0
        text.text = f"{int(tracks.track_id[i])}"
        arrow = base("velocity", mid, Marker.ARROW)
        v = tracks.velocity_over_ground[i]  # the car's own motion when known
        if not np.isfinite(v).all():
            v = tracks.velocity[i]
        arrow.points = [
            Point(x=float(c[0]), y=float(c[1]), z=float(c[2])),
            Point(x=float(c[0] + v[0]), y=float(c[1] + v[1]), z=float(c[2] + v[2])),
        ]
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
