"""Training/validation data from KITTI object (image_2/label_2) and tracking (image_02/label_02)
layouts, read through the player's KITTI reader; resizing, targets and augmentation.

A data source is written ``ROOT`` (every sequence of a tracking layout, or every frame of an
object layout) or ``ROOT:SEQ,SEQ`` (selected tracking sequences). Objects whose type is in
``positive_types`` (default Car and Van) are positives; DontCare regions are kept apart so the
loss does not penalise detections there as background; other types are background.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from vehicle_common.kitti import (
    DONTCARE,
    KittiFormatError,
    KittiObject,
    TrackingSequence,
    list_object_frames,
    list_tracking_sequences,
    read_png,
)
from vehicle_common.orientation_bins import alpha_to_bin, flip_bin


@dataclass
class FrameRef:
    """One labelled frame on disk."""

    image_path: Path
    objects: list[KittiObject]
    name: str


@dataclass
class Sample:
    """One frame resized to the network input.

    ``boxes`` (N, 4) positives in input px, ``bins`` (N,) orientation bins, ``dontcare`` (M, 4)
    ignore regions in input px, ``scale`` (sx, sy) = input px per original px.
    """

    image: np.ndarray
    boxes: np.ndarray
    bins: np.ndarray
    dontcare: np.ndarray
    scale: tuple[float, float]
    name: str = ""


def parse_source(spec: str) -> tuple[Path, list[str] | None]:
    """``ROOT`` or ``ROOT:SEQ,SEQ`` -> (root, sequences or None)."""
    root, sep, seqs = spec.partition(":")
    if sep and seqs:
        return Path(root), [s.strip() for s in seqs.split(",") if s.strip()]
    return Path(spec), None


def frames_from_source(spec: str) -> list[FrameRef]:
    """Every labelled frame of one data source (see module docstring)."""
    root, seqs = parse_source(spec)
    if (root / "image_2").is_dir():
        return [
            FrameRef(f.left_path, f.objects(), f"{root.name}/{f.frame_id}")
            for f in list_object_frames(root)
        ]
    if not (root / "image_02").is_dir():
        raise KittiFormatError(
            f"{root}: neither a KITTI object (image_2) nor tracking (image_02) root"
        )
    refs = []
    for seq in seqs if seqs is not None else list_tracking_sequences(root):
        ts = TrackingSequence.open(root, seq)
        if ts.labels is None:
            raise KittiFormatError(
                f"{root / 'label_02' / (ts.sequence + '.txt')}: labels not found"
            )
        for fid in ts.frame_ids:
            refs.append(FrameRef(ts.left_path(fid), ts.objects(fid), f"{ts.sequence}/{fid:06d}"))
    return refs


def sources_from_args(specs: list[str]) -> list[FrameRef]:
    """All frames of several sources."""
    refs: list[FrameRef] = []
    for spec in specs:
        refs.extend(frames_from_source(spec))
    if not refs:
        raise KittiFormatError(f"{', '.join(specs)}: no frames found")
    return refs


def split_objects(
    objects: list[KittiObject], positive_types: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positive boxes (N, 4), their orientation bins (N,), DontCare boxes (M, 4)), original px."""
    pos = [o for o in objects if o.type in positive_types]
    dc = [o for o in objects if o.type == DONTCARE]
    boxes = np.array([o.bbox for o in pos], dtype=np.float32).reshape(-1, 4)
    bins = np.array([alpha_to_bin(o.alpha) for o in pos], dtype=np.int64)
    dcb = np.array([o.bbox for o in dc], dtype=np.float32).reshape(-1, 4)
    return boxes, bins, dcb


def resize_image(
    rgb: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, tuple[float, float]]:
    """Resize to the network input; returns the image and (sx, sy) input px per original px.

    KITTI's 1242x375 (aspect 3.31) goes to e.g. 640x192 (3.33) or 1152x352 (3.27): the slight
    anisotropy is kept in the scale factors, so no letterbox is needed.
    """
    h, w = rgb.shape[:2]
    out = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
    return out, (width / w, height / h)


