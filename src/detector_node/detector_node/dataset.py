"""Training/validation data from KITTI object (image_2/label_2) and tracking (image_02/label_02)
layouts, read through the player's KITTI label reader (left images and labels only): frame
selection, labels -> :class:`Sample`, resizing (augmentation: :mod:`detector_node.augmentation`).

A data source is written ``ROOT`` (every sequence of a tracking layout, or every frame of an
object layout), ``ROOT:SEQ,SEQ`` (selected tracking sequences; also for a ``tracking_keyframes``
layout: ``image_2/SSSS_NNNNNN.png`` + ``frames.csv``, labelled by the rows of frame NNNNNN in
``../tracking/training/label_02/SSSS.txt``) or ``ROOT:IDS`` (object frames by
id and inclusive id range, e.g. ``ROOT:0-59,80-100``); training sources may add ``@WEIGHT`` (the
sampling weight, :func:`parse_weighted_source`). Objects whose type is in
``positive_types`` (default Car and Van) are positives; DontCare regions are kept apart so the
loss does not penalise detections there as background; other types are background.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
from vehicle_common.kitti import (
    DONTCARE,
    KittiFormatError,
    KittiObject,
    list_object_frames,
    list_tracking_sequences,
    read_png,
    read_tracking_labels,
)
from vehicle_common.orientation_bins import alpha_to_bin


@dataclass
class FrameRef:
    """One labelled frame on disk."""

    image_path: Path
    objects: list[KittiObject]
    name: str


@dataclass
class Sample:
    """One frame resized to the network input.

    ``boxes`` (N, 4) positives in input px, ``bins`` (N,) orientation bins (-1: unknown, no
    alpha in the label), ``dontcare`` (M, 4) ignore regions in input px, ``scale`` (sx, sy) =
    input px per original px.
    """

    image: np.ndarray
    boxes: np.ndarray
    bins: np.ndarray
    dontcare: np.ndarray
    scale: tuple[float, float]
    name: str = ""
    #: (N,) truncation of each box in [0, 1] (None = unknown, taken as 0)
    truncation: np.ndarray | None = None
    #: (N,) KITTI occlusion flag of each box (None = unknown)
    occluded: np.ndarray | None = None
    #: (N,) observation angle alpha [rad] of each box, NaN = unknown (None = all unknown)
    alphas: np.ndarray | None = None
    #: (N, 2) where each box was seen: its centre (x, y) in the frame it was labelled in, as
    #: inference frames that frame, normalised to [0, 1]; scale jitter and crops move a box in
    #: the network input but not its viewing ray (``detector_train --true-view``); None =
    #: where the box is now
    view: np.ndarray | None = None


def sample_alphas(sample: Sample) -> np.ndarray:
    """(N,) alphas of a sample's boxes, NaN where unknown."""
    if sample.alphas is None:
        return np.full(len(sample.boxes), np.nan, np.float32)
    return sample.alphas


def box_view(boxes: np.ndarray, width: float, height: float) -> np.ndarray:
    """(N, 2) box centres normalised by the frame size (see :attr:`Sample.view`)."""
    b = np.asarray(boxes, np.float32).reshape(-1, 4)
    return np.stack([(b[:, 0] + b[:, 2]) / (2 * width), (b[:, 1] + b[:, 3]) / (2 * height)], 1)


def sample_view(sample: Sample) -> np.ndarray:
    """(N, 2) :attr:`Sample.view` of a sample's boxes (where they are now when not set)."""
    if sample.view is not None:
        return sample.view
    h, w = sample.image.shape[:2]
    return box_view(sample.boxes, w, h)


def select_boxes(sample: Sample, keep: np.ndarray) -> Sample:
    """``sample`` with only the boxes where ``keep`` holds, and their per-box fields (bins,
    truncation, occlusion, alphas, view) with them."""
    return replace(
        sample,
        boxes=sample.boxes[keep],
        bins=sample.bins[keep],
        truncation=None if sample.truncation is None else sample.truncation[keep],
        occluded=None if sample.occluded is None else sample.occluded[keep],
        alphas=None if sample.alphas is None else sample.alphas[keep],
        view=None if sample.view is None else sample.view[keep],
    )


