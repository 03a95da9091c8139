"""Offline evaluation of a recorded run (a bag of the pipeline's topics) by KITTI rules.

:func:`evaluate_bag` reads the bag (:mod:`vehicle_common.bags.recorded_run`), takes the ground
truth from the recorded ``/kitti/ground_truth`` or from KITTI label files, and computes, in one
dict that is also the JSON output:

- ``detections_3d`` / ``tracks_3d``: 3D localisation AP (centre distance 1.5/3/5/10 m) per
  difficulty of the unfiltered 3D detections and of the tracks (KITTI's AP|R40 with the
  devkit's interpolation, with AP|R11 and the 41-point mean beside it, fractions);
- ``detections_2d``: 2D AP|R40 at IoU 0.5 and 0.7 (AP|R11 and 41-point beside it) and Pascal VOC
  11-point AP at 0.5;
- ``orientation``: orientation-bin accuracy and 4x4 confusion of the 2D detections;
- ``tracking``: CLEAR-MOT and HOTA of the tracks (2D IoU: CLEAR-MOT at 0.5, HOTA on 2D IoU;
  ``iou3d``: CLEAR-MOT at 3D IoU 0.25 and HOTA on 3D IoU);
- ``velocity``: velocity error (``rmse``, ``mae`` [m/s], per speed bucket) and stability;
- ``filter_comparison``: the tracker core re-run on the recorded 3D detections with each
  filter (Table 1, 3D AP at 1.5 m per difficulty);
- ``throughput``: frames processed, frames per second and latency from receive times;
- ``curves``: sampled precision/recall curves for the report's figures.

All AP values are fractions in [0, 1]; NaN (``null`` in JSON) where nothing is counted.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from vehicle_common.bags.recorded_run import (
    DET3D_TOPIC,
    GT_TOPIC,
    TRACKS_TOPIC,
    BagReadError,
    RecordedRun,
    read_run,
)
from vehicle_common.kitti import KittiObject, read_calib, read_tracking_labels

from eval_node.detection_metrics import LEVELS, ap_table, orientation_accuracy, voc07_ap
from eval_node.tracking_metrics import evaluate_tracking

DISTANCES = (1.5, 3.0, 5.0, 10.0)
IOUS = (0.5, 0.7)


def load_labels(labels_dir: str | Path, sequence: str) -> dict[int, list[KittiObject]]:
    """Ground truth of ``sequence`` from ``labels_dir/SSSS.txt`` (or ``labels_dir/label_02/``)."""
    d = Path(labels_dir)
    for cand in (d / f"{sequence}.txt", d / "label_02" / f"{sequence}.txt"):
        if cand.is_file():
            return read_tracking_labels(cand)
    raise BagReadError(f"{d / (sequence + '.txt')}: label file of sequence {sequence} not found")


def run_ground_truth(run: RecordedRun, labels_dir, sequence: str) -> tuple[dict, str]:
    """The ground truth per frame of a recorded run: from ``labels_dir`` (label_02 files) when
    given, else as recorded; and its source ("labels", "bag" or "none")."""
    if labels_dir is not None:
        labels = load_labels(labels_dir, sequence)
        gt = {
            f.frame: [o.with_(frame=f.frame) for o in labels.get(f.frame, [])] for f in run.frames
        }
        return gt, "labels"
    source = "bag" if any(GT_TOPIC in f.receive_ns for f in run.frames) else "none"
    return {f.frame: f.gt for f in run.frames}, source


def tracking_scores(gt, tracks) -> dict:
    """CLEAR-MOT + HOTA of the tracks (KITTI devkit rules, 2D IoU 0.5, HOTA on 2D IoU) and the
    same with 3D IoU (CLEAR-MOT at 0.25, HOTA on 3D IoU) under ``iou3d``."""
    res = evaluate_tracking(gt, tracks, similarity="iou2d", hota_similarity="iou2d")
    res.pop("hota_per_alpha", None)
    res3 = evaluate_tracking(gt, tracks, similarity="iou3d", hota_similarity="iou3d")
    res3.pop("hota_per_alpha", None)
    res["iou3d"] = {k: v for k, v in res3.items() if k != "all_rows"}
    return res


def velocity_scores(run: RecordedRun, gt) -> dict:
    """Velocity error of the tracks' filtered velocities against ground-truth finite differences
    on the ground plane (x, z) and stability (:mod:`eval_node.motion_metrics`; tracks paired with
    ground truth by the tracking matcher, times from the stamps). Adds ``velocity_jitter`` [m/s]:
    RMS of the frame-to-frame change of each track's reported velocity (lower is steadier)."""
    from eval_node.motion_metrics import stability, velocity_errors

    pred_v, by_track = {}, {}
    for f in run.frames:
        for o, v in zip(f.tracks, f.track_velocities, strict=True):
            pred_v[(f.frame, o.track_id)] = v[[0, 2]]
            by_track.setdefault(o.track_id, []).append(v)
    tracks = {f.frame: f.tracks for f in run.frames}
    stamps = {f.frame: f.stamp_ns * 1e-9 for f in run.frames}
    res = velocity_errors(gt, tracks, pred_velocities=pred_v, stamps=stamps)
    res["stability"] = stability(gt, tracks)
    steps = [
        float(np.linalg.norm(d))
        for vs in by_track.values()
        if len(vs) > 1
        for d in np.diff(np.array(vs), axis=0)
    ]
    res["velocity_jitter"] = float(np.sqrt(np.mean(np.square(steps)))) if steps else math.nan
    return res


