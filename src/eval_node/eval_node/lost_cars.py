"""Why a car is not tracked: every missed ground-truth box of the tracking evaluation, by cause.

The tracking evaluation (:mod:`eval_node.tracking_metrics`, KITTI's rules, 2D IoU 0.5) counts a
labelled car in a frame as missed (FN) when no output track row (confirmed or coasting) matches
it. :func:`lost_cars` follows each missed box back through the graph, first cause first:

- ``not detected``: no 2D detection overlaps it (2D IoU >= ``iou``) and no reported track is on
  it (a coasting one that is: ``track off the box``);
- ``no 3D detection``: a 2D detection does, but no 3D detection (the stereo node left it out: too
  few disparities, or its plausibility check rejected it; ``drop_causes`` splits them into
  ``not ranged`` and ``rejected by the check`` when the caller knows);
- ``below birth_score``: a 3D detection exists, no track (of any state) is on it, and its score
  is below the tracker's ``birth_score`` (it may only keep a track alive);
- ``tentative (min_hits)``: a tentative track is on it (matched fewer than ``min_hits`` times);
- ``track off the box``: a reported track row is on the car (centre within ``near`` metres) but
  its 2D box overlaps the label's less than ``iou`` (a coasting projection, a matched box that
  is off);
- ``no track (association)``: a 3D detection that could start a track exists and no track
  is on it (another track took it, or its track was ended).

Per car (ground-truth track id): the frames it counts in, the share it is tracked, and the
cause of most of its missed frames; "mostly lost" as the devkit's ML (tracked < 20 %). Pure
core: ``evaluate bag --lost-cars`` and ``bench/bench_tracker.py real --lost-cars`` print it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from vehicle_common.kitti import KittiObject

from eval_node.detection_metrics import box_iou_2d, boxes_2d
from eval_node.tracking_metrics import counted_ground_truth, match_tracks

CAUSES = (
    "not detected",
    "no 3D detection",
    "not ranged",
    "rejected by the check",
    "below birth_score",
    "tentative (min_hits)",
    "track off the box",
    "no track (association)",
)
Frames = Mapping[int, list[KittiObject]]


@dataclass
class CarRecord:
    """One labelled car over a sequence: frames counted, tracked, and the causes of its misses."""

    sequence: str
    track_id: int
    frames: int = 0
    tracked: int = 0
    causes: Counter = field(default_factory=Counter)
    depths: list = field(default_factory=list)  # [m] label depth of each counted frame

    @property
    def share(self) -> float:
        return self.tracked / self.frames if self.frames else 0.0

    @property
    def mostly_lost(self) -> bool:
        return self.share < 0.2

    @property
    def main_cause(self) -> str:
        return self.causes.most_common(1)[0][0] if self.causes else "-"


def _best_overlap(box, objs: list[KittiObject]) -> tuple[int, float]:
    if not objs:
        return -1, 0.0
    iou = box_iou_2d(np.asarray([box], float), boxes_2d(objs))[0]
    j = int(np.argmax(iou))
    return j, float(iou[j])


def lost_cars(
    sequence: str,
    gt: Frames,
    det2d: Frames,
    det3d: Frames,
    tracks: Frames,
    tentative: Frames,
    birth_score: float = 0.0,
    iou: float = 0.5,
    near: float = 3.0,
    drop_causes: Callable[[int, KittiObject], str] | None = None,
) -> list[CarRecord]:
    """The :class:`CarRecord` of every counted Car of one sequence (see module doc). ``gt``,
    ``det2d``, ``det3d``, ``tracks`` (reported rows: confirmed and coasting) and ``tentative``
    (tracks not yet confirmed) per frame as KITTI rows (``score`` on the 3D detections);
    ``drop_causes(frame, 2D detection)``: ``"not ranged"`` or ``"rejected by the check"`` for a
    2D detection without a 3D one, when known."""
    matched = match_tracks(gt, tracks, similarity="iou2d", iou_threshold=iou)
    cars: dict[int, CarRecord] = {}
    for k in sorted(gt):
        hit = {id(g) for g, _ in matched.get(k, [])}
        for g in counted_ground_truth(gt[k]):
            rec = cars.setdefault(g.track_id, CarRecord(sequence, g.track_id))
            rec.frames += 1
            rec.depths.append(float(g.location[2]))
            if id(g) in hit:
                rec.tracked += 1
                continue
            rec.causes[_cause(k, g, det2d, det3d, tracks, tentative, birth_score, iou, near,
                              drop_causes)] += 1  # fmt: skip
    return list(cars.values())


def _cause(k, g, det2d, det3d, tracks, tentative, birth_score, iou, near, drop_causes) -> str:
    centre = np.asarray(g.centre_of_mass, float)
    rows = tracks.get(k, [])
    on_car = (
        bool(rows)
        and min(np.linalg.norm(np.asarray(t.centre_of_mass) - centre) for t in rows) < near
    )
    j2, o2 = _best_overlap(g.bbox, det2d.get(k, []))
    if o2 < iou:  # a coasting track may still be on it, its projected box off the label's
        return "track off the box" if on_car else "not detected"
    j3, o3 = _best_overlap(g.bbox, det3d.get(k, []))
    if o3 < iou:
        return drop_causes(k, det2d[k][j2]) if drop_causes is not None else "no 3D detection"
    _, ot = _best_overlap(g.bbox, tentative.get(k, []))
    if ot >= iou:
        return "tentative (min_hits)"
    if on_car:
        return "track off the box"
    score = det3d[k][j3].score
    if score is not None and score < birth_score:
        return "below birth_score"
    return "no track (association)"


def cause_table(records: list[CarRecord]) -> str:
    """Markdown: missed frames per cause (all cars / the mostly lost ones) and per mostly lost
    car its main cause."""
    fn = Counter()
    fn_ml = Counter()
    for r in records:
        fn.update(r.causes)
        if r.mostly_lost:
            fn_ml.update(r.causes)
    n_fn = sum(fn.values())
    n_gt = sum(r.frames for r in records)
    ml = [r for r in records if r.mostly_lost]
    lines = [
        f"counted car-frames {n_gt}, tracked {n_gt - n_fn} (recall {1 - n_fn / max(n_gt, 1):.3f}),"
        f" missed {n_fn}; cars {len(records)}, mostly lost (< 20 % tracked) {len(ml)}",
        "",
        "| cause | missed car-frames | share of missed | of the mostly lost cars | mostly lost "
        "cars with it as main cause |",
        "|---|---|---|---|---|",
    ]
    for c in CAUSES:
        if not fn[c]:
            continue
        main = sum(r.main_cause == c for r in ml)
        lines.append(f"| {c} | {fn[c]} | {fn[c] / max(n_fn, 1):.2f} | {fn_ml[c]} | {main} |")
    if ml:
        lines += ["", "| mostly lost car | sequence | frames | tracked | depth m | causes |"]
        lines.append("|---|---|---|---|---|---|")
        for r in sorted(ml, key=lambda r: (r.sequence, r.track_id)):
            why = ", ".join(f"{c} {n}" for c, n in r.causes.most_common())
            z = np.asarray(r.depths)
            lines.append(
                f"| {r.track_id} | {r.sequence} | {r.frames} | {r.tracked} | "
                f"{z.min():.0f}-{z.max():.0f} | {why} |"
            )
    return "\n".join(lines)


# ----------------------------------------------------------------------------- false tracks

FALSE_CAUSES = (
    "duplicate",
    "off the box",
    "outlived its car",
    "wrong class",
    "ghost",
)


@dataclass
class FalseRow:
    """One reported track row the tracking evaluation counts as a false positive."""

    sequence: str
    frame: int
    track_id: int
    cause: str
    depth: float  # [m] the row's depth (its 3D position's z)


def false_tracks(
    sequence: str, gt: Frames, tracks: Frames, iou: float = 0.5, near: float = 3.0, touch=0.1
) -> list[FalseRow]:
    """Every reported track row (confirmed and coasting) the evaluation counts as a false
    positive (KITTI's rules at 2D IoU ``iou``, every row kept: no score threshold), by cause,
    first cause first:

    - ``duplicate``: it is on a labelled Car (2D IoU >= ``touch`` or 3D centre within ``near``
      metres) that another row of the frame is matched to;
    - ``off the box``: it is on a labelled Car no row is matched to, its box overlapping the
      label's less than ``iou`` (a visible-part box, a coasting projection off the car);
    - ``outlived its car``: on no labelled Car, and its track was matched to a car earlier that
      is no longer labelled here (left the view, or hidden: the track coasts on);
    - ``wrong class``: on a labelled object of another class (Pedestrian, Cyclist, Truck, Tram,
      Misc, ...) or a DontCare region (2D IoU, or the share of its box inside the region, >=
      ``touch``);
    - ``ghost``: near no labelled object at all (a false detection of the stereo graph).
    """
    from eval_node.tracking_metrics import (
        _match_frame,
        _prepare_frame,
        _tracker_rows,
        class_status,
    )

    out: list[FalseRow] = []
    matched_cars: dict[int, set] = {}  # track id -> labelled car ids it was matched to so far
    for k in sorted(set(gt) | set(tracks)):
        labels, rows = gt.get(k, []), tracks.get(k, [])
        fr = _prepare_frame(labels, rows, "Car", "iou2d", None)
        res = _match_frame(fr, len(fr.t_ids), iou)
        t = _tracker_rows(rows, "Car")
        # the evaluation's ground-truth rows (Car and its neighbour Van), as it matched them
        g = [o for o in labels if not o.is_dontcare and class_status(o.type, "Car") >= 0]
        pairs = {tid: g[r] for r, tid in enumerate(res.g_tracker) if tid >= 0}
        for tid, car in pairs.items():
            matched_cars.setdefault(tid, set()).add(car.track_id)
        cars = [o for o in labels if not o.is_dontcare and o.type == "Car"]
        others = [o for o in labels if o.type != "Car"]  # DontCare, Van, Pedestrian, Truck...
        taken = {id(c) for c in pairs.values()}
        present = {o.track_id for o in g}
        for j, row in enumerate(t):
            if row.track_id in pairs or fr.t_ign[j]:
                continue  # matched (a TP or an ignored pair) or ignored: not a false positive
            car = _on(row, cars, touch, near)
            if car is not None:
                cause = "duplicate" if id(car) in taken else "off the box"
            elif matched_cars.get(row.track_id, set()) - present:
                cause = "outlived its car"
            elif _on(row, others, touch, near) is not None:
                cause = "wrong class"
            else:
                cause = "ghost"
            out.append(FalseRow(sequence, k, row.track_id, cause, float(row.location[2])))
    return out


def _on(row: KittiObject, objs: list[KittiObject], touch: float, near: float):
    """The object of ``objs`` that ``row`` is on: the best 2D overlap (IoU, or the share of the
    row's box inside a DontCare region) >= ``touch``, else the nearest 3D centre within
    ``near`` metres (objects without a 3D box: 2D only); None."""
    from eval_node.detection_metrics import box_overlap_over_first

    if not objs:
        return None
    b = np.asarray([row.bbox], float)
    ov = box_iou_2d(b, boxes_2d(objs))[0]
    dc = np.array([o.is_dontcare for o in objs])
    if dc.any():
        ov = np.where(dc, box_overlap_over_first(b, boxes_2d(objs))[0], ov)
    j = int(np.argmax(ov))
    if ov[j] >= touch:
        return objs[j]
    c = np.asarray(row.centre_of_mass, float)
    dist = [
        np.linalg.norm(np.asarray(o.centre_of_mass) - c) if not o.is_dontcare else np.inf
        for o in objs
    ]
    j = int(np.argmin(dist))
    return objs[j] if dist[j] < near else None


def false_track_table(rows: list[FalseRow]) -> str:
    """Markdown: the false-positive track rows per cause (rows, share, distinct tracks, median
    depth)."""
    n = len(rows)
    lines = [
        f"false-positive track rows {n} (every row kept; KITTI tracking rules, 2D IoU 0.5)",
        "",
        "| cause | false-positive rows | share | tracks | depth m (median) |",
        "|---|---|---|---|---|",
    ]
    for c in FALSE_CAUSES:
        sub = [r for r in rows if r.cause == c]
        if not sub:
            continue
        tracks = len({(r.sequence, r.track_id) for r in sub})
        z = float(np.median([r.depth for r in sub]))
        lines.append(f"| {c} | {len(sub)} | {len(sub) / n:.2f} | {tracks} | {z:.0f} |")
    return "\n".join(lines)
