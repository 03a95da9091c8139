"""The tracker scored on real PointRCNN detections (issues #14 and #25): the splits and the
table of ``bench/bench_tracker.py compare``, which ``bench/bench_ab3dmot.py`` prints AB3DMOT's
rows in, scored by the same code.

It composes the tracker's offline core and the evaluation package's KITTI tracking metrics, so it
lives here, where packages meet. ``dets`` is a folder of PointRCNN detection files
(``../shared/kitti/detections/pointrcnn_Car_val``), ``labels`` the tracking labels
(``.../tracking/training/label_02``).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from tracker_node.config import TrackerConfig
from tracker_node.detection_files import read_detection_file
from tracker_node.offline import find_calib_dir, run

#: the usual KITTI tracking validation split, the sequences of it that are here
VAL = ["0001", "0006", "0008", "0010", "0012", "0013"]
# Split fixed before any tuning: DEV = the KITTI validation sequences present here (report only);
# TUNE = the other shared sequences with labels and detections (training split; tune only).
DEV = VAL
TUNE = ["0000", "0002", "0004", "0005", "0007", "0009", "0011", "0017", "0020"]
#: Fixed score threshold stated before tuning: rows count when their track's mean score >= this
#: (PointRCNN score scale; the evaluator's track-mean rule).
FIXED_THRESHOLD = 3.0
SIMILARITY_LABELS = {"iou3d": "3D IoU", "iou2d": "2D IoU"}


def score_results(res_dir: Path, labels: Path, seqs: list[str], similarity: str = "iou3d") -> dict:
    """The issue #14 figures of one result folder, as ``evaluate tracking --similarity
    SIMILARITY`` computes them (every metric, HOTA included, with that similarity; Car, 3D IoU
    0.25 or 2D IoU 0.5): ``best`` = best-threshold CLEAR-MOT, sAMOTA and HOTA (HOTA on all
    rows), ``none`` = CLEAR-MOT with no threshold, ``fixed`` = CLEAR-MOT at FIXED_THRESHOLD
    (tracks whose mean score is below it removed)."""
    from eval_node.tracking_metrics import evaluate_tracking_dirs, track_mean_scores
    from vehicle_common.kitti import read_tracking_labels, write_tracking_labels

    sim = {"similarity": similarity, "hota_similarity": similarity}
    full = evaluate_tracking_dirs(res_dir, labels, seqs=seqs, **sim)["total"]
    with tempfile.TemporaryDirectory() as fixed_dir:
        for s in seqs:
            pred = track_mean_scores(read_tracking_labels(Path(res_dir) / f"{s}.txt"))
            kept = [o for objs in pred.values() for o in objs if o.score >= FIXED_THRESHOLD]
            write_tracking_labels(Path(fixed_dir) / f"{s}.txt", kept)
        fixed = evaluate_tracking_dirs(fixed_dir, labels, seqs=seqs, hota=False, **sim)
    return {"best": full, "none": full["all_rows"], "fixed": fixed["total"]["all_rows"]}


def sequence_frames(dets: Path, seqs: list[str]) -> int:
    """Frames tracked in ``seqs`` (0 .. the last frame with a detection)."""
    return sum(int(read_detection_file(Path(dets) / f"{s}.txt").frame.max()) + 1 for s in seqs)


def compare_modes(
    cfg: TrackerConfig,
    dets: Path,
    labels: Path,
    seqs: list[str],
    lookahead: int = 0,
    similarities=("iou3d",),
) -> dict:
    """:func:`score_results` of one mode of ``tracker_offline`` per similarity (keys
    ``similarities``), with the tracking time (``seconds``, file I/O included) and ``frames``."""
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run(Path(dets), Path(tmp), seqs, cfg, find_calib_dir(Path(dets)), lookahead)
        elapsed = time.perf_counter() - t0
        out = {sim: score_results(Path(tmp), labels, seqs, sim) for sim in similarities}
    return {**out, "seconds": elapsed, "frames": sequence_frames(dets, seqs)}


def compare_row(name: str, r: dict) -> str:
    """One Markdown table row of :func:`score_results`' figures."""
    b, n, f = r["best"], r["none"], r["fixed"]

    def clear(m):
        return f"{100 * m['mota']:.2f} | {m['idsw']} | {m['fp']} | {m['fn']}"

    return (
        f"| {name} | {clear(b)} | {b['frag']} | {100 * b['motp']:.2f} | {100 * b['samota']:.2f} "
        f"| {clear(f)} | {clear(n)} | {100 * b['hota']:.2f} |"
    )


def compare_header(similarity: str) -> str:
    """Header of :func:`compare_row`'s table; every figure uses ``similarity``."""
    return (
        "| mode | best-thr MOTA | IDSW | FP | FN | FRAG | MOTP | sAMOTA "
        f"| MOTA @{FIXED_THRESHOLD:g} | IDSW | FP | FN | MOTA no thr | IDSW | FP | FN "
        f"| HOTA ({SIMILARITY_LABELS[similarity]}) |\n" + "|---|" + "---|" * 16
    )
