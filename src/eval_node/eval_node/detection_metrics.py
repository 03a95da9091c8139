"""Detection metrics on KITTI objects: 3D localisation AP by centre distance, 2D AP by IoU (KITTI
devkit and Pascal VOC 2007), and orientation-bin accuracy.

Inputs are ``{frame: [KittiObject, ...]}`` dicts (as :func:`kitti.read_tracking_labels` returns;
object-benchmark frames may use any hashable key) for ground truth and predictions. Predictions
carry ``score`` (``None`` counts as 1.0); their 2D ``bbox`` is used for the height and DontCare
rules, so outputs must carry the projection of their 3D box into the left image.

The AP computation follows the KITTI object devkit (``evaluate_object.cpp`` and its Python port
kitti-object-eval-python ``eval.py``): per-frame greedy matching of each ground truth to the best
remaining prediction, ignored ground truth (neighbouring class ``Van``, outside the difficulty) and
ignored predictions (below the level's minimum height; unmatched predictions covering a DontCare box
with intersection over their own area > ``dontcare_overlap``), score thresholds sampled from the
true positives' scores (at most 41, spaced about 1/40 apart in recall), then 41 precision samples
by one of two interpolations:

- ``"kitti"`` (default; the official devkit's ``eval_class``, what the leaderboard reports): the
  k-th sampled score threshold's precision is booked at recall k/40, then each sample takes the
  maximum over itself and all later ones (missing samples are 0). With fewer than 40 counted
  ground-truth boxes every true positive is a threshold and the AP is capped near num_gt/40; with
  40-250 boxes the booked recall k/40 trails the actual recall at high recall, so it is not the
  same as
- ``"recall"`` (a named option): each sample r = 0, 1/40, ..., 1 takes the best precision of any
  sampled operating point whose actual recall is >= r (no cap with few boxes),

and the AP summaries are

- ``ap_r11``: mean precision at recall 0, 0.1, ..., 1 (every 4th of the 41 samples; KITTI's original
  metric, "AP|R11"),
- ``ap_r40``: mean precision at the 40 recall points 1/40 .. 1 (KITTI's metric since 2019),
- ``ap_r41``: mean precision at all 41 sampled recall points 0, 1/40, ..., 1.

The 3D localisation variant replaces "2D IoU > t" by "centre-of-mass distance <= d" (centre of mass
= ``location`` lifted by h/2, :attr:`KittiObject.centre_of_mass`) and "largest IoU" by "smallest
distance". All AP values are fractions in [0, 1] (not percent); NaN when there is no counted ground
truth.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from vehicle_common.box2d import iou_2d as box_iou_2d
from vehicle_common.box2d import overlap_over_first as box_overlap_over_first
from vehicle_common.kitti import KittiObject
from vehicle_common.orientation_bins import alpha_to_bin

from eval_node.difficulty import DIFFICULTIES, Difficulty, class_status, gt_within_difficulty

Frames = Mapping[Hashable, list[KittiObject]]

#: Number of recall sample points of the KITTI devkit.
N_SAMPLE_PTS = 41
#: Default centre distances (m) of the 3D localisation AP.
DEFAULT_DISTANCES = (1.5, 3.0, 5.0, 10.0)
#: Default 2D IoU thresholds of the 2D detection AP.
DEFAULT_IOUS = (0.5, 0.7)
#: The object benchmark's difficulty levels, in order.
LEVELS = ("easy", "moderate", "hard")
#: Precision interpolations of :func:`precision_recall` (the first is the default).
INTERPOLATIONS = ("kitti", "recall")

# ----------------------------------------------------------------------------- geometry


def boxes_2d(objects: Iterable[KittiObject]) -> np.ndarray:
    """2D boxes (N, 4) ``x1, y1, x2, y2`` of a list of objects."""
    arr = np.array([o.bbox for o in objects], dtype=float)
    return arr.reshape(-1, 4)


def centres_of_mass(objects: Iterable[KittiObject]) -> np.ndarray:
    """3D box centres (N, 3) in camera-0 coordinates (bottom centre lifted by h/2)."""
    arr = np.array([o.centre_of_mass for o in objects], dtype=float)
    return arr.reshape(-1, 3)


def centre_distances(pred: Iterable[KittiObject], gt: Iterable[KittiObject]) -> np.ndarray:
    """Pairwise Euclidean distances (N_pred, N_gt) between 3D centres of mass, metres."""
    p, g = centres_of_mass(pred), centres_of_mass(gt)
    return np.linalg.norm(p[:, None, :] - g[None, :, :], axis=-1)


# ----------------------------------------------------------------------------- KITTI devkit AP


@dataclass
class _FrameData:
    ignored_gt: list[int]  # 0 counted, 1 ignored, -1 other class
    ignored_dt: list[int]  # 0 valid, 1 ignored (too small), -1 other class
    scores: list[float]  # predictions sorted by score, descending
    ok: np.ndarray  # (n_dt, n_gt) bool: the pair passes the criterion
    quality: np.ndarray  # (n_dt, n_gt) larger is better (IoU, or -distance)
    in_dontcare: list[bool]  # prediction covers a DontCare box
    n_valid_gt: int


def _score(o: KittiObject) -> float:
    return 1.0 if o.score is None else float(o.score)


def _prepare(
    gt: list[KittiObject],
    pred: list[KittiObject],
    cls: str,
    level: Difficulty,
    criterion: str,
    threshold: float,
    dontcare_overlap: float,
) -> _FrameData:
    gt_objs = [o for o in gt if not o.is_dontcare]
    dc = boxes_2d([o for o in gt if o.is_dontcare])
    ignored_gt = []
    for o in gt_objs:
        status = class_status(o.type, cls)
        inside = gt_within_difficulty(o, level)
        if status == 1 and inside:
            ignored_gt.append(0)
        elif status == 0 or status == 1:
            ignored_gt.append(1)
        else:
            ignored_gt.append(-1)
    order = sorted(range(len(pred)), key=lambda i: -_score(pred[i]))
    dts = [pred[i] for i in order]
    ignored_dt = []
    for o in dts:
        if abs(o.bbox[3] - o.bbox[1]) < level.min_height:
            ignored_dt.append(1)
        elif class_status(o.type, cls) == 1:
            ignored_dt.append(0)
        else:
            ignored_dt.append(-1)
    if criterion == "iou2d":
        quality = box_iou_2d(boxes_2d(dts), boxes_2d(gt_objs))
        ok = quality > threshold
    elif criterion == "centre_distance":
        dist = centre_distances(dts, gt_objs)
        quality = -dist
        ok = dist <= threshold
    else:
        raise ValueError(f"unknown criterion {criterion!r} (iou2d or centre_distance)")
    if len(dc) and len(dts):
        in_dc = (box_overlap_over_first(boxes_2d(dts), dc) > dontcare_overlap).any(axis=1)
    else:
        in_dc = np.zeros(len(dts), dtype=bool)
    return _FrameData(
        ignored_gt=ignored_gt,
        ignored_dt=ignored_dt,
        scores=[_score(o) for o in dts],
        ok=ok,
        quality=quality,
        in_dontcare=in_dc.tolist(),
        n_valid_gt=ignored_gt.count(0),
    )


def _tp_scores(fd: _FrameData) -> list[float]:
    """Devkit pass without a threshold: each ground truth takes the highest-scoring prediction
    that passes the criterion (ties: the best quality); returns the true positives' scores."""
    n_dt = len(fd.scores)
    assigned = [False] * n_dt
    out = []
    for i, ig in enumerate(fd.ignored_gt):
        if ig == -1:
            continue
        best = -1
        for j in range(n_dt):  # sorted by descending score: the first candidate is the best
            if fd.ignored_dt[j] == -1 or assigned[j] or not fd.ok[j, i]:
                continue
            if best < 0:
                best = j
            elif fd.scores[j] < fd.scores[best]:
                break
            elif fd.quality[j, i] > fd.quality[best, i]:
                best = j  # equal scores: the better-matching prediction (devkit: file order)
        if best < 0:
            continue
        assigned[best] = True
        if ig == 0 and fd.ignored_dt[best] == 0:
            out.append(fd.scores[best])
    return out


