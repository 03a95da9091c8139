"""The training mix: data sources of three kinds sampled by weight, each with its augmentation
pipeline, producing network-input :class:`~detector_node.dataset.Sample` objects.

Kinds of source:

- ``real``: real KITTI frames with complete labels (object or tracking layout), kept at full
  resolution; pipeline: copy-paste of real car crops (probability ``paste_probability``, 1 to
  ``paste_max`` cars), scale jitter + random crop keeping the frame's aspect (probability
  ``crop_probability``), resize, horizontal flip, photometric jitter / blur / noise; each box
  keeps where it was seen (``Sample.view``, set before the crops; a pasted car's is its
  source's);
- ``partial``: native-resolution crops with incomplete Car-only labels (``object_crops352``): each
  is pasted at its native position into a random real frame (its area ignored for the background
  term, see :func:`~detector_node.augmentation.paste_native_crop`), then the ``real`` pipeline;
- ``synthetic``: renderer frames, stored at network resolution; flip and photometric only.

Each epoch draws ``n`` samples: a source with probability weight / sum of weights, then a frame of
it uniformly. The real:synthetic ratio is therefore the ratio of the weights.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .augmentation import (
    RowSizeModel,
    collect_car_crops,
    crop_roi_top,
    flip_sample,
    paste_cars,
    paste_native_crop,
    photometric,
    random_crop,
    resize_sample,
)
from .dataset import Sample, sample_view, select_boxes

KINDS = ("real", "partial", "synthetic")


@dataclass
class Source:
    """One data source: its frames, kind and sampling weight."""

    name: str
    kind: str
    samples: list[Sample]
    weight: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"{self.name}: kind must be one of {KINDS}, got {self.kind!r}")


@dataclass
class AugmentConfig:
    """Probabilities and ranges of the augmentations (see module docstring)."""

    flip: bool = True
    photometric: bool = True
    crop_probability: float = 0.6
    min_scale: float = 0.6
    max_scale: float = 1.0
    paste_probability: float = 0.5
    paste_max: int = 3
    blur_probability: float = 0.25
    noise_probability: float = 0.3
    #: the checkpoint's region of interest (DetectorConfig.roi_top): the top of each real frame
    #: is left out before the scale jitter, as inference does before the resize
    roi_top: float = 0.0


def _fully_visible(s: Sample) -> np.ndarray:
    """Mask of boxes neither truncated nor occluded (for the row-size model)."""
    ok = np.ones(len(s.boxes), bool)
    if s.truncation is not None:
        ok &= s.truncation < 0.05
    if s.occluded is not None:
        ok &= s.occluded == 0
    return ok


class TrainingMix:
    """Weighted sampling over sources and the per-kind augmentation pipeline."""

    def __init__(
        self, sources: list[Source], width: int, height: int, augment: AugmentConfig | None = None
    ) -> None:
        self.sources = [s for s in sources if s.samples and s.weight > 0]
        if not self.sources:
            raise ValueError("training data: no source with frames and a positive weight")
        self.width, self.height = width, height
        self.aug = augment or AugmentConfig()
        w = np.array([s.weight for s in self.sources], float)
        self.probabilities = w / w.sum()
        real = [x for s in self.sources if s.kind == "real" for x in s.samples]
        if any(s.kind == "partial" for s in self.sources) and not real:
            raise ValueError("a 'partial' source needs a 'real' source for its backgrounds")
        self.backgrounds = real
        self.car_crops = collect_car_crops(real)
        boxes = [s.boxes[_fully_visible(s)] for s in real if len(s.boxes)]
        all_boxes = np.concatenate(boxes) if boxes else np.zeros((0, 4), np.float32)
        try:
            self.rows: RowSizeModel | None = RowSizeModel.fit(all_boxes)
        except ValueError:  # too few real boxes: no copy-paste
            self.rows = None

    def summary(self) -> str:
        parts = [
            f"{s.name} ({s.kind}, {len(s.samples)} frames, p={p:.2f})"
            for s, p in zip(self.sources, self.probabilities, strict=True)
        ]
        r = self.rows
        rows = f"h = {r.slope:.3f} (y2 - {r.horizon:.1f}), spread {r.spread:.2f}" if r else "none"

        return f"sources: {'; '.join(parts)}; {len(self.car_crops)} car crops; row model {rows}"

    def draw(self, n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
        """``n`` (source index, frame index) pairs."""
        src = rng.choice(len(self.sources), size=n, p=self.probabilities)
        return [(int(k), int(rng.integers(len(self.sources[k].samples)))) for k in src]

    def make(self, source_index: int, frame_index: int, rng: np.random.Generator) -> Sample:
        """One augmented network-input sample."""
        src = self.sources[source_index]
        s = src.samples[frame_index]
        a = self.aug
        if src.kind == "partial":
            bg = self.backgrounds[int(rng.integers(len(self.backgrounds)))]
            H, W = bg.image.shape[:2]
            ch, cw = s.image.shape[:2]
            s = paste_native_crop(bg, s, (W - cw) // 2, (H - ch) // 2)
        if src.kind in ("real", "partial"):
            if self.rows is not None and rng.random() < a.paste_probability:
                count = int(rng.integers(1, a.paste_max + 1))
                s = paste_cars(s, self.car_crops, self.rows, rng, count)
            s = replace(s, view=sample_view(s))  # where each box is seen, before any crop
            s = crop_roi_top(s, a.roi_top)
            if rng.random() < a.crop_probability:
                s = random_crop(s, rng, a.min_scale, a.max_scale)
        if s.image.shape[:2] != (self.height, self.width):
            s = resize_sample(s, self.width, self.height)
            ok = ((s.boxes[:, 2] - s.boxes[:, 0]) >= 2) & ((s.boxes[:, 3] - s.boxes[:, 1]) >= 2)
            if not ok.all():
                s = select_boxes(s, ok)
        if a.flip and rng.random() < 0.5:  # after the resize: same result, fewer pixels
            s = flip_sample(s)
        if a.photometric:
            s = photometric(s, rng, a.blur_probability, a.noise_probability)
        return s
