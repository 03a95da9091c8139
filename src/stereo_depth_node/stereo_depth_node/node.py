"""ROS 2 node ``stereo_depth``: disparity, optional point cloud, and 3D ranging of 2D detections.

Subscribes to the rectified stereo pair, its CameraInfos and ``/vehicles/detections_2d``; publishes
``/stereo/disparity`` (stereo_msgs/DisparityImage, invalid pixels -1.0), ``/stereo/points``
(sensor_msgs/PointCloud2, off by default) and ``/vehicles/detections_3d``. Left and right images
are paired, and detection arrays matched to their stereo frame, by exact header stamp through
bounded caches (:mod:`.stamp_sync`); every detection array gets exactly one 3D array (empty when
its stereo frame is lost or failed). All computation is in the pure core modules.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
from kitti_player_node.frame_accounting import FrameCounter, LatestFrameWorker
from kitti_player_node.frame_messages import bbox_to_xyxy, stamp_ns
from kitti_player_node.image_conversion import (
    ImageConversionError,
    byte_array,
    image_to_rgb,
    numpy_to_image,
)

from .disparity import DisparityParams, compute_disparity, disparity_range
from .ranging import RangingParams, RangingSetup, range_boxes
from .reprojection import StereoGeometry, decimated_points
from .stamp_sync import ExactStampSync

NODE_NAME = "stereo_depth"
TOPIC_LEFT = "/stereo/left/image_rect"
TOPIC_RIGHT = "/stereo/right/image_rect"
TOPIC_LEFT_INFO = "/stereo/left/camera_info"
TOPIC_RIGHT_INFO = "/stereo/right/camera_info"
TOPIC_DETECTIONS_2D = "/vehicles/detections_2d"
TOPIC_DISPARITY = "/stereo/disparity"
TOPIC_POINTS = "/stereo/points"
TOPIC_DETECTIONS_3D = "/vehicles/detections_3d"

# Parameter names that differ from the core dataclass field names.
_RENAMED = {"method": "ranging_method"}
_NODE_PARAMS = {
    "publish_disparity": True,
    "publish_points": False,
    "points_decimation": 4,
    "points_max_depth": 80.0,
    "points_rgb": False,
    "sync_cache_size": 10,
    "num_threads": 2,  # OpenCV threads of the matcher (cv2.setNumThreads, process-wide)
    "frame_queue": 1,  # newest stereo pairs kept waiting (1: latest-frame policy)
    "match_rows": [0, 0],  # [top, bottom) rows to match; bottom <= top means all rows
}


def _param_default(value):
    if isinstance(value, tuple):
        return [float(v) for v in value]
    return value


def _core_fields(cls):
    for f in dataclasses.fields(cls):
        if f.name == "row_band":
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        yield f.name, _RENAMED.get(f.name, f.name), default


def _stamp_text(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


class _NoGeometry(ValueError):
    """No usable stereo geometry (no CameraInfo yet, or a bad calibration)."""


@dataclasses.dataclass
class _Frame:
    """A processed stereo frame waiting for its detection array (None fields: it failed)."""

    header: object
    disparity: np.ndarray | None
    geometry: StereoGeometry | None
    skipped: bool = False  # superseded by a newer pair (latest-frame policy): no 3D array


def build_point_cloud(points: np.ndarray, colours: np.ndarray | None, header):
    """sensor_msgs/PointCloud2 of (N, 3) float32 points (+ packed rgb float32 when given)."""
    from sensor_msgs.msg import PointCloud2, PointField

    fields = [
        PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
        for i, n in enumerate("xyz")
    ]
    cols = [points.astype(np.float32)]
    if colours is not None:
        fields.append(PointField(name="rgb", offset=12, datatype=PointField.FLOAT32, count=1))
        c = colours.astype(np.uint32)
        packed = ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).astype(np.uint32)
        cols.append(packed.view(np.float32)[:, None])
    data = np.ascontiguousarray(np.hstack(cols), dtype=np.float32)
    msg = PointCloud2()
    msg.header = header
    msg.height, msg.width = 1, int(data.shape[0])
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = 4 * data.shape[1]
    msg.row_step = msg.point_step * msg.width
    msg.is_dense = True
    msg.data = byte_array(data)
    return msg


def _make_node_class():
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import CameraInfo, Image
    from stereo_msgs.msg import DisparityImage
    from stereo_vehicle_msgs.msg import (
        VehicleDetection2DArray,
        VehicleDetection3D,
        VehicleDetection3DArray,
    )

    class StereoDepthNode(Node):
        """Thin ROS wrapper around compute_disparity / range_boxes."""

        def __init__(self, **kwargs):
            super().__init__(NODE_NAME, **kwargs)
            self.disparity_params = self._read_disparity_params()
            self.ranging = self._read_ranging_setup()  # validated once, with the bin offsets
            self.ranging_params = self.ranging.params
            self._band_params: tuple[int, DisparityParams] | None = None  # (height, params)
            p = {k: self._declare(k, v) for k, v in _NODE_PARAMS.items()}
            self.publish_disparity = bool(p["publish_disparity"])
            self.publish_points = bool(p["publish_points"])
            self.points_decimation = int(p["points_decimation"])
            self.points_max_depth = float(p["points_max_depth"])
            self.points_rgb = bool(p["points_rgb"])
            import cv2

            cv2.setNumThreads(max(1, int(p["num_threads"])))
            if len(p["match_rows"]) != 2:
                raise ValueError(f"parameter match_rows: {p['match_rows']} needs [top, bottom]")
            self.match_rows = (int(p["match_rows"][0]), int(p["match_rows"][1]))
            cache = max(1, int(p["sync_cache_size"]))
            self.pair_sync = ExactStampSync(("left", "right"), cache, in_order=True)
            self.frame_sync = ExactStampSync(("frame", "detections"), cache, in_order=True)
            self.left_info = None
            self.right_info = None
            self.geometry: StereoGeometry | None = None  # from the latest CameraInfo pair
            self._geometry_error = "no CameraInfo received yet on both camera_info topics"
            self._calibration_key = None  # (left P, right P) the geometry was built from
            self.dropped_detection_arrays = 0
            self.unranged_detections = 0
            self.frames_processed = 0
            self.frames_failed = 0
            # frames = detection arrays: in, 3D arrays out, dropped with their skipped pair.
            # Everything after stereo pairing runs in order in one worker thread; a pair still
            # waiting when a newer one is complete is skipped (latest-frame policy).
            self.frames = FrameCounter()
            self.worker = LatestFrameWorker(
                self._work,
                name="stereo",
                on_error=self._work_failed,
                skip=self._skip_pair,
                max_waiting=max(1, int(p["frame_queue"])),
            )

            self.pub_disparity = self.create_publisher(DisparityImage, TOPIC_DISPARITY, 5)
            self.pub_points = None
            if self.publish_points:
                from sensor_msgs.msg import PointCloud2

                self.pub_points = self.create_publisher(PointCloud2, TOPIC_POINTS, 5)
            self.pub_det3d = self.create_publisher(VehicleDetection3DArray, TOPIC_DETECTIONS_3D, 10)
            self._msg_types = (DisparityImage, VehicleDetection3D, VehicleDetection3DArray)
            self.create_subscription(Image, TOPIC_LEFT, lambda m: self._on_image("left", m), 5)
            self.create_subscription(Image, TOPIC_RIGHT, lambda m: self._on_image("right", m), 5)
            self.create_subscription(CameraInfo, TOPIC_LEFT_INFO, self._on_left_info, 5)
            self.create_subscription(CameraInfo, TOPIC_RIGHT_INFO, self._on_right_info, 5)
            self.create_subscription(
                VehicleDetection2DArray,
                TOPIC_DETECTIONS_2D,
                self._on_detections,
                QoSProfile(depth=10),
            )
            from kitti_player_node.node_runtime import NodeHealth

            self.health = NodeHealth(self, self.frames, busy=lambda: self.worker.busy)

        def destroy_node(self):
            self.worker.stop()  # the frames in hand and waiting are finished first
            super().destroy_node()

        # ------------------------------------------------------------------ parameters
        def _declare(self, name: str, default):
            """Declare with dynamic typing (a YAML ``8`` for a double is accepted) and coerce the
            value to the default's type; raises ValueError when it cannot be."""
            desc = ParameterDescriptor(dynamic_typing=True)
            value = self.declare_parameter(name, _param_default(default), desc).value
            try:
                if isinstance(default, bool):
                    if not isinstance(value, bool):
                        raise TypeError
                    return value
                if isinstance(default, tuple | list):
                    kind = float if isinstance(default, tuple) else type(default[0])
                    out = [kind(v) for v in value]
                    return tuple(out) if isinstance(default, tuple) else out
                return type(default)(value)
            except (TypeError, ValueError):
                raise ValueError(
                    f"parameter {name}: {value!r} is not a {type(default).__name__}"
                ) from None

        def _declare_fields(self, cls) -> dict:
            return {field: self._declare(name, d) for field, name, d in _core_fields(cls)}

        def _read_disparity_params(self) -> DisparityParams:
            params = DisparityParams(**self._declare_fields(DisparityParams))
            params.validate()
            return params

        def _read_ranging_setup(self) -> RangingSetup:
            return RangingSetup.from_params(RangingParams(**self._declare_fields(RangingParams)))

        def _match_band(self, height: int):
            top, bottom = self.match_rows
            if bottom <= top:
                return None
            return (max(0, top), min(height, bottom))

        def _disparity_params_for(self, height: int) -> DisparityParams:
            """The disparity settings with the match band of images ``height`` rows tall."""
            if self._band_params is None or self._band_params[0] != height:
                params = dataclasses.replace(
                    self.disparity_params, row_band=self._match_band(height)
                )
                self._band_params = (height, params)
            return self._band_params[1]

        # ------------------------------------------------------------------ callbacks
        def _on_left_info(self, msg) -> None:
            self.left_info = msg
            self._update_geometry()

        def _on_right_info(self, msg) -> None:
            self.right_info = msg
            self._update_geometry()

        def _update_geometry(self) -> None:
            """Rebuild the stereo geometry when the calibration changes (a bad one is reported
            once per change; its frames are then skipped)."""
            if self.left_info is None or self.right_info is None:
                return
            key = (tuple(self.left_info.p), tuple(self.right_info.p))
            if key == self._calibration_key:
                return
            self._calibration_key = key
            try:
                self.geometry = StereoGeometry.from_camera_infos(self.left_info, self.right_info)
            except ValueError as exc:
                self.geometry = None
                self._geometry_error = f"{TOPIC_LEFT_INFO}/{TOPIC_RIGHT_INFO}: {exc}"
                self.get_logger().warning(
                    f"{self._geometry_error}; frames skipped until it changes"
                )

        def _on_image(self, side: str, msg) -> None:
            group = self.pair_sync.add(stamp_ns(msg.header), side, msg)
            for ev in self.pair_sync.take_evicted():
                self.get_logger().warning(
                    f"stereo pair at stamp {_stamp_text(ev.stamp)} incomplete (missing "
                    f"{', '.join(ev.missing(self.pair_sync.slots))}); dropped"
                )
                # its detection array (waiting or still to come) gets an empty 3D array
                header = next(iter(ev.values.values())).header
                self.worker.submit(("frame", ev.stamp, _Frame(header, None, None)), frame=False)
            if group is not None:
                self.worker.submit(("pair", group["left"], group["right"]))

        def _on_detections(self, msg) -> None:
            self.frames.received()
            self.worker.submit(("detections", stamp_ns(msg.header), msg), frame=False)

        def _work(self, item) -> None:
            kind, a, b = item
            if kind == "pair":
                self._process_pair(a, b)
            else:
                self._add_to_frame_sync(a, kind, b)

        def _skip_pair(self, item) -> None:
            left = item[1]
            self._add_to_frame_sync(
                stamp_ns(left.header), "frame", _Frame(left.header, None, None, True)
            )

        def _work_failed(self, exc: Exception, item) -> None:
            self.get_logger().warning(f"stereo processing failed: {exc}")
            if item[0] == "pair":
                self._add_to_frame_sync(
                    stamp_ns(item[1].header), "frame", _Frame(item[1].header, None, None)
                )

        def _add_to_frame_sync(self, key, slot, value) -> None:
            group = self.frame_sync.add(key, slot, value)
            for ev in self.frame_sync.take_evicted():
                if "detections" in ev.values:
                    self.dropped_detection_arrays += 1
                    self.get_logger().warning(
                        f"{TOPIC_DETECTIONS_2D}: detection array at stamp {_stamp_text(ev.stamp)} "
                        "not ranged, its stereo frame never arrived; empty 3D array published "
                        f"({self.dropped_detection_arrays} so far)"
                    )
                    self._publish_empty(ev.values["detections"])
            if group is not None:
                self._publish_detections(group["frame"], group["detections"])

        # ------------------------------------------------------------------ processing
        def _process_pair(self, left_msg, right_msg) -> None:
            frame = _Frame(left_msg.header, None, None)
            try:
                if self.geometry is None:
                    raise _NoGeometry(self._geometry_error)
                frame.geometry = self.geometry
                left = image_to_rgb(left_msg)
                right = image_to_rgb(right_msg)
                if left.shape != right.shape:
                    raise ImageConversionError(
                        f"left {left.shape[1]}x{left.shape[0]} and right "
                        f"{right.shape[1]}x{right.shape[0]} sizes differ"
                    )
                params = self._disparity_params_for(left.shape[0])
                frame.disparity = compute_disparity(left, right, params)
            except (ImageConversionError, ValueError) as exc:
                self.frames_failed += 1
                # a bad calibration was reported when it arrived; a missing one is reported here
                log = self.get_logger().debug
                if not isinstance(exc, _NoGeometry) or self._calibration_key is None:
                    log = self.get_logger().warning
                log(f"{TOPIC_LEFT}/{TOPIC_RIGHT}: {exc}; frame skipped")
                frame.disparity = None
            if frame.disparity is not None:
                self.frames_processed += 1
                if self.publish_disparity:
                    self.pub_disparity.publish(self._disparity_msg(frame))
                if self.pub_points is not None:
                    pts, rgb = decimated_points(
                        frame.disparity,
                        frame.geometry,
                        self.points_decimation,
                        left if self.points_rgb else None,
                        self.points_max_depth,
                    )
                    self.pub_points.publish(build_point_cloud(pts, rgb, left_msg.header))
            self._add_to_frame_sync(stamp_ns(left_msg.header), "frame", frame)

        def _disparity_msg(self, frame: _Frame):
            DisparityImage = self._msg_types[0]
            msg = DisparityImage()
            msg.header = frame.header
            msg.image = numpy_to_image(frame.disparity, "32FC1", frame.header)
            msg.f = float(frame.geometry.fx)
            msg.t = float(frame.geometry.baseline)
            lo, hi = disparity_range(self.disparity_params)
            msg.min_disparity, msg.max_disparity = float(lo), float(hi)
            p = self.disparity_params
            msg.delta_d = 1.0 / 16.0 if p.use_wls else p.downscale / 16.0
            valid = frame.disparity > 0
            if valid.any():
                rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
                msg.valid_window.x_offset, msg.valid_window.y_offset = int(cols[0]), int(rows[0])
                msg.valid_window.width = int(cols[-1] - cols[0] + 1)
                msg.valid_window.height = int(rows[-1] - rows[0] + 1)
            return msg

        def _publish_empty(self, det_msg) -> None:
            """An empty 3D array for a detection array that cannot be ranged."""
            out = self._msg_types[2]()
            out.header = det_msg.header
            self.pub_det3d.publish(out)
            self.frames.published()

        def _publish_detections(self, frame: _Frame, det_msg) -> None:
            if frame.skipped:
                self.frames.dropped()
                return
            _, VehicleDetection3D, VehicleDetection3DArray = self._msg_types
            out = VehicleDetection3DArray()
            out.header = frame.header if frame.disparity is not None else det_msg.header
            dets = list(det_msg.detections)
            if frame.disparity is not None and dets:
                boxes = [bbox_to_xyxy(d.bbox) for d in dets]
                bins = [int(d.orientation_bin) for d in dets]
                results = range_boxes(frame.disparity, boxes, frame.geometry, self.ranging, bins)
            else:
                results = [None] * len(dets)
            for d, r in zip(dets, results, strict=True):
                if r is None:
                    self.unranged_detections += 1
                    self.get_logger().debug(
                        f"detection {d.id!r}: no valid depth in its box "
                        f"({self.unranged_detections} unranged so far)"
                    )
                    continue
                m = VehicleDetection3D()
                m.id, m.class_id, m.score = d.id, d.class_id, float(d.score)
                m.position.x, m.position.y, m.position.z = (float(v) for v in r.position)
                m.position_covariance = [float(v) for v in r.covariance.ravel()]
                m.bbox = d.bbox
                m.orientation_bin = d.orientation_bin
                m.orientation_probs = [float(v) for v in d.orientation_probs]
                m.disparity = float(r.disparity)
                m.valid_pixel_fraction = float(r.valid_pixel_fraction)
                out.detections.append(m)
            self.pub_det3d.publish(out)
            self.frames.published()

    return StereoDepthNode


def create_node(**kwargs):
    """A StereoDepthNode (rclpy must be initialised; kwargs go to rclpy.node.Node)."""
    return _make_node_class()(**kwargs)


def main(args=None) -> int:
    """Console script ``stereo_depth``."""
    import rclpy
    from kitti_player_node.node_runtime import StopRequest, spin_until_stopped
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopRequest.install()
    try:
        node = create_node()
    except ValueError as exc:
        print(f"error: parameters: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except KeyboardInterrupt:  # stopped during start-up
        rclpy.try_shutdown()
        return 0
    try:
        spin_until_stopped(node, stop, node.health, on_stop=[node.worker.stop])
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
