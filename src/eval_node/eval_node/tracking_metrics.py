"""Multi-object tracking metrics on KITTI tracking results: CLEAR-MOT under the KITTI tracking
devkit's rules (with AB3DMOT's score-threshold sampling: sAMOTA, AMOTA, AMOTP), HOTA (TrackEval),
and the rotated 3D box IoU used by the 3D variant.

Inputs: ground truth and tracker output per sequence as ``{frame: [KittiObject, ...]}`` (as
:func:`kitti.read_tracking_labels` returns; tracker rows carry ``track_id`` and ``score``; a
missing score counts as 1.0). Rules (KITTI tracking devkit; shared/notes/kitti-tracking-eval.md):

- Class ``cls`` (default Car) is evaluated; ground truth of the neighbouring class (Van) takes part
  in the matching but is ignored; tracker rows of other classes than ``cls``/neighbour are dropped.
- Ground truth counts only when occlusion <= 2 and truncation <= 0 (and 2D height >
  ``gt_min_height`` when given). Default: no height limit on ground truth, as AB3DMOT's
  scripts/KITTI/evaluate.py (compute3rdPartyMetrics ignores ground truth on occlusion, truncation
  and class only; ``min_height`` is tested on tracker boxes). Its reference figures agree: on the
  6 validation sequences 4528 ground-truth boxes count without a height limit (MOTA 83.28 = 1 -
  757 / 4528), 3609 with the 25 px limit shared/notes states. Matching an ignored ground truth is
  neither TP nor FP, missing it is not a FN.
- Unmatched tracker boxes are ignored when they are of the neighbouring class, 2D height <= 25 px,
  or cover a DontCare box (intersection over the tracker box's area > 0.5).
- Per frame, Hungarian matching on ``1 - similarity`` with pairs below ``iou_threshold``
  forbidden (2D IoU 0.5 by default; 3D IoU 0.25 with ``similarity="iou3d"``).
- ID switches, fragmentations and MT/PT/ML (80 % / 20 %) are counted on ground-truth trajectories
  exactly as the devkit's loop does (an ID switch also counts as a fragmentation there; a change
  of id across a gap is a fragmentation only).
- Tracker rows without an id (-1) are dropped, as the devkit does.
- Scores (AB3DMOT's evaluate.py, compute3rdPartyMetrics: ``id_average_score``): every row takes
  its track's mean score in the sequence (``score_mode="track_mean"``; ``"row"`` keeps row
  scores); ``getThresholds`` samples score thresholds at 40 recall points from the scores of all
  matched pairs (ignored ground truth included) over ``num_gt = tp + fn`` with its ignored TPs; a
  threshold drops whole tracks whose mean is below it. The headline figures (``mota``, ``motp``,
  ``fp``...) are those of the threshold with the best MOTA (all rows when no threshold gives
  MOTA > 0, as the devkit's ``best_mota = 0`` start), ``samota``/``amota``/``amotp`` average over
  the recall points.
- MOTP is the devkit's ``total_cost / tp``: the mean similarity over all matched pairs, pairs
  with ignored ground truth included (``tp`` itself counts only non-ignored ground truth here;
  ``itp`` holds the ignored matched pairs).

HOTA follows TrackEval (Luiten et al., IJCV 2021) on the same filtered data: HOTA, DetA, AssA,
LocA averaged over alpha = 0.05 .. 0.95, 2D IoU similarity by default. All figures are fractions.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment
from vehicle_common.box3d import iou_3d as box3d_iou
from vehicle_common.box3d import projected_bbox
from vehicle_common.kitti import KittiFormatError, KittiObject, read_calib, read_tracking_labels

from eval_node.detection_metrics import (
    box_iou_2d,
    box_overlap_over_first,
    boxes_2d,
    sample_thresholds,
)
from eval_node.difficulty import (
    TRACKING_MIN_HEIGHT,
    class_status,
    gt_counted_for_tracking,
)

Frames = Mapping[int, list[KittiObject]]

#: Recall sample points of AB3DMOT's evaluation (41 points, the first (recall 0) dropped).
N_SAMPLE_PTS = 41
#: HOTA's localisation thresholds.
HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)
_MAX_COST = 1e9

# ----------------------------------------------------------------------------- 3D IoU


def iou_3d(a: KittiObject, b: KittiObject) -> float:
    """3D IoU of two KITTI objects (:func:`vehicle_common.box3d.iou_3d`): 1 for identical
    boxes, 0 for invalid sizes."""
    return box3d_iou(
        (a.dimensions, a.location, a.rotation_y), (b.dimensions, b.location, b.rotation_y)
    )


def iou_3d_matrix(a: list[KittiObject], b: list[KittiObject]) -> np.ndarray:
    """Pairwise 3D IoU (N, M); pairs whose footprints cannot touch are skipped (0)."""
    out = np.zeros((len(a), len(b)))
    if not a or not b:
        return out
    ca = np.array([[o.location[0], o.location[2]] for o in a])
    cb = np.array([[o.location[0], o.location[2]] for o in b])
    ra = np.array([0.5 * math.hypot(o.dimensions[1], o.dimensions[2]) for o in a])
    rb = np.array([0.5 * math.hypot(o.dimensions[1], o.dimensions[2]) for o in b])
    near = np.linalg.norm(ca[:, None] - cb[None], axis=-1) <= ra[:, None] + rb[None] + 1e-9
    for i, j in zip(*np.nonzero(near), strict=False):
        out[i, j] = iou_3d(a[i], b[j])
    return out


# ----------------------------------------------------------------------------- per-frame data


def _score(o: KittiObject) -> float:
    return 1.0 if o.score is None else float(o.score)


@dataclass
class _Frame:
    g_ids: list[int]
    g_ign: np.ndarray  # bool: ignored ground truth (neighbour class or not counted)
    t_ids: list[int]  # tracker ids, sorted by score descending
    t_scores: np.ndarray
    t_ign: np.ndarray  # bool: ignored when unmatched (neighbour class, small, DontCare)
    sim: np.ndarray  # (n_g, n_t) similarity of the CLEAR-MOT matching
    hota_sim: np.ndarray | None  # (n_g, n_t) similarity for HOTA (None: HOTA not computed)
    # _FrameResult per number of top-scored tracker rows kept; it depends on that number alone
    # (the IoU threshold is fixed per evaluation), so it stays valid across score thresholds
    cache: dict = field(default_factory=dict)


@dataclass
class _FrameResult:
    tp: int
    fp: int
    fn: int
    itp: int  # matched pairs with ignored ground truth
    sim_sum: float  # similarity over all matched pairs (ignored ground truth included)
    tp_scores: list[float]
    g_tracker: list[int]  # matched tracker id per ground truth, -1 if none
    t_kept: np.ndarray  # bool (n_kept,): tracker counted (not ignored) -- for HOTA
    pairs: list[tuple[int, int]]  # (gt index, tracker column) of the counted TPs


def _prepare_frame(
    gt: list[KittiObject],
    pred: list[KittiObject],
    cls: str,
    similarity: str,
    hota_similarity: str | None,
    gt_min_height: float | None = None,
) -> _Frame:
    """One frame's filtered data; ``hota_similarity`` None skips the HOTA similarity."""
    g = [o for o in gt if not o.is_dontcare and class_status(o.type, cls) >= 0]
    dc = boxes_2d([o for o in gt if o.is_dontcare])
    t = _tracker_rows(pred, cls)
    g_ign = np.array(
        [
            class_status(o.type, cls) == 0 or not gt_counted_for_tracking(o, gt_min_height)
            for o in g
        ],
        dtype=bool,
    )
    tb = boxes_2d(t)
    t_ign = np.array([class_status(o.type, cls) == 0 for o in t], dtype=bool) | (
        np.abs(tb[:, 3] - tb[:, 1]) <= TRACKING_MIN_HEIGHT
    )
    if len(dc) and len(t):
        t_ign |= (box_overlap_over_first(tb, dc) > 0.5).any(axis=1)
    sims = {}
    for kind in {similarity, hota_similarity} - {None}:
        if kind == "iou2d":
            sims[kind] = box_iou_2d(boxes_2d(g), tb)
        elif kind == "iou3d":
            sims[kind] = iou_3d_matrix(g, t)
        else:
            raise ValueError(f"unknown similarity {kind!r} (iou2d or iou3d)")
    return _Frame(
        g_ids=[o.track_id for o in g],
        g_ign=g_ign,
        t_ids=[o.track_id for o in t],
        t_scores=np.array([_score(o) for o in t]),
        t_ign=t_ign,
        sim=sims[similarity],
        hota_sim=None if hota_similarity is None else sims[hota_similarity],
    )


