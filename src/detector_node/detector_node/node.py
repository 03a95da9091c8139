"""``vehicle_detector`` node: left image -> 2D vehicle detections.

Backends: ``cnn`` (default; the YOLOv2-style network, the shipped checkpoint unless
``checkpoint`` is set) and ``oracle`` (ablations only: ground-truth boxes from
/kitti/ground_truth, matched to the image by exact stamp, with optional noise and drops).
Exactly one VehicleDetection2DArray per left image, with the image's header.
"""

from __future__ import annotations

import sys

import numpy as np
import rclpy
from kitti_player_node.frame_accounting import FrameCounter, LatestFrameWorker
from kitti_player_node.frame_messages import kitti_objects_from_message, stamp_ns, xyxy_to_bbox
from kitti_player_node.image_conversion import ImageConversionError, image_to_rgb
from kitti_player_node.node_parameters import declare_parameters
from kitti_player_node.node_runtime import NodeHealth, StopRequest, spin_until_stopped
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Image
from stereo_vehicle_msgs.msg import KittiFrameLabels, VehicleDetection2D, VehicleDetection2DArray

from .inference import Detection

IMAGE_TOPIC = "/stereo/left/image_rect"
GT_TOPIC = "/kitti/ground_truth"
DETECTIONS_TOPIC = "/vehicles/detections_2d"

#: ROS parameters: name -> default.
PARAMETERS = {
    "backend": "cnn",
    "checkpoint": "",
    "device": "auto",
    "score_threshold": 0.3,
    "nms_iou": 0.45,
    "input_width": 0,
    "input_height": 0,
    "num_threads": 2,
    # newest images kept waiting while one is detected (1: latest-frame policy; the launcher sets
    # the player's lockstep_window in lockstep so that nothing is skipped)
    "frame_queue": 1,
    "vehicle_types": ["Car", "Van"],
    "oracle_box_noise_px": 0.0,
    "oracle_score": 1.0,
    "oracle_drop_probability": 0.0,
    "oracle_seed": 0,
    "oracle_max_pending": 10,
}


def detections_message(header, detections: list[Detection]) -> VehicleDetection2DArray:
    """VehicleDetection2DArray with ``header``: centre/size boxes, ids "0", "1", ..."""
    msg = VehicleDetection2DArray(header=header)
    for i, d in enumerate(detections):
        m = VehicleDetection2D()
        m.id = str(i)
        m.class_id = "car"
        m.score = float(d.score)
        xyxy_to_bbox(d.box, m.bbox)
        m.orientation_bin = int(d.orientation_bin)
        m.orientation_probs = [float(p) for p in d.orientation_probs]
        msg.detections.append(m)
    return msg


class VehicleDetectorNode(Node):
    """Thin ROS wrapper around :class:`CnnDetector` / :class:`OracleDetector`."""

    def __init__(self, **kwargs) -> None:
        super().__init__("vehicle_detector", **kwargs)
        p = declare_parameters(self, PARAMETERS)  # ValueError names a mistyped parameter
        self.backend = str(p["backend"])
        types = tuple(p["vehicle_types"])
        self.frames = FrameCounter()  # images in, detection arrays out, images skipped
        self.worker: LatestFrameWorker | None = None
        self.pub = self.create_publisher(VehicleDetection2DArray, DETECTIONS_TOPIC, 10)
        if self.backend == "cnn":
            import torch

            from .inference import CnnDetector

            torch.set_num_threads(max(1, int(p["num_threads"])))
            self.cnn = CnnDetector.from_checkpoint(
                str(p["checkpoint"]),
                str(p["device"]),
                float(p["score_threshold"]),
                float(p["nms_iou"]),
                int(p["input_width"]),
                int(p["input_height"]),
            )
            c = self.cnn.config
            self.get_logger().info(
                f"cnn backend: {c.size} model (width {c.width}, depth {c.depth}), input "
                f"{c.input_width}x{c.input_height}, device {self.cnn.device}"
            )
            # the first inference's set-up cost is paid here, before the graph is ready
            self.cnn.detect(np.zeros((c.input_height, c.input_width, 3), np.uint8))
            # latest-frame policy: the newest image is detected, an image still waiting when a
            # newer one arrives is skipped and counted (never a growing queue)
            self.worker = LatestFrameWorker(
                self._detect,
                self.frames,
                "detector",
                self._failed,
                max_waiting=max(1, int(p["frame_queue"])),
            )
        elif self.backend == "oracle":
            from .oracle import OracleDetector, StampPairing

            self.oracle = OracleDetector(
                positive_types=types,
                box_noise_px=float(p["oracle_box_noise_px"]),
                score=float(p["oracle_score"]),
                drop_probability=float(p["oracle_drop_probability"]),
                seed=int(p["oracle_seed"]),
            )
            self.pairing = StampPairing(max_pending=int(p["oracle_max_pending"]))
            self.create_subscription(KittiFrameLabels, GT_TOPIC, self._on_labels, 10)
            self.get_logger().warning(
                "ORACLE backend: publishing ground-truth boxes as detections (ablation only)"
            )
        else:
            raise ValueError(f"parameter backend: expected 'cnn' or 'oracle', got {self.backend!r}")
        self.create_subscription(Image, IMAGE_TOPIC, self._on_image, 5)
        self.health = NodeHealth(
            self, self.frames, busy=lambda: bool(self.worker and self.worker.busy)
        )

    def destroy_node(self):
        if self.worker is not None:
            self.worker.stop()  # the image in hand and the one waiting are finished first
        super().destroy_node()

    def _on_image(self, msg: Image) -> None:
        self.frames.received()
        if self.backend == "oracle":
            for image, labels in self.pairing.add_image(stamp_ns(msg.header), msg):
                self._publish_oracle(image, labels)
            return
        self.worker.submit(msg)

    def _failed(self, exc: Exception, msg: Image) -> None:
        self.get_logger().warning(f"{IMAGE_TOPIC}: detection failed: {exc}; no detections")
        self._publish(detections_message(msg.header, []))

    def _publish(self, out: VehicleDetection2DArray) -> None:
        self.pub.publish(out)
        self.frames.published()

    def _detect(self, msg: Image) -> None:
        try:
            rgb = image_to_rgb(msg)
        except ImageConversionError as exc:
            self.get_logger().warning(f"{IMAGE_TOPIC}: {exc}; publishing no detections")
            self._publish(detections_message(msg.header, []))
            return
        self._publish(detections_message(msg.header, self.cnn.detect(rgb)))

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
        else:
            dets = self.oracle.detect(
                kitti_objects_from_message(labels), (int(image.width), int(image.height))
            )
        self._publish(detections_message(image.header, dets))


def main(args: list[str] | None = None) -> int:
    """Entry point of ``vehicle_detector``."""
    rclpy.init(
        args=args if args is not None else sys.argv,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    stop = StopRequest.install()
    try:
        node = VehicleDetectorNode()
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except KeyboardInterrupt:  # stopped while loading
        rclpy.try_shutdown()
        return 0
    try:
        drain = [node.worker.stop] if node.worker else []
        spin_until_stopped(node, stop, node.health, on_stop=drain)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
