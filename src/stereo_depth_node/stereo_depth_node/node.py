"""ROS 2 node ``stereo_depth``: 3D ranging of 2D detections, visual odometry, optional disparity.

Subscribes to the rectified stereo pair, its CameraInfos and ``/vehicles/detections_2d``; publishes
``/vehicles/detections_3d``, ``/stereo/disparity`` (stereo_msgs/DisparityImage, invalid pixels
-1.0, built only while someone subscribes) and ``/stereo/points`` (sensor_msgs/PointCloud2, off by
default); with the visual odometry, ``/stereo/odometry`` (nav_msgs/Odometry), odom -> camera (or
base) on ``/tf`` and the rig on ``/tf_static`` (:mod:`.odometry_output`). A frame is the complete
set of its three inputs with one stamp: the left and right images and the 2D detection array
(:mod:`.stamp_sync`, in order). The newest complete set is processed; a set still waiting when a
newer one is complete, and a set that can no longer complete (a newer one did), is dropped and
counted before any work on it. Each processed set gets exactly one 3D array (empty when its
images cannot be used). All computation is in the pure core modules.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import CameraInfo, PointCloud2
from stereo_msgs.msg import DisparityImage
from stereo_vehicle_msgs.msg import VehicleDetection2DArray, VehicleDetection3DArray
from tf2_msgs.msg import TFMessage
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.camera_settings import (
    DERIVED_ROWS,
    KITTI_CAMERA_HEIGHT,
    CameraModel,
    StereoSettings,
    stereo_settings,
)
from vehicle_common.frame_accounting import FrameCounter, LatestFrameWorker
from vehicle_common.frame_messages import bbox_to_xyxy, stamp_ns, write_transform
from vehicle_common.frame_trace import frame_tracer
from vehicle_common.image_conversion import ImageConversionError, image_to_rgb
from vehicle_common.image_transport import (
    ImageTransportParameters,
    as_message,
    subscribe_image,
)
from vehicle_common.node_parameters import (
    ParameterError,
    check_overrides,
    declare_config,
    param,
)
from vehicle_common.node_runtime import NodeHealth, apply_process_settings, run_node
from vehicle_common.stereo_camera import check_stereo_images

from vehicle_common import topics

from .conversions import build_point_cloud, detection_3d_message, disparity_message
from .disparity import (
    DisparityParams,
    RowBandError,
    block_matching_disparity,
    check_match_rows,
    coarse_disparity,
    compute_disparity,
    compute_disparity_in_boxes,
    match_band,
)
from .odometry_output import OdometryOutput, OdometryOutputParameters
from .plausibility import GroundEstimator, GroundHeightCheck, PlausibilityParams, check_boxes
from .ranging import (
    RangingParams,
    RangingSetup,
    disparity_bias_at,
    observation_angles_of,
    range_boxes,
)
from .region_matching import to_gray
from .reprojection import StereoGeometry, decimated_points
from .stamp_sync import ExactStampSync
from .visual_odometry import FrameToFrameOdometry

NODE_NAME = "stereo_depth"
#: the inputs of one frame, paired by stamp
FRAME_SLOTS = ("left", "right", "detections")
TOPIC_LEFT = topics.LEFT_IMAGE
TOPIC_RIGHT = topics.RIGHT_IMAGE
TOPIC_LEFT_INFO = topics.LEFT_INFO
TOPIC_RIGHT_INFO = topics.RIGHT_INFO
TOPIC_DETECTIONS_2D = topics.DETECTIONS_2D
TOPIC_DISPARITY = topics.DISPARITY
TOPIC_POINTS = topics.POINTS
TOPIC_DETECTIONS_3D = topics.DETECTIONS_3D

#: Parameter names that differ from the core dataclass field names.
RANGING_RENAMED = {"method": "ranging_method"}
#: Ranges of the core settings beyond what their validate() checks (type and finiteness are
#: checked for every parameter).
DISPARITY_RULES = {
    "min_disparity": {"low": 0},
    "p1_factor": {"low": 0},
    "p2_factor": {"low": 0},
    "pre_filter_cap": {"low": 1, "high": 63},
    "uniqueness_ratio": {"low": 0},
    "speckle_window_size": {"low": 0},
    "speckle_range": {"low": 0},
    "wls_lambda": {"low": 0},
    "wls_sigma": {"low": 0},
    "wls_lrc_thresh": {"low": 0},
    "wls_min_confidence": {"low": 0},
}
RANGING_RULES = {
    "sigma_d": {"low": 0, "low_open": True},
    "sigma_d_far": {"low": 0, "low_open": True},
    "far_disparity": {"low": 0},
    "sigma_pixel": {"low": 0},
    "depth_offset_std": {"low": 0},
    "min_valid_pixels": {"low": 0},
    "min_valid_fraction": {"low": 0.0, "high": 1.0},
    "core_fraction": {"low": 0.0, "high": 1.0, "low_open": True},
    "ground_margin": {"low": 0},
    "mode_bin": {"low": 0, "low_open": True},
    "min_mode_fraction": {"low": 0.0, "high": 1.0},
    "prior_height": {"low": 0, "low_open": True},
    "prior_log_sigma": {"low": 0},
    "correction_bin_spread": {"low": 0.0, "high": 1.0},
    "surface_blend": {"low": 0.0, "high": 1.0},
}
PLAUSIBILITY_RULES = {
    "max_ground_fraction": {"low": 0.0, "high": 1.0},
    "ground_max_depth": {"low": 0, "low_open": True},
    "ground_max_tilt": {"low": 0.0, "high": 45.0},
    "ground_min_inliers": {"low": 3},
    "ground_keep_frames": {"low": 0},
}


@dataclasses.dataclass
class StereoNodeParameters:
    """The node's own parameters (the core's are DisparityParams' and RangingParams' fields)."""

    publish_disparity: bool = True
    publish_points: bool = False
    points_decimation: int = param(4, low=1)
    points_max_depth: float = param(80.0, low=0, low_open=True)
    points_rgb: bool = False
    sync_cache_size: int = param(10, low=1)
    num_threads: int = param(2, low=1)  # OpenCV threads of the matcher (cv2.setNumThreads)
    frame_queue: int = param(1, low=1)  # newest complete frames kept waiting (1: latest frame)
    # where the ranging's disparity map is computed: "boxes" (the 2D boxes with their matching
    # context; the odometry and the road plane take a block-matching map of the band) or
    # "band" (the whole band for everything, as before issue #33)
    map_area: str = param("boxes", choices=("boxes", "band"))
    # the camera-dependent settings: 0 / [-1, -1] = derived from the CameraInfo pair at run
    # time (vehicle_common.camera_settings); a value given wins
    # [px] disparity range (>= 16, the DisparityParams field); 0: fx * baseline / 4.05 m
    num_disparities: int = param(0, low=0)
    # [top, bottom) rows to match; bottom <= top means all rows; [-1, -1]: derived (KITTI's
    # camera: below the detector's region of interest; another camera: all)
    match_rows: list = param([-1, -1], low=-1, length=2)
    # [m] camera height above the road (the RangingParams field); 0: KITTI's 1.65 m assumed
    # and checked against the fitted road plane
    ground_height: float = param(0.0, low=0.0)
    # stereo visual odometry between successive frames (camera_motion of the 3D arrays)
    visual_odometry: bool = True

    def validate(self) -> None:
        if 0 < self.num_disparities < 16:
            raise ValueError(
                f"num_disparities: {self.num_disparities} must be >= 16 (0: derived from the "
                "camera)"
            )
        if tuple(self.match_rows) != DERIVED_ROWS:
            check_match_rows(self.match_rows)  # against the image: match_band, at the first pair


def _stamp_text(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


@dataclasses.dataclass(frozen=True)
class _Ready:
    """A result already computed, read like a Future's."""

    value: object

    def result(self):
        return self.value


