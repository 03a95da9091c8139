"""AB3DMOT re-scored with this project's evaluator, beside our online tracker (issue #25).

    python bench/bench_ab3dmot.py [--settings 2020[,2022]] [--box2d projection|detection|ours]
                                  [--only DEV|TUNE] [--similarity iou3d,iou2d] [--keep DIR]

Runs AB3DMOT ONLINE (each frame's rows from that frame and earlier ones) over the real PointRCNN
Car detections in ../shared/kitti/detections/pointrcnn_Car_val, writes KITTI tracking result files
(2D box per ``--box2d``, the AB3DMOT score column = the track's last matched detection's score)
and scores them and ``tracker_offline --params tracker_pointrcnn.yaml`` (online) with the same
code as ``evaluate tracking --similarity S`` (every metric, HOTA included, with similarity S):
best-threshold MOTA / IDSW / FP / FN / FRAG / MOTP / sAMOTA, the same at the fixed score threshold
3.0 and with no threshold, and HOTA on all rows (tracking_bringup.tracker_scoring.score_results).

AB3DMOT is the package ``pure-ab-3d-mot`` 2.2.0 (PyPI; Xinshuo Weng's AB3DMOT refactored by Peter
Koval, stated to give the original's results without the ego-motion ("centre of motion")
compensation; MIT licence, as association-quality-clavia). It pins numpy<=2.3.4; it runs
unchanged on this project's numpy 2.4.6, so it is installed without its pins (not a project
dependency):

    pip install --no-deps pure-ab-3d-mot==2.2.0 association-quality-clavia==0.3.2

(scripts/setup.sh does it)

(filterpy and scipy, its other dependencies, are the project's). Without it this script prints
that command and exits with code 2; nothing is downloaded at run time.

Settings (``--settings``; the Kalman filter is the same in both: 10-state constant velocity,
P0 = 10 I with 10^4 on the velocities, Q = I with 0.01 on the velocities, R = I):
- ``2020``: the original 2020 release (AB3DMOT_libs/model.py): Hungarian assignment on 3D IoU,
  pairs below 0.01 rejected, min_hits 3, max_age 2.
- ``2022``: the later code's KITTI PointRCNN Car row (get_param: 'hungar', 'giou_3d', -0.2, 3, 2),
  also the package's defaults.
Both: no ego-motion compensation (the shared data has no OXTS), frames from the sequence's first
to last detection frame as AB3DMOT's main.py, a track is written while unmatched for < max_age
frames and once it has min_hits matches (every track in the first min_hits frames).

``--box2d``: ``projection`` (default): every row's 2D box is the projection of its written 3D box
with the sequence's P2, clipped to 1242 x 375 as tracker_offline clips (a row whose box falls
outside the image is dropped, as tracker_offline drops rows without a 2D box); ``detection``:
AB3DMOT's own writer, the 2D box of the track's last matched detection (stale on coasting rows);
``ours``: tracker_offline's rule, the matched detection's box on rows matched in that frame and
the projection on coasting rows. The PointRCNN files' 2D boxes are the projections of their own
3D boxes (checked: within 0.01 px), so the three differ only by which 3D box is projected.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
KITTI = REPO.parent / "shared" / "kitti"
DETS = KITTI / "detections" / "pointrcnn_Car_val"
LABELS = KITTI / "tracking" / "training" / "label_02"
CALIB = KITTI / "tracking" / "training" / "calib"
PACKAGE_VERSION = "2.2.0"
INSTALL = (
    f".venv/bin/pip install --no-deps pure-ab-3d-mot=={PACKAGE_VERSION} "
    "association-quality-clavia==0.3.2"
)
#: tracker_offline's image size for clipping projected boxes (TrackerConfig defaults)
IMAGE_SIZE = (1242, 375)
BOX2D_MODES = ("projection", "detection", "ours")
#: AB3DMOT on DEV in 3D (3D IoU 0.25, best threshold) with this evaluator, as quoted in
#: ../shared/notes/kitti-tracking-eval.md (its run there, ego-motion off)
REFERENCE_3D = {"mota": 83.28, "fp": 246, "fn": 511, "idsw": 0, "frag": 7}


@dataclass(frozen=True)
class Settings:
    """AB3DMOT's association and lifecycle parameters for KITTI Car."""

    metric: str  # pure_ab_3d_mot.dist_metrics.MetricKind name
    threshold: float  # pairs whose similarity is below this are not matched
    algorithm: str  # pure_ab_3d_mot.matching.MatchingAlgorithm name
    min_hits: int
    max_age: int

    def describe(self) -> str:
        return (
            f"{self.algorithm.lower()} on {self.metric.lower()} >= {self.threshold:g}, "
            f"min_hits {self.min_hits}, max_age {self.max_age}"
        )


