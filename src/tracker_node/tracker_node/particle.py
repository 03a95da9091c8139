"""The paper's particle filter for 3D vehicle positions, batched over tracks.

Per track: ``num_particles`` (100) particles drawn uniformly within ``init_radius`` (1 m) of the
first observation; prediction moves them by the mean of the last ``history`` (3) velocity
estimates times dt (plus a small random walk, ``diffusion``, so that resampled particles do not
collapse onto one point); an observation weights them with a 3D Gaussian of covariance
``obs_var`` I (9 m^2) around it; they are then resampled (systematic resampling). When all weights
vanish (underflow) the track's particles are re-seeded around the observation. The estimate is
the particle mean; velocities are finite differences of successive estimates.
"""

from __future__ import annotations

import numpy as np


def _uniform_ball(rng: np.random.Generator, shape: tuple[int, int], radius: float) -> np.ndarray:
    """Points (shape + (3,)) uniform in a ball of ``radius``."""
    v = rng.normal(size=shape + (3,))
    v /= np.linalg.norm(v, axis=-1, keepdims=True) + 1e-12
    r = radius * rng.random(shape + (1,)) ** (1.0 / 3.0)
    return v * r


def _spread(particles: np.ndarray, n: int) -> np.ndarray:
    """Sample covariances (N, 3, 3) of particle sets (N, n, 3)."""
    d = particles - particles.mean(axis=1, keepdims=True)
    return np.einsum("npi,npj->nij", d, d) / max(n - 1, 1)


class BatchedParticleFilter:
    """Particle filters of N tracks: ``particles`` (N, Np, 3)."""

    name = "particle"

    def __init__(
        self,
        num_particles: int = 100,
        init_radius: float = 1.0,
        obs_var: float = 9.0,
        history: int = 3,
        diffusion: float = 0.3,
        seed: int = 0,
        dt: float = 0.1,
    ):
        self.n = int(num_particles)
        self.init_radius = float(init_radius)
        self.obs_var = float(obs_var)
        self.history = int(history)
        self.diffusion = float(diffusion)
        self.rng = np.random.default_rng(seed)
        self.dt = float(dt)  # [s] frame period assumed by velocity_cov
        self.particles = np.zeros((0, self.n, 3))
        self.vel_hist = np.zeros((0, self.history, 3))
        self.vel_count = np.zeros(0, dtype=int)
        self.estimate = np.zeros((0, 3))
        self.velocity = np.zeros((0, 3))
        self.last_pos = np.zeros((0, 3))  # estimate at the last update
        self.elapsed = np.zeros(0)  # [s] since the last update
        self.reseeds = 0  # how many times particles were re-seeded (all weights vanished)
        self._cov: np.ndarray | None = None  # position_cov of the current particles (cache)

    def __len__(self) -> int:
        return len(self.particles)

    def add(self, z: np.ndarray, R: np.ndarray) -> None:
        m = len(z)
        p = z[:, None, :] + _uniform_ball(self.rng, (m, self.n), self.init_radius)
        self.particles = np.concatenate([self.particles, p])
        self.vel_hist = np.concatenate([self.vel_hist, np.zeros((m, self.history, 3))])
        self.vel_count = np.concatenate([self.vel_count, np.zeros(m, dtype=int)])
        self.estimate = np.concatenate([self.estimate, p.mean(axis=1)])
        self.velocity = np.concatenate([self.velocity, np.zeros((m, 3))])
        self.last_pos = np.concatenate([self.last_pos, p.mean(axis=1)])
        self.elapsed = np.concatenate([self.elapsed, np.zeros(m)])
        if self._cov is not None:
            self._cov = np.concatenate([self._cov, _spread(p, self.n)])

    def keep(self, mask: np.ndarray) -> None:
        self.particles = self.particles[mask]
        self.vel_hist = self.vel_hist[mask]
        self.vel_count = self.vel_count[mask]
        self.estimate = self.estimate[mask]
        self.velocity = self.velocity[mask]
        self.last_pos = self.last_pos[mask]
        self.elapsed = self.elapsed[mask]
        if self._cov is not None:
            self._cov = self._cov[mask]

    def _mean_velocity(self) -> np.ndarray:
        count = np.minimum(self.vel_count, self.history)
        total = self.vel_hist.sum(axis=1)
        return total / np.maximum(count, 1)[:, None]

    def predict(self, dt: float) -> None:
        if not len(self.particles):
            return
        v = self._mean_velocity()
        noise = self.rng.normal(scale=self.diffusion, size=self.particles.shape)
        self.particles = self.particles + (v * dt)[:, None, :] + noise
        self.estimate = self.estimate + v * dt
        self.velocity = v
        self.elapsed = self.elapsed + dt
        self._cov = None  # every particle moved

    def update(self, rows: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        if not len(rows):
            return
        p = self.particles[rows]  # (M, Np, 3)
        d2 = ((p - z[:, None, :]) ** 2).sum(axis=-1)
        w = np.exp(-0.5 * d2 / self.obs_var)
        total = w.sum(axis=1)
        dead = total <= 1e-300
        m, n = w.shape
        w[dead] = 1.0
        w /= w.sum(axis=1, keepdims=True)
        # systematic resampling, all tracks at once
        cdf = np.cumsum(w, axis=1)
        cdf[:, -1] = 1.0
        u = (self.rng.random((m, 1)) + np.arange(n)[None, :]) / n
        idx = np.empty((m, n), dtype=int)
        for i in range(m):  # searchsorted has no batched form; M is small
            idx[i] = np.searchsorted(cdf[i], u[i])
        p = np.take_along_axis(p, idx[:, :, None], axis=1)
        if dead.any():
            self.reseeds += int(dead.sum())
            p[dead] = z[dead][:, None, :] + _uniform_ball(
                self.rng, (int(dead.sum()), n), self.init_radius
            )
        new_est = p.mean(axis=1)
        vel = (new_est - self.last_pos[rows]) / np.maximum(self.elapsed[rows], 1e-6)[:, None]
        hist = np.roll(self.vel_hist[rows], 1, axis=1)
        hist[:, 0] = vel
        self.vel_hist[rows] = hist
        self.vel_count[rows] += 1
        self.particles[rows] = p
        self.estimate[rows] = new_est
        self.last_pos[rows] = new_est
        self.elapsed[rows] = 0.0
        self.velocity[rows] = self._mean_velocity()[rows]
        if self._cov is not None:
            self._cov[rows] = _spread(p, self.n)

    @property
    def position(self) -> np.ndarray:
        return self.estimate

    @property
    def position_cov(self) -> np.ndarray:
        """Sample covariances of the particles (N, 3, 3); computed once after each prediction,
        then kept up to date row-wise by update/add/keep."""
        if self._cov is None:
            self._cov = _spread(self.particles, self.n)
        return self._cov

    @property
    def velocity_cov(self) -> np.ndarray:
        # finite difference of two estimates one frame period apart
        return self.position_cov * (2.0 / self.dt**2)