def _match_frame(fr: _Frame, k: int, threshold: float) -> _FrameResult:
    """Devkit frame step with the ``k`` highest-scoring tracker rows."""
    n_g = len(fr.g_ids)
    sim = fr.sim[:, :k]
    g_tracker = [-1] * n_g
    t_matched = np.zeros(k, dtype=bool)
    t_to_ign_gt = np.zeros(k, dtype=bool)
    tp = fn = itp = 0
    sim_sum = 0.0
    tp_scores = []
    pairs = []
    if n_g and k:
        cost = np.where(sim >= threshold, 1.0 - sim, _MAX_COST)
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows.tolist(), cols.tolist(), strict=False):
            if cost[r, c] >= _MAX_COST:
                continue
            g_tracker[r] = fr.t_ids[c]
            t_matched[c] = True
            tp_scores.append(float(fr.t_scores[c]))  # the devkit keeps ignored pairs' too
            sim_sum += float(sim[r, c])  # the devkit's total_cost includes ignored pairs
            if fr.g_ign[r]:
                t_to_ign_gt[c] = True
                itp += 1
            else:
                tp += 1
                pairs.append((r, c))
    for r in range(n_g):
        if g_tracker[r] < 0 and not fr.g_ign[r]:
            fn += 1
    t_kept = ~t_to_ign_gt & (t_matched | ~fr.t_ign[:k])
    fp = int((~t_matched & ~fr.t_ign[:k]).sum())
    return _FrameResult(tp, fp, fn, itp, sim_sum, tp_scores, g_tracker, t_kept, pairs)


