"""The camera-dependent settings as parameter overrides (docs/bags_and_cameras.md).

The nodes derive them at run time from the CameraInfo (``vehicle_common.camera_settings``):
nothing needs to be set for another camera. This module turns the same derivation into
``node.param:=value`` overrides, for pinning them (a launch that must not depend on the first
CameraInfo) or for comparing with other settings (``stereo_tracking_demo
--no-camera-settings`` runs a synthetic camera with KITTI's settings instead).
"""

from __future__ import annotations

from vehicle_common.camera_settings import (
    TRAINING_FX,
    TRAINING_IMAGE,
    CameraModel,
    detector_framing,
    stereo_settings,
)

#: KITTI's camera (the training camera): its settings are the KITTI graph's
KITTI_CAMERA = CameraModel(
    TRAINING_IMAGE[0], TRAINING_IMAGE[1], TRAINING_FX, TRAINING_FX, 609.6, 172.9, 0.5327
)


def checkpoint_framing(checkpoint: str = ""):
    """((input w, h), roi_top, (training input w, h), training roi_top) of a detector
    checkpoint ("" = the shipped one), from the user cache when it holds it."""
    from detector_node.loading import checkpoint_framing as framing

    config, training_input, training_roi_top = framing(checkpoint)
    return (
        (config.input_width, config.input_height),
        config.roi_top,
        training_input,
        training_roi_top,
    )


def camera_overrides(camera: CameraModel, checkpoint: str = "") -> list[str]:
    """The overrides that pin what the nodes derive for ``camera`` (with its baseline) and the
    detector ``checkpoint``: input size (the checkpoint's when it is 0), region of interest,
    disparity range, match rows, camera height."""
    (cw, ch), *rest = checkpoint_framing(checkpoint)
    f = detector_framing(camera, (cw, ch), *rest)
    s = stereo_settings(camera)
    return [
        f"vehicle_detector.input_width:={f.input_width or cw}",
        f"vehicle_detector.input_height:={f.input_height or ch}",
        f"vehicle_detector.roi_top:={f.roi_top}",
        f"stereo_depth.num_disparities:={s.num_disparities}",
        f"stereo_depth.match_rows:=[{s.match_rows[0]}, {s.match_rows[1]}]",
        f"stereo_depth.ground_height:={s.ground_height}",
    ]
