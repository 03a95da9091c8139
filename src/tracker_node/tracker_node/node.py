"""``vehicle_tracker`` node: /vehicles/detections_3d -> /vehicles/tracks (+ RViz markers).

Converts messages, reads parameters (every field of :class:`.config.TrackerConfig`, same names and
defaults, plus ``camera_matrix``) and calls :class:`.tracker.Tracker`. One TrackedVehicleArray is
published per detection array with the same header. Coasting tracks get the projection of their
3D box as 2D box; the camera matrix comes from the ``camera_matrix`` parameter (12 numbers, the
left camera's P; all zeros = unset) or else from ``/stereo/left/camera_info``.
QoS of all topics: RELIABLE, KEEP_LAST, depth 10, VOLATILE.
"""

from __future__ import annotations

import math
import sys
from dataclasses import fields

import numpy as np
from kitti_player_node.frame_accounting import FrameCounter
from kitti_player_node.frame_messages import bbox_to_xyxy, stamp_ns, xyxy_to_bbox

from .config import NODE_NAME, TrackerConfig, TrackerConfigError
from .tracker import DetectionBatch, Tracker, TrackSet

QOS_DEPTH = 10


def detections_from_msg(msg) -> tuple[DetectionBatch, list[str]]:
    """A DetectionBatch from a VehicleDetection3DArray, and warnings for skipped detections."""
    pos, cov, bbox, bins, score, cls, problems = [], [], [], [], [], [], []
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
    if not pos:
        return DetectionBatch.empty(), problems
    batch = DetectionBatch.create(
        np.array(pos),
        covariance=np.array(cov),
        orientation_bin=np.array(bins),
        bbox=np.array(bbox),
        score=np.array(score),
        class_id=cls,
    )
    return batch, problems


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


def markers_for(tracks: TrackSet, header, ended_ids) -> object:
    """MarkerArray: per track a LINE_LIST box, a TEXT_VIEW_FACING id label and an ARROW for the
    velocity; DELETE markers for the tracks in ``ended_ids``."""
    from geometry_msgs.msg import Point
    from kitti_player_node.box3d import box_corners, box_edges
    from visualization_msgs.msg import Marker, MarkerArray

    colours = {0: (1.0, 1.0, 0.0), 1: (0.0, 1.0, 0.0), 2: (1.0, 0.5, 0.0)}
    arr = MarkerArray()

    def base(ns, mid, kind):
        m = Marker()
        m.header = header
        m.ns, m.id, m.type, m.action = ns, mid, kind, Marker.ADD
        m.pose.orientation.w = 1.0
        return m

    for i in range(len(tracks)):
        mid = int(tracks.track_id[i]) % 2**31
        r, g, b = colours.get(int(tracks.state[i]), (1.0, 1.0, 1.0))
        l, w, h = (float(a) for a in tracks.size[i])
        c = tracks.position[i]
        corners = box_corners((h, w, l), (c[0], c[1] + h / 2, c[2]), float(tracks.yaw[i]))
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


def _make_node_class():
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo
    from stereo_vehicle_msgs.msg import TrackedVehicleArray, VehicleDetection3DArray
    from visualization_msgs.msg import MarkerArray

    class VehicleTrackerNode(Node):
        """Thin ROS wrapper around :class:`Tracker`."""

        def __init__(self, **kwargs):
            super().__init__(NODE_NAME, **kwargs)
            values = {}
            for f in fields(TrackerConfig):
                default = getattr(TrackerConfig(), f.name)
                values[f.name] = self.declare_parameter(f.name, default).value
            cam = self.declare_parameter("camera_matrix", [0.0] * 12).value
            self.config = TrackerConfig.from_dict(values, source="parameters")
            self.tracker = Tracker(self.config)
            if len(cam) == 12 and any(cam):
                self.tracker.set_projection(np.asarray(cam, float).reshape(3, 4))
            qos = QoSProfile(
                depth=QOS_DEPTH,
                reliability=ReliabilityPolicy.RELIABLE,
                history=HistoryPolicy.KEEP_LAST,
            )
            self.pub = self.create_publisher(TrackedVehicleArray, "/vehicles/tracks", qos)
            self.marker_pub = self.create_publisher(MarkerArray, "/vehicles/track_markers", qos)
            self.sub = self.create_subscription(
                VehicleDetection3DArray, "/vehicles/detections_3d", self.on_detections, qos
            )
            self.info_sub = None
            if self.tracker.projection is None:
                self.info_sub = self.create_subscription(
                    CameraInfo, "/stereo/left/camera_info", self.on_camera_info, 5
                )
            self.shown_ids: set[int] = set()
            from kitti_player_node.node_runtime import NodeHealth

            self.frames = FrameCounter()  # detection arrays in, track arrays out
            self.health = NodeHealth(self, self.frames)

        def on_camera_info(self, msg) -> None:
            P = np.asarray(msg.p, float).reshape(3, 4)
            if not np.isfinite(P).all() or P[0, 0] <= 0:
                self.get_logger().warning("/stereo/left/camera_info: invalid P, ignored")
                return
            P = P.copy()
            P[:, 3] = 0.0  # tracks are in this camera's own optical frame
            self.tracker.set_projection(P, (msg.width, msg.height))

        def on_detections(self, msg) -> None:
            self.frames.received()
            try:
                dets, problems = detections_from_msg(msg)
            except (ValueError, TypeError) as exc:
                self.get_logger().warning(f"/vehicles/detections_3d: malformed message: {exc}")
                dets, problems = DetectionBatch.empty(), []
            for p in problems:
                self.get_logger().warning(f"/vehicles/detections_3d: {p}")
            stamp = stamp_ns(msg.header) * 1e-9
            tracks = self.tracker.step(dets, stamp)
            self.pub.publish(tracks_to_msg(tracks, msg.header))
            self.frames.published()
            ids = {int(t) for t in tracks.track_id}
            ended = sorted(self.shown_ids - ids)
            self.shown_ids = ids
            self.marker_pub.publish(markers_for(tracks, msg.header, ended))

    return VehicleTrackerNode


def create_node(**kwargs):
    """Create the vehicle_tracker node (rclpy must be initialised)."""
    return _make_node_class()(**kwargs)


def main(args: list[str] | None = None) -> int:
    import rclpy
    from kitti_player_node.node_runtime import StopRequest, spin_until_stopped
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(
        args=args if args is not None else sys.argv, signal_handler_options=SignalHandlerOptions.NO
    )
    stop = StopRequest.install()
    try:
        node = create_node()
    except TrackerConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except KeyboardInterrupt:  # stopped during start-up
        rclpy.try_shutdown()
        return 0
    try:
        spin_until_stopped(node, stop, node.health)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