def _frame_result(fr: _Frame, threshold_score: float | None, iou_threshold: float):
    if threshold_score is None:
        k = len(fr.t_ids)
    else:
        k = int((fr.t_scores >= threshold_score).sum())
    if k not in fr.cache:
        fr.cache[k] = _match_frame(fr, k, iou_threshold)
    return fr.cache[k]


# ----------------------------------------------------------------------------- CLEAR-MOT


def _trajectory_counts(traj: dict[int, list[int]], ign: dict[int, list[bool]]) -> dict:
    """ID switches, fragmentations and MT/PT/ML of a sequence's ground-truth trajectories
    (the devkit's loop, verbatim in logic)."""
    idsw = frag = mt = pt = ml = 0
    for tid, g in traj.items():
        ign_g = ign[tid]
        if all(ign_g):
            continue
        if all(x == -1 for x in g):
            ml += 1
            continue
        last_id = g[0]
        tracked = 1 if g[0] >= 0 else 0
        f = 0
        for f in range(1, len(g)):
            if ign_g[f]:
                last_id = -1
                continue
            if last_id != g[f] and last_id != -1 and g[f] != -1 and g[f - 1] != -1:
                idsw += 1
            if (
                f < len(g) - 1
                and g[f - 1] != g[f]
                and last_id != -1
                and g[f] != -1
                and g[f + 1] != -1
            ):
                frag += 1
            if g[f] != -1:
                tracked += 1
                last_id = g[f]
        if len(g) > 1 and g[f - 1] != g[f] and last_id != -1 and g[f] != -1 and not ign_g[f]:
            frag += 1
        ratio = tracked / float(len(g) - sum(ign_g))
        if ratio > 0.8:
            mt += 1
        elif ratio < 0.2:
            ml += 1
        else:
            pt += 1
    return {"idsw": idsw, "frag": frag, "mt": mt, "pt": pt, "ml": ml}


def _clear_mot(seqs: list[list[_Frame]], score: float | None, iou_threshold: float) -> dict:
    tot = {"tp": 0, "fp": 0, "fn": 0, "itp": 0, "idsw": 0, "frag": 0, "mt": 0, "pt": 0, "ml": 0}
    sim_sum = 0.0
    tp_scores: list[float] = []
    for frames in seqs:
        traj: dict[int, list[int]] = {}
        ign: dict[int, list[bool]] = {}
        for fr in frames:
            res = _frame_result(fr, score, iou_threshold)
            tot["tp"] += res.tp
            tot["fp"] += res.fp
            tot["fn"] += res.fn
            tot["itp"] += res.itp
            sim_sum += res.sim_sum
            tp_scores += res.tp_scores
            for gid, tid, gi in zip(fr.g_ids, res.g_tracker, fr.g_ign.tolist(), strict=False):
                traj.setdefault(gid, []).append(tid)
                ign.setdefault(gid, []).append(gi)
        for key, v in _trajectory_counts(traj, ign).items():
            tot[key] += v
    return _finish(tot, sim_sum, tp_scores)


