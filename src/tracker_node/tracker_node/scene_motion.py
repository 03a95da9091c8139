"""The initial velocity of a new track: zero (the paper) or the scene's common relative motion.

The tracker works in the moving camera's frame without ego-motion, so a parked car seen from a
car driving at 12 m/s moves at about -12 m/s along z. A track started at zero velocity then lags
its detections for several frames (on real KITTI trajectories: a lag of metres, tracks localised
worse than the raw detections). Most cars in view share that apparent motion (parked cars, and
traffic at similar speed differs from it by a few m/s), so the component-wise median velocity of
the established tracks is a good prior for a new one: :func:`initial_velocity` returns it (or
zero when fewer than ``min_tracks`` tracks are established), and the filters start new tracks
there with the configured initial velocity variance around it along z and, sideways and
vertically, no more than the labelled cars' relative velocity spreads (:func:`known_scene_var`:
the scene motion is mostly along z, so a car's own motion around it is too; measured on the
tuning sequences with 20-frame cold starts: equal AP, Kalman MOTA 84.1 -> 84.2, IDSW 14 -> 12,
docs/tracker.md).

While the scene's motion is not yet known (no established track: the first frames of a drive),
a new track's velocity starts at zero, and the prior around it must cover the relative
velocities cars really have: :func:`velocity_prior` then returns the per-axis second moment of
the relative velocity of labelled cars (``UNKNOWN_SCENE_VELOCITY_VAR``, measured on the
real-motion benchmark's tuning sequences) instead of the variance around a known scene motion.
Seen from a driving car that is mostly along the optical axis (z: RMS 8.4 m/s) and little
sideways (x: 3.1 m/s) or vertically (y: 0.4 m/s); an isotropic prior either lags the cars'
apparent motion along z or lets lateral stereo noise into the velocity.

When the camera's own motion is known (the stereo node's visual odometry, the 3D arrays'
``camera_motion``), the scene's motion is known from the first pair of frames on, before any
track is established: a new track then starts at the apparent velocity of a static point at
its position (``static_velocity``), with the variance around a known scene motion. Parked cars,
the commonest case, then start right; a car driving at the camera's speed starts as far off as
a parked one does without odometry, but near the camera, where stereo is precise.
"""

from __future__ import annotations

import numpy as np

INIT_VELOCITIES = ("zero", "scene")
#: [(m/s)^2] E[v^2] per axis (x, y, z; camera frame) of the relative velocity of labelled Cars
#: and Vans (finite differences at 10 Hz) on the tuning sequences 0000, 0002, 0004, 0007, 0009,
#: 0011, 0017, 0020 (17671 pairs; docs/tracker.md).
UNKNOWN_SCENE_VELOCITY_VAR = (9.6, 0.17, 70.0)
MIN_UPDATES = 3  # updates after which a track's velocity counts for the scene motion


def initial_velocity(
    mode: str,
    velocity: np.ndarray,
    updates: np.ndarray,
    min_updates: int = MIN_UPDATES,
    min_tracks: int = 1,
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


def scene_known(velocity: np.ndarray, updates: np.ndarray, min_updates: int = MIN_UPDATES) -> bool:
    """Whether some track is established (``updates >= min_updates``) to give the scene motion."""
    return bool(len(velocity)) and bool((updates >= min_updates).any())


def velocity_prior(
    mode: str,
    velocity: np.ndarray,
    updates: np.ndarray,
    velocity_var: float,
    unknown_scene_var=UNKNOWN_SCENE_VELOCITY_VAR,
    static_velocity: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean (3,) or (M, 3) and per-axis variance (3,) of new tracks' velocities. ``mode``
    "zero": zero and ``velocity_var`` on every axis (the paper); "scene": :func:`initial_velocity`
    and :func:`known_scene_var` while some track is established; before that, ``static_velocity``
    (M, 3) (the apparent velocity of a static point at each new track's position, from the
    camera's motion) and :func:`known_scene_var` when given, else zero and
    ``unknown_scene_var``."""
    v0 = initial_velocity(mode, velocity, updates)
    if mode != "scene":
        return v0, np.full(3, float(velocity_var))
    known = known_scene_var(velocity_var, unknown_scene_var)
    if not scene_known(velocity, updates):
        if static_velocity is not None:
            return np.asarray(static_velocity, float), known
        return v0, np.asarray(unknown_scene_var, dtype=float)
    return v0, known


def known_scene_var(
    velocity_var: float, unknown_scene_var=UNKNOWN_SCENE_VELOCITY_VAR
) -> np.ndarray:
    """Per-axis variance (3,) of a new track's velocity around a known scene motion: the scene
    motion is mostly along the optical axis (the camera drives forward), so a car's own motion
    around it keeps, sideways and vertically, no more spread than the labelled cars' relative
    velocity has (``unknown_scene_var`` x, y), and along z ``velocity_var``."""
    u = np.asarray(unknown_scene_var, dtype=float)
    v = float(velocity_var)
    return np.array([min(v, u[0]), min(v, u[1]), v])


def restarted_velocity_prior(
    mode: str,
    velocity: np.ndarray,
    updates: np.ndarray,
    velocity_var: float,
    static_velocity: np.ndarray,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The prior (mean (M, 3), per-axis variance (3,)) that tracks seen once take again when
    the static scene's apparent velocity at their positions, ``static_velocity`` (M, 3), becomes
    known; None when nothing changes: mode "zero" (the paper), or the scene motion is already
    known from established tracks (then their median keeps priority, :func:`velocity_prior`)."""
    if not len(static_velocity) or mode != "scene" or scene_known(velocity, updates):
        return None
    return np.asarray(static_velocity, float), known_scene_var(velocity_var)


def reset_velocity_covariance(cov: np.ndarray, rows: np.ndarray, v_var: np.ndarray) -> None:
    """In the (N, 6, 6) position-velocity covariances ``cov``, give tracks ``rows`` the
    velocity variances ``v_var`` (3,) and no position-velocity correlation (in place)."""
    cov[rows, 3:, :] = 0.0
    cov[rows, :, 3:] = 0.0
    cov[rows, 3:, 3:] = np.diag(v_var)
