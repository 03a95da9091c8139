"""``tracker_offline``: run the tracker over KITTI-format 3D detection files.

    tracker_offline --detections DIR --output DIR [--seqs 0001,0006] [--params FILE.yaml]
                    [--calib DIR]

Reads ``DIR/SSSS.txt`` (PointRCNN/AB3DMOT format, see :mod:`.detection_files`), writes KITTI
tracking result files ``OUTPUT/SSSS.txt`` (label format with track ids and a score column).
Parameters come from the ``vehicle_tracker: ros__parameters:`` section of a ROS parameter file,
the same names and defaults as the node (:class:`.config.TrackerConfig`). With calibration
(``--calib DIR`` with ``DIR/SSSS.txt``; by default ``DETECTIONS/../calib`` or the shared layout's
``tracking/training/calib``), tracking runs in the left optical frame and coasting rows carry the
projection of their 3D box with P2; otherwise in camera 0 with the last detection's 2D box.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from kitti_player_node.kitti import (
    Calibration,
    KittiFormatError,
    KittiObject,
    alpha_from_rotation_y,
    read_calib,
    write_tracking_labels,
)

from .config import TrackerConfig, TrackerConfigError
from .detection_files import TYPE_NAMES, DetectionRows, detection_batch, read_detection_file
from .tracker import COASTING, TENTATIVE, Tracker

FRAME_PERIOD = 0.1  # [s] KITTI's 10 Hz
CAR_TYPE_ID = 2  # detection files' type column (TYPE_NAMES)


def track_sequence(
    rows: DetectionRows,
    config: TrackerConfig,
    calib: Calibration | None = None,
) -> list[KittiObject]:
    """Track one sequence's car detections (``type_id`` 2); returns KITTI result rows (camera 0,
    bottom-centre locations, track ids, scores)."""
    rows = rows.select(rows.type_id == CAR_TYPE_ID)
    offset = np.zeros(3) if calib is None else calib.left_camera_offset
    projection = None
    if calib is not None:
        projection = np.hstack([calib.K, np.zeros((3, 1))])
    tracker = Tracker(config, projection=projection)
    type_name = TYPE_NAMES[CAR_TYPE_ID]
    n_frames = int(rows.frame.max()) + 1 if len(rows) else 0
    order = np.argsort(rows.frame, kind="stable")
    frames = rows.frame[order]
    starts = np.searchsorted(frames, np.arange(n_frames + 1))
    out: list[KittiObject] = []
    # output_coasting="refound": coasting rows wait here until their track is matched again
    pending: dict[int, list[KittiObject]] = {}
    hold = config.output_coasting == "refound"
    for f in range(n_frames):
        sel = order[starts[f] : starts[f + 1]]
        dets = detection_batch(rows.select(sel), offset, type_name)
        ts = tracker.step(dets, f * FRAME_PERIOD)
        if hold:  # tracks gone from the tracker (deleted) never come back: drop their rows
            alive = set(tracker.ids.tolist())
            pending = {k: v for k, v in pending.items() if k in alive}
        for i in range(len(ts)):
            if ts.state[i] == TENTATIVE and not config.output_tentative:
                continue
            l, w, h = (float(v) for v in ts.size[i])
            x, y, z = ts.position[i] - offset
            y += h / 2.0
            yaw = float(ts.yaw[i])
            bbox = ts.bbox[i]
            if not np.isfinite(bbox).all():
                continue
            row = KittiObject(
                type=type_name,
                alpha=alpha_from_rotation_y(yaw, x, z),
                bbox=tuple(float(v) for v in bbox),
                dimensions=(h, w, l),
                location=(float(x), float(y), float(z)),
                rotation_y=yaw,
                frame=f,
                track_id=int(ts.track_id[i]),
                score=float(ts.score[i]),
            )
            tid = int(ts.track_id[i])
            if hold and ts.state[i] == COASTING:
                pending.setdefault(tid, []).append(row)
                continue
            out.extend(pending.pop(tid, []))
            out.append(row)
    out.sort(key=lambda o: o.frame)
    return out


def find_calib_dir(detections: Path) -> Path | None:
    """Default calibration folder for a detections folder (None when there is none)."""
    candidates = [
        detections / ".." / "calib",
        detections / ".." / ".." / "tracking" / "training" / "calib",
    ]
    for c in candidates:
        if c.is_dir():
            return c.resolve()
    return None


def run(
    detections: Path,
    output: Path,
    seqs: list[str] | None,
    config: TrackerConfig,
    calib_dir: Path | None,
) -> list[Path]:
    """Track every selected sequence; returns the written result files."""
    if not detections.is_dir():
        raise KittiFormatError(f"{detections}: detections folder not found")
    if seqs is None:
        seqs = sorted(p.stem for p in detections.glob("*.txt"))
    written = []
    for seq in seqs:
        rows = read_detection_file(detections / f"{seq}.txt")
        calib = None
        if calib_dir is not None and (calib_dir / f"{seq}.txt").is_file():
            calib = read_calib(calib_dir / f"{seq}.txt")
        objects = track_sequence(rows, config, calib)
        path = output / f"{seq}.txt"
        write_tracking_labels(path, objects)
        written.append(path)
    return written


def _parse_seqs(text: str | None) -> list[str] | None:
    if not text:
        return None
    out = []
    for tok in text.split(","):
        tok = tok.strip()
        if not tok.isdigit():
            raise TrackerConfigError(f"--seqs: {tok!r} is not a sequence number")
        out.append(f"{int(tok):04d}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="tracker_offline", description="Track KITTI-format 3D detections offline."
    )
    parser.add_argument("--detections", required=True, type=Path, help="folder of SSSS.txt")
    parser.add_argument("--output", required=True, type=Path, help="folder for results")
    parser.add_argument("--seqs", help="comma-separated sequences, e.g. 0001,0006 (default all)")
    parser.add_argument("--params", type=Path, help="ROS parameter YAML (vehicle_tracker)")
    parser.add_argument("--calib", type=Path, help="calibration folder (default: searched)")
    args = parser.parse_args(argv)
    try:
        config = TrackerConfig.from_yaml(args.params) if args.params else TrackerConfig()
        seqs = _parse_seqs(args.seqs)
        calib_dir = args.calib
        if calib_dir is not None and not calib_dir.is_dir():
            raise KittiFormatError(f"{calib_dir}: calibration folder not found")
        if calib_dir is None:
            calib_dir = find_calib_dir(args.detections)
        written = run(args.detections, args.output, seqs, config, calib_dir)
    except (KittiFormatError, TrackerConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {len(written)} result file(s) to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
