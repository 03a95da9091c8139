"""The detector's configuration (stored in every checkpoint) and its input framing. Pure:
no torch (the ONNX Runtime path and the camera-derived settings use it without loading a
model; :mod:`detector_node.model` re-exports it)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

#: Anchors (w, h) in input pixels used before k-means anchors are available (KITTI-like cars
#: at 352x1152); training replaces them with k-means anchors of its data.
DEFAULT_ANCHORS_352x1152 = (
    (40.0, 30.0),
    (80.0, 55.0),
    (130.0, 85.0),
    (210.0, 130.0),
    (340.0, 200.0),
)


def check_roi_top(roi_top: float) -> float:
    """``roi_top`` (the top fraction of the image not searched) when in [0, 0.9), else
    ValueError."""
    if not 0.0 <= roi_top < 0.9:
        raise ValueError(f"roi_top must be in [0, 0.9), got {roi_top}")
    return roi_top


@dataclass(frozen=True)
class DetectorConfig:
    """Everything needed to rebuild a detector; stored in every checkpoint."""

    size: str = "tiny"
    width: float = 0.25
    depth: int = 1
    input_height: int = 192
    input_width: int = 640
    anchors: tuple[tuple[float, float], ...] = field(default=())
    positive_types: tuple[str, ...] = ("Car", "Van")
    #: fraction of the image height at the top left out before the resize to the input (the
    #: region above where vehicles are sought; inference.CnnDetector.detect): 0 = whole image
    roi_top: float = 0.0

    def __post_init__(self) -> None:
        check_roi_top(self.roi_top)
        if self.input_height % 32 or self.input_width % 32:
            raise ValueError(
                f"input size {self.input_width}x{self.input_height} must be multiples of 32"
            )
        if not self.anchors:
            sx, sy = self.input_width / 1152, self.input_height / 352
            scaled = tuple((w * sx, h * sy) for w, h in DEFAULT_ANCHORS_352x1152)
            object.__setattr__(self, "anchors", scaled)
        object.__setattr__(self, "anchors", tuple((float(w), float(h)) for w, h in self.anchors))
        object.__setattr__(self, "positive_types", tuple(self.positive_types))

    @property
    def num_anchors(self) -> int:
        return len(self.anchors)

    @property
    def grid(self) -> tuple[int, int]:
        """Output grid (H, W)."""
        return self.input_height // 32, self.input_width // 32

    def to_dict(self) -> dict:
        d = asdict(self)
        d["anchors"] = [list(a) for a in self.anchors]
        d["positive_types"] = list(self.positive_types)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> DetectorConfig:
        d = dict(d)
        d["anchors"] = tuple(tuple(a) for a in d.get("anchors", ()))
        d["positive_types"] = tuple(d.get("positive_types", ("Car", "Van")))
        return cls(**d)


def preset(size: str, **overrides) -> DetectorConfig:
    """The ``full`` (paper) or ``tiny`` configuration, with optional field overrides."""
    presets = {
        "full": dict(size="full", width=1.0, depth=7, input_height=352, input_width=1152),
        "tiny": dict(size="tiny", width=0.25, depth=1, input_height=192, input_width=640),
        # pretrained CenterNet (detector_node.centernet); width/depth/anchors unused
        "centernet": dict(size="centernet", width=1.0, depth=0, input_height=320, input_width=1024),
    }
    if size not in presets:
        raise ValueError(f"unknown detector size {size!r} (full | tiny | centernet)")
    return DetectorConfig(**{**presets[size], **overrides})


#: the image size the checkpoints were trained at (KITTI): an overridden input size keeps the
#: anchors at the training's input px per image px (CnnDetector.from_checkpoint)
TRAINING_IMAGE_SIZE = (1242, 375)


def geo_frame(
    training_input: tuple[int, int],
    training_roi_top: float,
    input_size: tuple[int, int],
    width: int,
    height: int,
    top: int,
    scale: tuple[float, float],
):
    """The CenterNet orientation head's box-geometry map (centernet.orientation_at) from an
    input (image of ``width`` x ``height`` px, ``top`` rows left out, resized by ``scale`` to
    ``input_size``) to its training framing (the image below its training ``roi_top`` resized
    to the training input size): centre x / width, (centre y - training top) / the rows
    below it, aspect ratio at the training's x / y scale. None when the two framings are the
    same."""
    tw, th = training_input
    t_top = int(round(training_roi_top * height))
    if top == t_top and tuple(input_size) == (tw, th):
        return None
    sx, sy = scale
    rows = height - t_top
    aspect = math.log((tw / width) / (th / rows)) - math.log(sx / sy)
    return (1.0 / (sx * width), 0.0, 1.0 / (sy * rows), (top - t_top) / rows, aspect)
