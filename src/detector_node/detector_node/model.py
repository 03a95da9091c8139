"""YOLOv2 with a passthrough (reorg) layer, sized for KITTI's wide frames (Chan et al. 2019).

One definition, two presets differing only in ``width`` (channel multiplier) and ``depth``
(layers kept per stage, taken from the front of each stage of the paper's table):

- ``full``: the paper's network, input 352x1152, 11x36 output grid.
- ``tiny``: width 0.25, one 3x3 conv per stage, same passthrough and head; for CPU real time.

Output: (B, A * (5 + 4), H/32, W/32) = per anchor (tx, ty, tw, th, objectness, 4 orientation
logits); 45 channels for 5 anchors.
"""

from __future__ import annotations

import torch
from torch import nn
from vehicle_common.orientation_bins import NUM_BINS

from .config import (  # noqa: F401 (re-exported: the configuration lives in .config)
    DEFAULT_ANCHORS_352x1152,
    DetectorConfig,
    check_roi_top,
    preset,
)

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