SETTINGS = {
    "2020": Settings("IOU_3D", 0.01, "HUNGARIAN", 3, 2),
    "2022": Settings("GIOU_3D", -0.2, "HUNGARIAN", 3, 2),
}


class MissingPackage(RuntimeError):
    """AB3DMOT's package is not installed."""


def require_package() -> None:
    """Raise :class:`MissingPackage` (message: the install command) unless AB3DMOT's package
    and its dependencies import."""
    for module, dist in (
        ("pure_ab_3d_mot", "pure-ab-3d-mot"),
        ("association_quality_clavia", "association-quality-clavia"),
        ("filterpy", "filterpy"),
    ):
        if importlib.util.find_spec(module) is None:
            raise MissingPackage(
                f"{dist} is not installed (AB3DMOT for this benchmark); install it with: {INSTALL}"
            )


def make_tracker(settings: Settings):
    """A fresh ``pure_ab_3d_mot`` tracker with ``settings`` (no ego-motion compensation)."""
    from pure_ab_3d_mot.dist_metrics import MetricKind
    from pure_ab_3d_mot.matching import MatchingAlgorithm
    from pure_ab_3d_mot.tracker import Ab3DMot

    trk = Ab3DMot()
    trk.metric = MetricKind[settings.metric]
    trk.threshold = settings.threshold
    trk.algorithm = MatchingAlgorithm[settings.algorithm]
    trk.min_hits = settings.min_hits
    trk.max_age = settings.max_age
    trk.ego_com = False
    return trk


def track_sequence(rows, settings: Settings, P2: np.ndarray, box2d: str = "projection"):
    """AB3DMOT over one sequence's detection rows (``tracker_node.detection_files.DetectionRows``,
    Car rows used), online, frame by frame. Returns (KITTI result rows, rows dropped because
    their projected 2D box lies outside the image)."""
    from tracker_node.detection_files import TYPE_NAMES
    from vehicle_common.box3d import projected_bbox
    from vehicle_common.kitti import KittiObject

    if box2d not in BOX2D_MODES:
        raise ValueError(f"box2d must be one of {BOX2D_MODES}, got {box2d!r}")
    rows = rows.select(rows.type_id == 2)
    out, dropped = [], 0
    if not len(rows):
        return out, dropped
    trk = make_tracker(settings)
    for frame in range(int(rows.frame.min()), int(rows.frame.max()) + 1):
        sel = rows.frame == frame
        # AB3DMOT's input: dets [h, w, l, x, y, z, rot_y]; info [alpha, type, x1, y1, x2, y2,
        # score] (its main.py's column order)
        dets = np.column_stack([rows.hwl[sel], rows.location[sel], rows.rotation_y[sel]])
        info = np.column_stack(
            [rows.alpha[sel], rows.type_id[sel], rows.bbox[sel], rows.score[sel]]
        )
        result = trk.track({"dets": dets.reshape(-1, 7), "info": info.reshape(-1, 7)})[0]
        matched_now = {t.id for t in trk.trackers if t.time_since_update == 0}
        for r in result:
            hwl, loc, ry = r[0:3], r[3:6], float(r[6])
            tid, alpha, type_id, det_box, score = int(r[7]), r[8], int(r[9]), r[10:14], r[14]
            if box2d == "detection" or (box2d == "ours" and tid in matched_now):
                box = tuple(float(v) for v in det_box)
            else:
                box = projected_bbox(P2, hwl, loc, ry, IMAGE_SIZE)
            if box is None:
                dropped += 1
                continue
            out.append(
                KittiObject(
                    type=TYPE_NAMES[type_id],
                    alpha=float(alpha),
                    bbox=box,
                    dimensions=tuple(float(v) for v in hwl),
                    location=tuple(float(v) for v in loc),
                    rotation_y=ry,
                    frame=frame,
                    track_id=tid,
                    score=float(score),
                )
            )
    return out, dropped


def run_ab3dmot(
    dets_dir: Path,
    calib_dir: Path,
    out_dir: Path,
    seqs: list[str],
    settings: Settings,
    box2d: str = "projection",
) -> dict:
    """AB3DMOT over ``seqs``: writes ``out_dir/SSSS.txt``; returns ``frames``, ``seconds`` (file
    reading, tracking and writing, as bench_tracker times tracker_offline) and ``dropped``."""
    from tracker_node.detection_files import read_detection_file
    from vehicle_common.kitti import read_calib, write_tracking_labels

    frames = dropped = 0
    t0 = time.perf_counter()
    for s in seqs:
        rows = read_detection_file(Path(dets_dir) / f"{s}.txt")
        P2 = read_calib(Path(calib_dir) / f"{s}.txt").P2
        objs, n = track_sequence(rows, settings, P2, box2d)
        write_tracking_labels(Path(out_dir) / f"{s}.txt", objs)
        dropped += n
        frames += int(rows.frame.max()) - int(rows.frame.min()) + 1 if len(rows) else 0
    return {"frames": frames, "seconds": time.perf_counter() - t0, "dropped": dropped}


