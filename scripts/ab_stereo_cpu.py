"""The stereo node's CPU per frame, old code against new, A/B interleaved in one process.

Usage: python scripts/ab_stereo_cpu.py [--old-ref main] [--repeats 5] [--detections DIR]

Copies ``src/stereo_depth_node/stereo_depth_node`` at git ``--old-ref`` into a temporary folder
as the package ``stereo_depth_node_old`` and runs both versions on real 0005's 16 stereo
frames (../shared/kitti), frame by frame (old, new, new, old, ...):
- core: ``StereoPipeline`` with the serial executor (``time.process_time`` per frame);
- node: ``StereoDepthNode`` in-process, its ``_process_frame`` given the frame's serialized
  rgb8 images and 2D detection array as the subscriptions would (its helper thread drained
  before the clock stops; rclpy's executor and the middleware are not included).
Boxes: the labels' Car/Van (score 1), or ``--detections DIR`` (``detector_offline``'s files,
scores >= 0.3 as the detector publishes). Prints the medians, new / old (of the medians,
and run by run: a run's two versions share its moment of the machine), the load average, and
whether the 3D arrays and odometry messages are bit-identical (every number).
In scripts/, not bench/: it drives the node module's internals in-process, which bench/ must
not (tests/test_architecture.py).
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TRACKING = ROOT.parent / "shared" / "kitti" / "tracking" / "training"


def old_package(ref: str, folder: Path) -> None:
    """The stereo node's package at ``ref`` as ``stereo_depth_node_old`` under ``folder``."""
    path = "src/stereo_depth_node/stereo_depth_node"
    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", ref, path], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=tar, check=True)
    (folder / path).rename(folder / "stereo_depth_node_old")
    sys.path.insert(0, str(folder))


def frames_of(seq, detections: Path | None):
    """[(left bytes, right bytes, VehicleDetection2DArray, FrameBoxes)] of the sequence."""
    from rclpy.serialization import serialize_message
    from stereo_depth_node.offline import detection_boxes, oracle_boxes
    from stereo_vehicle_msgs.msg import VehicleDetection2D, VehicleDetection2DArray
    from vehicle_common.frame_messages import xyxy_to_bbox
    from vehicle_common.image_conversion import numpy_to_image

    out = []
    for f in seq.frame_ids:
        left, right = seq.read_stereo(f)
        sec, nsec = divmod((f + 1) * 100_000_000, 10**9)
        msgs = []
        for img in (left, right):
            m = numpy_to_image(img, "rgb8")
            m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = sec, nsec, "cam2"
            msgs.append(serialize_message(m))
        boxes = (
            oracle_boxes(seq, f, ("Car", "Van"))
            if detections is None
            else detection_boxes(detections, f)
        )
        det = VehicleDetection2DArray()
        det.header.stamp.sec, det.header.stamp.nanosec, det.header.frame_id = sec, nsec, "cam2"
        for i in range(len(boxes)):
            if boxes.scores[i] < 0.3:
                continue
            d = VehicleDetection2D(id=str(i), class_id="car", score=float(boxes.scores[i]))
            xyxy_to_bbox(boxes.boxes[i], d.bbox)
            d.orientation_bin = int(boxes.bins[i])
            d.orientation_probs = [0.25] * 4
            d.observation_angle = float(boxes.angles[i])
            d.observation_angle_variance = 0.01
            det.detections.append(d)
        out.append((*msgs, det, left, right))
    return out


