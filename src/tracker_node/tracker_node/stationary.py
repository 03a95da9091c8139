"""A stationary (parked) model beside the motion filter, in the world frame (issue #41 item 4).

Once the tracker has the camera's motion, a parked car stands still in the world, but the
constant-velocity filter still lets its velocity wander (a stereo detection at 40 m is
uncertain by a metre in depth, so every correction moves the velocity by a fraction of the
innovation), and the reported position follows: on real KITTI 0005 the parked cars' velocity
over the ground swung between -1.5 and +1.8 m/s and their positions jumped by 0.2-0.5 m
per frame (second difference), ten times the labels'.

This model keeps, per track, a second estimate: the car's position if it is parked, a 3-state
Kalman filter with no velocity (the inverse-variance mean of its detections in the world frame,
moved with the camera like the motion filter's state; ``process_noise`` [m^2/s] a slow random
walk for the odometry's drift), and the probability ``mu`` that the car is parked, from the two
models' innovation likelihoods of each detection (a two-model switching filter without
mixing: the motion filter is never changed by this one, so a car that starts moving is
followed by the motion filter with its own latency; the reported state leaves the parked
estimate as fast as ``mu`` falls, within a frame or two for a car moving more than a metre per
frame). The reported position is the mixture: ``mu`` times the parked estimate plus ``1 - mu``
times the motion filter's; the velocity is the motion filter's (:meth:`blend`). With
``mixing`` the tracker also runs the IMM's interaction step (:meth:`mix`) on Kalman rows. Pure
numpy.
"""

from __future__ import annotations

import numpy as np

from .ego_motion import rotate_covariances
from .kalman import inv3_sym, robust_noise

_LOG_2PI_3 = 3.0 * np.log(2.0 * np.pi)


