"""Settings that follow from the stereo camera when it is not KITTI's (docs/bags_and_cameras.md).

Two things in the graph are not read from CameraInfo at run time and must fit the camera:
- the CNN's input size (``vehicle_detector.input_width`` / ``input_height``; 0 = the
  checkpoint's, 896x224 below the top 25 % of the image for the shipped one, whose weights
  were trained on KITTI's 1242x375 at fx 721.5 px): the
  image is resized to it, so another aspect ratio is squeezed and another focal length shows the
  cars at another size than in training. :func:`detector_input_size` keeps the training's pixels
  per metre in both directions (the detector then keeps its anchors at that scale:
  detector_node.inference.CnnDetector.from_checkpoint);
- the stereo matcher's disparity range (``stereo_depth.num_disparities``): the nearest depth it
  measures is fx * baseline / num_disparities. :func:`camera_overrides` keeps KITTI's 4.05 m.
Everything else (fx, fy, cx, cy, baseline of ranging, reprojection, odometry, the tracker's
2D boxes, the evaluation) comes from the CameraInfos' ``P``.
"""

from __future__ import annotations

from vehicle_common.stereo_camera import num_disparities_for

#: the camera the checkpoints were trained on (KITTI)
TRAINING_IMAGE = (1242, 375)
TRAINING_FX = 721.5377
#: the nearest depth of the default num_disparities (96 px) on KITTI [m]
MIN_DEPTH = 4.05


def _round32(v: float) -> int:
    return max(32, int(round(v / 32.0)) * 32)


def checkpoint_input_size(checkpoint: str = "") -> tuple[float, float]:
    """The network input (width, height) of a detector checkpoint ("" = the shipped one) as
    the whole KITTI image's: a checkpoint that leaves the top ``roi_top`` of the image out
    (the shipped CenterNet: 896x224 below the top 25 %) shows the image at 224 / 0.75 px of
    height per 375, which is what another camera's whole image is scaled by (it is not
    cropped: camera_overrides sets roi_top 0, its horizon is not KITTI's)."""
    from detector_node.checkpoint import SHIPPED_CHECKPOINT, load_checkpoint

    model, _ = load_checkpoint(checkpoint or SHIPPED_CHECKPOINT, "cpu")
    c = model.config
    return c.input_width, c.input_height / (1.0 - c.roi_top)


def detector_input_size(
    width: int, height: int, fx: float, network_input: tuple[int, int]
) -> tuple[int, int]:
    """(input_width, input_height), multiples of 32, that show a ``width`` x ``height`` camera
    with focal length ``fx`` [px] to the network at the scale of its training images."""
    sx = network_input[0] / TRAINING_IMAGE[0] * TRAINING_FX / fx
    sy = network_input[1] / TRAINING_IMAGE[1] * TRAINING_FX / fx
    return _round32(width * sx), _round32(height * sy)


def camera_overrides(
    width: int,
    height: int,
    fx: float,
    baseline: float,
    network_input: tuple[int, int],
    min_depth: float = MIN_DEPTH,
) -> list[str]:
    """``node.param:=value`` overrides for a rectified camera of that size, focal length [px]
    and baseline [m]: the detector's input size (``network_input``: the checkpoint's) and the
    matcher's disparity range."""
    w, h = detector_input_size(width, height, fx, network_input)
    return [
        f"vehicle_detector.input_width:={w}",
        f"vehicle_detector.input_height:={h}",
        "vehicle_detector.roi_top:=0.0",
        "stereo_depth.match_rows:=[0, 0]",
        f"stereo_depth.num_disparities:={num_disparities_for(fx, baseline, min_depth)}",
    ]