def _tp_fp_fn(fd: _FrameData, k: int) -> tuple[int, int, int]:
    """Devkit pass keeping the ``k`` highest-scoring predictions (score >= threshold): each
    ground truth takes the best-quality valid prediction, else an ignored one."""
    assigned = [False] * k
    tp = fn = 0
    for i, ig in enumerate(fd.ignored_gt):
        if ig == -1:
            continue
        det, best_q, took_ignored = -1, -math.inf, False
        for j in range(k):
            if fd.ignored_dt[j] == -1 or assigned[j] or not fd.ok[j, i]:
                continue
            q = fd.quality[j, i]
            if fd.ignored_dt[j] == 0 and (q > best_q or took_ignored):
                det, best_q, took_ignored = j, q, False
            elif fd.ignored_dt[j] == 1 and det < 0:
                det, took_ignored = j, True
        if det < 0:
            if ig == 0:
                fn += 1
            continue
        assigned[det] = True
        if ig == 0 and fd.ignored_dt[det] == 0:
            tp += 1
    fp = 0
    for j in range(k):
        if not assigned[j] and fd.ignored_dt[j] == 0 and not fd.in_dontcare[j]:
            fp += 1
    return tp, fp, fn


def sample_thresholds(
    tp_scores: Iterable[float], num_gt: int, n_sample_pts: int = N_SAMPLE_PTS
) -> list[float]:
    """Score thresholds at (about) evenly spaced recall points, from the true positives' scores
    (the devkits' ``get_thresholds``)."""
    scores = np.sort(np.asarray(list(tp_scores), dtype=float))[::-1]
    current, out = 0.0, []
    n = len(scores)
    for i, s in enumerate(scores):
        l_recall = (i + 1) / num_gt
        r_recall = (i + 2) / num_gt if i < n - 1 else l_recall
        if (r_recall - current) < (current - l_recall) and i < n - 1:
            continue
        out.append(float(s))
        current += 1.0 / (n_sample_pts - 1.0)
    return out


