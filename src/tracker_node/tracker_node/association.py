"""Data association: cost matrices (tracks x detections) with gating, and the two solvers.

Solvers: ``hungarian`` (globally optimal, ``scipy.optimize.linear_sum_assignment``) and
``nearest`` (the paper's greedy: repeatedly take the cheapest remaining track/detection pair);
:func:`solve_two_stage` runs one of them first on high-score detections, then on the rest.
Gated-out pairs (cost ``inf``) are never matched.
"""

from __future__ import annotations

import numpy as np
from vehicle_common.box2d import iou_2d

from .kalman import inv3_sym
from .overlap import giou_3d_matrix, shape_similarity


def euclidean_cost(track_pos: np.ndarray, det_pos: np.ndarray) -> np.ndarray:
    """Centre distances (N, M) in metres."""
    d = track_pos[:, None, :] - det_pos[None, :, :]
    return np.sqrt(np.einsum("nmi,nmi->nm", d, d))


def mahalanobis_cost_gated(
    track_pos: np.ndarray,
    track_cov: np.ndarray,
    det_pos: np.ndarray,
    det_cov: np.ndarray,
    candidates: np.ndarray,
    gate: float = np.inf,
) -> np.ndarray:
    """Squared Mahalanobis distances (N, M) of each detection from each track under the
    innovation covariance ``S_ij = P_i + R_j`` (``track_cov`` P (N, 3, 3): the tracks' predicted
    position covariances; ``det_cov`` R: (M, 3, 3) per detection, or (3, 3) shared by all).
    Computed only for ``candidates`` (bool (N, M)); other pairs and distances above ``gate`` are
    inf. A shared R takes N inversions instead of one per candidate pair."""
    out = np.full(candidates.shape, np.inf)
    r, c = np.nonzero(candidates)
    if len(r):
        d = det_pos[c] - track_pos[r]
        if det_cov.ndim == 2:
            Si = inv3_sym(track_cov + det_cov)[r]
        else:
            Si = inv3_sym(track_cov[r] + det_cov[c])
        q = (d * (Si @ d[..., None])[..., 0]).sum(axis=-1)
        out[r, c] = np.where(q <= gate, q, np.inf)
    return out


def iou_shape_cost(track_boxes: np.ndarray, det_boxes: np.ndarray) -> np.ndarray:
    """``1 - IoU * shape similarity`` of 2D boxes (N, 4) vs (M, 4); NaN boxes give cost 1."""
    aff = iou_2d(track_boxes, det_boxes) * shape_similarity(track_boxes, det_boxes)
    return 1.0 - np.nan_to_num(aff)


def giou_cost(track_boxes: np.ndarray, det_boxes: np.ndarray, candidates=None) -> np.ndarray:
    """``1 - GIoU`` (in [0, 2]) of 3D boxes (N, 7) vs (M, 7)."""
    return 1.0 - giou_3d_matrix(track_boxes, det_boxes, candidates)


def solve(cost: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Matched (track rows, detection columns) minimising ``cost`` (inf = forbidden)."""
    n, m = cost.shape
    if n == 0 or m == 0:
        return np.zeros(0, int), np.zeros(0, int)
    valid = np.isfinite(cost)
    if not valid.any():
        return np.zeros(0, int), np.zeros(0, int)
    if method == "hungarian":
        # imported here: scipy.optimize costs the tracker's start-up 0.5 s of CPU, and the
        # graph's default association is "nearest"
        from scipy.optimize import linear_sum_assignment

        big = (np.abs(cost[valid]).max() + 1.0) * max(n, m) + 1.0
        r, c = linear_sum_assignment(np.where(valid, cost, big))
        ok = valid[r, c]
        return r[ok], c[ok]
    if method == "nearest":
        rows, cols = np.nonzero(valid)
        order = np.argsort(cost[rows, cols], kind="stable")
        used_r = np.zeros(n, bool)
        used_c = np.zeros(m, bool)
        out_r, out_c = [], []
        for k in order:
            i, j = rows[k], cols[k]
            if not used_r[i] and not used_c[j]:
                used_r[i] = used_c[j] = True
                out_r.append(i)
                out_c.append(j)
        return np.array(out_r, int), np.array(out_c, int)
    raise ValueError(f"association: unknown method {method!r}")


def solve_two_stage(
    cost: np.ndarray, first: np.ndarray, method: str
) -> tuple[np.ndarray, np.ndarray]:
    """Two-stage association: the detections where ``first`` (bool (M,)) are matched first; the
    others only to the tracks the first stage left unmatched. Returns (rows, columns)."""
    if first.all() or not first.any():  # one stage: every detection is in the same one
        return solve(cost, method)
    rows, cols = solve(np.where(first, cost, np.inf), method)
    free = np.ones(len(cost), bool)
    free[rows] = False
    rows2, cols2 = solve(np.where(free[:, None] & ~first, cost, np.inf), method)
    return np.concatenate([rows, rows2]), np.concatenate([cols, cols2])
