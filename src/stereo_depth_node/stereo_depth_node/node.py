"""ROS 2 node ``stereo_depth``: 3D ranging of 2D detections, visual odometry, optional disparity.

Subscribes to the rectified stereo pair, its CameraInfos and ``/vehicles/detections_2d``; publishes
``/vehicles/detections_3d``, ``/stereo/disparity`` (stereo_msgs/DisparityImage, invalid pixels
-1.0, built only while someone subscribes) and ``/stereo/points`` (sensor_msgs/PointCloud2, off by
default); with the visual odometry, ``/stereo/odometry`` (nav_msgs/Odometry), odom -> camera (or
base) on ``/tf`` and the rig on ``/tf_static`` (:mod:`.odometry_output`). A frame is the complete
set of its three inputs with one stamp: the left and right images and the 2D detection array
(:mod:`.intake`, in order). The newest complete set is processed; a set still waiting when a
newer one is complete, and a set that can no longer complete (a newer one did), is dropped and
counted before any work on it. Each processed set gets exactly one 3D array (empty when its
images cannot be used). The node converts messages, reads its parameters (:mod:`.parameters`)
and publishes; the frame's path (map area, disparity, ranging, plausibility, odometry, road
plane) is the pure core :class:`.pipeline.StereoPipeline`, with one helper thread for its side
work.
"""

from __future__ import annotations

import sys
from concurrent.futures import ThreadPoolExecutor

import cv2
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Header
from stereo_msgs.msg import DisparityImage
from stereo_vehicle_msgs.msg import VehicleDetection2DArray, VehicleDetection3DArray
from tf2_msgs.msg import TFMessage
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.cpu_affinity import available_cpus, usable_threads
from vehicle_common.frame_accounting import FrameCounter, LatestFrameWorker
from vehicle_common.frame_messages import bbox_to_xyxy, stamp_ns, write_transform
from vehicle_common.frame_trace import frame_tracer
from vehicle_common.image_conversion import ImageConversionError, image_to_rgb
from vehicle_common.image_transport import as_message, subscribe_camera, subscribe_image
from vehicle_common.input_usage import InputUsage
from vehicle_common.node_parameters import ParameterError, check_overrides, declare_config
from vehicle_common.node_runtime import NodeHealth, apply_process_settings, run_node
from vehicle_common.stereo_camera import check_stereo_images

from vehicle_common import topics

from .conversions import build_point_cloud, detection_3d_message, disparity_message
from .disparity import RowBandError
from .early_start import EarlyStart
from .intake import FrameIntake, stamp_text
from .odometry_output import OdometryOutput
from .parameters import read_stereo_config
from .pipeline import FrameBoxes, NoGeometry, StereoPipeline
from .reprojection import decimated_points

NODE_NAME = "stereo_depth"


def log_line(logger, level: str, line: str) -> None:
    """A core's report (level "debug" | "info" | "warning") on a node's logger."""
    # one call per severity: rclpy refuses another severity from the same line
    if level == "warning":
        logger.warning(line)
    elif level == "info":
        logger.info(line)
    else:
        logger.debug(line)


def frame_boxes(dets) -> FrameBoxes:
    """The pipeline's view of a frame's 2D detection messages."""
    return FrameBoxes(
        [bbox_to_xyxy(d.bbox) for d in dets],
        [int(d.orientation_bin) for d in dets],
        [getattr(d, "observation_angle", float("nan")) for d in dets],
        [getattr(d, "observation_angle_variance", -1.0) for d in dets],
        [d.score for d in dets],
        [d.id for d in dets],
    )


class OdometryPublishers:
    """The node's odometry outputs (:mod:`.odometry_output`): its integration in odom on
    stereo/odometry and /tf, the rig on /tf_static (each when enabled; nothing without visual
    odometry)."""

    def __init__(self, node: Node, params, visual_odometry: bool) -> None:
        self.out = OdometryOutput(params) if visual_odometry else None
        self.odometry = self.tf = self.tf_static = None
        if self.out is None:
            return
        if params.publish_odometry:
            self.odometry = node.create_publisher(Odometry, topics.ODOMETRY, 10)
        if params.publish_tf:  # tf2's broadcaster QoS: depth 100, volatile
            self.tf = node.create_publisher(TFMessage, topics.TF, 100)
        if params.publish_static_tf:  # tf2's static broadcaster: the last one kept
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.tf_static = node.create_publisher(TFMessage, topics.TF_STATIC, latched)

    def rig(self, left_info, right_info, geometry) -> None:
        """The rig's fixed transforms on /tf_static (when its frames or baseline changed)."""
        if self.tf_static is None:
            return
        left, right = left_info.header, right_info.header
        msg = self.out.rig(stamp_ns(left), left.frame_id, right.frame_id, geometry.baseline)
        if msg is not None:
            self.tf_static.publish(msg)

    def frame(self, header, motion: CameraMotion | None) -> None:
        """The frame's integrated odometry (stereo/odometry) and odom -> child (/tf), before its
        3D array: a consumer of both finds the frame's transform when the array arrives."""
        if self.out is None:
            return
        odom, tf = self.out.frame(stamp_ns(header), header.frame_id, motion)
        if odom is not None and self.odometry is not None:
            self.odometry.publish(odom)
        if tf is not None and self.tf is not None:
            self.tf.publish(tf)


