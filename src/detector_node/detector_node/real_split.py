"""The detector's fixed split of the real labelled KITTI frames in ``../shared/kitti``.

Fixed by the lead (docs/interfaces) before any training or tuning, and never trained on:

- validation (99 frames): every frame here of tracking sequences 0001 and 0005 (31 + 16 frames
  of ``tracking/training``), the ``tracking_keyframes`` of 0001, 0005, 0008 and 0010 (6 + 9 +
  10 + 7), and object frames 000060-000079 (20);
- training: the other object frames (000000-000059, 000080-000100, 000154, 000192, 000463; 84
  frames), the ``tracking_keyframes`` of 0000, 0002, 0004, 0006, 0007, 0009 and 0011 (39;
  0000 has none here), and (as ``partial`` data) ``object_crops352`` without crops 000135 and
  000218 (pixel-identical to frames 22 and 5 of tracking 0001) and 000138 (closest to
  keyframe 0005/000273 of all crops, mean thumbnail difference 5 grey levels: taken as the same
  drive, left out to be safe): 145 crops.

Checked with image thumbnails (grey, 96x30; crops against the same native window of every
validation frame): after these exclusions the closest training image to any validation image
differs by >= 8.8 grey levels on average (object 000028 vs object 000070, as in the earlier split).
"""

from __future__ import annotations

from pathlib import Path

VAL_TRACKING_SEQUENCES = ("0001", "0005")
VAL_KEYFRAME_SEQUENCES = ("0001", "0005", "0008", "0010")
TRAIN_KEYFRAME_SEQUENCES = ("0000", "0002", "0004", "0006", "0007", "0009", "0011")
VAL_OBJECT_IDS = "60-79"
TRAIN_OBJECT_IDS = "0-59,80-100,154,192,463"
#: object_crops352 ids without 135, 138 and 218 (see module docstring)
TRAIN_CROP_IDS = "101-134,136-137,139-217,219-273,2100-2146"


def val_sources(kitti: Path) -> list[str]:
    """Data-source specs (see :mod:`detector_node.dataset`) of the validation split."""
    return [
        f"{kitti / 'tracking' / 'training'}:{','.join(VAL_TRACKING_SEQUENCES)}",
        f"{kitti / 'tracking_keyframes'}:{','.join(VAL_KEYFRAME_SEQUENCES)}",
        f"{kitti / 'object' / 'training'}:{VAL_OBJECT_IDS}",
    ]


def train_sources(kitti: Path) -> list[str]:
    """Data-source specs of the real training frames with complete labels."""
    return [
        f"{kitti / 'tracking_keyframes'}:{','.join(TRAIN_KEYFRAME_SEQUENCES)}",
        f"{kitti / 'object' / 'training'}:{TRAIN_OBJECT_IDS}",
    ]


def partial_source(kitti: Path) -> str:
    """The supplementary crops with incomplete Car-only labels (training ones)."""
    return f"{kitti / 'object_crops352'}:{TRAIN_CROP_IDS}"
