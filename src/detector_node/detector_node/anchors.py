"""Anchor shapes by k-means over training box sizes with the distance 1 - IoU (YOLOv2).

CLI ``detector_anchors``: reads KITTI object/tracking layouts, prints and saves the anchors
(in pixels of the network input) as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from .boxes import shape_iou


def kmeans_anchors(
    wh: np.ndarray, k: int = 5, seed: int = 0, iterations: int = 300, restarts: int = 5
) -> tuple[np.ndarray, float]:
    """Cluster box sizes ``wh`` (N, 2) into ``k`` anchors with distance 1 - IoU.

    k-means++ seeding (in 1 - IoU), median updates, the best of ``restarts`` runs by mean IoU.
    Returns the anchors sorted by area (k, 2) and the mean IoU of each box with its best anchor.
    """
    wh = np.asarray(wh, dtype=float).reshape(-1, 2)
    if wh.shape[0] < k:
        raise ValueError(f"need at least {k} boxes for {k} anchors, got {wh.shape[0]}")
    rng = np.random.default_rng(seed)
    best: tuple[np.ndarray, float] | None = None
    for _ in range(restarts):
        centres = _kmeans_once(wh, k, rng, iterations)
        mean_iou = float(shape_iou(wh, centres).max(axis=1).mean())
        if best is None or mean_iou > best[1]:
            best = (centres, mean_iou)
    centres, mean_iou = best
    return centres[np.argsort(centres[:, 0] * centres[:, 1])], mean_iou


def _kmeans_once(wh: np.ndarray, k: int, rng: np.random.Generator, iterations: int) -> np.ndarray:
    centres = [wh[rng.integers(wh.shape[0])]]
    for _ in range(1, k):
        d = 1.0 - shape_iou(wh, np.array(centres)).max(axis=1)
        p = d**2 / (d**2).sum() if d.sum() > 0 else None
        centres.append(wh[rng.choice(wh.shape[0], p=p)])
    centres = np.array(centres, dtype=float)
    assign = np.full(wh.shape[0], -1)
    for _ in range(iterations):
        new_assign = np.argmax(shape_iou(wh, centres), axis=1)
        if np.array_equal(new_assign, assign):
            break
        assign = new_assign
        for j in range(k):
            members = wh[assign == j]
            if len(members):
                centres[j] = np.median(members, axis=0)
            else:  # re-seed an empty cluster on the worst-covered box
                centres[j] = wh[np.argmin(shape_iou(wh, centres).max(axis=1))]
    return centres


def main(argv: list[str] | None = None) -> int:
    """``detector_anchors``: k-means anchors from KITTI training labels."""
    from vehicle_common.kitti import KittiFormatError

    from .dataset import add_data_arguments, collect_box_sizes, sources_from_args

    parser = argparse.ArgumentParser(prog="detector_anchors", description=__doc__)
    add_data_arguments(parser, train_only=True)
    parser.add_argument("-k", type=int, default=5, help="number of anchors (default 5)")
    parser.add_argument("--input-width", type=int, default=640)
    parser.add_argument("--input-height", type=int, default=192)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, help="JSON file to save the anchors to")
    args = parser.parse_args(argv)
    try:
        sources = sources_from_args(args.train)
        wh = collect_box_sizes(sources, args.input_width, args.input_height, tuple(args.types))
        anchors, mean_iou = kmeans_anchors(wh, k=args.k, seed=args.seed)
    except (KittiFormatError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    result = {
        "anchors": [[round(float(w), 2), round(float(h), 2)] for w, h in anchors],
        "input_width": args.input_width,
        "input_height": args.input_height,
        "boxes": int(wh.shape[0]),
        "mean_iou": round(mean_iou, 4),
    }
    print(json.dumps(result))
    if args.output:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
