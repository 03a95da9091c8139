"""Settings that follow from the stereo camera when it is not KITTI's (docs/bags_and_cameras.md).

Two things in the graph are not read from CameraInfo at run time and must fit the camera:
- the CNN's input size (``vehicle_detector.input_width`` / ``input_height``; 0 = the
  checkpoint's, 640x192 for the shipped one, trained on KITTI's 1242x375 at fx 721.5 px): the
  image is resized to it, so another aspect ratio is squeezed and another focal length shows the
  cars at another size than in training. :func:`detector_input_size` keeps the training's pixels
  per metre in both directions;
- the stereo matcher's disparity range (``stereo_depth.num_disparities``): the nearest depth it
  measures is fx * baseline / num_disparities. :func:`camera_overrides` keeps KITTI's 4.05 m.
Everything else (fx, fy, cx, cy, baseline of ranging, reprojection, odometry, the tracker's
2D boxes, the evaluation) comes from the CameraInfos' ``P``.
"""

from __future__ import annotations

from vehicle_common.stereo_camera import num_disparities_for

#: the shipped checkpoint's network input and the camera it was trained on (KITTI)
NETWORK_INPUT = (640, 192)
TRAINING_IMAGE = (1242, 375)
TRAINING_FX = 721.5377
#: the nearest depth of the default num_disparities (96 px) on KITTI [m]
MIN_DEPTH = 4.05


def _round32(v: float) -> int:
    return max(32, int(round(v / 32.0)) * 32)


def detector_input_size(
    width: int, height: int, fx: float, network_input: tuple[int, int] = NETWORK_INPUT
) -> tuple[int, int]:
    """(input_width, input_height), multiples of 32, that show a ``width`` x ``height`` camera
    with focal length ``fx`` [px] to the network at the scale of its training images."""
    sx = network_input[0] / TRAINING_IMAGE[0] * TRAINING_FX / fx
    sy = network_input[1] / TRAINING_IMAGE[1] * TRAINING_FX / fx
    return _round32(width * sx), _round32(height * sy)


def camera_overrides(
    width: int, height: int, fx: float, baseline: float, min_depth: float = MIN_DEPTH
) -> list[str]:
    """``node.param:=value`` overrides for a rectified camera of that size, focal length [px]
    and baseline [m]: the detector's input size and the matcher's disparity range."""
    w, h = detector_input_size(width, height, fx)
    return [
        f"vehicle_detector.input_width:={w}",
        f"vehicle_detector.input_height:={h}",
        f"stereo_depth.num_disparities:={num_disparities_for(fx, baseline, min_depth)}",
    ]