def _finish(tot: dict, sim_sum: float, tp_scores: list[float]) -> dict:
    tp, fp, fn = tot["tp"], tot["fp"], tot["fn"]
    n_gt = tp + fn
    out = dict(tot)
    out["n_gt"] = n_gt
    out["n_tr"] = tp + fp
    out["mota"] = 1.0 - (fn + fp + tot["idsw"]) / n_gt if n_gt else math.nan
    n_matched = tp + tot["itp"]
    out["motp"] = sim_sum / n_matched if n_matched else math.nan
    out["recall"] = tp / n_gt if n_gt else math.nan
    out["precision"] = tp / (tp + fp) if tp + fp else math.nan
    n_traj = tot["mt"] + tot["pt"] + tot["ml"]
    for key in ("mt", "pt", "ml"):
        out[key + "_ratio"] = tot[key] / n_traj if n_traj else math.nan
    out["_tp_scores"] = tp_scores
    return out


# ----------------------------------------------------------------------------- HOTA


def _hota_sequence(frames: list[_Frame], iou_threshold: float) -> dict:
    """Per-alpha HOTA components of one sequence (TrackEval's HOTA.eval_sequence) on the data
    left after the KITTI filtering (ignored ground truth and ignored tracker rows removed)."""
    na = len(HOTA_ALPHAS)
    data = []
    gt_index: dict[int, int] = {}
    tr_index: dict[int, int] = {}
    for fr in frames:
        res = _frame_result(fr, None, iou_threshold)
        gk = ~fr.g_ign
        tk = res.t_kept
        gids = np.array([gt_index.setdefault(i, len(gt_index)) for i in np.array(fr.g_ids)[gk]])
        tids = np.array([tr_index.setdefault(i, len(tr_index)) for i in np.array(fr.t_ids)[tk]])
        data.append((gids.astype(int), tids.astype(int), fr.hota_sim[np.ix_(gk, tk)]))
    tp = np.zeros(na)
    fn = np.zeros(na)
    fp = np.zeros(na)
    loc = np.zeros(na)
    ng, nt = len(gt_index), len(tr_index)
    potential = np.zeros((ng, nt))
    gt_count = np.zeros((ng, 1))
    tr_count = np.zeros((1, nt))
    for gids, tids, sim in data:
        if len(gids) and len(tids):
            denom = sim.sum(0)[None, :] + sim.sum(1)[:, None] - sim
            s = np.zeros_like(sim)
            mask = denom > np.finfo(float).eps
            s[mask] = sim[mask] / denom[mask]
            potential[gids[:, None], tids[None, :]] += s
        gt_count[gids] += 1
        tr_count[0, tids] += 1
    global_score = potential / np.maximum(gt_count + tr_count - potential, np.finfo(float).eps)
    matches = np.zeros((na, ng, nt))
    for gids, tids, sim in data:
        if len(gids) == 0:
            fp += len(tids)
            continue
        if len(tids) == 0:
            fn += len(gids)
            continue
        score = global_score[gids[:, None], tids[None, :]] * sim
        rows, cols = linear_sum_assignment(-score)
        msim = sim[rows, cols]
        for a, alpha in enumerate(HOTA_ALPHAS):
            ok = msim >= alpha - np.finfo(float).eps
            n = int(ok.sum())
            tp[a] += n
            fn[a] += len(gids) - n
            fp[a] += len(tids) - n
            if n:
                loc[a] += msim[ok].sum()
                matches[a, gids[rows[ok]], tids[cols[ok]]] += 1
    ass_a = np.zeros(na)
    for a in range(na):
        m = matches[a]
        ass = m / np.maximum(1, gt_count + tr_count - m)
        ass_a[a] = (m * ass).sum() / max(1.0, tp[a])
    return {"tp": tp, "fn": fn, "fp": fp, "loc_sum": loc, "ass_a": ass_a}


