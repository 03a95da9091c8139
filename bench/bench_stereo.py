"""Stereo depth benchmarks: disparity accuracy, ranging accuracy, time per frame.

Usage: python bench/bench_stereo.py [disparity|ranging|centre|odometry|plausibility|occluder|timing
       |all]
       [--repeats N]
       [--synth ROOT:SEQ ...]
Reads ../shared/kitti (KITTI Stereo 2015 training pairs 0..4 and tracking sequence 0005); prints
tables. Uses the same core functions as the stereo_depth node (compute_disparity, range_boxes).
``centre``: centre-of-mass error of the ranged labelled Car/Van boxes (orientation bin from the
label's alpha, as the oracle detector gives it) on KITTI 0005 and on synthetic sequences written
by ``kitti_synth`` (e.g. ``--synth /tmp/synth_rng:0001 --synth /tmp/synth_rng:0002``), before and
after the geometric centre correction, plus predicted vs measured error spread (covariance).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import stereo_real  # the real-frame sections of issue #23 (bench/stereo_real.py)
from stereo_depth_node.disparity import (
    DisparityParams,
    compute_disparity,
    d1_error,
    interpolate_background,
)
from stereo_depth_node.ground_truth import KITTI_GEOMETRY as KITTI_GEO
from stereo_depth_node.ground_truth import stereo_pairs as _stereo_pairs
from stereo_depth_node.ground_truth import surface_regions
from stereo_depth_node.ranging import (
    RangingParams,
    disparity_bias_at,
    position_covariance,
    range_boxes,
    robust_disparity,
)
from stereo_depth_node.region_matching import box_disparity, refine_shift, to_gray
from stereo_depth_node.reprojection import StereoGeometry
from stereo_depth_node.visual_odometry import FrameToFrameOdometry
from vehicle_common.kitti import TrackingSequence, list_object_frames, read_png
from vehicle_common.orientation_bins import alpha_to_bin

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "kitti"
TRACKING = SHARED / "tracking" / "training"

DEFAULT = DisparityParams()
FULL = DisparityParams(downscale=1, num_disparities=128, block_size=5, use_wls=True, pad_left=True)
VARIANTS = {
    "left SGBM, full res, 128 disp, no pad": replace(FULL, use_wls=False, pad_left=False),
    "L+R+WLS, full res, 128 disp, no pad": replace(FULL, pad_left=False),
    "left SGBM, full res, 128 disp": replace(FULL, use_wls=False),
    "L+R+WLS, full res, 128 disp": FULL,
    "L+R+WLS, full res, 96 disp": replace(FULL, num_disparities=96),
    "left SGBM, half res, 96 disp": replace(FULL, use_wls=False, downscale=2, num_disparities=96),
    "L+R+WLS, half res, 128 disp": replace(FULL, downscale=2),
    "L+R+WLS, half res, 96 disp": replace(FULL, downscale=2, num_disparities=96),
    "L+R+WLS, half res, 96 disp, block 3": replace(
        FULL, downscale=2, num_disparities=96, block_size=3
    ),
    "L+R+WLS, half res, 96 disp, block 7": replace(
        FULL, downscale=2, num_disparities=96, block_size=7
    ),
    "L+R+WLS, half res, 96 disp, rows 100-375": replace(
        FULL, downscale=2, num_disparities=96, row_band=(100, 375)
    ),
    "L+R+WLS, half res, 96 disp, mode SGBM": replace(
        FULL, downscale=2, num_disparities=96, mode="sgbm"
    ),
    "L+R+WLS, half res, 96 disp, colour": replace(
        FULL, downscale=2, num_disparities=96, use_color=True
    ),
    "L+R+WLS, half res, 96 disp, lambda 2000": replace(
        FULL, downscale=2, num_disparities=96, wls_lambda=2000.0
    ),
    "L+R+WLS, quarter res, 96 disp": replace(FULL, downscale=4, num_disparities=96),
    "L+R+WLS, half res, 96 disp, block 3, WLS at half res": replace(
        FULL, downscale=2, num_disparities=96, block_size=3, wls_full_res_guide=False
    ),
}


#: RangingParams defaults before issue #13 (for before/after figures)
PREVIOUS_DEFAULTS = replace(
    RangingParams(),
    refine="none",
    disparity_bias=0.0,
    disparity_bias_column=0.0,
    surface_model="visible",
    truncated_surface_model="visible",
    lateral_fit=False,
)


def stereo_pairs():
    """The 5 KITTI 2015 pairs of ../shared (``stereo_depth_node.ground_truth``)."""
    return _stereo_pairs(SHARED)


def bench_disparity(variants: dict[str, DisparityParams]) -> None:
    pairs = list(stereo_pairs())
    print("\n## Disparity accuracy, KITTI Stereo 2015 training 000000..000004 (disp_occ_0)")
    print("D1: bad if |d-gt| > 3 px and > 5 %. raw = holes counted bad; interp = KITTI devkit")
    print("background interpolation of holes (how the benchmark scores, reference SGBM 10.86 %)")
    print("| variant | D1-all raw % | D1-all interp % | D1 valid px % | density % | ms/frame |")
    print("|---|---|---|---|---|---|")
    for name, p in variants.items():
        raw, interp, valid, dens, times = [], [], [], [], []
        for left, right, gt in pairs:
            t0 = time.perf_counter()
            d = compute_disparity(left, right, p)
            times.append(time.perf_counter() - t0)
            e = d1_error(d, gt)
            raw.append(e["d1_all"] * e["n_gt"])
            valid.append(e["d1_valid"])
            dens.append(e["density"])
            interp.append(d1_error(interpolate_background(d), gt)["d1_all"] * e["n_gt"])
        n_gt = sum(float((gt > 0).sum()) for _, _, gt in pairs)
        print(
            f"| {name} | {100 * sum(raw) / n_gt:.2f} | {100 * sum(interp) / n_gt:.2f} | "
            f"{100 * np.mean(valid):.2f} | {100 * np.mean(dens):.1f} | "
            f"{1000 * np.median(times):.0f} |"
        )


def orientation_bin(alpha: float) -> int:
    """KITTI alpha folded modulo 180 deg into the 4 bins centred on 0, 45, 90, 135 deg."""
    return int(round((alpha % math.pi) / (math.pi / 4))) % 4


def difficulty_ok(obj, level: str) -> bool:
    h = obj.height_px
    if level == "easy":
        return h >= 40 and obj.occluded == 0 and obj.truncated <= 0.15
    if level == "moderate":
        return h >= 25 and obj.occluded <= 1 and obj.truncated <= 0.30
    if level == "hard":
        return h >= 25 and obj.occluded <= 2 and obj.truncated <= 0.50
    return True  # "all": every labelled car


def tracking_frames(dparams: DisparityParams):
    seq = TrackingSequence.open(TRACKING, "0005")
    geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    frames = []
    for f in seq.frame_ids:
        left, right = seq.read_stereo(f)
        cars = [o for o in seq.objects(f) if o.type == "Car"]
        frames.append((compute_disparity(left, right, dparams), cars))
    return seq, geo, frames


def occlude(disp: np.ndarray, obj, geo: StereoGeometry, share: float, depth_ratio: float):
    """A copy of ``disp`` where a nearer surface (at depth_ratio x the car's depth) hides the
    left ``share`` of the car's box over its full height (and everything below it)."""
    out = disp.copy()
    x1, y1, x2, y2 = (int(round(v)) for v in obj.bbox)
    z = float(obj.location[2])
    xe = x1 + int(round(share * (x2 - x1)))
    top = max(y1 - 10, 0)
    out[top:, max(x1 - 10, 0) : xe] = geo.disparity_at_depth(depth_ratio * z)
    return out


def ranging_errors(seq, geo, frames, rparams: RangingParams, occluder=None):
    """Per car: (obj, estimated position or None, ground-truth centre of mass, left frame).

    ``occluder`` = (share, depth_ratio) pastes a synthetic occluder into each car's box first."""
    out = []
    for disp, cars in frames:
        if not cars:
            continue
        if occluder is not None:
            for o in cars:
                d_occ = occlude(disp, o, geo, *occluder)
                r = range_boxes(d_occ, [o.bbox], geo, rparams, [orientation_bin(o.alpha)])[0]
                gt = seq.calib.cam0_to_left(o.centre_of_mass)
                out.append((o, None if r is None else r.position, gt, r))
            continue
        boxes = np.array([o.bbox for o in cars])
        bins = [orientation_bin(o.alpha) for o in cars]
        res = range_boxes(disp, boxes, geo, rparams, bins)
        for o, r in zip(cars, res, strict=True):
            gt = seq.calib.cam0_to_left(o.centre_of_mass)
            out.append((o, None if r is None else r.position, gt, r))
    return out


def summarise(rows, level: str) -> str:
    sel = [r for r in rows if difficulty_ok(r[0], level)]
    if not sel:
        return f"| {level} | 0 | - | - | - | - | - |"
    ranged = [r for r in sel if r[1] is not None]
    err = np.array([abs(r[1][2] - r[2][2]) for r in ranged])
    err3 = np.array([np.linalg.norm(r[1] - r[2]) for r in ranged])
    n = len(sel)
    return (
        f"| {level} | {n} | {len(ranged) / n:.2f} | {np.median(err):.2f} | "
        f"{np.sum(err <= 1.5) / n:.2f} | {np.sum(err <= 3.0) / n:.2f} | {np.median(err3):.2f} |"
    )


def bench_ranging(dparams: DisparityParams) -> None:
    seq, geo, frames = tracking_frames(dparams)
    base = replace(PREVIOUS_DEFAULTS, centre_correction=False)  # the estimators alone
    geo_off = (0.8, 1.4, 2.0, 1.4)  # w/2, corner, l/2 of a 1.6 x 4 m car per orientation bin
    half_off = tuple(0.5 * v for v in geo_off)
    none = (0.0,) * 4
    variants = {
        "median, no offset": replace(base, method="median", depth_offset=none),
        "robust, no offset": replace(base, depth_offset=none),
        "robust without height prior, no offset": replace(
            base, prior_log_sigma=0.0, depth_offset=none
        ),
        "robust without core restriction, no offset": replace(
            base, core_fraction=1.0, depth_offset=none
        ),
        "robust without ground rejection, no offset": replace(
            base, reject_ground=False, depth_offset=none
        ),
        "median + car offset (0.8,1.4,2.0,1.4)": replace(
            base, method="median", depth_offset=geo_off
        ),
        "robust + car offset (0.8,1.4,2.0,1.4)": replace(base, depth_offset=geo_off),
        "robust + half car offset": replace(base, depth_offset=half_off),
        "robust without far weighting, no offset": replace(base, far_weight=0.0, depth_offset=none),
        "previous defaults (before issue #13)": PREVIOUS_DEFAULTS,
    }
    print("\n## Ranging, KITTI tracking 0005 (16 frames), labelled Car boxes as input")
    print(f"disparity: downscale={dparams.downscale} use_wls={dparams.use_wls}; error = |z - z_gt|")
    print(
        "against the label's centre of mass in the left frame; shares over all boxes of the level"
    )
    print("(unranged boxes count as misses)")
    for name, rp in variants.items():
        rows = ranging_errors(seq, geo, frames, rp)
        print(f"\n### {name}")
        print("| level | boxes | ranged | median abs dz m | <=1.5 m | <=3 m | median 3D err m |")
        print("|---|---|---|---|---|---|---|")
        for level in ("easy", "moderate", "hard", "all"):
            print(summarise(rows, level))
    print("\n### Synthetic occlusion on the real disparity maps: a surface at 0.6 (0.8) x the")
    print("car's depth hides the left 30/50/70 % of each box over its full height (moderate cars)")
    print("| occluded share | depth ratio | estimator | median abs dz m | <=1.5 m | <=3 m |")
    print("|---|---|---|---|---|---|")
    for share in (0.3, 0.5, 0.7):
        for ratio in (0.6, 0.8):
            for name in ("median, no offset", "previous defaults (before issue #13)"):
                rows = ranging_errors(seq, geo, frames, variants[name], occluder=(share, ratio))
                c = [x.strip() for x in summarise(rows, "moderate").split("|")]
                print(f"| {share:.0%} | {ratio} | {name} | {c[4]} | {c[5]} | {c[6]} |")
    # signed surface-to-centre residual per orientation bin (to choose depth_offset)
    rows = ranging_errors(seq, geo, frames, replace(base, depth_offset=(0.0,) * 4))
    res_d = [
        r[3].disparity - geo.disparity_at_depth(r[2][2])
        for r in ranging_errors(seq, geo, frames, base)
        if r[3] is not None and difficulty_ok(r[0], "moderate")
    ]
    print(
        f"\ndefault: disparity residual d_est - fB/z_gt over moderate cars: median "
        f"{np.median(res_d):+.2f} px, robust std 1.4826*MAD = "
        f"{1.4826 * np.median(np.abs(res_d - np.median(res_d))):.2f} px, "
        f"1.4826*median|res| = {1.4826 * np.median(np.abs(res_d)):.2f} px (sigma_d)"
    )
    print("\nrobust, no offset: median signed z_gt - z_est per orientation bin (moderate cars)")
    for b in range(4):
        res = [
            r[2][2] - r[1][2]
            for r in rows
            if r[1] is not None
            and difficulty_ok(r[0], "moderate")
            and orientation_bin(r[0].alpha) == b
        ]
        if res:
            print(f"  bin {b}: n={len(res)} median {np.median(res):+.2f} m")


CLASSES = ("Car", "Van")
DIST_BUCKETS = ((0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 45.0), (45.0, 1e9))


def centre_records(root: Path, sequence: str, dparams: DisparityParams, variants: dict):
    """Per labelled Car/Van box: dict with the label, its centre of mass (left frame), and per
    variant the RangeResult (or None). Disparity computed once per frame (default params)."""
    seq = TrackingSequence.open(root, sequence)
    geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    out = []
    for f in seq.frame_ids:
        objs = [o for o in seq.objects(f) if o.type in CLASSES]
        if not objs:
            continue
        left, right = seq.read_stereo(f)
        disp = compute_disparity(left, right, dparams)
        boxes = np.array([o.bbox for o in objs])
        bins = [alpha_to_bin(o.alpha) for o in objs]
        images = (to_gray(left), to_gray(right))
        res = {
            name: range_boxes(disp, boxes, geo, rp, bins, images) for name, rp in variants.items()
        }
        for i, o in enumerate(objs):
            com = seq.calib.cam0_to_left(np.asarray(o.centre_of_mass, float)[None])[0]
            out.append({"obj": o, "bin": bins[i], "com": com, **{k: v[i] for k, v in res.items()}})
    return out


def _errors(recs, variant: str):
    """Arrays over ranged records: signed error along the ray [m] (+ = estimate farther than
    the centre of mass), signed z error, 3D distance, lateral error, predicted ray/lateral std."""
    rows = []
    for r in recs:
        res = r[variant]
        if res is None:
            continue
        p, c = res.position, r["com"]
        ray = p / np.linalg.norm(p)
        lat = np.cross(ray, [0.0, 1.0, 0.0])
        lat /= np.linalg.norm(lat)
        rows.append(
            (
                float((p - c) @ ray),
                float(p[2] - c[2]),
                float(np.linalg.norm(p - c)),
                float((p - c) @ lat),
                float(np.sqrt(ray @ res.covariance @ ray)),
                float(np.sqrt(lat @ res.covariance @ lat)),
            )
        )
    return np.array(rows).reshape(-1, 6)


def _robust_std(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if x.size else float("nan")


def _centre_line(label: str, recs, variant: str) -> str:
    n = len(recs)
    e = _errors(recs, variant)
    if n == 0 or e.size == 0:
        return f"| {label} | {n} | - | - | - | - | - | - | - |"
    ray, dz, d3 = e[:, 0], e[:, 1], e[:, 2]
    return (
        f"| {label} | {n} | {len(e) / n:.2f} | {np.median(ray):+.2f} | {_robust_std(ray):.2f} | "
        f"{np.median(dz):+.2f} | {np.median(d3):.2f} | {np.sum(d3 <= 1.5) / n:.2f} | "
        f"{np.sum(d3 <= 3.0) / n:.2f} |"
    )


def _groups(recs):
    yield from ((lvl, [r for r in recs if difficulty_ok(r["obj"], lvl)]) for lvl in LEVELS)
    for cls in CLASSES:
        yield (
            f"moderate {cls}",
            [r for r in recs if r["obj"].type == cls and difficulty_ok(r["obj"], "moderate")],
        )
    for b in range(4):
        yield f"bin {b} ({45 * b} deg)", [r for r in recs if r["bin"] == b]
    for lo, hi in DIST_BUCKETS:
        name = f"{lo:.0f}-{hi:.0f} m" if hi < 1e8 else f">= {lo:.0f} m"
        yield name, [r for r in recs if lo <= np.linalg.norm(r["com"]) < hi]


LEVELS = ("easy", "moderate", "hard", "all")


def centre_report(title: str, recs, variants: dict, detail: tuple[str, ...]) -> None:
    """Print the centre-of-mass error tables of one data set."""
    print(f"\n## {title}: {len(recs)} labelled Car/Van boxes")
    print("ray / dz: signed error along the viewing ray / in z (+ = estimate farther than the")
    print("centre of mass); d3: 3D distance to the centre of mass; shares over all boxes of the")
    print("group (unranged = miss); spread = 1.4826 MAD of the ray error")
    hdr = (
        "| group | boxes | ranged | med ray m | spread m | med dz m | med d3 m | d3<=1.5 | d3<=3 |"
    )
    for name in variants:
        print(f"\n### {name}")
        print(hdr)
        print("|---|---|---|---|---|---|---|---|---|")
        for label, sel in _groups(recs):
            if label in LEVELS or label.startswith("moderate ") or name in detail:
                print(_centre_line(label, sel, name))
    for name in detail:
        print(f"\n### covariance check, {name}: predicted std vs measured error spread")
        print("(measured: 1.4826 median|e| incl. bias, and 1.4826 MAD around the median)")
        print(
            "| distance | n | ray pred std m | ray meas m | ray MAD m | lat pred m | lat meas m |"
        )
        print("|---|---|---|---|---|---|---|")
        for label, sel in list(_groups(recs))[-len(DIST_BUCKETS) :]:
            e = _errors(sel, name)
            if e.size == 0:
                continue
            print(
                f"| {label} | {len(e)} | {np.median(e[:, 4]):.2f} | "
                f"{1.4826 * np.median(np.abs(e[:, 0])):.2f} | {_robust_std(e[:, 0]):.2f} | "
                f"{np.median(e[:, 5]):.2f} | {1.4826 * np.median(np.abs(e[:, 3])):.2f} |"
            )


def bench_centre(dparams: DisparityParams, synth: list[str]) -> None:
    base = RangingParams()
    prev = PREVIOUS_DEFAULTS
    variants = {
        "robust, no correction": replace(prev, centre_correction=False),
        "previous defaults (visible model, no refinement, no bias)": prev,
        "previous + nearest model, lateral fit (new centre step only)": replace(
            base, refine="none", disparity_bias=0.0, disparity_bias_column=0.0
        ),
        "default without disparity_bias (no real-camera offset)": replace(
            base, disparity_bias=0.0, disparity_bias_column=0.0
        ),
        "default RangingParams()": base,
    }
    detail = (
        "previous defaults (visible model, no refinement, no bias)",
        "default without disparity_bias (no real-camera offset)",
        "default RangingParams()",
    )
    sets = [("KITTI tracking 0005 (16 frames, real)", TRACKING, "0005")]
    for spec in synth:
        root, _, name = spec.rpartition(":")
        sets.append((f"synthetic {root} sequence {name}", Path(root), name))
    for title, root, name in sets:
        recs = centre_records(root, name, dparams, variants)
        centre_report(title, recs, variants, detail)


FIT_PAIRS, REPORT_PAIRS = (0, 2, 4), (1, 3)  # KITTI 2015 pairs: bias fitted / reported
D_BINS = ((0.0, 20.0), (20.0, 40.0), (40.0, 1e9))


REGION_ESTIMATORS = (
    "a: robust on the default map",
    "b: full-res SGBM on the region",
    "c: (b) mask + box-level shift",
)
#: full-resolution left SGBM (no WLS): the matcher of estimators b and c, for the pixel-level fit
FULL_LEFT = replace(DEFAULT, downscale=1, use_wls=False, block_size=5, num_disparities=128)


def column_x2(u) -> np.ndarray:
    """((u - cx) / fx)^2 of image columns u (the regressor of the column-dependent bias)."""
    return ((np.asarray(u, float) - KITTI_GEO.cx) / KITTI_GEO.fx) ** 2


def region_records():
    """Per surface region of the 5 KITTI 2015 pairs: (pair, truth, a, b, c estimates [px], time
    of b and c [s], centre column); plus, per pair, the pixel errors (error, column regressor) of
    the default map and of FULL_LEFT for pixels with ground truth < 20 px. The robust estimator
    runs without ground rejection and height prior (windows are not cars); b, c start from a."""
    rp = replace(RangingParams(), reject_ground=False, prior_log_sigma=0.0)
    rows, pixels = [], []
    for i, (left, right, gt) in enumerate(stereo_pairs()):
        disp = compute_disparity(left, right, DEFAULT)
        full = compute_disparity(left, right, FULL_LEFT)
        lg, rg = to_gray(left), to_gray(right)
        for box, g in surface_regions(gt):
            da, _ = robust_disparity(disp, box, KITTI_GEO, rp)
            t0 = time.perf_counter()
            db, _ = box_disparity(lg, rg, box, da)
            t1 = time.perf_counter()
            dc, _ = refine_shift(lg, rg, box, da)
            t2 = time.perf_counter()
            rows.append((i, g, da, db, dc, t1 - t0, t2 - t1, 0.5 * (box[0] + box[2])))
        per = []
        for m in (disp, full):
            e = m - gt
            ok = (gt > 0) & (m > 0) & (np.abs(e) < 3)
            ok[:, :100] = False  # columns the right image does not see
            per.append((e[ok], gt[ok], np.nonzero(ok)[1].astype(float)))
        pixels.append(per)
    return np.array(rows), pixels


def bench_offset(pixels) -> None:
    """Print where the far-range offset comes from: pixel error per ground-truth bin, a linear
    fit per pair (scale vs offset) and the error per image column, for both matchers."""
    gt_bins = (0, 10, 20, 30, 40, 60, 1000)
    col_bins = (100, 300, 450, 600, 750, 900, 1050, 1250)
    print("\n## Where the far-range offset comes from (pixels with |error| < 3 px, columns >= 100)")
    for which, matcher in enumerate(("default map", "full-res left SGBM, no WLS")):
        e = np.concatenate([p[which][0] for p in pixels])
        g = np.concatenate([p[which][1] for p in pixels])
        u = np.concatenate([p[which][2] for p in pixels])
        by_gt = [
            np.median(e[(g >= a) & (g < b)]) for a, b in zip(gt_bins[:-1], gt_bins[1:], strict=True)
        ]
        print(f"{matcher}: median error per ground-truth bin {gt_bins} px: ", end="")
        print(" ".join(f"{v:+.2f}" for v in by_gt))
        fits = []
        for p in pixels:
            slope, icpt = np.polyfit(p[which][1], p[which][0], 1)
            fits.append(f"{100 * slope:+.1f} % d {icpt:+.2f}")
        print(f"  linear fit per pair (error = slope d + offset): {'; '.join(fits)}")
        near = g < 40
        by_col = [
            np.median(e[near & (u >= a) & (u < b)])
            for a, b in zip(col_bins[:-1], col_bins[1:], strict=True)
        ]
        print(f"  median error per column bin {col_bins} (ground truth < 40 px): ", end="")
        print(" ".join(f"{v:+.2f}" for v in by_col))


def pixel_column_fit(pixels, pairs, which: int) -> tuple[float, float]:
    """(b0, b2) of error = b0 + b2 ((u - cx)/fx)^2, least squares through the medians of 10
    equally populated bins of the regressor, pixels of ``pairs`` (which: 0 map, 1 full-res)."""
    far = [pixels[i][which][1] < 20 for i in pairs]
    e = np.concatenate([pixels[i][which][0][f] for i, f in zip(pairs, far, strict=True)])
    x = column_x2(np.concatenate([pixels[i][which][2][f] for i, f in zip(pairs, far, strict=True)]))
    edges = np.quantile(x, np.linspace(0, 1, 11))
    xs, ms = [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (x >= lo) & (x <= hi)
        xs.append(np.median(x[sel]))
        ms.append(np.median(e[sel]))
    b0, b2 = np.linalg.lstsq(np.c_[np.ones(len(xs)), xs], np.array(ms), rcond=None)[0]
    return float(b0), float(b2)


def bench_regions() -> dict[str, tuple[float, float]]:
    """Region-level bias and spread per disparity bin on the KITTI 2015 pairs. Bias model per
    estimator, fitted on FIT_PAIRS only: the column growth b2 from the pixels of its matcher,
    the constant b0 from its far-bin regions given b2; reported on REPORT_PAIRS. Returns
    {estimator: (b0, b2)} and {estimator + ' constant': (median far-bin error, 0)}."""
    rows, pixels = region_records()
    bench_offset(pixels)
    print("\n## Column model of the offset: pixel errors, ground truth < 20 px")
    print("error = b0 + b2 ((u - cx) / fx)^2 (medians of 10 bins of the regressor, columns >= 100)")
    print("| matcher | pairs | b0 px | b2 px |")
    print("|---|---|---|---|")
    b2_of = {}
    for which, matcher in enumerate(("default map", "full-res left SGBM, no WLS")):
        for label, pairs in (("fit", FIT_PAIRS), ("report", REPORT_PAIRS), ("all", range(5))):
            b0, b2 = pixel_column_fit(pixels, pairs, which)
            print(f"| {matcher} | {label} {tuple(pairs)} | {b0:+.2f} | {b2:+.2f} |")
            if label == "fit":
                b2_of[which] = b2
    print("\n## Region-level disparity error, KITTI Stereo 2015 training 000000..000004")
    print("car-sized windows on one surface (bench_stereo.surface_regions); error = estimate -")
    print("the surface's mean ground truth; bias = median, spread = 1.4826 MAD; ok = share")
    print("estimated; 'model': after subtracting the bias model fitted on the fit pairs")
    fitted: dict[str, tuple[float, float]] = {}
    far = rows[:, 1] < 20
    fit = np.isin(rows[:, 0], FIT_PAIRS)
    x2 = column_x2(rows[:, 7])
    for k, name in enumerate(REGION_ESTIMATORS):
        e = rows[:, 2 + k] - rows[:, 1]
        sel = fit & far & np.isfinite(e)
        b2 = b2_of[0 if k == 0 else 1]
        fitted[name] = (float(np.median(e[sel] - b2 * x2[sel])), b2)
        fitted[name + " constant"] = (float(np.median(e[sel])), 0.0)
    print(
        f"bias models fitted on pairs {FIT_PAIRS} (b0 + b2 x^2): "
        + ", ".join(f"{n[0]} {b0:+.2f} {b2:+.2f}" for n, (b0, b2) in fitted.items() if len(n) > 9)
    )
    print("| pairs | bin px | n | estimator | ok | bias | spread | bias, model | spread, model |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, pairs in (
        ("all", range(5)),
        (f"fit {FIT_PAIRS}", FIT_PAIRS),
        (f"report {REPORT_PAIRS}", REPORT_PAIRS),
    ):
        for lo, hi in D_BINS:
            sel = np.isin(rows[:, 0], pairs) & (rows[:, 1] >= lo) & (rows[:, 1] < hi)
            bin_name = f"{lo:.0f}-{hi:.0f}" if hi < 1e8 else f">{lo:.0f}"
            for k, name in enumerate(REGION_ESTIMATORS):
                e = rows[sel, 2 + k] - rows[sel, 1]
                ok = np.isfinite(e)
                if not ok.any():
                    continue
                b0, b2 = fitted[name]
                ec = e[ok] - (b0 + b2 * x2[sel][ok])
                print(
                    f"| {label} | {bin_name} | {int(sel.sum())} | {name} | {ok.mean():.2f} | "
                    f"{np.median(e[ok]):+.2f} | {_robust_std(e[ok]):.2f} | "
                    f"{np.median(ec):+.2f} | {_robust_std(ec):.2f} |"
                )
    small = rows[:, 1] < 40
    print(
        f"time per region (disparity < 40 px): b median {1000 * np.median(rows[small, 5]):.2f} "
        f"ms, c median {1000 * np.median(rows[small, 6]):.2f} ms"
    )
    return fitted


FAR_BUCKETS = ((0.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 45.0), (45.0, 1e9))


def far_variants(fitted: dict[str, tuple[float, float]]) -> dict[str, RangingParams]:
    """Ranging variants of the far-car table (centre step: default; biases from bench_regions)."""
    base = RangingParams()
    a, b, c = (fitted[n] for n in REGION_ESTIMATORS)
    c_const = fitted[REGION_ESTIMATORS[2] + " constant"]

    def biased(p: RangingParams, model: tuple[float, float]) -> RangingParams:
        return replace(p, disparity_bias=model[0], disparity_bias_column=model[1])

    return {
        "a: robust map, no bias correction": biased(replace(base, refine="none"), (0.0, 0.0)),
        f"a: robust map, bias {a[0]:+.2f} {a[1]:+.2f} x^2": biased(replace(base, refine="none"), a),
        f"b: full-res region SGBM, bias {b[0]:+.2f} {b[1]:+.2f} x^2": biased(
            replace(base, refine="region_sgbm"), b
        ),
        "c: box-level shift, no bias correction": biased(base, (0.0, 0.0)),
        f"c: box-level shift, constant bias {c_const[0]:+.2f}": biased(base, c_const),
        f"c: box-level shift, bias {c[0]:+.2f} {c[1]:+.2f} x^2": biased(base, c),
        "c + column bias, previous centre step (visible model, no lateral fit)": biased(
            replace(base, surface_model="visible", lateral_fit=False), c
        ),
        "default RangingParams()": base,
    }


def bench_far(fitted: dict[str, tuple[float, float]]) -> None:
    """Signed depth error of each labelled Car of tracking 0005 per distance bin, per variant."""
    variants = far_variants(fitted)
    recs = [
        r for r in centre_records(TRACKING, "0005", DEFAULT, variants) if r["obj"].type == "Car"
    ]
    print("\n## Far cars: labelled Cars of KITTI tracking 0005 (16 frames, oracle boxes)")
    print(
        "signed depth error (z_est - z_com) / z_com of the ranged centre vs the label's centre of"
    )
    print("mass (left frame), median per distance bin [%]; spread = 1.4826 MAD [%]; n = boxes")
    print(
        "| variant | " + " | ".join(_bucket_name(lo, hi) for lo, hi in FAR_BUCKETS) + " | > 30 m |"
    )
    print("|---|" + "---|" * (len(FAR_BUCKETS) + 1))
    for name in variants:
        cells = []
        for lo, hi in (*FAR_BUCKETS, (30.0, 1e9)):
            sel = [r for r in recs if lo <= r["com"][2] < hi and r[name] is not None]
            if not sel:
                cells.append("-")
                continue
            e = np.array([100 * (r[name].position[2] / r["com"][2] - 1) for r in sel])
            cells.append(f"{np.median(e):+.1f} / {_robust_std(e):.1f} (n={len(e)})")
        print(f"| {name} | " + " | ".join(cells) + " |")


def _bucket_name(lo: float, hi: float) -> str:
    return f"{lo:.0f}-{hi:.0f} m" if hi < 1e8 else f">= {lo:.0f} m"


OBJECT = SHARED / "object" / "training"


def box_surface_depth(obj, calib, us: np.ndarray, vs: np.ndarray) -> np.ndarray:
    """Depth z [m] (left optical frame) where the rays of pixels (us, vs) of the left image
    enter the labelled 3D box of ``obj`` (slab test in the box frame); nan where they miss."""
    h, w, l = (float(v) for v in obj.dimensions)
    bottom = calib.cam0_to_left(np.asarray(obj.location, float))
    c, s = np.cos(obj.rotation_y), np.sin(obj.rotation_y)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # box frame -> camera
    d = np.stack([(us - calib.cx) / calib.fx, (vs - calib.cy) / calib.fy, np.ones_like(us)], -1)
    o = rot.T @ -bottom  # camera origin in the box frame
    db = d @ rot  # ray directions in the box frame (rows: rot.T @ d)
    lo, hi = np.array([-l / 2, -h, -w / 2]), np.array([l / 2, 0.0, w / 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - o) / db, (hi - o) / db
    t_in = np.nanmax(np.minimum(t1, t2), axis=-1)
    t_out = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (t_in <= t_out) & (t_in > 0)
    return np.where(hit, t_in, np.nan)  # t is the depth (ray z component is 1)


def real_car_views():
    """Labelled Cars of tracking 0005 (16 frames) and of object training 000000..000100 (with
    calib and 3D labels): (source, obj, calib, image width)."""
    seq = TrackingSequence.open(TRACKING, "0005")
    width = read_png(seq.left_path(seq.frame_ids[0])).shape[1]
    for f in seq.frame_ids:
        for o in seq.objects(f):
            if o.type == "Car":
                yield "0005", o, seq.calib, width
    for fr in list_object_frames(OBJECT):
        if not (fr.root / "calib" / f"{fr.frame_id}.txt").is_file():
            continue
        cars = [o for o in fr.objects() if o.type == "Car" and o.dimensions[0] > 0]
        if not cars:
            continue
        width = cv2.imread(str(fr.left_path), cv2.IMREAD_GRAYSCALE).shape[1]
        calib = fr.calib()
        for o in cars:
            yield "object", o, calib, width


def centre_step_records(variants: dict[str, RangingParams]):
    """Per real labelled car: the centre step of each variant applied to the car's TRUE visible
    surface (a disparity map rendered from the labelled 3D box over the 2D box, other pixels
    invalid; orientation bin from the label's alpha): dicts with case, distance and 3D error."""
    out = []
    for source, o, calib, width in real_car_views():
        x1, y1, x2, y2 = (int(round(v)) for v in o.bbox)
        x1, y1 = max(x1, 0), max(y1, 0)
        if x2 - x1 < 4 or y2 - y1 < 4:
            continue
        vs, us = np.mgrid[y1 : y2 + 1, x1 : x2 + 1].astype(float)
        z = box_surface_depth(o, calib, us, vs)
        geo = StereoGeometry.from_projections(calib.P2, calib.P3)
        disp = np.full((y2 + 2, max(width, x2 + 2)), -1.0, np.float32)
        disp[y1 : y2 + 1, x1 : x2 + 1] = np.where(
            np.isfinite(z), geo.fx * geo.baseline / np.where(np.isfinite(z), z, 1.0), -1.0
        )
        disp = disp[:, :width]
        com = calib.cam0_to_left(o.centre_of_mass)
        b = alpha_to_bin(o.alpha)
        truncated = o.truncated > 0.05 or o.bbox[0] <= 2 or o.bbox[2] >= width - 3
        view = ("side", "oblique", "rear", "oblique")[b]
        rec = {"source": source, "case": "truncated" if truncated else view, "com": com}
        for name, rp in variants.items():
            r = range_boxes(disp, [o.bbox], geo, rp, [b])[0]
            rec[name] = None if r is None else r.position
        out.append(rec)
    return out


def bench_centre_real() -> None:
    """Error of the box-to-centre step on real labelled cars given their true visible surface."""
    exact = replace(RangingParams(), refine="none", disparity_bias=0.0, disparity_bias_column=0.0)
    variants = {
        "no centre step (visible surface on the box-centre ray)": replace(
            exact, centre_correction=False, lateral_fit=False
        ),
        "depth step only (before)": replace(
            exact, surface_model="visible", truncated_surface_model="visible", lateral_fit=False
        ),
        "visible-face depth step + lateral fit": replace(
            exact, surface_model="visible", truncated_surface_model="visible"
        ),
        "nearest-corner depth step + lateral fit": replace(
            exact, surface_model="nearest", truncated_surface_model="nearest"
        ),
        "default (RangingParams(), exact disparities)": exact,
    }
    recs = centre_step_records(variants)
    print("\n## Box-to-centre step on real labelled Cars, given the TRUE visible surface")
    print("tracking 0005 (16 frames) + object training 000000..000100; disparity rendered from")
    print("the labelled 3D box over its 2D box; bin from the label's alpha (oracle detector).")
    print("side = bin 0, rear/front = bin 2, oblique = bins 1/3; truncated = truncation > 0.05 or")
    print("box at the image border. near < 20 m <= far (centre of mass). Cells: median 3D error m")
    print(
        "/ median signed error along the ray m (+ = too far) / median |lateral| m / share <= 1.5 m"
    )
    print("Model choice made on the object frames (tuning); 0005 reported apart.")
    print("| data | case | range | n | " + " | ".join(variants) + " |")
    print("|---|---|---|---|" + "---|" * len(variants))
    for source in ("object", "0005"):
        for case in ("side", "rear", "oblique", "truncated", "all"):
            for rng_name, lo, hi in (("near", 0.0, 20.0), ("far", 20.0, 1e9), ("all", 0.0, 1e9)):
                sel = [
                    r
                    for r in recs
                    if r["source"] == source
                    and (case == "all" or r["case"] == case)
                    and lo <= np.linalg.norm(r["com"]) < hi
                ]
                if not sel:
                    continue
                cells = [_centre_cell(sel, name) for name in variants]
                print(
                    f"| {source} | {case} | {rng_name} | {len(sel)} | " + " | ".join(cells) + " |"
                )


COV_BUCKETS = ((5.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 45.0), (45.0, 60.0), (60.0, 100.0))


def covariance_errors():
    """TUNING data only. Disparity errors [px] of the default estimator (c) after the default
    bias model on the car-sized surface regions of the KITTI 2015 fit pairs, with their true
    disparity; and the centre step's signed along-ray and lateral errors [m] with the car's
    distance, for each labelled Car of the object frames (true visible surface, as
    ``centre_real``)."""
    rp = RangingParams()
    rows, _ = region_records()
    fit = np.isin(rows[:, 0], FIT_PAIRS) & np.isfinite(rows[:, 4])
    bias = rp.disparity_bias + rp.disparity_bias_column * column_x2(rows[:, 7])
    e_d = (rows[:, 4] - rows[:, 1] - bias)[fit]
    exact = replace(rp, refine="none", disparity_bias=0.0, disparity_bias_column=0.0)
    steps = []
    for r in centre_step_records({"default": exact}):
        p, c = r["default"], r["com"]
        if r["source"] != "object" or p is None:
            continue
        ray = c / np.linalg.norm(c)
        err = np.asarray(p) - c
        along = float(err @ ray)
        steps.append((float(np.linalg.norm(c)), along, float(np.linalg.norm(err - along * ray))))
    return rows[fit, 1], e_d, np.array(steps)


def _spread0(x: np.ndarray) -> float:
    """Robust spread about zero (1.4826 x median |x|): what a filter sees, bias included."""
    return float(1.4826 * np.median(np.abs(x))) if len(x) else float("nan")


def _depth_var(z: np.ndarray, p: RangingParams, fb: float) -> np.ndarray:
    """The depth variance ``position_covariance`` reports at depth z on the optical axis."""
    return (z * z * p.sigma_d / fb) ** 2 + p.depth_offset_std**2


def consistent_sigma_d(z: np.ndarray, dz: np.ndarray, fb: float) -> float:
    """sigma_d [px] that makes the median of the regions' dz^2 / var(z) the chi2(1) median
    (0.455), var(z) the disparity term alone (the regions' depths have no centre step; bisection,
    robust to the few mixed-surface regions)."""
    lo, hi = 1e-3, 5.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        p = replace(RangingParams(), sigma_d=mid, depth_offset_std=0.0)
        if np.median(dz**2 / _depth_var(z, p, fb)) > CHI2_1_MEDIAN:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


CHI2_1_MEDIAN = 0.4549


def bench_covariance() -> None:
    """The depth std the ranging reports (``position_covariance``) against the errors it makes,
    per distance bin, on tuning data; and the sigma_d / depth_offset_std / sigma_pixel those
    errors give."""
    rp = RangingParams()
    fb = KITTI_GEO.fx * KITTI_GEO.baseline
    d_true, e_d, steps = covariance_errors()
    print("\n## Measurement covariance vs real errors (TUNING data: KITTI 2015 pairs", FIT_PAIRS)
    print("regions, estimator c after the default bias model; object frames 000000..000100, the")
    print("centre step on the true visible surface). Spreads = 1.4826 median |error| (about 0).")
    far = d_true < 40
    print(
        f"disparity error (< 40 px, n={int(far.sum())}): median {np.median(e_d[far]):+.2f} px, "
        f"spread {_spread0(e_d[far]):.2f} px (< 20 px: {_spread0(e_d[d_true < 20]):.2f}, "
        f"20-40 px: {_spread0(e_d[(d_true >= 20) & far]):.2f})"
    )
    along, lateral = steps[:, 1], steps[:, 2]
    lat_px = lateral * KITTI_GEO.fx / steps[:, 0]
    print(
        f"centre step (n={len(steps)}): along-ray spread {_spread0(along):.2f} m, lateral spread "
        f"{_spread0(lateral):.2f} m = {_spread0(lat_px):.2f} px"
    )
    z_reg = fb / d_true
    dz_reg = fb / (d_true + e_d) - z_reg
    offset = _spread0(along)
    sigma_d = consistent_sigma_d(z_reg, dz_reg, fb)
    fitted = replace(rp, sigma_d=sigma_d, depth_offset_std=offset)
    print(
        f"consistent values (depth_offset_std = the centre step's along-ray spread; sigma_d such "
        f"that the regions' squared depth errors over the disparity term have the chi2(1) "
        f"median 0.455): "
        f"sigma_d {sigma_d:.3f} px (default {rp.sigma_d}), depth_offset_std {offset:.3f} m "
        f"(default {rp.depth_offset_std}); sigma_pixel: lateral spread above (default "
        f"{rp.sigma_pixel})"
    )
    for name, p in (("defaults", rp), ("consistent values", fitted)):
        r_reg = dz_reg**2 / _depth_var(z_reg, replace(p, depth_offset_std=0.0), fb)
        r_car = along**2 / p.depth_offset_std**2
        print(
            f"  {name}: squared normalised depth error, median / share < 1 (chi2(1): 0.455 / "
            f"0.68): regions (disparity term) {np.median(r_reg):.3f} / {np.mean(r_reg < 1):.2f}, "
            f"cars (centre step) {np.median(r_car):.3f} / {np.mean(r_car < 1):.2f}"
        )
    print(
        "| range [m] | regions | cars | actual depth std [m] | reported (defaults) | ratio | "
        "reported (consistent values) | ratio |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for lo, hi in COV_BUCKETS:
        sel = (z_reg >= lo) & (z_reg < hi)
        near = (steps[:, 0] >= lo) & (steps[:, 0] < hi)
        step_sd = _spread0(along[near]) if near.sum() >= 5 else _spread0(along)
        actual = math.hypot(_spread0(dz_reg[sel]), step_sd) if sel.sum() >= 5 else float("nan")
        zm = 0.5 * (lo + hi)
        rep, rep_fit = (
            math.sqrt(position_covariance(KITTI_GEO.cx, KITTI_GEO.cy, zm, KITTI_GEO, p)[2, 2])
            for p in (rp, fitted)
        )
        print(
            f"| {lo:.0f}-{hi:.0f} | {int(sel.sum())} | {int(near.sum())} | {actual:.2f} | "
            f"{rep:.2f} | {actual / rep:.2f} | {rep_fit:.2f} | {actual / rep_fit:.2f} |"
        )


def _centre_cell(recs, name: str) -> str:
    errs = []
    for r in recs:
        p, c = r[name], r["com"]
        if p is None:
            continue
        ray = c / np.linalg.norm(c)
        lat = np.cross(ray, [0.0, 1.0, 0.0])
        lat /= np.linalg.norm(lat)
        errs.append((np.linalg.norm(p - c), (p - c) @ ray, abs((p - c) @ lat)))
    if not errs:
        return "-"
    e = np.array(errs)
    share = np.sum(e[:, 0] <= 1.5) / len(recs)
    return (
        f"{np.median(e[:, 0]):.2f} / {np.median(e[:, 1]):+.2f} / {np.median(e[:, 2]):.2f} / "
        f"{share:.2f}"
    )


def bench_timing(variants: dict[str, DisparityParams], repeats: int) -> None:
    seq = TrackingSequence.open(TRACKING, "0005")
    geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    frames = [
        seq.read_stereo(f) + ([o.bbox for o in seq.objects(f) if o.type == "Car"],)
        for f in seq.frame_ids[:4]
    ]
    print(
        f"\n## Time per frame, disparity + ranging, 1242x375, cv2.setNumThreads(2), "
        f"median of {repeats}x{len(frames)} frames"
    )
    print("variants interleaved round-robin so that load changes hit all alike")
    print("| variant | median ms | p90 ms | ratio to L+R+WLS full res 128 |")
    print("|---|---|---|---|")
    times: dict[str, list[float]] = {name: [] for name in variants}
    rtimes, new_rtimes, frame_old, frame_new = [], [], [], []
    old_ranging = replace(RangingParams(), refine="none")
    for _ in range(repeats):
        for name, p in variants.items():
            for left, right, boxes in frames:
                t0 = time.perf_counter()
                d = compute_disparity(left, right, p)
                t1 = time.perf_counter()
                range_boxes(d, np.array(boxes).reshape(-1, 4), geo, old_ranging)
                t2 = time.perf_counter()
                times[name].append(t2 - t0)
                rtimes.append(t2 - t1)
                if p is DEFAULT:  # new ranging path (refinement on the gray pair), same frame
                    t3 = time.perf_counter()
                    images = (to_gray(left), to_gray(right))
                    range_boxes(
                        d, np.array(boxes).reshape(-1, 4), geo, RangingParams(), None, images
                    )
                    new_rtimes.append(time.perf_counter() - t3)
                    frame_old.append(t2 - t0)
                    frame_new.append(t1 - t0 + new_rtimes[-1])
    ref = 1000 * np.median(times[next(iter(variants))])
    for name, ts in times.items():
        med = 1000 * np.median(ts)
        print(f"| {name} | {med:.0f} | {1000 * np.percentile(ts, 90):.0f} | {med / ref:.2f} |")
    n_boxes = np.mean([len(b) for _, _, b in frames])
    print(
        f"ranging step alone (range_boxes, {n_boxes:.1f} boxes/frame): median "
        f"{1000 * np.median(rtimes):.2f} ms without refinement, {1000 * np.median(new_rtimes):.2f} "
        "ms with the default refinement (incl. gray conversion)"
    )
    print(
        f"default disparity + ranging per frame: old path (refine none) "
        f"{1000 * np.median(frame_old):.1f} ms, new path {1000 * np.median(frame_new):.1f} ms, "
        f"ratio new/old {np.median(frame_new) / np.median(frame_old):.3f}"
    )


def bench_odometry() -> None:
    """Visual odometry on the 16 stereo frames of tracking 0005 against its labelled cars: a
    static car's centre must move as R p + t predicts (its residual is then the odometry's
    error at that car); timing per frame against the default disparity map of the same frame."""
    seq = TrackingSequence.open(TRACKING, "0005")
    geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    frames = []
    for f in seq.frame_ids:
        left, right = seq.read_stereo(f)
        cars = {
            o.track_id: seq.calib.cam0_to_left(np.asarray(o.location, float))
            - [0.0, o.dimensions[0] / 2, 0.0]
            for o in seq.objects(f)
            if o.type == "Car"
        }
        boxes = [o.bbox for o in seq.objects(f) if o.type != "DontCare"]
        t0 = time.perf_counter()
        d = compute_disparity(left, right, DEFAULT)
        frames.append((f, to_gray(left), d, boxes, cars, time.perf_counter() - t0))
    bias = disparity_bias_at(np.arange(frames[0][2].shape[1]), geo, RangingParams())
    print("\n## Visual odometry, KITTI tracking 0005 (16 frames, ego car at about 17.5 m/s)")
    print("residual = |R p_k + t - p_k+1| of each labelled Car centre (a parked car: the error")
    print("of the odometry there; a moving one: its own motion); step = |t| per frame [m]")
    print("| disparity bias | pairs with motion | median step m | labelled median step m |")
    print("|---|---|---|---|")
    detail = []
    for label, b in (("KITTI model (default)", bias), ("none", 0.0)):
        odo = FrameToFrameOdometry()
        steps, label_steps, vo_t = [], [], []
        prev: dict = {}
        prev_boxes: list = []
        for f, gray, d, boxes, cars, _ in frames:
            t0 = time.perf_counter()
            m = odo.step(int(f * 1e8), gray, d, geo, prev_boxes, b)
            prev_boxes = boxes
            vo_t.append(time.perf_counter() - t0)
            if m is not None:
                steps.append(float(np.linalg.norm(m.translation)))
                for tid in cars.keys() & prev.keys():
                    label_steps.append(float(np.linalg.norm(cars[tid] - prev[tid])))
                    if b is bias:
                        res = m.rotation @ prev[tid] + m.translation - cars[tid]
                        detail.append((tid, float(cars[tid][2]), float(np.linalg.norm(res))))
            prev = cars
        print(
            f"| {label} | {len(steps)} / {len(frames) - 1} | {np.median(steps):.2f} | "
            f"{np.median(label_steps):.2f} |"
        )
        if b is bias:
            odo_ms = 1000 * np.median(vo_t[1:])
    by_car: dict[int, list] = {}
    for tid, z, res in detail:
        by_car.setdefault(tid, []).append((z, res))
    print("| labelled car | range m | median residual m | max residual m |")
    print("|---|---|---|---|")
    for tid, rows in sorted(by_car.items()):
        z, res = np.array(rows).T
        print(f"| {tid} | {z.min():.0f}-{z.max():.0f} | {np.median(res):.2f} | {res.max():.2f} |")
    disp_ms = 1000 * np.median([fr[5] for fr in frames])
    print(
        f"time per frame: odometry {odo_ms:.1f} ms (median), default disparity map of the same "
        f"frame {disp_ms:.1f} ms, ratio {odo_ms / disp_ms:.2f}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument(
        "section",
        nargs="?",
        default="all",
        choices=[
            "disparity",
            "ranging",
            "regions",
            "far",
            "centre",
            "centre_keyframes",
            "centre_bias",
            "centre_real",
            "timing",
            "covariance",
            "odometry",
            "plausibility",
            "plausibility_range",
            "box_steps",
            "occluder",
            "all",
        ],
    )
    ap.add_argument("--synth", action="append", default=[], help="ROOT:SEQ of kitti_synth data")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--road-map",
        choices=stereo_real.ROAD_MAPS,
        default="band",
        help="plausibility: the map 0005's road plane is fitted to (band: the band's map; own, "
        "shared: the node's road_map with map_area boxes)",
    )
    args = ap.parse_args()
    if not (SHARED / "README.md").is_file():
        print(f"error: {SHARED}: KITTI samples not found", file=sys.stderr)
        return 2
    cv2.setNumThreads(2)
    variants = {"L+R+WLS, full res, 128 disp": FULL}  # reference first (ratios)
    variants.update(VARIANTS)
    variants["default (DisparityParams())"] = DEFAULT
    if args.section in ("disparity", "all"):
        bench_disparity({**VARIANTS, "default (DisparityParams())": DEFAULT})
    if args.section in ("ranging", "all"):
        bench_ranging(DEFAULT)
    fitted = {}
    if args.section in ("regions", "far", "all"):
        fitted = bench_regions()
    if args.section in ("far", "all"):
        bench_far(fitted)
    if args.section in ("centre_real", "all"):
        bench_centre_real()
    if args.section in ("centre", "all"):
        stereo_real.bench_centre_keyframes()
        bench_centre(DEFAULT, args.synth)
    if args.section == "centre_keyframes":
        stereo_real.bench_centre_keyframes()
    if args.section in ("centre_bias", "all"):
        stereo_real.bench_centre_bias()
    if args.section in ("covariance", "all"):
        bench_covariance()
    if args.section in ("odometry", "all"):
        bench_odometry()
    if args.section in ("plausibility", "all"):
        stereo_real.bench_plausibility(args.road_map)
    if args.section in ("plausibility_range", "all"):
        stereo_real.bench_plausibility_range()
    if args.section in ("box_steps", "all"):
        stereo_real.bench_box_steps()
    if args.section in ("occluder", "all"):
        stereo_real.bench_occluder()
    if args.section in ("timing", "all"):
        bench_timing(variants, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
