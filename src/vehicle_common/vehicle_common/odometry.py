"""The camera's pose in a fixed ``odom`` frame, integrated from its frame-to-frame motions, with
covariance. Pure numpy (no rclpy): the stereo node publishes it (nav_msgs/Odometry and /tf,
:mod:`.odometry_messages`), the tracker uses the same integration to place tracks in ``odom``
between two /tf messages.

Frames and conventions (REP-103 / REP-105):

- ``odom``: fixed to the world, x forward, y left, z up, with its origin where the base frame
  started. The base frame is the camera's own body frame at the left camera (x forward, y left,
  z up: :data:`BODY_FROM_OPTICAL` away from its optical frame) unless a base frame with a static
  camera mount is configured (:class:`CameraMount`); either way the camera starts at the mount's
  pose in ``odom``.
- A motion (:class:`~vehicle_common.camera_motion.CameraMotion`, the stereo node's visual
  odometry) takes a static point's coordinates in the earlier left optical frame to the later
  one, ``X_later = R X_earlier + t`` over ``dt`` seconds. The camera's pose (``X_odom = R_oc
  X_cam + t_oc``) then moves as ``R_oc' = R_oc R^T``, ``t_oc' = t_oc - R_oc R^T t``.
- Covariances are 6x6 over (x, y, z, rotation about x, y, z), row-major in messages, as
  geometry_msgs/PoseWithCovariance: the pose's in the ``odom`` axes (rotations about the fixed
  axes), the twist's in the child (camera or base) axes, as nav_msgs/Odometry defines them.

What each frame gets (:meth:`OdometryIntegrator.update`, one call per published frame):

- **A measured motion**: the pose is composed from the pose of the frame the motion starts at
  (found by its stamp among the last ``history`` frames, so a motion that bridges frames
  integrated without one, e.g. a stereo pair lost in between, replaces their extrapolation
  instead of adding to it). The step's noise is :class:`OdometryNoise` ``translation_fraction``
  x the step's length (+ ``translation_floor``) per axis and ``rotation`` per axis, in the
  earlier camera's axes; the pose covariance grows by first-order compounding
  ``S' = F S F' + G Q G'`` (``F`` carries the orientation's uncertainty into the position along
  the step's lever arm, ``G`` rotates the step's noise into ``odom``), so it never shrinks and
  grows faster once the heading is uncertain. The twist is the step over ``dt`` with the step's
  covariance over ``dt^2``.
- **No motion** (the odometry failed: too few tracked points, a lost pair, the first frame after
  one): the last measured motion is extrapolated to this frame's time span (constant twist, as
  the tracker does), and the step's covariance is the twist's over the span plus an unknown
  acceleration (``extrapolation_accel`` / ``extrapolation_angular_accel``, per camera axis) over
  it. The frame is flagged not measured. Before any motion was measured the camera is held where
  it is with an unknown twist (:data:`UNKNOWN_VARIANCE`).

The step noise defaults were measured on real KITTI 0005 (the only stereo frames here; watched
while choosing): per step the odometry's translation differs from the one the labelled parked
cars give by 0.02 / 0.05 / 0.04 m (x / y / z std, 1.8 m steps; the labels' own noise included)
and its rotation from ORB-SLAM3's by 0.0002 rad per axis (RMS). The acceleration of the
extrapolation is the per-axis RMS frame-to-frame change of ORB-SLAM3's steps over the 15
labelled KITTI tracking sequences (5745 pairs): 1.5 / 0.7 / 2.6 m/s^2 and 0.15 / 0.10 / 0.16
rad/s^2 (camera x / y / z).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from .camera_motion import CameraMotion, extrapolate, rotation_from_vector, rotation_vector

#: The optical frame's axes (x right, y down, z forward) in the camera's body frame (x forward,
#: y left, z up): ``X_body = BODY_FROM_OPTICAL @ X_optical`` (REP-103).
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
#: Variance given to what is not known (a twist before the first measured motion) [m^2, rad^2,
#: (m/s)^2, (rad/s)^2]: large enough that any consumer that weighs by it ignores the value.
UNKNOWN_VARIANCE = 1.0e6
#: Tolerance when a motion's start is looked up among the integrated frames' stamps [ns].
STAMP_TOLERANCE_NS = 1_000_000


def skew(v) -> np.ndarray:
    """The cross-product matrix ``[v]x`` (``skew(a) @ b == np.cross(a, b)``)."""
    x, y, z = (float(a) for a in v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


@dataclass(frozen=True)
class Pose:
    """A rigid transform ``X_parent = rotation @ X_child + translation`` (the child frame's pose
    in the parent frame)."""

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        object.__setattr__(self, "rotation", np.asarray(self.rotation, float).reshape(3, 3))
        object.__setattr__(self, "translation", np.asarray(self.translation, float).reshape(3))

    def compose(self, other: Pose) -> Pose:
        """``self * other``: ``other`` (child in self's child) expressed in self's parent."""
        return Pose(
            self.rotation @ other.rotation, self.rotation @ other.translation + self.translation
        )

    def inverse(self) -> Pose:
        Rt = self.rotation.T
        return Pose(Rt, -Rt @ self.translation)

    def apply(self, points) -> np.ndarray:
        """Points (N, 3) or (3,) of the child frame in the parent frame."""
        p = np.asarray(points, float)
        return p @ self.rotation.T + self.translation


def rpy_rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation of fixed-axis roll, pitch, yaw (about x, then y, then z; URDF's ``rpy``)."""
    cr, sr, cp, sp, cy, sy = (
        np.cos(roll),
        np.sin(roll),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(yaw),
        np.sin(yaw),
    )
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@dataclass(frozen=True)
class CameraMount:
    """Where the left camera sits on the robot: its body frame (x forward, y left, z up, origin
    at the optical centre) at ``xyz`` [m] and ``rpy`` [rad] in the base frame. :attr:`pose` is
    the left optical frame's pose in the base frame. The default (zeros) is a base frame at the
    camera, level with it."""

    xyz: tuple = (0.0, 0.0, 0.0)
    rpy: tuple = (0.0, 0.0, 0.0)

    @property
    def pose(self) -> Pose:
        return Pose(rpy_rotation(*self.rpy) @ BODY_FROM_OPTICAL, np.asarray(self.xyz, float))


@dataclass(frozen=True)
class OdometryNoise:
    """Noise of the integrated odometry (module docstring: what each one is, and on what data
    the defaults were measured)."""

    translation_fraction: float = 0.02  # std per axis of a measured step, x its length
    translation_floor: float = 0.005  # [m] std per axis of a measured step, added
    rotation: float = 0.0003  # [rad] std per axis of a measured step
    extrapolation_accel: tuple = (1.5, 0.7, 2.6)  # [m/s^2] camera x, y, z
    extrapolation_angular_accel: tuple = (0.15, 0.10, 0.16)  # [rad/s^2] camera x, y, z

    def step_covariance(self, motion: CameraMotion) -> np.ndarray:
        """6x6 covariance of a measured step (its translation and rotation, camera axes)."""
        length = float(np.linalg.norm(motion.translation))
        s_t = np.hypot(self.translation_fraction * length, self.translation_floor)
        return np.diag([s_t**2] * 3 + [self.rotation**2] * 3)

    def extrapolation_covariance(self, span: float) -> np.ndarray:
        """6x6 covariance an unknown acceleration adds to an extrapolated step of ``span``
        seconds (camera axes): the step's ``a span^2``, per axis."""
        s = span * span
        return np.diag(
            [(a * s) ** 2 for a in self.extrapolation_accel]
            + [(a * s) ** 2 for a in self.extrapolation_angular_accel]
        )


@dataclass(frozen=True)
class OdometryState:
    """The camera's integrated odometry at one stamp.

    ``pose``: the left optical frame's pose in ``odom``; ``covariance`` (6x6, odom axes);
    ``linear_velocity`` / ``angular_velocity`` [m/s, rad/s] and ``twist_covariance`` (6x6): the
    camera's, in its own (optical) axes; ``measured``: this frame's step came from a motion
    estimate (False: extrapolated, or the first frame); ``extrapolated_frames``: frames in a row
    without a motion up to this one."""

    stamp_ns: int
    pose: Pose
    covariance: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    twist_covariance: np.ndarray
    measured: bool
    extrapolated_frames: int = 0


def _compound(state: OdometryState, step: Pose, step_cov: np.ndarray) -> np.ndarray:
    """First-order covariance of ``state.pose * step`` (odom axes, rotations about fixed axes):
    ``F S F' + G Q G'`` with ``F = [[I, -[R t_step]x], [0, I]]``, ``G = diag(R, R)``."""
    R = state.pose.rotation
    F = np.eye(6)
    F[:3, 3:] = -skew(R @ step.translation)
    G = np.zeros((6, 6))
    G[:3, :3] = G[3:, 3:] = R
    return F @ state.covariance @ F.T + G @ step_cov @ G.T


def _step_of(motion: CameraMotion) -> Pose:
    """The camera's pose change (later camera in the earlier one) of a static-point motion."""
    Rt = np.asarray(motion.rotation, float).T
    return Pose(Rt, -Rt @ np.asarray(motion.translation, float))


class OdometryIntegrator:
    """The camera's pose in ``odom`` over a stream of frames (module docstring).

    ``initial``: the camera's (left optical frame's) pose in ``odom`` at the first frame (the
    mount's :attr:`CameraMount.pose`); ``history``: how many frames are kept to look a motion's
    start up by stamp."""

    def __init__(
        self,
        initial: Pose | None = None,
        noise: OdometryNoise | None = None,
        history: int = 32,
    ):
        self.initial = initial or CameraMount().pose
        self.noise = noise or OdometryNoise()
        self.history_size = int(history)
        self.history: OrderedDict[int, OdometryState] = OrderedDict()
        self.last: OdometryState | None = None
        self._last_motion: CameraMotion | None = None  # last measured one (for extrapolation)

    def reset(self) -> None:
        """Forget everything: the next frame starts at ``initial`` again."""
        self.history.clear()
        self.last = None
        self._last_motion = None

    def _keep(self, state: OdometryState) -> OdometryState:
        self.history[state.stamp_ns] = state
        while len(self.history) > self.history_size:
            self.history.popitem(last=False)
        self.last = state
        return state

    def _at(self, stamp_ns: int) -> OdometryState | None:
        for s, state in reversed(self.history.items()):
            if abs(s - stamp_ns) <= STAMP_TOLERANCE_NS:
                return state
        return None

    def anchor(self, stamp_ns: int, pose: Pose) -> None:
        """Set the pose at ``stamp_ns`` (e.g. from /tf: a consumer keeps its integration on the
        publisher's). The twist and covariance stay as integrated (covariance 0 at the first)."""
        state = self._at(stamp_ns)
        if state is None:
            base = self.last
            zero = np.zeros(3)
            state = OdometryState(
                int(stamp_ns),
                pose,
                np.zeros((6, 6)) if base is None else base.covariance,
                zero if base is None else base.linear_velocity,
                zero if base is None else base.angular_velocity,
                np.eye(6) * UNKNOWN_VARIANCE if base is None else base.twist_covariance,
                False,
            )
        else:
            state = OdometryState(**{**state.__dict__, "pose": pose})
        if self.last is None or stamp_ns >= self.last.stamp_ns:
            self._keep(state)
        else:
            self.history[state.stamp_ns] = state

    def update(self, stamp_ns: int, motion: CameraMotion | None) -> OdometryState:
        """The odometry at ``stamp_ns`` given this frame's motion since an earlier frame (None:
        not measured). A stamp already integrated returns that frame's state again; one before
        the last integrated frame is ValueError (frames come in stamp order)."""
        stamp_ns = int(stamp_ns)
        if self.last is None:
            return self._keep(self._first(stamp_ns, motion))
        known = self._at(stamp_ns)
        if known is not None:
            return known
        if stamp_ns < self.last.stamp_ns:
            raise ValueError(
                f"stamp {stamp_ns} ns is before the last integrated one ({self.last.stamp_ns} ns)"
            )
        if motion is not None and motion.dt > 0:
            start = stamp_ns - round(motion.dt * 1e9)
            base = self._at(start)
            if base is None and start > self.last.stamp_ns:
                base = self._extrapolated(start)  # a gap before the motion's span
            # None: the motion starts at a frame no longer (or never) integrated; its step,
            # taken from the last frame, is still the best estimate there is
            self._last_motion = motion
            return self._keep(self._measured(stamp_ns, base or self.last, motion))
        return self._keep(self._extrapolated(stamp_ns))

    # ------------------------------------------------------------------ steps
    def _first(self, stamp_ns: int, motion: CameraMotion | None) -> OdometryState:
        if motion is not None and motion.dt > 0:
            self._last_motion = motion
            v, w, tw = self._twist(motion)
        else:
            v, w, tw = np.zeros(3), np.zeros(3), np.eye(6) * UNKNOWN_VARIANCE
        return OdometryState(stamp_ns, self.initial, np.zeros((6, 6)), v, w, tw, False)

    def _twist(self, motion: CameraMotion):
        """Linear and angular velocity (camera axes) and their covariance of a measured step,
        as a constant twist over it: the rotation ``w dt`` and the chord, which leaves at half
        the step's rotation from the body-fixed velocity (exact to ``1 - (w dt)^2 / 24``)."""
        dt = float(motion.dt)
        step = _step_of(motion)
        rv = rotation_vector(step.rotation)
        v = rotation_from_vector(rv / 2.0).T @ step.translation / dt
        return v, rv / dt, self.noise.step_covariance(motion) / dt**2

    def _measured(self, stamp_ns: int, base: OdometryState, motion: CameraMotion) -> OdometryState:
        step = _step_of(motion)
        cov = _compound(base, step, self.noise.step_covariance(motion))
        v, w, tw = self._twist(motion)
        return OdometryState(stamp_ns, base.pose.compose(step), cov, v, w, tw, True)

    def _extrapolated(self, stamp_ns: int) -> OdometryState:
        last = self.last
        span = (stamp_ns - last.stamp_ns) * 1e-9
        added = self.noise.extrapolation_covariance(span)
        if self._last_motion is None:  # nothing measured yet: held, twist unknown
            step = Pose()
            step_cov = np.eye(6) * UNKNOWN_VARIANCE
        else:
            step = _step_of(extrapolate(self._last_motion, span))
            step_cov = last.twist_covariance * span**2 + added
        cov = _compound(last, step, step_cov)
        twist_cov = last.twist_covariance + (added / span**2 if span > 0 else 0.0)
        return OdometryState(
            stamp_ns,
            last.pose.compose(step),
            cov,
            last.linear_velocity,
            last.angular_velocity,
            np.minimum(twist_cov, UNKNOWN_VARIANCE),
            False,
            last.extrapolated_frames + 1,
        )


def base_odometry(
    state: OdometryState, mount: Pose
) -> tuple[Pose, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The base frame's odometry from the camera's, with the camera at ``mount`` (the left
    optical frame's pose in the base frame): pose in ``odom``, its covariance (odom axes),
    linear and angular velocity (base axes) and their covariance. A rigid body: the base's
    velocity is the camera's plus ``w x (p_base - p_camera)``."""
    base_pose = state.pose.compose(mount.inverse())
    lever = state.pose.rotation @ mount.inverse().translation  # camera -> base, odom axes
    F = np.eye(6)
    F[:3, 3:] = -skew(lever)
    cov = F @ state.covariance @ F.T
    Rbc, tbc = mount.rotation, mount.translation
    w = Rbc @ state.angular_velocity
    v = Rbc @ state.linear_velocity - np.cross(w, tbc)
    J = np.zeros((6, 6))
    J[:3, :3] = Rbc
    J[:3, 3:] = skew(tbc) @ Rbc
    J[3:, 3:] = Rbc
    twist_cov = J @ state.twist_covariance @ J.T
    return base_pose, cov, v, w, twist_cov