def _hota_summary(parts: list[dict]) -> dict:
    """Combine per-sequence HOTA components (TrackEval: sums of TP/FN/FP, AssA weighted by TP)."""
    tp = sum(p["tp"] for p in parts)
    fn = sum(p["fn"] for p in parts)
    fp = sum(p["fp"] for p in parts)
    loc = sum(p["loc_sum"] for p in parts)
    ass = sum(p["ass_a"] * p["tp"] for p in parts) / np.maximum(1.0, tp)
    det_a = tp / np.maximum(1.0, tp + fn + fp)
    hota = np.sqrt(det_a * ass)
    loc_a = np.maximum(1e-10, loc) / np.maximum(1e-10, tp)
    return {
        "hota": float(hota.mean()),
        "deta": float(det_a.mean()),
        "assa": float(ass.mean()),
        "loca": float(loc_a.mean()),
        "detre": float((tp / np.maximum(1.0, tp + fn)).mean()),
        "detpr": float((tp / np.maximum(1.0, tp + fp)).mean()),
        "hota_per_alpha": hota.tolist(),
    }


# ----------------------------------------------------------------------------- public API


def _tracker_rows(pred: list[KittiObject], cls: str) -> list[KittiObject]:
    """Rows of class ``cls`` or its neighbour with a track id, by descending score (stable)."""
    rows = (o for o in pred if o.track_id >= 0 and class_status(o.type, cls) >= 0)
    return sorted(rows, key=lambda o: -_score(o))


def track_mean_scores(pred: Frames) -> dict[int, list[KittiObject]]:
    """A copy of a sequence's tracker output whose rows carry their track's mean score."""
    scores: dict[int, list[float]] = {}
    for objs in pred.values():
        for o in objs:
            scores.setdefault(o.track_id, []).append(_score(o))
    mean = {tid: sum(v) / len(v) for tid, v in scores.items()}
    return {k: [o.with_(score=mean[o.track_id]) for o in objs] for k, objs in pred.items()}


def _prepare_sequences(
    gts: list[Frames],
    preds: list[Frames],
    cls: str,
    similarity: str,
    hota_similarity: str | None,
    score_mode: str = "track_mean",
    gt_min_height: float | None = None,
) -> list[list[_Frame]]:
    if score_mode not in ("track_mean", "row"):
        raise ValueError(f"unknown score_mode {score_mode!r} (track_mean or row)")
    seqs = []
    for gt, pred in zip(gts, preds, strict=True):
        if score_mode == "track_mean":
            pred = track_mean_scores(pred)
        keys = sorted(set(gt) | set(pred))
        seqs.append(
            [
                _prepare_frame(
                    gt.get(k, []), pred.get(k, []), cls, similarity, hota_similarity, gt_min_height
                )
                for k in keys
            ]
        )
    return seqs


def _evaluate(
    seqs: list[list[_Frame]],
    iou_threshold: float,
    n_sample_pts: int,
    hota_parts: list[dict] | None,
) -> dict:
    """CLEAR-MOT figures of ``seqs`` pooled; with ``hota_parts`` (the sequences'
    :func:`_hota_sequence` components) also the HOTA figures."""
    base = _clear_mot(seqs, None, iou_threshold)
    n_gt = base["n_gt"]
    # devkit getThresholds(scores, num_gt): num_gt = tp + fn with the ignored TPs
    num_gt = n_gt + base["itp"]
    thresholds = sample_thresholds(base["_tp_scores"], num_gt, n_sample_pts) if n_gt else []
    thresholds = thresholds[1:n_sample_pts]  # drop the recall-0 sample
    recalls = [(i + 1) / (n_sample_pts - 1.0) for i in range(len(thresholds))]
    best = None
    samota = amota = amotp = 0.0
    for thr, r in zip(thresholds, recalls, strict=False):
        m = _clear_mot(seqs, thr, iou_threshold)
        m["score_threshold"] = thr
        if best is None or m["mota"] > best["mota"]:
            best = m
        errors = m["fn"] + m["fp"] + m["idsw"]
        samota += min(1.0, max(0.0, 1.0 - (errors - (1.0 - r) * n_gt) / (r * n_gt)))
        amota += m["mota"]
        amotp += 0.0 if math.isnan(m["motp"]) else m["motp"]
    if best is None or not best["mota"] > 0.0:  # devkit: best_mota = 0, threshold -10000
        best = dict(base)
        best["score_threshold"] = None
    denom = n_sample_pts - 1.0
    out = {k: v for k, v in best.items() if not k.startswith("_")}
    out["samota"] = samota / denom if n_gt else math.nan
    out["amota"] = amota / denom if n_gt else math.nan
    out["amotp"] = amotp / denom if n_gt else math.nan
    out["all_rows"] = {k: v for k, v in base.items() if not k.startswith("_")}
    if hota_parts is not None:
        out.update(_hota_summary(hota_parts))
    return out


