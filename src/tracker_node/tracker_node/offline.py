"""``tracker_offline``: run the tracker over KITTI-format 3D detection files.

    tracker_offline --detections DIR --output DIR [--seqs 0001,0006] [--params FILE.yaml]
                    [--calib DIR] [--lookahead N]

Reads ``DIR/SSSS.txt`` (PointRCNN/AB3DMOT format, see :mod:`.detection_files`), writes KITTI
tracking result files ``OUTPUT/SSSS.txt`` (label format with track ids and a score column).
Parameters come from the ``vehicle_tracker: ros__parameters:`` section of a ROS parameter file,
the same names and defaults as the node (:class:`.config.TrackerConfig`). With calibration
(``--calib DIR`` with ``DIR/SSSS.txt``; by default ``DETECTIONS/../calib`` or the shared layout's
``tracking/training/calib``), tracking runs in the left optical frame and coasting rows carry the
projection of their 3D box with P2; otherwise in camera 0, and coasting rows have no 2D box (a
stale detection box would misplace them) and are not written.

Online by default: the rows of frame f depend only on frames 0..f and are exactly the tracks the
``vehicle_tracker`` node publishes for that frame (tentative tracks and tracks without a 2D box
left out). ``--lookahead N`` is look-ahead smoothing (not online, see :class:`LookaheadBuffer`).
For PointRCNN-scored LiDAR detections use ``--params
src/tracking_bringup/config/tracker_pointrcnn.yaml`` (docs/tracker.md).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from vehicle_common.camera_frames import kitti_row_from_centre
from vehicle_common.kitti import (
    MEAN_CAR_DIMENSIONS,
    Calibration,
    KittiFormatError,
    KittiObject,
    read_calib,
    write_tracking_labels,
)
from vehicle_common.output_paths import make_output_dir, os_error_line

from .config import TrackerConfig, TrackerConfigError
from .detection_files import TYPE_NAMES, DetectionRows, detection_batch, read_detection_file
from .lifecycle import COASTING, CONFIRMED, TENTATIVE
from .tracker import DetectionBatch, Tracker, TrackSet

FRAME_PERIOD = 0.1  # [s] KITTI's 10 Hz
CAR_TYPE_ID = 2  # detection files' type column (TYPE_NAMES)
#: track states written as results (tentative tracks only with ``output_tentative``)
OUTPUT_STATES = (CONFIRMED, COASTING)


def detections_for_frame(
    rows: DetectionRows, sel: np.ndarray, offset: np.ndarray
) -> DetectionBatch:
    """The tracker's input for detection rows ``sel`` (KITTI camera-0 bottom centres ->
    centres of mass in the tracking frame, ``offset`` = camera 0 -> tracking frame)."""
    return detection_batch(rows.select(sel), offset, TYPE_NAMES[CAR_TYPE_ID])


def result_rows(
    ts: TrackSet,
    frame: int,
    offset: np.ndarray | None,
    states: Iterable[int] = OUTPUT_STATES,
    *,
    clip_score: bool = False,
    mean_hwl=MEAN_CAR_DIMENSIONS,
) -> list[KittiObject]:
    """KITTI result rows (camera 0, bottom centres, :mod:`vehicle_common.camera_frames`) of one
    frame's tracks whose state is in ``states``; rows that are not finite (no 2D box) are
    dropped. ``clip_score``: the score clipped to [0, 1] as ``vehicle_tracker`` publishes it
    (else the tracker's own score, e.g. PointRCNN's logits); ``mean_hwl``: the size of tracks
    without one. Shared by ``tracker_offline`` and the evaluator's filter comparison."""
    keep = set(int(s) for s in states)
    out = []
    for i in range(len(ts)):
        if int(ts.state[i]) not in keep:
            continue
        score = float(ts.score[i])
        row = kitti_row_from_centre(
            ts.position[i],
            ts.size[i],
            ts.bbox[i],
            offset,
            yaw=float(ts.yaw[i]),
            frame=frame,
            track_id=int(ts.track_id[i]),
            score=min(max(score, 0.0), 1.0) if clip_score else score,
            type_name=TYPE_NAMES[CAR_TYPE_ID],
            mean_hwl=mean_hwl,
        )
        if row is not None:  # non-finite box: not representable in a KITTI file
            out.append(row)
    return out


