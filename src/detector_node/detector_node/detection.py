"""A 2D vehicle detection as the detector's backends return it (pure: no torch)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Detection:
    """One 2D vehicle detection in original image pixels."""

    box: tuple[float, float, float, float]  # x1, y1, x2, y2 [px]
    score: float  # objectness (one object class: class confidence is 1)
    orientation_bin: int
    orientation_probs: tuple[float, float, float, float]
    #: continuous observation angle alpha [rad] folded into [-pi/2, pi/2) (the bin centre for
    #: models without an angle head)
    observation_angle: float = 0.0
    #: its variance [rad^2]; < 0 = not provided (models with 4 bins only)
    observation_angle_variance: float = -1.0
