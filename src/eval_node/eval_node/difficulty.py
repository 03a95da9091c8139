"""KITTI difficulty levels and class rules shared by the detection and tracking metrics.

Object benchmark (KITTI object devkit, ``evaluate_object.cpp`` / kitti-object-eval-python):

==========  =====================  ==============  ===============
level       min 2D box height      max occlusion   max truncation
==========  =====================  ==============  ===============
easy        40 px                  0 (visible)     0.15
moderate    25 px                  1               0.30
hard        25 px                  2               0.50
==========  =====================  ==============  ===============

A ground truth exactly at the minimum height is outside the level: the devkit's server code
(``evaluate_object.cpp``, which produces the leaderboard) ignores ground truth with
``height <= MIN_HEIGHT``, as kitti-object-eval-python does. Predictions are ignored below the
minimum (``height < MIN_HEIGHT``), so a prediction exactly at it counts. Ground truth of the
evaluated class outside the level, and ground truth of the neighbouring class
(``Van`` for ``Car``, ``Person_sitting`` for ``Pedestrian``), is *ignored*: matching it is neither a
true nor a false positive, missing it is not a false negative. Predictions lower than the level's
minimum height are ignored too.

Tracking benchmark (KITTI tracking devkit ``evaluate_tracking.py`` and AB3DMOT's port): ground
truth counts when occlusion <= 2 and truncation <= 0; unmatched tracker boxes of 2D height
<= 25 px are ignored. The devkit's code applies no height limit to ground truth (its
``min_height`` is only used on tracker boxes); ``gt_counted_for_tracking(obj, min_height=25.0)``
gives the stricter rule of shared/notes/kitti-tracking-eval.md where wanted.
"""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common.kitti import KittiObject


@dataclass(frozen=True)
class Difficulty:
    """One KITTI object-benchmark difficulty level."""

    name: str
    min_height: float
    max_occlusion: int
    max_truncation: float


EASY = Difficulty("easy", 40.0, 0, 0.15)
MODERATE = Difficulty("moderate", 25.0, 1, 0.30)
HARD = Difficulty("hard", 25.0, 2, 0.50)
#: The three object-benchmark levels by name.
DIFFICULTIES: dict[str, Difficulty] = {d.name: d for d in (EASY, MODERATE, HARD)}

#: Tracking devkit limits for counted ground truth and ignored tracker boxes.
TRACKING_MAX_OCCLUSION = 2
TRACKING_MAX_TRUNCATION = 0.0
TRACKING_MIN_HEIGHT = 25.0

#: Neighbouring (ignored) class of each evaluated class.
NEIGHBOUR_CLASS = {"car": "van", "pedestrian": "person_sitting"}


def class_status(obj_type: str, cls: str) -> int:
    """1 if ``obj_type`` is the evaluated class ``cls``, 0 if it is its neighbouring class
    (ignored), -1 otherwise (case-insensitive)."""
    t, c = obj_type.lower(), cls.lower()
    if t == c:
        return 1
    if NEIGHBOUR_CLASS.get(c) == t:
        return 0
    return -1


def gt_within_difficulty(obj: KittiObject, level: Difficulty) -> bool:
    """Whether a ground-truth box satisfies a level (height > min, occlusion, truncation)."""
    return (
        obj.height_px > level.min_height
        and int(obj.occluded) <= level.max_occlusion
        and float(obj.truncated) <= level.max_truncation
    )


def gt_counted_for_tracking(obj: KittiObject, min_height: float | None = None) -> bool:
    """Whether the tracking devkit counts a ground-truth box (its class aside): occlusion <= 2
    and truncation <= 0, and 2D height > ``min_height`` when one is given (the devkit: none)."""
    return (
        int(obj.occluded) <= TRACKING_MAX_OCCLUSION
        and float(obj.truncated) <= TRACKING_MAX_TRUNCATION
        and (min_height is None or obj.height_px > min_height)
    )
