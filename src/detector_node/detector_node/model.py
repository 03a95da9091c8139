"""YOLOv2 with a passthrough (reorg) layer, sized for KITTI's wide frames (Chan et al. 2019).

One definition, two presets differing only in ``width`` (channel multiplier) and ``depth``
(layers kept per stage, taken from the front of each stage of the paper's table):

- ``full``: the paper's network, input 352x1152, 11x36 output grid.
- ``tiny``: width 0.25, one 3x3 conv per stage, same passthrough and head; for CPU real time.

Output: (B, A * (5 + 4), H/32, W/32) = per anchor (tx, ty, tw, th, objectness, 4 orientation
logits); 45 channels for 5 anchors.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import torch
from torch import nn
from vehicle_common.orientation_bins import NUM_BINS

#: Stages of the paper's table: (kernel, channels) per conv; a 2x2 max-pool follows stages 1-5.
#: The output of stage 5 (stride 16) feeds the passthrough.
STAGES: tuple[tuple[tuple[int, int], ...], ...] = (
    ((3, 32),),
    ((3, 64),),
    ((3, 128), (1, 64), (3, 128)),
    ((3, 256), (1, 128), (3, 256)),
    ((3, 512), (1, 256), (3, 512), (1, 256), (3, 512)),
    ((3, 1024), (1, 512), (3, 1024), (1, 512), (3, 1024), (3, 1024), (3, 1024)),
)
PASSTHROUGH_CHANNELS = 64
HEAD_CHANNELS = 1024
VALUES_PER_ANCHOR = 5 + NUM_BINS

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


def _channels(c: int, width: float) -> int:
    return max(8, int(round(c * width / 8.0)) * 8)


class ConvBnLeaky(nn.Sequential):
    """Convolution (no bias), batch norm, leaky ReLU (slope 0.1)."""

    def __init__(self, cin: int, cout: int, k: int) -> None:
        super().__init__(
            nn.Conv2d(cin, cout, k, padding=k // 2, bias=False),
            nn.BatchNorm2d(cout),
            nn.LeakyReLU(0.1, inplace=True),
        )


def space_to_depth(x: torch.Tensor, block: int = 2) -> torch.Tensor:
    """Reorg: (B, C, H, W) -> (B, C * block^2, H / block, W / block)."""
    return nn.functional.pixel_unshuffle(x, block)


class YoloV2Passthrough(nn.Module):
    """The detector network built from a :class:`DetectorConfig`."""

    def __init__(self, config: DetectorConfig) -> None:
        super().__init__()
        self.config = config
        w, depth = config.width, config.depth
        cin = 3
        stages = []
        for spec in STAGES:
            layers = []
            for k, c in spec[: max(1, depth)]:
                cout = _channels(c, w)
                layers.append(ConvBnLeaky(cin, cout, k))
                cin = cout
            stages.append(nn.Sequential(*layers))
        self.stage1to5 = nn.ModuleList(stages[:5])
        self.stage6 = stages[5]
        c5 = self.stage1to5[4][-1][0].out_channels
        c6 = cin
        cp = _channels(PASSTHROUGH_CHANNELS, w)
        self.passthrough = ConvBnLeaky(c5, cp, 1)
        self.head = ConvBnLeaky(c6 + 4 * cp, _channels(HEAD_CHANNELS, w), 3)
        self.out = nn.Conv2d(_channels(HEAD_CHANNELS, w), config.num_anchors * VALUES_PER_ANCHOR, 1)
        self.pool = nn.MaxPool2d(2, 2)
        with torch.no_grad():  # start with low objectness (rare positives)
            bias = self.out.bias.view(config.num_anchors, VALUES_PER_ANCHOR)
            bias.zero_()
            bias[:, 4] = -4.0

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Images (B, 3, H, W) in [0, 1] -> raw outputs (B, A * 9, H/32, W/32)."""
        for i, stage in enumerate(self.stage1to5):
            x = stage(x)
            if i == 4:
                fine = x
            x = self.pool(x)
        x = self.stage6(x)
        p = space_to_depth(self.passthrough(fine), 2)
        x = self.head(torch.cat([p, x], dim=1))
        return self.out(x)


def split_output(raw: torch.Tensor, num_anchors: int) -> torch.Tensor:
    """(B, A * 9, H, W) -> (B, A, 9, H, W)."""
    b, _, h, w = raw.shape
    return raw.view(b, num_anchors, VALUES_PER_ANCHOR, h, w)