def evaluate_tracking(
    gt: Frames,
    pred: Frames,
    *,
    cls: str = "Car",
    similarity: str = "iou2d",
    iou_threshold: float | None = None,
    hota_similarity: str = "iou2d",
    n_sample_pts: int = N_SAMPLE_PTS,
    hota: bool = True,
    score_mode: str = "track_mean",
    gt_min_height: float | None = None,
) -> dict:
    """All tracking metrics of one sequence; see :func:`evaluate_tracking_sequences`."""
    return evaluate_tracking_sequences(
        {"seq": gt},
        {"seq": pred},
        cls=cls,
        similarity=similarity,
        iou_threshold=iou_threshold,
        hota_similarity=hota_similarity,
        n_sample_pts=n_sample_pts,
        hota=hota,
        score_mode=score_mode,
        gt_min_height=gt_min_height,
    )["total"]


def evaluate_tracking_sequences(
    gts: Mapping[Hashable, Frames],
    preds: Mapping[Hashable, Frames],
    *,
    cls: str = "Car",
    similarity: str = "iou2d",
    iou_threshold: float | None = None,
    hota_similarity: str = "iou2d",
    n_sample_pts: int = N_SAMPLE_PTS,
    hota: bool = True,
    score_mode: str = "track_mean",
    gt_min_height: float | None = None,
) -> dict:
    """Tracking metrics per sequence and over all of them: ``{"per_sequence": {seq: m},
    "total": m}``. Sequences missing from ``preds`` count as empty output.

    ``similarity``: ``"iou2d"`` (threshold 0.5 by default) or ``"iou3d"`` (0.25 by default).
    Each ``m`` holds, at the best-MOTA score threshold (``score_threshold``): ``mota``, ``motp``,
    ``tp``, ``fp``, ``fn``, ``idsw``, ``frag``, ``mt``, ``pt``, ``ml`` (counts) and their
    ``*_ratio``, ``precision``, ``recall``, ``n_gt``, ``n_tr``; ``samota``, ``amota``, ``amotp``
    over the recall samples; ``all_rows`` (the same CLEAR-MOT figures without a score threshold);
    with ``hota``: ``hota``, ``deta``, ``assa``, ``loca``, ``detre``, ``detpr``,
    ``hota_per_alpha`` (on all rows, as TrackEval). The total pools all sequences as the devkit
    does (one set of score thresholds). ``score_mode``: ``"track_mean"`` (AB3DMOT: rows take
    their track's mean score) or ``"row"``. ``gt_min_height``: count only ground truth higher
    than this (pixels; None = the devkit's code, no limit)."""
    if iou_threshold is None:
        iou_threshold = 0.25 if similarity == "iou3d" else 0.5
    names = list(gts.keys())
    seqs = _prepare_sequences(
        [gts[n] for n in names],
        [preds.get(n, {}) for n in names],
        cls,
        similarity,
        hota_similarity if hota else None,
        score_mode,
        gt_min_height,
    )
    # the frames' match caches stay valid across sequences' and the total's score thresholds;
    # HOTA's per-sequence components serve the sequences and the total
    parts = [_hota_sequence(s, iou_threshold) for s in seqs] if hota else None
    per = {
        n: _evaluate([s], iou_threshold, n_sample_pts, None if parts is None else [parts[i]])
        for i, (n, s) in enumerate(zip(names, seqs, strict=False))
    }
    if len(seqs) == 1:  # the total is that sequence's evaluation
        total = copy.deepcopy(per[names[0]])
    else:
        total = _evaluate(seqs, iou_threshold, n_sample_pts, parts)
    return {"per_sequence": per, "total": total}


