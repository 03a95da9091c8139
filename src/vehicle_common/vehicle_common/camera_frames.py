"""The one frame convention between the graph's messages and KITTI's label files.

The graph (stereo ranging, tracker, messages) places a vehicle by its CENTRE OF MASS in the LEFT
camera's optical frame (REP-103 optical: x right, y down, z forward). KITTI labels and results
place it by the BOTTOM CENTRE of its box in CAMERA 0 (the rectified reference camera):

    location_cam0 = centre_left - left_camera_offset,   location.y = centre.y + height / 2

with sizes as (length, width, height) in the messages and (h, w, l) in KITTI. A vehicle whose
size is unknown (not finite and positive) gets the KITTI mean car. Every conversion between the
two goes through :func:`kitti_from_centre` / :func:`centre_from_kitti`, and result rows through
:func:`kitti_row_from_centre`, which drops (returns None for) a row that would hold a non-finite
value, since a KITTI file cannot represent it.
"""

from __future__ import annotations

import math

import numpy as np

from .kitti import (
    MEAN_CAR_DIMENSIONS,
    KittiObject,
    alpha_from_rotation_y,
    rotation_y_from_alpha,
    wrap_angle,
)


def size_or_mean(size_lwh, mean_hwl=MEAN_CAR_DIMENSIONS) -> tuple[float, float, float]:
    """(length, width, height) of ``size_lwh`` when all finite and > 0, else of ``mean_hwl``
    (given as KITTI (h, w, l))."""
    if size_lwh is not None:
        length, width, height = (float(v) for v in size_lwh)
        if all(math.isfinite(v) and v > 0 for v in (length, width, height)):
            return length, width, height
    h, w, length = (float(v) for v in mean_hwl)
    return length, w, h


def kitti_from_centre(centre, height, offset=None) -> np.ndarray:
    """KITTI bottom-centre location(s) in camera 0 of centre(s) of mass in the left optical frame.
    ``centre`` (3,) or (N, 3), ``height`` scalar or (N,), ``offset`` the left camera's position in
    camera 0 (None: the same camera)."""
    loc = np.array(centre, dtype=float)
    if offset is not None:
        loc = loc - offset
    loc[..., 1] = loc[..., 1] + np.asarray(height, dtype=float) / 2.0
    return loc


def centre_from_kitti(location, height, offset=None) -> np.ndarray:
    """Centre(s) of mass in the left optical frame of KITTI bottom-centre location(s) in camera 0
    (inverse of :func:`kitti_from_centre`)."""
    centre = np.array(location, dtype=float)
    if offset is not None:
        centre = centre + offset
    centre[..., 1] -= np.asarray(height, dtype=float) / 2.0
    return centre


def kitti_row_from_centre(
    centre,
    size_lwh,
    bbox,
    offset=None,
    *,
    yaw: float | None = None,
    alpha: float | None = None,
    frame: int = -1,
    track_id: int = -1,
    score: float | None = None,
    type_name: str = "Car",
    mean_hwl=MEAN_CAR_DIMENSIONS,
) -> KittiObject | None:
    """One KITTI result row (camera 0, bottom centre) of a vehicle given by its centre of mass in
    the left optical frame. The heading is ``yaw`` (rotation_y; alpha derived) or else ``alpha``
    (rotation_y derived). Unknown size: ``mean_hwl``. Returns None (the row is dropped) when the
    position, heading or 2D box is not finite."""
    length, width, height = size_or_mean(size_lwh, mean_hwl)
    x, y, z = (float(v) for v in kitti_from_centre(centre, height, offset))
    box = tuple(float(v) for v in bbox)
    heading = yaw if yaw is not None else alpha
    if heading is None or not all(math.isfinite(v) for v in (x, y, z, heading, *box)):
        return None
    if yaw is not None:  # wrapped to (-pi, pi] only when outside (in range: kept exactly)
        rotation_y = float(yaw) if -math.pi < yaw <= math.pi else wrap_angle(float(yaw))
        alpha = alpha_from_rotation_y(rotation_y, x, z)
    else:
        alpha = float(alpha)
        rotation_y = rotation_y_from_alpha(alpha, x, z)
    return KittiObject(
        type=type_name,
        alpha=alpha,
        bbox=box,
        dimensions=(height, width, length),
        location=(x, y, z),
        rotation_y=rotation_y,
        frame=frame,
        track_id=track_id,
        score=score,
    )