def load_sample(ref: FrameRef, width: int, height: int, positive_types: tuple[str, ...]) -> Sample:
    """Read a frame and its labels at network resolution."""
    img, (sx, sy) = resize_image(read_png(ref.image_path), width, height)
    boxes, bins, dc = split_objects(ref.objects, positive_types)
    s = np.array([sx, sy, sx, sy], dtype=np.float32)
    boxes, dc = boxes * s, dc * s
    keep = ((boxes[:, 2] - boxes[:, 0]) >= 2) & ((boxes[:, 3] - boxes[:, 1]) >= 2)
    return Sample(img, boxes[keep], bins[keep], dc, (sx, sy), ref.name)


def collect_box_sizes(refs: list[FrameRef], width: int, height: int, positive_types=("Car", "Van")):
    """Widths/heights (N, 2) of all positive boxes, in network-input px (for k-means)."""
    sizes = []
    for ref in refs:
        boxes, _, _ = split_objects(ref.objects, tuple(positive_types))
        if not len(boxes):
            continue
        img_w, img_h = _image_size(ref.image_path)
        wh = np.stack([boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]], axis=1)
        sizes.append(wh * np.array([width / img_w, height / img_h]))
    if not sizes:
        raise KittiFormatError("training data: no positive boxes found")
    sizes = np.concatenate(sizes)
    return sizes[(sizes > 1).all(axis=1)]


_SIZE_CACHE: dict[Path, tuple[int, int]] = {}


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image; one read per folder (KITTI frames share a size)."""
    key = path.parent
    if key not in _SIZE_CACHE:
        img = read_png(path)
        _SIZE_CACHE[key] = (img.shape[1], img.shape[0])
    return _SIZE_CACHE[key]


def flip_sample(sample: Sample) -> Sample:
    """Horizontal flip: boxes mirrored, orientation bins 45 <-> 135 (orientation_bins)."""
    w = sample.image.shape[1]
    b = sample.boxes.copy()
    b[:, [0, 2]] = w - sample.boxes[:, [2, 0]]
    d = sample.dontcare.copy()
    d[:, [0, 2]] = w - sample.dontcare[:, [2, 0]]
    return Sample(
        np.ascontiguousarray(sample.image[:, ::-1]),
        b,
        flip_bin(sample.bins),
        d,
        sample.scale,
        sample.name,
    )


def colour_jitter(image: np.ndarray, rng: np.random.Generator, strength: float = 0.3) -> np.ndarray:
    """Random brightness, contrast and saturation (uint8 RGB in, uint8 out)."""
    x = image.astype(np.float32)
    gray = x.mean(axis=2, keepdims=True)
    x = gray + (x - gray) * rng.uniform(1 - strength, 1 + strength)  # saturation
    m = x.mean()
    x = m + (x - m) * rng.uniform(1 - strength, 1 + strength)  # contrast
    x = x * rng.uniform(1 - strength, 1 + strength)  # brightness
    return np.clip(x, 0, 255).astype(np.uint8)


def augment(
    sample: Sample, rng: np.random.Generator, flip: bool = True, jitter: bool = True
) -> Sample:
    """Training augmentation: colour jitter and horizontal flip (no random crop)."""
    if flip and rng.random() < 0.5:
        sample = flip_sample(sample)
    if jitter:
        sample = Sample(
            colour_jitter(sample.image, rng),
            sample.boxes,
            sample.bins,
            sample.dontcare,
            sample.scale,
            sample.name,
        )
    return sample


def add_data_arguments(parser: argparse.ArgumentParser, train_only: bool = False) -> None:
    """Data options shared by ``detector_train`` and ``detector_anchors``."""
    parser.add_argument(
        "--train",
        nargs="+",
        required=True,
        metavar="ROOT[:SEQ,...]",
        help="KITTI object or tracking roots (tracking: optionally :SEQ,SEQ)",
    )
    if not train_only:
        parser.add_argument(
            "--val",
            nargs="*",
            default=[],
            metavar="ROOT[:SEQ,...]",
            help="held-out data for the per-epoch validation AP",
        )
    parser.add_argument(
        "--types",
        nargs="+",
        default=["Car", "Van"],
        help="label types counted as vehicles (default: Car Van)",
    )
