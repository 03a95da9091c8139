"""Tracker benchmarks: CLEAR-MOT on real KITTI detections, update speed, simulated filtering.

    python bench/bench_tracker.py mot     [--seqs 1,6,8,10,12,13] [--quick] [--lookahead N]
    python bench/bench_tracker.py compare [NAME=PARAMS.yaml[@LOOKAHEAD] ...] [--only DEV|TUNE]
                                          [--similarity iou3d,iou2d]
    python bench/bench_tracker.py tune    [--params START.yaml] [--seqs 0,2,...] [--rounds 1]
    python bench/bench_tracker.py speed
    python bench/bench_tracker.py sim
    python bench/bench_tracker.py real   [--source stereo,camera,pointrcnn] [--split tuning]
                                         [--set K=V] [--no-camera-motion] [--checkpoint PT]
                                         [--keep-every K] [--seed-offset N] [--json F]
                                         [--lost-cars] [--breakdown]
                                         [--ranging-error-scale S [--ranging-error-min-depth Z]]
    python bench/bench_tracker.py graph  OUTPUT/bag [--sequence 0005] [--set K=V]

``mot``: tracker_offline's core over ../shared/kitti/detections/pointrcnn_Car_val, scored with
eval_node.tracking_metrics (KITTI devkit rules; 3D IoU 0.25 and 2D IoU 0.5), per filter x
association x cost, per sequence and total. ``compare``: the issue #14 table (best-threshold,
fixed-threshold and no-threshold CLEAR-MOT, HOTA, sAMOTA; one evaluator, every figure with the
similarity named in the table's title) on DEV and TUNE; AB3DMOT's rows: bench/bench_ab3dmot.py.
``tune``: coordinate descent over TUNE_GRID on the tuning sequences only (DEV refused).
``speed``: Tracker.step time with 20 and 100 vehicles.
``sim``: noisy stereo detections of the labelled cars (sigma_z = z^2 sigma_d / (f B), dropped
detections): mean position error of unfiltered / kalman / particle tracks. ``real``: the
real-motion benchmark (the paper's Table 2 on the labelled KITTI trajectories, stereo error model
measured on KITTI Stereo 2015, and the real PointRCNN detections; see bench/real_motion.py);
``--source camera``: the shipped CNN's measured statistics replayed (bench/camera_stats.py);
every source gets poses_orbslam3 as the camera motion unless ``--no-camera-motion``;
``--keep-every K``: the tracker steps on every K-th frame only, scored on those. ``graph``:
a recorded whole-graph run (``make demo``) on a real sequence: velocity over the ground and the
confirmed rows where no vehicle is; with ``--set`` (any, even ``--set box_gain=1``) also the run
re-tracked offline with the graph's parameters and the overrides.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import tempfile
import time
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
from tracker_node.config import TrackerConfig
from tracker_node.offline import find_calib_dir, run
from tracker_node.tracker import DetectionBatch, Tracker
from tracking_bringup.tracker_scoring import (
    DEV,
    SIMILARITY_LABELS,
    TUNE,
    VAL,
    compare_header,
    compare_modes,
    compare_row,
)

REPO = Path(__file__).resolve().parent.parent
KITTI = REPO.parent / "shared" / "kitti"
DETS = KITTI / "detections" / "pointrcnn_Car_val"
LABELS = KITTI / "tracking" / "training" / "label_02"
CALIB = KITTI / "tracking" / "training" / "calib"
GRAPH_PARAMS = REPO / "src" / "tracking_bringup" / "config" / "pipeline.params.yaml"
#: AB3DMOT's speed on these 2-core machines (shared/notes/kitti-tracking-eval.md; quoted, not run)
AB3DMOT_FPS = 50
KEYS = ("mota", "motp", "idsw", "frag", "fp", "fn", "samota")


def evaluate(
    cfg: TrackerConfig, seqs: list[str], similarities=("iou3d", "iou2d"), lookahead: int = 0
) -> dict:
    from eval_node.tracking_metrics import evaluate_tracking_dirs

    with tempfile.TemporaryDirectory() as tmp:
        run(DETS, Path(tmp), seqs, cfg, find_calib_dir(DETS), lookahead)
        return {
            sim: evaluate_tracking_dirs(tmp, LABELS, seqs=seqs, similarity=sim, hota=False)
            for sim in similarities
        }


def cmd_compare(args) -> None:
    modes = [("online (default)", TrackerConfig(), 0)]
    for spec in args.modes:
        name, _, rest = spec.partition("=")
        path, _, la = rest.partition("@")
        cfg = TrackerConfig.from_yaml(path) if path else TrackerConfig()
        modes.append((name, cfg, int(la or 0)))
    sims = args.similarity.split(",")
    for set_name, seqs in (("DEV (report)", DEV), ("TUNE (tuning only)", TUNE)):
        if args.only and args.only not in set_name:
            continue
        rows = {sim: [] for sim in sims}
        for name, cfg, la in modes:
            label = f"{name}, LOOK-AHEAD {la}" if la else name
            r = compare_modes(cfg, DETS, LABELS, seqs, la, sims)
            fps = r["frames"] / r["seconds"]
            for sim in sims:
                rows[sim].append(
                    compare_row(label, r[sim]) + f"  <!-- tracker_offline incl. file I/O: "
                    f"{r['frames']} frames in {r['seconds']:.1f} s = {fps:.0f} frames/s, "
                    f"{fps / AB3DMOT_FPS:.1f}x AB3DMOT's ~{AB3DMOT_FPS} frames/s here -->"
                )
        for sim in sims:
            print(
                f"\n{set_name}: sequences {','.join(seqs)}; every figure {SIMILARITY_LABELS[sim]}"
            )
            print(compare_header(sim))
            print("\n".join(rows[sim]))
        sys.stdout.flush()


def fmt(m: dict) -> str:
    a = m["all_rows"]
    return (
        f"MOTA {100 * m['mota']:6.2f}  MOTP {100 * m['motp']:5.2f}  IDSW {m['idsw']:3d}  "
        f"FRAG {m['frag']:3d}  FP {m['fp']:4d}  FN {m['fn']:4d}  sAMOTA {100 * m['samota']:5.2f}"
        f"  | no threshold: MOTA {100 * a['mota']:6.2f} IDSW {a['idsw']} FP {a['fp']} FN {a['fn']}"
    )


def cmd_mot(args) -> None:
    seqs = [f"{int(s):04d}" for s in args.seqs.split(",")]
    base = TrackerConfig()
    combos = [("kalman", "hungarian", "mahalanobis")]
    if not args.quick:
        combos = list(
            itertools.product(
                args.filters.split(","), args.associations.split(","), args.costs.split(",")
            )
        )
    print(f"sequences {','.join(seqs)}; defaults {base}")
    print("reference AB3DMOT (same detections, 3D IoU 0.25, these 6 seqs): MOTA 83.28, MOTP 79.42,")
    print("  IDSW 0, FRAG 7, FP 246, FN 511")
    for flt, assoc, cost in combos:
        cfg = replace(base, filter=flt, association=assoc, cost=cost)
        res = evaluate(cfg, seqs, lookahead=args.lookahead)
        mode = f"LOOK-AHEAD {args.lookahead} frames" if args.lookahead else "online"
        print(f"\n== filter={flt} association={assoc} cost={cost} ({mode})")
        for sim in ("iou3d", "iou2d"):
            r = res[sim]
            print(f"  {sim} total: {fmt(r['total'])}")
            if args.per_seq:
                for s, m in r["per_sequence"].items():
                    print(f"    {s}: {fmt(m)}")
        sys.stdout.flush()


TUNE_GRID = {
    "min_hits": [2, 3],
    "birth_score": [0.0, 1.0, 2.0],
    "confirm_score": [6.0, 10.0, 14.0],
    "score_ramp_hits": [3, 5, 7],
    "max_staleness": [2, 4],
    "association": ["nearest", "hungarian"],
    "mahalanobis_gate": [9.0, 25.0],
    "process_noise": [8.0, 16.0],
}


def tune_objective(m: dict) -> float:
    """Tuning objective: 3D MOTA at the best threshold plus half the 3D MOTA with no threshold
    (the tracker's own output, which HOTA scores)."""
    return m["mota"] + 0.5 * m["all_rows"]["mota"]


def cmd_tune(args) -> None:
    """Coordinate descent over TUNE_GRID on the tuning sequences only (never on DEV)."""
    seqs = [f"{int(s):04d}" for s in args.seqs.split(",")]
    if set(seqs) & set(DEV):
        sys.exit(f"error: --seqs: {sorted(set(seqs) & set(DEV))} are reporting sequences")
    base = TrackerConfig.from_yaml(args.params) if args.params else TrackerConfig()
    best = evaluate(base, seqs, ("iou3d",))["iou3d"]["total"]
    print(f"tuning on {seqs}, baseline: {fmt(best)}")
    for _ in range(args.rounds):
        for name, values in TUNE_GRID.items():
            for v in values:
                if getattr(base, name) == v:
                    continue
                cfg = replace(base, **{name: v}).validate()
                m = evaluate(cfg, seqs, ("iou3d",))["iou3d"]["total"]
                print(f"  {name}={v}: {fmt(m)}  objective {100 * tune_objective(m):.2f}")
                if tune_objective(m) > tune_objective(best):
                    best, base = m, cfg
            print(f"-> {name}={getattr(base, name)}")
            sys.stdout.flush()
    changed = {
        f.name: getattr(base, f.name)
        for f in fields(TrackerConfig)
        if getattr(base, f.name) != getattr(TrackerConfig(), f.name)
    }
    print(f"tuned (changed from the defaults): {changed}\n{fmt(best)}")


def _synthetic_frame(n: int, k: int, rng) -> DetectionBatch:
    x = np.linspace(-15, 15, n)
    z = 10.0 + 50.0 * (np.arange(n) % 10) / 10.0 + 0.5 * k * 0.1 * (np.arange(n) % 3)
    pos = np.column_stack([x, np.full(n, 1.0), z]) + rng.normal(scale=0.1, size=(n, 3))
    bbox = np.column_stack([x * 20 + 600, np.full(n, 150.0), x * 20 + 660, np.full(n, 200.0)])
    return DetectionBatch.create(
        pos, size=np.tile([3.9, 1.6, 1.5], (n, 1)), yaw=np.zeros(n), bbox=bbox, score=np.ones(n)
    )


def _filterpy_ms(n: int, repeats: int = 3) -> float:
    """Baseline: filterpy per-track KalmanFilter objects, predict+update alone, ms per frame."""
    from tracker_node.kalman import filterpy_reference, process_noise, transition

    kfs = [filterpy_reference(np.zeros(3), 2.0, np.eye(3) * 0.25) for _ in range(n)]
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(50):
            for kf in kfs:
                kf.F, kf.Q = transition(0.1), process_noise(0.1, 2.0)
                kf.predict()
                kf.update(np.zeros(3))
        best = min(best, (time.perf_counter() - t0) / 50)
    return 1e3 * best


def cmd_speed(args) -> None:
    rng = np.random.default_rng(0)
    print("Tracker.step (predict, cost, association, update, lifecycle, report), best of 3 runs")
    print("of 180 frames; baseline: filterpy per-track predict+update only (no association)")
    for n in (20, 100):
        frames = [_synthetic_frame(n, k, rng) for k in range(200)]
        base = _filterpy_ms(n)
        print(f"{n:3d} vehicles  filterpy per-track predict+update only: {base:6.3f} ms/frame")
        # two-stage: the tracker_pointrcnn profile's lifecycle, every third detection scoring
        # below birth_score after the tracks are born (so both association stages run)
        low = [replace(f, score=np.where(np.arange(n) % 3 == 0, 0.5, 8.0)) for f in frames]
        two_stage = {"restoration_conf_threshold": 0.9, "birth_score": 1.0, "score_ramp_hits": 7}
        for flt, cost, extra in (
            ("kalman", "mahalanobis", {}),
            ("kalman", "mahalanobis", two_stage),
            ("kalman", "euclidean", {}),
            ("none", "euclidean", {}),
            ("particle", "mahalanobis", {}),
            ("kalman", "giou3d", {}),
        ):
            if cost == "giou3d" and n == 100:
                continue
            seq = [*frames[:20], *low[20:]] if extra else frames
            best = np.inf
            for _ in range(1 if flt == "particle" or cost == "giou3d" else 3):
                trk = Tracker(TrackerConfig(filter=flt, cost=cost, **extra))
                for k in range(20):
                    trk.step(seq[k], 0.1 * k)
                t0 = time.perf_counter()
                for k in range(20, 200):
                    trk.step(seq[k], 0.1 * k)
                best = min(best, (time.perf_counter() - t0) / 180)
            name = f"{cost}{' two-stage' if extra else ''}"
            print(
                f"{n:3d} vehicles  filter={flt:8s} cost={name:21s}: {1e3 * best:6.3f} ms/frame "
                f"= {1 / best:7.0f} frames/s  ({base / (1e3 * best):5.2f}x filterpy)  "
                f"(tracks {len(trk)})"
            )
        sys.stdout.flush()


def cmd_sim(args) -> None:
    from vehicle_common.kitti import read_calib, read_tracking_labels

    rng = np.random.default_rng(0)
    sigma_d, drop = args.sigma_d, args.drop
    results = {}
    for seq in VAL:
        calib = read_calib(CALIB / f"{seq}.txt")
        f, B = calib.fx, calib.baseline
        labels = read_tracking_labels(LABELS / f"{seq}.txt")
        noisy = {}
        for k, objs in labels.items():
            cars = [o for o in objs if o.type == "Car" and 0 < o.location[2] < 60]
            rows = []
            for o in cars:
                c = calib.cam0_to_left(o.centre_of_mass)
                sz = c[2] ** 2 * sigma_d / (f * B)
                # stereo: depth error along the viewing ray; lateral ~ pixel noise
                ray = c / np.linalg.norm(c)
                sxy = c[2] * 1.0 / f
                e = ray * rng.normal(scale=sz) + rng.normal(scale=sxy, size=3) * [1, 1, 0]
                if rng.random() >= drop:
                    cov = sz**2 * np.outer(ray, ray) + sxy**2 * np.diag([1.0, 1.0, 0.0])
                    rows.append((o.track_id, c, c + e, cov + 1e-4 * np.eye(3)))
            noisy[k] = rows
        for flt in ("none", "kalman", "particle"):
            trk = Tracker(TrackerConfig(filter=flt, min_hits=1))
            errs_unf, errs = results.setdefault(flt, ([], []))
            for k in range(max(labels) + 1):
                rows = noisy.get(k, [])
                pos = np.array([r[2] for r in rows]).reshape(-1, 3)
                cov = np.array([r[3] for r in rows]).reshape(-1, 3, 3)
                ts = trk.step(DetectionBatch.create(pos, covariance=cov), 0.1 * k)
                for i in range(len(ts)):
                    j = ts.det_index[i]
                    if j >= 0:
                        errs.append(np.linalg.norm(ts.position[i] - rows[j][1]))
                        errs_unf.append(np.linalg.norm(rows[j][2] - rows[j][1]))
    print(f"sigma_d = {sigma_d} px, drop rate {drop}; val seqs {','.join(VAL)}; matched rows")
    for flt, (unf, err) in results.items():
        print(
            f"  {flt:8s}: mean position error {np.mean(err):.3f} m (median {np.median(err):.3f})"
            f"  vs raw detections {np.mean(unf):.3f} m"
            f"  -> {100 * (1 - np.mean(err) / np.mean(unf)):+.1f} %"
        )


def _overrides(pairs: list[str] | None) -> dict:
    """``--set NAME=VALUE`` pairs as TrackerConfig field values (typed as the field)."""
    base, out = TrackerConfig(), {}
    for kv in pairs or []:
        name, value = kv.split("=", 1)
        out[name] = type(getattr(base, name))(
            value if not isinstance(getattr(base, name), bool) else value == "true"
        )
    return out


def cmd_real(args) -> None:
    import real_motion as rm

    tune, report = rm.split_sequences()
    if args.seqs:
        report = [f"{int(s):04d}" for s in args.seqs.split(",")]
    print(f"tuning sequences (not reported): {','.join(tune)}")
    print(f"reporting sequences: {','.join(report)}")
    base = TrackerConfig()
    overrides = _overrides(args.set)
    # the stereo detections are tracked with the graph's parameters, PointRCNN's with the
    # TrackerConfig defaults (tracker_offline's)
    configs = {
        "stereo": replace(TrackerConfig.from_yaml(GRAPH_PARAMS), **overrides),
        "camera": replace(TrackerConfig.from_yaml(GRAPH_PARAMS), **overrides),
        "pointrcnn": replace(base, **overrides),
    }
    filters = args.filters.split(",")
    figures: dict = {}
    splits = {"tuning": tune, "reporting": report}
    if args.split != "both":
        splits = {args.split: splits[args.split]}
    for source in args.source.split(","):
        cfg = configs[source]
        print(f"\n[{source}] tracker configuration: {cfg}")
        if source in ("stereo", "camera"):
            model = rm.measure_stereo_model()
            dm = rm.DetectionModel(
                ranging_error_scale=args.ranging_error_scale,
                ranging_error_min_depth=args.ranging_error_min_depth,
            )
            print(f"detection model: {dm}")
        if source == "camera":
            import camera_stats

            cam = rm.CameraDetectionModel(camera_stats.measure(args.checkpoint))
            camera_stats.print_stats(camera_stats.measure(args.checkpoint, verbose=False))
        motion = "off" if args.no_camera_motion else "poses_orbslam3"
        print(f"camera motion given to the tracker: {motion}")
        for split, seqs in splits.items():
            t0 = time.perf_counter()
            if source == "stereo":
                datas = [
                    rm.stereo_sequence(s, model, dm, seed=int(s) + args.seed_offset) for s in seqs
                ]
            elif source == "camera":
                datas = [
                    rm.camera_sequence(s, model, cam, dm, seed=int(s) + args.seed_offset)
                    for s in seqs
                ]
            else:
                datas = [rm.pointrcnn_sequence(s) for s in seqs]
            datas = [rm.with_camera_motion(d) for d in datas]
            if args.cold_start:
                datas = [p for d in datas for p in rm.segments(d, args.cold_start)]
                split = f"{split} (cold starts every {args.cold_start} frames)"
            if args.keep_every > 1:
                datas = [replace(d, keep_every=args.keep_every) for d in datas]
                split = (
                    f"{split} (tracker steps on frames k % {args.keep_every} == 0, camera motion "
                    "composed over the frames dropped; scored on the frames kept)"
                )
            ap, stats, times = rm.evaluate_split(
                datas, cfg, filters, use_camera_motion=not args.no_camera_motion, hota=True
            )
            rm.print_ap(f"[{source}] {split} sequences {','.join(seqs)}", ap)
            rm.print_bars(source, ap)
            if source != "pointrcnn":
                rm.print_covariance_check(datas)
            rm.print_motion(stats, times)
            rm.print_tracking_summary(stats, bars=source == "camera" and split == "reporting")
            rm.print_orientation(stats)
            if args.lost_cars:
                rm.print_lost_cars(stats)
            if args.breakdown:
                rm.print_breakdown(stats)
            print(f"  ({time.perf_counter() - t0:.0f} s)")
            figures[f"{source}/{split}"] = {
                flt: rm.summary_figures(st, ap.get(flt)) for flt, st in stats.items() if st
            }
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
        print(f"figures written to {args.json}")


_VEHICLES = ("Car", "Van", "Truck", "Tram")


def _sort_track_rows(f, right: float, labelled_near: dict, false_rows: list, leaving: list) -> int:
    """Sort frame ``f``'s track rows away from every labelled vehicle into ``false_rows`` and
    ``leaving`` (at the image border, on a labelled car 1-2 frames before; ``labelled_near``:
    track id -> last frame near a label, updated); returns the rows projected outside the
    image."""
    anything = [o for o in f.gt if o.type in _VEHICLES]
    boxes = [o.bbox for o in f.gt if o.type in _VEHICLES or o.is_dontcare]
    centres = np.array([o.centre_of_mass for o in anything]).reshape(-1, 3)
    out_of_view = 0
    for o in f.tracks:
        if o.bbox[2] <= o.bbox[0]:  # projected outside the image: a car that left the view
            out_of_view += 1
            continue
        near = len(centres) and np.linalg.norm(centres - o.centre_of_mass, axis=1).min() < 3.0
        overlap = any(_iou2d(o.bbox, b) >= 0.1 for b in boxes)
        row = (f.frame, o.track_id, [round(float(v), 1) for v in o.location])
        at_border = o.bbox[0] <= 1.0 or o.bbox[2] >= right - 1.0
        if near:
            labelled_near[o.track_id] = f.frame
        elif not overlap and at_border and f.frame - labelled_near.get(o.track_id, -99) <= 2:
            # a labelled car leaving the view: KITTI stops labelling it while a sliver of
            # it is still in the image
            leaving.append(row)
        elif not overlap:
            false_rows.append(row)
    return out_of_view


def _add_ground_errors(f, v_ground: dict, ground_err: dict) -> None:
    """The velocity-over-the-ground errors [m/s] (x-z) of frame ``f``'s tracks matched within
    3 m to a labelled car, against each pose source's ground truth."""
    from scipy.optimize import linear_sum_assignment

    cars = [o for o in f.gt if o.type == "Car" and o.location[2] > 0]
    if not cars or not f.tracks:
        return
    g = np.array([o.centre_of_mass for o in cars])
    t = np.array([o.centre_of_mass for o in f.tracks])
    dist = np.linalg.norm(t[:, None] - g[None], axis=-1)
    r, c = linear_sum_assignment(np.where(dist < 3.0, dist, 1e6))
    for i, j in zip(r, c, strict=True):
        if dist[i, j] >= 3.0:
            continue
        vg = f.track_ground_velocities[i]
        for name, table in v_ground.items():
            vw = table.get((f.frame, cars[j].track_id))
            if vw is not None and np.isfinite(vg).all():
                ground_err[name].append(float(np.linalg.norm((vg - vw)[[0, 2]])))


def cmd_graph(args) -> None:
    """A recorded whole-graph run (``make demo`` output) on a real sequence: velocity over the
    ground against the labels (taken to the world with ``poses_orbslam3``, as the real-motion
    benchmark does), and the confirmed / coasting track rows where no vehicle is."""
    import real_motion as rm
    from vehicle_common.bags.reader import BagError
    from vehicle_common.bags.recorded_run import read_run

    bag = Path(args.bag)
    if (bag / "bag").is_dir() and not (bag / "metadata.yaml").exists():
        bag = bag / "bag"  # the demo's output folder
    try:
        run = read_run(bag)
    except BagError as exc:
        sys.exit(f"error: {exc}")
    seq = args.sequence or run.sequence
    gt = {f.frame: f.gt for f in run.frames}
    off = run.frames[0].offset if run.frames else np.zeros(3)
    # the ground truth's velocity over the ground, with two pose sources: the estimated
    # poses_orbslam3, and the graph's own visual odometry (the motions it recorded)
    sources = {"poses_orbslam3": rm.read_poses(seq), "recorded odometry": _recorded_poses(run)}
    v_ground = {
        name: rm.ground_velocities(gt, poses, off)
        for name, poses in sources.items()
        if poses is not None
    }
    ground_err = {name: [] for name in v_ground}
    false_rows, rows, out_of_view, leaving = [], 0, 0, []
    # the image's right border (labels are clipped to the image): the widest labelled box edge
    right = max((o.bbox[2] for f in run.frames for o in f.gt), default=1241.0)
    labelled_near: dict[int, int] = {}  # track id -> last frame it was within 3 m of a label
    for f in run.frames:
        rows += len(f.tracks)
        out_of_view += _sort_track_rows(f, right, labelled_near, false_rows, leaving)
        _add_ground_errors(f, v_ground, ground_err)
    print(f"{run.path}: sequence {seq}, {len(run.frames)} frames, {rows} output track rows")
    for name, errs in ground_err.items():
        ge = np.array(errs)
        if not len(ge):
            print(f"velocity over the ground ({name}): no matched row carries it")
            continue
        print(
            f"velocity over the ground (x-z), tracks within 3 m of a labelled car: RMSE "
            f"{np.sqrt(np.mean(ge**2)):.2f} m/s, median {np.median(ge):.2f} m/s (n = {len(ge)}; "
            f"ground truth: labels taken to the world with {name})"
        )
    print(
        f"confirmed / coasting rows where no vehicle is (> 3 m from every labelled vehicle and "
        f"2D IoU < 0.1 with every vehicle or DontCare box): {len(false_rows)}; rows at the "
        f"image border continuing a track that was on a labelled car 1-2 frames before (the car "
        f"leaving the view, no longer labelled): {len(leaving)}; coasting rows projected "
        f"outside the image (no 2D box: a car that left the view): {out_of_view}"
    )
    for fr, tid, loc in false_rows:
        print(f"  frame {fr} track {tid} at {loc} (camera 0, bottom centre)")
    for fr, tid, loc in leaving:
        print(f"  leaving the view: frame {fr} track {tid} at {loc}")
    if args.set is not None:
        _retrack(run, gt, _overrides(args.set))


def _retrack(run, gt, overrides: dict) -> None:
    """The recorded tracks and the recorded 3D arrays re-tracked offline with the graph's
    parameters (``GRAPH_PARAMS``) and ``overrides``: CLEAR-MOT / HOTA, 2D and 3D IoU."""
    from eval_node.bag_evaluation import tracking_scores
    from eval_node.filter_comparison import run_tracker
    from vehicle_common.bags.recorded_run import OUTPUT_STATES

    config = replace(TrackerConfig.from_yaml(GRAPH_PARAMS), **overrides)
    runs = {
        "recorded": {f.frame: f.tracks for f in run.frames},
        f"re-tracked {overrides}": run_tracker(run, config, states=OUTPUT_STATES),
    }
    for name, tracks in runs.items():
        m = tracking_scores(gt, tracks)
        m3 = m["iou3d"]
        print(
            f"{name}: MOTA / HOTA (2D IoU) {100 * m['mota']:.1f} / {100 * m['hota']:.1f}, "
            f"recall / precision {100 * m['recall']:.2f} / {100 * m['precision']:.2f} %, "
            f"MOTA (3D IoU 0.25) / HOTA (3D IoU) {100 * m3['mota']:.1f} / {100 * m3['hota']:.1f}"
        )


def _recorded_poses(run) -> list | None:
    """Left-camera poses (``X_first = R X_k + t``) chained from the camera motions the 3D
    arrays recorded (a frame without one repeats the previous); None when none is recorded."""
    from tracker_node.conversions import camera_motion_from_msg

    R, t, last, poses = np.eye(3), np.zeros(3), None, []
    for k, f in enumerate(run.frames):
        m = camera_motion_from_msg(f.det3d_msg)[0] if f.det3d_msg is not None else None
        last = m or last
        if k and last is not None:  # X_{k-1} = M' (X_k - m)
            R, t = R @ last.rotation.T, t - R @ last.rotation.T @ last.translation
        poses.append((R.copy(), t.copy()))
    return poses if last is not None else None


def _iou2d(a, b) -> float:
    x1, y1 = max(a[0], b[0]), max(a[1], b[1])
    x2, y2 = min(a[2], b[2]), min(a[3], b[3])
    inter = max(x2 - x1, 0.0) * max(y2 - y1, 0.0)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("mot")
    m.add_argument("--seqs", default=",".join(VAL))
    m.add_argument("--quick", action="store_true", help="only the default configuration")
    m.add_argument("--per-seq", action="store_true")
    m.add_argument("--lookahead", type=int, default=0, help="look-ahead frames (0 = online)")
    m.add_argument("--filters", default="none,kalman,particle")
    m.add_argument("--associations", default="nearest,hungarian")
    m.add_argument("--costs", default="mahalanobis", help="e.g. mahalanobis,euclidean,iou2d,giou3d")
    c = sub.add_parser("compare", help="issue #14 table: DEV and TUNE, every threshold rule")
    c.add_argument(
        "modes", nargs="*", help="extra modes NAME=PARAMS.yaml[@LOOKAHEAD] (default mode first)"
    )
    c.add_argument("--only", help="DEV or TUNE")
    c.add_argument(
        "--similarity", default="iou3d", help="iou3d and/or iou2d, comma separated (one table each)"
    )
    t = sub.add_parser("tune")
    t.add_argument("--seqs", default=",".join(TUNE))
    t.add_argument("--params", help="start from this parameter file")
    t.add_argument("--rounds", type=int, default=1, help="passes over the grid")
    sub.add_parser("speed")
    s = sub.add_parser("sim")
    s.add_argument("--sigma-d", type=float, default=0.5, help="disparity noise [px]")
    s.add_argument("--drop", type=float, default=0.1, help="fraction of dropped detections")
    r = sub.add_parser("real")
    r.add_argument(
        "--source",
        default="stereo,pointrcnn",
        help="stereo (stated detection model), camera (the shipped CNN's measured statistics, "
        "bench/camera_stats.py), pointrcnn",
    )
    r.add_argument("--checkpoint", default="", help="camera: detector checkpoint ('' = shipped)")
    r.add_argument(
        "--no-camera-motion",
        action="store_true",
        help="do not give the tracker the camera's motion (poses_orbslam3)",
    )
    r.add_argument("--filters", default="none,kalman,particle")
    r.add_argument("--split", default="both", choices=("both", "tuning", "reporting"))
    r.add_argument("--seqs", default="", help="override the reporting sequences")
    r.add_argument("--set", action="append", help="NAME=VALUE tracker parameter override")
    r.add_argument(
        "--lost-cars",
        action="store_true",
        help="print why labelled cars were missed, per cause (eval_node.lost_cars)",
    )
    r.add_argument(
        "--breakdown",
        action="store_true",
        help="print where the velocity error and the position jitter are: a track's first "
        "frames or later, by depth, by the car's speed (real_motion.breakdown)",
    )
    r.add_argument(
        "--cold-start",
        type=int,
        default=0,
        metavar="N",
        help="cut each sequence into pieces of N frames, each tracked from a fresh tracker "
        "(the start-up transient; 0 = whole sequences)",
    )
    r.add_argument(
        "--keep-every",
        type=int,
        default=1,
        metavar="K",
        help="the tracker steps only on frames k %% K == 0 (stamps k x 0.1 s; a camera faster "
        "than the graph), given the camera's motion composed over the frames dropped; every "
        "figure on the frames kept (1 = every frame)",
    )
    r.add_argument(
        "--seed-offset",
        type=int,
        default=0,
        metavar="N",
        help="stereo / camera sources: draw each sequence's detections with seed (sequence "
        "number + N) instead of the sequence number; a paired noise check of a change (0 = the "
        "benchmark's own draws)",
    )
    r.add_argument(
        "--ranging-error-scale",
        type=float,
        default=1.0,
        metavar="S",
        help="stereo / camera sources, a what-if: each 3D position's error times S and its "
        "reported covariance times S^2 (0 = the labelled centre itself; 1 = the measured stereo "
        "model); how the tracking figures depend on the ranging's precision",
    )
    r.add_argument(
        "--ranging-error-min-depth",
        type=float,
        default=0.0,
        metavar="Z",
        help="with --ranging-error-scale: only points at least Z m deep",
    )
    r.add_argument("--json", default="", help="also write the tracking figures, unrounded")
    g = sub.add_parser("graph", help="a recorded whole-graph run on a real sequence")
    g.add_argument("bag", help="the demo's output folder or its bag")
    g.add_argument("--sequence", default="", help="KITTI sequence (default: the recording's)")
    g.add_argument(
        "--set",
        action="append",
        help="NAME=VALUE: also re-track the recorded 3D arrays offline with the graph's "
        "parameters and these overrides, and score both (2D and 3D CLEAR-MOT / HOTA)",
    )
    args = p.parse_args()
    if args.cmd in ("mot", "tune", "compare") and not DETS.is_dir():
        sys.exit(f"error: {DETS}: shared KITTI detections not found")
    if args.cmd == "real" and not args.ranging_error_scale >= 0:
        sys.exit(f"error: --ranging-error-scale: {args.ranging_error_scale} is not >= 0")
    if args.cmd == "real" and args.keep_every < 1:
        sys.exit(f"error: --keep-every: {args.keep_every} is not a positive integer")
    if args.cmd == "real" and not LABELS.is_dir():
        sys.exit(f"error: {LABELS}: shared KITTI tracking labels not found")
    cmds = {"mot": cmd_mot, "tune": cmd_tune, "speed": cmd_speed, "sim": cmd_sim, "real": cmd_real}
    cmds["compare"] = cmd_compare
    cmds["graph"] = cmd_graph
    cmds[args.cmd](args)


if __name__ == "__main__":
    main()