class LookaheadBuffer:
    """Look-ahead smoothing of an online row stream (offline only): a coasting row is held
    back and written only if its track is matched again within ``frames`` frames of it (the gap
    is then filled with the prediction); otherwise it is dropped. Rows of frame f are final
    ``frames`` frames later."""

    def __init__(self, frames: int):
        self.frames = int(frames)
        self.pending: dict[int, list[KittiObject]] = {}

    def push(self, frame: int, rows: list[KittiObject], states: dict[int, int], alive: set[int]):
        """Take frame ``frame``'s rows (``states``: track id -> state); returns the rows
        released now."""
        horizon = frame - self.frames
        self.pending = {
            tid: kept
            for tid, held in self.pending.items()
            if tid in alive and (kept := [o for o in held if o.frame >= horizon])
        }
        out = []
        for row in rows:
            if states[row.track_id] == COASTING:
                self.pending.setdefault(row.track_id, []).append(row)
                continue
            out.extend(self.pending.pop(row.track_id, []))
            out.append(row)
        return out


def track_frames(
    batches: Iterable[DetectionBatch],
    config: TrackerConfig,
    projection: np.ndarray | None = None,
    offset: np.ndarray | None = None,
    lookahead: int = 0,
) -> list[KittiObject]:
    """Track frames 0, 1, ... (one DetectionBatch each, ``FRAME_PERIOD`` apart); returns the
    KITTI result rows (:func:`result_rows`; ``offset``: tracking frame -> camera 0).
    ``lookahead`` 0: online, frame f's rows are the tracks reported for it (what the node
    publishes); N > 0: :class:`LookaheadBuffer` (uses up to N later frames)."""
    if lookahead < 0:
        raise TrackerConfigError(f"--lookahead: must be >= 0, got {lookahead}")
    offset = np.zeros(3) if offset is None else offset
    tracker = Tracker(config, projection=projection)
    buffer = LookaheadBuffer(lookahead) if lookahead else None
    out: list[KittiObject] = []
    for f, dets in enumerate(batches):
        ts = tracker.step(dets, f * FRAME_PERIOD)
        states = (TENTATIVE, *OUTPUT_STATES) if config.output_tentative else OUTPUT_STATES
        frame_rows = result_rows(ts, f, offset, states)
        if buffer is not None:
            states = dict(zip(ts.track_id.tolist(), ts.state.tolist(), strict=True))
            frame_rows = buffer.push(f, frame_rows, states, set(tracker.tracks.ids.tolist()))
        out.extend(frame_rows)
    out.sort(key=lambda o: o.frame)
    return out


def track_sequence(
    rows: DetectionRows,
    config: TrackerConfig,
    calib: Calibration | None = None,
    lookahead: int = 0,
) -> list[KittiObject]:
    """Track one sequence's car detections (``type_id`` 2) with :func:`track_frames`; returns
    KITTI result rows (camera 0, bottom-centre locations, track ids, scores)."""
    rows = rows.select(rows.type_id == CAR_TYPE_ID)
    offset = np.zeros(3) if calib is None else calib.left_camera_offset
    projection = None
    if calib is not None:
        projection = np.hstack([calib.K, np.zeros((3, 1))])
    n_frames = int(rows.frame.max()) + 1 if len(rows) else 0
    order = np.argsort(rows.frame, kind="stable")
    starts = np.searchsorted(rows.frame[order], np.arange(n_frames + 1))
    batches = (
        detections_for_frame(rows, order[starts[f] : starts[f + 1]], offset)
        for f in range(n_frames)
    )
    return track_frames(batches, config, projection, offset, lookahead)


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
    lookahead: int = 0,
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
        objects = track_sequence(rows, config, calib, lookahead)
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
            raise TrackerConfigError("--seqs", f"{tok!r} is not a sequence number")
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
    parser.add_argument(
        "--lookahead",
        type=int,
        default=0,
        metavar="N",
        help="LOOK-AHEAD smoothing (not online): write a coasting row only if its track is "
        "matched again within N later frames. Default 0: online, each frame's rows are what "
        "the vehicle_tracker node publishes for it",
    )
    args = parser.parse_args(argv)
    try:
        config = TrackerConfig.from_yaml(args.params) if args.params else TrackerConfig()
        seqs = _parse_seqs(args.seqs)
        calib_dir = args.calib
        if calib_dir is not None and not calib_dir.is_dir():
            raise KittiFormatError(f"{calib_dir}: calibration folder not found")
        if calib_dir is None:
            calib_dir = find_calib_dir(args.detections)
        make_output_dir(args.output)
        written = run(args.detections, args.output, seqs, config, calib_dir, args.lookahead)
    except (KittiFormatError, TrackerConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a write failing half-way (disk full)
        print(f"error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    print(f"wrote {len(written)} result file(s) to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