class Variant:
    """One version of the package: a core pipeline and an in-process node."""

    def __init__(self, package: str, seq, frames) -> None:

        self.pl = importlib.import_module(package + ".pipeline")
        self.node_mod = importlib.import_module(package + ".node")
        self.params = importlib.import_module(package + ".parameters")
        self.seq, self.frames = seq, frames
        self.published: list = []

    def fresh_node(self):
        """A new node with the camera of the sequence, its outputs collected (serialized)."""
        from vehicle_common.image_conversion import camera_info_from_projection

        node = self.node_mod.StereoDepthNode()
        h, w = self.frames[0][3].shape[:2]
        node.left_info = camera_info_from_projection(self.seq.calib.P2, w, h)
        node.right_info = camera_info_from_projection(self.seq.calib.P3, w, h)
        node.left_info.header.frame_id = node.right_info.header.frame_id = "cam2"
        node._update_geometry()
        from vehicle_common.frame_messages import field_bits

        pub = self.published.append
        node.pub_det3d.publish = lambda m: pub(field_bits(m))
        if node.odometry_pubs.odometry is not None:
            node.odometry_pubs.odometry.publish = lambda m: pub(field_bits(m))
        return node

    def node_steps(self):
        """A fresh node (its creation not timed) and a function that processes frame ``i``
        and returns its CPU time (its helper thread drained: its corners ahead count)."""
        from sensor_msgs.msg import Image
        from vehicle_common.image_transport import SerializedImage

        node = self.fresh_node()

        def step(i: int) -> float:
            lb, rb, det, _, _ = self.frames[i]
            c0 = time.process_time()
            node._process_frame((SerializedImage(lb, Image), SerializedImage(rb, Image), det))
            node._helper.submit(lambda: None).result()
            return time.process_time() - c0

        return node, step

    def core_steps(self):
        """A fresh pipeline (serial executor) and a function that processes frame ``i`` and
        returns its CPU time."""
        from stereo_depth_node.node import frame_boxes

        pipeline = self.pl.StereoPipeline.from_config(self.params.stereo_config_from_values({}))

        def step(i: int) -> float:
            _, _, det, left, right = self.frames[i]
            c0 = time.process_time()
            if pipeline.settings is None:
                pipeline.camera_from_projections(left, self.seq.calib.P2, self.seq.calib.P3)
            geometry, settings = pipeline.camera()
            params = pipeline.disparity_params_for(left.shape[0], settings)
            boxes = frame_boxes(det.detections)
            stamp = det.header.stamp.sec * 10**9 + det.header.stamp.nanosec
            pipeline.process(stamp, left, right, geometry, params, boxes)
            pipeline.frame_done(boxes.boxes)
            return time.process_time() - c0

        return pipeline, step


def interleaved(variants: dict, part: str, n_frames: int) -> dict:
    """One run of both versions over the frames, alternating frame by frame (and which goes
    first); CPU per frame of each version, its outputs kept."""
    steps, nodes, total = {}, [], {k: 0.0 for k in variants}
    for k, v in variants.items():
        v.published.clear()
        owner, steps[k] = v.node_steps() if part == "node" else v.core_steps()
        if part == "node":
            nodes.append(owner)
    for i in range(n_frames):
        order = list(variants) if i % 2 == 0 else list(variants)[::-1]
        for k in order:
            total[k] += steps[k](i)
    for node in nodes:
        node.destroy_node()
    for v in variants.values():
        v.outputs = list(v.published)
    return {k: t / n_frames for k, t in total.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--old-ref", default="main")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--detections", type=Path)
    args = p.parse_args(argv)
    if not TRACKING.is_dir():
        print(f"error: {TRACKING}: no KITTI tracking data", file=sys.stderr)
        return 2
    import rclpy
    from vehicle_common.kitti import TrackingSequence

    tmp = tempfile.TemporaryDirectory()
    old_package(args.old_ref, Path(tmp.name))
    seq = TrackingSequence.open(TRACKING, "0005")
    frames = frames_of(seq, args.detections)
    rclpy.init()
    variants = {
        "old": Variant("stereo_depth_node_old", seq, frames),
        "new": Variant("stereo_depth_node", seq, frames),
    }
    interleaved(variants, "core", len(frames))  # warm-up
    interleaved(variants, "node", len(frames))  # and the outputs compared
    same = variants["old"].outputs == variants["new"].outputs
    n_msgs = len(variants["new"].outputs)
    cpu = {(k, part): [] for k in variants for part in ("core", "node")}
    loads = [Path("/proc/loadavg").read_text().split()[0]]
    for _ in range(args.repeats):
        for part in ("core", "node"):
            for k, t in interleaved(variants, part, len(frames)).items():
                cpu[k, part].append(t)
        same = same and variants["old"].outputs == variants["new"].outputs
        loads.append(Path("/proc/loadavg").read_text().split()[0])
    print(f"boxes: {args.detections or 'labels'}; old = {args.old_ref}; {args.repeats} repeats")
    print(f"published messages bit-identical old/new: {same} ({n_msgs} messages)")
    for part in ("core", "node"):
        old, new = (statistics.median(cpu[k, part]) * 1000 for k in ("old", "new"))
        print(f"{part}: CPU per frame old {old:.1f} ms, new {new:.1f} ms: new/old {new / old:.3f}")
        paired = [n / o for o, n in zip(cpu["old", part], cpu["new", part], strict=True)]
        print(f"  new/old run by run: median {statistics.median(paired):.3f}, ", end="")
        print(f"new lower in {sum(r < 1 for r in paired)} of {len(paired)}")
        print(f"  old runs {[round(x * 1000, 1) for x in cpu['old', part]]}")
        print(f"  new runs {[round(x * 1000, 1) for x in cpu['new', part]]}")
    print(f"load average (1 min) at each repeat: {' '.join(loads)}")
    rclpy.shutdown()
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