class _NoGeometry(ValueError):
    """No usable stereo geometry (no CameraInfo yet, or a bad calibration)."""


class StereoDepthNode(Node):
    """Thin ROS wrapper around compute_disparity / range_boxes."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        self.trace = frame_tracer(NODE_NAME)  # per-frame trace points (VEHICLE_TRACE_DIR)
        # num_disparities and ground_height are declared with the node's parameters (0:
        # derived from the camera), the other settings from the core's dataclasses
        self.disparity_params = declare_config(
            self, DisparityParams, skip=("row_band", "num_disparities"), rules=DISPARITY_RULES
        )
        ranging_params = declare_config(
            self,
            RangingParams,
            skip=("ground_height",),
            rename=RANGING_RENAMED,
            rules=RANGING_RULES,
        )
        p = declare_config(self, StereoNodeParameters)
        self.given = p  # the camera-dependent settings as given (0 / [-1, -1]: derived)
        ground_height = p.ground_height or KITTI_CAMERA_HEIGHT
        ranging_params = dataclasses.replace(ranging_params, ground_height=ground_height)
        # declare_config validated it (a bad value is a ParameterError naming the parameter)
        self.ranging = RangingSetup.from_params(ranging_params)
        self.ranging_params = self.ranging.params
        self.plausibility = declare_config(self, PlausibilityParams, rules=PLAUSIBILITY_RULES)
        self.ground = GroundEstimator(self.plausibility, ground_height)
        self.ground_check = GroundHeightCheck(
            ground_height, p.ground_height <= 0, self.plausibility.ground_height_range
        )
        self.implausible_detections = 0
        self._band_params: tuple | None = None  # ((height, settings), params)
        #: a parameter found not to fit the camera while running (node_runtime.run_node stops
        #: the node with its one-line error and exit code 2)
        self.fatal_error: ParameterError | None = None
        declare_config(self, ImageTransportParameters)  # read by subscribe_image below
        # its odometry's integration in odom: stereo/odometry, /tf, /tf_static (odometry_output.py)
        odom_params = declare_config(self, OdometryOutputParameters)
        check_overrides(self)  # every parameter is declared: refuse one the node has not
        self.publish_disparity = p.publish_disparity
        self.publish_points = p.publish_points
        self.points_decimation = p.points_decimation
        self.points_max_depth = p.points_max_depth
        self.points_rgb = p.points_rgb
        cv2.setNumThreads(p.num_threads)  # process-wide
        self.map_area = p.map_area
        self.odometry = FrameToFrameOdometry() if p.visual_odometry else None
        self.odometry_out = OdometryOutput(odom_params) if p.visual_odometry else None
        # a frame's odometry, then its road plane's map, run in this thread beside its map in
        # the boxes and its ranging; the check waits for the road map, the publishing of the
        # 3D array for the odometry (ARCHITECTURE.md, "A frame's path through the graph")
        self._helper = ThreadPoolExecutor(1, thread_name_prefix="stereo-helper")
        self._vehicle_boxes: list = []  # of the previous processed frame (the odometry's mask)
        self._bias_key: tuple | None = None  # (width, geometry) of the cached column bias
        self._bias: np.ndarray | None = None
        # a frame = its left image, right image and 2D detection array (one stamp; in order)
        self.frame_sync = ExactStampSync(FRAME_SLOTS, p.sync_cache_size, in_order=True)
        self.left_info = None
        self.right_info = None
        self.geometry: StereoGeometry | None = None  # from the latest CameraInfo pair
        #: the settings derived from it (vehicle_common.camera_settings)
        self.settings: StereoSettings | None = None
        self._geometry_error = "no CameraInfo received yet on both camera_info topics"
        self._calibration_key = None  # (left P, right P, sizes) the geometry was built from
        #: camera changes seen by the executor / handled by the worker (odometry, road plane)
        self._camera_generation = 0
        self._worker_generation = 0
        self.dropped_detection_arrays = 0  # whose images never arrived (lost or superseded)
        self.unranged_detections = 0
        self.frames_processed = 0
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

        # QoS (docs/ARCHITECTURE.md, "Topics"): RELIABLE (lockstep loses nothing), the newest
        # INPUT_DEPTH messages of each input: a burst the executor takes late is still seen,
        # and dropped and counted here before any work; older ones are never taken
        qos_in = QoSProfile(depth=max(topics.INPUT_DEPTH, p.frame_queue))
        self.pub_disparity = self.create_publisher(DisparityImage, TOPIC_DISPARITY, 5)
        self.pub_points = None
        if self.publish_points:
            self.pub_points = self.create_publisher(PointCloud2, TOPIC_POINTS, 5)
        self.pub_det3d = self.create_publisher(VehicleDetection3DArray, TOPIC_DETECTIONS_3D, 10)
        self.pub_odometry = self.pub_tf = self.pub_tf_static = None
        if self.odometry_out is not None:
            if odom_params.publish_odometry:
                self.pub_odometry = self.create_publisher(Odometry, topics.ODOMETRY, 10)
            if odom_params.publish_tf:  # tf2's broadcaster QoS: depth 100, volatile
                self.pub_tf = self.create_publisher(TFMessage, topics.TF, 100)
            if odom_params.publish_static_tf:  # tf2's static broadcaster: the last one kept
                latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
                self.pub_tf_static = self.create_publisher(TFMessage, topics.TF_STATIC, latched)
        # camera infos first: the executor runs ready callbacks in creation order, so a frame's
        # CameraInfo that arrives with its images is read before the frame is processed
        self.create_subscription(CameraInfo, TOPIC_LEFT_INFO, self._on_left_info, 1)
        self.create_subscription(CameraInfo, TOPIC_RIGHT_INFO, self._on_right_info, 1)
        # raw or compressed (parameter image_transport); as bytes, converted only for a frame
        # that is processed (a frame the detector skipped costs no image conversion)
        for slot, topic in (("left", TOPIC_LEFT), ("right", TOPIC_RIGHT)):
            on_image = functools.partial(self._on_input, slot)
            subscribe_image(self, topic, on_image, qos_in, serialized=True)
        self.create_subscription(
            VehicleDetection2DArray,
            TOPIC_DETECTIONS_2D,
            lambda m: self._on_input("detections", m),
            qos_in,
        )
        self.health = NodeHealth(self, self.frames, busy=lambda: self.worker.busy)

    def destroy_node(self):
        self.worker.stop()  # the frames in hand and waiting are finished first
        self._helper.shutdown(wait=True)
        super().destroy_node()

    def _disparity_params_for(self, height: int, settings: StereoSettings) -> DisparityParams:
        """The disparity settings of the camera (its disparity range) with the match band of
        images ``height`` rows tall. A band cut at the image's last row is warned about once; a
        band that leaves nothing to match stops the node (``fatal_error``: one line naming
        ``match_rows``, exit code 2)."""
        key = (height, settings)
        if self._band_params is None or self._band_params[0] != key:
            try:
                band, note = match_band(settings.match_rows, height, self.disparity_params)
            except RowBandError as exc:
                self.fatal_error = ParameterError(str(exc))
                raise
            if note:
                self.get_logger().warning(note)
            params = dataclasses.replace(
                self.disparity_params, num_disparities=settings.num_disparities, row_band=band
            )
            self._band_params = (key, params)
        return self._band_params[1]

    # ------------------------------------------------------------------ callbacks
    def _on_left_info(self, msg) -> None:
        self.left_info = msg
        self._update_geometry()

    def _on_right_info(self, msg) -> None:
        self.right_info = msg
        self._update_geometry()

    def _update_geometry(self) -> None:
        """Rebuild the stereo geometry and the settings derived from the camera when the
        calibration changes (a bad one is reported once per change; its frames are then
        skipped). A change after the first is reported with what it changed; the odometry and
        the road plane then start afresh (the worker resets them)."""
        if self.left_info is None or self.right_info is None:
            return
        key = tuple(
            (tuple(i.p), int(i.width), int(i.height)) for i in (self.left_info, self.right_info)
        )
        if key == self._calibration_key:
            return
        stamps = {stamp_ns(i.header) for i in (self.left_info, self.right_info)}
        if self.geometry is not None and len(stamps) == 2 and 0 not in stamps:
            return  # one side of a new pair: judged when the other side's arrives
        first = self._calibration_key is None
        self._calibration_key = key
        previous = self.settings
        try:
            camera = CameraModel.from_camera_info(self.left_info, self.right_info)
            geometry = StereoGeometry.from_camera_infos(self.left_info, self.right_info)
            g = self.given
            settings = stereo_settings(
                camera, g.num_disparities, tuple(g.match_rows), g.ground_height
            )
        except ValueError as exc:
            self.geometry = None
            self._geometry_error = f"{TOPIC_LEFT_INFO}/{TOPIC_RIGHT_INFO}: {exc}"
            self.get_logger().warning(f"{self._geometry_error}; frames skipped until it changes")
            return
        self.geometry, self.settings = geometry, settings
        self._publish_rig()
        if first or previous is None:
            self.get_logger().info(settings.text)
        else:
            self._camera_generation += 1
            self.get_logger().warning(f"camera_info changed: {settings.text}")

    def _publish_rig(self) -> None:
        """The rig's fixed transforms on /tf_static (when its frames or baseline changed)."""
        if self.pub_tf_static is None:
            return
        left, right = self.left_info.header, self.right_info.header
        msg = self.odometry_out.rig(
            stamp_ns(left), left.frame_id, right.frame_id, self.geometry.baseline
        )
        if msg is not None:
            self.pub_tf_static.publish(msg)

    def _publish_odometry(self, header, motion: CameraMotion | None) -> None:
        """The frame's integrated odometry (stereo/odometry) and odom -> child (/tf), before its
        3D array: a consumer of both finds the frame's transform when the array arrives."""
        if self.odometry_out is None:
            return
        odom, tf = self.odometry_out.frame(stamp_ns(header), header.frame_id, motion)
        if odom is not None and self.pub_odometry is not None:
            self.pub_odometry.publish(odom)
        if tf is not None and self.pub_tf is not None:
            self.pub_tf.publish(tf)

    def _on_input(self, slot: str, msg) -> None:
        """An image or a 2D detection array: into the frame's set; a complete set goes to the
        worker, and the sets it leaves behind (older, never to complete) are dropped."""
        stamp = stamp_ns(msg.header)
        self.trace(f"{slot}_received", stamp)
        if slot == "detections":
            self.frames.received()
        group = self.frame_sync.add(stamp, slot, msg)
        for ev in self.frame_sync.take_evicted():
            if "detections" not in ev.values:
                continue  # images of a frame the detector skipped (it counted it)
            self.frames.dropped()
            self.dropped_detection_arrays += 1
            self.get_logger().warning(
                f"{TOPIC_DETECTIONS_2D}: detection array at stamp {_stamp_text(ev.stamp)} "
                f"dropped: its {' and '.join(ev.missing(FRAME_SLOTS))} image never arrived "
                f"(lost, or superseded by a newer one); {self.dropped_detection_arrays} so far",
                throttle_duration_sec=5.0,
            )
        if group is not None:
            self.worker.submit((group["left"], group["right"], group["detections"]))

    def _work_failed(self, exc: Exception, item) -> None:
        self.get_logger().warning(f"stereo processing failed: {exc}")
        self._publish_empty(item[2])

    # ------------------------------------------------------------------ processing
    def _process_frame(self, item) -> None:
        """One complete frame: its disparity map where the ranging reads it, its odometry and
        road plane's map in the helper thread meanwhile, the ranging and check, then the 3D
        array."""
        left_msg, right_msg, det_msg = item
        stamp = stamp_ns(det_msg.header)
        self.trace("pair_start", stamp)
        dets = list(det_msg.detections)
        boxes = [bbox_to_xyxy(d.bbox) for d in dets]
        try:
            geometry, settings = self.geometry, self.settings
            if geometry is None or settings is None:
                raise _NoGeometry(self._geometry_error)
            if self._worker_generation != self._camera_generation:
                # another camera: the previous frame and road plane are not this camera's
                self._worker_generation = self._camera_generation
                self.ground.reset()
                if self.odometry is not None:
                    self.odometry.reset()
            left_msg, right_msg = as_message(left_msg), as_message(right_msg)
            left = image_to_rgb(left_msg)
            right = image_to_rgb(right_msg)
            # sizes and frame ids of the images and their camera_infos
            check_stereo_images(left_msg, right_msg, left, right, self.left_info, self.right_info)
            params = self._disparity_params_for(left.shape[0], settings)
        except (ImageConversionError, ValueError) as exc:
            self.frames_failed += 1
            # a bad calibration was reported when it arrived; a missing one is reported here
            log = self.get_logger().debug
            if not isinstance(exc, _NoGeometry) or self._calibration_key is None:
                log = self.get_logger().warning
            if self.fatal_error is not None:  # the node stops with that one line
                log = self.get_logger().debug
            log(f"{TOPIC_LEFT}/{TOPIC_RIGHT}: {exc}; frame skipped")
            if self.odometry is not None:
                self.odometry.reset()  # a lost frame breaks the odometry's chain
            self._publish_empty(det_msg)
            return
        gray, gray_right = to_gray(left), to_gray(right)
        if self.map_area == "band" or self._outputs_wanted():
            # the band's map for the ranging, the road plane and the odometry
            self.trace("disparity_start", stamp)
            disparity = compute_disparity(left, right, params)
            self.trace("disparity_end", stamp)
            odometry = self._start_odometry(stamp, gray, disparity, geometry)
            road = _Ready(disparity)
        else:
            # the odometry's map of the scene: block matching over the band; then, in the
            # helper thread, the odometry and the road plane's map (the map's algorithm at
            # half its resolution, when there are boxes to check) beside the map in the boxes
            # and the ranging
            self.trace("scene_start", stamp)
            scene = block_matching_disparity(gray, gray_right, params)
            self.trace("scene_end", stamp)
            odometry = self._start_odometry(stamp, gray, scene, geometry)
            road = self._helper.submit(self._road_map, stamp, left, right, params) if dets else None
            self.trace("disparity_start", stamp)
            disparity = compute_disparity_in_boxes(left, right, boxes, params)
            self.trace("disparity_end", stamp)
        self.trace("pair_end", stamp)
        self.frames_processed += 1
        images = (gray, gray_right) if self.ranging_params.refine != "none" else None
        self._publish_detections(det_msg, dets, boxes, disparity, road, geometry, images, odometry)
        if isinstance(road, _Ready):
            self._publish_frame_outputs(disparity, geometry, params, det_msg.header, left)

    def _road_map(self, stamp: int, left, right, params) -> np.ndarray:
        """The helper thread's map for the road plane (traced as road_start / road_end)."""
        self.trace("road_start", stamp)
        try:
            return coarse_disparity(left, right, params)
        finally:
            self.trace("road_end", stamp)

    def _outputs_wanted(self) -> bool:
        """Whether someone subscribes to the disparity image or the point cloud (they need the
        whole band's map)."""
        if self.publish_disparity and self.pub_disparity.get_subscription_count() > 0:
            return True
        return self.pub_points is not None and self.pub_points.get_subscription_count() > 0

    def _publish_frame_outputs(self, disparity, geometry, params, header, left) -> None:
        """The frame's disparity image and point cloud (when enabled and subscribed to: nothing
        is built for no one)."""
        if self.publish_disparity and self.pub_disparity.get_subscription_count() > 0:
            self.pub_disparity.publish(disparity_message(disparity, geometry, params, header))
        if self.pub_points is not None and self.pub_points.get_subscription_count() > 0:
            pts, rgb = decimated_points(
                disparity,
                geometry,
                self.points_decimation,
                left if self.points_rgb else None,
                self.points_max_depth,
            )
            self.pub_points.publish(build_point_cloud(pts, rgb, header))

    def _publish_empty(self, det_msg) -> None:
        """An empty 3D array for a detection array whose frame cannot be used."""
        out = VehicleDetection3DArray()
        out.header = det_msg.header
        self._publish_odometry(out.header, None)  # extrapolated: no frame, no motion
        self.pub_det3d.publish(out)
        self.frames.published()

    def _publish_detections(
        self, det_msg, dets, boxes, disparity, road, geometry, images, odometry
    ) -> None:
        """Range and check the frame's boxes (``road.result()``: the map the road plane is
        fitted to, None without boxes), wait for its odometry, publish."""
        stamp = stamp_ns(det_msg.header)
        self.trace("ranging_start", stamp)
        out = VehicleDetection3DArray()
        out.header = det_msg.header
        results, checks = [None] * len(dets), [None] * len(dets)
        if dets:
            bins = [int(d.orientation_bin) for d in dets]
            # the detector's continuous observation angle where it gives one (variance >= 0)
            alphas = observation_angles_of(
                [getattr(d, "observation_angle", float("nan")) for d in dets],
                [getattr(d, "observation_angle_variance", -1.0) for d in dets],
            )
            results = range_boxes(disparity, boxes, geometry, self.ranging, bins, images, alphas)
            checks = self._check(disparity, road.result(), geometry, boxes, results)
        self.trace("ranging_end", stamp)
        motion = self._camera_motion(odometry)
        if motion is not None:
            out.camera_motion_dt = motion.dt
            write_transform(motion.rotation, motion.translation, out.camera_motion)
        action = self.plausibility.plausibility_action
        for d, r, c in zip(dets, results, checks, strict=True):
            if r is None:
                self.unranged_detections += 1
                self.get_logger().debug(
                    f"detection {d.id!r}: no valid depth in its box "
                    f"({self.unranged_detections} unranged so far)"
                )
                continue
            if action == "reject" and not c.plausible:
                self.implausible_detections += 1
                self.get_logger().debug(
                    f"detection {d.id!r}: not a vehicle's size or ground contact (height "
                    f"{c.measures.height:.2f} m, bottom {c.measures.bottom_height:+.2f} m); "
                    f"dropped ({self.implausible_detections} so far)"
                )
                continue
            score = d.score * c.plausibility if action == "score" else None
            out.detections.append(detection_3d_message(d, r, c, score))
        self._publish_odometry(out.header, motion)
        self.pub_det3d.publish(out)
        self.trace("detections_3d_published", stamp)
        self.frames.published()
        self._vehicle_boxes = boxes
        if self.odometry is not None:
            # the next frame's odometry tracks this one's corners: found now, in idle time
            self._helper.submit(self.odometry.prepare(boxes))

    def _column_bias(self, width: int, geometry: StereoGeometry) -> np.ndarray:
        """The ranging's disparity bias model per image column [px] (read-only); it depends
        only on the calibration and the parameters, so it is computed once per geometry."""
        key = (width, geometry)
        if self._bias_key != key:
            bias = np.asarray(
                disparity_bias_at(np.arange(width), geometry, self.ranging_params), dtype=float
            )
            bias.setflags(write=False)
            self._bias_key, self._bias = key, bias
        return self._bias

    def _check(self, disparity, road, geo: StereoGeometry, boxes, results) -> list:
        """Plausibility of the ranged boxes (:mod:`.plausibility`, on the ranging's map)
        against this frame's road plane (fitted to the ``road`` map with the ranging's bias
        model subtracted)."""
        bias = self._column_bias(disparity.shape[1], geo)
        plane = self.ground.update(road, geo, bias)
        report = self.ground_check.add(plane)
        if report is not None:
            level, line = report
            (self.get_logger().warning if level == "warning" else self.get_logger().info)(line)
        fb = geo.fx * geo.baseline
        depths = [fb / r.disparity if r is not None else None for r in results]
        stds = [r.disparity_std if r is not None else None for r in results]
        return check_boxes(disparity, boxes, depths, geo, plane, self.plausibility, stds)

    def _start_odometry(self, stamp: int, gray: np.ndarray, scene: np.ndarray, geometry):
        """Start the visual odometry of a frame (the camera's motion since the previous
        processed frame: the span the tracker predicts over, however long) in its thread; the
        frame, with its scene map, becomes the next reference at once. None without odometry."""
        if self.odometry is None:
            return None
        job = self.odometry.begin(stamp, gray, scene)
        bias = self._column_bias(gray.shape[1], geometry)
        return self._helper.submit(
            self._estimate_motion, stamp, job, geometry, list(self._vehicle_boxes), bias
        )

    def _estimate_motion(self, stamp: int, job, *args) -> CameraMotion | None:
        """The helper thread's odometry (traced as odometry_start / odometry_end)."""
        self.trace("odometry_start", stamp)
        try:
            return job(*args)
        finally:
            self.trace("odometry_end", stamp)

    def _camera_motion(self, odometry) -> CameraMotion | None:
        """The frame's camera motion, once its odometry is done (None: no odometry, or it
        failed: reported)."""
        if odometry is None:
            return None
        try:
            return odometry.result()
        except (ValueError, cv2.error) as exc:
            self.get_logger().warning(f"visual odometry failed: {exc}")
            return None


def main(args=None) -> int:
    """Console script ``stereo_depth``; exit code 2 for a bad parameter."""
    return run_node(StereoDepthNode, NODE_NAME, args, on_stop=lambda node: [node.worker.stop])


if __name__ == "__main__":
    sys.exit(main())
