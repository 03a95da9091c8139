"""The **oracle** backend, for ablations only: it republishes ground-truth 2D boxes (with optional
noise, fixed score and random drops) instead of running a detector.

:class:`StampPairing` pairs left images with the ground truth of the same stamp (they arrive on
different topics, in either order) with small bounded caches, so that exactly one output is
produced per image.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
from vehicle_common.kitti import KittiObject
from vehicle_common.orientation_bins import NUM_BINS, alpha_to_bin, fold_alpha_signed

from .detection import Detection


@dataclass
class OracleDetector:
    """Ground-truth boxes as detections: cars (+ the other ``positive_types``), not DontCare.

    ``box_noise_px``: std of Gaussian noise added to each box edge [px]; ``score``: score given
    to every box; ``drop_probability``: chance of dropping each box; ``seed`` seeds the noise.
    Orientation: the bin of the label's alpha, with probability 1, and the label's alpha folded
    into [-pi/2, pi/2) as the continuous angle with variance 0 (-1 when the label has none).
    """

    positive_types: tuple[str, ...] = ("Car", "Van")
    box_noise_px: float = 0.0
    score: float = 1.0
    drop_probability: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)

    @classmethod
    def from_parameters(cls, p) -> OracleDetector:
        """The node's oracle of its parameters ``p`` (:class:`.parameters.DetectorParameters`)."""
        return cls(
            positive_types=tuple(p.vehicle_types),
            box_noise_px=p.oracle_box_noise_px,
            score=p.oracle_score,
            drop_probability=p.oracle_drop_probability,
            seed=p.oracle_seed,
        )

    def detect(
        self, objects: list[KittiObject], image_size: tuple[int, int] | None = None
    ) -> list[Detection]:
        """Detections from the label rows of one frame (``image_size`` = (w, h) clips boxes)."""
        out = []
        for o in objects:
            if o.type not in self.positive_types:
                continue
            if self.drop_probability > 0 and self._rng.random() < self.drop_probability:
                continue
            box = np.array(o.bbox, dtype=float)
            if self.box_noise_px > 0:
                box = box + self._rng.normal(0.0, self.box_noise_px, 4)
            x1, x2 = sorted((box[0], box[2]))
            y1, y2 = sorted((box[1], box[3]))
            if image_size is not None:
                x1, x2 = np.clip([x1, x2], 0, image_size[0])
                y1, y2 = np.clip([y1, y2], 0, image_size[1])
            b = alpha_to_bin(o.alpha)
            probs = tuple(1.0 if i == b else 0.0 for i in range(NUM_BINS))
            known = o.alpha >= -np.pi - 1e-6  # KITTI's -10 = unknown
            out.append(
                Detection(
                    (float(x1), float(y1), float(x2), float(y2)),
                    float(self.score),
                    b,
                    probs,
                    observation_angle=float(fold_alpha_signed(o.alpha)) if known else 0.0,
                    observation_angle_variance=0.0 if known else -1.0,
                )
            )
        return out


class StampPairing:
    """Pairs images and ground-truth messages by exact stamp.

    ``add_image`` / ``add_labels`` return the (image, labels) pairs now complete. An image
    waiting longer than ``max_pending`` newer images is released with labels ``None`` (the
    caller publishes an empty array, keeping one output per image); label messages not claimed
    by an image are kept for the last ``max_labels`` stamps.
    """

    def __init__(self, max_pending: int = 10, max_labels: int = 30) -> None:
        self.max_pending = max_pending
        self.max_labels = max_labels
        self._images: OrderedDict[int, Any] = OrderedDict()
        self._labels: OrderedDict[int, Any] = OrderedDict()

    def add_image(self, stamp_ns: int, image: Any) -> list[tuple[Any, Any]]:
        if stamp_ns in self._labels:
            return [(image, self._labels.pop(stamp_ns))]
        self._images[stamp_ns] = image
        released = []
        while len(self._images) > self.max_pending:
            _, old = self._images.popitem(last=False)
            released.append((old, None))
        return released

    def add_labels(self, stamp_ns: int, labels: Any) -> list[tuple[Any, Any]]:
        if stamp_ns in self._images:
            return [(self._images.pop(stamp_ns), labels)]
        self._labels[stamp_ns] = labels
        while len(self._labels) > self.max_labels:
            self._labels.popitem(last=False)
        return []

    @property
    def pending_images(self) -> int:
        return len(self._images)
