"""The settings the graph derives from the camera's CameraInfo at run time (pure: no rclpy).

Five settings depend on the camera. What each is derived from (docs/bags_and_cameras.md):

- the detector's input size (``vehicle_detector.input_width`` / ``input_height``): the image
  shown to the network at the pixels per metre of its training images (KITTI's 1242x375 at
  fx 721.5 px), i.e. the image size x the training's input px per image px x 721.5 / fx,
  rounded to multiples of 32 -- from the CameraInfo's size and fx;
- the region the detector searches (``vehicle_detector.roi_top``) and the rows the matcher
  matches (``stereo_depth.match_rows``): the checkpoint's region of interest (the shipped
  CenterNet leaves out the top 25 %, above where vehicles are with KITTI's mounting) on a camera
  with the training camera's image geometry (KITTI's own sequences: size within 2 %, fx within
  3 %); the whole image for any other camera, since where the sky begins depends on how the
  camera is mounted, which CameraInfo does not say;
- the matcher's disparity range (``stereo_depth.num_disparities``): fx * baseline / the
  nearest depth KITTI's default reaches (4.05 m), rounded up to 16 -- from fx and the baseline;
- the camera's height above the road (``stereo_depth.ground_height``): not in CameraInfo;
  KITTI's 1.65 m is assumed and said so, and the stereo node checks it against the road plane it
  fits (``stereo_depth_node.plausibility.GroundHeightCheck``).

An explicitly given parameter always wins. Each node logs ONE line saying what it derived and
from what (:func:`detector_framing`, :func:`stereo_settings` return it). On KITTI's camera the
derived values are the KITTI graph's hand settings (896x224 with the checkpoint's 25 %, 96,
rows 94-375, 1.65 m), on a 1280x720, 700 px, 0.12 m camera those ``tracking_bringup.camera``
computed before (896x512 for tiny_kitti, the whole image, 32).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .stereo_camera import check_stereo_infos, num_disparities_for

#: the camera the shipped checkpoints were trained on and the graph's defaults chosen on (KITTI)
TRAINING_IMAGE = (1242, 375)
TRAINING_FX = 721.5377
#: the nearest depth KITTI's default disparity range (96 px) measures [m]
MIN_DEPTH = 4.05
#: the top fraction of KITTI's image the graph leaves out: the shipped CenterNet's region of
#: interest (centernet_kitti.pt's roi_top), above where vehicles are with KITTI's mounting
KITTI_ROI_TOP = 0.25
#: KITTI's camera height above the road [m] (its documented mounting)
KITTI_CAMERA_HEIGHT = 1.65
#: a camera "like the training camera": image size within this fraction ...
SIZE_TOLERANCE = 0.02
#: ... and fx within this fraction (KITTI's tracking sequences: 1224-1242 x 370-376, 707-722 px)
FX_TOLERANCE = 0.03
#: ``match_rows`` value meaning "derived from the camera"
DERIVED_ROWS = (-1, -1)


@dataclass(frozen=True)
class CameraModel:
    """What the settings are derived from: image size [px], focal lengths and principal point
    [px] of the rectified left camera, baseline [m] (0 when only the left CameraInfo is known)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float = 0.0

    @classmethod
    def from_camera_info(cls, left_info, right_info=None) -> CameraModel:
        """From the left CameraInfo (and the right one: the baseline, after the checks of
        :func:`vehicle_common.stereo_camera.check_stereo_infos`). Raises ValueError (one line
        naming the field) for a CameraInfo the graph cannot use."""
        baseline = check_stereo_infos(left_info, right_info) if right_info is not None else 0.0
        p = [float(v) for v in left_info.p]
        if len(p) != 12 or not all(math.isfinite(v) for v in p) or p[0] <= 0 or p[5] <= 0:
            raise ValueError(
                "left camera_info: P has no positive fx, fy: the camera is not calibrated"
            )
        return cls._checked(int(left_info.width), int(left_info.height), p, baseline)

    @classmethod
    def from_projections(cls, width: int, height: int, p_left, p_right=None) -> CameraModel:
        """From an image size and the rectified 3x4 projection matrices (offline tools: a
        KITTI calibration's P2 and P3)."""
        pl = [float(v) for v in np.asarray(p_left, float).reshape(-1)]
        baseline = 0.0
        if p_right is not None:
            pr = np.asarray(p_right, float).reshape(-1)
            baseline = (pl[3] - float(pr[3])) / pl[0]
        return cls._checked(int(width), int(height), pl, baseline)

    @classmethod
    def _checked(cls, w: int, h: int, p: list[float], baseline: float) -> CameraModel:
        if w <= 0 or h <= 0:
            raise ValueError(f"left camera_info: size {w}x{h}: width and height must be > 0")
        return cls(w, h, p[0], p[5], p[2], p[6], float(baseline))

    def describe(self) -> str:
        text = f"{self.width}x{self.height}, fx {self.fx:.1f} px"
        return text + (f", baseline {self.baseline:.3f} m" if self.baseline > 0 else "")

    def like_training_camera(self) -> bool:
        """Image size within :data:`SIZE_TOLERANCE` and fx within :data:`FX_TOLERANCE` of the
        training camera's (KITTI's)."""
        tw, th = TRAINING_IMAGE
        return (
            abs(self.width / tw - 1) <= SIZE_TOLERANCE
            and abs(self.height / th - 1) <= SIZE_TOLERANCE
            and abs(self.fx / TRAINING_FX - 1) <= FX_TOLERANCE
        )


def _round32(v: float) -> int:
    return max(32, int(round(v / 32.0)) * 32)


