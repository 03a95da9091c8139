"""Runtime of the evaluation library on the 6 KITTI tracking validation sequences.

    python bench/bench_eval_metrics.py [--seqs 1,6,8,10,12,13]

Scores (a) the labels against themselves and (b) the tracker's output on the real PointRCNN
detections of ../shared/kitti (tracker_node.offline with its default configuration, written to a
temporary folder) with ``evaluate_tracking_dirs`` (2D IoU 0.5 with HOTA; 3D IoU 0.25), and the
detection metrics (3D localisation AP at 4 distances x 3 difficulties, 2D AP at 2 IoUs x 3
difficulties) of the labels against themselves. Prints wall times and their ratio to the time of
just reading the same label files (the baseline measured in this run).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
KITTI = REPO.parent / "shared" / "kitti"
DETS = KITTI / "detections" / "pointrcnn_Car_val"
LABELS = KITTI / "tracking" / "training" / "label_02"
CALIB = KITTI / "tracking" / "training" / "calib"


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def main() -> int:
    from eval_node.detection_metrics import detection_ap_2d, localisation_ap
    from eval_node.tracking_metrics import evaluate_tracking_dirs
    from vehicle_common.kitti import read_tracking_labels

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seqs", default="1,6,8,10,12,13")
    args = parser.parse_args()
    seqs = [f"{int(s):04d}" for s in args.seqs.split(",")]
    if not LABELS.is_dir():
        print(f"error: {LABELS}: KITTI labels not found", file=sys.stderr)
        return 2

    labels, t_read = timed(lambda: {s: read_tracking_labels(LABELS / f"{s}.txt") for s in seqs})
    n_rows = sum(len(v) for f in labels.values() for v in f.values())
    n_frames = sum(len(f) for f in labels.values())
    print(f"sequences {','.join(seqs)}: {n_frames} labelled frames, {n_rows} rows")
    print(f"baseline: reading the label files            {t_read:7.3f} s")

    def report(name, res, dt):
        t = res["total"]
        extra = f" HOTA {t['hota']:.4f}" if "hota" in t else ""
        print(
            f"{name:44s} {dt:7.3f} s ({dt / t_read:6.1f} x read)  MOTA {t['mota']:.4f} "
            f"MOTP {t['motp']:.4f} sAMOTA {t['samota']:.4f} IDSW {t['idsw']} FRAG {t['frag']} "
            f"FP {t['fp']} FN {t['fn']}{extra}"
        )

    res, dt = timed(evaluate_tracking_dirs, LABELS, LABELS, seqs=seqs)
    report("labels vs labels, 2D IoU 0.5 + HOTA", res, dt)
    res, dt = timed(
        evaluate_tracking_dirs, LABELS, LABELS, seqs=seqs, similarity="iou3d", hota=False
    )
    report("labels vs labels, 3D IoU 0.25", res, dt)

    try:
        from tracker_node.config import TrackerConfig
        from tracker_node.offline import run
    except ImportError as exc:  # tracker not available: labels only
        print(f"tracker_node.offline not available ({exc}); tracker output not scored")
    else:
        with tempfile.TemporaryDirectory() as tmp:
            _, t_track = timed(run, DETS, Path(tmp), seqs, TrackerConfig(), CALIB)
            print(f"tracker_offline on PointRCNN detections      {t_track:7.3f} s")
            res, dt = timed(evaluate_tracking_dirs, Path(tmp), LABELS, seqs=seqs)
            report("tracker vs labels, 2D IoU 0.5 + HOTA", res, dt)
            res, dt = timed(
                evaluate_tracking_dirs, Path(tmp), LABELS, seqs=seqs, similarity="iou3d", hota=False
            )
            report("tracker vs labels, 3D IoU 0.25", res, dt)

    t0 = time.perf_counter()
    for s in seqs:
        localisation_ap(labels[s], labels[s])
    dt = time.perf_counter() - t0
    print(f"{'localisation AP, 12 configurations':44s} {dt:7.3f} s ({dt / t_read:6.1f} x read)")
    t0 = time.perf_counter()
    for s in seqs:
        detection_ap_2d(labels[s], labels[s])
    dt = time.perf_counter() - t0
    print(f"{'2D AP, 6 configurations':44s} {dt:7.3f} s ({dt / t_read:6.1f} x read)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
