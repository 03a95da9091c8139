"""Raw vs compressed images (the player's ``image_transport``) on real KITTI tracking 0005.

Usage: python bench/bench_image_transport.py [--sequence 0005] [--repeats 3]

For each setting (raw rgb8, PNG lossless, JPEG quality 90 and 75), on every stereo pair of the
sequence (../shared/kitti, 16 pairs of 0005): bytes per image and the link's rate at 10 Hz (two
images per frame; three when the detector and stereo depth run on the other host, as the left
image then crosses once per subscribing process), CPU per image of the player's encoding and of
a subscriber's decoding (vehicle_common.image_conversion, what the nodes call; ratios against
the raw conversion in the same run, with the load average), and what the decoded images change
downstream, through the nodes' cores with their defaults:
- ranging: the labelled Car boxes ranged on the disparity of the decoded pair (as the oracle
  detector gives them: orientation bin from the label): share ranged, median |z - z_gt| of the
  centre of mass, and median |z - z_raw| against the raw images' estimate;
- detection: the CNN on the decoded left image: detections, and their agreement with the raw
  image's (matched at IoU >= 0.5, mean IoU of the matches, largest score change).
The whole graph's figures per setting come from the demo (docs/bags_and_cameras.md).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from detector_node.loading import load_detector
from stereo_depth_node.disparity import DisparityParams, compute_disparity
from stereo_depth_node.ranging import RangingSetup, range_boxes
from stereo_depth_node.region_matching import to_gray
from stereo_depth_node.reprojection import StereoGeometry
from vehicle_common.box2d import iou_2d
from vehicle_common.image_conversion import (
    image_to_rgb,
    numpy_to_compressed,
    numpy_to_image,
)
from vehicle_common.kitti import TrackingSequence

TRACKING = Path(__file__).resolve().parents[1] / ".." / "shared" / "kitti" / "tracking" / "training"
SETTINGS = {
    "raw": ("raw", 0),
    "png": ("png", 0),
    "jpeg q=90": ("jpeg", 90),
    "jpeg q=75": ("jpeg", 75),
}


def encode(rgb: np.ndarray, transport: str, quality: int):
    if transport == "raw":
        return numpy_to_image(rgb, "rgb8")
    return numpy_to_compressed(rgb, transport, quality)


def timed(fn, repeats: int) -> tuple[float, object]:
    """(best time of ``repeats`` calls [s], the last result)."""
    best, out = math.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def orientation_bin(alpha: float) -> int:
    return int(round((alpha % math.pi) / (math.pi / 4))) % 4


def _measure_setting(transport, quality, repeats, seq, geo, pairs, cars, detector) -> dict:
    """One transport setting: mean bytes per image, encode and decode s per image, the
    labelled cars ranged on the decoded pairs ((z, z_gt) or None each), the detections."""
    dparams, ranging = DisparityParams(), RangingSetup.from_params()
    sizes, t_enc, t_dec, decoded = [], 0.0, 0.0, []
    for left, right in pairs:
        out = []
        for img in (left, right):
            te, msg = timed(lambda i=img, t=transport, q=quality: encode(i, t, q), repeats)
            td, rgb = timed(lambda msg=msg: image_to_rgb(msg), repeats)
            t_enc, t_dec = t_enc + te, t_dec + td
            sizes.append(len(msg.data))
            out.append(rgb)
        decoded.append(out)
    n = 2 * len(pairs)
    rows, dets = [], []
    for (left, right), boxes in zip(decoded, cars, strict=True):
        disp = compute_disparity(left, right, dparams)
        if boxes:
            bins = [orientation_bin(o.alpha) for o in boxes]
            images = (to_gray(left), to_gray(right))
            res = range_boxes(disp, [o.bbox for o in boxes], geo, ranging, bins, images)
            for o, r in zip(boxes, res, strict=True):
                gt = seq.calib.cam0_to_left(o.centre_of_mass)[2]
                rows.append(None if r is None else (float(r.position[2]), float(gt)))
        dets.append(detector.detect(left))
    return dict(bytes=float(np.mean(sizes)), enc=t_enc / n, dec=t_dec / n, rows=rows, dets=dets)


def _print_size_table(results: dict) -> None:
    raw = results["raw"]
    base = raw["enc"] + raw["dec"]
    print(
        "\n| setting | bytes/image | ratio | Mbit/s, 2 images @10 Hz | 3 images (split graph) "
        "| encode ms/image | decode ms/image | (enc+dec) / raw |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        mbit = r["bytes"] * 8 * 10 / 1e6
        print(
            f"| {name} | {r['bytes']:.0f} | {r['bytes'] / raw['bytes']:.3f} | {2 * mbit:.1f} "
            f"| {3 * mbit:.1f} | {1e3 * r['enc']:.1f} | {1e3 * r['dec']:.1f} "
            f"| {(r['enc'] + r['dec']) / base:.1f} |"
        )


def _print_quality_table(results: dict) -> None:
    raw = results["raw"]
    print(
        "\n| setting | cars ranged | median abs(z - z_gt) [m] | median abs(z - z_raw) [m] "
        "| max abs(z - z_raw) [m] | detections | matched to raw (IoU>=0.5) | mean IoU | "
        "max score change |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        ranged = [(x, y) for x, y in zip(r["rows"], raw["rows"], strict=True) if x and y]
        err = [abs(z - g) for z, g in (x for x in r["rows"] if x)]
        dz = [abs(a[0] - b[0]) for a, b in ranged]
        n_det = sum(map(len, r["dets"]))
        matched, ious, dscore = 0, [], [0.0]
        for ds, dr in zip(r["dets"], raw["dets"], strict=True):
            if not ds or not dr:
                continue
            m = iou_2d(np.array([d.box for d in ds]), np.array([d.box for d in dr]))
            for i in range(len(ds)):
                j = int(np.argmax(m[i]))
                if m[i, j] >= 0.5:
                    matched += 1
                    ious.append(m[i, j])
                    dscore.append(abs(ds[i].score - dr[j].score))
        print(
            f"| {name} | {len(err)}/{len(r['rows'])} | {np.median(err):.2f} | "
            f"{np.median(dz):.3f} | {np.max(dz):.2f} | {n_det} | {matched}/{n_det} | "
            f"{np.mean(ious):.3f} | {max(dscore):.3f} |"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequence", default="0005")
    ap.add_argument("--repeats", type=int, default=3, help="timing: best of N")
    args = ap.parse_args(argv)
    if not (TRACKING / "image_03" / args.sequence).is_dir():
        print(f"error: {TRACKING / 'image_03' / args.sequence}: no right images", file=sys.stderr)
        return 2
    cv2.setNumThreads(1)
    import torch

    torch.set_num_threads(1)
    seq = TrackingSequence.open(TRACKING, args.sequence)
    geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
    pairs = [seq.read_stereo(f) for f in seq.frame_ids]
    cars = [[o for o in seq.objects(f) if o.type == "Car"] for f in seq.frame_ids]
    detector = load_detector("", "cpu")
    print(
        f"KITTI tracking {args.sequence}: {len(pairs)} stereo pairs {pairs[0][0].shape[1]}x"
        f"{pairs[0][0].shape[0]}, {sum(map(len, cars))} labelled Car boxes; "
        f"load average {os.getloadavg()[0]:.2f}"
    )

    results = {
        name: _measure_setting(transport, quality, args.repeats, seq, geo, pairs, cars, detector)
        for name, (transport, quality) in SETTINGS.items()
    }
    _print_size_table(results)
    _print_quality_table(results)
    print(f"load average at the end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