class FrameOutputs:
    """The node's per-frame images: stereo/disparity and stereo/points (each when enabled)."""

    def __init__(self, node: Node, given) -> None:
        self.given = given
        self.disparity = node.create_publisher(DisparityImage, topics.DISPARITY, 5)
        self.points = None
        if given.publish_points:
            self.points = node.create_publisher(PointCloud2, topics.POINTS, 5)

    def wanted(self) -> bool:
        """Whether someone subscribes to the disparity image or the point cloud (they need the
        whole band's map)."""
        if self.given.publish_disparity and self.disparity.get_subscription_count() > 0:
            return True
        return self.points is not None and self.points.get_subscription_count() > 0

    def publish(self, frame, header, left) -> None:
        """The frame's disparity image and point cloud (when enabled and subscribed to: nothing
        is built for no one)."""
        if self.given.publish_disparity and self.disparity.get_subscription_count() > 0:
            msg = disparity_message(frame.disparity, frame.geometry, frame.params, header)
            self.disparity.publish(msg)
        if self.points is not None and self.points.get_subscription_count() > 0:
            pts, rgb = decimated_points(
                frame.disparity,
                frame.geometry,
                self.given.points_decimation,
                left if self.given.points_rgb else None,
                self.given.points_max_depth,
            )
            self.points.publish(build_point_cloud(pts, rgb, header))


