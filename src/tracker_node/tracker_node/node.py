"""``vehicle_tracker`` node: vehicles/detections_3d -> vehicles/tracks (+ RViz markers).

Reads its parameters (every field of :class:`.config.TrackerConfig`, same names and defaults,
plus ``camera_matrix``), converts messages (:mod:`.conversions`) and calls
:class:`.tracker.Tracker`. One TrackedVehicleArray is published per detection array with the same
header. Coasting tracks get the projection of their 3D box as 2D box; the camera matrix comes
from the ``camera_matrix`` parameter (12 numbers, the left camera's P; all zeros = unset) or else
from ``stereo/left/camera_info``. Topic names are relative (:mod:`vehicle_common.topics`).
QoS of all topics: RELIABLE, KEEP_LAST, depth 10, VOLATILE.

The tracks also go out as vision_msgs/Detection3DArray on ``vehicles/vision/tracks`` (confirmed
and coasting tracks). The vision tracks and the markers are built only while someone subscribes
(a publisher sends only to its matched subscriptions: nobody could have received them; nothing
else depends on them, the markers' list of shown tracks is kept either way). ``tracks_frame``
(parameter; "" = the input's frame, the left camera's optical frame) publishes tracks, markers
and vision tracks in another frame, e.g. ``odom``: the camera's pose there at each array's stamp
comes from /tf and /tf_static (:class:`~vehicle_common.odometry_messages.TransformTree`), and,
when a frame's transform is not there (yet), from the last one it had carried on with the
arrays' camera motions, as the stereo node integrates them (:mod:`vehicle_common.odometry`).
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo
from stereo_vehicle_msgs.msg import TrackedVehicleArray, VehicleDetection3DArray
from tf2_msgs.msg import TFMessage
from vehicle_common.frame_accounting import FrameCounter
from vehicle_common.frame_messages import stamp_ns
from vehicle_common.frame_trace import frame_tracer
from vehicle_common.node_parameters import (
    ParameterError,
    check_overrides,
    declare_config,
)
from vehicle_common.node_runtime import NodeHealth, apply_process_settings, run_node
from vehicle_common.odometry import OdometryIntegrator
from vehicle_common.odometry_messages import TransformTree
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from vehicle_common import topics

from .config import NODE_NAME, TrackerConfig
from .conversions import (
    TrackGeometry,
    camera_motion_from_msg,
    detections_from_msg,
    markers_for,
    tracks_to_msg,
    vision_tracks_message,
)
from .parameters import TrackerNodeParameters
from .tracker import DetectionBatch, Tracker

QOS_DEPTH = 10


class VehicleTrackerNode(Node):
    """Thin ROS wrapper around :class:`Tracker`."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        self.trace = frame_tracer(NODE_NAME)  # per-frame trace points (VEHICLE_TRACE_DIR)
        self.config = declare_config(self, TrackerConfig)
        node_params = declare_config(self, TrackerNodeParameters)
        check_overrides(self)  # every parameter is declared: refuse one the node has not
        cam = node_params.camera_matrix
        if len(cam) != 12:
            raise ParameterError("camera_matrix", f"expected 12 numbers, got {len(cam)}")
        self.tracks_frame = node_params.tracks_frame
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
        self.vision_pub = self.create_publisher(Detection3DArray, topics.VISION_TRACKS, qos)
        self.transforms = None
        if self.tracks_frame:
            # the camera's pose in tracks_frame: /tf and /tf_static (subscribed before the 3D
            # arrays: a frame's transform, published first, is read first), carried on with the
            # arrays' camera motions where a frame's transform is missing
            self.transforms = TransformTree()
            self.pose_integrator = OdometryIntegrator()
            self.frames_without_tf = 0
            self._warned_frames: set[str] = set()
            self.create_subscription(TFMessage, topics.TF, self.on_tf, 100)
            latched = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(TFMessage, topics.TF_STATIC, self.on_tf_static, latched)
        self.sub = self.create_subscription(
            VehicleDetection3DArray, topics.DETECTIONS_3D, self.on_detections, qos
        )
        self.info_sub = None
        if self.tracker.projection is None:
            # BEST_EFFORT: any camera's camera_info matches (only the latest is used)
            info_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.info_sub = self.create_subscription(
                CameraInfo, topics.LEFT_INFO, self.on_camera_info, info_qos
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

    def on_tf(self, msg: TFMessage, static: bool = False) -> None:
        try:
            self.transforms.add_message(msg, static)
        except ValueError as exc:
            name = topics.TF_STATIC if static else topics.TF
            self.get_logger().warning(f"{name}: {exc}; ignored")

    def on_tf_static(self, msg: TFMessage) -> None:
        self.on_tf(msg, static=True)

    def _camera_pose(self, header, motion):
        """The camera's pose in ``tracks_frame`` at the array's stamp (None: unknown yet)."""
        stamp = stamp_ns(header)
        pose = self.transforms.lookup(self.tracks_frame, header.frame_id, stamp)
        integrator = self.pose_integrator
        if pose is not None:
            if integrator.last is None or stamp >= integrator.last.stamp_ns:
                integrator.update(stamp, motion)  # keeps its twist for the frames without tf
            integrator.anchor(stamp, pose)
            return pose
        self.frames_without_tf += 1
        if integrator.last is None:
            if header.frame_id not in self._warned_frames:
                self._warned_frames.add(header.frame_id)
                self.get_logger().warning(
                    f"no transform {self.tracks_frame} -> {header.frame_id} on {topics.TF} yet;"
                    f" tracks published in {header.frame_id} until there is one"
                )
            return None
        try:
            return integrator.update(stamp, motion).pose
        except ValueError:  # a stamp before the last one: no pose for it
            return None

    def _check_time(self, stamp: float) -> None:
        """An array older than the previous one (a restarted camera or bag): the tracks of
        the previous stream end and tracking starts afresh, with one warning line."""
        last = self.tracker.last_stamp
        if last is None or stamp >= last:
            return
        ended = self.tracker.reset()
        if self.transforms is not None:
            self.pose_integrator.reset()
        self.get_logger().warning(
            f"{topics.DETECTIONS_3D}: time went back from {last:.3f} s to {stamp:.3f} s (a "
            f"restarted camera?): {ended} tracks ended, tracking starts afresh"
        )

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
        self._check_time(stamp)
        tracks = self.tracker.step(dets, stamp, motion)
        header, pose = msg.header, None
        if self.transforms is not None:
            pose = self._camera_pose(msg.header, motion)
            if pose is not None:
                header = type(msg.header)(stamp=msg.header.stamp, frame_id=self.tracks_frame)
        geometry = TrackGeometry(tracks, pose)  # once for the tracks and the vision tracks
        self.pub.publish(tracks_to_msg(tracks, header, geometry=geometry))
        self.trace("tracks_published", stamp_ns(msg.header))
        self.frames.published()
        if self.vision_pub.get_subscription_count() > 0:
            self.vision_pub.publish(vision_tracks_message(tracks, header, geometry=geometry))
        ids = {int(t) for t in tracks.track_id}
        ended = sorted(self.shown_ids - ids)
        self.shown_ids = ids  # kept without subscribers too: a later one gets the same markers
        if self.marker_pub.get_subscription_count() > 0:
            self.marker_pub.publish(markers_for(tracks, header, ended, pose=pose))


def main(args: list[str] | None = None) -> int:
    """Console script ``vehicle_tracker``; exit code 2 for a bad parameter."""
    return run_node(VehicleTrackerNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
