"""The initial velocity of a new track: zero (the paper) or the scene's common relative motion.

The tracker works in the moving camera's frame without ego-motion, so a parked car seen from a
car driving at 12 m/s moves at about -12 m/s along z. A track started at zero velocity then lags
its detections for several frames (on real KITTI trajectories: a lag of metres, tracks localised
worse than the raw detections). Most cars in view share that apparent motion (parked cars, and
traffic at similar speed differs from it by a few m/s), so the component-wise median velocity of
the established tracks is a good prior for a new one: :func:`initial_velocity` returns it (or
zero when fewer than ``min_tracks`` tracks are established), and the filters start new tracks
there with the configured initial velocity variance around it.
"""

from __future__ import annotations

import numpy as np

INIT_VELOCITIES = ("zero", "scene")


def initial_velocity(
    mode: str, velocity: np.ndarray, updates: np.ndarray, min_updates: int = 3, min_tracks: int = 1
) -> np.ndarray:
    """Initial velocity (3,) for tracks started now.

    ``velocity`` (N, 3): current velocity estimates of the existing tracks; ``updates`` (N,):
    how many detections each has been corrected with. ``mode`` "zero": zeros; "scene": the
    component-wise median velocity of the tracks with at least ``min_updates`` updates (zeros
    when fewer than ``min_tracks`` such tracks)."""
    if mode == "zero" or not len(velocity):
        return np.zeros(3)
    mature = updates >= min_updates
    if int(mature.sum()) < min_tracks:
        return np.zeros(3)
    return np.median(velocity[mature], axis=0)
