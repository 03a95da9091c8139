"""The player node's parameters, defined once (no rclpy): :class:`PlayerParameters` (ROS names,
defaults, allowed values, one-line meanings). ``kitti_player`` declares them; the launchers read
their defaults from here."""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common.image_transport import PLAYER_TRANSPORTS
from vehicle_common.node_parameters import param

from vehicle_common import topics


@dataclass
class PlayerParameters:
    """The node's parameters (ROS names and defaults) with their allowed values."""

    dataset_root: str = ""  # KITTI tracking root (image_02, image_03, calib, label_02)
    sequence: str = "0000"  # KITTI sequence (4 digits) under dataset_root
    first_frame: int = param(0, low=0)  # first frame published
    last_frame: int = param(-1, low=-1)  # -1: to the end
    rate: float = param(10.0, low=0.0)  # [Hz] of dataset time; 0: as fast as the graph allows
    rate_multiplier: float = 1.0  # <= 0: as fast as the graph allows
    loop: bool = False  # start again at first_frame after the last
    lockstep: bool = False  # publish frame k+1 only once the tracks of frame k came back
    # lockstep: the topic whose messages acknowledge a frame (relative: in the node's namespace)
    lockstep_topic: str = topics.TRACKS
    lockstep_timeout: float = param(10.0, low=0.0, low_open=True)  # [s]
    # published frames that may be unacknowledged at a time (1: one frame in the graph at a time)
    lockstep_window: int = param(1, low=1)
    snr_db: float = 0.0  # additive Gaussian pixel noise; <= 0 disables
    drop_probability: float = param(0.0, low=0.0, high=1.0)  # probability of not publishing a frame
    seed: int = param(0, low=0)  # seed of the noise and the drops
    start_time: float = param(1.0, low=0.0)  # [s] stamp of frame 0
    wait_for_subscribers: int = param(0, low=0)  # subscriptions on the left image to wait for
    # "topic:N,topic:N": before the first frame, wait until each topic of the graph has N
    # matched subscriptions, the player's own topics and those of the other nodes (as they
    # report them on /diagnostics); the launchers set it from the graph description; relative
    # topic names are resolved in the node's namespace
    wait_for_topics: str = ""
    # "topic:N,...": subscribers outside the graph (a robot's own nodes, already running) the
    # first frame waits for too, on top of wait_for_topics: N more matched subscriptions on each
    # topic, the player's own or one another node publishes (vehicles/vision/tracks,
    # stereo/odometry, tf: as those nodes report them), so that they get every output from the
    # first frame (a running participant may be discovered only 3 s after the graph starts)
    external_subscribers: str = ""
    # s to wait after every expected subscription matched, before the first frame: across hosts
    # a remote reader may match the player's writer later than the writer matched it, and a
    # volatile reader drops what arrived before (README, "Across machines"); 0 on one host
    match_settle_time: float = param(0.0, low=0.0)
    exit_when_done: bool = True  # the node exits after the last frame
    # images on the wire: "raw" (sensor_msgs/Image, rgb8) or sensor_msgs/CompressedImage on
    # <image topic>/compressed, "png" (lossless) or "jpeg" (jpeg_quality); the launchers set the
    # detector's and stereo depth's image_transport to match (docs/bags_and_cameras.md)
    image_transport: str = param("raw", choices=PLAYER_TRANSPORTS)
    jpeg_quality: int = param(90, low=1, high=100)  # JPEG quality of image_transport "jpeg"
    # [MiB] decode the selected frames into memory before the first one is published, when
    # they fit in this much (a camera hands over decoded frames: PNG decoding, ~20 ms per KITTI
    # pair, then takes no CPU from the graph while it runs); larger sequences, or 0, read each
    # frame ahead while the graph works on the one before
    preload_mib: int = param(1024, low=0)
