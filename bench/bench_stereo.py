"""Stereo depth benchmarks: disparity accuracy, ranging accuracy, time per frame.

Usage: python bench/bench_stereo.py [disparity|ranging|timing|all] [--repeats N]
Reads ../shared/kitti (KITTI Stereo 2015 training pairs 0..4 and tracking sequence 0005); prints
tables. Uses the same core functions as the stereo_depth node (compute_disparity, range_boxes).
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
from kitti_player_node.kitti import TrackingSequence, read_png
from stereo_depth_node.disparity import (
    DisparityParams,
    compute_disparity,
    d1_error,
    interpolate_background,
)
from stereo_depth_node.ranging import RangingParams, range_boxes
from stereo_depth_node.reprojection import StereoGeometry

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "kitti"
STEREO = SHARED / "stereo_2015" / "training"
TRACKING = SHARED / "tracking" / "training"

DEFAULT = DisparityParams()
VARIANTS = {
    "left SGBM (full res)": replace(DEFAULT, use_wls=False, downscale=1),
    "left+right+WLS (full res)": replace(DEFAULT, use_wls=True, downscale=1),
    "left SGBM half-res": replace(DEFAULT, use_wls=False, downscale=2),
    "L+R+WLS half-res, full-res guide": replace(DEFAULT, use_wls=True, downscale=2),
    "L+R+WLS half-res, 96 disp": replace(DEFAULT, use_wls=True, downscale=2, num_disparities=96),
    "L+R+WLS full, 96 disp": replace(DEFAULT, use_wls=True, downscale=1, num_disparities=96),
    "L+R+WLS half-res, SGBM mode": replace(DEFAULT, use_wls=True, downscale=2, mode="sgbm"),
    "L+R+WLS half-res, colour": replace(DEFAULT, use_wls=True, downscale=2, use_color=True),
}


def stereo_pairs():
    for i in range(5):
        name = f"{i:06d}_10.png"
        left = read_png(STEREO / "image_2" / name)
        right = read_png(STEREO / "image_3" / name)
        gt = cv2.imread(str(STEREO / "disp_occ_0" / name), cv2.IMREAD_UNCHANGED)
        yield left, right, gt.astype(np.float32) / 256.0


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
    return h >= 25 and obj.occluded <= 2 and obj.truncated <= 0.50


def tracking_frames(dparams: DisparityParams):
    seq = TrackingSequence.open(TRACKING, "0005")
    geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    frames = []
    for f in seq.frame_ids:
        left, right = seq.read_stereo(f)
        cars = [o for o in seq.objects(f) if o.type == "Car"]
        frames.append((compute_disparity(left, right, dparams), cars))
    return seq, geo, frames


def ranging_errors(seq, geo, frames, rparams: RangingParams):
    """Per car: (obj, estimated position or None, ground-truth centre of mass, left frame)."""
    out = []
    for disp, cars in frames:
        if not cars:
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
        return f"| {level} | 0 | - | - | - | - |"
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
    base = RangingParams()
    variants = {
        "median (box, no offset)": replace(base, method="median", depth_offset=(0.0,) * 4),
        "robust, no offset": replace(base, depth_offset=(0.0,) * 4),
        "robust, no prior, no offset": replace(base, prior_log_sigma=0.0, depth_offset=(0.0,) * 4),
        "median + default offset": replace(base, method="median"),
        "robust + default offset (default)": base,
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
        for level in ("easy", "moderate", "hard"):
            print(summarise(rows, level))
    # signed surface-to-centre residual per orientation bin (to choose depth_offset)
    rows = ranging_errors(seq, geo, frames, replace(base, depth_offset=(0.0,) * 4))
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
    print("| variant | median ms | p90 ms | ratio to L+R+WLS full |")
    print("|---|---|---|---|")
    ref = None
    for name, p in variants.items():
        ts = []
        for _ in range(repeats):
            for left, right, boxes in frames:
                t0 = time.perf_counter()
                d = compute_disparity(left, right, p)
                range_boxes(d, np.array(boxes).reshape(-1, 4), geo)
                ts.append(time.perf_counter() - t0)
        med = 1000 * np.median(ts)
        if name.startswith("left+right+WLS (full"):
            ref = med
        print(
            f"| {name} | {med:.0f} | {1000 * np.percentile(ts, 90):.0f} | "
            f"{med / ref if ref else float('nan'):.2f} |"
        )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument(
        "section", nargs="?", default="all", choices=["disparity", "ranging", "timing", "all"]
    )
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    if not (SHARED / "README.md").is_file():
        print(f"error: {SHARED}: KITTI samples not found", file=sys.stderr)
        return 2
    cv2.setNumThreads(2)
    variants = {"left+right+WLS (full res)": VARIANTS["left+right+WLS (full res)"]}
    variants.update(VARIANTS)
    if args.section in ("disparity", "all"):
        bench_disparity(VARIANTS)
    if args.section in ("ranging", "all"):
        bench_ranging(DEFAULT)
    if args.section in ("timing", "all"):
        bench_timing(variants, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
