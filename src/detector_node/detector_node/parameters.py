"""The detector node's parameters, defined once (no rclpy, no torch): :class:`DetectorParameters`
(ROS names, defaults, allowed values, one-line meanings). ``vehicle_detector`` declares them;
the launchers read their defaults from here."""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common.node_parameters import param


@dataclass
class DetectorParameters:
    """The node's parameters (ROS names and defaults) with their allowed values."""

    # "cnn" (the network) or "oracle" (the ground-truth boxes, for ablations only)
    backend: str = param("cnn", choices=("cnn", "oracle"))
    checkpoint: str = ""  # "" = the shipped CenterNet checkpoint
    device: str = "auto"  # auto | cpu | cuda | cuda:N
    score_threshold: float = param(0.3, low=0.0, high=1.0)  # minimum score of a published box
    # IoU above which non-maximum suppression drops the lower-scored box
    nms_iou: float = param(0.45, low=0.0, high=1.0, low_open=True)
    # [px] network input; 0 = derived from the left CameraInfo (the image at the training's
    # pixels per metre; KITTI's camera: the checkpoint's); the network's stride is 32
    input_width: int = param(0, low=0, multiple_of=32)
    input_height: int = param(0, low=0, multiple_of=32)  # [px] the same for the height
    num_threads: int = param(2, low=1)  # torch / ONNX Runtime CPU threads
    # inference runtime: auto (ONNX Runtime for a CenterNet checkpoint on the CPU when the
    # onnx / onnxruntime packages are installed, else PyTorch) | torch | onnxruntime
    runtime: str = param("auto", choices=("auto", "torch", "onnxruntime"))
    # fraction of the image height at the top not searched (above where vehicles are);
    # < 0 = derived: the checkpoint's on KITTI's camera (0.25 for the shipped CenterNet, 0 for
    # tiny_kitti), the whole image on another camera
    roi_top: float = param(-1.0, low=-1.0, high=0.8)
    # [s] an image that arrives before any CameraInfo waits this long for one (then: the
    # checkpoint's framing) when the framing is derived from the camera
    camera_info_wait: float = param(1.0, low=0.0)
    # newest images kept waiting while one is detected (1: latest-frame policy; the launchers
    # set it to the player's lockstep_window in lockstep so that nothing is skipped)
    frame_queue: int = param(1, low=1)
    # back-pressure of a live camera (vehicle_common.flow_control): an image is detected only
    # while fewer than this many detected frames wait for their 3D array
    # (/vehicles/detections_3d, the stereo node's output); a newer image supersedes one held
    # back (skipped and counted). 0: none. Applies only while someone publishes the 3D
    # arrays; at least frame_queue (lockstep: the launchers set 0, the player paces)
    downstream_window: int = param(1, low=0)
    # [s] a detected frame whose 3D array never comes leaves the window after this, or after
    # twice the longest of the last 8 frames' times from the CNN's start to their 3D array
    downstream_timeout: float = param(1.0, low=0.0, low_open=True)
    # with back-pressure: when there is room downstream and the camera's next image is due
    # within this share of its period, wait for it (a fresher frame; vehicle_common.
    # flow_control.CameraCadence; chosen on real 0005, docs/RESULTS.md section 19). 0: off
    next_frame_wait: float = param(0.5, low=0.0, high=1.0)
    # with back-pressure: one more image may start its CNN while the window is full, timed to
    # finish when the newest frame in flight is expected to leave the stereo node (its start +
    # the median time in flight - the CNN's median time): the next frame's CNN runs beside the
    # stereo node's work on this one. Off: on 2 cores it cost latency (1.20 -> 1.52x
    # lockstep's at 2 x the capacity, docs/RESULTS.md section 29), for a machine with cores
    # to spare
    downstream_lead: bool = False
    vehicle_types: list = param(["Car", "Van"])  # oracle: label types republished
    oracle_box_noise_px: float = param(0.0, low=0.0)  # oracle: [px] std of noise on each box edge
    oracle_score: float = param(1.0, low=0.0, high=1.0)  # oracle: score of every box
    oracle_drop_probability: float = param(0.0, low=0.0, high=1.0)  # oracle: box dropped
    oracle_seed: int = param(0, low=0)  # oracle: seed of the noise and the drops
    # oracle: images waiting for their ground truth before they are released without boxes
    oracle_max_pending: int = param(10, low=1)