@dataclass
class PrecisionRecall:
    """Sampled precision/recall curve of one (class, difficulty, criterion, threshold)."""

    precision: np.ndarray  # (n_sample_pts,) interpolated precision at each recall sample point
    recall: np.ndarray  # (n_sample_pts,) the recall sample points 0, 1/(n-1), ..., 1
    thresholds: list[float]  # score thresholds of the samples
    num_gt: int  # counted ground truth
    tp_fp_fn: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), dtype=int))
    max_recall: float = 0.0  # highest recall reached by any operating point

    @property
    def ap_r11(self) -> float:
        """KITTI's original AP|R11: mean of every 4th of the 41 samples (recall 0, 0.1, .. 1)."""
        if self.num_gt == 0:
            return math.nan
        return float(self.precision[::4].sum() / 11.0)

    @property
    def ap_r40(self) -> float:
        """KITTI's AP|R40: mean precision at recall 1/40 .. 1 (samples 1..40)."""
        if self.num_gt == 0:
            return math.nan
        return float(self.precision[1:].sum() / (len(self.precision) - 1))

    @property
    def ap_r41(self) -> float:
        """Mean precision over all 41 sampled recall points 0, 1/40, .., 1."""
        if self.num_gt == 0:
            return math.nan
        return float(self.precision.mean())

    @property
    def ap_actual_recall(self) -> float:
        """AP|R40 with each operating point at its actual recall (the ``"recall"``
        interpolation, whatever this curve's): mean over r = 1/40 .. 1 of the best precision of
        any sampled operating point whose recall is >= r. Not capped near num_gt / 40 with few
        boxes, unlike the devkit's AP|R40."""
        if self.num_gt == 0:
            return math.nan
        op_precision, op_recall = _operating_points(self.tp_fp_fn)
        precision = _precision_at_actual_recall(op_precision, op_recall, self.recall)
        return float(precision[1:].sum() / (len(precision) - 1))

    def as_dict(self) -> dict:
        return {
            "ap_r41": self.ap_r41,
            "ap_r11": self.ap_r11,
            "ap_r40": self.ap_r40,
            "num_gt": self.num_gt,
        }


def _frame_keys(gt: Frames, pred: Frames) -> list:
    keys = list(gt.keys()) + [k for k in pred if k not in gt]
    return keys


