"""KITTI's ground-truth disparity, for measuring the matcher and the ranging offline.

Pure core (numpy/OpenCV). The benchmarks that share these read them from here
(``bench/bench_stereo.py``, ``bench/stereo_real.py``, ``bench/real_motion.py``,
``bench/depth_tails.py``); ``root`` is a folder laid out as ``../shared/kitti`` (its README):

- :func:`stereo_pairs`: the KITTI Stereo 2015 training pairs (left, right, ground-truth
  disparity), evaluated with :data:`KITTI_GEOMETRY` (their calibration files are not there);
- :func:`surface_regions`: car-sized windows of such a map that lie on one surface;
- :func:`keyframes`: the labelled tracking keyframes with their LiDAR disparity (left images
  only), ranged on the exact map with :data:`EXACT_RANGING`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from vehicle_common.kitti import (
    Calibration,
    KittiObject,
    read_calib,
    read_png,
    read_tracking_labels,
)

from .ranging import RangingParams
from .reprojection import StereoGeometry

#: the colour pair of KITTI tracking 0005 (fx, fy, cx, cy [px], baseline [m]): the geometry the
#: KITTI 2015 pairs are evaluated with
KITTI_GEOMETRY = StereoGeometry(721.5, 721.5, 609.6, 172.9, 0.5327)
#: ranging on a ground-truth disparity map: no full-resolution refinement (no right image) and
#: no camera disparity bias (the truth has none)
EXACT_RANGING = replace(
    RangingParams(), refine="none", disparity_bias=0.0, disparity_bias_column=0.0
)


def stereo_pairs(root: Path, count: int = 5):
    """Yield (left RGB, right RGB, ground-truth disparity [px], 0 = none) of the KITTI Stereo
    2015 training pairs ``000000_10`` .. of ``root/stereo_2015/training``."""
    folder = Path(root) / "stereo_2015" / "training"
    for i in range(count):
        name = f"{i:06d}_10.png"
        left = read_png(folder / "image_2" / name)
        right = read_png(folder / "image_3" / name)
        gt = cv2.imread(str(folder / "disp_occ_0" / name), cv2.IMREAD_UNCHANGED)
        yield left, right, gt.astype(np.float32) / 256.0


def surface_regions(gt: np.ndarray, margin: int = 100):
    """Car-sized windows of a KITTI 2015 ground-truth map that lie on one surface: for a car
    (3.2 x 1.4 m) at disparities 6..70 px, windows (half-overlapping, not in the leftmost
    ``margin`` columns that the right image does not see) whose ground truth covers >= 30 % of
    the pixels, has its median within 12 % of that disparity and >= 75 % of its pixels within
    10 % of the median. Yields (box, truth = mean ground truth of that surface, i.e. of the
    pixels within 10 % of the median)."""
    h, w = gt.shape
    for d in (6, 8, 10, 13, 16, 20, 25, 30, 36, 45, 55, 70):
        bw, bh = int(3.2 * d / 0.54), int(1.4 * d / 0.54)
        for y in range(0, h - bh, max(bh // 2, 4)):
            for x in range(margin, w - bw, max(bw // 2, 4)):
                g = gt[y : y + bh, x : x + bw]
                v = g[g > 0]
                if v.size < 0.3 * g.size:
                    continue
                m = float(np.median(v))
                on_surface = np.abs(v / m - 1) < 0.10
                if abs(m - d) > 0.12 * d or np.mean(on_surface) < 0.75:
                    continue
                yield (x, y, x + bw, y + bh), float(np.mean(v[on_surface]))


@dataclass
class Keyframe:
    """One labelled tracking keyframe with its LiDAR disparity (invalid pixels -1)."""

    name: str  # SSSS_NNNNNN
    sequence: str
    frame: int
    rgb: np.ndarray
    disparity: np.ndarray
    geometry: StereoGeometry
    calib: Calibration
    objects: list[KittiObject]


def keyframes(root: Path) -> list[Keyframe]:
    """The tracking keyframes of ``root/tracking_keyframes`` (``frames.csv``), with the labels and
    calibration of their sequences in ``root/tracking/training``."""
    kf, tracking = Path(root) / "tracking_keyframes", Path(root) / "tracking" / "training"
    labels: dict[str, dict] = {}
    out = []
    for row in csv.DictReader((kf / "frames.csv").open()):
        seq, frame = row["tracking_sequence"], int(row["tracking_frame"])
        if seq not in labels:
            labels[seq] = read_tracking_labels(tracking / "label_02" / f"{seq}.txt")
        calib = read_calib(tracking / "calib" / f"{seq}.txt")
        gt = cv2.imread(str(kf / "disp_occ_0" / f"{row['name']}.png"), -1)
        disp = np.where(gt > 0, gt.astype(np.float32) / 256.0, -1.0).astype(np.float32)
        out.append(
            Keyframe(
                row["name"],
                seq,
                frame,
                read_png(kf / "image_2" / f"{row['name']}.png"),
                disp,
                StereoGeometry.from_projections(calib.P2, calib.P3),
                calib,
                list(labels[seq].get(frame, [])),
            )
        )
    return out
