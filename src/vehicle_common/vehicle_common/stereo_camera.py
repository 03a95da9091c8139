"""What the graph needs of a stereo camera, checked with one clear line per problem.

The graph takes a RECTIFIED pair: ``stereo/{left,right}/image_rect`` (rgb8, bgr8 or mono8, or
their compressed form) and ``stereo/{left,right}/camera_info`` whose projection matrices ``P``
describe the rectified cameras (ROS convention, REP-104 / sensor_msgs/CameraInfo): the same
fx, fy, cx, cy on both sides, the rows aligned (``P[1,3] = 0``), and the right camera's
``Tx = P[0,3] = -fx * baseline`` (the left one's is 0, or any value as long as the difference
gives the baseline, as kitti2bag's P_rect_02 / P_rect_03). Images and CameraInfos of one side
share a size and a frame id. :func:`check_stereo_infos` and :func:`check_stereo_images` raise
:class:`StereoCameraError` naming what is wrong; :func:`num_disparities_for` gives the matcher's
disparity range for the nearest depth to be measured.
"""

from __future__ import annotations

import math

import numpy as np


class StereoCameraError(ValueError):
    """The camera pair is not one the graph can use; the message names the field."""


def _p(info, side: str) -> np.ndarray:
    p = np.asarray(info.p, dtype=float)
    if p.size != 12:
        raise StereoCameraError(f"{side} camera_info: P has {p.size} values, not 12")
    bad = np.flatnonzero(~np.isfinite(p))
    if bad.size:
        r, c = divmod(int(bad[0]), 4)
        raise StereoCameraError(
            f"{side} camera_info: P[{r},{c}] is {float(p[bad[0]])!r}: the calibration holds a "
            "non-finite value"
        )
    if not np.any(p):
        raise StereoCameraError(
            f"{side} camera_info: P is missing (all zeros): the camera is not calibrated"
        )
    return p.reshape(3, 4)


def check_stereo_infos(left_info, right_info) -> float:
    """Check that the two CameraInfos describe a rectified left/right pair; returns the
    baseline [m]. Raises StereoCameraError with one line naming the field at fault."""
    pl, pr = _p(left_info, "left"), _p(right_info, "right")
    sizes = [(int(i.width), int(i.height)) for i in (left_info, right_info)]
    if sizes[0] != sizes[1]:
        raise StereoCameraError(
            f"camera_info sizes differ: left {sizes[0][0]}x{sizes[0][1]}, right "
            f"{sizes[1][0]}x{sizes[1][1]} (a rectified pair has one size)"
        )
    fx = pl[0, 0]
    if fx <= 0 or pl[1, 1] <= 0:
        raise StereoCameraError(f"left camera_info: P fx, fy = {fx:g}, {pl[1, 1]:g} must be > 0")
    names = ("fx", "fy", "cx", "cy")
    rows, cols = [0, 1, 0, 1], [0, 1, 2, 2]
    for name, a, b in zip(names, pl[rows, cols], pr[rows, cols], strict=True):
        if not math.isclose(a, b, rel_tol=1e-3, abs_tol=0.5):
            raise StereoCameraError(
                f"camera_info P {name} differs (left {a:g}, right {b:g}): the images are not "
                "rectified together (give image_rect and the rectified P of one stereo "
                "calibration)"
            )
    tx = pr[0, 3] - pl[0, 3]
    # vertical and depth offsets of the right camera, small beside the baseline (KITTI: 0.6 %)
    if (
        abs(pr[1, 3] - pl[1, 3]) / pl[1, 1] > 0.05 * abs(tx) / fx
        or abs(pr[2, 3] - pl[2, 3]) > 0.05 * abs(tx) / fx
    ):
        raise StereoCameraError(
            "camera_info P[1,3]/P[2,3] differ between left and right by more than 5 % of the "
            "baseline: not a horizontally rectified pair"
        )
    if pr[0, 3] == 0 and pl[0, 3] == 0:
        raise StereoCameraError(
            "right camera_info: P[0,3] (Tx) is 0: no baseline (ROS convention: right "
            "Tx = -fx * baseline)"
        )
    if tx >= 0:
        raise StereoCameraError(
            f"camera_info: right P[0,3] - left P[0,3] = {tx:g} >= 0: left and right swapped, "
            "or the right Tx has the wrong sign (ROS: Tx = -fx * baseline)"
        )
    return float(-tx / fx)


def check_stereo_images(left_msg, right_msg, left_rgb, right_rgb, left_info, right_info) -> None:
    """Check that a stereo pair's images fit each other and their CameraInfos (sizes, frame
    ids); raises StereoCameraError naming what differs."""
    lh, lw = left_rgb.shape[:2]
    rh, rw = right_rgb.shape[:2]
    if (lw, lh) != (rw, rh):
        raise StereoCameraError(f"left {lw}x{lh} and right {rw}x{rh} image sizes differ")
    for side, info, msg in (("left", left_info, left_msg), ("right", right_info, right_msg)):
        if info is None:
            continue
        if (int(info.width), int(info.height)) != (lw, lh):
            raise StereoCameraError(
                f"{side} image is {lw}x{lh} but its camera_info says {info.width}x{info.height}"
            )
        frame, info_frame = msg.header.frame_id, info.header.frame_id
        if frame and info_frame and frame != info_frame:
            raise StereoCameraError(
                f"{side} image frame_id {frame!r} differs from its camera_info's {info_frame!r}"
            )


def num_disparities_for(fx: float, baseline: float, min_depth: float) -> int:
    """The SGBM disparity range (a multiple of 16, >= 16) that measures depths down to
    ``min_depth`` [m]: d_max = fx * baseline / min_depth. KITTI (fx 721.5 px, 0.54 m): 96 px
    reaches 4.05 m; a 0.12 m, 700 px camera: 32 px reach 2.6 m, 96 px 0.88 m."""
    if fx <= 0 or baseline <= 0 or min_depth <= 0:
        raise ValueError("fx, baseline and min_depth must be > 0")
    return max(16, int(math.ceil(fx * baseline / min_depth / 16.0)) * 16)