def precision_recall(
    gt: Frames,
    pred: Frames,
    *,
    criterion: str = "centre_distance",
    threshold: float = 1.5,
    difficulty: str | Difficulty = "moderate",
    cls: str = "Car",
    n_sample_pts: int = N_SAMPLE_PTS,
    dontcare_overlap: float | None = None,
    interpolation: str = "kitti",
) -> PrecisionRecall:
    """KITTI-devkit precision/recall curve of ``pred`` against ``gt``.

    ``criterion``: ``"iou2d"`` (a pair matches when 2D IoU > ``threshold``) or
    ``"centre_distance"`` (centre-of-mass distance <= ``threshold`` metres).
    ``dontcare_overlap``: intersection-over-prediction-area above which an unmatched prediction
    covering a DontCare box is ignored (default: ``threshold`` for ``iou2d`` as the devkit does,
    0.5 for ``centre_distance``).
    ``interpolation``: ``"kitti"`` (the devkit's: threshold k booked at recall k/40) or
    ``"recall"`` (each threshold at its actual recall); see the module docstring.
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"unknown interpolation {interpolation!r} ({' or '.join(INTERPOLATIONS)})")
    level = DIFFICULTIES[difficulty] if isinstance(difficulty, str) else difficulty
    if dontcare_overlap is None:
        dontcare_overlap = threshold if criterion == "iou2d" else 0.5
    frames = [
        _prepare(gt.get(k, []), pred.get(k, []), cls, level, criterion, threshold, dontcare_overlap)
        for k in _frame_keys(gt, pred)
    ]
    num_gt = sum(f.n_valid_gt for f in frames)
    precision = np.zeros(n_sample_pts)
    recall = np.zeros(n_sample_pts)
    if num_gt == 0:
        return PrecisionRecall(precision, recall, [], 0)
    tp_scores = [s for f in frames for s in _tp_scores(f)]
    thresholds = sample_thresholds(tp_scores, num_gt, n_sample_pts)[:n_sample_pts]
    pr = np.zeros((len(thresholds), 3), dtype=int)
    for f in frames:
        if not f.scores:
            pr[:, 2] += f.n_valid_gt
            continue
        neg = -np.asarray(f.scores)
        # number of predictions with score >= t (scores sorted descending)
        ks = np.searchsorted(neg, -np.asarray(thresholds), side="right")
        cache: dict[int, tuple[int, int, int]] = {}
        for t, k in enumerate(ks.tolist()):
            if k not in cache:
                cache[k] = _tp_fp_fn(f, k)
            pr[t] += cache[k]
    op_precision, op_recall = _operating_points(pr)
    recall[:] = np.linspace(0.0, 1.0, n_sample_pts)
    if interpolation == "kitti":
        # evaluate_object.cpp: precision[i] of the i-th threshold, then max over i..end; the
        # samples after the last threshold stay 0.
        n = len(op_precision)
        precision[:n] = np.maximum.accumulate(op_precision[::-1])[::-1]
    else:
        precision[:] = _precision_at_actual_recall(op_precision, op_recall, recall)
    max_recall = float(op_recall.max()) if op_recall.size else 0.0
    return PrecisionRecall(precision, recall, thresholds, num_gt, pr, max_recall)


def _operating_points(tp_fp_fn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Precision and recall of each sampled score threshold (rows: TP, FP, FN)."""
    tp, fp, fn = (tp_fp_fn[:, i].astype(float) for i in range(3))
    with np.errstate(divide="ignore", invalid="ignore"):
        op_recall = np.where(tp + fn > 0, tp / (tp + fn), 0.0)
        op_precision = np.where(tp + fp > 0, tp / (tp + fp), 0.0)
    return op_precision, op_recall


def _precision_at_actual_recall(op_precision, op_recall, recall: np.ndarray) -> np.ndarray:
    """The best precision of any operating point with actual recall >= r_k (0 where never)."""
    out = np.zeros(len(recall))
    for k, r in enumerate(recall):
        reached = op_precision[op_recall >= r - 1e-9]
        out[k] = reached.max() if reached.size else 0.0
    return out


def localisation_ap(
    gt: Frames,
    pred: Frames,
    distances: Iterable[float] = DEFAULT_DISTANCES,
    difficulties: Iterable[str] = ("easy", "moderate", "hard"),
    cls: str = "Car",
    interpolation: str = "kitti",
) -> dict[str, dict[float, dict]]:
    """3D localisation AP by centre-of-mass distance: ``{difficulty: {d: {"ap_r41", "ap_r11",
    "ap_r40", "num_gt"}}}`` (fractions, NaN without counted ground truth)."""
    return _ap_grid(gt, pred, "centre_distance", distances, difficulties, cls, interpolation)


