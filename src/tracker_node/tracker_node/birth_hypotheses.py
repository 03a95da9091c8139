"""Multi-hypothesis velocity at a track's birth: a Gaussian sum over the velocity over the ground.

In the world frame a new track starts at the static scene's velocity (about 0 over the ground,
:mod:`.scene_motion`) with a unimodal prior. Real cars' velocities over the ground are not
unimodal: most are parked (~0), the others drive along the road at 8-15 m/s, one way or the
other. A car oncoming at 12 m/s is 2.5 standard deviations off a prior of variance 23 (m/s)^2,
and a stereo detection's few-decimetre position noise gives little velocity evidence per frame
at 10 Hz, so the single filter needs many frames to reach its speed.

Here a track born in the world frame carries, while it is young, a small bank of Kalman filters
(the multiple-model / Gaussian-sum filter of Bar-Shalom, Li & Kirubarajan, "Estimation with
Applications to Tracking and Navigation", 2001, ch. 11; filterpy's ``IMMEstimator`` holds its
bank the same way, here without mode switching): the track's position prior, velocity means

    v0 (parked: the static world's velocity, not the established tracks' median, which is a
        moving one in traffic),
    v0 +- s_j a,   s_j = j / n * birth_max_speed,  j = 1..n  (n = ``birth_speed_steps``)

with ``a`` the car's heading axis in the camera's x-z plane (from the detection's yaw, its
orientation bin up to 180 degrees, which is why both ways; the optical axis when the detection
gives none), prior probabilities ``1 - p`` (parked) and ``p / 2n`` each (``p`` =
``birth_moving_prior``), and each hypothesis' velocity covariance
:func:`.scene_motion.known_scene_var` of ``birth_hypothesis_var`` (narrow: the spread of the
speeds is in the set of means, not in each one). Every hypothesis is predicted and
corrected like the track's filter; its log weight accumulates the log likelihood of each
detection under its predicted measurement (``N(z; H x, H P H' + R)``). Until the track has
``resolve_updates`` corrections, the track's state is the mixture's moments (its position and
covariance cover every hypothesis, for gating); then the track takes the most probable
hypothesis and the bank is dropped. Tracks born while the camera's motion is unknown (velocity
relative to the camera) get no bank. Pure numpy.
"""

from __future__ import annotations

import numpy as np

from .scene_motion import reset_velocity_covariance


def hypothesis_speeds(max_speed: float, steps: int) -> np.ndarray:
    """Signed speeds (2 steps + 1,) along the heading axis: 0, then +-s for s = max_speed j /
    steps, j = 1..steps."""
    s = float(max_speed) * np.arange(1, int(steps) + 1) / int(steps)
    return np.concatenate([[0.0], np.stack([s, -s], axis=1).ravel()])


def heading_axis(yaw: np.ndarray | None, m: int) -> np.ndarray:
    """Unit heading axes (m, 3) in the camera frame from KITTI rotation_y ``yaw`` (m,): the
    box's length direction ``(cos yaw, 0, -sin yaw)`` (:mod:`.orientation`); the optical axis
    (0, 0, 1) where the yaw is unknown (NaN) or not given."""
    axis = np.zeros((m, 3))
    axis[:, 2] = 1.0
    if yaw is None:
        return axis
    yaw = np.asarray(yaw, float).reshape(m)
    ok = np.isfinite(yaw)
    axis[ok, 0] = np.cos(yaw[ok])
    axis[ok, 2] = -np.sin(yaw[ok])
    return axis


def log_priors(moving_prior: float, n_moving: int) -> np.ndarray:
    """Log prior probabilities (1 + n_moving,): parked ``1 - moving_prior``, each of the
    ``n_moving`` moving hypotheses an equal share of ``moving_prior``."""
    p = float(moving_prior)
    return np.log(np.array([1.0 - p] + [p / n_moving] * n_moving))


def gaussian_loglik(innovation: np.ndarray, S: np.ndarray) -> np.ndarray:
    """log N(innovation; 0, S) for (K, 3) innovations and (K, 3, 3) covariances."""
    _, logdet = np.linalg.slogdet(S)
    maha = np.einsum("ki,ki->k", innovation, np.linalg.solve(S, innovation[:, :, None])[:, :, 0])
    return -0.5 * (maha + logdet + 3.0 * np.log(2.0 * np.pi))


