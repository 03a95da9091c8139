"""The filter ablation (the paper's Table 1): re-run the tracker core offline on a recorded run's
3D detection messages with each motion filter (``none``, ``kalman``, ``particle``; association and
lifecycle unchanged) and score the resulting tracks by 3D localisation AP at 1.5 m per
difficulty. Pure core: uses ``tracker_node.tracker`` and the detection metrics, no ROS.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from tracker_node.offline import result_rows
from vehicle_common.bags.recorded_run import RANKED_STATES, RecordedRun
from vehicle_common.kitti import KittiObject

from eval_node.detection_metrics import LEVELS, precision_recall

FILTER_NAMES = ("none", "kalman", "particle")


def run_tracker(
    run: RecordedRun, config, progress: bool = False, states=RANKED_STATES
) -> dict[int, list[KittiObject]]:
    """Track the run's recorded 3D detections with ``config`` (a TrackerConfig):
    ``{frame: [KittiObject...]}`` of the tracks in ``states``; by default those the AP ranks
    (``RANKED_STATES``: confirmed, coasting and, at their lowered score, tentative; as
    ``evaluate`` scores the live graph), ``OUTPUT_STATES`` for CLEAR-MOT / HOTA."""
    from tracker_node.conversions import camera_motion_from_msg, detections_from_msg
    from tracker_node.tracker import DetectionBatch, Tracker

    tracker = Tracker(config)
    if run.P_left is not None and run.frames:
        K = run.P_left[:, :3]
        tracker.set_projection(np.hstack([K, np.zeros((3, 1))]), run.image_size)
    frames = run.frames
    if progress:
        from tqdm import tqdm

        frames = tqdm(frames, desc=f"tracker ({config.filter})", unit="frame", leave=False)
    out: dict[int, list[KittiObject]] = {}
    mean_hwl = (config.mean_height, config.mean_width, config.mean_length)
    for f in frames:
        # the same message conversion as the live vehicle_tracker node
        batch = detections_from_msg(f.det3d_msg)[0] if f.det3d_msg else DetectionBatch.empty()
        motion = camera_motion_from_msg(f.det3d_msg)[0] if f.det3d_msg else None
        tracks = tracker.step(batch, f.stamp_ns * 1e-9, motion)
        out[f.frame] = result_rows(
            tracks, f.frame, f.offset, states, clip_score=True, mean_hwl=mean_hwl
        )
    return out


def compare_filters(
    run: RecordedRun,
    gt: dict[int, list[KittiObject]],
    config=None,
    filters=FILTER_NAMES,
    distance: float = 1.5,
    progress: bool = False,
) -> dict[str, dict]:
    """Table 1: ``{filter: {"easy", "moderate", "hard": AP|R40 (KITTI devkit interpolation),
    "ap_r40": {...}, "ap_r11": {...}, "ap_r41": {...}, "fps": ...}}``
    of the re-tracked detections at centre distance ``distance`` (``fps``: frames per second of
    the tracker core on this machine)."""
    import tracker_node.tracker  # noqa: F401  (imported before timing)
    from tracker_node.config import TrackerConfig

    base = config or TrackerConfig()
    results: dict[str, dict] = {}
    for name in filters:
        cfg = replace(base, filter=name)
        t0 = time.perf_counter()
        pred = run_tracker(run, cfg, progress)
        dt = time.perf_counter() - t0
        row: dict = {
            "ap_r40": {},
            "ap_r11": {},
            "ap_r41": {},
            "fps": len(run.frames) / dt if dt > 0 else float("nan"),
        }
        for level in LEVELS:
            pr = precision_recall(
                gt, pred, criterion="centre_distance", threshold=distance, difficulty=level
            )
            row[level] = pr.ap_r40
            row["ap_r40"][level] = pr.ap_r40
            row["ap_r11"][level] = pr.ap_r11
            row["ap_r41"][level] = pr.ap_r41
        results[name] = row
    return results
