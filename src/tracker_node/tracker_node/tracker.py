"""The multi-vehicle tracker: filter + association + lifecycle + orientation, no ROS.

Positions are vehicle centres (centre of mass) in one camera frame (x right, y down, z forward;
the node uses the left optical frame). Each :meth:`Tracker.step` takes one frame's detections and
its stamp (seconds; dt comes from successive stamps) and returns the reported tracks.

Lifecycle: a new track is tentative until matched ``min_hits`` times (a tentative track that
misses a frame is deleted); a confirmed track that misses frames coasts on the filter's
prediction with its confidence multiplied by ``decay_rate`` per missed frame, is reported while
confidence >= ``restoration_conf_threshold``, and is deleted after ``max_staleness`` missed
frames. Track ids start at 1 and are never reused within a Tracker's life.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from vehicle_common.box3d import projected_bbox
from vehicle_common.camera_frames import kitti_from_centre

from .association import (
    euclidean_cost,
    giou_cost,
    iou_shape_cost,
    mahalanobis_cost_gated,
    solve,
)
from .config import TrackerConfig
from .filters import make_filter
from .orientation import align_to, resolve_heading, wrap, yaw_from_bin

TENTATIVE, CONFIRMED, COASTING = 0, 1, 2  # = TrackedVehicle.STATE_*
DEFAULT_YAW = -np.pi / 2.0  # a car aligned with the optical axis, heading away


def _nan(shape) -> np.ndarray:
    return np.full(shape, np.nan)


@dataclass
class DetectionBatch:
    """One frame's detections as arrays (M rows). Unknown values are NaN (or -1 for bins).

    position: (M, 3) vehicle centres [m]; covariance: (M, 3, 3) [m^2] (NaN -> the configured
    measurement noise); size: (M, 3) length, width, height [m]; yaw: (M,) rotation_y [rad];
    orientation_bin: (M,) 0..3 or -1; bbox: (M, 4) x1, y1, x2, y2 [px]; score: (M,).
    """

    position: np.ndarray
    covariance: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    orientation_bin: np.ndarray
    bbox: np.ndarray
    score: np.ndarray
    class_id: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.position)

    @classmethod
    def create(
        cls,
        position,
        covariance=None,
        size=None,
        yaw=None,
        orientation_bin=None,
        bbox=None,
        score=None,
        class_id=None,
    ) -> DetectionBatch:
        """Build a batch; omitted fields are unknown. Raises ValueError for a non-finite or
        mis-shaped position (the caller names the input)."""
        pos = np.asarray(position, dtype=float).reshape(-1, 3)
        m = len(pos)
        if not np.isfinite(pos).all():
            raise ValueError("non-finite detection position")
        cov = _nan((m, 3, 3)) if covariance is None else np.asarray(covariance, float)
        return cls(
            position=pos,
            covariance=cov.reshape(m, 3, 3),
            size=_nan((m, 3)) if size is None else np.asarray(size, float).reshape(m, 3),
            yaw=_nan(m) if yaw is None else np.asarray(yaw, float).reshape(m),
            orientation_bin=(
                np.full(m, -1) if orientation_bin is None else np.asarray(orientation_bin, int)
            ),
            bbox=_nan((m, 4)) if bbox is None else np.asarray(bbox, float).reshape(m, 4),
            score=np.ones(m) if score is None else np.asarray(score, float).reshape(m),
            class_id=["car"] * m if class_id is None else list(class_id),
        )

    @classmethod
    def empty(cls) -> DetectionBatch:
        return cls.create(np.zeros((0, 3)))


@dataclass
class TrackSet:
    """Tracks reported for one frame, as arrays (N rows), fields as in TrackedVehicle.msg.

    ``det_index``: column of the detection matched this frame, -1 when coasting.
    ``score``: last matched detection's score times the track confidence.
    """

    track_id: np.ndarray
    state: np.ndarray
    confidence: np.ndarray
    position: np.ndarray
    position_cov: np.ndarray
    velocity: np.ndarray
    velocity_cov: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    orientation_bin: np.ndarray
    bbox: np.ndarray
    age: np.ndarray
    frames_since_update: np.ndarray
    score: np.ndarray
    class_id: list[str]
    det_index: np.ndarray

    def __len__(self) -> int:
        return len(self.track_id)


_META = (
    "ids",
    "hits",
    "age",
    "misses",
    "conf",
    "confirmed",
    "size",
    "yaw",
    "yaw_amb",
    "bin",
    "bbox",
    "score",
    "cls",
    "det_index",
)


class Tracker:
    """Multi-vehicle tracker configured by a :class:`TrackerConfig`.

    ``projection``: optional 3x4 camera matrix acting on the tracker's frame (the left optical
    frame: ``[K | 0]``), used to give coasting tracks the 2D box of their projected 3D box;
    ``image_size`` (width, height) clips it.
    """

    def __init__(
        self,
        config: TrackerConfig | None = None,
        projection: np.ndarray | None = None,
        image_size: tuple[int, int] | None = None,
    ):
        self.cfg = (config or TrackerConfig()).validate()
        self.filter = make_filter(self.cfg)
        self.projection = None if projection is None else np.asarray(projection, float)
        self.image_size = image_size or (self.cfg.image_width, self.cfg.image_height)
        self.next_id = 1
        self.last_stamp: float | None = None
        self._R0 = np.eye(3) * self.cfg.measurement_noise**2
        self.ids = np.zeros(0, np.int64)
        self.hits = np.zeros(0, np.int64)
        self.age = np.zeros(0, np.int64)
        self.misses = np.zeros(0, np.int64)
        self.conf = np.zeros(0)
        self.confirmed = np.zeros(0, bool)
        self.size = np.zeros((0, 3))
        self.yaw = np.zeros(0)
        self.yaw_amb = np.zeros(0, bool)  # yaw known only up to 180 deg (bins or default)
        self.bin = np.zeros(0, np.int64)
        self.bbox = np.zeros((0, 4))
        self.score = np.zeros(0)
        self.cls = np.zeros(0, dtype=object)
        self.det_index = np.zeros(0, np.int64)

    def __len__(self) -> int:
        return len(self.ids)

    def set_projection(self, projection, image_size=None) -> None:
        """Set (or replace) the camera matrix used to project coasting tracks' boxes."""
        self.projection = np.asarray(projection, float).reshape(3, 4)
        if image_size is not None:
            self.image_size = tuple(int(v) for v in image_size)

    # ------------------------------------------------------------------ step

    def step(self, dets: DetectionBatch, stamp: float | None = None) -> TrackSet:
        """Process one frame. ``stamp`` in seconds; None or non-increasing -> ``default_dt``."""
        cfg = self.cfg
        dt = cfg.default_dt
        if stamp is not None:
            if self.last_stamp is not None and stamp > self.last_stamp:
                dt = float(stamp - self.last_stamp)
            self.last_stamp = float(stamp)

        R, shared_R = self._det_covariances(dets)
        det_yaw = self._det_yaw(dets)
        self.filter.predict(dt)
        self.age += 1
        self.det_index[:] = -1

        rows, cols = solve(self._cost(dets, R, det_yaw, shared_R), cfg.association)

        # matched tracks
        self.filter.update(rows, dets.position[cols], R[cols])
        self.hits[rows] += 1
        self.misses[rows] = 0
        self.conf[rows] = 1.0
        self.score[rows] = dets.score[cols]
        self.det_index[rows] = cols
        dsize = dets.size[cols]
        has_size = np.isfinite(dsize).all(axis=1)
        g = cfg.size_gain
        self.size[rows[has_size]] += g * (dsize[has_size] - self.size[rows[has_size]])
        dyaw = det_yaw[cols]
        has_yaw = np.isfinite(dyaw)
        r_y = rows[has_yaw]
        obs = align_to(dyaw[has_yaw], self.yaw[r_y])
        self.yaw[r_y] = wrap(self.yaw[r_y] + cfg.yaw_gain * wrap(obs - self.yaw[r_y]))
        self.yaw_amb[rows] &= ~np.isfinite(dets.yaw[cols])  # a full detected yaw resolves it
        dbin = dets.orientation_bin[cols]
        self.bin[rows[dbin >= 0]] = dbin[dbin >= 0]
        self.bbox[rows] = dets.bbox[cols]
        if len(rows):
            self.cls[rows] = np.array(dets.class_id, dtype=object)[cols]
        self.confirmed |= self.hits >= cfg.min_hits

        # unmatched tracks
        missed = np.ones(len(self.ids), bool)
        missed[rows] = False
        self.misses[missed] += 1
        self.conf[missed] *= cfg.decay_rate
        dead = missed & (~self.confirmed | (self.misses > cfg.max_staleness))
        if dead.any():
            self._keep(~dead)

        # new tracks from unmatched detections
        new = np.ones(len(dets), bool)
        new[cols] = False
        if new.any():
            self._add(dets, np.nonzero(new)[0], R, det_yaw)

        amb = self.yaw_amb
        if amb.any():
            self.yaw[amb] = resolve_heading(
                self.yaw[amb], self.filter.velocity[amb], cfg.min_heading_speed
            )
        return self._report()

    # ------------------------------------------------------------------ helpers

    def _det_covariances(self, dets: DetectionBatch) -> tuple[np.ndarray, bool]:
        """Per-detection covariances (M, 3, 3) and whether they all are the configured one."""
        if not len(dets) or np.isnan(dets.covariance[:, 0, 0]).all():
            return np.broadcast_to(self._R0, (len(dets), 3, 3)), True
        R = dets.covariance.copy()
        # a usable covariance is finite with a positive diagonal; fall back otherwise
        diag = R[:, [0, 1, 2], [0, 1, 2]]
        bad = ~np.isfinite(R).all(axis=(1, 2)) | ~(diag > 0).all(axis=1)
        R[bad] = self._R0
        return R, False

    def _det_yaw(self, dets: DetectionBatch) -> np.ndarray:
        yaw = dets.yaw.copy()
        if not (dets.orientation_bin >= 0).any():
            return yaw
        from_bin = ~np.isfinite(yaw) & (dets.orientation_bin >= 0)
        if from_bin.any():
            p = dets.position[from_bin]
            yaw[from_bin] = yaw_from_bin(dets.orientation_bin[from_bin], p[:, 0], p[:, 2])
        return yaw

    def _cost(
        self, dets: DetectionBatch, R: np.ndarray, det_yaw: np.ndarray, shared_R: bool = False
    ) -> np.ndarray:
        cfg = self.cfg
        n, m = len(self.ids), len(dets)
        if n == 0 or m == 0:
            return np.zeros((n, m))
        tpos = self.filter.position
        dist = euclidean_cost(tpos, dets.position)
        near = dist <= cfg.dist_cap
        if cfg.cost == "euclidean":
            cost = dist
        elif cfg.cost == "mahalanobis":
            det_cov = R[0] if shared_R else R  # one R for all: N inversions, not one per pair
            cost = mahalanobis_cost_gated(
                tpos, self.filter.position_cov, dets.position, det_cov, near, cfg.mahalanobis_gate
            )
            near &= np.isfinite(cost)
        elif cfg.cost == "iou2d":
            cost = iou_shape_cost(self._predicted_bboxes(), dets.bbox)
            near &= cost <= 1.0 - cfg.min_iou
        else:  # giou3d
            dsize = np.where(np.isfinite(dets.size), dets.size, np.array(cfg.mean_size))
            dyaw = np.where(np.isfinite(det_yaw), det_yaw, DEFAULT_YAW)
            cost = giou_cost(
                np.column_stack([tpos, self.size, self.yaw]),
                np.column_stack([dets.position, dsize, dyaw]),
                near,
            )
            near &= cost <= 1.0 - cfg.min_giou
        return np.where(near, cost, np.inf)

    def _predicted_bboxes(self) -> np.ndarray:
        if self.projection is None:
            return self.bbox.copy()
        out = self.bbox.copy()
        for i in range(len(self.ids)):
            b = self._project(self.filter.position[i], self.size[i], self.yaw[i])
            if b is not None:
                out[i] = b
        return out

    def _project(self, centre, size, yaw):
        l, w, h = size
        bottom = kitti_from_centre(centre, h)
        return projected_bbox(self.projection, (h, w, l), bottom, float(yaw), self.image_size)

    def _keep(self, mask: np.ndarray) -> None:
        self.filter.keep(mask)
        for name in _META:
            setattr(self, name, getattr(self, name)[mask])

    def _add(self, dets: DetectionBatch, idx: np.ndarray, R: np.ndarray, det_yaw) -> None:
        k = len(idx)
        pos = dets.position[idx]
        self.filter.add(pos, R[idx])
        size = dets.size[idx]
        size = np.where(np.isfinite(size), size, np.array(self.cfg.mean_size))
        yaw = det_yaw[idx]
        yaw = np.where(np.isfinite(yaw), yaw, DEFAULT_YAW)
        new = {
            "ids": np.arange(self.next_id, self.next_id + k, dtype=np.int64),
            "hits": np.ones(k, np.int64),
            "age": np.ones(k, np.int64),
            "misses": np.zeros(k, np.int64),
            "conf": np.ones(k),
            "confirmed": np.full(k, self.cfg.min_hits <= 1),
            "size": size,
            "yaw": wrap(yaw),
            "yaw_amb": ~np.isfinite(dets.yaw[idx]),
            "bin": np.maximum(dets.orientation_bin[idx], 0),
            "bbox": dets.bbox[idx],
            "score": dets.score[idx],
            "cls": np.array([dets.class_id[i] for i in idx], dtype=object),
            "det_index": idx.astype(np.int64),
        }
        self.next_id += k
        for name in _META:
            setattr(self, name, np.concatenate([getattr(self, name), new[name]]))

    def _report(self) -> TrackSet:
        cfg = self.cfg
        matched = self.misses == 0
        state = np.where(~self.confirmed, TENTATIVE, np.where(matched, CONFIRMED, COASTING)).astype(
            np.uint8
        )
        report = (state != COASTING) | (self.conf >= cfg.restoration_conf_threshold)
        idx = np.nonzero(report)[0]
        bbox = self.bbox[idx].copy()
        need = idx[(~matched[idx]) | ~np.isfinite(self.bbox[idx]).all(axis=1)]
        if self.projection is not None:
            for i in need:
                b = self._project(self.filter.position[i], self.size[i], self.yaw[i])
                if b is not None:
                    bbox[np.searchsorted(idx, i)] = b
        return TrackSet(
            track_id=self.ids[idx],
            state=state[idx],
            confidence=self.conf[idx],
            position=self.filter.position[idx].copy(),
            position_cov=self.filter.position_cov[idx],
            velocity=self.filter.velocity[idx].copy(),
            velocity_cov=self.filter.velocity_cov[idx],
            size=self.size[idx].copy(),
            yaw=self.yaw[idx].copy(),
            orientation_bin=self.bin[idx].copy(),
            bbox=bbox,
            age=self.age[idx].copy(),
            frames_since_update=self.misses[idx].copy(),
            score=np.where(
                self.score[idx] >= 0,
                self.score[idx] * self.conf[idx],
                self.score[idx] / np.maximum(self.conf[idx], 1e-6),
            ),
            class_id=[str(c) for c in self.cls[idx]],
            det_index=self.det_index[idx].copy(),
        )
