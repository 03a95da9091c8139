"""Track lifecycle: confirmation, coasting, deletion and what is reported (no motion, no costs).

A new track is tentative until matched ``min_hits`` times (a tentative track that misses a frame
is deleted); a confirmed track that misses frames coasts on the filter's prediction with its
confidence multiplied by ``decay_rate`` per missed frame, is reported while confidence >=
``restoration_conf_threshold``, and is deleted after ``max_staleness`` missed frames.
"""

from __future__ import annotations

import numpy as np

from .config import TrackerConfig
from .track_table import TrackTable

TENTATIVE, CONFIRMED, COASTING = 0, 1, 2  # = TrackedVehicle.STATE_*


class TrackLifecycle:
    """The lifecycle rules of :class:`TrackerConfig` applied to a :class:`TrackTable`."""

    def __init__(self, cfg: TrackerConfig):
        self.cfg = cfg

    def matched(self, table: TrackTable, rows: np.ndarray, score: np.ndarray) -> None:
        """Tracks ``rows`` were matched to detections with ``score``."""
        table.hits[rows] += 1
        table.misses[rows] = 0
        table.conf[rows] = 1.0
        table.score[rows] = score
        table.confirmed |= table.hits >= self.cfg.min_hits

    def missed(self, table: TrackTable, missed: np.ndarray) -> np.ndarray:
        """Tracks where ``missed`` (bool) were not matched; returns which of them end now."""
        table.misses[missed] += 1
        table.conf[missed] *= self.cfg.decay_rate
        return missed & (~table.confirmed | (table.misses > self.cfg.max_staleness))

    def born_confirmed(self, k: int) -> np.ndarray:
        """Whether ``k`` new tracks start confirmed (``min_hits`` <= 1)."""
        return np.full(k, self.cfg.min_hits <= 1)

    def states(self, table: TrackTable) -> np.ndarray:
        """TENTATIVE / CONFIRMED / COASTING per track (uint8)."""
        matched = table.misses == 0
        state = np.where(matched, CONFIRMED, COASTING)
        return np.where(~table.confirmed, TENTATIVE, state).astype(np.uint8)

    def reported(self, table: TrackTable, state: np.ndarray) -> np.ndarray:
        """Which tracks are reported this frame (bool)."""
        return (state != COASTING) | (table.conf >= self.cfg.restoration_conf_threshold)

    @staticmethod
    def row_score(table: TrackTable, idx: np.ndarray) -> np.ndarray:
        """Reported score: the last detection's score scaled by the track confidence (a
        negative score is divided by it, so it still falls while coasting)."""
        s, c = table.score[idx], table.conf[idx]
        return np.where(s >= 0, s * c, s / np.maximum(c, 1e-6))
