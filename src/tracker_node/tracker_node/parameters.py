"""The tracker node's parameters, defined once (no rclpy): how it tracks is
:class:`.config.TrackerConfig`; how it publishes is :class:`TrackerNodeParameters` (ROS names,
defaults, allowed values, one-line meanings). ``vehicle_tracker`` declares both; the launchers
read their defaults from here."""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common.node_parameters import param


@dataclass
class TrackerNodeParameters:
    """The node's parameters beside TrackerConfig's: how it publishes, not how it tracks."""

    # 3x4 projection matrix of the left camera (row-major) for the boxes of coasting tracks;
    # all 0: none (the boxes are left empty)
    camera_matrix: list = param([0.0] * 12)
    # the frame the tracks are published in: "" = the camera's (the 3D arrays'); e.g. odom
    # (the camera's pose from /tf and /tf_static)
    tracks_frame: str = ""
