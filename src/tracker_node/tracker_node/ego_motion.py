"""The camera's own motion in the tracker's prediction (tracking in a world frame).

The tracker's state lives in the current left optical frame (x right, y down, z forward). Once
the input carries the camera's motion (the stereo node's visual odometry, the 3D arrays'
``camera_motion``: ``X_now = R X_before + t`` for a static point), every track's velocity is its
velocity over the ground (relative to the static world), expressed in the current camera axes,
and the prediction of each frame is

    p_now = R (p_before + v dt) + t,    v_now = R v,    P_now = A (F P F' + Q) A',  A = diag(R, R)

(constant velocity over the ground; :meth:`move_frame` of each filter applies the rigid part).
A parked car then stands still in the state (v = 0) while its position follows the camera's
motion, and a moving car keeps its own speed. Before the first motion arrives the tracker works
as before the world frame (velocity relative to the camera); when it arrives, every track's
velocity is converted (:func:`static_velocity_before`). A frame without a motion once the world
frame is in use (a frame lost by the odometry) is predicted with the last motion extrapolated to
its time span (:func:`extrapolate`). Pure numpy.
"""

from __future__ import annotations

import numpy as np
from vehicle_common.camera_motion import CameraMotion, extrapolate

__all__ = ["extrapolate", "rotate_covariances", "static_velocity_before"]  # extrapolate: shared


def static_velocity_before(motion: CameraMotion, points: np.ndarray, dt: float) -> np.ndarray:
    """Apparent velocity (N, 3) [m/s], in the earlier frame's axes, of static points at
    ``points`` (N, 3) of the earlier frame: ``(R p + t - p) / dt``. A track's velocity relative
    to the camera minus this is its velocity over the ground."""
    p = np.asarray(points, float).reshape(-1, 3)
    return (p @ motion.rotation.T + motion.translation - p) / float(dt)


def rotate_covariances(cov: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``A cov A'`` for covariances (N, 3k, 3k) of k stacked 3-vectors, A = diag(R, ..., R)."""
    k = cov.shape[-1] // 3
    # np.kron(np.eye(k), R) without its generic reshaping: the same products (1 x R on the
    # diagonal blocks, 0 x R off it, signed zeros included), a fifth of the CPU
    A = np.multiply.outer(np.eye(k), R).transpose(0, 2, 1, 3).reshape(3 * k, 3 * k)
    return A @ cov @ A.T
