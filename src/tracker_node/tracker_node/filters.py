"""The motion-filter interface, the unfiltered baseline, and the factory selecting a filter.

Every filter is batched over the tracks (row i = the tracker's i-th track) and offers:
``add(z, R, static_velocity=None, heading=None)``, ``restart_velocity(rows, static_velocity)``,
``keep(mask)``, ``predict(dt)``, ``move_frame(R, t)`` (the camera's own motion: every track
expressed in the new camera frame, :mod:`.ego_motion`), ``shift_velocity(dv)`` (a change of
velocity reference), ``set_process_noise(q)``, ``update(rows, z, R)`` and the arrays
``position`` (N, 3), ``velocity`` (N, 3), ``position_cov`` (N, 3, 3), ``velocity_cov`` (N, 3, 3).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from .config import TrackerConfig
from .ego_motion import rotate_covariances
from .kalman import BatchedKalmanFilter
from .particle import BatchedParticleFilter


class MotionFilter(Protocol):
    """What the tracker needs from a filter (see the module docstring)."""

    name: str

    def __len__(self) -> int: ...
    def add(self, z: np.ndarray, R: np.ndarray, static_velocity=None, heading=None) -> None: ...
    def keep(self, mask: np.ndarray) -> None: ...
    def restart_velocity(self, rows: np.ndarray, static_velocity: np.ndarray) -> None: ...
    def predict(self, dt: float) -> None: ...
    def move_frame(self, R: np.ndarray, t: np.ndarray) -> None: ...
    def set_process_noise(self, q: float) -> None: ...
    def shift_velocity(self, dv: np.ndarray) -> None: ...
    def update(self, rows: np.ndarray, z: np.ndarray, R: np.ndarray) -> None: ...

    @property
    def position(self) -> np.ndarray: ...
    @property
    def velocity(self) -> np.ndarray: ...
    @property
    def position_cov(self) -> np.ndarray: ...
    @property
    def velocity_cov(self) -> np.ndarray: ...


class PassThroughFilter:
    """The unfiltered baseline: a track's position is its last detection's (held while
    coasting), its velocity the finite difference of its last two detections (over the time
    between them: frames dropped at camera rate make it longer than a frame period)."""

    name = "none"

    def __init__(
        self, init_position_var: float = 1.0, init_velocity_var: float = 50.0, dt: float = 0.1
    ):
        self.pos_var = float(init_position_var)
        self.vel_var = float(init_velocity_var)
        self.dt = float(dt)  # [s] frame period (the span of a difference not yet taken)
        self._pos = np.zeros((0, 3))
        self._vel = np.zeros((0, 3))
        self._R = np.zeros((0, 3, 3))
        self._elapsed = np.zeros(0)
        self._span = np.zeros(0)  # [s] between the two detections of the last difference
        self._seen = np.zeros(0, dtype=bool)

    def __len__(self) -> int:
        return len(self._pos)

    def add(self, z: np.ndarray, R: np.ndarray, static_velocity=None, heading=None) -> None:
        """Start tracks at ``z``; the velocity (zero) is the finite difference from the next
        detection on, so ``static_velocity`` and ``heading`` (a prior) are not used."""
        m = len(z)
        self._pos = np.concatenate([self._pos, z])
        self._vel = np.concatenate([self._vel, np.zeros((m, 3))])
        self._R = np.concatenate([self._R, R])
        self._elapsed = np.concatenate([self._elapsed, np.zeros(m)])
        self._span = np.concatenate([self._span, np.full(m, self.dt)])
        self._seen = np.concatenate([self._seen, np.zeros(m, dtype=bool)])

    def restart_velocity(self, rows: np.ndarray, static_velocity: np.ndarray) -> None:
        """No prior to restart: the velocity is a finite difference of detections."""

    def keep(self, mask: np.ndarray) -> None:
        self._pos, self._vel, self._R = self._pos[mask], self._vel[mask], self._R[mask]
        self._elapsed, self._seen = self._elapsed[mask], self._seen[mask]
        self._span = self._span[mask]

    def predict(self, dt: float) -> None:
        self._elapsed = self._elapsed + dt

    def move_frame(self, R: np.ndarray, t: np.ndarray) -> None:
        """The held detection moves with the camera's motion into the new frame (a parked car's
        stays where it is in the world), velocity and covariance rotated: the next finite
        difference is over the ground."""
        if not len(self._pos):
            return
        self._pos = self._pos @ R.T + t
        self._vel = self._vel @ R.T
        self._R = rotate_covariances(self._R, R)

    def shift_velocity(self, dv: np.ndarray) -> None:
        self._vel = self._vel - dv

    def set_process_noise(self, q: float) -> None:
        """No motion model: nothing to change."""

    def update(self, rows: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        if not len(rows):
            return
        span = np.maximum(self._elapsed[rows], 1e-6)
        self._vel[rows] = (z - self._pos[rows]) / span[:, None]
        self._span[rows] = span
        self._seen[rows] = True
        self._pos[rows] = z
        self._R[rows] = R
        self._elapsed[rows] = 0.0

    @property
    def position(self) -> np.ndarray:
        return self._pos

    @property
    def velocity(self) -> np.ndarray:
        return self._vel

    @property
    def position_cov(self) -> np.ndarray:
        # the detection's covariance, growing while the track coasts (for gating)
        grow = (self.vel_var * self._elapsed**2)[:, None, None] * np.eye(3)
        return self._R + grow

    @property
    def velocity_cov(self) -> np.ndarray:
        # the difference of two detections' noise over the time between them
        v = 2.0 * np.trace(self._R, axis1=1, axis2=2) / 3.0 / self._span**2
        v = np.where(self._seen, v, self.vel_var)
        return v[:, None, None] * np.eye(3)


def make_filter(cfg: TrackerConfig) -> MotionFilter:
    """The batched filter selected by ``cfg.filter``."""
    if cfg.filter == "kalman":
        return BatchedKalmanFilter(
            cfg.process_noise,
            cfg.init_position_var,
            cfg.init_velocity_var,
            cfg.init_velocity,
            cfg.init_position_from_detection,
            birth_max_speed=cfg.birth_max_speed,
            birth_speed_steps=cfg.birth_speed_steps,
            birth_moving_prior=cfg.birth_moving_prior,
            birth_hypothesis_var=cfg.birth_hypothesis_var,
            birth_resolve_updates=cfg.birth_resolve_updates,
        )
    if cfg.filter == "particle":
        return BatchedParticleFilter(
            num_particles=cfg.num_particles,
            q=cfg.process_noise,
            init_position_var=cfg.init_position_var,
            init_velocity_var=cfg.init_velocity_var,
            init_velocity=cfg.init_velocity,
            init_position_from_detection=cfg.init_position_from_detection,
            roughening=cfg.particle_roughening,
            proposal=cfg.particle_proposal,
            seed=cfg.seed,
        )
    if cfg.filter == "none":
        return PassThroughFilter(cfg.init_position_var, cfg.init_velocity_var, cfg.default_dt)
    raise ValueError(f"filter: unknown filter {cfg.filter!r}")
