"""Score KITTI object-format detection files (``evaluate detection``).

Results: a folder with one file per frame, ``NNNNNN.txt``, KITTI object rows
``type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y score`` (the score column is
what the devkit ranks by; a row without it counts as score 1). Labels: either an object-benchmark
``label_2`` folder (``NNNNNN.txt`` per frame) or one tracking label file ``label_02/SSSS.txt``,
whose frame indices name the result files (frame 7 -> ``000007.txt``).

2D AP is the KITTI object devkit's (``evaluate_object.cpp``, the server code): AP|R40 and AP|R11
at IoU 0.7 and 0.5 per difficulty, with the devkit's interpolation by default. When result rows
carry a 3D box (h, w, l > 0 and a location), the paper's centre-distance 3D AP is computed too,
on the frames whose labels carry 3D boxes (object labels with -1000 placeholders are 2D only).
"""

from __future__ import annotations

import os
from pathlib import Path

from vehicle_common.kitti import (
    KittiFormatError,
    KittiObject,
    read_object_labels,
    read_tracking_labels,
)

from eval_node.detection_metrics import DEFAULT_DISTANCES, DEFAULT_IOUS, LEVELS, ap_table


def _carries_3d(o: KittiObject) -> bool:
    return min(o.dimensions) > 0 and o.location[2] > -999.0


def _frame_id(path: Path) -> int:
    if not path.stem.isdigit():  # "-00001", "+3", "1e3" are no frame numbers
        raise KittiFormatError(
            f"{path}: result file names must be frame numbers (NNNNNN.txt) to pair with a "
            "tracking label file"
        )
    return int(path.stem)


def read_detection_dirs(
    results_dir: str | os.PathLike, labels: str | os.PathLike
) -> tuple[dict, dict, int]:
    """``(gt, pred, n_missing)``: ground truth and results keyed by frame, and the number of
    labelled frames without a result file (they count as frames with no detection).

    Raises :class:`KittiFormatError` naming the file (and line) for a missing folder, a results
    folder without ``.txt`` files, a result file whose frame has no label, or a malformed row."""
    results_dir, labels = Path(results_dir), Path(labels)
    if not results_dir.is_dir():
        raise KittiFormatError(f"{results_dir}: results folder not found")
    files = sorted(results_dir.glob("*.txt"))
    if not files:
        raise KittiFormatError(f"{results_dir}: no result files (*.txt) in the results folder")
    if labels.is_file():  # one tracking label file: frames by index
        gt = {k: v for k, v in read_tracking_labels(labels).items()}
        pred = {}
        for f in files:
            pred[_frame_id(f)] = read_object_labels(f)
        for k in pred:
            gt.setdefault(k, [])  # a frame without label rows has no object
    elif labels.is_dir():
        gt, pred = {}, {}
        for lf in sorted(labels.glob("*.txt")):
            gt[lf.stem] = read_object_labels(lf)
        for f in files:
            if f.stem not in gt:
                raise KittiFormatError(f"{labels / f.name}: no label file for result {f}")
            pred[f.stem] = read_object_labels(f)
    else:
        raise KittiFormatError(f"{labels}: label folder or tracking label file not found")
    n_missing = sum(1 for k in gt if k not in pred)
    return gt, pred, n_missing


def evaluate_detections(
    gt: dict,
    pred: dict,
    *,
    cls: str = "Car",
    ious=DEFAULT_IOUS,
    distances=DEFAULT_DISTANCES,
    interpolation: str = "kitti",
) -> dict:
    """``{"frames", "class", "interpolation", "detections_2d": {"0.7": {"easy": AP|R40, ...,
    "easy_r11", ...}, "0.5": ...}, "detections_3d" (only when results carry 3D boxes),
    "frames_3d"}``; APs are fractions, as in the demo's ``results.json``."""
    out: dict = {
        "frames": len(gt),
        "class": cls,
        "interpolation": interpolation,
        "detections_2d": ap_table(
            gt, pred, "iou2d", sorted(ious, reverse=True), cls=cls, interpolation=interpolation
        ),
    }
    rows = [o for objs in pred.values() for o in objs]
    if any(_carries_3d(o) for o in rows):
        frames_3d = [
            k for k, objs in gt.items() if all(_carries_3d(o) for o in objs if not o.is_dontcare)
        ]
        gt3 = {k: gt[k] for k in frames_3d}
        pred3 = {k: pred.get(k, []) for k in frames_3d}
        out["frames_3d"] = len(frames_3d)
        out["detections_3d"] = ap_table(
            gt3, pred3, "centre_distance", distances, cls=cls, interpolation=interpolation
        )
    return out


def detection_table(res: dict) -> str:
    """The printed table of ``evaluate detection`` (AP in percent, 2 decimals)."""
    head = f"{'metric (' + res['class'] + ', %)':<26}" + "".join(f"{lv:>10}" for lv in LEVELS)
    lines = [head]

    def cell(v: float) -> str:
        return f"{'n/a' if v != v else f'{100 * v:.2f}':>10}"  # v != v: NaN, nothing counted

    def add(name: str, row: dict, suffix: str) -> None:
        cells = "".join(cell(row[lv + suffix]) for lv in LEVELS)
        lines.append(f"{name:<26}{cells}")

    for t, row in res["detections_2d"].items():
        add(f"2D AP|R40 @ IoU {t}", row, "_r40")
        add(f"2D AP|R11 @ IoU {t}", row, "_r11")
    for d, row in res.get("detections_3d", {}).items():
        add(f"3D AP|R40 @ {d} m", row, "_r40")
    first = next(iter(res["detections_2d"].values()))
    counts = " / ".join(str(first[f"{lv}_num_gt"]) for lv in LEVELS)
    interp = "KITTI devkit" if res["interpolation"] == "kitti" else "actual recall"
    lines.append(
        f"{res['frames']} frames, counted ground truth easy / moderate / hard {counts}, "
        f"{interp} interpolation"
        + (f"; 3D AP on {res['frames_3d']} frames with 3D labels" if "frames_3d" in res else "")
    )
    return "\n".join(lines)
