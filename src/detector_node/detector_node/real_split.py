"""The detector's fixed split of the real labelled KITTI frames in ``../shared/kitti``.

Fixed before any training on real data and never trained on:

- validation: all 16 frames of tracking sequence 0005 (52 Car labels) and the 20 object frames
  000060-000079 (48 Car labels);
- training: the other object frames (000000-000059, 000080-000100, 000154, 000192, 000463:
  84 frames, 275 Car labels), the 31 frames of tracking sequence 0001 (234 Car labels), and (as
  ``partial`` data) the 148 frames of ``object_crops352`` (368 Car labels).

No frame of the validation split occurs in the training data (checked with image thumbnails:
the closest object/crop frame to any 0005 frame differs clearly; two crops are frames of 0001,
which is training data).
"""

from __future__ import annotations

from pathlib import Path

VAL_TRACKING_SEQUENCES = ("0005",)
TRAIN_TRACKING_SEQUENCES = ("0001",)
VAL_OBJECT_IDS = "60-79"
TRAIN_OBJECT_IDS = "0-59,80-100,154,192,463"


def val_sources(kitti: Path) -> list[str]:
    """Data-source specs (see :mod:`detector_node.dataset`) of the validation split."""
    return [
        f"{kitti / 'tracking' / 'training'}:{','.join(VAL_TRACKING_SEQUENCES)}",
        f"{kitti / 'object' / 'training'}:{VAL_OBJECT_IDS}",
    ]


def train_sources(kitti: Path) -> list[str]:
    """Data-source specs of the real training frames with complete labels."""
    return [
        f"{kitti / 'tracking' / 'training'}:{','.join(TRAIN_TRACKING_SEQUENCES)}",
        f"{kitti / 'object' / 'training'}:{TRAIN_OBJECT_IDS}",
    ]


def partial_source(kitti: Path) -> str:
    """The supplementary crops with incomplete Car-only labels."""
    return str(kitti / "object_crops352")
