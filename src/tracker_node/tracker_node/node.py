"""``vehicle_tracker`` node: vehicles/detections_3d -> vehicles/tracks (+ RViz markers).

Reads its parameters (every field of :class:`.config.TrackerConfig`, same names and defaults,
plus ``camera_matrix``), converts messages (:mod:`.conversions`) and calls
:class:`.tracker.Tracker`. One TrackedVehicleArray is published per detection array with the same
header. Coasting tracks get the projection of their 3D box as 2D box; the camera matrix comes
from the ``camera_matrix`` parameter (12 numbers, the left camera's P; all zeros = unset) or else
from ``stereo/left/camera_info``. Topic names are relative (:mod:`vehicle_common.topics`).
QoS of all topics: RELIABLE, KEEP_LAST, depth 10, VOLATILE.
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo
from stereo_vehicle_msgs.msg import TrackedVehicleArray, VehicleDetection3DArray
from vehicle_common.frame_accounting import FrameCounter
from vehicle_common.frame_messages import stamp_ns
from vehicle_common.frame_trace import frame_tracer
from vehicle_common.node_parameters import (
    ParameterError,
    check_overrides,
    check_value,
    declare_config,
)
from vehicle_common.node_runtime import NodeHealth, apply_process_settings, run_node
from visualization_msgs.msg import MarkerArray

from vehicle_common import topics

from .config import NODE_NAME, TrackerConfig
from .conversions import camera_motion_from_msg, detections_from_msg, markers_for, tracks_to_msg
from .tracker import DetectionBatch, Tracker

QOS_DEPTH = 10


class VehicleTrackerNode(Node):
    """Thin ROS wrapper around :class:`Tracker`."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        self.trace = frame_tracer(NODE_NAME)  # per-frame trace points (VEHICLE_TRACE_DIR)
        self.config = declare_config(self, TrackerConfig)
        cam = check_value(
            "camera_matrix", self.declare_parameter("camera_matrix", [0.0] * 12).value, [0.0]
        )
        check_overrides(self)  # every parameter is declared: refuse one the node has not
        if len(cam) != 12:
            raise ParameterError("camera_matrix", f"expected 12 numbers, got {len(cam)}")
        self.tracker = Tracker(self.config)
        if any(cam):
            self.tracker.set_projection(np.asarray(cam, float).reshape(3, 4))
        qos = QoSProfile(
            depth=QOS_DEPTH,
            reliability=ReliabilityPolicy.RELIABLE,
            history=HistoryPolicy.KEEP_LAST,
        )
        self.pub = self.create_publisher(TrackedVehicleArray, topics.TRACKS, qos)
        self.marker_pub = self.create_publisher(MarkerArray, topics.TRACK_MARKERS, qos)
        self.sub = self.create_subscription(
            VehicleDetection3DArray, topics.DETECTIONS_3D, self.on_detections, qos
        )
        self.info_sub = None
        if self.tracker.projection is None:
            self.info_sub = self.create_subscription(
                CameraInfo, topics.LEFT_INFO, self.on_camera_info, 5
            )
        self.shown_ids: set[int] = set()
        self.frames = FrameCounter()  # detection arrays in, track arrays out
        self.health = NodeHealth(self, self.frames)

    def on_camera_info(self, msg: CameraInfo) -> None:
        P = np.asarray(msg.p, float).reshape(3, 4)
        if not np.isfinite(P).all() or P[0, 0] <= 0:
            self.get_logger().warning(f"{topics.LEFT_INFO}: invalid P, ignored")
            return
        P = P.copy()
        P[:, 3] = 0.0  # tracks are in this camera's own optical frame
        self.tracker.set_projection(P, (msg.width, msg.height))

    def on_detections(self, msg: VehicleDetection3DArray) -> None:
        self.frames.received()
        try:
            dets, problems = detections_from_msg(msg)
        except (ValueError, TypeError) as exc:
            self.get_logger().warning(f"{topics.DETECTIONS_3D}: malformed message: {exc}")
            dets, problems = DetectionBatch.empty(), []
        motion, motion_problems = camera_motion_from_msg(msg)
        for p in problems + motion_problems:
            self.get_logger().warning(f"{topics.DETECTIONS_3D}: {p}")
        stamp = stamp_ns(msg.header) * 1e-9
        tracks = self.tracker.step(dets, stamp, motion)
        self.pub.publish(tracks_to_msg(tracks, msg.header))
        self.trace("tracks_published", stamp_ns(msg.header))
        self.frames.published()
        ids = {int(t) for t in tracks.track_id}
        ended = sorted(self.shown_ids - ids)
        self.shown_ids = ids
        self.marker_pub.publish(markers_for(tracks, msg.header, ended))


def main(args: list[str] | None = None) -> int:
    """Console script ``vehicle_tracker``; exit code 2 for a bad parameter."""
    return run_node(VehicleTrackerNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
