"""Are the ranging's depth errors heavy-tailed? (issue #41 item 4, third round; docs/tracker.md)

Depth error of 3D detections against the labels' centres, in units of the std the ranging
reports, against a Gaussian (kurtosis 3, 0.27 % beyond 3 std):

    python bench/depth_tails.py keyframes          # the 71 LiDAR keyframes, label boxes
    python bench/depth_tails.py run BAG [BAG ...]  # recorded graph runs (make demo's bag)

``keyframes``: the shipped ranging on the ground-truth disparity (the box-to-centre step, not
the matcher), split by occlusion. ``run``: the recorded 3D detections matched to labelled cars
(2D IoU >= 0.5), with the reported covariance."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

SHARED_KITTI = Path(__file__).resolve().parent.parent.parent / "shared" / "kitti"


def tail_line(name: str, u) -> str:
    u = np.asarray(u, float)
    u = u[np.isfinite(u)]
    if len(u) < 5:
        return f"{name}: n {len(u)}"
    med = float(np.median(u))
    mad = 1.4826 * float(np.median(np.abs(u - med)))
    kurt = float(np.mean((u - u.mean()) ** 4) / np.var(u) ** 2)
    return (
        f"{name}: n {len(u)}, median {med:+.2f}, 1.4826 MAD {mad:.2f}, kurtosis {kurt:.1f}, "
        f"beyond 3 reported std {100 * np.mean(np.abs(u) > 3):.1f} %, beyond 3 robust std "
        f"{100 * np.mean(np.abs(u - med) > 3 * mad):.1f} %, max |u| {np.abs(u).max():.1f}"
    )


def keyframe_rows() -> np.ndarray:
    """(true depth, error, reported std, occluded, truncated) of every labelled Car."""
    from stereo_depth_node.ground_truth import EXACT_RANGING, keyframes
    from stereo_depth_node.ranging import range_boxes
    from vehicle_common.orientation_bins import alpha_to_bin

    rows = []
    for fr in keyframes(SHARED_KITTI):
        cars = [o for o in fr.objects if o.type == "Car" and o.dimensions[0] > 0]
        if not cars:
            continue
        bins = [alpha_to_bin(o.alpha) for o in cars]
        res = range_boxes(fr.disparity, [o.bbox for o in cars], fr.geometry, EXACT_RANGING, bins)
        for o, r in zip(cars, res, strict=True):
            if r is None:
                continue
            c = fr.calib.cam0_to_left(np.asarray(o.centre_of_mass, float))
            sz = float(np.sqrt(r.covariance[2, 2]))
            rows.append((c[2], r.position[2] - c[2], sz, o.occluded, o.truncated))
    return np.array(rows).reshape(-1, 5)


def run_rows(bag: str) -> np.ndarray:
    """(true depth, error, reported std) of the run's 3D detections matched to labelled cars."""
    from tracker_node.conversions import detections_from_msg
    from vehicle_common.bags.recorded_run import read_run
    from vehicle_common.box2d import iou_2d

    rows = []
    for f in read_run(bag).frames:
        if not f.det3d_msg:
            continue
        b = detections_from_msg(f.det3d_msg)[0]
        cars, used = [o for o in f.gt if o.type == "Car"], set()
        ious = iou_2d(b.bbox, [o.bbox for o in cars])  # (detections, cars)
        for i in range(len(b)):
            best, bj = 0.5, None
            for j in range(len(cars)):
                if j not in used and ious[i, j] > best:
                    best, bj = float(ious[i, j]), j
            if bj is None:
                continue
            used.add(bj)
            c = cars[bj].centre_of_mass + f.offset  # the detections' (left optical) frame
            rows.append((c[2], b.position[i][2] - c[2], float(np.sqrt(b.covariance[i][2, 2]))))
    return np.array(rows).reshape(-1, 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("keyframes")
    r = sub.add_parser("run")
    r.add_argument("bags", nargs="+")
    args = ap.parse_args()
    if args.cmd == "keyframes":
        a = keyframe_rows()
        u = a[:, 1] / a[:, 2]
        print(tail_line("all labelled cars, error / reported std", u))
        clean = (a[:, 3] == 0) & (a[:, 4] <= 0.1)
        print(tail_line("not occluded, not truncated", u[clean]))
        print(f"  of those off by > 5 m: {100 * np.mean(np.abs(a[clean, 1]) > 5):.1f} %")
        for occ in (1, 2):
            print(tail_line(f"occlusion {occ}", u[a[:, 3] == occ]))
        return
    for bag in args.bags:
        try:
            a = run_rows(bag)
        except Exception as exc:  # noqa: BLE001 - one line naming the bag
            sys.exit(f"error: {bag}: {exc}")
        u = a[:, 1] / a[:, 2]
        print(f"{bag}:")
        print(tail_line("  error / reported std", u))
        for lo, hi in ((30, 45), (45, 100)):
            m = (a[:, 0] >= lo) & (a[:, 0] < hi)
            print(tail_line(f"  {lo}-{hi} m", u[m]))


if __name__ == "__main__":
    main()