def parse_source(spec: str) -> tuple[Path, list[str] | None]:
    """``ROOT`` or ``ROOT:SEQ,SEQ`` -> (root, sequences or None)."""
    root, sep, seqs = spec.partition(":")
    if sep and seqs:
        return Path(root), [s.strip() for s in seqs.split(",") if s.strip()]
    return Path(spec), None


def parse_weighted_source(spec: str) -> tuple[str, float]:
    """``SOURCE@WEIGHT`` -> (SOURCE, WEIGHT); no ``@`` -> weight 1."""
    source, sep, weight = spec.rpartition("@")
    if not sep:
        return spec, 1.0
    try:
        w = float(weight)
    except ValueError:
        raise ValueError(f"{spec}: sampling weight {weight!r} is not a number") from None
    if not (w >= 0.0 and math.isfinite(w)):
        raise ValueError(f"{spec}: sampling weight must be a finite number >= 0")
    return source, w


def _expand_ids(items: list[str]) -> set[int]:
    """Object frame selection: ids and inclusive ranges ``A-B`` -> set of ints."""
    out: set[int] = set()
    for item in items:
        lo, sep, hi = item.partition("-")
        try:
            out.update(range(int(lo), int(hi) + 1) if sep else [int(lo)])
        except ValueError:
            raise ValueError(f"{item}: not a frame id or id range A-B") from None
    return out


def frames_from_source(spec: str) -> list[FrameRef]:
    """Every labelled frame of one data source (see module docstring). For an object layout,
    ``ROOT:IDS`` selects frames by id (ids and inclusive ranges, e.g. ``ROOT:0-79,100``)."""
    root, seqs = parse_source(spec)
    if (root / "frames.csv").is_file() and (root / "image_2").is_dir():
        return _keyframes(root, seqs)
    if (root / "image_2").is_dir():
        wanted = _expand_ids(seqs) if seqs is not None else None
        return [
            FrameRef(f.left_path, f.objects(), f"{root.name}/{f.frame_id}")
            for f in list_object_frames(root)
            if wanted is None or int(f.frame_id) in wanted
        ]
    if not (root / "image_02").is_dir():
        raise KittiFormatError(
            f"{root}: neither a KITTI object (image_2) nor tracking (image_02) root"
        )
    refs = []
    for seq in seqs if seqs is not None else list_tracking_sequences(root):
        seq = f"{int(seq):04d}" if seq.isdigit() else seq
        # left images and labels only (no calib or right images needed for the detector)
        left = root / "image_02" / seq
        if not left.is_dir():
            raise KittiFormatError(f"{left}: image folder of sequence {seq} not found")
        label_path = root / "label_02" / f"{seq}.txt"
        if not label_path.is_file():
            raise KittiFormatError(f"{label_path}: labels not found")
        labels = read_tracking_labels(label_path)
        for png in sorted(left.glob("*.png")):
            fid = int(png.stem)
            refs.append(FrameRef(png, list(labels.get(fid, [])), f"{seq}/{fid:06d}"))
    return refs


def _keyframes(root: Path, seqs: list[str] | None) -> list[FrameRef]:
    """Frames of a ``tracking_keyframes`` layout (see module docstring), optionally of some
    sequences only; labels from the tracking layout beside it."""
    label_dir = root.parent / "tracking" / "training" / "label_02"
    wanted = None if seqs is None else {f"{int(s):04d}" if s.isdigit() else s for s in seqs}
    refs, labels = [], {}
    for png in sorted((root / "image_2").glob("*_*.png")):
        seq, _, frame = png.stem.partition("_")
        if (wanted is not None and seq not in wanted) or not frame.isdigit():
            continue
        if seq not in labels:
            path = label_dir / f"{seq}.txt"
            if not path.is_file():
                raise KittiFormatError(f"{path}: labels of keyframe sequence {seq} not found")
            labels[seq] = read_tracking_labels(path)
        refs.append(FrameRef(png, list(labels[seq].get(int(frame), [])), f"kf{seq}/{frame}"))
    return refs