def reference_check(m3d: dict) -> str:
    """AB3DMOT's DEV 3D figures at the best threshold against :data:`REFERENCE_3D`."""
    got = {
        "mota": round(100 * m3d["mota"], 2),
        "fp": m3d["fp"],
        "fn": m3d["fn"],
        "idsw": m3d["idsw"],
        "frag": m3d["frag"],
    }
    diff = {k: (got[k], v) for k, v in REFERENCE_3D.items() if got[k] != v}
    if not diff:
        return "reference reproduced: " + ", ".join(f"{k} {v}" for k, v in got.items())
    return "reference NOT reproduced: " + ", ".join(
        f"{k} {g} (reference {r})" for k, (g, r) in diff.items()
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--settings", default="2020", help="2020 and/or 2022, comma separated")
    p.add_argument("--box2d", default="projection", choices=BOX2D_MODES)
    p.add_argument("--only", choices=("DEV", "TUNE"), help="one split (default both)")
    p.add_argument("--similarity", default="iou3d,iou2d", help="iou3d and/or iou2d")
    p.add_argument("--keep", help="keep AB3DMOT's result files in DIR/SPLIT_SETTINGS/")
    args = p.parse_args(argv)
    try:
        require_package()
    except MissingPackage as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    settings = {}
    for name in args.settings.split(","):
        if name not in SETTINGS:
            print(f"error: --settings: {name!r} is not one of {sorted(SETTINGS)}", file=sys.stderr)
            return 2
        settings[name] = SETTINGS[name]
    sims = args.similarity.split(",")
    if not sims or not set(sims) <= {"iou3d", "iou2d"}:
        print(f"error: --similarity: {args.similarity!r}: use iou3d and/or iou2d", file=sys.stderr)
        return 2
    import pure_ab_3d_mot
    from tracker_node.config import TrackerConfig

    from tracking_bringup import tracker_scoring as ts

    if not DETS.is_dir() or not CALIB.is_dir() or not LABELS.is_dir():
        print(f"error: {KITTI}: shared KITTI detections/labels not found", file=sys.stderr)
        return 2
    profile = REPO / "src" / "tracking_bringup" / "config" / "tracker_pointrcnn.yaml"
    ours = TrackerConfig.from_yaml(profile)
    print(f"pure-ab-3d-mot {pure_ab_3d_mot.__version__}, numpy {np.__version__}")
    if pure_ab_3d_mot.__version__ != PACKAGE_VERSION:
        print(f"note: the figures in docs/tracker.md are from pure-ab-3d-mot {PACKAGE_VERSION}")
    for name, s in settings.items():
        print(f"AB3DMOT settings {name}: {s.describe()}; 2D boxes: {args.box2d}")
    print(f"ours: tracker_offline --params {profile.relative_to(REPO)} (online)")
    for split, seqs in (("DEV", ts.DEV), ("TUNE", ts.TUNE)):
        if args.only and args.only != split:
            continue
        entries = []
        for name, s in settings.items():
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(args.keep) / f"{split}_{name}" if args.keep else Path(tmp)
                run = run_ab3dmot(DETS, CALIB, out, seqs, s, args.box2d)
                scores = {sim: ts.score_results(out, LABELS, seqs, sim) for sim in sims}
            if run["dropped"]:
                print(f"  AB3DMOT {name}: {run['dropped']} rows outside the image dropped")
            entries.append((f"AB3DMOT {name} settings, online", run, scores))
        r = ts.compare_modes(ours, DETS, LABELS, seqs, 0, sims)
        entries.append(("ours, online: tracker_pointrcnn.yaml", r, r))
        load = os.getloadavg()[0]
        for sim in sims:
            print(
                f"\n{split}: sequences {','.join(seqs)}; every figure {ts.SIMILARITY_LABELS[sim]}"
            )
            print(ts.compare_header(sim))
            for label, _, scores in entries:
                print(ts.compare_row(label, scores[sim]))
        ours_fps = r["frames"] / r["seconds"]
        print(f"\nspeed (file I/O included; load average {load:.1f}):")
        for label, run, _ in entries:
            fps = run["frames"] / run["seconds"]
            print(
                f"  {label}: {run['frames']} frames in {run['seconds']:.1f} s = {fps:.0f} frames/s"
                f" ({fps / ours_fps:.3f}x ours)"
            )
        if split == "DEV" and "iou3d" in sims:
            for label, _, scores in entries[: len(settings)]:  # AB3DMOT's rows
                print(f"{label}: {reference_check(scores['iou3d']['best'])}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
