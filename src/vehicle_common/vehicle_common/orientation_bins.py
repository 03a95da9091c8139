"""Orientation classes: the KITTI observation angle alpha folded modulo 180 degrees into 4 bins.

A car seen from the front and from the back look alike, so alpha is folded to [0, pi) and
quantised into bins centred on 0, 45, 90 and 135 degrees (bin 0 also takes [157.5, 180)).

Horizontal flip (x -> W - x) mirrors the scene: rotation_y -> pi - rotation_y and the viewing ray's
angle atan2(x, z) changes sign, so alpha = rotation_y - atan2(x, z) -> pi - alpha (wrapped).
Folded modulo pi this is -alpha, so the bin centred on c goes to the bin centred on 180 - c:
0 -> 0, 45 -> 135, 90 -> 90, 135 -> 45.
"""

from __future__ import annotations

import math

import numpy as np

NUM_BINS = 4
BIN_WIDTH = math.pi / NUM_BINS
#: Bin centres in degrees (index = orientation bin).
BIN_CENTRES_DEG = (0.0, 45.0, 90.0, 135.0)
#: Bin of the mirrored object for each bin (horizontal flip).
FLIP_BIN = np.array([0, 3, 2, 1], dtype=np.int64)


def fold_alpha(alpha: float | np.ndarray) -> float | np.ndarray:
    """Fold an observation angle [rad] modulo pi into [0, pi)."""
    return np.mod(alpha, math.pi)


def alpha_to_bin(alpha: float | np.ndarray) -> int | np.ndarray:
    """Orientation bin (0..3) of an observation angle alpha [rad]."""
    b = np.floor(fold_alpha(alpha) / BIN_WIDTH + 0.5).astype(np.int64) % NUM_BINS
    return int(b) if np.ndim(b) == 0 else b


def bin_to_alpha(bins: int | np.ndarray) -> float | np.ndarray:
    """Observation angle [rad] at the centre of orientation bins (0, 45, 90, 135 deg)."""
    a = np.asarray(bins, dtype=np.int64) % NUM_BINS * BIN_WIDTH
    return float(a) if np.ndim(a) == 0 else a


def flip_alpha(alpha: float | np.ndarray) -> float | np.ndarray:
    """Observation angle after a horizontal image flip: pi - alpha, wrapped to (-pi, pi]."""
    a = math.pi - np.asarray(alpha, dtype=float)
    a = np.where(a > math.pi, a - 2 * math.pi, a)
    a = np.where(a <= -math.pi, a + 2 * math.pi, a)
    return float(a) if np.ndim(a) == 0 else a


def flip_bin(bins: int | np.ndarray) -> int | np.ndarray:
    """Orientation bin after a horizontal image flip (45 <-> 135; 0, 90 and an unknown bin,
    below 0, unchanged)."""
    b = np.asarray(bins, dtype=np.int64)
    out = np.where(b >= 0, FLIP_BIN[np.maximum(b, 0)], b)
    return int(out) if np.ndim(out) == 0 else out


def fold_alpha_signed(alpha: float | np.ndarray) -> float | np.ndarray:
    """Fold an observation angle [rad] modulo pi into [-pi/2, pi/2): the convention of the
    continuous ``observation_angle`` of VehicleDetection2D (opposite directions share it, as
    they share a bin). NaN stays NaN."""
    a = np.mod(np.asarray(alpha, dtype=float) + math.pi / 2, math.pi) - math.pi / 2
    return float(a) if np.ndim(a) == 0 else a


def bin_residual_to_alpha(bins: int | np.ndarray, residual: float | np.ndarray):
    """MultiBin decoding: the folded angle (:func:`fold_alpha_signed`) of bin centre + residual
    [rad]; a residual past a neighbouring centre simply folds."""
    return fold_alpha_signed(bin_to_alpha(bins) + np.asarray(residual, dtype=float))


def alpha_to_bin_residual(alpha: float | np.ndarray):
    """(bin, residual) of an observation angle: the residual is the folded difference to the bin
    centre, in [-pi/8, pi/8]; inverse of :func:`bin_residual_to_alpha` up to the fold."""
    b = alpha_to_bin(alpha)
    return b, fold_alpha_signed(np.asarray(alpha, dtype=float) - bin_to_alpha(b))
