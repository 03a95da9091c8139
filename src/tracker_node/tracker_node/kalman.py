"""Constant-velocity Kalman filter in 3D (state x, y, z, vx, vy, vz), batched over tracks.

:class:`BatchedKalmanFilter` runs predict/update for all tracks at once in numpy (the tracker's
filter). :func:`filterpy_reference` builds the equivalent ``filterpy.kalman.KalmanFilter`` for one
track; it is the documented reference, and the tests check that both give the same estimates.

Model: ``x_k = F(dt) x_{k-1} + w``, ``F = [[I, dt I], [0, I]]``, ``w`` discrete white-noise
acceleration with spectral density ``q``: ``Q = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]``.
Measurement: position only, ``z = H x + v``, ``H = [I 0]``, ``v ~ N(0, R)`` with R taken from the
detection when it has a covariance. Initial state: the first detection's position with covariance
``init_position_var`` I (1 m^2 in the paper) or, with ``init_position_from_detection``, the
detection's own covariance R (a stereo detection at 40 m is uncertain by metres in depth, not
1 m); velocity zero (the paper) or the scene's common motion (``init_velocity="scene"``, see
:mod:`.scene_motion`), variance ``init_velocity_var`` (50 (m/s)^2; while the scene motion is
unknown, the per-axis prior :data:`.scene_motion.UNKNOWN_SCENE_VELOCITY_VAR`). The update uses
``P - K H P``
(filterpy uses the Joseph form; equal for the optimal gain, checked by the tests).

With ``birth_max_speed > 0``, a track born in the world frame (``static_velocity`` given)
starts with a bank of velocity hypotheses (parked, moving forward / backward along its heading)
until it has ``birth_resolve_updates`` corrections (:mod:`.birth_hypotheses`).
"""

from __future__ import annotations

import numpy as np

from .birth_hypotheses import BirthHypotheses, heading_axis
from .ego_motion import rotate_covariances
from .scene_motion import (
    known_scene_var,
    reset_velocity_covariance,
    restarted_velocity_prior,
    velocity_prior,
)

_I3 = np.eye(3)


def transition(dt: float) -> np.ndarray:
    """The 6x6 constant-velocity transition matrix F(dt)."""
    F = np.eye(6)
    F[:3, 3:] = dt * _I3
    return F


def process_noise(dt: float, q: float) -> np.ndarray:
    """The 6x6 discrete white-noise-acceleration process covariance Q(dt) for density q."""
    Q = np.zeros((6, 6))
    Q[:3, :3] = (dt**3 / 3.0) * _I3
    Q[:3, 3:] = Q[3:, :3] = (dt**2 / 2.0) * _I3
    Q[3:, 3:] = dt * _I3
    return q * Q


def inv3_sym(S: np.ndarray) -> np.ndarray:
    """Inverses of symmetric 3x3 matrices (..., 3, 3) in closed form (adjugate / determinant);
    much cheaper than ``np.linalg.inv`` on small batches."""
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    d, e, f = S[..., 1, 1], S[..., 1, 2], S[..., 2, 2]
    A = d * f - e * e
    B = c * e - b * f
    C = b * e - c * d
    det = a * A + b * B + c * C
    out = np.empty(S.shape)
    out[..., 0, 0] = A
    out[..., 0, 1] = out[..., 1, 0] = B
    out[..., 0, 2] = out[..., 2, 0] = C
    out[..., 1, 1] = a * f - c * c
    out[..., 1, 2] = out[..., 2, 1] = b * c - a * e
    out[..., 2, 2] = a * d - b * b
    out /= det[..., None, None]
    return out


def robust_noise(nu: np.ndarray, S: np.ndarray, R: np.ndarray, k: float) -> np.ndarray:
    """Measurement covariances ``R`` (M, 3, 3) re-weighted for innovations ``nu`` (M, 3) with
    covariances ``S`` (M, 3, 3): a Huber-type weight on the Mahalanobis size d of the
    innovation, ``R`` times max(1, d / k), so an innovation beyond ``k`` standard deviations
    moves the state by about ``k`` of them at most (a stereo depth that jumped to the
    background or an occluder); ordinary innovations (d <= k) are taken as before. ``k`` <= 0:
    ``R`` unchanged."""
    if k <= 0 or not len(nu):
        return R
    d = np.sqrt(np.einsum("mi,mij,mj->m", nu, inv3_sym(S), nu))
    return R * np.maximum(1.0, d / k)[:, None, None]


