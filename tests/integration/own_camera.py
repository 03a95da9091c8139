"""A user's own stereo camera, as the attacks of issue #42 drive the graph with it: a process that
publishes a KITTI-layout sequence (real 0005 or a synthetic one) the way camera drivers do.

- images and camera_info with the QoS ``--reliability`` (BEST_EFFORT: the sensor-data QoS of most
  drivers), in ``--encoding`` (``bgra8``: ZED's default);
- the right image stamped ``--offsets-ms`` after the left one (cycled: two drivers not hardware
  synced), each camera_info published just before its image, with that image's stamp;
- ``/kitti/ground_truth`` with the left stamp, so that the recorded run is scored against the
  labels as the KITTI player's run is;
- ``--info zeros`` (camera_info all zeros) or ``--info size`` (1280x720 for 1242x375 images);
- ``--restart-at K``: from frame K on the stamps start again 1.7 s earlier (a restarted camera).

Stamps are the sequence's 10 Hz ones (from 100 s). The frames are paced by the graph's tracks:
the next pair goes out when the tracks of the previous one arrived, or after ``--timeout`` s, so
that what is counted is what the graph accepts and pairs, not how fast a loaded test machine
runs the detector (a real camera at 10 Hz drives the latest-frame policy instead). It waits first
until the graph's nodes subscribe (``--subscribers``: left image subscriptions to wait for,
``--info-subscribers``: left camera_info ones).
Prints ``published N frames, tracks for M``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from stereo_vehicle_msgs.msg import KittiFrameLabels, TrackedVehicleArray
from vehicle_common.frame_messages import (
    LEFT_FRAME,
    RIGHT_FRAME,
    ground_truth_message,
    header,
    stamp_ns,
    stereo_camera_infos,
)
from vehicle_common.image_conversion import numpy_to_image
from vehicle_common.kitti import calib_path, read_calib, read_png, read_tracking_labels

START_NS = 100 * 10**9
PERIOD_NS = 100_000_000  # KITTI: 10 Hz


def _encode(rgb: np.ndarray, encoding: str):
    if encoding == "bgra8":
        alpha = np.full(rgb.shape[:2], 255, np.uint8)
        return np.dstack([rgb[:, :, ::-1], alpha])
    if encoding == "rgb8":
        return rgb
    if encoding == "bayer_rggb8":  # not read by the graph: the test of its one line
        return rgb[:, :, 1]
    raise SystemExit(f"error: --encoding {encoding!r}: bgra8, rgb8 or bayer_rggb8")


def _image(rgb: np.ndarray, encoding: str):
    arr = _encode(rgb, encoding)
    if encoding == "bayer_rggb8":
        msg = numpy_to_image(arr, "mono8")
        msg.encoding = encoding
        return msg
    return numpy_to_image(arr, encoding)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", required=True, help="KITTI tracking root (image_02, image_03, ...)")
    ap.add_argument("--sequence", default="0005")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--encoding", default="bgra8")
    ap.add_argument("--reliability", default="best_effort", choices=("best_effort", "reliable"))
    ap.add_argument("--offsets-ms", default="1,3,5,2,4")
    ap.add_argument("--info", default="ok", choices=("ok", "zeros", "size"))
    ap.add_argument("--restart-at", type=int, default=0)
    ap.add_argument("--subscribers", type=int, default=2)
    ap.add_argument("--info-subscribers", type=int, default=3)  # + the tracker's
    ap.add_argument("--timeout", type=float, default=20.0)
    args = ap.parse_args(argv)
    root = Path(args.root)
    seq = args.sequence
    calib = read_calib(calib_path(root, seq))
    labels = read_tracking_labels(root / "label_02" / f"{seq}.txt")
    offsets = [float(v) for v in args.offsets_ms.split(",")]

    rclpy.init()
    node = Node("own_camera")
    policy = ReliabilityPolicy.BEST_EFFORT
    if args.reliability == "reliable":
        policy = ReliabilityPolicy.RELIABLE
    qos = QoSProfile(depth=5, reliability=policy)
    pub_left = node.create_publisher(Image, "/stereo/left/image_rect", qos)
    pub_right = node.create_publisher(Image, "/stereo/right/image_rect", qos)
    pub_left_info = node.create_publisher(CameraInfo, "/stereo/left/camera_info", qos)
    pub_right_info = node.create_publisher(CameraInfo, "/stereo/right/camera_info", qos)
    pub_gt = node.create_publisher(KittiFrameLabels, "/kitti/ground_truth", 10)
    acked: set[int] = set()
    node.create_subscription(
        TrackedVehicleArray, "/vehicles/tracks", lambda m: acked.add(stamp_ns(m.header)), 10
    )
    deadline = time.monotonic() + 60.0
    wanted = {pub_left: args.subscribers, pub_left_info: args.info_subscribers}
    wanted.update({pub_right: 1, pub_right_info: 1})
    while any(pub.get_subscription_count() < n for pub, n in wanted.items()):
        rclpy.spin_once(node, timeout_sec=0.1)
        if time.monotonic() > deadline:
            print("error: the graph never subscribed", flush=True)
            return 1
    time.sleep(1.0)  # the other endpoints of the nodes match too

    tracked = published = 0
    for k in range(args.frames):
        frame = k
        stamp = START_NS + k * PERIOD_NS
        if args.restart_at and k >= args.restart_at:
            stamp -= 17 * PERIOD_NS  # 1.7 s back, as 101.7 s -> 100.0 s
        right_stamp = stamp + round(offsets[k % len(offsets)] * 1e6)
        left_rgb = read_png(root / "image_02" / seq / f"{frame:06d}.png")
        right_rgb = read_png(root / "image_03" / seq / f"{frame:06d}.png")
        h, w = left_rgb.shape[:2]
        info_w, info_h = (1280, 720) if args.info == "size" else (w, h)
        left_info, _ = stereo_camera_infos(calib, info_w, info_h, stamp)
        _, right_info = stereo_camera_infos(calib, info_w, info_h, right_stamp)
        if args.info == "zeros":
            for info in (left_info, right_info):
                info.k, info.p, info.width, info.height = [0.0] * 9, [0.0] * 12, 0, 0
        left, right = (_image(rgb, args.encoding) for rgb in (left_rgb, right_rgb))
        left.header = header(stamp, LEFT_FRAME)
        right.header = header(right_stamp, RIGHT_FRAME)
        pub_gt.publish(ground_truth_message(seq, frame, calib, labels.get(frame, []), stamp))
        pub_left_info.publish(left_info)
        pub_left.publish(left)
        pub_right_info.publish(right_info)
        pub_right.publish(right)
        published += 1
        until = time.monotonic() + args.timeout
        while stamp not in acked and time.monotonic() < until:
            rclpy.spin_once(node, timeout_sec=0.05)
        tracked += stamp in acked
    until = time.monotonic() + 1.0
    while time.monotonic() < until:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(f"published {published} frames, tracks for {tracked}", flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
