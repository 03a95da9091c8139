"""``vehicle_detector`` node: left image -> 2D vehicle detections.

Backends: ``cnn`` (default; the YOLOv2-style network, the shipped checkpoint unless
``checkpoint`` is set) and ``oracle`` (ablations only: ground-truth boxes from
/kitti/ground_truth, matched to the image by exact stamp, with optional noise and drops).
Exactly one VehicleDetection2DArray per left image, with the image's header.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Image
from stereo_vehicle_msgs.msg import KittiFrameLabels, VehicleDetection2DArray
from vehicle_common.frame_accounting import FrameCounter, LatestFrameWorker
from vehicle_common.frame_messages import kitti_objects_from_message, stamp_ns
from vehicle_common.frame_trace import frame_tracer
from vehicle_common.image_conversion import ImageConversionError, image_size, image_to_rgb
from vehicle_common.image_transport import subscribe_image
from vehicle_common.node_parameters import (
    declare_config,
    param,
)
from vehicle_common.node_runtime import NodeHealth, apply_process_settings, run_node

from vehicle_common import topics

from .conversions import detections_message

NODE_NAME = "vehicle_detector"
IMAGE_TOPIC = topics.LEFT_IMAGE
GT_TOPIC = topics.GROUND_TRUTH
DETECTIONS_TOPIC = topics.DETECTIONS_2D


@dataclass
class DetectorParameters:
    """The node's parameters (ROS names and defaults) with their allowed values."""

    backend: str = param("cnn", choices=("cnn", "oracle"))
    checkpoint: str = ""  # "" = the shipped tiny checkpoint
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    score_threshold: float = param(0.3, low=0.0, high=1.0)
    nms_iou: float = param(0.45, low=0.0, high=1.0, low_open=True)
    # [px] network input; 0 = the checkpoint's; the network's stride is 32
    input_width: int = param(0, low=0, multiple_of=32)
    input_height: int = param(0, low=0, multiple_of=32)
    num_threads: int = param(2, low=1)  # torch / ONNX Runtime CPU threads
    # inference runtime: auto (ONNX Runtime for a CenterNet checkpoint on the CPU when the
    # onnx / onnxruntime packages are installed, else PyTorch) | torch | onnxruntime
    runtime: str = param("auto", choices=("auto", "torch", "onnxruntime"))
    # fraction of the image height at the top not searched (above where vehicles are);
    # < 0 = the checkpoint's (0.25 for the shipped CenterNet, 0 for tiny_kitti)
    roi_top: float = param(-1.0, low=-1.0, high=0.8)
    # newest images kept waiting while one is detected (1: latest-frame policy; the launchers
    # set it to the player's lockstep_window in lockstep so that nothing is skipped)
    frame_queue: int = param(1, low=1)
    vehicle_types: list = param(["Car", "Van"])  # oracle: label types republished
    oracle_box_noise_px: float = param(0.0, low=0.0)
    oracle_score: float = param(1.0, low=0.0, high=1.0)
    oracle_drop_probability: float = param(0.0, low=0.0, high=1.0)
    oracle_seed: int = param(0, low=0)
    oracle_max_pending: int = param(10, low=1)


class VehicleDetectorNode(Node):
    """Thin ROS wrapper around :class:`CnnDetector` / :class:`OracleDetector`."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        apply_process_settings(self)  # first: the threads started below inherit it
        self.trace = frame_tracer(NODE_NAME)  # per-frame trace points (VEHICLE_TRACE_DIR)
        self.params = p = declare_config(self, DetectorParameters)
        self.backend = p.backend
        types = tuple(p.vehicle_types)
        self.frames = FrameCounter()  # images in, detection arrays out, images skipped
        self.worker: LatestFrameWorker | None = None
        self.pub = self.create_publisher(VehicleDetection2DArray, DETECTIONS_TOPIC, 10)
        if self.backend == "cnn":
            import torch

            from .inference import CnnDetector

            torch.set_num_threads(p.num_threads)
            self.cnn = CnnDetector.from_checkpoint(
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
            c = self.cnn.config
            self.get_logger().info(
                f"cnn backend: {c.size} model (width {c.width}, depth {c.depth}), input "
                f"{c.input_width}x{c.input_height}, region of interest below the top "
                f"{100 * self.cnn.roi_top:.0f} %, device {self.cnn.device}, runtime "
                f"{self.cnn.runtime}"
            )
            if (
                c.size == "centernet"
                and p.runtime == "auto"
                and self.cnn.device.type == "cpu"  # on a GPU, PyTorch is the right choice
                and self.cnn.runtime == "torch"
            ):
                self.get_logger().warning(
                    "onnx / onnxruntime not installed: the CenterNet runs on PyTorch, about 3x "
                    "slower (pip install onnx==1.23.1 onnxruntime==1.30.0; scripts/setup.sh "
                    "installs them)"
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
                max_waiting=p.frame_queue,
            )
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
        # raw or compressed; RELIABLE, the newest INPUT_DEPTH images (docs/ARCHITECTURE.md,
        # "Topics"): a burst taken late is seen and counted, only the newest is detected
        subscribe_image(self, IMAGE_TOPIC, self._on_image, max(topics.INPUT_DEPTH, p.frame_queue))
        self.health = NodeHealth(
            self, self.frames, busy=lambda: bool(self.worker and self.worker.busy)
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
        self.worker.submit(msg)

    def _failed(self, exc: Exception, msg: Image) -> None:
        self.get_logger().warning(f"{IMAGE_TOPIC}: detection failed: {exc}; no detections")
        self._publish(detections_message(msg.header, []))

    def _publish(self, out: VehicleDetection2DArray) -> None:
        self.pub.publish(out)
        self.frames.published()

    def _detect(self, msg: Image) -> None:
        stamp = stamp_ns(msg.header)
        self.trace("detect_start", stamp)
        try:
            rgb = image_to_rgb(msg)
        except ImageConversionError as exc:
            self.get_logger().warning(f"{IMAGE_TOPIC}: {exc}; publishing no detections")
            self._publish(detections_message(msg.header, []))
            return
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
        else:
            dets = self.oracle.detect(kitti_objects_from_message(labels), image_size(image))
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