def log_likelihood(innovation: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Gaussian log densities (M,) of innovations (M, 3) with covariances S (M, 3, 3)."""
    Si = inv3_sym(S)
    m = np.einsum("ni,nij,nj->n", innovation, Si, innovation)
    det = np.linalg.det(S)
    return -0.5 * (m + np.log(np.maximum(det, 1e-300)) + _LOG_2PI_3)


class StationaryModel:
    """Parked-car estimates of N tracks (row i = the tracker's i-th track).

    ``prior``: probability that a new track is parked; ``switch``: probability per frame that a
    car changes between parked and moving (the Markov chain's off-diagonal); ``process_noise``
    [m^2/s]: the parked position's random walk; ``report_rate``: the most the weight of the
    parked estimate in the reported position changes per frame (:meth:`settle`; 1: it is
    ``mu``). Inactive (``active`` False) until the tracker has the camera's motion: without it a
    parked car moves in the camera frame."""

    def __init__(
        self,
        prior: float,
        switch: float,
        process_noise: float,
        min_updates: int = 0,
        robust_k: float = 0.0,
        report_rate: float = 1.0,
    ):
        self.prior = float(prior)
        self.robust_k = float(robust_k)  # kalman.robust_noise's k (0: off)
        self.switch = float(switch)
        self.q = float(process_noise)
        self.min_updates = int(min_updates)
        self.report_rate = float(report_rate)
        self.active = False
        self.x = np.zeros((0, 3))
        self.P = np.zeros((0, 3, 3))
        self.mu = np.zeros(0)
        self.updates = np.zeros(0, dtype=int)  # detections each parked estimate has taken
        self.weight = np.zeros(0)  # the parked estimate's weight in the reported position

    def __len__(self) -> int:
        return len(self.x)

    def start(self, position: np.ndarray, cov: np.ndarray) -> None:
        """Become active (the world frame begins) with every existing track's parked estimate
        at its motion filter's position and covariance, probability ``prior``."""
        self.active = True
        self.x = np.array(position, float).reshape(-1, 3)
        self.P = np.array(cov, float).reshape(-1, 3, 3)
        self.mu = np.full(len(self.x), self.prior)
        self.updates = np.zeros(len(self.x), dtype=int)
        self.weight = self._blend_weight(np.arange(len(self.x)))

    def add(self, z: np.ndarray, R: np.ndarray) -> None:
        m = len(z)
        self.x = np.concatenate([self.x, np.asarray(z, float).reshape(m, 3)])
        self.P = np.concatenate([self.P, np.asarray(R, float).reshape(m, 3, 3)])
        self.mu = np.concatenate([self.mu, np.full(m, self.prior if self.active else 0.0)])
        self.updates = np.concatenate([self.updates, np.zeros(m, dtype=int)])
        new = np.arange(len(self.x) - m, len(self.x))
        self.weight = np.concatenate([self.weight, self._blend_weight(new)])

    def keep(self, mask: np.ndarray) -> None:
        self.x, self.P, self.mu = self.x[mask], self.P[mask], self.mu[mask]
        self.updates, self.weight = self.updates[mask], self.weight[mask]

    def mix(self, x: np.ndarray, P: np.ndarray, rows: np.ndarray) -> None:
        """The IMM's interaction step for motion-filter rows ``rows`` (constant-velocity
        states ``x`` (N, 6), covariances ``P`` (N, 6, 6), changed in place): each model starts
        the frame from the mixture of both estimates, weighted by the probability that the car
        was in the other model and switched (a parked car's state: its position, velocity
        exactly 0). Without it the two estimates drift apart and the reported mixture jumps
        when ``mu`` moves."""
        if not (self.active and len(rows)):
            return
        s, mu = self.switch, self.mu[rows]
        c_s = (1.0 - s) * mu + s * (1.0 - mu)  # probability parked after the switch
        c_m = 1.0 - c_s
        w_ms = (s * (1.0 - mu) / c_s)[:, None]  # moving -> parked share of the parked input
        w_sm = (s * mu / c_m)[:, None]  # parked -> moving share of the moving input
        xs, Ps = self.x[rows], self.P[rows]
        xm, Pm = x[rows], P[rows]
        # parked model's input: its estimate mixed with the moving one's position
        e = xm[:, :3] - xs
        xs0 = xs + w_ms * e
        d0, e0 = xs - xs0, xm[:, :3] - xs0
        self.P[rows] = (1.0 - w_ms)[:, :, None] * (Ps + d0[:, :, None] * d0[:, None, :]) + w_ms[
            :, :, None
        ] * (Pm[:, :3, :3] + e0[:, :, None] * e0[:, None, :])
        self.x[rows] = xs0
        # moving model's input: its state mixed with the parked one's (velocity 0)
        xa = np.zeros_like(xm)
        xa[:, :3] = xs
        Pa = np.zeros_like(Pm)
        Pa[:, :3, :3] = Ps
        xm0 = (1.0 - w_sm) * xm + w_sm * xa
        da, dm = xa - xm0, xm - xm0
        P[rows] = w_sm[:, :, None] * (Pa + da[:, :, None] * da[:, None, :]) + (1.0 - w_sm)[
            :, :, None
        ] * (Pm + dm[:, :, None] * dm[:, None, :])
        x[rows] = xm0

    def predict(self, dt: float, rotation=None, translation=None) -> None:
        """Random walk over ``dt``, then into the current camera axes (``X_new = R X + t``);
        the Markov chain's prior for this frame."""
        if not (self.active and len(self.x)):
            return
        self.P = self.P + (self.q * dt) * np.eye(3)
        if rotation is not None:
            self.x = self.x @ rotation.T + translation
            self.P = rotate_covariances(self.P, rotation)
        s = self.switch
        self.mu = (1.0 - s) * self.mu + s * (1.0 - self.mu)

    def update(
        self,
        rows: np.ndarray,
        z: np.ndarray,
        R: np.ndarray,
        moving_position: np.ndarray,
        moving_cov: np.ndarray,
    ) -> None:
        """Correct tracks ``rows`` with detections ``z`` (M, 3), covariances ``R``;
        ``moving_position`` / ``moving_cov``: the motion filter's predicted position and its
        covariance for the same rows (before its own update), for its likelihood."""
        if not (self.active and len(rows)):
            return
        x, P = self.x[rows], self.P[rows]
        S = P + R
        nu = z - x
        ll_s = log_likelihood(nu, S)
        ll_m = log_likelihood(z - moving_position, moving_cov + R)
        if self.robust_k > 0:  # the likelihoods above keep the stated R
            S = P + robust_noise(nu, S, R, self.robust_k)
        K = P @ inv3_sym(S)
        self.x[rows] = x + (K @ nu[:, :, None])[:, :, 0]
        P = P - K @ P
        self.P[rows] = 0.5 * (P + P.transpose(0, 2, 1))
        mu = np.clip(self.mu[rows], 1e-9, 1.0 - 1e-9)
        log_odds = np.log(mu) - np.log1p(-mu) + ll_s - ll_m
        self.mu[rows] = 1.0 / (1.0 + np.exp(-np.clip(log_odds, -50.0, 50.0)))
        self.updates[rows] += 1

    def _blend_weight(self, rows: np.ndarray) -> np.ndarray:
        """``mu`` of ``rows``, 0 where the parked estimate has taken fewer than
        ``min_updates`` detections."""
        return np.where(self.updates[rows] >= self.min_updates, self.mu[rows], 0.0)

    def settle(self) -> None:
        """End of a frame: the parked estimate's weight in the reported position moves toward
        :meth:`_blend_weight` by at most ``report_rate``. A far car first taken for parked
        loses ``mu`` within a frame or two once it is seen to move, and its reported position
        would catch up by metres in one step (the largest second differences on the camera
        benchmark, docs/tracker.md); at most ``report_rate`` per frame spreads the step over
        frames. 1: nothing to do (:meth:`blend` reads ``mu`` itself)."""
        r = self.report_rate
        if r >= 1.0 or not (self.active and len(self.x)):
            return  # at 1, :meth:`blend` reads mu itself
        target = self._blend_weight(np.arange(len(self.x)))
        self.weight = np.clip(target, self.weight - r, self.weight + r)

    def blend(self, rows: np.ndarray, position: np.ndarray) -> np.ndarray:
        """The reported position of tracks ``rows`` from the motion filter's ``position``
        (M, 3): the mixture with the parked estimate. The velocity stays the motion filter's
        (the mixture's velocity, ``1 - mu`` times it, slowed cars that were still taken for
        parked: velocity RMSE on real 0005 2.18 -> 2.75 m/s, moving cars on the camera
        benchmark's tuning sequences 2.38 -> 2.57 m/s; the position alone changes neither).
        A parked estimate that has taken fewer than ``min_updates`` detections is not blended:
        until then ``mu`` is mostly the prior, and a young moving car taken for parked is
        reported at its first detections, behind it by its speed times the frames (real 0005's
        lead car, 18 m/s: 1.8-1.9 m off at its third frame with ``mu`` 0.74-0.77, where the
        filter alone was within 1.3-1.5 m; ``mu`` fell to 0.02 one frame later)."""
        if not (self.active and len(rows)):
            return position
        if self.report_rate >= 1.0:
            mu = self._blend_weight(rows)[:, None]
        else:
            mu = self.weight[rows][:, None]
        return mu * self.x[rows] + (1.0 - mu) * position