def detection_ap_2d(
    gt: Frames,
    pred: Frames,
    ious: Iterable[float] = DEFAULT_IOUS,
    difficulties: Iterable[str] = ("easy", "moderate", "hard"),
    cls: str = "Car",
    interpolation: str = "kitti",
) -> dict[str, dict[float, dict]]:
    """2D detection AP (KITTI devkit, IoU > t): ``{difficulty: {iou: {"ap_r41", "ap_r11",
    "ap_r40", "num_gt"}}}``."""
    return _ap_grid(gt, pred, "iou2d", ious, difficulties, cls, interpolation)


def _ap_grid(gt, pred, criterion, thresholds, difficulties, cls, interpolation) -> dict:
    """``{difficulty: {threshold: PrecisionRecall.as_dict()}}`` of one criterion."""
    return {
        diff: {
            float(t): precision_recall(
                gt,
                pred,
                criterion=criterion,
                threshold=float(t),
                difficulty=diff,
                cls=cls,
                interpolation=interpolation,
            ).as_dict()
            for t in thresholds
        }
        for diff in difficulties
    }


def key(threshold: float) -> str:
    """JSON key of a threshold: 1.5 -> "1.5", 3.0 -> "3"."""
    return f"{float(threshold):g}"


def ap_table(
    gt: Frames,
    pred: Frames,
    criterion: str,
    thresholds: Iterable[float],
    curves: dict | None = None,
    *,
    cls: str = "Car",
    interpolation: str = "kitti",
) -> dict[str, dict[str, float]]:
    """AP per threshold and difficulty in the layout of ``results.json``: ``{key(t): {"easy":
    AP|R40, "easy_r40", "easy_r11", "easy_r41", "easy_num_gt", "easy_actual_recall" (AP|R40 at
    the actual recall, not capped with few boxes), "moderate": ..., ...}}`` (fractions).
    ``curves``, when given, receives ``{level: {key(t): {"precision", "recall"}}}``.
    """
    table: dict[str, dict[str, float]] = {}
    for t in thresholds:
        row: dict[str, float] = {}
        for level in LEVELS:
            pr = precision_recall(
                gt,
                pred,
                criterion=criterion,
                threshold=t,
                difficulty=level,
                cls=cls,
                interpolation=interpolation,
            )
            row[level] = pr.ap_r40
            row[f"{level}_r40"] = pr.ap_r40
            row[f"{level}_r11"] = pr.ap_r11
            row[f"{level}_r41"] = pr.ap_r41
            row[f"{level}_num_gt"] = pr.num_gt
            row[f"{level}_actual_recall"] = pr.ap_actual_recall
            if curves is not None:
                curves.setdefault(level, {})[key(t)] = {
                    "precision": pr.precision.tolist(),
                    "recall": pr.recall.tolist(),
                }
        table[key(t)] = row
    return table


# ----------------------------------------------------------------------------- Pascal VOC 2007


def voc07_ap(
    gt: Frames,
    pred: Frames,
    iou: float = 0.5,
    difficulty: str | Difficulty | None = "moderate",
    cls: str = "Car",
) -> float:
    """Pascal VOC 2007 11-point AP at 2D IoU > ``iou``.

    Predictions of all frames are ranked by score; each takes the ground truth of its frame with the
    largest IoU: a TP if that one is counted and unused, a FP if it is used or below ``iou``.
    Ground truth that KITTI ignores (neighbouring class, outside ``difficulty``) plays VOC's
    "difficult" role (matching it is neither TP nor FP), and so do predictions below the level's
    minimum height or covering a DontCare box (intersection over prediction area > 0.5) while
    unmatched. ``difficulty=None`` counts all ground truth of the class.
    """
    level = DIFFICULTIES[difficulty] if isinstance(difficulty, str) else difficulty
    records = []  # (score, frame index, pred index)
    per_frame = []
    npos = 0
    for fi, k in enumerate(_frame_keys(gt, pred)):
        g = [o for o in gt.get(k, []) if not o.is_dontcare and class_status(o.type, cls) >= 0]
        dc = boxes_2d([o for o in gt.get(k, []) if o.is_dontcare])
        p = [o for o in pred.get(k, []) if class_status(o.type, cls) == 1]
        counted = np.array(
            [
                class_status(o.type, cls) == 1 and (level is None or gt_within_difficulty(o, level))
                for o in g
            ],
            dtype=bool,
        )
        npos += int(counted.sum())
        pb = boxes_2d(p)
        small = (
            np.abs(pb[:, 3] - pb[:, 1]) < level.min_height
            if level is not None
            else np.zeros(len(p), dtype=bool)
        )
        in_dc = (
            (box_overlap_over_first(pb, dc) > 0.5).any(axis=1)
            if len(dc) and len(p)
            else np.zeros(len(p), dtype=bool)
        )
        per_frame.append((box_iou_2d(pb, boxes_2d(g)), counted, small, in_dc, np.zeros(len(g))))
        records += [(_score(o), fi, j) for j, o in enumerate(p)]
    if npos == 0:
        return math.nan
    records.sort(key=lambda r: -r[0])
    tp, fp = [], []
    for _, fi, j in records:
        ious, counted, small, in_dc, used = per_frame[fi]
        if ious.shape[1]:
            gi = int(np.argmax(ious[j]))
            ovmax = ious[j, gi]
        else:
            gi, ovmax = -1, 0.0
        if ovmax > iou:
            if not counted[gi] or small[j]:
                continue  # matched ignored ground truth, or an ignored prediction
            if not used[gi]:
                used[gi] = 1
                tp.append(1)
                fp.append(0)
            else:
                tp.append(0)
                fp.append(1)
        else:
            if small[j] or in_dc[j]:
                continue
            tp.append(0)
            fp.append(1)
    ctp, cfp = np.cumsum(tp), np.cumsum(fp)
    rec = ctp / npos
    prec = ctp / np.maximum(ctp + cfp, np.finfo(float).eps)
    ap = 0.0
    for t in np.arange(0.0, 1.1, 0.1):
        p = prec[rec >= t].max() if np.any(rec >= t) else 0.0
        ap += p / 11.0
    return float(ap)