def trajectories(run: RecordedRun, gt) -> dict:
    """Bird's-eye-view paths (x, z in camera 0) per ground-truth and track id."""
    out: dict[str, dict] = {"gt": {}, "tracks": {}}
    for k in sorted(gt):
        for o in gt[k]:
            if not o.is_dontcare and o.type in ("Car", "Van"):
                out["gt"].setdefault(str(o.track_id), []).append([o.location[0], o.location[2]])
    for f in run.frames:
        for o in f.tracks:
            out["tracks"].setdefault(str(o.track_id), []).append([o.location[0], o.location[2]])
    return out


def _throughput(run: RecordedRun) -> dict:
    t_tracks = [f.receive_ns[TRACKS_TOPIC] for f in run.frames if TRACKS_TOPIC in f.receive_ns]
    lat = [
        (f.receive_ns[TRACKS_TOPIC] - f.receive_ns[GT_TOPIC]) * 1e-6
        for f in run.frames
        if TRACKS_TOPIC in f.receive_ns and GT_TOPIC in f.receive_ns
    ]
    stamps = [f.stamp_ns for f in run.frames if TRACKS_TOPIC in f.receive_ns]
    out = {
        "frames": len(run.frames),
        "frames_with_tracks": len(t_tracks),
        "frames_with_detections_3d": sum(DET3D_TOPIC in f.receive_ns for f in run.frames),
        "fps": math.nan,
        "dataset_fps": math.nan,
        "latency_ms_mean": float(np.mean(lat)) if lat else math.nan,
        "latency_ms_max": float(np.max(lat)) if lat else math.nan,
    }
    if len(t_tracks) > 1:
        span = (max(t_tracks) - min(t_tracks)) * 1e-9
        out["fps"] = (len(t_tracks) - 1) / span if span > 0 else math.nan
        span_s = (max(stamps) - min(stamps)) * 1e-9
        out["dataset_fps"] = (len(stamps) - 1) / span_s if span_s > 0 else math.nan
    return out


def evaluate_bag(
    bag_path: str | Path,
    labels_dir: str | Path | None = None,
    sequence: str | None = None,
    run_filters: bool = True,
    tracker_config=None,
    progress: bool = False,
    calib_dir: str | Path | None = None,
    run: RecordedRun | None = None,
) -> dict:
    """Evaluate a recorded run; returns the results dict described in the module docstring.
    ``run``: the bag already read with :func:`read_run` (read here when None), so that a caller
    writing the report as well reads the bag once.
    Raises BagReadError (a KittiFormatError) naming the file for unusable input."""
    if run is None:
        run = read_run(bag_path, progress=progress)
    if not run.frames:
        raise BagReadError(f"{bag_path}: no frames (no {GT_TOPIC} and no pipeline outputs)")
    seq = sequence or run.sequence or "0000"
    if calib_dir is not None and run.P_left is None:
        run.P_left = read_calib(Path(calib_dir) / f"{seq}.txt").P2
    gt, gt_source = run_ground_truth(run, labels_dir, seq)
    det2d = {f.frame: f.det2d for f in run.frames}
    det3d = {f.frame: f.det3d for f in run.frames}
    tracks = {f.frame: f.tracks for f in run.frames}
    # AP ranks tentative tracks too, at their lowered score (recorded_run.RANKED_STATES)
    ranked = {f.frame: f.tracks + f.tentative for f in run.frames}

    curves: dict = {"detections_3d": {}, "tracks_3d": {}, "detections_2d": {}}
    res: dict = {
        "bag": str(bag_path),
        "sequence": seq,
        "gt_source": gt_source,
        "frames": len(run.frames),
        "topics": run.topics,
        "unmatched_stamps": run.unmatched_stamps,
        "detections_3d": ap_table(gt, det3d, "centre_distance", DISTANCES, curves["detections_3d"]),
        "tracks_3d": ap_table(gt, ranked, "centre_distance", DISTANCES, curves["tracks_3d"]),
        "detections_2d": ap_table(gt, det2d, "iou2d", IOUS, curves["detections_2d"]),
    }
    res["detections_2d"]["voc11_0.5"] = {
        level: voc07_ap(gt, det2d, 0.5, difficulty=level) for level in LEVELS
    }
    res["orientation"] = orientation_accuracy(gt, det2d, iou=0.5).as_dict()
    res["tracking"] = tracking_scores(gt, tracks)
    res["velocity"] = velocity_scores(run, gt)
    res["trajectories"] = trajectories(run, gt)
    res["throughput"] = _throughput(run)
    if run_filters:
        from eval_node.filter_comparison import compare_filters

        res["filter_comparison"] = compare_filters(run, gt, tracker_config, progress=progress)
    res["curves"] = curves
    return res
