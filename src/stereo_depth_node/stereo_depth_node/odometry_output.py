"""What the stereo node publishes of its visual odometry: the camera's pose integrated in an
``odom`` frame (nav_msgs/Odometry on ``stereo/odometry``, odom -> child on /tf) and the rig's
fixed transforms (/tf_static). Pure core (no rclpy): the node hands each published frame's
camera motion to :meth:`OdometryOutput.frame` and publishes what it returns.

The integration, its frames and its covariance are :mod:`vehicle_common.odometry`'s; the
messages :mod:`vehicle_common.odometry_messages`'. docs/stereo_depth.md ("Odometry and TF").
"""

from __future__ import annotations

from dataclasses import dataclass

from vehicle_common.camera_motion import CameraMotion
from vehicle_common.node_parameters import param
from vehicle_common.odometry import CameraMount, OdometryIntegrator, OdometryNoise
from vehicle_common.odometry_messages import (
    OdometryFrames,
    odometry_message,
    odometry_tf,
    rig_static_tf,
)


@dataclass
class OdometryOutputParameters:
    """The node's odometry and TF parameters (docs/stereo_depth.md, "Odometry and TF")."""

    odom_frame: str = "odom"  # the odometry's fixed frame (REP-105)
    # child of the odometry and of odom -> child on /tf; "" = the left camera's optical frame
    base_frame: str = ""
    # the left camera's body frame (x forward, y left, z up) in base_frame: [x, y, z] m,
    # [roll, pitch, yaw] rad (URDF rpy); only with a base_frame
    camera_mount_xyz: list = param([0.0, 0.0, 0.0], length=3)
    camera_mount_rpy: list = param([0.0, 0.0, 0.0], length=3)  # [rad] see camera_mount_xyz
    publish_odometry: bool = True  # nav_msgs/Odometry on stereo/odometry (visual_odometry on)
    publish_tf: bool = True  # odom -> child on /tf (false: another node owns odom -> base)
    publish_static_tf: bool = True  # base -> left -> right optical frames on /tf_static

    # noise of the integration (vehicle_common.odometry: measured on real KITTI, 10 Hz)
    odometry_translation_noise: float = param(0.02, low=0)  # std per axis / step length
    odometry_translation_noise_floor: float = param(0.005, low=0)  # [m] per axis and step
    odometry_rotation_noise: float = param(0.0003, low=0)  # [rad] per axis and step
    # [m/s^2] a step without a motion: the extrapolation's std grows with these accelerations
    # (x, y, z; ORB-SLAM3 steps of 15 KITTI sequences)
    odometry_extrapolation_accel: list = param([1.5, 0.7, 2.6], low=0, length=3)
    # [rad/s^2] the same for the rotation
    odometry_extrapolation_angular_accel: list = param([0.15, 0.1, 0.16], low=0, length=3)

    def validate(self) -> None:
        if not self.odom_frame:
            raise ValueError("odom_frame: must not be empty")
        if self.base_frame == self.odom_frame:
            raise ValueError(f"base_frame: must differ from odom_frame ({self.odom_frame!r})")

    @property
    def frames(self) -> OdometryFrames:
        mount = CameraMount(tuple(self.camera_mount_xyz), tuple(self.camera_mount_rpy))
        return OdometryFrames(self.odom_frame, self.base_frame, mount.pose)

    @property
    def noise(self) -> OdometryNoise:
        return OdometryNoise(
            self.odometry_translation_noise,
            self.odometry_translation_noise_floor,
            self.odometry_rotation_noise,
            tuple(self.odometry_extrapolation_accel),
            tuple(self.odometry_extrapolation_angular_accel),
        )


class OdometryOutput:
    """The messages of each published frame's odometry, and of the rig when it changes."""

    def __init__(self, params: OdometryOutputParameters | None = None):
        self.params = params or OdometryOutputParameters()
        self.frames = self.params.frames
        # the camera starts at its mount's pose in odom (odom: where the base started); with no
        # base frame the camera's own body frame is the base (odom level with the camera)
        initial = self.frames.mount if self.frames.base else CameraMount().pose
        self.integrator = OdometryIntegrator(initial, self.params.noise)
        self._rig: tuple | None = None
        self.frames_extrapolated = 0

    def frame(self, stamp_ns: int, camera_frame: str, motion: CameraMotion | None):
        """(nav_msgs/Odometry or None, tf2_msgs/TFMessage or None) of the frame at ``stamp_ns``
        whose camera motion since an earlier frame is ``motion`` (None: not measured; the pose
        is extrapolated and its covariance grows). None for a stamp not after the last one."""
        try:
            state = self.integrator.update(stamp_ns, motion)
        except ValueError:
            return None, None
        if not state.measured and state.extrapolated_frames:
            self.frames_extrapolated += 1
        p = self.params
        odom = odometry_message(state, camera_frame, self.frames) if p.publish_odometry else None
        tf = odometry_tf(state, camera_frame, self.frames) if p.publish_tf else None
        return odom, tf

    def rig(self, stamp_ns: int, left_frame: str, right_frame: str, baseline: float):
        """tf2_msgs/TFMessage for /tf_static when the rig's frames or baseline changed (None
        otherwise, when static TF is off, or when there is nothing to say: no base frame and
        both cameras in one frame)."""
        key = (left_frame, right_frame, round(float(baseline), 9))
        if not self.params.publish_static_tf or key == self._rig:
            return None
        self._rig = key
        msg = rig_static_tf(stamp_ns, left_frame, right_frame, baseline, self.frames)
        return msg if msg.transforms else None