def sources_from_args(specs: list[str]) -> list[FrameRef]:
    """All frames of several sources."""
    refs: list[FrameRef] = []
    for spec in specs:
        refs.extend(frames_from_source(spec))
    if not refs:
        raise KittiFormatError(f"{', '.join(specs)}: no frames found")
    return refs


def label_bin(alpha: float) -> int:
    """Orientation bin of a label's alpha, -1 for KITTI's 'unknown' placeholder -10 (any alpha
    below -pi)."""
    return -1 if alpha < -math.pi - 1e-6 else alpha_to_bin(alpha)


def split_objects(
    objects: list[KittiObject], positive_types: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positive boxes (N, 4), their orientation bins (N,; -1 unknown), DontCare boxes (M, 4)),
    original px."""
    pos = [o for o in objects if o.type in positive_types]
    dc = [o for o in objects if o.type == DONTCARE]
    boxes = np.array([o.bbox for o in pos], dtype=np.float32).reshape(-1, 4)
    bins = np.array([label_bin(o.alpha) for o in pos], dtype=np.int64)
    dcb = np.array([o.bbox for o in dc], dtype=np.float32).reshape(-1, 4)
    return boxes, bins, dcb


def label_alphas(objects: list[KittiObject], positive_types) -> np.ndarray:
    """(N,) alphas of the positives, NaN for KITTI's 'unknown' placeholder -10."""
    pos = [o for o in objects if o.type in positive_types]
    return np.array(
        [np.nan if o.alpha < -math.pi - 1e-6 else o.alpha for o in pos], dtype=np.float32
    )


def _positive_flags(objects: list[KittiObject], positive_types) -> tuple[np.ndarray, np.ndarray]:
    """(truncation, occlusion) of the positives; the -1 placeholders of 2D-only labels -> 0."""
    pos = [o for o in objects if o.type in positive_types]
    trunc = np.array([max(o.truncated, 0.0) for o in pos], dtype=np.float32)
    occl = np.array([max(o.occluded, 0) for o in pos], dtype=np.int64)
    return trunc, occl


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


def load_full_sample(ref: FrameRef, positive_types: tuple[str, ...]) -> Sample:
    """Read a frame and its labels at its own resolution (any size; scale (1, 1))."""
    boxes, bins, dc = split_objects(ref.objects, positive_types)
    trunc, occl = _positive_flags(ref.objects, positive_types)
    alphas = label_alphas(ref.objects, positive_types)
    return Sample(
        read_png(ref.image_path), boxes, bins, dc, (1.0, 1.0), ref.name, trunc, occl, alphas
    )


def load_sample(ref: FrameRef, width: int, height: int, positive_types: tuple[str, ...]) -> Sample:
    """Read a frame and its labels at network resolution (boxes under 2 px dropped)."""
    img, (sx, sy) = resize_image(read_png(ref.image_path), width, height)
    boxes, bins, dc = split_objects(ref.objects, positive_types)
    trunc, occl = _positive_flags(ref.objects, positive_types)
    s = np.array([sx, sy, sx, sy], dtype=np.float32)
    boxes, dc = boxes * s, dc * s
    keep = ((boxes[:, 2] - boxes[:, 0]) >= 2) & ((boxes[:, 3] - boxes[:, 1]) >= 2)
    alphas = label_alphas(ref.objects, positive_types)
    sample = Sample(img, boxes, bins, dc, (sx, sy), ref.name, trunc, occl, alphas)
    return select_boxes(sample, keep)


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
    """(width, height) of an image (object frames differ slightly in size)."""
    key = path
    if key not in _SIZE_CACHE:
        img = read_png(path)
        _SIZE_CACHE[key] = (img.shape[1], img.shape[0])
    return _SIZE_CACHE[key]


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