# ----------------------------------------------------------------------------- orientation


@dataclass
class OrientationResult:
    """Orientation-bin accuracy over matched pairs; ``confusion[gt_bin, pred_bin]`` counts."""

    accuracy: float
    confusion: np.ndarray
    n_pairs: int

    def as_dict(self) -> dict:
        return {
            "accuracy": self.accuracy,
            "confusion": self.confusion.tolist(),
            "n_pairs": self.n_pairs,
        }


def match_2d(gt: list[KittiObject], pred: list[KittiObject], iou: float = 0.5) -> list:
    """One-to-one matching of a frame's boxes maximising total 2D IoU (Hungarian), keeping pairs
    with IoU >= ``iou``: list of ``(gt_index, pred_index, iou)``."""
    if not gt or not pred:
        return []
    m = box_iou_2d(boxes_2d(gt), boxes_2d(pred))
    cost = np.where(m >= iou, 1.0 - m, 1e6)
    rows, cols = linear_sum_assignment(cost)
    return [
        (int(r), int(c), float(m[r, c])) for r, c in zip(rows, cols, strict=False) if m[r, c] >= iou
    ]


def orientation_accuracy(
    gt: Frames,
    pred: Frames,
    iou: float = 0.5,
    cls: str = "Car",
    difficulty: str | Difficulty | None = None,
) -> OrientationResult:
    """Accuracy of the 4 orientation bins (the detector's ``orientation.alpha_to_bin`` of
    ``alpha``: folded modulo pi, bins centred on 0, 45, 90, 135 deg) over ground
    truth / prediction pairs matched per frame by 2D IoU >= ``iou`` (Hungarian). Ground truth of
    class ``cls`` only (within ``difficulty`` when given); predictions of class ``cls``. A
    ground truth without an angle (KITTI's -10 placeholder, below -pi: 2D-only labels) is
    matched but not counted (it once counted as the 135-deg bin that -10 rad folds to)."""
    level = DIFFICULTIES[difficulty] if isinstance(difficulty, str) else difficulty
    confusion = np.zeros((4, 4), dtype=int)
    for k in _frame_keys(gt, pred):
        g = [
            o
            for o in gt.get(k, [])
            if class_status(o.type, cls) == 1 and (level is None or gt_within_difficulty(o, level))
        ]
        p = [o for o in pred.get(k, []) if class_status(o.type, cls) == 1]
        for gi, pi, _ in match_2d(g, p, iou):
            if g[gi].alpha >= -math.pi:
                confusion[alpha_to_bin(g[gi].alpha), alpha_to_bin(p[pi].alpha)] += 1
    n = int(confusion.sum())
    acc = float(np.trace(confusion) / n) if n else math.nan
    return OrientationResult(acc, confusion, n)