class StereoDepthNode(Node):
    """ROS wrapper of :class:`.pipeline.StereoPipeline`: parameters, messages, publishing."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        self.trace = frame_tracer(NODE_NAME)  # per-frame trace points (VEHICLE_TRACE_DIR)
        # num_disparities and ground_height are declared with the node's parameters (0:
        # derived from the camera), the other settings from the core's dataclasses
        config = read_stereo_config(lambda cls, **kw: declare_config(self, cls, **kw))
        p = self.given = config.node  # the camera-dependent settings as given (0: derived)
        #: a parameter found not to fit the camera while running (node_runtime.run_node stops
        #: the node with its one-line error and exit code 2)
        self.fatal_error: ParameterError | None = None
        check_overrides(self)  # every parameter is declared: refuse one the node has not
        # process-wide; at most the CPUs the process may use (cpu_affinity: more only wait)
        cv2.setNumThreads(usable_threads(p.num_threads))
        # a frame's odometry, then its road plane's map, run in this thread beside its map in
        # the boxes and its ranging; the check waits for the road map, the publishing of the
        # 3D array for the odometry (ARCHITECTURE.md, "A frame's path through the graph")
        self._helper = ThreadPoolExecutor(1, thread_name_prefix="stereo-helper")
        self.pipeline = StereoPipeline.from_config(
            config,
            executor=self._helper,
            trace=self.trace,
            log=lambda level, line: log_line(self.get_logger(), level, line),
        )
        #: frames used, and the cause of each one not used (on /diagnostics; issue #42)
        self.usage = InputUsage()
        self.left_info = None
        self.right_info = None
        self.frames_failed = 0
        # frames = detection arrays: in, 3D arrays out, dropped (superseded while waiting, or
        # their images never arrived). The complete sets are processed in one worker thread;
        # a set still waiting when a newer one is complete is dropped (latest-frame policy).
        self.frames = FrameCounter()
        self.worker = LatestFrameWorker(
            self._process_frame,
            self.frames,
            name="stereo",
            on_error=self._work_failed,
            max_waiting=p.frame_queue,
        )
        # not on one CPU: the early work would take it from the CNN (measured, section 17)
        self.early_start = p.early_start and len(available_cpus()) > 1
        if p.early_start and not self.early_start:
            self.get_logger().info("early_start: off, this process may use one CPU only")
        # a frame = its left image, right image and 2D detection array, one stamp (.intake)
        self.intake = FrameIntake(
            p.sync_cache_size,
            p.stereo_sync_tolerance,
            self.frames,
            self.usage,
            self.worker.submit,
            lambda line: self.get_logger().warning(line, throttle_duration_sec=5.0),
            on_pair=(lambda stamp: self.early.pair_ready(stamp)) if self.early_start else None,
        )
        # a frame's work that needs no boxes, begun in the helper thread when the detector
        # announces it started the frame (.early_start); taken by the worker with its boxes
        self.early = EarlyStart(self._helper, self._begin_early, self.intake.pair_of)
        # QoS (docs/ARCHITECTURE.md, "Topics"): the newest INPUT_DEPTH messages of each input:
        # a burst the executor takes late is still seen, and dropped and counted here before
        # any work; older ones are never taken. The camera's topics BEST_EFFORT (any camera)
        # or RELIABLE (parameter camera_reliability: the graph's own player, lockstep loses
        # nothing); the detector's arrays RELIABLE.
        depth_in = max(topics.INPUT_DEPTH, p.frame_queue)
        qos_in = QoSProfile(depth=depth_in)
        self.outputs = FrameOutputs(self, p)  # the disparity image and the point cloud
        self.pub_det3d = self.create_publisher(VehicleDetection3DArray, topics.DETECTIONS_3D, 10)
        self.odometry_pubs = OdometryPublishers(self, config.odometry_output, p.visual_odometry)
        # camera infos first: the executor runs ready callbacks in creation order, so a frame's
        # CameraInfo that arrives with its images is read before the frame is processed
        note = self.usage.note
        subscribe_camera(self, CameraInfo, topics.LEFT_INFO, self._on_left_info, depth_in, note)
        subscribe_camera(self, CameraInfo, topics.RIGHT_INFO, self._on_right_info, depth_in, note)
        # raw or compressed (parameter image_transport); as bytes, converted only for a frame
        # that is processed (a frame the detector skipped costs no image conversion)
        left_cb, right_cb = (lambda m: self._on_input("left", m)), self._on_right
        subscribe_image(self, topics.LEFT_IMAGE, left_cb, depth_in, note, serialized=True)
        subscribe_image(self, topics.RIGHT_IMAGE, right_cb, depth_in, note, serialized=True)
        # the detector's announcement before its array: the executor takes ready callbacks in
        # creation order, so an announcement that arrives with its array is read first
        self.create_subscription(Header, topics.DETECTIONS_2D_STARTED, self._on_started, qos_in)
        self.create_subscription(
            VehicleDetection2DArray,
            topics.DETECTIONS_2D,
            lambda m: self._on_input("detections", m),
            qos_in,
        )
        self.health = NodeHealth(self, self.frames, busy=lambda: self.worker.busy, usage=self.usage)

    def destroy_node(self):
        self.worker.stop()  # the frames in hand and waiting are finished first
        self._helper.shutdown(wait=True)
        super().destroy_node()

    # ------------------------------------------------------------------ callbacks
    def _on_left_info(self, msg) -> None:
        self.left_info = msg
        self._update_geometry()

    def _on_right_info(self, msg) -> None:
        self.right_info = msg
        self._update_geometry()

    def _update_geometry(self) -> None:
        """A new CameraInfo: the pipeline's camera (:meth:`.pipeline.StereoPipeline.update_camera`)
        and the rig's transforms."""
        source = f"{topics.LEFT_INFO}/{topics.RIGHT_INFO}"
        report = self.pipeline.update_camera(self.left_info, self.right_info, source)
        if report is not None:
            taken, level, line = report
            if taken:
                self.odometry_pubs.rig(self.left_info, self.right_info, self.pipeline.geometry)
            log_line(self.get_logger(), level, line)

    def _on_input(self, slot: str, msg) -> None:
        """A left image or a 2D detection array: into the frame's set (:mod:`.intake`)."""
        stamp = stamp_ns(msg.header)
        self.trace(f"{slot}_received", stamp)
        self.intake.add(slot, stamp, msg)

    def _on_right(self, msg) -> None:
        """A right image: into the set of the left image it pairs with (:mod:`.intake`)."""
        stamp = stamp_ns(msg.header)
        self.trace("right_received", stamp)
        self.intake.add_right(stamp, msg)

    def _on_started(self, header) -> None:
        """The detector started a frame: its work that needs no boxes begins once its images
        are here (with ``early_start``; not while the whole band's map is wanted: the
        disparity image or the point cloud has a subscriber)."""
        if self.early_start and not self.outputs.wanted():
            self.early.announce(stamp_ns(header))

    def _begin_early(self, stamp: int, left_msg, right_msg):
        """The helper thread's early work on a frame: its images converted, then
        :meth:`.pipeline.StereoPipeline.begin` (None when it cannot be done ahead)."""
        left_msg, right_msg = as_message(left_msg), as_message(right_msg)
        left, right = image_to_rgb(left_msg), image_to_rgb(right_msg)
        return left_msg, right_msg, left, right, self.pipeline.begin(stamp, left, right)

    def _images(self, stamp: int, left_msg, right_msg):
        """The frame's messages, RGB images and early work (:meth:`_begin_early`, or None):
        from the work begun ahead when there is one, else converted here (a conversion that
        failed ahead fails here again, with its error)."""
        early = self.early.take(stamp)
        if early is not None:
            try:
                return early.result()
            except Exception:  # noqa: BLE001 - converted again below, where it is reported
                pass
        left_msg, right_msg = as_message(left_msg), as_message(right_msg)
        return left_msg, right_msg, image_to_rgb(left_msg), image_to_rgb(right_msg), None

    def _time_went_back(self, stamp: int) -> None:
        """The worker's frame is older than its previous one (a restarted camera or bag): the
        visual odometry, its integration in odom and the road plane start afresh, with one
        warning line."""
        last = self.intake.frame_went_back(stamp)
        if last is None:
            return
        self.get_logger().warning(
            f"time went back from {stamp_text(last)} s to {stamp_text(stamp)} s (a restarted "
            "camera?): the odometry starts afresh in odom"
        )
        self.pipeline.ground.reset()
        if self.pipeline.odometry is not None:
            self.pipeline.odometry.reset()
        if self.odometry_pubs.out is not None:
            self.odometry_pubs.out.integrator.reset()

    def _work_failed(self, exc: Exception, item) -> None:
        self.get_logger().warning(f"stereo processing failed: {exc}")
        self.usage.skipped(f"stereo processing failed: {exc}")
        self._publish_empty(item[2])

    # ------------------------------------------------------------------ processing
    def _process_frame(self, item) -> None:
        """One complete frame: the pipeline's frame path (its disparity map where the ranging
        reads it, its odometry and road plane's map in the helper thread meanwhile, the ranging
        and check), then the 3D array."""
        left_msg, right_msg, det_msg = item
        stamp = stamp_ns(det_msg.header)
        self.trace("pair_start", stamp)
        self._time_went_back(stamp)
        dets = list(det_msg.detections)
        try:
            geometry, settings = self.pipeline.camera()
            left_msg, right_msg, left, right, early = self._images(stamp, left_msg, right_msg)
            # sizes and frame ids of the images and their camera_infos
            check_stereo_images(left_msg, right_msg, left, right, self.left_info, self.right_info)
            params = self.pipeline.disparity_params_for(left.shape[0], settings)
        except (ImageConversionError, ValueError) as exc:
            if isinstance(exc, RowBandError):  # the node stops with that one line
                self.fatal_error = ParameterError(str(exc))
            self.frames_failed += 1
            self.usage.skipped(str(exc))
            # a bad calibration was reported when it arrived; a missing one is reported here
            log = self.get_logger().debug
            if not isinstance(exc, NoGeometry) or self.pipeline.calibration_key is None:
                log = self.get_logger().warning
            if self.fatal_error is not None:  # the node stops with that one line
                log = self.get_logger().debug
            log(f"{topics.LEFT_IMAGE}/{topics.RIGHT_IMAGE}: {exc}; frame skipped")
            self.pipeline.frame_lost()  # a lost frame breaks the odometry's chain
            self._publish_empty(det_msg)
            return
        boxes = frame_boxes(dets)
        frame = self.pipeline.process(
            stamp, left, right, geometry, params, boxes, self.outputs.wanted(), early=early
        )
        out = VehicleDetection3DArray()
        out.header = det_msg.header
        if frame.motion is not None:
            out.camera_motion_dt = frame.motion.dt
            write_transform(frame.motion.rotation, frame.motion.translation, out.camera_motion)
        for i, r, c, score in frame.kept:
            out.detections.append(detection_3d_message(dets[i], r, c, score))
        self.odometry_pubs.frame(out.header, frame.motion)
        self.pub_det3d.publish(out)
        self.trace("detections_3d_published", stamp)
        self.frames.published()
        self.usage.used()
        self.pipeline.frame_done(boxes.boxes)
        if frame.full_map:
            self.outputs.publish(frame, det_msg.header, left)

    def _publish_empty(self, det_msg) -> None:
        """An empty 3D array for a detection array whose frame cannot be used."""
        out = VehicleDetection3DArray()
        out.header = det_msg.header
        self.odometry_pubs.frame(out.header, None)  # extrapolated: no frame, no motion
        self.pub_det3d.publish(out)
        self.frames.published()


def main(args=None) -> int:
    """Console script ``stereo_depth``; exit code 2 for a bad parameter."""
    return run_node(
        StereoDepthNode,
        NODE_NAME,
        args,
        on_stop=lambda node: [node.worker.stop, node.intake.drop_pending],
    )


if __name__ == "__main__":
    sys.exit(main())