def counted_ground_truth(
    gt: list[KittiObject], cls: str = "Car", gt_min_height: float | None = None
) -> list[KittiObject]:
    """The ground-truth rows of one frame that count (a miss is a FN): class ``cls``, not
    DontCare, within the devkit's occlusion / truncation (/ height) rules."""
    return [
        o
        for o in gt
        if not o.is_dontcare
        and class_status(o.type, cls) == 1
        and gt_counted_for_tracking(o, gt_min_height)
    ]


def match_tracks(
    gt: Frames,
    pred: Frames,
    *,
    cls: str = "Car",
    similarity: str = "iou2d",
    iou_threshold: float | None = None,
    gt_min_height: float | None = None,
) -> dict[int, list[tuple[KittiObject, KittiObject]]]:
    """Per-frame (ground truth, prediction) pairs of the tracking matcher that count as true
    positives (ignored ground truth excluded): ``{frame: [(gt_obj, pred_obj), ...]}``."""
    if iou_threshold is None:
        iou_threshold = 0.25 if similarity == "iou3d" else 0.5
    out: dict[int, list] = {}
    for k in sorted(set(gt) | set(pred)):
        g_all, p_all = gt.get(k, []), pred.get(k, [])
        fr = _prepare_frame(g_all, p_all, cls, similarity, similarity, gt_min_height)
        res = _match_frame(fr, len(fr.t_ids), iou_threshold)
        g = [o for o in g_all if not o.is_dontcare and class_status(o.type, cls) >= 0]
        t = _tracker_rows(p_all, cls)
        out[k] = [(g[r], t[c]) for r, c in res.pairs]
    return out


# ----------------------------------------------------------------------------- files


def fill_missing_boxes(
    frames: Frames, calib_path: str | os.PathLike, image_size: tuple[int, int] = (1242, 375)
) -> dict[int, list[KittiObject]]:
    """Rows whose 2D box is empty get the projection of their 3D box into the left image (P2,
    clipped to ``image_size`` = (width, height)); the devkit needs 2D boxes even in 3D mode."""
    P2 = read_calib(calib_path).P2
    out = {}
    for k, objs in frames.items():
        row = []
        for o in objs:
            x1, y1, x2, y2 = o.bbox
            if (x2 <= x1 or y2 <= y1) and min(o.dimensions) > 0 and o.location[2] > 0:
                box = projected_bbox(P2, o.dimensions, o.location, o.rotation_y, image_size)
                if box is not None:
                    o = o.with_(bbox=box)
            row.append(o)
        out[k] = row
    return out


def evaluate_tracking_dirs(
    results_dir: str | os.PathLike,
    labels_dir: str | os.PathLike,
    seqs: Iterable[str | int] | None = None,
    calib_dir: str | os.PathLike | None = None,
    **kwargs,
) -> dict:
    """Score KITTI tracking result files ``results_dir/SSSS.txt`` against ``labels_dir/SSSS.txt``.

    ``seqs``: sequence names or numbers (default: every label file that has a result file; a
    listed sequence without a result file counts as empty output). ``calib_dir``: when given,
    result rows without a 2D box get their 3D box's projection (``calib_dir/SSSS.txt``). Other
    keyword arguments go to :func:`evaluate_tracking_sequences`, whose dict is returned.
    Raises :class:`KittiFormatError` (message names the file) on missing or malformed files.
    """
    results_dir, labels_dir = Path(results_dir), Path(labels_dir)
    if not labels_dir.is_dir():
        raise KittiFormatError(f"{labels_dir}: label folder not found")
    if not results_dir.is_dir():
        raise KittiFormatError(f"{results_dir}: result folder not found")
    if seqs is None:
        names = sorted(p.stem for p in labels_dir.glob("*.txt") if (results_dir / p.name).is_file())
        if not names:
            raise KittiFormatError(f"{results_dir}: no result file matches a label file")
    else:
        names = [f"{int(s):04d}" if str(s).isdigit() else str(s) for s in seqs]
    gts, preds = {}, {}
    for n in names:
        gts[n] = read_tracking_labels(labels_dir / f"{n}.txt")
        rp = results_dir / f"{n}.txt"
        pred = read_tracking_labels(rp) if rp.is_file() else {}  # score column kept
        if calib_dir is not None:
            pred = fill_missing_boxes(pred, Path(calib_dir) / f"{n}.txt")
        preds[n] = pred
    return evaluate_tracking_sequences(gts, preds, **kwargs)
