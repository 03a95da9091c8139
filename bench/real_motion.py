"""The real-motion filter benchmark (the paper's Table 2 on real KITTI trajectories).

Used by ``bench/bench_tracker.py real``. Two detection sources on the labelled KITTI tracking
sequences (real trajectories, real ego-motion, positions in the moving camera-0 frame):

``stereo``: detections made from the ground truth through a stereo error model measured on the
    KITTI Stereo 2015 pairs with the project's default disparity map
    (:func:`measure_stereo_model`: window-level disparity bias and spread per disparity bin,
    piecewise linear between the bins), applied to each labelled car's centre of mass: disparity
    ``d' = d + bias(d) + spread(d) * n`` -> depth ``z' = f B / d'`` along the pixel ray (lateral
    error in proportion), plus the box noise, missed detections and false alarms of
    :class:`DetectionModel` (rates stated there and printed). Each detection carries the
    covariance the ranging reports (``stereo_depth_node.ranging.position_covariance`` with the
    default RangingParams).
``pointrcnn``: the real PointRCNN (LiDAR) detections of ``../shared/kitti/detections``.

Scored with the project's evaluator (``eval_node.detection_metrics.precision_recall``: 3D
localisation AP by centre distance, KITTI difficulties, as ``evaluate`` does) for the raw
detections and the reported tracks of each filter; plus position error, lag (error along the
car's relative motion) and velocity RMSE per relative-speed bucket of the tracks matched to a
labelled car this frame.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from eval_node.detection_metrics import precision_recall
from eval_node.lost_cars import false_tracks
from eval_node.motion_metrics import track_velocities
from eval_node.tracking_metrics import evaluate_tracking_sequences
from scipy.optimize import linear_sum_assignment
from tracker_node.config import TrackerConfig
from tracker_node.detection_files import detection_batch, read_detection_file
from tracker_node.offline import result_rows
from tracker_node.tracker import DetectionBatch, Tracker
from vehicle_common.bags.recorded_run import OUTPUT_STATES, RANKED_STATES
from vehicle_common.kitti import (
    KittiObject,
    alpha_from_rotation_y,
    read_calib,
    read_tracking_labels,
)

KITTI = Path(__file__).resolve().parent.parent.parent / "shared" / "kitti"
TRACKING = KITTI / "tracking" / "training"
POINTRCNN = KITTI / "detections" / "pointrcnn_Car_val"
#: The usual KITTI tracking validation split; the labelled sequences outside it tune, those in
#: it (and 0005, the graph's real sequence) report.
VAL_SPLIT = ("0001", "0006", "0008", "0010", "0012", "0013", "0014", "0015", "0016", "0018", "0019")
GRAPH_SEQUENCE = "0005"
FRAME_PERIOD = 0.1
LEVELS = ("easy", "moderate", "hard")
DISTANCES = (1.5, 3.0)
SPEED_BUCKETS = (0.0, 2.0, 5.0, 10.0, 15.0, math.inf)
MEAN_HWL = (1.53, 1.63, 3.88)


def split_sequences() -> tuple[list[str], list[str]]:
    """(tuning, reporting) sequences among the labelled ones, chosen up front: tuning = outside
    the validation split and not 0005; reporting = the rest."""
    seqs = sorted(p.stem for p in (TRACKING / "label_02").glob("*.txt"))
    tune = [s for s in seqs if s not in VAL_SPLIT and s != GRAPH_SEQUENCE]
    return tune, [s for s in seqs if s not in tune]


# ----------------------------------------------------------------------------- stereo model


@dataclass(frozen=True)
class StereoErrorModel:
    """Window-level disparity error [px] as a function of disparity: piecewise linear through
    the measured bins (``disparity``: each bin's median ground-truth disparity), constant beyond
    the first and last bin."""

    disparity: tuple[float, ...]
    bias_px: tuple[float, ...]
    spread_px: tuple[float, ...]

    def bias(self, d):
        return np.interp(d, self.disparity, self.bias_px)

    def spread(self, d):
        return np.interp(d, self.disparity, self.spread_px)


MODEL_BIN_EDGES = (0, 10, 15, 20, 30, 40, 60, 128)  # [px] ground-truth disparity bins
STEREO_MODELS = ("ranging", "map")  # measure_stereo_model(source=...)


def _map_windows(window: int = 16):
    """(error, truth, column) of the default map's median over ``window`` px windows on one
    surface (ground-truth disparity 10-90th percentile within 10 % of its median, at least a
    fifth of the window with ground truth: the LiDAR truth is sparse)."""
    from stereo_depth_node.disparity import compute_disparity
    from stereo_depth_node.ground_truth import stereo_pairs

    rows = []
    for left, right, gt32 in stereo_pairs(KITTI):
        gt = gt32.astype(np.float64)  # (exact: 1/256 px steps)
        est = compute_disparity(left, right)
        h, w = gt.shape
        for y in range(0, h - window + 1, window):
            for x in range(0, w - window + 1, window):
                g = gt[y : y + window, x : x + window]
                e = est[y : y + window, x : x + window]
                ok = (g > 0) & (e > 0)
                if ok.sum() < window * window // 5:
                    continue
                gm = float(np.median(g[ok]))
                lo, hi = np.percentile(g[ok], [10, 90])
                if hi - lo > 0.1 * gm:
                    continue
                rows.append((float(np.median(e[ok])) - gm, gm, x + window / 2))
    return np.array(rows)


def _ranging_regions():
    """(error, truth, column) of the shipped ranging's disparity on the KITTI 2015 pairs, as
    ``range_boxes`` computes it with the default RangingParams: on car-sized surface regions
    (``stereo_depth_node.ground_truth.surface_regions``) the robust estimate on the default map, the
    full-resolution region refinement (``refine``, coarse disparity <= refine_max_disparity)
    and the KITTI bias model subtracted; the regions are few beyond 30 px (near surfaces), so
    there (truth > refine_max_disparity, where the ranging does not refine) also the map's 16 px
    windows with the bias model subtracted. The robust estimator runs without ground rejection
    and height prior (the regions are not cars)."""
    from stereo_depth_node.disparity import compute_disparity
    from stereo_depth_node.ground_truth import KITTI_GEOMETRY as KITTI_GEO
    from stereo_depth_node.ground_truth import stereo_pairs, surface_regions
    from stereo_depth_node.ranging import (
        RangingParams,
        disparity_bias_at,
        refined_disparity,
        robust_disparity,
    )
    from stereo_depth_node.region_matching import to_gray

    params = RangingParams()
    coarse = replace(params, reject_ground=False, prior_log_sigma=0.0)
    rows = []
    for left, right, gt in stereo_pairs(KITTI):
        disp = compute_disparity(left, right)
        images = (to_gray(left), to_gray(right))
        for box, truth in surface_regions(gt):
            d, _ = robust_disparity(disp, box, KITTI_GEO, coarse)
            if not (np.isfinite(d) and d > 0):
                continue
            u = 0.5 * (box[0] + box[2])
            d = refined_disparity(d, box, images, params)
            d -= float(disparity_bias_at(u, KITTI_GEO, params))
            rows.append((d - truth, truth, u))
    near = _map_windows()
    near = near[near[:, 1] > params.refine_max_disparity]
    near[:, 0] -= disparity_bias_at(near[:, 2], KITTI_GEO, params)
    return np.concatenate([np.array(rows).reshape(-1, 3), near])


def measure_stereo_model(source: str = "ranging", verbose: bool = True) -> StereoErrorModel:
    """Measure a disparity error model on the KITTI Stereo 2015 pairs 0-4: signed error
    (estimate - ground truth) binned by ground-truth disparity; bias = median, spread = 1.4826
    MAD of the bin.

    ``source`` "ranging" (default): the disparity the shipped ranging gives a car-sized region
    on one surface (robust estimate, full-resolution refinement, KITTI bias model subtracted;
    :func:`_ranging_regions`), i.e. the error the tracker's detections really carry.
    "map": the default disparity map's median over 16 px windows with no refinement and no
    bias model (the ranging before issue #13; kept to show what the correction changed)."""
    if source not in STEREO_MODELS:
        raise ValueError(f"stereo model: {source!r} not one of {STEREO_MODELS}")
    rows = _ranging_regions() if source == "ranging" else _map_windows()
    errs, gts = rows[:, 0], rows[:, 1]
    centres, bias, spread = [], [], []
    if verbose:
        what = (
            "shipped ranging (robust + region refinement + KITTI bias model) on car-sized "
            "surface regions"
            if source == "ranging"
            else "default disparity map, 16x16 px windows on one surface, no bias model"
        )
        print(f"stereo error model ({source}): {what}, KITTI Stereo 2015 pairs 0-4 ({len(errs)})")
        print("  GT disparity bin [px] | n | bias (median) [px] | spread (1.4826 MAD) [px]")
    edges = MODEL_BIN_EDGES
    for lo, hi in zip(edges, edges[1:], strict=False):
        m = (gts >= lo) & (gts < hi)
        if m.sum() < 10:
            continue
        e = errs[m]
        med = float(np.median(e))
        mad = 1.4826 * float(np.median(np.abs(e - med)))
        centres.append(float(np.median(gts[m])))
        bias.append(med)
        spread.append(mad)
        if verbose:
            print(f"  {lo:3d}-{hi:3d}               | {m.sum():5d} | {med:+18.3f} | {mad:24.3f}")
    model = StereoErrorModel(tuple(centres), tuple(bias), tuple(spread))
    if verbose:
        knots = ", ".join(
            f"{d:.1f}: {b:+.2f}/{s:.2f}" for d, b, s in zip(centres, bias, spread, strict=True)
        )
        print(f"  model (piecewise linear, disparity px: bias/spread px): {knots}")
    return model


@dataclass(frozen=True)
class DetectionModel:
    """Rates of the simulated stereo detector (stated, not measured)."""

    box_noise_px: float = 2.0  # [px] std of each 2D box edge; the centre ray moves by ~ that/sqrt2
    centre_depth_std: float = 0.3  # [m] box-to-centre (visible surface -> centre) depth error
    miss_rate: float = 0.1  # probability a labelled car is not detected in a frame
    miss_rate_occluded: float = 0.3  # ... when the label says largely occluded (occluded >= 2)
    false_alarms_per_frame: float = 0.2  # Poisson rate; uniform in the image, 5-50 m deep
    min_box_height_px: float = 10.0  # labelled cars with smaller boxes are never detected
    # a what-if of a better ranging (``bench_tracker.py real --ranging-error-scale``): each
    # measured position's error from the true point times this, its reported covariance times
    # its square (at least 0.05^2: a zero covariance would make the filter singular), for
    # points at least ``ranging_error_min_depth`` m deep; 1: the measured stereo model as it is
    ranging_error_scale: float = 1.0
    ranging_error_min_depth: float = 0.0


@dataclass
class SequenceData:
    """One sequence's ground truth and detections (camera-0 frame)."""

    name: str
    gt: dict[int, list[KittiObject]]
    P2: np.ndarray
    frames: list[DetectionBatch]
    det_gt_id: list[np.ndarray]  # per frame, the labelled track id of each detection (-1: none)
    raw: dict[int, list[KittiObject]]  # the detections as KITTI result objects
    errors: list[tuple[float, float, float]]  # (gt depth, measured - true depth, reported std)
    # per frame, the camera's motion since the previous frame (None: unknown / not used)
    motions: list | None = None
    # {(frame, track id): velocity over the ground (3,) in that frame's camera axes} [m/s]
    ground_velocity: dict | None = None
    # the tracker steps on frames k % keep_every == 0 only (a camera faster than the graph),
    # at stamps k x FRAME_PERIOD; every figure is scored on those frames (:meth:`kept`)
    keep_every: int = 1

    def kept(self, frames: dict) -> dict:
        """The entries of ``frames`` (frame -> rows: ``gt``, ``raw``) of the frames the tracker
        steps on."""
        return {k: v for k, v in frames.items() if k % self.keep_every == 0}


# ----------------------------------------------------------------------------- camera poses


def read_poses(seq: str) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """ORB-SLAM3's estimated left-camera poses of ``seq`` (``poses_orbslam3``: ``X_first = R
    X_k + t``), or None when the file is absent."""
    path = TRACKING / "poses_orbslam3" / f"{seq}.txt"
    if not path.is_file():
        return None
    m = np.loadtxt(path).reshape(-1, 3, 4)
    return [(a[:, :3], a[:, 3]) for a in m]


def camera_motions(poses, offset: np.ndarray) -> list:
    """Per frame the camera's motion since the previous one in camera-0 coordinates (the
    benchmark's tracking frame): ``X0_k = M X0_{k-1} + m + M off - off`` with the left camera's
    ``X2_k = M X2_{k-1} + m``, ``M = R_k' R_{k-1}``, ``m = R_k' (t_{k-1} - t_k)``; None for
    frame 0."""
    from vehicle_common.camera_motion import CameraMotion

    out = [None]
    for (R0, t0), (R1, t1) in zip(poses, poses[1:], strict=False):
        M = R1.T @ R0
        m = R1.T @ (t0 - t1)
        out.append(CameraMotion(M, m + M @ offset - offset, FRAME_PERIOD))
    return out


def kept_motion(motions: list, k: int, step: int):
    """The camera's motion from kept frame ``k - step`` to frame ``k`` (every ``step``-th frame
    kept; the per-frame ``motions`` composed over the frames dropped); None before the first."""
    return compose_motions(motions[max(k - step + 1, 0) : k + 1])


def compose_motions(motions: list):
    """The camera's motion over consecutive per-frame ``motions`` (earliest first; each
    ``X_k = M_k X_{k-1} + m_k`` over ``dt_k``): ``X_last = M X_first + m`` with ``M = M_n ..
    M_1``, ``m = M_n (.. (M_2 m_1 + m_2) ..) + m_n``, ``dt`` their sum; None when any is unknown
    (None). One motion is returned as it is."""
    from vehicle_common.camera_motion import CameraMotion

    if not motions or any(m is None for m in motions):
        return None
    if len(motions) == 1:
        return motions[0]
    M, t = np.eye(3), np.zeros(3)
    for m in motions:
        R = np.asarray(m.rotation, float)
        M, t = R @ M, R @ t + np.asarray(m.translation, float)
    dt = sum(float(m.dt) for m in motions) if all(m.dt > 0 for m in motions) else 0.0
    return CameraMotion(M, t, dt, min(int(m.inliers) for m in motions))


def ground_velocities(gt, poses, offset: np.ndarray) -> dict:
    """Velocity over the ground of every labelled car at every frame with a labelled neighbour
    (central difference where both exist), in that frame's camera axes: the labels' centres
    taken to the first frame's coordinates with the same poses the tracker is given (so the
    figure measures the tracker, not the poses)."""
    world = {}
    for k, objs in gt.items():
        if k >= len(poses):
            continue
        R, t = poses[k]
        for o in _cars(objs):
            world[(k, o.track_id)] = R @ (o.centre_of_mass + offset) + t
    out = {}
    for (k, tid), x in world.items():
        before, after = world.get((k - 1, tid)), world.get((k + 1, tid))
        if before is not None and after is not None:
            v = (after - before) / (2 * FRAME_PERIOD)
        elif after is not None:
            v = (after - x) / FRAME_PERIOD
        elif before is not None:
            v = (x - before) / FRAME_PERIOD
        else:
            continue
        out[(k, tid)] = poses[k][0].T @ v
    return out


def with_camera_motion(data: SequenceData) -> SequenceData:
    """``data`` with the poses' camera motions and the ground truth's velocities over the
    ground (unchanged when the sequence has no poses)."""
    poses = read_poses(data.name)
    if poses is None:
        return data
    off = read_calib(TRACKING / "calib" / f"{data.name}.txt").left_camera_offset
    return replace(
        data,
        motions=camera_motions(poses, off)[: len(data.frames)],
        ground_velocity=ground_velocities(data.gt, poses, off),
    )


def segments(data: SequenceData, length: int) -> list[SequenceData]:
    """``data`` cut into consecutive pieces of ``length`` frames (the last may be shorter), each
    re-indexed from frame 0: tracked one by one with a fresh tracker they measure the start-up
    transient of a tracker joining a drive (no track established, scene motion unknown), which
    the full sequences dilute."""
    out = []
    n = len(data.frames)
    for k0 in range(0, n, length):
        ks = range(k0, min(n, k0 + length))
        out.append(
            SequenceData(
                f"{data.name}+{k0}",
                {k - k0: [o.with_(frame=k - k0) for o in data.gt.get(k, [])] for k in ks},
                data.P2,
                [data.frames[k] for k in ks],
                [data.det_gt_id[k] for k in ks],
                {k - k0: [o.with_(frame=k - k0) for o in data.raw.get(k, [])] for k in ks},
                data.errors if k0 == 0 else [],  # the ranging errors once per sequence
                # a fresh tracker has no earlier frame: no motion in its first
                None if data.motions is None else [None] + data.motions[k0 + 1 : ks.stop],
                None
                if data.ground_velocity is None
                else {(k - k0, g): v for (k, g), v in data.ground_velocity.items() if k in ks},
            )
        )
    return out


def _cars(objs):
    return [o for o in objs if o.type == "Car" and o.location[2] > 0]


def _to_objects(batch: DetectionBatch, frame: int) -> list[KittiObject]:
    out = []
    for i in range(len(batch)):
        x, y, z = batch.position[i]
        lwh = batch.size[i] if np.isfinite(batch.size[i]).all() else MEAN_HWL[::-1]
        length, w, h = (float(v) for v in lwh)
        yaw = float(batch.yaw[i]) if np.isfinite(batch.yaw[i]) else -np.pi / 2
        out.append(
            KittiObject(
                type="Car",
                alpha=alpha_from_rotation_y(yaw, x, z),
                bbox=tuple(float(v) for v in batch.bbox[i]),
                dimensions=(h, w, length),
                location=(float(x), float(y + h / 2.0), float(z)),
                rotation_y=yaw,
                frame=frame,
                score=float(batch.score[i]),
            )
        )
    return out


class _Ranger:
    """Stereo ranging of a labelled point through the error model: the disparity at its depth
    with the model's bias and spread, the box-to-centre depth error, the box centre's pixel
    moved by the box noise (the point moves along its ray), and the covariance the ranging
    reports (``stereo_depth_node.ranging.position_covariance``; it refines boxes up to
    refine_max_disparity: disparity_std's ``refined``). ``errors``: (true depth, error,
    reported std) of every measurement."""

    def __init__(self, calib, model: StereoErrorModel, dm: DetectionModel, rng):
        from stereo_depth_node.ranging import RangingParams
        from stereo_depth_node.reprojection import StereoGeometry

        self.calib, self.model, self.dm, self.rng = calib, model, dm, rng
        self.geo = StereoGeometry.from_projections(calib.P2, calib.P3)
        self.rparams = RangingParams()
        self.fB = calib.fx * calib.baseline
        self.errors: list[tuple[float, float, float]] = []

    def covariance(self, u: float, v: float, z: float, d: float) -> np.ndarray:
        from stereo_depth_node.ranging import disparity_std, position_covariance

        sd = disparity_std(d, d <= self.rparams.refine_max_disparity, self.rparams)
        return position_covariance(u, v, z, self.geo, self.rparams, sd)

    def measure(self, c: np.ndarray, du=None, dv=None) -> tuple[np.ndarray, np.ndarray]:
        """(measured point, reported covariance) of the point ``c`` (left optical frame);
        ``du``, ``dv``: the box centre's pixel error (None: drawn from the stated box noise)."""
        calib, model, rng = self.calib, self.model, self.rng
        z = c[2]
        d = self.fB / z
        dm_ = max(d + float(model.bias(d)) + float(model.spread(d)) * rng.normal(), 0.5)
        zm = self.fB / dm_ + rng.normal(scale=self.dm.centre_depth_std)
        s = self.dm.box_noise_px / math.sqrt(2)
        u = calib.fx * c[0] / z + calib.cx + (rng.normal(scale=s) if du is None else du)
        v = calib.fy * c[1] / z + calib.cy + (rng.normal(scale=s) if dv is None else dv)
        R = self.covariance(u, v, zm, dm_)
        p = self.geo.backproject(u, v, zm)
        s = self.dm.ranging_error_scale
        if s != 1.0 and z >= self.dm.ranging_error_min_depth:
            c = np.asarray(c, float)
            p = c + s * (p - c)
            R = max(s, 0.05) ** 2 * R
        self.errors.append((z, float(p[2] - z), float(np.sqrt(R[2, 2]))))
        return p, R


def _batch(pos, cov, bbox, score, bins=None) -> DetectionBatch:
    """One frame's simulated detections (lists) as a DetectionBatch."""
    return DetectionBatch.create(
        np.array(pos).reshape(-1, 3),
        covariance=np.array(cov).reshape(-1, 3, 3),
        bbox=np.array(bbox).reshape(-1, 4),
        score=np.array(score),
        orientation_bin=None if bins is None else np.array(bins, dtype=int),
    )


def stereo_sequence(
    seq: str, model: StereoErrorModel, dm: DetectionModel, seed: int
) -> SequenceData:
    from vehicle_common.box3d import projected_bbox

    rng = np.random.default_rng(seed)
    calib = read_calib(TRACKING / "calib" / f"{seq}.txt")
    gt = read_tracking_labels(TRACKING / "label_02" / f"{seq}.txt")
    ranger = _Ranger(calib, model, dm, rng)
    geo, f, fB = ranger.geo, calib.fx, ranger.fB
    reported_covariance = ranger.covariance

    off = calib.left_camera_offset
    n_frames = max(gt) + 1
    frames, ids, raw = [], [], {}
    for k in range(n_frames):
        pos, cov, bbox, score, gid = [], [], [], [], []
        for o in _cars(gt.get(k, [])):
            if o.height_px < dm.min_box_height_px:
                continue
            miss = dm.miss_rate_occluded if o.occluded >= 2 else dm.miss_rate
            if rng.random() < miss:
                continue
            p, R = ranger.measure(o.centre_of_mass + off)  # left optical frame
            pos.append(p - off)
            cov.append(R)
            bbox.append(np.array(o.bbox) + rng.normal(scale=dm.box_noise_px, size=4))
            score.append(float(np.clip(0.9 - 0.1 * o.occluded + rng.normal(scale=0.05), 0, 1)))
            gid.append(o.track_id)
        for _ in range(rng.poisson(dm.false_alarms_per_frame)):
            zf = rng.uniform(5.0, 50.0)
            u = rng.uniform(50, 1190)
            p = geo.backproject(u, geo.cy + f * 0.9 / zf, zf)  # on the road, centre 0.9 m up
            b = projected_bbox(calib.P2, MEAN_HWL, p - off + [0, 0.75, 0], -np.pi / 2, (1242, 375))
            if b is None:
                continue
            pos.append(p - off)
            cov.append(reported_covariance(u, geo.cy + f * 0.9 / zf, zf, fB / zf))
            bbox.append(np.array(b))
            score.append(float(rng.uniform(0.2, 0.6)))
            gid.append(-1)
        batch = _batch(pos, cov, bbox, score)
        frames.append(batch)
        ids.append(np.array(gid, dtype=int))
        raw[k] = _to_objects(batch, k)
    return SequenceData(seq, gt, calib.P2, frames, ids, raw, ranger.errors)


class CameraDetectionModel:
    """The shipped CNN's measured statistics (:mod:`camera_stats`) as a detector of labelled
    cars: miss rate by box height and occlusion (truncated cars apart), box edge errors and
    scores drawn from the measured ones of the same height bin (bootstrap: their correlations
    and tails kept), orientation bins from the confusion matrix; false positives per frame drawn
    from the measured counts, each a static background object (the measured box and score at
    a depth where its bottom edge meets the road) that is detected again in the next frame with
    the measured probability."""

    CAMERA_HEIGHT = 1.65  # [m] KITTI's camera above the road

    def __init__(self, stats: dict):
        edges = [h if h is not None else math.inf for h in stats["height_bins"]]
        self.edges = np.array(edges)
        found, total = np.array(stats["found"]), np.array(stats["total"])
        per_bin = 1 - found.sum(axis=1) / np.maximum(total.sum(axis=1), 1)
        self.miss = np.where(total >= 5, 1 - found / np.maximum(total, 1), per_bin[:, None])
        tr = stats["truncated"]
        self.miss_truncated = 1 - tr[0] / tr[1] if tr[1] else float(per_bin.mean())
        pooled = [e for es in stats["edge_err"] for e in es]
        self.edge_err = [
            np.array(e if len(e) >= 5 else pooled).reshape(-1, 4) for e in stats["edge_err"]
        ]
        # scores by height bin, not occluded / occluded (occluded cars score lower; a bin with
        # fewer than 5 takes that occlusion class's scores pooled over heights)
        self.tp_score = []
        for key in ("tp_score", "tp_score_occluded"):
            pooled = [s for ss in stats[key] for s in ss]
            self.tp_score.append([np.array(s if len(s) >= 5 else pooled) for s in stats[key]])
        c = np.array(stats["confusion"], float) + 0.5  # (a little smoothing for empty rows)
        self.confusion = c / c.sum(axis=1, keepdims=True)
        col = np.array(stats["confusion"], float).sum(axis=0) + 0.5
        self.fp_bin = col / col.sum()
        self.fp_counts = np.array(stats["fp_counts"])
        self.fp_boxes = np.array(stats["fp_boxes"]).reshape(-1, 4)
        self.fp_scores = np.array(stats["fp_scores"])
        pe = stats["fp_persist"]
        self.fp_persist = pe[0] / pe[1] if pe[1] else 0.0

    def _bin(self, h: float) -> int:
        b = np.searchsorted(self.edges, h, side="right") - 1
        return int(np.clip(b, 0, len(self.miss) - 1))

    def detect(self, o: KittiObject, rng):
        """(box edge errors (4,), score, orientation bin) of a labelled car, or None (missed)."""
        from vehicle_common.orientation_bins import alpha_to_bin

        b = self._bin(o.height_px)
        miss = self.miss_truncated if o.truncated > 0.3 else self.miss[b, min(int(o.occluded), 3)]
        if rng.random() < miss:
            return None
        err = self.edge_err[b][rng.integers(len(self.edge_err[b]))]
        scores = self.tp_score[int(o.occluded >= 1)][b]
        score = float(scores[rng.integers(len(scores))])
        gbin = int(alpha_to_bin(o.alpha)) if o.alpha > -math.pi - 1e-6 else 2
        return err, score, int(rng.choice(4, p=self.confusion[gbin]))

    def new_false_objects(self, rng, n_alive: int, f: float, cx: float, cy: float):
        """New static false objects for this frame, each (pixel centre u, v, depth [m], metric
        half width, half height, score): as many as keep the measured count per frame given the
        ``n_alive`` ones found again."""
        births = max(int(self.fp_counts[rng.integers(len(self.fp_counts))]) - n_alive, 0)
        out = []
        for _ in range(births):
            i = rng.integers(len(self.fp_boxes))
            x1, y1, x2, y2 = self.fp_boxes[i]
            if y2 - cy > 3.0:  # the bottom edge on the road
                z = f * self.CAMERA_HEIGHT / (y2 - cy)
            else:
                z = f * 1.5 / max(y2 - y1, 1.0)  # a 1.5 m tall thing
            z = float(np.clip(z, 3.0, 80.0))
            hw, hh = (x2 - x1) * z / (2 * f), (y2 - y1) * z / (2 * f)
            out.append(((x1 + x2) / 2, (y1 + y2) / 2, z, hw, hh, float(self.fp_scores[i])))
        return out


def camera_sequence(
    seq: str, model: StereoErrorModel, cam: CameraDetectionModel, dm: DetectionModel, seed: int
) -> SequenceData:
    """Detections of the labelled cars of ``seq`` as the shipped CNN makes them (``cam``'s
    measured statistics), ranged with the stereo error model as :func:`stereo_sequence`; false
    positives are static background objects (world-fixed through the estimated camera poses, so
    a false positive found again stands where it stood), with the camera's motion and the
    ground truth's velocities over the ground attached (:func:`with_camera_motion`)."""
    rng = np.random.default_rng(seed)
    calib = read_calib(TRACKING / "calib" / f"{seq}.txt")
    gt = read_tracking_labels(TRACKING / "label_02" / f"{seq}.txt")
    ranger = _Ranger(calib, model, dm, rng)
    f, off = calib.fx, calib.left_camera_offset
    poses = read_poses(seq)
    n_frames = max(gt) + 1
    frames, ids, raw = [], [], {}
    alive = []  # static false objects: (world point (3,), half width, half height, score)
    for k in range(n_frames):
        pos, cov, bbox, score, bins, gid = [], [], [], [], [], []
        for o in _cars(gt.get(k, [])):
            hit = cam.detect(o, rng)
            if hit is None:
                continue
            err, sc, b = hit
            du, dv = (err[0] + err[2]) / 2, (err[1] + err[3]) / 2
            p, R = ranger.measure(o.centre_of_mass + off, du, dv)
            pos.append(p - off)
            cov.append(R)
            bbox.append(np.array(o.bbox) + err)
            score.append(sc)
            bins.append(b)
            gid.append(o.track_id)
        R_k, t_k = poses[k] if poses is not None and k < len(poses) else (np.eye(3), np.zeros(3))
        kept = []
        for xw, hw, hh, sc in alive:  # found again with the measured probability
            if (R_k.T @ (xw - t_k))[2] >= 3.0 and rng.random() < cam.fp_persist:
                kept.append((xw, hw, hh, sc))
        for u, v, z, hw, hh, sc in cam.new_false_objects(rng, len(kept), f, calib.cx, calib.cy):
            kept.append((R_k @ ranger.geo.backproject(u, v, z) + t_k, hw, hh, sc))
        alive = []
        for xw, hw, hh, sc in kept:
            pc = R_k.T @ (xw - t_k)  # left optical frame
            u, v = f * pc[0] / pc[2] + calib.cx, calib.fy * pc[1] / pc[2] + calib.cy
            du, dv = f * hw / pc[2], calib.fy * hh / pc[2]
            if not (0 <= u < 1242 and 0 <= v < 375):
                continue
            alive.append((xw, hw, hh, sc))
            p, R = ranger.measure(pc, 0.0, 0.0)
            pos.append(p - off)
            cov.append(R)
            bbox.append(np.array([u - du, v - dv, u + du, v + dv]))
            score.append(sc)
            bins.append(int(rng.choice(4, p=cam.fp_bin)))
            gid.append(-1)
        batch = _batch(pos, cov, bbox, score, bins)
        frames.append(batch)
        ids.append(np.array(gid, dtype=int))
        raw[k] = _to_objects(batch, k)
    data = SequenceData(seq, gt, calib.P2, frames, ids, raw, ranger.errors)
    return with_camera_motion(data)


def pointrcnn_sequence(seq: str) -> SequenceData:
    calib = read_calib(TRACKING / "calib" / f"{seq}.txt")
    gt = read_tracking_labels(TRACKING / "label_02" / f"{seq}.txt")
    rows = read_detection_file(POINTRCNN / f"{seq}.txt")
    rows = rows.select(rows.type_id == 2)
    n_frames = max(max(gt), int(rows.frame.max()) if len(rows) else 0) + 1
    frames, ids, raw = [], [], {}
    for k in range(n_frames):
        batch = detection_batch(rows.select(rows.frame == k))
        # the labelled car each detection is (centre within 2 m, one-to-one)
        cars = _cars(gt.get(k, []))
        gid = np.full(len(batch), -1)
        if len(cars) and len(batch):
            g = np.array([o.centre_of_mass for o in cars])
            dist = np.linalg.norm(batch.position[:, None] - g[None], axis=-1)
            r, c = linear_sum_assignment(np.where(dist < 2.0, dist, 1e6))
            for i, j in zip(r, c, strict=True):
                if dist[i, j] < 2.0:
                    gid[i] = cars[j].track_id
        frames.append(batch)
        ids.append(gid)
        raw[k] = _to_objects(batch, k)
    return SequenceData(seq, gt, calib.P2, frames, ids, raw, [])


# ----------------------------------------------------------------------------- runs


@dataclass
class MotionStats:
    """Per matched track row: position error, along-motion error, velocity error."""

    pos_err: list
    along: list  # [m] error along the car's relative motion (negative = behind), moving cars
    lag: list  # [m] track minus its detection along the motion (negative = behind it)
    lag_s: list  # [s] the same divided by the relative speed
    vel_err: list
    speed: list
    mot: dict  # CLEAR-MOT totals (KITTI tracking rules, 2D IoU 0.5) and HOTA (2D IoU)
    ground_err: list = field(default_factory=list)  # [m/s] velocity over the ground, x-z error
    ground_speed: list = field(default_factory=list)  # [m/s] the car's true speed over ground
    # (sequence, frame, labelled id, accelerating or braking) of each ground_err row
    ground_keys: list = field(default_factory=list)
    # (track age [frames since its birth, tentative ones too], depth z [m]) of each ground_err row
    ground_detail: list = field(default_factory=list)
    frames: int = 0  # frames tracked
    lost: list = field(default_factory=list)  # eval_node.lost_cars.CarRecord per labelled car
    false: list = field(default_factory=list)  # eval_node.lost_cars.FalseRow per false row
    # orientation of the matched rows: (yaw error [rad] against the label's rotation_y, 4-bin
    # of the implied observation angle right, the car's speed over the ground [m/s] or nan)
    yaw: list = field(default_factory=list)
    mot3: dict = field(default_factory=dict)  # CLEAR-MOT at 3D IoU 0.25 and HOTA on 3D IoU
    # position jitter (eval_node.motion_metrics.matched_jitter) pooled over the sequences:
    # [sum of squared second differences of the tracks, of their cars, triplets]
    jitter: list = field(default_factory=lambda: [0.0, 0.0, 0])
    # each triplet of it: (the car's speed over the ground [m/s] or nan, the track's age [frames]
    # and depth z [m] at the middle frame, the track's second difference [m], the car's [m])
    jitter_rows: list = field(default_factory=list)
    # {(sequence, frame, track id): track age [frames]} of the reported rows (jitter_rows' ages)
    track_age: dict = field(default_factory=dict)
    # the same triplets over the ground (:func:`ground_second_differences`; the camera motions
    # the tracker was given): (the car's speed over the ground [m/s] or nan, the track's second
    # difference [m], the car's labels' [m])
    jitter_ground: list = field(default_factory=list)
    # rows of a car accelerating or braking over the ground (|a| > ACCEL_MIN): (velocity over
    # the ground error [m/s], lag [s] = the error against the acceleration / |a|)
    accel: list = field(default_factory=list)


def run_tracker(
    data: SequenceData, cfg: TrackerConfig, stats: MotionStats | None, use_motion: bool = True
):
    trk = Tracker(cfg, projection=data.P2)
    gt_vel = track_velocities(data.gt, dt=FRAME_PERIOD, axes="xyz")
    gt_pos = {(k, o.track_id): o.centre_of_mass for k, objs in data.gt.items() for o in _cars(objs)}
    gt_obj = {(k, o.track_id): o for k, objs in data.gt.items() for o in _cars(objs)}
    out, ranked = {}, {}
    motions = data.motions if use_motion and data.motions is not None else None
    step = data.keep_every
    for k, batch in enumerate(data.frames):
        if k % step:  # dropped: the camera was faster than the graph
            continue
        # the camera's motion since the previous kept frame (unknown before the first)
        motion = None if motions is None else kept_motion(motions, k, step)
        ts = trk.step(batch, k * FRAME_PERIOD, motion)
        # tracks keep the tracker's own score (PointRCNN's are logits) for the AP ranking, which
        # takes tentative tracks too (at their lowered score, as `evaluate` does); CLEAR-MOT
        # takes the output states (confirmed / coasting) only.
        ranked[k] = result_rows(ts, k, np.zeros(3), RANKED_STATES, mean_hwl=MEAN_HWL)
        out[k] = result_rows(ts, k, np.zeros(3), OUTPUT_STATES, mean_hwl=MEAN_HWL)
        if stats is None:
            continue
        stats.frames += 1
        for tid, age in zip(ts.track_id, ts.age, strict=True):
            stats.track_age[(data.name, k, int(tid))] = int(age)
        for i in np.nonzero(ts.det_index >= 0)[0]:
            if ts.state[i] == 0:
                continue
            g = int(data.det_gt_id[k][ts.det_index[i]])
            if g < 0 or (k, g) not in gt_pos:
                continue
            e = ts.position[i] - gt_pos[(k, g)]
            stats.pos_err.append(float(np.linalg.norm(e)))
            vw = None if data.ground_velocity is None else data.ground_velocity.get((k, g))
            stats.yaw.append(_orientation_row(ts, i, gt_obj[(k, g)], vw))
            if vw is not None and np.isfinite(ts.velocity_over_ground[i]).all():
                ew = (ts.velocity_over_ground[i] - vw)[[0, 2]]
                stats.ground_err.append(float(np.linalg.norm(ew)))
                stats.ground_speed.append(float(np.linalg.norm(vw[[0, 2]])))
                a = _ground_acceleration(data.ground_velocity, k, g, data.motions)
                accelerating = a is not None and np.linalg.norm(a) > ACCEL_MIN
                stats.ground_keys.append((data.name, k, g, accelerating))
                stats.ground_detail.append((int(ts.age[i]), float(ts.position[i][2])))
                if accelerating:
                    an = float(np.linalg.norm(a))
                    stats.accel.append((float(np.linalg.norm(ew)), -float(ew @ a) / an**2))
            vg = gt_vel.get((k, g))
            if vg is None:
                continue
            ve = ts.velocity[i] - vg
            s = float(np.linalg.norm(vg[[0, 2]]))
            stats.vel_err.append(float(np.linalg.norm(ve[[0, 2]])))
            stats.speed.append(s)
            if s > 3.0:
                ed = ts.position[i] - batch.position[ts.det_index[i]]
                lag = float(ed[[0, 2]] @ vg[[0, 2]]) / s
                stats.along.append(float(e[[0, 2]] @ vg[[0, 2]]) / s)
                stats.lag.append(lag)
                stats.lag_s.append(lag / s)
    return ranked, out


#: [m/s^2] a labelled car accelerating or braking (ground speed change over 0.4 s)
ACCEL_MIN = 1.5


def _ground_acceleration(ground_velocity, k: int, g: int, motions: list | None = None):
    """Acceleration over the ground (x, z) [m/s^2] of car ``g`` at frame ``k``: the central
    difference of its ground velocity over frames k-2 .. k+2 (None where either is missing).
    Each velocity is in its own frame's camera axes; with the per-frame camera ``motions`` both
    are first turned into frame k's axes (without, a car at constant speed seen while the camera
    turns would count as accelerating; None where a motion is unknown)."""
    a, b = ground_velocity.get((k - 2, g)), ground_velocity.get((k + 2, g))
    if a is None or b is None:
        return None
    a, b = np.asarray(a, float), np.asarray(b, float)
    if motions is not None:
        before = compose_motions(motions[k - 1 : k + 1])  # frame k-2 -> k
        after = compose_motions(motions[k + 1 : k + 3])  # frame k -> k+2
        if before is None or after is None:
            return None
        a = np.asarray(before.rotation, float) @ a
        b = np.asarray(after.rotation, float).T @ b
    return (b - a)[[0, 2]] / (4 * FRAME_PERIOD)


def _orientation_row(ts, i: int, o: KittiObject, v_ground) -> tuple[float, bool, float]:
    """(yaw error [rad], bin of the implied observation angle right, ground speed [m/s]) of
    track row ``i`` against its labelled car ``o``."""
    from vehicle_common.kitti import wrap_angle
    from vehicle_common.orientation_bins import alpha_to_bin

    x, z = ts.position[i, 0], ts.position[i, 2]
    yaw = float(ts.yaw[i])
    alpha = alpha_from_rotation_y(yaw, x, z)
    right = alpha_to_bin(alpha) == alpha_to_bin(o.alpha)
    speed = math.nan if v_ground is None else float(np.linalg.norm(np.asarray(v_ground)[[0, 2]]))
    return float(wrap_angle(yaw - o.rotation_y)), bool(right), speed


def print_orientation(stats: dict[str, MotionStats]) -> None:
    """Per filter: the tracks' orientation (matched rows) against the labels: 4-bin accuracy of
    the observation angle the track's yaw implies, the share of rows heading the right way
    (|yaw error| < 90 deg) and the median |yaw error|, for cars moving over the ground (> 3
    m/s) and the others."""
    print(
        "  | filter | cars | rows | 4-bin accuracy | heading the right way (|err| < 90 deg) | "
        "median |yaw error| [deg] |"
    )
    for flt, st in stats.items():
        if st is None or not st.yaw:
            continue
        err, right, speed = (np.array(v, float) for v in zip(*st.yaw, strict=True))
        for name, sel in (
            ("moving > 3 m/s", speed > 3.0),
            ("parked / slow", ~(speed > 3.0)),
            ("all", np.ones(len(err), bool)),
        ):
            if not sel.any():
                continue
            e = np.abs(err[sel])
            print(
                f"  | {flt} | {name} | {int(sel.sum())} | {100 * right[sel].mean():.1f} | "
                f"{100 * np.mean(e < math.pi / 2):.1f} | {np.degrees(np.median(e)):.1f} |"
            )
    sys.stdout.flush()


def _ap_table(gt, preds: dict[str, dict]) -> dict[str, dict]:
    res = {}
    for name, pred in preds.items():
        res[name] = {
            (lvl, d): 100
            * precision_recall(
                gt, pred, criterion="centre_distance", threshold=d, difficulty=lvl
            ).ap_r40
            for lvl in LEVELS
            for d in DISTANCES
        }
    return res


def evaluate_split(
    datas: list[SequenceData],
    cfg: TrackerConfig,
    filters,
    motion=True,
    use_camera_motion: bool = True,
    hota: bool = False,
):
    """AP of raw detections and of each filter's tracks over the sequences, plus motion stats
    (``use_camera_motion``: the sequences' camera motions given to the tracker; ``hota``: HOTA
    too, 2D IoU similarity)."""
    gt, preds = {}, {"raw": {}}
    stats, times = {}, {}
    for data in datas:  # scored on the frames the tracker steps on (``keep_every``)
        for k, objs in data.kept(data.gt).items():
            gt[(data.name, k)] = objs
        for k, objs in data.kept(data.raw).items():
            preds["raw"][(data.name, k)] = objs
    gts = {data.name: data.kept(data.gt) for data in datas}
    for flt in filters:
        st = MotionStats([], [], [], [], [], [], {}) if motion else None
        preds[flt] = {}
        per_seq = {}
        t0 = time.perf_counter()
        for data in datas:
            ranked, out = run_tracker(data, replace(cfg, filter=flt), st, use_camera_motion)
            per_seq[data.name] = out
            for k, objs in ranked.items():
                preds[flt][(data.name, k)] = objs
            if st is not None:
                st.lost += sequence_lost_cars(data, ranked, out, cfg.birth_score)
                st.false += false_tracks(data.name, gts[data.name], out)
                # a sequence without poses: its triplets over the ground are NaN, so that
                # st.jitter_ground stays row for row with st.jitter_rows
                motions = (data.motions or []) if use_camera_motion else None
                _add_jitter(st, gts[data.name], out, data.keep_every, data, motions)
        times[flt] = time.perf_counter() - t0
        if st is not None:
            st.mot = evaluate_tracking_sequences(
                gts, per_seq, similarity="iou2d", hota_similarity="iou2d", hota=hota
            )["total"]
            st.mot3 = evaluate_tracking_sequences(
                gts, per_seq, similarity="iou3d", hota_similarity="iou3d", hota=hota
            )["total"]
        stats[flt] = st
    return _ap_table(gt, preds), stats, times


def _add_jitter(
    st: MotionStats,
    gt,
    out,
    keep_every: int = 1,
    data: SequenceData | None = None,
    motions: list | None = None,
) -> None:
    """Pool one sequence's matched-car position jitter into ``st.jitter``: second differences
    over three consecutive frames tracked (``keep_every`` > 1: kept frames, spanning 2 x
    keep_every periods, the labels' over the same frames); with ``data`` also each triplet
    into ``st.jitter_rows`` (the same triplets as ``matched_jitter``), and with the camera
    ``motions`` the tracker was given (per frame, ``motions[k]``: frame k-1 to k) each
    triplet over the ground into ``st.jitter_ground``."""
    from eval_node.motion_metrics import jitter_of_triplets, matched_jitter_triplets

    if keep_every > 1:
        gt = {k // keep_every: v for k, v in gt.items() if k % keep_every == 0}
        out = {k // keep_every: v for k, v in out.items() if k % keep_every == 0}
        if motions is not None:  # the motion between kept frames j-1 and j
            kept = range(0, len(motions), keep_every)
            motions = [kept_motion(motions, k, keep_every) for k in kept]
    triplets = matched_jitter_triplets(gt, out)  # the tracks matched once, for both uses
    j = jitter_of_triplets(triplets)
    if j["n"]:
        st.jitter[0] += j["pred_rms_m"] ** 2 * j["n"]
        st.jitter[1] += j["gt_rms_m"] ** 2 * j["n"]
        st.jitter[2] += j["n"]
    if data is None:
        return
    vg = data.ground_velocity or {}
    speeds = []
    for f, tid, gid, p, d_pred, d_gt in triplets:
        k = f * keep_every
        v = vg.get((k, gid))
        speed = float(np.linalg.norm(np.asarray(v)[[0, 2]])) if v is not None else math.nan
        speeds.append(speed)
        age = st.track_age.get((data.name, k, tid), -1)
        st.jitter_rows.append((speed, age, float(p[1]), d_pred, d_gt))
    if motions is not None:
        ground = ground_second_differences(gt, out, triplets, motions)
        st.jitter_ground += [(s, a, b) for s, (a, b) in zip(speeds, ground, strict=True)]


def ground_second_differences(gt, out, triplets, motions) -> list[tuple[float, float]]:
    """Per triplet of ``eval_node.motion_metrics.matched_jitter_triplets(gt, out)`` (frames
    f-1, f, f+1): the track's and the labelled car's second difference over the ground (x, z
    of frame f's camera) [m], with the positions at f-1 and f+1 carried into frame f's camera by
    the camera ``motions`` (``motions[k]``: ``X_k = R X_{k-1} + t``). A parked car's labels then
    move only by the odometry's error and the labels' own noise; what the track moves beyond
    that is its estimate's. NaN where a motion is unknown."""

    def centres(frames):
        return {
            (k, o.track_id): np.asarray(o.centre_of_mass, float)
            for k, v in frames.items()
            for o in v
        }

    tracks, cars = centres(out), centres(gt)
    res = []
    for f, tid, gid, _, _, _ in triplets:
        ma = motions[f] if f < len(motions) else None
        mb = motions[f + 1] if f + 1 < len(motions) else None
        if ma is None or mb is None:
            res.append((math.nan, math.nan))
            continue
        Ra, ta = np.asarray(ma.rotation, float), np.asarray(ma.translation, float)
        Rb, tb = np.asarray(mb.rotation, float), np.asarray(mb.translation, float)
        row = []
        for pos, i in ((tracks, tid), (cars, gid)):
            a, b, c = pos[(f - 1, i)], pos[(f, i)], pos[(f + 1, i)]
            d2 = Rb.T @ (c - tb) - 2.0 * b + (Ra @ a + ta)  # f-1 and f+1 in frame f's axes
            row.append(float(np.linalg.norm(d2[[0, 2]])))
        res.append(tuple(row))
    return res


def jitter_ratio(st: MotionStats) -> tuple[float, float]:
    """(tracks' RMS second difference [m], ratio to their labelled cars') of ``st``."""
    sp, sg, n = st.jitter
    if not n or sg <= 0:
        return math.nan, math.nan
    return math.sqrt(sp / n), math.sqrt(sp / sg)


def accel_lag(st: MotionStats) -> tuple[float, float, int]:
    """(velocity RMSE over the ground [m/s], mean lag [s], rows) of the accelerating rows."""
    if not st.accel:
        return math.nan, math.nan, 0
    e, lag = np.array(st.accel).T
    return float(np.sqrt(np.mean(e**2))), float(np.mean(lag)), len(e)


def sequence_lost_cars(data: SequenceData, ranked: dict, out: dict, birth_score: float) -> list:
    """:func:`eval_node.lost_cars.lost_cars` of one replayed sequence: its detections are 2D
    and 3D at once (the replay ranges every detection), tentative rows = ranked minus output."""
    from eval_node.lost_cars import lost_cars

    tentative = {}
    for k, rows in ranked.items():
        shown = {o.track_id for o in out.get(k, [])}
        tentative[k] = [o for o in rows if o.track_id not in shown]
    raw = data.kept(data.raw)
    return lost_cars(data.name, data.kept(data.gt), raw, raw, out, tentative, birth_score)


def print_ap(title: str, ap: dict) -> None:
    print(f"\n{title}: 3D localisation AP|R40 (%, KITTI devkit interpolation) by centre distance")
    head = " | ".join(f"{lvl[:3]} @{d:g}m" for d in DISTANCES for lvl in LEVELS)
    print(f"| {'':8s} | {head} |")
    for name, row in ap.items():
        vals = " | ".join(f"{row[(lvl, d)]:9.1f}" for d in DISTANCES for lvl in LEVELS)
        print(f"| {name:8s} | {vals} |")
    sys.stdout.flush()


def bar_checks(source: str, ap: dict) -> list[tuple[str, bool, str]]:
    """Issue #13's part-1 bars on one split's AP table (@1.5 m, every difficulty):
    (bar, holds, margins). Stereo model: Kalman above ``none``; PointRCNN: Kalman not below
    ``none`` by more than 1 point; both: particle within 3 points of Kalman. Bars whose filters
    were not run are left out."""
    out = []

    def margins(a: str, b: str) -> list[float]:
        """a - b per difficulty; a difficulty with no labelled car (NaN) is not checked."""
        return [ap[a][(lvl, 1.5)] - ap[b][(lvl, 1.5)] for lvl in LEVELS]

    def text(m: list[float]) -> str:
        return " / ".join(f"{v:+.1f}" for v in m)

    if "kalman" in ap and "none" in ap:
        m = margins("kalman", "none")
        if source == "stereo":
            out.append(("kalman above none @1.5 m", all(not v <= 0 for v in m), text(m)))
        else:
            out.append(("kalman not below none by > 1 @1.5 m", all(not v < -1 for v in m), text(m)))
    if "kalman" in ap and "particle" in ap:
        m = margins("particle", "kalman")
        out.append(("particle within 3 of kalman @1.5 m", all(not v < -3 for v in m), text(m)))
    return out


def print_bars(source: str, ap: dict) -> None:
    for name, ok, m in bar_checks(source, ap):
        print(f"  bar: {name}: {'holds' if ok else 'FAILS'} (easy / moderate / hard {m})")


def print_motion(stats: dict[str, MotionStats], times: dict[str, float]) -> None:
    print("  tracks matched to a labelled car this frame (relative motion in the camera frame):")
    edges = SPEED_BUCKETS
    labels = [
        f"{lo:g}-{hi:g}" if math.isfinite(hi) else f">={lo:g}"
        for lo, hi in zip(edges, edges[1:], strict=False)
    ]
    print(
        f"  {'filter':8s} | pos err mean/median [m] | along-motion err [m] | "
        "lag behind detection [m] / [s] (speed > 3 m/s) | "
        f"velocity RMSE [m/s] all | "
        + " | ".join(f"{s} m/s (n)" for s in labels)
        + " | MOTA / IDSW (2D IoU 0.5) | time [s]"
    )
    for flt, st in stats.items():
        if st is None:
            continue
        pe, ve, sp = np.array(st.pos_err), np.array(st.vel_err), np.array(st.speed)
        buckets = []
        for lo, hi in zip(edges, edges[1:], strict=False):
            m = (sp >= lo) & (sp < hi)
            buckets.append(
                f"{np.sqrt(np.mean(ve[m] ** 2)):5.2f} ({m.sum()})" if m.any() else "   - (0)"
            )
        along = np.mean(st.along) if st.along else math.nan
        lag = np.mean(st.lag) if st.lag else math.nan
        lag_s = np.mean(st.lag_s) if st.lag_s else math.nan
        print(
            f"  {flt:8s} | {pe.mean():.2f} / {np.median(pe):.2f}           | {along:+.2f}"
            f"                | {lag:+.2f} / {lag_s:+.3f}"
            f"                                  | {np.sqrt(np.mean(ve**2)):5.2f}"
            f"                   | "
            + " | ".join(buckets)
            + f" | {100 * st.mot['mota']:5.1f} / {st.mot['idsw']} | {times[flt]:.1f}"
        )
    sys.stdout.flush()


def summary_figures(st: MotionStats, ap_row: dict | None = None, keyed: bool = True) -> dict:
    """The tracking summary's figures of one filter at full precision (what
    :func:`print_tracking_summary` prints rounded; ``bench_tracker.py real --json``); with
    ``keyed`` also every velocity row with its key."""
    m, a = st.mot, st.mot["all_rows"]
    ge, gs = np.array(st.ground_err), np.array(st.ground_speed)
    parked, moving = gs < 1.0, gs > 3.0
    jit = jitter_ratio(st)
    acc = accel_lag(st)
    out = {
        "mota_all_rows": 100 * a["mota"],
        "mota_best_threshold": 100 * m["mota"],
        "hota_2d": 100 * m.get("hota", math.nan),
        "recall": 100 * (a["tp"] / max(a["tp"] + a["fn"], 1)),
        "precision": 100 * (a["tp"] / max(a["tp"] + a["fp"], 1)),
        "idsw": int(a["idsw"]),
        "false_tracks_per_frame": a["fp"] / max(st.frames, 1),
        "velocity_rmse_ground": float(np.sqrt(np.mean(ge**2))) if len(ge) else math.nan,
        "velocity_rows": len(ge),
        "velocity_rmse_parked": (
            float(np.sqrt(np.mean(ge[parked] ** 2))) if parked.any() else math.nan
        ),
        "velocity_rmse_moving": (
            float(np.sqrt(np.mean(ge[moving] ** 2))) if moving.any() else math.nan
        ),
        # moving cars (relative speed > 3 m/s): the track's mean error along the car's motion
        # (negative: behind it) [m] and its mean lag behind its detection [s]
        "along_moving_m": float(np.mean(st.along)) if st.along else math.nan,
        "lag_behind_detection_s": float(np.mean(st.lag_s)) if st.lag_s else math.nan,
        "mota_3d": 100 * st.mot3.get("all_rows", {}).get("mota", math.nan),
        "hota_3d": 100 * st.mot3.get("hota", math.nan),
        "jitter_m": jit[0],
        "jitter_ratio": jit[1],
        "accel_velocity_rmse": acc[0],
        "accel_lag_s": acc[1],
        "accel_rows": acc[2],
    }
    if keyed:  # per row, for a like-for-like comparison of two runs on the rows both matched
        # [sequence, frame, car, accelerating, error, the car's speed, track age, depth]
        out["velocity_rows_keyed"] = [
            [name, int(k), int(g), int(accelerating), round(e, 4), round(v, 3), age, round(z, 2)]
            for (name, k, g, accelerating), e, v, (age, z) in zip(
                st.ground_keys, st.ground_err, st.ground_speed, st.ground_detail, strict=True
            )
        ]
        # [the car's speed, track age, depth, the track's second difference, the car's]
        out["jitter_rows"] = [
            [round(v, 3), age, round(z, 2), round(dp, 4), round(dg, 4)]
            for v, age, z, dp, dg in st.jitter_rows
        ]
    if ap_row is not None:
        for lvl in LEVELS:
            for d in DISTANCES:
                out[f"ap_{lvl}_{d:g}m"] = float(ap_row[(lvl, d)])
    return out


def print_tracking_summary(stats: dict[str, MotionStats], bars: bool = False) -> None:
    """Per filter: CLEAR-MOT (2D IoU 0.5, KITTI rules) on every output row (what a robot
    receives; ``best``: at the devkit's best score threshold), HOTA (2D IoU similarity, all
    rows), false tracks per frame (output rows matching no labelled car, Van / DontCare
    ignored), velocity RMSE over the ground (x-z; tracks matched to a labelled car this frame);
    with ``bars`` issue 23's bars checked."""
    print(
        "  | filter | MOTA (all rows) | MOTA (best thr.) | HOTA (2D IoU) | recall / precision | "
        "IDSW | false tracks / frame | velocity RMSE over ground [m/s] (n) | parked < 1 m/s: "
        "RMSE | MOTA (3D IoU 0.25, all rows) | HOTA (3D IoU) | position jitter, matched cars: "
        "tracks [m] / ratio to the labels | accelerating / braking cars: velocity RMSE over "
        "ground [m/s], mean lag [s] (n) |"
    )
    for flt, st in stats.items():
        if st is None:
            continue
        f = summary_figures(st, keyed=False)
        mota, hota, rmse = f["mota_all_rows"], f["hota_2d"], f["velocity_rmse_ground"]
        print(
            f"  | {flt} | {mota:.1f} | {f['mota_best_threshold']:.1f} | {hota:.1f} | "
            f"{f['recall']:.1f} / {f['precision']:.1f} | {f['idsw']} | "
            f"{f['false_tracks_per_frame']:.2f} | {rmse:.2f} ({f['velocity_rows']}) | "
            f"{f['velocity_rmse_parked']:.2f} | {f['mota_3d']:.1f} | {f['hota_3d']:.1f} | "
            f"{f['jitter_m']:.3f} / {f['jitter_ratio']:.1f} | "
            f"{f['accel_velocity_rmse']:.2f}, {f['accel_lag_s']:+.2f} ({f['accel_rows']}) |"
        )
        if bars:  # issue 23's, then issue 34's (the CNN graph's bars; this replay stands in)
            checks = [
                ("MOTA >= 60", mota, 60.0, 1),
                ("HOTA >= 50", hota, 50.0, 1),
                ("velocity RMSE over ground <= 2.5 m/s", -rmse, -2.5, -1),
                ("issue 34: MOTA >= 80", mota, 80.0, 1),
                ("issue 34: HOTA >= 65", hota, 65.0, 1),
                ("issue 34: velocity RMSE over ground <= 1.5 m/s", -rmse, -1.5, -1),
            ]
            for name, v, bar, sign in checks:
                ok = v >= bar
                print(f"    bar {name}: {'holds' if ok else 'FAILS'} ({sign * v:.2f})")
    sys.stdout.flush()


def print_lost_cars(stats: dict[str, MotionStats]) -> None:
    """Per filter: why labelled cars were missed, per cause (eval_node.lost_cars)."""
    from eval_node.lost_cars import cause_table, false_track_table

    for flt, st in stats.items():
        if st is not None and st.lost:
            print(f"\n  [{flt}] why labelled cars were missed (2D IoU 0.5, KITTI tracking rules):")
            print("  " + cause_table(st.lost).replace("\n", "\n  "))
        if st is not None and st.false:
            print(f"\n  [{flt}] what the false-positive track rows were:")
            print("  " + false_track_table(st.false).replace("\n", "\n  "))
    sys.stdout.flush()


#: a track's first frames (track age, frames since its birth) and the depth bins of the
#: breakdown (docs/tracker.md, "Where the velocity error is", "Where the position jitter is")
YOUNG_FRAMES = 8
DEPTH_BINS = ((0.0, 30.0), (30.0, 45.0), (45.0, math.inf))
#: shares of the triplets with the largest second differences (``breakdown``'s tail)
JITTER_TAIL = (0.01, 0.05, 0.25)
SPEED_CLASSES = (
    ("parked < 1 m/s", 0.0, 1.0),
    ("1-3 m/s", 1.0, 3.0),
    ("moving > 3 m/s", 3.0, math.inf),
)


def breakdown(st: MotionStats) -> dict:
    """Where the velocity error and the position jitter are: per group of rows (a track's first
    ``YOUNG_FRAMES`` frames or later, by depth; by the car's speed over the ground), the share of
    the rows, the RMSE (velocity) or the ratio to the labels (jitter) and the share of the
    squared error. Returns ``{"velocity": [(group, share, rmse, share_sq)], "jitter": [(group,
    share, ratio, share_sq)], "jitter_tail": [(share of the triplets, share of the squared
    jitter)] of the largest second differences, "jitter_ground": [(cars, triplets, tracks' RMS,
    labels' RMS over the ground, labels' RMS in the camera frame)] [m]}``."""
    out = {"velocity": [], "jitter": [], "jitter_tail": [], "jitter_ground": []}
    if st.ground_err:
        e = np.array(st.ground_err, float)
        age, z = np.array(st.ground_detail, float).reshape(-1, 2).T
        groups = _groups(np.array(st.ground_speed, float), age, z)
        out["velocity"] = _shares(groups, e**2, lambda m: float(np.sqrt(np.mean(e[m] ** 2))))
    if st.jitter_rows:
        v, age, z, dp, dg = np.array(st.jitter_rows, float).T
        out["jitter"] = _shares(
            _groups(v, age, z),
            dp**2,
            lambda m: float(np.sqrt(np.sum(dp[m] ** 2) / max(np.sum(dg[m] ** 2), 1e-12))),
        )
        sq = np.sort(dp**2)[::-1]
        for q in JITTER_TAIL:
            n = max(int(round(q * len(sq))), 1)
            out["jitter_tail"].append((q, float(sq[:n].sum() / max(sq.sum(), 1e-12))))
    if st.jitter_ground:
        v, tr, lab = np.array(st.jitter_ground, float).T
        cam = np.array(st.jitter_rows, float)[:, 4]
        ok = np.isfinite(tr) & np.isfinite(lab)
        for name, lo, hi in SPEED_CLASSES:
            m = ok & (v >= lo) & (v < hi)
            if m.any():
                rms = [float(np.sqrt(np.mean(x[m] ** 2))) for x in (tr, lab, cam)]
                out["jitter_ground"].append((name, int(m.sum()), *rms))
    return out


def _shares(groups, sq: np.ndarray, value) -> list[tuple]:
    """(group, share of the rows, ``value(mask)``, share of ``sq``) of each non-empty group."""
    total = float(np.sum(sq))
    return [
        (name, m.mean(), value(m), float(np.sum(sq[m]) / total)) for name, m in groups if m.any()
    ]


def _groups(speed, age, z):
    yield "every row", np.ones(len(z), bool)
    for young, label in ((True, f"a track's first {YOUNG_FRAMES} frames"), (False, "older tracks")):
        a = age < YOUNG_FRAMES if young else age >= YOUNG_FRAMES
        for lo, hi in DEPTH_BINS:
            rng = f">= {lo:g} m" if hi == math.inf else f"{lo:g}-{hi:g} m"
            yield f"{label}, {rng}", a & (z >= lo) & (z < hi)
    for name, lo, hi in SPEED_CLASSES:
        yield f"cars {name}", (speed >= lo) & (speed < hi)


def print_breakdown(stats: dict[str, MotionStats]) -> None:
    """``bench_tracker.py real --breakdown``: :func:`breakdown` per filter."""
    for flt, st in stats.items():
        if st is None:
            continue
        b = breakdown(st)
        for key, what, fig in (
            ("velocity", "velocity error", "RMSE over the ground [m/s]"),
            ("jitter", "position jitter (matched cars)", "ratio to the labels"),
        ):
            print(f"  {flt}: where the {what} is (track age: frames since birth)")
            print(f"  | rows | share of rows | {fig} | share of the squared error |")
            for name, share, val, sq in b[key]:
                print(f"  | {name} | {100 * share:5.1f} % | {val:5.2f} | {100 * sq:5.1f} % |")
        tail = ", ".join(f"{100 * q:g} %: {100 * sh:.0f} %" for q, sh in b["jitter_tail"])
        if tail:
            print(f"  {flt}: share of the squared jitter in the largest second differences: {tail}")
        if b["jitter_ground"]:
            print(
                f"  {flt}: the same triplets over the ground (frames f-1, f+1 carried into f by "
                "the camera motion the tracker was given; a parked car's labels then move by the "
                "odometry's error and their own noise only)"
            )
            print(
                "  | cars | triplets | tracks [m] | labels over the ground [m] | labels, camera "
                "frame [m] |"
            )
            for name, n, tr, lab, cam in b["jitter_ground"]:
                print(f"  | {name} | {n} | {tr:.3f} | {lab:.3f} | {cam:.3f} |")


def print_covariance_check(datas: list[SequenceData]) -> None:
    """The depth std the ranging reports against the depth error the model makes, per range."""
    e = np.array([x for d in datas for x in d.errors])
    print("  depth error of the stereo detections vs the std the ranging covariance reports:")
    print("  range [m] | n | bias [m] | actual std [m] | actual RMS [m] | reported std [m]")
    for lo, hi in ((0, 10), (10, 20), (20, 30), (30, 45), (45, 60), (60, 100)):
        m = (e[:, 0] >= lo) & (e[:, 0] < hi)
        if m.sum() < 5:
            continue
        err, rep = e[m, 1], e[m, 2]
        print(
            f"  {lo:3d}-{hi:3d}   | {m.sum():5d} | {err.mean():+.2f} | {err.std():.2f} | "
            f"{np.sqrt(np.mean(err**2)):.2f} | {np.median(rep):.2f}"
        )
