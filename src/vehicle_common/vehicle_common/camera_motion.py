"""The camera's rigid motion between two frames, and the apparent motion it gives static points.

Shared by the stereo node (which measures it: visual odometry, and integrates it into its
pose: :mod:`.odometry`) and the tracker (which predicts tracks with it). Pure numpy. Points are
in the left optical frame (x right, y down, z forward), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraMotion:
    """``X_later = rotation @ X_earlier + translation`` [m] for a static point's coordinates, over
    ``dt`` seconds (0: not given). ``inliers``: how many points it was solved from (0: unknown)."""

    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)
    dt: float = 0.0
    inliers: int = 0

    def static_point_velocity(self, points: np.ndarray, dt: float | None = None) -> np.ndarray:
        """Apparent velocity (N, 3) [m/s] in the later frame of static points now at ``points``
        (N, 3): their displacement over ``dt`` seconds (default: the motion's own) divided by
        it."""
        span = float(self.dt if dt is None else dt)
        if not span > 0:
            raise ValueError(f"dt: {span} s is not positive")
        p = np.asarray(points, float).reshape(-1, 3)
        earlier = (p - self.translation) @ self.rotation  # R^T (p - t), row-wise
        return (p - earlier) / span


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis x angle, rad) of a rotation matrix."""
    R = np.asarray(R, float)
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(c))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-9:
        return 0.5 * w
    if np.pi - angle < 1e-6:  # half a turn: sin ~ 0, the axis from the symmetric part
        k = np.sqrt(np.clip((np.diag(R) + 1.0) / 2.0, 0.0, None))
        i = int(np.argmax(k))
        k[np.arange(3) != i] *= np.sign(R[i, np.arange(3) != i] + R[np.arange(3) != i, i])
        return angle * k / np.linalg.norm(k)
    return angle / (2.0 * np.sin(angle)) * w


def rotation_from_vector(rv) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues)."""
    rv = np.asarray(rv, float)
    angle = float(np.linalg.norm(rv))
    if angle < 1e-12:
        return np.eye(3)
    k = rv / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def extrapolate(motion: CameraMotion, dt: float) -> CameraMotion:
    """``motion`` scaled to the time span ``dt`` (constant twist: rotation vector and
    translation times dt / motion.dt): the camera keeps moving as it did."""
    s = float(dt) / float(motion.dt)
    rot = rotation_from_vector(s * rotation_vector(motion.rotation))
    return CameraMotion(rot, s * np.asarray(motion.translation, float), float(dt))
