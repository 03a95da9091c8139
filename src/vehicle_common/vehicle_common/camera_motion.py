"""The camera's rigid motion between two frames, and the apparent motion it gives static points.

Shared by the stereo node (which measures it: visual odometry) and the tracker (which starts new
tracks at the apparent velocity of the static scene). Pure numpy. Points are in the left
optical frame (x right, y down, z forward), metres.
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