class BirthHypotheses:
    """The hypothesis banks of young tracks: ``bank``, a Kalman filter (the track filter's
    class, :class:`.kalman.BatchedKalmanFilter`) with one row per (track, hypothesis);
    ``owner`` (K,): the track row each belongs to; ``logw`` (K,): its unnormalised log
    posterior. Track rows follow the owning filter's (:meth:`keep` keeps them aligned)."""

    def __init__(
        self,
        bank,
        max_speed: float,
        steps: int,
        moving_prior: float,
        velocity_var: np.ndarray,
        resolve_updates: int,
    ):
        self.bank = bank
        self.speeds = hypothesis_speeds(max_speed, steps)
        self.log_prior = log_priors(moving_prior, len(self.speeds) - 1)
        self.velocity_var = np.asarray(velocity_var, float)  # (3,) per hypothesis
        self.resolve_updates = int(resolve_updates)
        self.owner = np.zeros(0, dtype=int)
        self.logw = np.zeros(0)

    def __len__(self) -> int:
        return len(self.owner)

    def start(self, rows: np.ndarray, x: np.ndarray, P: np.ndarray, axis: np.ndarray) -> None:
        """Banks for new tracks ``rows`` (M,) born with state ``x`` (M, 6) and covariance ``P``
        (M, 6, 6): one copy per hypothesis, the velocity moved by each of ``speeds`` along
        ``axis`` (M, 3), the velocity covariance ``velocity_var`` (diagonal, no
        position-velocity correlation)."""
        m, h = len(rows), len(self.speeds)
        if not m:
            return
        P = P.copy()
        reset_velocity_covariance(P, np.arange(m), self.velocity_var)
        xs = np.repeat(x[:, None, :], h, axis=1)
        xs[:, :, 3:] += self.speeds[None, :, None] * axis[:, None, :]
        self.bank.append(xs.reshape(m * h, 6), np.repeat(P, h, axis=0))
        self.owner = np.concatenate([self.owner, np.repeat(rows, h)])
        self.logw = np.concatenate([self.logw, np.tile(self.log_prior, m)])

    def keep(self, mask: np.ndarray) -> None:
        """The owning filter keeps track rows ``mask`` (N,): drop the banks of the others and
        renumber the owners."""
        if not len(self.owner):
            return
        alive = mask[self.owner]
        new_index = np.cumsum(mask) - 1
        self.bank.keep(alive)
        self.owner = new_index[self.owner[alive]]
        self.logw = self.logw[alive]

    def drop(self, rows: np.ndarray) -> None:
        """Forget the banks of track rows ``rows`` (their tracks keep their own state)."""
        if len(self.owner) and len(rows):
            alive = ~np.isin(self.owner, rows)
            self.bank.keep(alive)
            self.owner, self.logw = self.owner[alive], self.logw[alive]

    def update(self, rows: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        """Correct the hypotheses of track rows ``rows`` (M,) with their detections ``z`` (M, 3),
        ``R`` (M, 3, 3); each hypothesis' weight takes the detection's log likelihood under its
        prediction."""
        if not len(self.owner) or not len(rows):
            return
        col = np.full(self.owner.max() + 1, -1)
        inside = rows <= self.owner.max()
        col[rows[inside]] = np.nonzero(inside)[0]
        j = col[self.owner]
        hit = np.nonzero(j >= 0)[0]
        if not len(hit):
            return
        zj, Rj = z[j[hit]], R[j[hit]]
        x, P = self.bank.x[hit], self.bank.P[hit]
        self.logw[hit] += gaussian_loglik(zj - x[:, :3], P[:, :3, :3] + Rj)
        self.bank.update(hit, zj, Rj)

    def owners(self) -> np.ndarray:
        """Track rows that have a bank (sorted)."""
        return np.unique(self.owner)

    def mixture(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Moment-matched mean (M, 6) and covariance (M, 6, 6) of the banks of track rows
        ``rows`` (each must have one)."""
        w = self._weights()
        out_x = np.zeros((len(rows), 6))
        out_P = np.zeros((len(rows), 6, 6))
        pos = np.searchsorted(rows, self.owner)
        pos = np.clip(pos, 0, len(rows) - 1)
        mine = rows[pos] == self.owner
        k, p = np.nonzero(mine)[0], pos[mine]
        np.add.at(out_x, p, w[k, None] * self.bank.x[k])
        d = self.bank.x[k] - out_x[p]
        spread = self.bank.P[k] + d[:, :, None] * d[:, None, :]
        np.add.at(out_P, p, w[k, None, None] * spread)
        return out_x, out_P

    def resolve(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The most probable hypothesis' state (M, 6) and covariance (M, 6, 6) of each of track
        rows ``rows`` (sorted, each with a bank); their banks are dropped."""
        best = np.full(len(rows), -1)
        best_w = np.full(len(rows), -np.inf)
        for k in np.nonzero(np.isin(self.owner, rows))[0]:
            i = np.searchsorted(rows, self.owner[k])
            if self.logw[k] > best_w[i]:
                best_w[i], best[i] = self.logw[k], k
        x, P = self.bank.x[best].copy(), self.bank.P[best].copy()
        self.drop(rows)
        return x, P

    def _weights(self) -> np.ndarray:
        """Posterior probabilities (K,) of the hypotheses within each bank."""
        top = np.full(self.owner.max() + 1, -np.inf)
        np.maximum.at(top, self.owner, self.logw)
        w = np.exp(self.logw - top[self.owner])
        total = np.zeros(len(top))
        np.add.at(total, self.owner, w)
        return w / total[self.owner]
