"""Stereo geometry of a rectified pair, the Q matrix, and reprojection of disparities to 3D.

Pure core. Points are in the left camera's optical frame (x right, y down, z forward), metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StereoGeometry:
    """Intrinsics of the rectified left camera and the stereo baseline [m]."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float

    @classmethod
    def from_camera_infos(cls, left_info, right_info) -> StereoGeometry:
        """Geometry from the two sensor_msgs/CameraInfo of a rectified pair (ROS P convention:
        right ``P[0,3] = -fx * baseline``). Raises ValueError when they do not describe one."""
        return cls.from_projections(
            np.asarray(left_info.p, dtype=float).reshape(3, 4),
            np.asarray(right_info.p, dtype=float).reshape(3, 4),
        )

    @classmethod
    def from_projections(cls, P_left: np.ndarray, P_right: np.ndarray) -> StereoGeometry:
        """Geometry from the 3x4 projection matrices of the rectified left and right cameras."""
        Pl, Pr = np.asarray(P_left, float), np.asarray(P_right, float)
        fx = float(Pl[0, 0])
        baseline = float((Pl[0, 3] - Pr[0, 3]) / fx) if fx > 0 else 0.0
        if fx <= 0 or baseline <= 0:
            raise ValueError("projection matrices do not describe a rectified left/right pair")
        return cls(fx, float(Pl[1, 1]), float(Pl[0, 2]), float(Pl[1, 2]), baseline)

    @property
    def q_matrix(self) -> np.ndarray:
        """4x4 reprojection matrix Q: ``[X Y Z W]^T = Q [u v d 1]^T`` (equal principal points,
        as in cv2.stereoRectify's Q for a rectified pair)."""
        f, B = self.fx, self.baseline
        return np.array(
            [
                [1.0, 0.0, 0.0, -self.cx],
                [0.0, self.fx / self.fy, 0.0, -self.cy * self.fx / self.fy],
                [0.0, 0.0, 0.0, f],
                [0.0, 0.0, 1.0 / B, 0.0],
            ]
        )

    def depth(self, disparity):
        """Depth z = f * B / d [m] (inf where d <= 0)."""
        d = np.asarray(disparity, dtype=float)
        with np.errstate(divide="ignore"):
            return np.where(d > 0, self.fx * self.baseline / np.where(d > 0, d, 1.0), np.inf)

    def disparity_at_depth(self, z):
        """Disparity d = f * B / z [px]."""
        return self.fx * self.baseline / np.asarray(z, dtype=float)

    def backproject(self, u, v, z) -> np.ndarray:
        """3D point(s) (..., 3) of pixel(s) (u, v) at depth(s) z."""
        u, v, z = (np.asarray(a, dtype=float) for a in (u, v, z))
        return np.stack([(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z], axis=-1)


def reproject(disparity: np.ndarray, geometry: StereoGeometry) -> tuple[np.ndarray, np.ndarray]:
    """3D points (H, W, 3) float32 of a disparity map with Q, and the mask of valid ones.

    Invalid pixels (disparity <= 0) are NaN in the points."""
    disp = np.asarray(disparity, np.float32)
    h, w = disp.shape
    Q = geometry.q_matrix
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d = disp.astype(np.float64)
    hom = np.stack([u, v, d, np.ones_like(d)], axis=-1) @ Q.T
    valid = disp > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        pts = hom[..., :3] / hom[..., 3:4]
    pts[~valid] = np.nan
    return pts.astype(np.float32), valid


def decimated_points(
    disparity: np.ndarray,
    geometry: StereoGeometry,
    step: int = 4,
    rgb: np.ndarray | None = None,
    max_depth: float = 80.0,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Valid 3D points of every ``step``-th pixel in both directions, up to ``max_depth`` [m].

    Returns (N, 3) float32 xyz and, when ``rgb`` is given, (N, 3) uint8 colours."""
    step = max(1, int(step))
    sub = np.ascontiguousarray(disparity[::step, ::step])
    h, w = sub.shape
    v, u = np.mgrid[0:h, 0:w]
    u, v = u * step, v * step
    valid = sub > 0
    z = geometry.depth(np.where(valid, sub, 1.0))
    valid &= z <= max_depth
    pts = geometry.backproject(u[valid], v[valid], z[valid]).astype(np.float32)
    colours = None
    if rgb is not None:
        colours = np.ascontiguousarray(rgb[::step, ::step][valid], dtype=np.uint8)
    return pts, colours