def training_scale(training_input: tuple[int, int], training_roi_top: float) -> tuple[float, float]:
    """(x, y) input px per image px of a checkpoint in training: its training input size over
    the part of KITTI's image it saw (below ``training_roi_top``)."""
    tw, th = TRAINING_IMAGE
    return training_input[0] / tw, training_input[1] / ((1.0 - training_roi_top) * th)


def input_size_for(
    camera: CameraModel, scale: tuple[float, float], roi_top: float
) -> tuple[int, int]:
    """The network input (multiples of 32) that shows the part of the camera's image below
    ``roi_top`` at the training's pixels per metre (``scale``: :func:`training_scale`)."""
    k = TRAINING_FX / camera.fx
    return (
        _round32(camera.width * scale[0] * k),
        _round32((1.0 - roi_top) * camera.height * scale[1] * k),
    )


@dataclass(frozen=True)
class DetectorFraming:
    """The detector's input size (0, 0: the checkpoint's own) and region of interest, with the
    log line that says where they come from."""

    input_width: int
    input_height: int
    roi_top: float
    text: str


def detector_framing(
    camera: CameraModel | None,
    checkpoint_input: tuple[int, int],
    checkpoint_roi_top: float,
    training_input: tuple[int, int],
    training_roi_top: float,
    given_size: tuple[int, int] = (0, 0),
    given_roi_top: float = -1.0,
) -> DetectorFraming:
    """The detector's framing of ``camera`` (None: no CameraInfo: the checkpoint's) for a
    checkpoint whose inference framing is ``checkpoint_input`` / ``checkpoint_roi_top`` and
    training framing ``training_input`` / ``training_roi_top``. ``given_size`` (0 = derive;
    each side separately) and ``given_roi_top`` (< 0 = derive) are the parameters: given, they
    win."""
    roi_given = given_roi_top >= 0
    if roi_given:
        roi, roi_why = float(given_roi_top), "parameter"
    elif camera is None or camera.like_training_camera():
        roi = float(checkpoint_roi_top)
        roi_why = "the checkpoint's" + (", KITTI's camera" if camera is not None else "")
    else:
        roi = 0.0
        roi_why = (
            "not KITTI's camera: where the sky begins depends on the mounting, which CameraInfo "
            "does not say; set vehicle_detector.roi_top to leave it out"
        )
    w, h = given_size
    if camera is None or (not (w and h) and camera.like_training_camera() and not roi_given):
        size_why = "the checkpoint's" if camera is None else "the checkpoint's, KITTI's camera"
        derived = (0, 0)
    else:
        derived = input_size_for(camera, training_scale(training_input, training_roi_top), roi)
        size_why = "image x the training's px per metre"
    if w and h:
        size_why = "parameter"
    out_w, out_h = (w or derived[0]), (h or derived[1])
    if (out_w, out_h) == tuple(checkpoint_input) and not (w or h):
        out_w = out_h = 0  # the checkpoint's framing as it is
    shown = (out_w or checkpoint_input[0], out_h or checkpoint_input[1])
    source = "without CameraInfo" if camera is None else f"camera {camera.describe()}"
    where = f"below the top {100 * roi:.0f} %" if roi > 0 else "the whole image"
    text = f"{source}: input {shown[0]}x{shown[1]} ({size_why}), searched: {where} ({roi_why})"
    return DetectorFraming(out_w, out_h, roi, text)


@dataclass(frozen=True)
class StereoSettings:
    """The matcher's disparity range and rows, the camera height, with the log line."""

    num_disparities: int
    match_rows: tuple[int, int]  # [top, bottom); bottom <= top: all rows
    ground_height: float
    ground_height_assumed: bool
    text: str


def stereo_settings(
    camera: CameraModel,
    given_num_disparities: int = 0,
    given_match_rows: tuple[int, int] = DERIVED_ROWS,
    given_ground_height: float = 0.0,
) -> StereoSettings:
    """The stereo node's settings for ``camera`` (needs its baseline). Parameters given
    (``num_disparities`` > 0, ``match_rows`` not [-1, -1], ``ground_height`` > 0) win."""
    if given_num_disparities > 0:
        nd, nd_why = int(given_num_disparities), "parameter"
    else:
        nd = num_disparities_for(camera.fx, camera.baseline, MIN_DEPTH)
        nd_why = (
            f"fx x baseline / {MIN_DEPTH} m, KITTI's nearest depth, up to 16: depths from "
            f"{camera.fx * camera.baseline / nd:.2f} m"
        )
    if tuple(given_match_rows) != DERIVED_ROWS:
        rows, rows_why = (int(given_match_rows[0]), int(given_match_rows[1])), "parameter"
    elif camera.like_training_camera():
        rows = (int(round(KITTI_ROI_TOP * camera.height)), camera.height)
        rows_why = f"below the detector's region of interest, the top {100 * KITTI_ROI_TOP:.0f} %"
    else:
        rows, rows_why = (0, 0), "not KITTI's camera: the detector searches the whole image"
    if given_ground_height > 0:
        gh, assumed, gh_why = float(given_ground_height), False, "parameter"
    else:
        gh, assumed = KITTI_CAMERA_HEIGHT, True
        gh_why = "assumed, KITTI's camera height: not in CameraInfo; checked against the road plane"
    shown_rows = f"{rows[0]}-{rows[1]}" if rows[1] > rows[0] else "all"
    text = (
        f"camera {camera.describe()}: num_disparities {nd} ({nd_why}), match_rows {shown_rows} "
        f"({rows_why}), ground_height {gh:.2f} m ({gh_why})"
    )
    return StereoSettings(nd, rows, gh, assumed, text)
