"""``evaluate``: offline evaluation of KITTI tracking results, KITTI object-format detections or
of a recorded run (bag).

    evaluate tracking --results DIR --labels DIR [--seqs 0001 0006] [--calib DIR]
                      [--similarity iou2d|iou3d] [--json FILE]
    evaluate detection --results DIR --labels DIR|SSSS.txt [--class Car]
                       [--interpolation kitti|recall] [--json FILE]
    evaluate bag BAG [--labels DIR] [--sequence 0000] [--calib DIR] [--images DIR]
                 [--json FILE] [--report DIR] [--no-filters] [--tracker-params FILE]

Bad input prints one line ``error: <file>: <what>`` on stderr and exits with code 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from vehicle_common.kitti import KittiFormatError
from vehicle_common.output_paths import check_output_file, make_output_dir, os_error_line


def _jsonable(obj):
    """NaN/inf -> None, numpy scalars/arrays -> Python, dict keys -> str."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json(path: str | Path, results: dict) -> None:
    """Write results as strict JSON (NaN as null)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(results), indent=1) + "\n")


def _pct(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.1f}"


SIMILARITY_NAMES = {
    "iou2d": "2D box IoU (CLEAR-MOT at 0.5, HOTA on 2D IoU)",
    "iou3d": "3D box IoU (CLEAR-MOT at 0.25, HOTA on 3D IoU)",
}


def tracking_table(res: dict, similarity: str = "iou2d") -> str:
    """Compact per-sequence CLEAR-MOT/HOTA table of ``evaluate tracking``, headed by the
    similarity every figure uses."""
    cols = ["mota", "motp", "hota", "samota", "idsw", "frag", "fp", "fn"]
    rows = [(name, m) for name, m in res["per_sequence"].items()] + [("total", res["total"])]
    lines = [f"similarity: {SIMILARITY_NAMES[similarity]}"]
    lines.append("seq     " + " ".join(f"{c.upper():>7}" for c in cols))
    for name, m in rows:
        cells = []
        for c in cols:
            v = m.get(c)
            cells.append(f"{_pct(v):>7}" if c in ("mota", "motp", "hota", "samota") else f"{v:>7}")
        lines.append(f"{name:<8}" + " ".join(cells))
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="evaluate", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("tracking", help="score KITTI tracking result files")
    t.add_argument("--results", required=True, help="folder of SSSS.txt result files")
    t.add_argument("--labels", required=True, help="folder of SSSS.txt label files (label_02)")
    t.add_argument("--seqs", nargs="*", help="sequences (default: all with results)")
    t.add_argument("--calib", help="calib folder: fills missing 2D boxes by projection")
    t.add_argument(
        "--similarity",
        choices=["iou2d", "iou3d"],
        default="iou2d",
        help="box similarity of every metric: CLEAR-MOT matching (2D IoU 0.5 / 3D IoU 0.25) "
        "and HOTA",
    )
    t.add_argument("--json", help="write the metrics here")
    d = sub.add_parser("detection", help="score KITTI object-format detection files")
    d.add_argument("--results", required=True, help="folder of NNNNNN.txt detection files")
    d.add_argument(
        "--labels",
        required=True,
        help="label_2 folder (object benchmark) or one tracking label file label_02/SSSS.txt",
    )
    d.add_argument("--class", dest="cls", default="Car", help="evaluated class (default Car)")
    d.add_argument(
        "--interpolation",
        choices=["kitti", "recall"],
        default="kitti",
        help="precision interpolation: the devkit's (default) or at the actual recall",
    )
    d.add_argument("--json", help="write the metrics here")
    b = sub.add_parser("bag", help="evaluate a recorded run")
    b.add_argument("bag", help="bag directory (metadata.yaml + .mcap) or .mcap file")
    b.add_argument("--labels", help="label_02 folder (default: ground truth recorded in the bag)")
    b.add_argument("--sequence", help="sequence name (default: the one recorded)")
    b.add_argument(
        "--start-time",
        type=float,
        default=1.0,
        help="with --labels and no recorded ground truth: stamp [s] of frame 0, the KITTI "
        "player's start_time (default 1.0, its own); frames are numbered by stamp, 0.1 s each",
    )
    b.add_argument("--calib", help="KITTI calib folder (projection for the overlay without "
                   "camera_info)")  # fmt: skip
    b.add_argument("--images", help="KITTI tracking root with image_02 (overlay GIF)")
    b.add_argument("--json", help="write the metrics here")
    b.add_argument("--report", help="write the Markdown/HTML report and figures here")
    b.add_argument("--no-filters", action="store_true", help="skip the filter comparison")
    b.add_argument("--tracker-params", help="ROS params file for the re-run tracker")
    b.add_argument("--no-progress", action="store_true", help="no progress bars")
    b.add_argument(
        "--lost-cars",
        action="store_true",
        help="print why labelled cars were missed, per cause, and what each false-positive "
        "track row was (eval_node.lost_cars; the "
        "tracker's birth_score from --tracker-params)",
    )
    b.add_argument(
        "--namespace",
        help="namespace the graph ran in, e.g. /rig2 (default: detected from the bag's topics)",
    )
    return p


def _run_tracking(args) -> int:
    from eval_node.tracking_metrics import evaluate_tracking_dirs

    res = evaluate_tracking_dirs(
        args.results,
        args.labels,
        seqs=args.seqs,
        calib_dir=args.calib,
        similarity=args.similarity,
        hota_similarity=args.similarity,
    )
    for m in [res["total"], *res["per_sequence"].values()]:
        m.pop("hota_per_alpha", None)
    res["similarity"] = args.similarity
    if args.json:
        write_json(args.json, res)
    print(tracking_table(res, args.similarity))
    return 0


def _run_detection(args) -> int:
    from eval_node.detection_scoring import (
        detection_table,
        evaluate_detections,
        read_detection_dirs,
    )

    gt, pred, n_missing = read_detection_dirs(args.results, args.labels)
    if n_missing:
        print(
            f"note: {n_missing} labelled frames have no result file in {args.results}: "
            "counted as frames without detections",
            file=sys.stderr,
        )
    res = evaluate_detections(gt, pred, cls=args.cls, interpolation=args.interpolation)
    if args.json:
        write_json(args.json, res)
    print(detection_table(res))
    return 0


def _run_bag(args) -> int:
    from vehicle_common.bags.recorded_run import FrameGrid, read_run

    from eval_node.bag_evaluation import evaluate_bag
    from eval_node.report import results_table, write_report

    config = None
    if args.tracker_params:
        from tracker_node.config import TrackerConfig, TrackerConfigError

        try:
            config = TrackerConfig.from_yaml(args.tracker_params)
        except (OSError, TrackerConfigError) as exc:
            raise KittiFormatError(str(exc)) from None
    if args.calib and not Path(args.calib).is_dir():
        raise KittiFormatError(f"{args.calib}: calib folder not found")
    if not math.isfinite(args.start_time) or args.start_time < 0:
        raise KittiFormatError(f"--start-time {args.start_time}: expected a stamp [s] >= 0")
    run = read_run(
        args.bag,
        progress=not args.no_progress,
        namespace=args.namespace,
        # labels are numbered by frame: a run without recorded ground truth by its stamps
        frame_grid=FrameGrid(start_s=args.start_time) if args.labels else None,
    )
    res = evaluate_bag(
        args.bag,
        run=run,
        labels_dir=args.labels,
        sequence=args.sequence,
        run_filters=not args.no_filters,
        tracker_config=config,
        progress=not args.no_progress,
        calib_dir=args.calib,
    )
    if args.json:
        write_json(args.json, res)
    if args.report:
        files = write_report(res, args.report, run=run, images_dir=args.images)
        res_files = ", ".join(sorted(p.name for p in files.values()))
        print(f"report: {args.report} ({res_files})", file=sys.stderr)
    print(results_table(res))
    if args.lost_cars:
        print(lost_cars_table(run, args.labels, args.sequence, config))
    return 0


def _check_outputs(args) -> None:
    """The output file and folder, checked before the evaluation (which can take minutes)."""
    if getattr(args, "json", None):
        check_output_file(args.json, "the --json file")
    if getattr(args, "report", None):
        make_output_dir(args.report, "the --report folder")


def lost_cars_table(run, labels_dir=None, sequence=None, config=None) -> str:
    """:func:`eval_node.lost_cars.cause_table` of a recorded run (ground truth as evaluated)."""
    from eval_node.bag_evaluation import run_ground_truth
    from eval_node.lost_cars import cause_table, false_track_table, false_tracks, lost_cars

    def per_frame(attr: str) -> dict:
        return {f.frame: getattr(f, attr) for f in run.frames}

    seq = sequence or run.sequence or "0000"
    gt, _ = run_ground_truth(run, labels_dir, seq)
    records = lost_cars(
        seq,
        gt,
        per_frame("det2d"),
        per_frame("det3d"),
        per_frame("tracks"),
        per_frame("tentative"),
        birth_score=config.birth_score if config is not None else 0.0,
    )
    false_rows = false_tracks(seq, gt, per_frame("tracks"))
    return (
        "\nwhy labelled cars were missed (2D IoU 0.5, KITTI tracking rules):\n"
        + cause_table(records)
        + "\n\nwhat the false-positive track rows were (eval_node.lost_cars.false_tracks):\n"
        + false_track_table(false_rows)
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``evaluate`` console script."""
    args = build_parser().parse_args(argv)
    try:
        _check_outputs(args)
        run = {"tracking": _run_tracking, "detection": _run_detection, "bag": _run_bag}
        return run[args.command](args)
    except (KittiFormatError, OSError) as exc:
        msg = str(exc) if isinstance(exc, KittiFormatError) else os_error_line(exc)
        print("error: " + " ".join(msg.split()), file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