class BatchedKalmanFilter:
    """Constant-velocity Kalman filters of N tracks in structure-of-arrays form.

    ``x``: (N, 6) states, ``P``: (N, 6, 6) covariances. Rows are added with :meth:`add` and
    dropped with :meth:`keep`; row order is the tracker's track order.
    """

    name = "kalman"

    def __init__(
        self,
        q: float,
        init_position_var: float = 1.0,
        init_velocity_var: float = 50.0,
        init_velocity: str = "zero",
        init_position_from_detection: bool = False,
        birth_max_speed: float = 0.0,
        birth_speed_steps: int = 3,
        birth_moving_prior: float = 0.18,
        birth_hypothesis_var: float = 4.0,
        birth_resolve_updates: int = 10,
    ):
        self.q = float(q)
        self.P0 = np.diag([init_position_var] * 3 + [init_velocity_var] * 3).astype(float)
        self.init_velocity = init_velocity
        self.init_position_from_detection = bool(init_position_from_detection)
        self.x = np.zeros((0, 6))
        self.P = np.zeros((0, 6, 6))
        self.updates = np.zeros(0, dtype=int)  # detections each track was corrected with
        self._model_dt: float | None = None
        self._model_cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.hypotheses = None  # velocity hypotheses of young tracks (birth_max_speed > 0)
        if birth_max_speed > 0:
            self.hypotheses = BirthHypotheses(
                BatchedKalmanFilter(q),
                birth_max_speed,
                birth_speed_steps,
                birth_moving_prior,
                known_scene_var(birth_hypothesis_var),
                birth_resolve_updates,
            )

    def __len__(self) -> int:
        return len(self.x)

    def add(
        self,
        z: np.ndarray,
        R: np.ndarray,
        static_velocity: np.ndarray | None = None,
        heading: np.ndarray | None = None,
    ) -> None:
        """Start tracks at positions ``z`` (M, 3) with covariances ``R`` (M, 3, 3) (used as the
        initial position covariance with ``init_position_from_detection``), velocity per
        ``init_velocity`` (``static_velocity`` (M, 3): the apparent velocity of static points
        at ``z`` when the camera's motion is known, see :func:`.scene_motion.velocity_prior`).
        ``heading`` (M,): the detections' yaw (NaN: unknown), the axis of the moving velocity
        hypotheses of tracks born in the world frame (:mod:`.birth_hypotheses`)."""
        m = len(z)
        x = np.zeros((m, 6))
        x[:, :3] = z
        v0, v_var = velocity_prior(
            self.init_velocity,
            self.velocity,
            self.updates,
            self.P0[3, 3],
            static_velocity=static_velocity,
        )
        x[:, 3:] = v0
        P = np.repeat(self.P0[None], m, axis=0)
        P[:, 3:, 3:] = np.diag(v_var)
        if self.init_position_from_detection and m:
            P[:, :3, :3] = R
        rows = np.arange(len(self.x), len(self.x) + m)
        self.append(x, P)
        if self.hypotheses is not None and static_velocity is not None and m:
            # the hypotheses are velocities over the ground: parked = the static world's
            # velocity (not the established tracks' median, a moving one in traffic)
            x = x.copy()
            x[:, 3:] = static_velocity
            self.hypotheses.start(rows, x, P, heading_axis(heading, m))
            self._take_mixture()

    def append(self, x: np.ndarray, P: np.ndarray) -> None:
        """Append rows with states ``x`` (M, 6) and covariances ``P`` (M, 6, 6)."""
        self.x = np.concatenate([self.x, x])
        self.P = np.concatenate([self.P, P])
        self.updates = np.concatenate([self.updates, np.zeros(len(x), dtype=int)])

    def _take_mixture(self) -> None:
        """Tracks with a hypothesis bank take its mixture's moments."""
        rows = self.hypotheses.owners()
        if len(rows):
            self.x[rows], self.P[rows] = self.hypotheses.mixture(rows)

    def restart_velocity(self, rows: np.ndarray, static_velocity: np.ndarray) -> None:
        """Tracks ``rows``, not yet corrected by a second detection (their velocity is still
        the prior they were born with), take the prior again now that the static scene's
        apparent velocity at their positions, ``static_velocity`` (M, 3), is known
        (:func:`.scene_motion.velocity_prior`; no change once the scene motion is known from
        established tracks, or in the paper's "zero" mode)."""
        prior = restarted_velocity_prior(
            self.init_velocity, self.velocity, self.updates, self.P0[3, 3], static_velocity
        )
        if prior is None:
            return
        if self.hypotheses is not None:
            self.hypotheses.drop(rows)
        self.x[rows, 3:], v_var = prior
        reset_velocity_covariance(self.P, rows, v_var)

    def start_hypotheses(
        self, rows: np.ndarray, static_velocity: np.ndarray, heading: np.ndarray | None
    ) -> None:
        """Tracks ``rows`` (sorted), seen once before the camera's motion was known, take the
        velocity hypotheses a track born in the world frame gets (parked = ``static_velocity``
        (M, 3), moving both ways along ``heading`` (M,) yaws), as if born now; without them
        their velocity prior is one narrow Gaussian about the static world's, and a car
        driving ahead at the camera's speed (real 0005's lead car, 18 m/s) was followed
        1.3-1.5 m behind for its first frames (:mod:`.birth_hypotheses`). Nothing without
        ``birth_max_speed``."""
        if self.hypotheses is None or not len(rows):
            return
        self.hypotheses.drop(rows)
        x = self.x[rows].copy()
        x[:, 3:] = static_velocity
        self.hypotheses.start(rows, x, self.P[rows], heading_axis(heading, len(rows)))
        self._take_mixture()

    def keep(self, mask: np.ndarray) -> None:
        """Keep only the rows where ``mask`` is true."""
        if self.hypotheses is not None:
            self.hypotheses.keep(mask)
        self.x = self.x[mask]
        self.P = self.P[mask]
        self.updates = self.updates[mask]

    def _model(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """F, F^T and Q for ``dt``, cached (successive frames share one dt)."""
        if self._model_dt != dt:
            F = transition(dt)
            self._model_cache = (F, F.T.copy(), process_noise(dt, self.q))
            self._model_dt = dt
        return self._model_cache

    def predict(self, dt: float) -> None:
        """Advance all tracks by ``dt`` seconds."""
        if not len(self.x):
            return
        F, FT, Q = self._model(dt)
        self.x[:, :3] += dt * self.x[:, 3:]
        # two batched 6x6 products: fewer numpy calls than the blockwise form at small N
        P = np.matmul(F, self.P)
        np.matmul(P, FT, out=P)
        P += Q
        self.P = P
        if self.hypotheses is not None and len(self.hypotheses):
            self.hypotheses.bank.predict(dt)
            self._take_mixture()

    def set_process_noise(self, q: float) -> None:
        """Use white-acceleration density ``q`` from the next prediction on."""
        self.q = float(q)
        self._model_dt = None
        if self.hypotheses is not None:
            self.hypotheses.bank.set_process_noise(q)

    def move_frame(self, R: np.ndarray, t: np.ndarray) -> None:
        """Express every track in a new camera frame, ``X_new = R X + t`` (the camera's own
        motion, :mod:`.ego_motion`): positions moved, velocities (over the ground) rotated,
        covariances ``A P A'`` with ``A = diag(R, R)``."""
        if not len(self.x):
            return
        self.x[:, :3] = self.x[:, :3] @ R.T + t
        self.x[:, 3:] = self.x[:, 3:] @ R.T
        self.P = rotate_covariances(self.P, R)
        if self.hypotheses is not None and len(self.hypotheses):
            self.hypotheses.bank.move_frame(R, t)

    def shift_velocity(self, dv: np.ndarray) -> None:
        """Subtract ``dv`` (N, 3) from every track's velocity (a change of reference: relative
        to the camera -> over the ground, :mod:`.ego_motion`); covariances unchanged."""
        self.x[:, 3:] -= dv
        if self.hypotheses is not None and len(self.hypotheses):
            dv = np.broadcast_to(dv, self.x[:, 3:].shape)
            self.hypotheses.bank.x[:, 3:] -= dv[self.hypotheses.owner]

    def update(self, rows: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        """Correct tracks ``rows`` (M,) with measured positions ``z`` (M, 3), covariances
        ``R`` (M, 3, 3)."""
        if not len(rows):
            return
        x, P = self.x[rows], self.P[rows]
        PHt = P[:, :, :3]  # P H^T, (M, 6, 3)
        K = PHt @ inv3_sym(P[:, :3, :3] + R)  # gain P H^T S^-1
        x += (K @ (z - x[:, :3])[:, :, None])[:, :, 0]
        # P - K H P (equal to filterpy's Joseph form for this optimal gain), kept symmetric
        P -= K @ P[:, :3, :]
        P = 0.5 * (P + P.transpose(0, 2, 1))
        self.x[rows] = x
        self.P[rows] = P
        self.updates[rows] += 1
        if self.hypotheses is not None and len(self.hypotheses):
            self._update_hypotheses(rows, z, R)

    def _update_hypotheses(self, rows: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        """Correct the hypothesis banks of ``rows``; tracks with ``resolve_updates``
        corrections take their most probable hypothesis, the others their mixture."""
        h = self.hypotheses
        h.update(rows, z, R)
        owners = h.owners()
        done = owners[self.updates[owners] >= h.resolve_updates]
        if len(done):
            self.x[done], self.P[done] = h.resolve(done)
        self._take_mixture()

    @property
    def position(self) -> np.ndarray:
        return self.x[:, :3]

    @property
    def velocity(self) -> np.ndarray:
        return self.x[:, 3:]

    @property
    def position_cov(self) -> np.ndarray:
        return self.P[:, :3, :3]

    @property
    def velocity_cov(self) -> np.ndarray:
        return self.P[:, 3:, 3:]


def filterpy_reference(
    z0: np.ndarray,
    q: float,
    R: np.ndarray,
    init_position_var: float = 1.0,
    init_velocity_var: float = 50.0,
):
    """The same filter for one track as a ``filterpy.kalman.KalmanFilter`` (reference).

    Before each ``predict()`` set ``kf.F = transition(dt)`` and ``kf.Q = process_noise(dt, q)``.
    """
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.x = np.concatenate([np.asarray(z0, float), np.zeros(3)])
    kf.P = np.diag([init_position_var] * 3 + [init_velocity_var] * 3).astype(float)
    kf.H = np.hstack([_I3, np.zeros((3, 3))])
    kf.R = np.asarray(R, float)
    kf.F = transition(0.1)
    kf.Q = process_noise(0.1, q)
    return kf
