"""Motion metrics of tracked vehicles: velocity error against ground truth, and stability (jitter).

Positions are centres of mass (:attr:`KittiObject.centre_of_mass`, camera-0 frame) on the ground
plane (x, z) by default: speed is what a vehicle tracker reports, and the label's y is mostly
box-height noise. Ground-truth velocity is the finite difference of a labelled track's positions
over time: central where the track has both neighbouring frames, one-sided at its ends; frames are
10 Hz (``dt = 0.1`` s) unless ``stamps`` (frame -> seconds) are given. Predictions are associated
with ground truth per frame by the tracking matcher (:func:`tracking_metrics.match_tracks`:
Hungarian on 2D IoU >= 0.5, KITTI's ignore rules); their velocity is either given
(``pred_velocities``, e.g. the tracker's filter state) or the same finite difference of their
track.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np
from vehicle_common.kitti import KittiObject

from eval_node.difficulty import class_status
from eval_node.tracking_metrics import match_tracks

Frames = Mapping[int, list[KittiObject]]

#: Default speed buckets (m/s) of the velocity error: [0, 2), [2, 5), [5, 10), [10, inf).
DEFAULT_BUCKETS = (0.0, 2.0, 5.0, 10.0, math.inf)
_AXES = {"xz": [0, 2], "xyz": [0, 1, 2]}


def _tracks(frames: Frames, cls: str | None, axes: str) -> dict[int, dict[int, np.ndarray]]:
    """``{track_id: {frame: position}}`` of the objects of class ``cls`` (all when None)."""
    idx = _AXES[axes]
    out: dict[int, dict[int, np.ndarray]] = {}
    for f, objs in frames.items():
        for o in objs:
            if o.is_dontcare or o.track_id < 0:
                continue
            if cls is not None and class_status(o.type, cls) != 1:
                continue
            out.setdefault(o.track_id, {})[int(f)] = o.centre_of_mass[idx]
    return out


def _time(f: int, dt: float, stamps: Mapping[int, float] | None) -> float:
    return float(stamps[f]) if stamps is not None else f * dt


def track_velocities(
    frames: Frames,
    *,
    dt: float = 0.1,
    stamps: Mapping[int, float] | None = None,
    cls: str | None = "Car",
    axes: str = "xz",
) -> dict[tuple[int, int], np.ndarray]:
    """Finite-difference velocity (m/s) of every track at every frame it has a neighbouring
    frame: ``{(frame, track_id): v}``; central difference between frames f-1 and f+1 where both
    exist, else backward or forward. ``axes``: ``"xz"`` (ground plane) or ``"xyz"``."""
    out = {}
    for tid, pos in _tracks(frames, cls, axes).items():
        for f, p in pos.items():
            prev, nxt = pos.get(f - 1), pos.get(f + 1)
            if prev is not None and nxt is not None:
                a, b, fa, fb = prev, nxt, f - 1, f + 1
            elif prev is not None:
                a, b, fa, fb = prev, p, f - 1, f
            elif nxt is not None:
                a, b, fa, fb = p, nxt, f, f + 1
            else:
                continue
            span = _time(fb, dt, stamps) - _time(fa, dt, stamps)
            if span > 0:
                out[(f, tid)] = (b - a) / span
    return out


def velocity_errors(
    gt: Frames,
    pred: Frames,
    *,
    pred_velocities: Mapping[tuple[int, int], Iterable[float]] | None = None,
    dt: float = 0.1,
    stamps: Mapping[int, float] | None = None,
    buckets: Iterable[float] = DEFAULT_BUCKETS,
    cls: str = "Car",
    axes: str = "xz",
) -> dict:
    """Velocity error of matched tracked vehicles against ground-truth velocity.

    ``pred_velocities``: ``{(frame, track_id): v}`` in the same axes (default: finite differences
    of the predicted tracks). Returns ``{"n", "rmse", "mae", "speed_rmse", "buckets": [{"lo",
    "hi", "n", "rmse", "mae", "mean_speed", "relative"}]}`` (m/s; ``relative`` = mean error norm
    over mean ground-truth speed in the bucket, NaN where undefined); buckets by ground-truth
    speed."""
    gt_v = track_velocities(gt, dt=dt, stamps=stamps, cls=cls, axes=axes)
    if pred_velocities is None:
        pr_v = track_velocities(pred, dt=dt, stamps=stamps, cls=cls, axes=axes)
    else:
        pr_v = {k: np.asarray(v, dtype=float) for k, v in pred_velocities.items()}
    errs, speeds, speed_errs = [], [], []
    for f, pairs in match_tracks(gt, pred, cls=cls).items():
        for g, p in pairs:
            vg, vp = gt_v.get((f, g.track_id)), pr_v.get((f, p.track_id))
            if vg is None or vp is None:
                continue
            errs.append(float(np.linalg.norm(vp - vg)))
            speeds.append(float(np.linalg.norm(vg)))
            speed_errs.append(float(np.linalg.norm(vp) - np.linalg.norm(vg)))
    e, s, se = np.array(errs), np.array(speeds), np.array(speed_errs)

    def summary(mask: np.ndarray) -> dict:
        n = int(mask.sum())
        if n == 0:
            return {
                "n": 0,
                "rmse": math.nan,
                "mae": math.nan,
                "mean_speed": math.nan,
                "relative": math.nan,
            }
        mae = float(e[mask].mean())
        mean_speed = float(s[mask].mean())
        return {
            "n": n,
            "rmse": float(np.sqrt((e[mask] ** 2).mean())),
            "mae": mae,
            "mean_speed": mean_speed,
            "relative": mae / mean_speed if mean_speed > 0 else math.nan,
        }

    edges = list(buckets)
    out = summary(np.ones(len(e), dtype=bool))
    out["speed_rmse"] = float(np.sqrt((se**2).mean())) if len(se) else math.nan
    out["buckets"] = [
        {"lo": lo, "hi": hi, **summary((s >= lo) & (s < hi))}
        for lo, hi in zip(edges, edges[1:], strict=False)
    ]
    return out


def jitter(frames: Frames, *, cls: str | None = "Car", axes: str = "xz") -> dict:
    """Frame-to-frame jitter of tracked positions: RMS norm of the second difference
    ``p[f+1] - 2 p[f] + p[f-1]`` over every track's runs of three consecutive frames.
    Returns ``{"n": triplets, "rms_m": metres per frame^2}``."""
    d2 = []
    for pos in _tracks(frames, cls, axes).values():
        for f, p in pos.items():
            a, b = pos.get(f - 1), pos.get(f + 1)
            if a is not None and b is not None:
                d2.append(float(np.linalg.norm(b - 2.0 * p + a)))
    arr = np.array(d2)
    return {"n": len(arr), "rms_m": float(np.sqrt((arr**2).mean())) if len(arr) else math.nan}


def matched_jitter_triplets(
    gt: Frames, pred: Frames, *, cls: str = "Car", axes: str = "xz"
) -> list[tuple]:
    """Every three consecutive frames in which one track is matched to one labelled car
    (tracking matcher, 2D IoU 0.5): ``(frame, track id, car id, the track's position at the
    middle frame (``axes``), the track's second difference [m], the car's [m])``."""
    idx = _AXES[axes]
    rows = {}
    for f, pairs in match_tracks(gt, pred, cls=cls).items():
        for g, p in pairs:
            rows[(int(f), p.track_id)] = (g.track_id, p.centre_of_mass[idx], g.centre_of_mass[idx])
    out = []
    for (f, tid), (gid, p, g) in rows.items():
        a, b = rows.get((f - 1, tid)), rows.get((f + 1, tid))
        if a is not None and b is not None and a[0] == gid == b[0]:
            d_pred = float(np.linalg.norm(b[1] - 2.0 * p + a[1]))
            d_gt = float(np.linalg.norm(b[2] - 2.0 * g + a[2]))
            out.append((f, tid, gid, p, d_pred, d_gt))
    return out


def matched_jitter(gt: Frames, pred: Frames, *, cls: str = "Car", axes: str = "xz") -> dict:
    """Jitter of the tracked cars against their own ground truth: the second difference over
    every three consecutive frames in which one track is matched to one labelled car (tracking
    matcher, 2D IoU 0.5), for the track and for the car (:func:`matched_jitter_triplets`).
    Returns ``{"n", "pred_rms_m", "gt_rms_m", "ratio"}`` (false tracks and unmatched frames left
    out, unlike :func:`jitter`)."""
    return jitter_of_triplets(matched_jitter_triplets(gt, pred, cls=cls, axes=axes))


def jitter_of_triplets(triplets: list[tuple]) -> dict:
    """:func:`matched_jitter`'s figures of triplets from :func:`matched_jitter_triplets` (a
    caller that needs the triplets too matches the tracks once)."""
    dp = [t[4] for t in triplets]
    dg = [t[5] for t in triplets]
    if not dp:
        return {"n": 0, "pred_rms_m": math.nan, "gt_rms_m": math.nan, "ratio": math.nan}
    rp, rg = float(np.sqrt(np.mean(np.square(dp)))), float(np.sqrt(np.mean(np.square(dg))))
    ratio = rp / rg if rg > 0 else math.nan
    return {"n": len(dp), "pred_rms_m": rp, "gt_rms_m": rg, "ratio": ratio}


def stability(
    gt: Frames, pred: Frames, *, dt: float = 0.1, cls: str = "Car", axes: str = "xz"
) -> dict:
    """Jitter of the predicted tracks compared with the ground truth's: ``{"pred_rms_m",
    "gt_rms_m", "pred_rms_mps2", "gt_rms_mps2", "ratio" (pred / gt), "n_pred", "n_gt",
    "matched"}``; the m/s^2 figures divide by ``dt**2`` (an acceleration-noise scale);
    ``ratio`` takes every track (false ones too), ``matched`` is :func:`matched_jitter`."""
    jp = jitter(pred, cls=cls, axes=axes)
    jg = jitter(gt, cls=cls, axes=axes)
    ratio = jp["rms_m"] / jg["rms_m"] if jg["rms_m"] and not math.isnan(jg["rms_m"]) else math.nan
    return {
        "matched": matched_jitter(gt, pred, cls=cls, axes=axes),
        "pred_rms_m": jp["rms_m"],
        "gt_rms_m": jg["rms_m"],
        "pred_rms_mps2": jp["rms_m"] / dt**2,
        "gt_rms_mps2": jg["rms_m"] / dt**2,
        "ratio": ratio,
        "n_pred": jp["n"],
        "n_gt": jg["n"],
    }
