"""ROS messages of the integrated odometry (:mod:`.odometry`): nav_msgs/Odometry, the /tf and
/tf_static messages (tf2_msgs/TFMessage) of the odometry and of the stereo rig, and a small
tf buffer (:class:`TransformTree`) for consumers without tf2 (the pip install has none).

Message packages are imported inside the functions that build messages (no rclpy here).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from .frame_messages import header, read_transform, stamp_ns, write_pose, write_transform
from .odometry import OdometryState, Pose, base_odometry


@dataclass(frozen=True)
class OdometryFrames:
    """The frames of the published odometry: ``odom`` (fixed), the ``base`` frame (the child of
    the odometry and of odom -> base on /tf; "" = the left camera's optical frame itself) and
    ``mount``, the left optical frame's pose in the base frame (ignored without a base frame)."""

    odom: str = "odom"
    base: str = ""
    mount: Pose = Pose()

    def child(self, camera_frame: str) -> str:
        return self.base or camera_frame


def _covariance(values: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(values, float).reshape(36)]


def odometry_message(state: OdometryState, camera_frame: str, frames: OdometryFrames):
    """nav_msgs/Odometry of ``state``: header (stamp of the frame, ``frames.odom``), child frame
    (the base frame, or ``camera_frame``), the child's pose in odom with covariance (odom axes)
    and its twist with covariance (child axes)."""
    from nav_msgs.msg import Odometry

    msg = Odometry()
    msg.header = header(state.stamp_ns, frames.odom)
    msg.child_frame_id = frames.child(camera_frame)
    if frames.base:
        pose, cov, v, w, twist_cov = base_odometry(state, frames.mount)
    else:
        pose, cov = state.pose, state.covariance
        v, w, twist_cov = state.linear_velocity, state.angular_velocity, state.twist_covariance
    write_pose(pose.rotation, pose.translation, msg.pose.pose)
    msg.pose.covariance = _covariance(cov)
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z = (float(a) for a in v)
    t.angular.x, t.angular.y, t.angular.z = (float(a) for a in w)
    msg.twist.covariance = _covariance(twist_cov)
    return msg


def transform_stamped(parent: str, child: str, stamp: int, pose: Pose):
    """geometry_msgs/TransformStamped: ``child``'s pose in ``parent`` at ``stamp`` [ns]."""
    from geometry_msgs.msg import TransformStamped

    msg = TransformStamped()
    msg.header = header(stamp, parent)
    msg.child_frame_id = child
    write_transform(pose.rotation, pose.translation, msg.transform)
    return msg


def odometry_tf(state: OdometryState, camera_frame: str, frames: OdometryFrames):
    """tf2_msgs/TFMessage for /tf: odom -> the odometry's child frame at the frame's stamp."""
    from tf2_msgs.msg import TFMessage

    pose = state.pose.compose(frames.mount.inverse()) if frames.base else state.pose
    child = frames.child(camera_frame)
    return TFMessage(transforms=[transform_stamped(frames.odom, child, state.stamp_ns, pose)])


def rig_static_tf(
    stamp: int, left_frame: str, right_frame: str, baseline: float, frames: OdometryFrames
):
    """tf2_msgs/TFMessage for /tf_static: the rig's fixed transforms, all in one message (a
    late subscriber gets the last message only, as from tf2's static broadcaster): base -> left
    optical frame (the mount, when a base frame is set) and left -> right optical frame (the
    rectified pair: the right camera ``baseline`` m along the left one's x, same axes)."""
    from tf2_msgs.msg import TFMessage

    out = []
    if frames.base:
        out.append(transform_stamped(frames.base, left_frame, stamp, frames.mount))
    if right_frame and right_frame != left_frame:  # else the right camera has no frame name
        right = Pose(np.eye(3), np.array([float(baseline), 0.0, 0.0]))
        out.append(transform_stamped(left_frame, right_frame, stamp, right))
    return TFMessage(transforms=out)


def transforms_from_tf(msg) -> list[tuple[str, str, int, Pose]]:
    """(parent, child, stamp [ns], child's pose in parent) of each transform of a TFMessage;
    ValueError naming the transform when one is malformed (empty frame, bad quaternion)."""
    out = []
    for k, t in enumerate(msg.transforms):
        parent, child = t.header.frame_id, t.child_frame_id
        if not parent or not child or parent == child:
            raise ValueError(f"transform {k}: frames {parent!r} -> {child!r}")
        try:
            R, tv = read_transform(t.transform)
        except ValueError as exc:
            raise ValueError(f"transform {k} ({parent} -> {child}): {exc}") from None
        out.append((parent, child, stamp_ns(t.header), Pose(R, tv)))
    return out


class TransformTree:
    """The transforms of /tf and /tf_static, looked up at exact stamps: what a tf2 buffer gives
    a node that places data in another frame, for the frames and stamps this graph publishes
    (no interpolation between stamps: every transform the stereo node publishes has the stamp
    of a frame). Static transforms hold at every stamp; dynamic ones keep the last ``history``
    stamps per child frame."""

    def __init__(self, history: int = 64):
        self.history = int(history)
        self._parent: dict[str, str] = {}
        self._static: dict[str, Pose] = {}
        self._dynamic: dict[str, OrderedDict[int, Pose]] = {}

    def add(self, parent: str, child: str, stamp: int, pose: Pose, static: bool = False) -> None:
        self._parent[child] = parent
        if static:
            self._static[child] = pose
            self._dynamic.pop(child, None)
            return
        self._static.pop(child, None)
        stamps = self._dynamic.setdefault(child, OrderedDict())
        stamps[int(stamp)] = pose
        while len(stamps) > self.history:
            stamps.popitem(last=False)

    def add_message(self, msg, static: bool = False) -> None:
        """Every transform of a TFMessage (ValueError as :func:`transforms_from_tf`)."""
        for parent, child, stamp, pose in transforms_from_tf(msg):
            self.add(parent, child, stamp, pose, static)

    def _to_root(self, frame: str, stamp: int) -> tuple[list[str], Pose] | None:
        """Frames from ``frame`` up to its root and ``frame``'s pose in the root (None when a
        dynamic link has no transform at ``stamp``)."""
        chain, pose = [frame], Pose()
        while frame in self._parent and len(chain) <= len(self._parent) + 1:
            link = self._static.get(frame)
            if link is None:
                link = self._dynamic.get(frame, {}).get(int(stamp))
            if link is None:
                return None
            pose = link.compose(pose)
            frame = self._parent[frame]
            chain.append(frame)
        return chain, pose

    def lookup(self, target: str, source: str, stamp: int) -> Pose | None:
        """``source``'s pose in ``target`` at ``stamp`` [ns] (``X_target = R X_source + t``), or
        None when the frames are not connected at that stamp."""
        if target == source:
            return Pose()
        up_source = self._to_root(source, stamp)
        up_target = self._to_root(target, stamp)
        if up_source is None or up_target is None or up_source[0][-1] != up_target[0][-1]:
            return None
        return up_target[1].inverse().compose(up_source[1])
