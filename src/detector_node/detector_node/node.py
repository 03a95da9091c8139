"""``vehicle_detector`` node: left image -> 2D vehicle detections.

Backends: ``cnn`` (default; the YOLOv2-style network, the shipped checkpoint unless
``checkpoint`` is set) and ``oracle`` (ablations only: ground-truth boxes from
/kitti/ground_truth, matched to the image by exact stamp, with optional noise and drops).
Exactly one VehicleDetection2DArray per left image, with the image's header; the same boxes as
vision_msgs/Detection2DArray on ``vehicles/vision/detections_2d`` (built while someone
subscribes, after the project's array).
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from stereo_vehicle_msgs.msg import (
    KittiFrameLabels,
    VehicleDetection2DArray,
    VehicleDetection3DArray,
)
from vehicle_common.camera_settings import CameraModel
from vehicle_common.frame_accounting import FrameCounter, LatestFrameWorker
from vehicle_common.frame_messages import kitti_objects_from_message, stamp_ns
from vehicle_common.frame_trace import frame_tracer
from vehicle_common.image_conversion import ImageConversionError, image_size, image_to_rgb
from vehicle_common.image_transport import (
    ImageTransportParameters,
    as_message,
    subscribe_camera,
    subscribe_image,
)
from vehicle_common.input_usage import InputUsage
from vehicle_common.node_parameters import (
    check_overrides,
    declare_config,
)
from vehicle_common.node_runtime import NodeHealth, apply_process_settings, run_node
from vision_msgs.msg import Detection2DArray

from vehicle_common import topics

from .admission import DOWNSTREAM_TOPIC, CameraWait, DownstreamAdmission, apply_framing
from .conversions import detections_message, vision_detections_message
from .parameters import DetectorParameters

NODE_NAME = "vehicle_detector"


class VehicleDetectorNode(Node):
    """Thin ROS wrapper around :class:`CnnDetector` / :class:`OracleDetector`."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        self.trace = frame_tracer(NODE_NAME)  # per-frame trace points (VEHICLE_TRACE_DIR)
        self.params = p = declare_config(self, DetectorParameters)
        declare_config(self, ImageTransportParameters)  # read by subscribe_image below
        self.usage = InputUsage()  # frames used, and why not the others (on /diagnostics)
        check_overrides(self)  # every parameter is declared: refuse one the node has not
        self.backend = p.backend
        self.frames = FrameCounter()  # images in, detection arrays out, images skipped
        self.worker: LatestFrameWorker | None = None
        self.flow: DownstreamAdmission | None = None  # back-pressure (the CNN, a live camera)
        self.pub = self.create_publisher(VehicleDetection2DArray, topics.DETECTIONS_2D, 10)
        self.vision_pub = self.create_publisher(Detection2DArray, topics.VISION_DETECTIONS_2D, 10)
        if self.backend == "cnn":
            from .loading import load_node_detector

            # each frame the CNN starts, announced (its image's header) before its array: the
            # stereo node begins the frame's work that needs no boxes meanwhile
            self.started_pub = self.create_publisher(Header, topics.DETECTIONS_2D_STARTED, 5)

            self.cnn, info, warning = load_node_detector(p)
            c = self.cnn.config
            self.get_logger().info(info)
            if warning is not None:
                self.get_logger().warning(warning)
            # the camera-dependent framing (vehicle_common.camera_settings): derived from the
            # left CameraInfo unless every part of it is given
            self.cam = CameraWait(not (p.input_width and p.input_height and p.roi_top >= 0))
            self._hold_timer = None
            # the first inference's set-up cost is paid here, before the graph is ready (at
            # the checkpoint's framing, KITTI's camera; another camera's is loaded from the
            # cache when its CameraInfo arrives)
            self.cnn.detect(np.zeros((c.input_height, c.input_width, 3), np.uint8))
            # latest-frame policy: the newest image is detected, an image still waiting when a
            # newer one arrives is skipped and counted (never a growing queue); with
            # back-pressure an image also waits while the stereo node has no room for it
            if p.downstream_window > 0:
                self.flow = DownstreamAdmission(
                    max(p.downstream_window, p.frame_queue),
                    p.downstream_timeout,
                    lambda: self.count_publishers(DOWNSTREAM_TOPIC),
                    lambda line: self.get_logger().warning(line, throttle_duration_sec=5.0),
                    p.next_frame_wait,
                    self._cnn_seconds if p.downstream_lead else None,
                )
            self.worker = LatestFrameWorker(
                self._work,
                self.frames,
                "detector",
                self._failed,
                max_waiting=p.frame_queue,
                admit=self.flow.admit if self.flow is not None else None,
            )
            if self.flow is not None:
                # a 3D array: the frames detected up to its stamp are done downstream
                done = lambda m: self.flow.finish(m, self.worker.wake)  # noqa: E731
                self.create_subscription(VehicleDetection3DArray, DOWNSTREAM_TOPIC, done, 10)
            if not self.cam.derive:
                self.worker.submit(None, frame=False)  # the framing of the parameters, logged
            subscribe_camera(
                self, CameraInfo, topics.LEFT_INFO, self._on_camera_info, 5, self.usage.note
            )
        elif self.backend == "oracle":
            from .oracle import OracleDetector, StampPairing

            self.oracle = OracleDetector.from_parameters(p)
            self.pairing = StampPairing(max_pending=p.oracle_max_pending)
            self.create_subscription(KittiFrameLabels, topics.GROUND_TRUTH, self._on_labels, 10)
            self.get_logger().warning(
                "ORACLE backend: publishing ground-truth boxes as detections (ablation only)"
            )
        # raw or compressed; BEST_EFFORT (any camera) or RELIABLE (camera_reliability), the
        # newest INPUT_DEPTH images (docs/ARCHITECTURE.md, "Topics"): a burst taken late is
        # seen and counted, only the newest is detected; the CNN's images as bytes, converted
        # only when detected (not the skipped ones)
        depth, cnn = max(topics.INPUT_DEPTH, p.frame_queue), self.backend == "cnn"
        subscribe_image(
            self, topics.LEFT_IMAGE, self._on_image, depth, self.usage.note, serialized=cnn
        )
        self.health = NodeHealth(
            self,
            self.frames,
            busy=lambda: bool(self.worker and self.worker.busy),
            usage=self.usage,
        )

    def destroy_node(self):
        if self.worker is not None:
            self.worker.stop()  # the image in hand and the one waiting are finished first
        super().destroy_node()

    def _on_image(self, msg: Image) -> None:
        self.trace("image_received", stamp_ns(msg.header))
        self.frames.received()
        if self.flow is not None:
            self.flow.arrived()  # the camera's cadence
        if self.backend == "oracle":
            for image, labels in self.pairing.add_image(stamp_ns(msg.header), msg):
                self._publish_oracle(image, labels)
            return
        with self.cam.lock:
            if self.cam.derive and self.cam.camera is None and self.cam.error is None:
                # no CameraInfo yet: the image waits for the first one (bounded)
                if self.cam.held is not None:
                    self.frames.dropped()  # superseded while waiting, as the worker would
                    self._publish(detections_message(self.cam.held.header, []))
                self.cam.held = msg
                if self._hold_timer is None:
                    self._hold_timer = self.create_timer(
                        max(self.params.camera_info_wait, 1e-3), self._camera_info_late
                    )
                return
        self.worker.submit(msg)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        """A left CameraInfo: the framing is derived again when the camera's size or fx
        changed (applied by the worker, in order with the images)."""
        try:
            camera = CameraModel.from_camera_info(msg)
        except ValueError as exc:
            if self.cam.bad(exc):
                self.get_logger().warning(f"{topics.LEFT_INFO}: {exc}; framing unchanged")
            self._release_held()
            return
        changed, old = self.cam.changed(camera)
        if not changed:
            return
        if self.cam.derive:
            self.worker.submit((camera, old), frame=False)
        self._release_held()

    def _camera_info_late(self) -> None:
        """No CameraInfo came within ``camera_info_wait``: the waiting image is detected with
        the checkpoint's framing (reported once)."""
        self.destroy_timer(self._hold_timer)
        with self.cam.lock:
            if self.cam.camera is None and self.cam.error is None:
                self.cam.error = "none yet"
                self.get_logger().warning(
                    f"no CameraInfo on {topics.LEFT_INFO} within "
                    f"{self.params.camera_info_wait:g} s: "
                    "detecting with the checkpoint's framing until one arrives"
                )
                self.worker.submit(None, frame=False)
        self._release_held()

    def _release_held(self) -> None:
        held = self.cam.take_held()
        if held is not None:
            self.worker.submit(held)

    def _work(self, item) -> None:
        """The worker's items: an image, or a camera to frame the images for (None: the
        parameters' framing or the checkpoint's: :func:`.admission.apply_framing`, one line)."""
        if item is not None and not isinstance(item, tuple):
            self._detect(item)
            return
        level, line = apply_framing(self.cnn, self.params, *(item or (None, None)))
        if level == "info":
            self.get_logger().info(line)
        else:
            self.get_logger().warning(line)

    def _cnn_seconds(self) -> float | None:
        """[s] the CNN worker's median wall time per frame (None before the first): the lead
        of ``downstream_lead``."""
        t = self.frames.processing_ms()
        return None if t is None else t[0] / 1e3

    def _failed(self, exc: Exception, msg: Image) -> None:
        self.get_logger().warning(f"{topics.LEFT_IMAGE}: detection failed: {exc}; no detections")
        self._publish(detections_message(msg.header, []))

    def _publish(self, out: VehicleDetection2DArray) -> None:
        self.pub.publish(out)
        self.frames.published()
        if self.vision_pub.get_subscription_count() > 0:
            self.vision_pub.publish(vision_detections_message(out))

    def _detect(self, msg: Image) -> None:
        stamp = stamp_ns(msg.header)
        self.trace("detect_start", stamp)
        self.started_pub.publish(msg.header)
        try:
            rgb = image_to_rgb(as_message(msg))
        except ImageConversionError as exc:
            self.usage.skipped(f"{topics.LEFT_IMAGE}: {exc}")
            self.get_logger().warning(f"{topics.LEFT_IMAGE}: {exc}; publishing no detections")
            self._publish(detections_message(msg.header, []))
            return
        self.usage.used()
        detections = self.cnn.detect(rgb)
        self.trace("detect_end", stamp)
        self._publish(detections_message(msg.header, detections))
        self.trace("detections_published", stamp)

    def _on_labels(self, msg: KittiFrameLabels) -> None:
        for image, labels in self.pairing.add_labels(stamp_ns(msg.header), msg):
            self._publish_oracle(image, labels)

    def _publish_oracle(self, image: Image, labels: KittiFrameLabels | None) -> None:
        if labels is None:
            self.get_logger().warning(
                f"{topics.GROUND_TRUTH}: no ground truth for image stamp "
                f"{stamp_ns(image.header)} ns; "
                "publishing an empty array"
            )
            dets = []
            self.usage.skipped(f"{topics.GROUND_TRUTH}: no ground truth for the image's stamp")
        else:
            dets = self.oracle.detect(kitti_objects_from_message(labels), image_size(image))
            self.usage.used()
        self._publish(detections_message(image.header, dets))


def main(args: list[str] | None = None) -> int:
    """Entry point of ``vehicle_detector``; exit code 2 for a bad parameter."""
    return run_node(
        VehicleDetectorNode,
        NODE_NAME,
        args,
        on_stop=lambda node: [node.worker.stop] if node.worker else [],
    )


if __name__ == "__main__":
    sys.exit(main())
