"""Reader of 3D detection files in the AB3DMOT / PointRCNN KITTI-tracking format.

One file per sequence, comma separated, one row per box:
``frame, type, x1, y1, x2, y2, score, h, w, l, x, y, z, rot_y, alpha`` with type 2 = Car (1 =
Pedestrian, 3 = Cyclist), the 2D box in left-image pixels, (h, w, l) in metres, (x, y, z) KITTI's
bottom centre in camera-0 coordinates and rot_y, alpha in radians. This format is not a KITTI
dataset file (those are read by ``vehicle_common.kitti``), so it is parsed here.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from vehicle_common.camera_frames import centre_from_kitti
from vehicle_common.kitti import KittiFormatError, read_text

TYPE_NAMES = {1: "Pedestrian", 2: "Car", 3: "Cyclist"}
NUM_COLUMNS = 15


@dataclass
class DetectionRows:
    """All rows of one file as arrays (R rows)."""

    frame: np.ndarray  # (R,) int
    type_id: np.ndarray  # (R,) int
    bbox: np.ndarray  # (R, 4) x1 y1 x2 y2 [px]
    score: np.ndarray  # (R,)
    hwl: np.ndarray  # (R, 3) [m]
    location: np.ndarray  # (R, 3) bottom centre, camera 0 [m]
    rotation_y: np.ndarray  # (R,) [rad]
    alpha: np.ndarray  # (R,) [rad]

    def __len__(self) -> int:
        return len(self.frame)

    def select(self, mask: np.ndarray) -> DetectionRows:
        return DetectionRows(**{k: v[mask] for k, v in self.__dict__.items()})


def read_detection_file(path: str | os.PathLike) -> DetectionRows:
    """Parse a detection file; raises KittiFormatError naming the file and line."""
    path = Path(path)
    text = read_text(path, "detections")
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        tokens = line.split(",")
        if len(tokens) != NUM_COLUMNS:
            raise KittiFormatError(
                f"{path}:{lineno}: expected {NUM_COLUMNS} comma-separated columns "
                f"(frame, type, x1, y1, x2, y2, score, h, w, l, x, y, z, rot_y, alpha), "
                f"got {len(tokens)}"
            )
        try:
            vals = [float(t) for t in tokens]
        except ValueError:
            raise KittiFormatError(f"{path}:{lineno}: non-numeric value") from None
        if not all(math.isfinite(v) for v in vals):
            raise KittiFormatError(f"{path}:{lineno}: non-finite value")
        if vals[0] < 0 or vals[0] != int(vals[0]):
            raise KittiFormatError(f"{path}:{lineno}: frame must be a non-negative integer")
        if vals[1] != int(vals[1]):
            raise KittiFormatError(f"{path}:{lineno}: type must be an integer (2 = Car)")
        if min(vals[7:10]) <= 0:
            raise KittiFormatError(f"{path}:{lineno}: box size h, w, l must be > 0")
        rows.append(vals)
    a = np.array(rows, dtype=float).reshape(-1, NUM_COLUMNS)
    return DetectionRows(
        frame=a[:, 0].astype(int),
        type_id=a[:, 1].astype(int),
        bbox=a[:, 2:6],
        score=a[:, 6],
        hwl=a[:, 7:10],
        location=a[:, 10:13],
        rotation_y=a[:, 13],
        alpha=a[:, 14],
    )


def detection_batch(rows: DetectionRows, offset=None, class_name: str = "Car"):
    """The rows as a tracker :class:`~tracker_node.tracker.DetectionBatch`: centres of mass
    (bottom centre lifted by h/2), moved by ``offset`` (3,) (camera 0 -> the tracker's frame;
    none: stay in camera 0), size (l, w, h), yaw, 2D box and score."""
    from .tracker import DetectionBatch

    hwl = rows.hwl
    centre = centre_from_kitti(rows.location, hwl[:, 0], offset)
    return DetectionBatch.create(
        centre,
        size=hwl[:, [2, 1, 0]],
        yaw=rows.rotation_y,
        bbox=rows.bbox,
        score=rows.score,
        class_id=[class_name] * len(rows),
    )
