"""``detector_offline``: run the detector over a folder of images and write KITTI object-format
result files (one ``<image stem>.txt`` per image, also for images without detections), for
``evaluate detection --results DIR --labels DIR``.

Input: ``--images DIR`` (every ``*.png`` in it), ``--kitti-root ROOT`` of a KITTI object layout
(``ROOT/image_2``) or of a tracking layout with ``--sequence S`` (``ROOT/image_02/S``). The
detector is the node's core (:class:`detector_node.inference.CnnDetector`, same checkpoint,
thresholds and input size parameters as ``vehicle_detector``).

Each detection is one row ``Car -1 -1 alpha x1 y1 x2 y2 -1 -1 -1 -1000 -1000 -1000 -10 score``:
``alpha`` = the continuous observation angle folded into [-pi/2, pi/2) (for a checkpoint without
the angle head: the centre of the predicted bin); its variance is not part of the KITTI format and
is not written. Bad input: one line ``error: ...`` on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from vehicle_common.kitti import KittiFormatError, KittiObject, format_row, read_png
from vehicle_common.output_paths import make_output_dir, os_error_line


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="detector_offline",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--images", type=Path, help="folder of PNG images")
    src.add_argument("--kitti-root", type=Path, help="KITTI object or tracking root")
    p.add_argument("--sequence", help="tracking sequence (with a tracking --kitti-root)")
    p.add_argument("--output", type=Path, required=True, help="folder for the result files")
    p.add_argument("--checkpoint", default="", help="checkpoint ('' = the shipped default)")
    p.add_argument("--score-threshold", type=float, default=0.05)
    p.add_argument("--nms-iou", type=float, default=0.45)
    p.add_argument("--input-width", type=int, default=0, help="0 = the checkpoint's")
    p.add_argument("--input-height", type=int, default=0, help="0 = the checkpoint's")
    p.add_argument("--num-threads", type=int, default=2, help="torch CPU threads")
    return p


def image_paths(args: argparse.Namespace) -> list[Path]:
    """The images to process, sorted; KittiFormatError (one line) when there are none."""
    if args.images is not None:
        folder = args.images
        if args.sequence:
            raise KittiFormatError("--sequence: only with a tracking --kitti-root")
    elif (args.kitti_root / "image_2").is_dir():
        folder = args.kitti_root / "image_2"
        if args.sequence:
            raise KittiFormatError(f"{args.kitti_root}: object layout, --sequence does not apply")
    elif (args.kitti_root / "image_02").is_dir():
        if not args.sequence:
            raise KittiFormatError(f"{args.kitti_root}: tracking layout, --sequence is required")
        seq = f"{int(args.sequence):04d}" if args.sequence.isdigit() else args.sequence
        folder = args.kitti_root / "image_02" / seq
    else:
        raise KittiFormatError(
            f"{args.kitti_root}: neither a KITTI object (image_2) nor tracking (image_02) root"
        )
    if not folder.is_dir():
        raise KittiFormatError(f"{folder}: image folder not found")
    paths = sorted(folder.glob("*.png"))
    if not paths:
        raise KittiFormatError(f"{folder}: no PNG images")
    return paths


def detection_rows(detections) -> list[str]:
    """KITTI object-format rows of detections (see module docstring)."""
    rows = []
    for d in detections:
        obj = KittiObject(
            "Car",
            truncated=-1.0,
            occluded=-1,
            alpha=float(d.observation_angle),
            bbox=tuple(float(v) for v in d.box),
            score=float(d.score),
        )
        rows.append(format_row(obj, tracking=False, with_score=True))
    return rows


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``detector_offline``."""
    args = build_parser().parse_args(argv)
    try:
        return _run(args)
    except (KittiFormatError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a write failing half-way (disk full)
        print(f"error: {os_error_line(exc)}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    from .loading import load_detector

    if not 0.0 <= args.score_threshold <= 1.0:
        raise ValueError(f"--score-threshold: {args.score_threshold} not in [0, 1]")
    if not 0.0 < args.nms_iou <= 1.0:
        raise ValueError(f"--nms-iou: {args.nms_iou} not in (0, 1]")
    if args.num_threads < 1:
        raise ValueError(f"--num-threads: {args.num_threads} must be >= 1")
    for name in ("input_width", "input_height"):
        v = getattr(args, name)
        if v < 0 or v % 32:
            raise ValueError(f"--{name.replace('_', '-')}: {v} must be 0 or a multiple of 32")
    paths = image_paths(args)
    make_output_dir(args.output)  # before the model is loaded: a bad path fails at once
    det = load_detector(
        args.checkpoint,
        "cpu",
        args.score_threshold,
        args.nms_iou,
        args.input_width,
        args.input_height,
        threads=args.num_threads,
    )
    if det.runtime == "torch":
        import torch

        torch.set_num_threads(args.num_threads)
    if args.kitti_root is not None and args.sequence:
        # the framing the node derives from this camera's CameraInfo (its calibration)
        from vehicle_common.camera_settings import CameraModel, detector_framing
        from vehicle_common.kitti import TrackingSequence

        try:
            calib = TrackingSequence.open(args.kitti_root, paths[0].parent.name).calib
        except (KittiFormatError, OSError):
            calib = None  # no calibration: the checkpoint's framing
        if calib is not None:
            h, w = read_png(paths[0]).shape[:2]
            camera = CameraModel.from_projections(w, h, calib.P2, calib.P3)
            f = detector_framing(
                camera, *det.checkpoint_framing(), (args.input_width, args.input_height)
            )
            det.set_framing(f.input_width, f.input_height, f.roi_top)
            print(f.text)
    t0 = time.perf_counter()
    n = 0
    for path in paths:
        rows = detection_rows(det.detect(read_png(path)))
        (args.output / f"{path.stem}.txt").write_text("".join(r + "\n" for r in rows))
        n += len(rows)
    dt = time.perf_counter() - t0
    print(
        f"{len(paths)} images, {n} detections -> {args.output} "
        f"({1000 * dt / len(paths):.1f} ms per image)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
