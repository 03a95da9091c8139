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
import threading
import time

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from stereo_vehicle_msgs.msg import (
    KittiFrameLabels,
    VehicleDetection2DArray,
    VehicleDetection3DArray,
)
from vehicle_common.camera_settings import CameraModel, detector_framing
from vehicle_common.flow_control import InFlightWindow
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
    ParameterError,
    check_overrides,
    declare_config,
)
from vehicle_common.node_runtime import NodeHealth, apply_process_settings, run_node
from vision_msgs.msg import Detection2DArray

from vehicle_common import topics

from .conversions import detections_message, vision_detections_message
from .parameters import DetectorParameters

NODE_NAME = "vehicle_detector"
IMAGE_TOPIC = topics.LEFT_IMAGE
INFO_TOPIC = topics.LEFT_INFO
GT_TOPIC = topics.GROUND_TRUTH
DETECTIONS_TOPIC = topics.DETECTIONS_2D
DOWNSTREAM_TOPIC = topics.DETECTIONS_3D  # back-pressure: a frame's end downstream
#: [s] between two looks at whether anyone publishes the 3D arrays
DOWNSTREAM_CHECK_S = 0.5


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
        types = tuple(p.vehicle_types)
        self.frames = FrameCounter()  # images in, detection arrays out, images skipped
        self.worker: LatestFrameWorker | None = None
        self.pub = self.create_publisher(VehicleDetection2DArray, DETECTIONS_TOPIC, 10)
        self.vision_pub = self.create_publisher(Detection2DArray, topics.VISION_DETECTIONS_2D, 10)
        if self.backend == "cnn":
            from .checkpoint import CheckpointError
            from .loading import load_detector

            try:  # device and runtime raise ParameterError themselves
                self.cnn = load_detector(
                    p.checkpoint,
                    p.device,
                    p.score_threshold,
                    p.nms_iou,
                    p.input_width,
                    p.input_height,
                    runtime=p.runtime,
                    threads=p.num_threads,
                    roi_top=p.roi_top,
                )
            except CheckpointError as exc:
                raise ParameterError("checkpoint", str(exc)) from None
            if self.cnn.runtime == "torch":
                import torch

                torch.set_num_threads(p.num_threads)
            c = self.cnn.config
            built = getattr(getattr(self.cnn, "source", None), "built", [])
            self.get_logger().info(
                f"cnn backend: {c.size} model (width {c.width}, depth {c.depth}), device "
                f"{self.cnn.device}, runtime {self.cnn.runtime}"
                + (f"; built and cached: {', '.join(built)}" if built else "")
            )
            if (
                c.size == "centernet"
                and p.runtime == "auto"
                and str(self.cnn.device) == "cpu"  # on a GPU, PyTorch is the right choice
                and self.cnn.runtime == "torch"
            ):
                self.get_logger().warning(
                    "onnx / onnxruntime not installed: the CenterNet runs on PyTorch, about 3x "
                    "slower (pip install onnx==1.23.1 onnxruntime==1.30.0; scripts/setup.sh "
                    "installs them)"
                )
            # the camera-dependent framing (vehicle_common.camera_settings): derived from the
            # left CameraInfo unless every part of it is given
            self._derive = not (p.input_width and p.input_height and p.roi_top >= 0)
            self._camera: CameraModel | None = None
            self._camera_error: str | None = None
            self._held: Image | None = None  # an image that waits for the first CameraInfo
            self._hold_timer = None
            self._lock = threading.Lock()
            # the first inference's set-up cost is paid here, before the graph is ready (at
            # the checkpoint's framing, KITTI's camera; another camera's is loaded from the
            # cache when its CameraInfo arrives)
            self.cnn.detect(np.zeros((c.input_height, c.input_width, 3), np.uint8))
            # latest-frame policy: the newest image is detected, an image still waiting when a
            # newer one arrives is skipped and counted (never a growing queue); with
            # back-pressure an image also waits while the stereo node has no room for it
            self.flow = None
            if p.downstream_window > 0:
                window = max(p.downstream_window, p.frame_queue)
                self.flow = InFlightWindow(window, p.downstream_timeout)
                self._downstream = (False, float("-inf"))  # (publisher seen, checked at)
                self._expired_seen = 0
            self.worker = LatestFrameWorker(
                self._work,
                self.frames,
                "detector",
                self._failed,
                max_waiting=p.frame_queue,
                admit=self._admit if self.flow is not None else None,
            )
            if self.flow is not None:
                self.create_subscription(
                    VehicleDetection3DArray, DOWNSTREAM_TOPIC, self._on_downstream, 10
                )
            if not self._derive:
                self.worker.submit(None, frame=False)  # the framing of the parameters, logged
            subscribe_camera(self, CameraInfo, INFO_TOPIC, self._on_camera_info, 5, self.usage.note)
        elif self.backend == "oracle":
            from .oracle import OracleDetector, StampPairing

            self.oracle = OracleDetector(
                positive_types=types,
                box_noise_px=p.oracle_box_noise_px,
                score=p.oracle_score,
                drop_probability=p.oracle_drop_probability,
                seed=p.oracle_seed,
            )
            self.pairing = StampPairing(max_pending=p.oracle_max_pending)
            self.create_subscription(KittiFrameLabels, GT_TOPIC, self._on_labels, 10)
            self.get_logger().warning(
                "ORACLE backend: publishing ground-truth boxes as detections (ablation only)"
            )
        # raw or compressed; BEST_EFFORT (any camera) or RELIABLE (camera_reliability), the
        # newest INPUT_DEPTH images (docs/ARCHITECTURE.md, "Topics"): a burst taken late is
        # seen and counted, only the newest is detected; the CNN's images as bytes, converted
        # only when detected (not the skipped ones)
        depth, cnn = max(topics.INPUT_DEPTH, p.frame_queue), self.backend == "cnn"
        subscribe_image(self, IMAGE_TOPIC, self._on_image, depth, self.usage.note, serialized=cnn)
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
        if self.backend == "oracle":
            for image, labels in self.pairing.add_image(stamp_ns(msg.header), msg):
                self._publish_oracle(image, labels)
            return
        with self._lock:
            if self._derive and self._camera is None and self._camera_error is None:
                # no CameraInfo yet: the image waits for the first one (bounded)
                if self._held is not None:
                    self.frames.dropped()  # superseded while waiting, as the worker would
                    self._publish(detections_message(self._held.header, []))
                self._held = msg
                if self._hold_timer is None:
                    self._hold_timer = self.create_timer(
                        max(self.params.camera_info_wait, 1e-3), self._camera_info_late
                    )
                return
        self.worker.submit(msg)

    def _admit(self, msg: Image) -> float | None:
        """The worker's question before it detects ``msg`` (back-pressure): None to start it,
        else seconds to wait for a frame's end downstream. No one publishing the 3D arrays
        (checked every DOWNSTREAM_CHECK_S): no back-pressure."""
        seen, at = self._downstream
        now = time.monotonic()
        if now - at >= DOWNSTREAM_CHECK_S:
            seen = self.count_publishers(DOWNSTREAM_TOPIC) > 0
            if not seen:
                self.flow.clear()
            self._downstream = (seen, now)
        if not seen:
            return None
        wait = self.flow.admit(stamp_ns(msg.header))
        if self.flow.expired > self._expired_seen:
            self._expired_seen = self.flow.expired
            self.get_logger().warning(
                f"{DOWNSTREAM_TOPIC}: no 3D array for a detected frame within "
                f"{self.flow.timeout:.1f} s ({self.flow.expired} so far); its place in the "
                "window is freed",
                throttle_duration_sec=5.0,
            )
        return wait

    def _on_downstream(self, msg: VehicleDetection3DArray) -> None:
        """A 3D array: the frames detected up to its stamp are done downstream."""
        if self.flow.finish(stamp_ns(msg.header)):
            self.worker.wake()

    def _on_camera_info(self, msg: CameraInfo) -> None:
        """A left CameraInfo: the framing is derived again when the camera's size or fx
        changed (applied by the worker, in order with the images)."""
        try:
            camera = CameraModel.from_camera_info(msg)
        except ValueError as exc:
            if str(exc) != self._camera_error:
                self._camera_error = str(exc)
                self.get_logger().warning(f"{INFO_TOPIC}: {exc}; framing unchanged")
            self._release_held()
            return
        key = (camera.width, camera.height, camera.fx)
        with self._lock:
            old = self._camera
            if old is not None and (old.width, old.height, old.fx) == key:
                return
            self._camera, self._camera_error = camera, None
        if self._derive:
            self.worker.submit((camera, old), frame=False)
        self._release_held()

    def _camera_info_late(self) -> None:
        """No CameraInfo came within ``camera_info_wait``: the waiting image is detected with
        the checkpoint's framing (reported once)."""
        self.destroy_timer(self._hold_timer)
        with self._lock:
            if self._camera is None and self._camera_error is None:
                self._camera_error = "none yet"
                self.get_logger().warning(
                    f"no CameraInfo on {INFO_TOPIC} within {self.params.camera_info_wait:g} s: "
                    "detecting with the checkpoint's framing until one arrives"
                )
                self.worker.submit(None, frame=False)
        self._release_held()

    def _release_held(self) -> None:
        with self._lock:
            held, self._held = self._held, None
        if held is not None:
            self.worker.submit(held)

    def _work(self, item) -> None:
        """The worker's items: an image, or a camera to frame the images for (None: the
        parameters' framing or the checkpoint's)."""
        if item is None or isinstance(item, tuple):
            self._apply_framing(*(item or (None, None)))
        else:
            self._detect(item)

    def _apply_framing(self, camera: CameraModel | None, old: CameraModel | None) -> None:
        """Frame the images for ``camera`` (vehicle_common.camera_settings) and log ONE line:
        what was derived and from what (a changed camera: also what it was)."""
        p, cnn = self.params, self.cnn
        framing = detector_framing(
            camera, *cnn.checkpoint_framing(), (p.input_width, p.input_height), p.roi_top
        )
        before = (cnn.config.input_width, cnn.config.input_height, cnn.roi_top)
        cnn.set_framing(framing.input_width, framing.input_height, framing.roi_top)
        if old is None:
            self.get_logger().info(framing.text)
        else:
            where = f"below the top {100 * before[2]:.0f} %" if before[2] > 0 else "whole image"
            was = f"was {before[0]}x{before[1]}, {where}"
            self.get_logger().warning(f"camera_info changed ({was}): {framing.text}")

    def _failed(self, exc: Exception, msg: Image) -> None:
        self.get_logger().warning(f"{IMAGE_TOPIC}: detection failed: {exc}; no detections")
        self._publish(detections_message(msg.header, []))

    def _publish(self, out: VehicleDetection2DArray) -> None:
        self.pub.publish(out)
        self.frames.published()
        if self.vision_pub.get_subscription_count() > 0:
            self.vision_pub.publish(vision_detections_message(out))

    def _detect(self, msg: Image) -> None:
        stamp = stamp_ns(msg.header)
        self.trace("detect_start", stamp)
        try:
            rgb = image_to_rgb(as_message(msg))
        except ImageConversionError as exc:
            self.usage.skipped(f"{IMAGE_TOPIC}: {exc}")
            self.get_logger().warning(f"{IMAGE_TOPIC}: {exc}; publishing no detections")
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
                f"{GT_TOPIC}: no ground truth for image stamp {stamp_ns(image.header)} ns; "
                "publishing an empty array"
            )
            dets = []
            self.usage.skipped(f"{GT_TOPIC}: no ground truth for the image's stamp")
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
