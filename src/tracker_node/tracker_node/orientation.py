"""Vehicle heading from the detector's orientation bins and the track's velocity.

The detector's 4 bins are of the KITTI observation angle alpha folded modulo 180 deg, centred on
0, 45, 90 and 135 deg, so a bin fixes the yaw only up to 180 deg (and to +-22.5 deg):
``rotation_y = alpha + atan2(x, z)`` (camera frame, x right, z forward).
A KITTI box at yaw ``ry`` has its length (front) along ``(cos ry, -sin ry)`` in the camera x-z
plane (``vehicle_common.box3d``), so a vehicle moving with velocity ``(vx, vz)`` heads at
``ry = atan2(-vz, vx)``.
"""

from __future__ import annotations

import numpy as np
from vehicle_common.kitti import wrap_angle as wrap
from vehicle_common.orientation_bins import bin_to_alpha


def yaw_from_bin(orientation_bin, x, z):
    """A yaw (one of the two 180-degree-apart candidates) from an orientation bin at (x, z)."""
    return wrap(bin_to_alpha(orientation_bin) + np.arctan2(x, z))


def heading_from_velocity(vx, vz):
    """KITTI rotation_y of a vehicle moving with camera-frame velocity (vx, vz)."""
    return np.arctan2(-np.asarray(vz, float), np.asarray(vx, float))


def align_to(yaw, reference):
    """``yaw`` or ``yaw + pi``, whichever is closer to ``reference`` (resolves the 180-degree
    ambiguity)."""
    yaw = np.asarray(yaw, float)
    flip = np.abs(wrap(yaw - reference)) > np.pi / 2.0
    return wrap(np.where(flip, yaw + np.pi, yaw))


def resolve_heading(yaw, velocity, min_speed: float):
    """Yaws flipped by 180 deg where needed to agree with the motion direction of tracks whose
    ground speed (x-z plane) exceeds ``min_speed``; others unchanged. ``velocity``: (N, 3)."""
    v = np.asarray(velocity, float)
    speed = np.hypot(v[:, 0], v[:, 2])
    heading = heading_from_velocity(v[:, 0], v[:, 2])
    return np.where(speed > min_speed, align_to(yaw, heading), wrap(yaw))


def motion_heading(velocity, velocity_cov) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(heading [rad], its std [rad], speed [m/s]) of the direction of travel of velocities
    ``velocity`` (N, 3) with covariances ``velocity_cov`` (N, 3, 3), in the x-z plane: the
    heading's std is the velocity's std across its direction over the speed (first order)."""
    v = np.asarray(velocity, float)[:, [0, 2]]
    cov = np.asarray(velocity_cov, float)[:, [0, 2]][:, :, [0, 2]]
    speed = np.hypot(v[:, 0], v[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        across = np.stack([-v[:, 1], v[:, 0]], axis=1) / speed[:, None]
        var = np.einsum("ni,nij,nj->n", across, cov, across)
        std = np.sqrt(np.maximum(var, 0.0)) / speed
    return heading_from_velocity(v[:, 0], v[:, 1]), np.where(speed > 0, std, np.inf), speed


def fuse_heading(yaw, yaw_std: float, heading, heading_std):
    """The detector's yaw (known up to 180 deg, std ``yaw_std`` [rad]) and the heading of travel
    (``heading_std`` [rad]) combined: the yaw turned to the heading's side, then the
    inverse-variance weighted mean of the two angles."""
    aligned = align_to(yaw, heading)
    w = yaw_std**2 / (yaw_std**2 + np.asarray(heading_std, float) ** 2)
    return wrap(aligned + w * wrap(heading - aligned))
