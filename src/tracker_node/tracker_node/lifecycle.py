"""Track lifecycle: confirmation, coasting, deletion and what is reported (no motion, no costs).

A new track is tentative until matched ``min_hits`` times, or in each of its frames, twice or
more, over at least ``min_hits_span`` seconds (fewer frames processed: a graph under overload),
or until its matched
detections' scores sum to >= ``confirm_score`` (a tentative track that misses a frame is
deleted); a
confirmed track that misses frames coasts on the filter's prediction with its confidence
multiplied by ``decay_rate`` per missed frame, is reported while confidence >=
``restoration_conf_threshold`` (and it has been matched >= ``coast_min_hits`` times, to
detections scoring ``coast_min_score`` on average), and is deleted after ``max_staleness``
missed frames. (Births below ``birth_score`` are refused by the
tracker's spawn step.)
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
        table.score_sum[rows] += score
        table.confirmed |= (
            (table.hits >= self.cfg.min_hits)
            | (table.score_sum >= self.cfg.confirm_score)
            | self._spanned(table)
        )

    #: relative tolerance of the span (stamps in seconds: 1.2 - 1.0 < 0.2)
    SPAN_TOLERANCE = 1e-6

    def _spanned(self, table: TrackTable) -> np.ndarray:
        """Matched in each of its frames, at least twice, over ``min_hits_span`` seconds (0:
        never): at 10 Hz the ``min_hits`` frames of KITTI span (min_hits - 1) x 0.1 s; a graph
        that processes every second frame (a camera faster than the graph) has seen as long a
        track after 2. A track that missed a frame is not confirmed by its span (at 10 Hz
        nothing changes: matched in each frame, 2 matches span 0.1 s)."""
        span = self.cfg.min_hits_span
        if span <= 0:
            return np.zeros(len(table), bool)
        every_frame = table.hits >= table.age
        long_enough = table.span >= span * (1.0 - self.SPAN_TOLERANCE)
        return (table.hits >= 2) & every_frame & long_enough

    def missed(
        self, table: TrackTable, missed: np.ndarray, out_of_view: np.ndarray | None = None
    ) -> np.ndarray:
        """Tracks where ``missed`` (bool) were not matched; returns which of them end now:
        tentative ones, those past ``max_staleness``, and those ``out_of_view`` (bool, when
        given: their car has left the image, issue #41)."""
        table.misses[missed] += 1
        table.conf[missed] *= self.cfg.decay_rate
        end = ~table.confirmed | (table.misses > self.cfg.max_staleness)
        if out_of_view is not None:
            end |= out_of_view
        return missed & end

    def born_confirmed(self, score: np.ndarray) -> np.ndarray:
        """Whether new tracks born from detections with ``score`` start confirmed
        (``min_hits`` <= 1, or a score >= ``confirm_score``)."""
        return (score >= self.cfg.confirm_score) | (self.cfg.min_hits <= 1)

    def states(self, table: TrackTable) -> np.ndarray:
        """TENTATIVE / CONFIRMED / COASTING per track (uint8)."""
        matched = table.misses == 0
        state = np.where(matched, CONFIRMED, COASTING)
        return np.where(~table.confirmed, TENTATIVE, state).astype(np.uint8)

    def reported(self, table: TrackTable, state: np.ndarray) -> np.ndarray:
        """Which tracks are reported this frame (bool)."""
        cfg = self.cfg
        coast_ok = (table.conf >= cfg.restoration_conf_threshold) & (
            table.hits >= cfg.coast_min_hits
        )
        if cfg.coast_min_score > 0:
            coast_ok &= table.score_sum >= cfg.coast_min_score * np.maximum(table.hits, 1)
        return (state != COASTING) | coast_ok

    def row_score(self, table: TrackTable, idx: np.ndarray) -> np.ndarray:
        """Reported score: the last detection's score scaled by the track confidence and by
        ``min(1, hits / ramp)`` (young tracks, most of them false, score lower); ``ramp`` is
        ``score_ramp_hits``, and for a tentative track at least ``min_hits`` (its progress
        toward confirmation: a tentative track ranks below a confirmed one with the same
        detection score, so a ranking metric such as AP can take tentative rows without
        letting them outrank confirmed ones). A negative score is divided by the factor
        instead, so it still falls."""
        cfg = self.cfg
        s = table.score[idx]
        ramp = np.where(
            table.confirmed[idx], cfg.score_ramp_hits, max(cfg.score_ramp_hits, cfg.min_hits)
        )
        c = table.conf[idx] * np.minimum(1.0, table.hits[idx] / ramp)
        return np.where(s >= 0, s * c, s / np.maximum(c, 1e-6))
