"""The multi-vehicle tracker: filter + association + lifecycle + orientation, no ROS.

Positions are vehicle centres (centre of mass) in one camera frame (x right, y down, z forward;
the node uses the left optical frame). Each :meth:`Tracker.step` takes one frame's detections and
its stamp (seconds; dt comes from successive stamps) and, when known, the camera's motion since
the previous frame, and returns the reported tracks. With the camera's motion every track is
predicted in a world frame (:mod:`.ego_motion`: velocity over the ground, the camera's motion
compensated); without it ever, velocities are relative to the camera.

The parts, as in Autoware's multi_object_tracker: motion model (:mod:`.filters`), association
(:mod:`.association`), track lifecycle (:mod:`.lifecycle`) over the track table
(:mod:`.track_table`). Track ids start at 1 and are never reused within a Tracker's life.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from vehicle_common.box3d import projected_bbox
from vehicle_common.camera_frames import kitti_from_centre
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.orientation_bins import alpha_to_bin

from .association import (
    euclidean_cost,
    giou_cost,
    iou_shape_cost,
    mahalanobis_cost_gated,
    solve_two_stage,
)
from .config import TrackerConfig
from .ego_motion import extrapolate, static_velocity_before
from .filters import make_filter
from .kalman import robust_noise
from .lifecycle import COASTING, CONFIRMED, TENTATIVE, TrackLifecycle
from .orientation import (
    align_to,
    fuse_heading,
    motion_heading,
    resolve_heading,
    wrap,
    yaw_from_bin,
)
from .overlap import covered_by_tracks
from .stationary import StationaryModel
from .track_table import TrackTable

__all__ = ["COASTING", "CONFIRMED", "TENTATIVE", "DetectionBatch", "Tracker", "TrackSet"]
DEFAULT_YAW = -np.pi / 2.0  # a car aligned with the optical axis, heading away


def _nan(shape) -> np.ndarray:
    return np.full(shape, np.nan)


@dataclass
class DetectionBatch:
    """One frame's detections as arrays (M rows). Unknown values are NaN (or -1 for bins).

    position: (M, 3) vehicle centres [m]; covariance: (M, 3, 3) [m^2] (NaN -> the configured
    measurement noise); size: (M, 3) length, width, height [m]; yaw: (M,) rotation_y [rad];
    orientation_bin: (M,) 0..3 or -1; bbox: (M, 4) x1, y1, x2, y2 [px]; score: (M,);
    plausibility: (M,) the stereo plausibility of the box as a vehicle in [0, 1] (0: cannot be
    a vehicle), NaN when the input does not give it.
    """

    position: np.ndarray
    covariance: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    orientation_bin: np.ndarray
    bbox: np.ndarray
    score: np.ndarray
    class_id: list[str] = field(default_factory=list)
    plausibility: np.ndarray | None = None

    def __post_init__(self):
        if self.plausibility is None:
            self.plausibility = _nan(len(self.position))

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
        plausibility=None,
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
            plausibility=None if plausibility is None else np.asarray(plausibility, float),
        )

    @classmethod
    def empty(cls) -> DetectionBatch:
        return cls.create(np.zeros((0, 3)))


@dataclass
class TrackSet:
    """Tracks reported for one frame, as arrays (N rows), fields as in TrackedVehicle.msg.

    ``det_index``: column of the detection matched this frame, -1 when coasting.
    ``score``: last matched detection's score times the track confidence.
    ``velocity`` / ``velocity_cov``: relative to the camera (the apparent motion in the current
    frame); ``velocity_over_ground`` / ``velocity_over_ground_cov``: relative to the static
    world, expressed in the current camera axes; NaN while the camera's motion is unknown.
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
    velocity_over_ground: np.ndarray
    velocity_over_ground_cov: np.ndarray

    def __len__(self) -> int:
        return len(self.track_id)


class Tracker:
    """Multi-vehicle tracker configured by a :class:`TrackerConfig`.

    ``projection``: optional 3x4 camera matrix acting on the tracker's frame (the left optical
    frame: ``[K | 0]``), used to give coasting tracks the 2D box of their projected 3D box;
    ``image_size`` (width, height) clips it.

    State: ``tracks`` (:class:`.track_table.TrackTable`, one row per live track) and ``filter``
    (the motion filter, same rows). Each :meth:`step` runs predict -> cost -> assign -> update
    -> prune -> spawn -> report.
    """

    def __init__(
        self,
        config: TrackerConfig | None = None,
        projection: np.ndarray | None = None,
        image_size: tuple[int, int] | None = None,
    ):
        self.cfg = (config or TrackerConfig()).validate()
        self.filter = make_filter(self.cfg)
        self.lifecycle = TrackLifecycle(self.cfg)
        self.tracks = TrackTable()
        self.projection = None if projection is None else np.asarray(projection, float)
        self.image_size = image_size or (self.cfg.image_width, self.cfg.image_height)
        self.next_id = 1
        self.last_stamp: float | None = None
        self._R0 = np.eye(3) * self.cfg.measurement_noise**2
        # this frame's camera motion (given, or the last one extrapolated in the world frame)
        self._camera_motion: CameraMotion | None = None
        self._last_motion: CameraMotion | None = None  # the last one given
        # whether the filter's velocities are over the ground (a camera motion has arrived)
        self.world_frame = False
        # parked-car estimates beside the filter, world frame only (stationary.py)
        self.stationary = (
            StationaryModel(
                self.cfg.stationary_prior,
                self.cfg.stationary_switch,
                self.cfg.stationary_process_noise,
                self.cfg.stationary_min_updates,
                self.cfg.robust_update_k,
                self.cfg.stationary_report_rate,
            )
            if self.cfg.stationary_prior > 0
            else None
        )

    def __len__(self) -> int:
        return len(self.tracks)

    def reset(self) -> int:
        """End every track and forget the stream's time and motion (time went back: a
        restarted camera or bag); track ids go on from where they were, so that an id is never
        given twice. Returns how many tracks ended."""
        ended = len(self.tracks)
        self.filter.keep(np.zeros(ended, bool))
        self.tracks.keep(np.zeros(ended, bool))
        self.last_stamp = None
        self._camera_motion = self._last_motion = None
        self.world_frame = False
        return ended

    def set_projection(self, projection, image_size=None) -> None:
        """Set (or replace) the camera matrix used to project coasting tracks' boxes."""
        self.projection = np.asarray(projection, float).reshape(3, 4)
        if image_size is not None:
            self.image_size = tuple(int(v) for v in image_size)

    # ------------------------------------------------------------------ step

    def step(
        self,
        dets: DetectionBatch,
        stamp: float | None = None,
        camera_motion: CameraMotion | None = None,
    ) -> TrackSet:
        """Process one frame. ``stamp`` in seconds; None or non-increasing -> ``default_dt``.
        ``camera_motion``: the camera's motion since the previous frame when known (visual
        odometry). From the first one on, every track is predicted with it (:mod:`.ego_motion`:
        velocities over the ground; a frame without one takes the last one extrapolated), and
        new tracks start at the static scene's velocity while no track is established
        (:func:`.scene_motion.velocity_prior`). Never given: as before, velocities relative to
        the camera."""
        if camera_motion is not None and not camera_motion.dt > 0:
            camera_motion = None  # no time span: no velocity to derive
        R, shared_R = self._det_covariances(dets)
        det_yaw = self._det_yaw(dets)
        dt = self._dt(stamp)
        self._camera_motion = self._frame_motion(camera_motion, dt)
        self._predict(dt)
        cost = self._cost(dets, R, det_yaw, shared_R)
        rows, cols = self._assign(cost, self._may_start(dets))
        self._update(dets, rows, cols, R, det_yaw)
        self._prune(rows)
        self._spawn(dets, cols, R, det_yaw)
        if self.stationary is not None:
            self.stationary.settle()
        return self._report()

    def _dt(self, stamp: float | None) -> float:
        dt = self.cfg.default_dt
        if stamp is not None:
            if self.last_stamp is not None and stamp > self.last_stamp:
                dt = float(stamp - self.last_stamp)
            self.last_stamp = float(stamp)
        return dt

    def _frame_motion(self, given: CameraMotion | None, dt: float) -> CameraMotion | None:
        """This frame's camera motion: the one given; in the world frame without one, the last
        one extrapolated to ``dt`` (the camera keeps moving); else None. The first one given
        switches the tracker to the world frame (:meth:`_enter_world_frame`)."""
        if given is not None:
            if not self.world_frame:
                self._enter_world_frame(given)
            self._last_motion = given
            return given
        if self.world_frame:
            return extrapolate(self._last_motion, dt)
        return None

    def _enter_world_frame(self, motion: CameraMotion) -> None:
        """Velocities relative to the camera -> over the ground: minus the apparent velocity
        of a static point at each track's position; the process noise becomes
        ``world_process_noise`` (a car's own acceleration only). Tracks seen once (velocity
        still the birth prior) take the prior again, now that the static scene's velocity is
        known (zero over the ground)."""
        self.world_frame = True
        self.filter.set_process_noise(self.cfg.world_process_noise)
        if self.stationary is not None:
            self.stationary.start(self.filter.position, self.filter.position_cov)
        if not len(self.tracks):
            return
        self.filter.shift_velocity(static_velocity_before(motion, self.filter.position, motion.dt))
        rows = np.nonzero(self.tracks.hits == 1)[0]
        if len(rows):
            self.filter.restart_velocity(rows, np.zeros((len(rows), 3)))
            if self.cfg.world_entry_hypotheses and hasattr(self.filter, "start_hypotheses"):
                self.filter.start_hypotheses(rows, np.zeros((len(rows), 3)), self.tracks.yaw[rows])

    def _predict(self, dt: float) -> None:
        """Constant velocity over ``dt``, then (world frame) into this frame's camera axes."""
        if self.stationary is not None and self.cfg.stationary_mixing:
            self._mix_models()
        self.filter.predict(dt)
        motion = self._camera_motion
        if motion is not None:
            self.filter.move_frame(motion.rotation, motion.translation)
            if self.stationary is not None:
                self.stationary.predict(dt, motion.rotation, motion.translation)
        self.tracks.age += 1
        self.tracks.span += dt
        self.tracks.det_index[:] = -1

    def _mix_models(self) -> None:
        """The IMM's interaction step between the Kalman filter and the stationary model
        (:meth:`.stationary.StationaryModel.mix`), for tracks without a bank of birth
        hypotheses (their state is the bank's mixture, rebuilt every frame)."""
        flt = self.filter
        if getattr(flt, "name", "") != "kalman" or not len(flt):
            return
        free = np.ones(len(flt), bool)
        if flt.hypotheses is not None and len(flt.hypotheses):
            free[flt.hypotheses.owners()] = False
        self.stationary.mix(flt.x, flt.P, np.nonzero(free)[0])

    def _assign(self, cost: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Matched (track rows, detection columns): the ``high`` detections (score >=
        ``birth_score``) first, then the others to the tracks still unmatched."""
        return solve_two_stage(cost, high, self.cfg.association)

    def _update(self, dets: DetectionBatch, rows, cols, R: np.ndarray, det_yaw) -> None:
        """Matched tracks take their detections: filter, lifecycle, size, yaw, box, class."""
        cfg, t = self.cfg, self.tracks
        if self.stationary is not None:
            self.stationary.update(
                rows,
                dets.position[cols],
                R[cols],
                self.filter.position[rows],
                self.filter.position_cov[rows],
            )
        Rm = R[cols]
        if (
            cfg.robust_update_k > 0
            and cfg.robust_update_models == "both"
            and getattr(self.filter, "name", "") == "kalman"
        ):
            nu = dets.position[cols] - self.filter.position[rows]
            S = self.filter.position_cov[rows] + Rm
            Rm = robust_noise(nu, S, Rm, cfg.robust_update_k)
        self.filter.update(rows, dets.position[cols], Rm)
        self.lifecycle.matched(t, rows, dets.score[cols])
        t.det_index[rows] = cols
        dsize = dets.size[cols]
        has_size = np.isfinite(dsize).all(axis=1)
        r_s = rows[has_size]
        t.size[r_s] += cfg.size_gain * (dsize[has_size] - t.size[r_s])
        dyaw = det_yaw[cols]
        has_yaw = np.isfinite(dyaw)
        r_y = rows[has_yaw]
        obs = align_to(dyaw[has_yaw], t.yaw[r_y])
        t.yaw[r_y] = wrap(t.yaw[r_y] + cfg.yaw_gain * wrap(obs - t.yaw[r_y]))
        t.yaw_amb[rows] &= ~np.isfinite(dets.yaw[cols])  # a full detected yaw resolves it
        dbin = dets.orientation_bin[cols]
        t.bin[rows[dbin >= 0]] = dbin[dbin >= 0]
        box, now = dets.bbox[cols], self._pixels(self.filter.position[rows])
        if cfg.box_gain < 1:  # smoothed: gain x detection + (1 - gain) x the carried last box
            prev = self._shifted_boxes(t.bbox[rows], t.box_anchor[rows], now)
            both = np.isfinite(prev).all(axis=1) & np.isfinite(box).all(axis=1)
            box[both] += (1.0 - cfg.box_gain) * (prev[both] - box[both])
        t.bbox[rows] = box
        t.box_anchor[rows] = now
        if len(rows):
            t.cls[rows] = np.array(dets.class_id, dtype=object)[cols]

    def _prune(self, matched_rows: np.ndarray) -> None:
        """Unmatched tracks miss a frame; those the lifecycle ends are removed."""
        missed = np.ones(len(self.tracks), bool)
        missed[matched_rows] = False
        dead = self.lifecycle.missed(self.tracks, missed, self._out_of_view(missed))
        if dead.any():
            self.filter.keep(~dead)
            if self.stationary is not None:
                self.stationary.keep(~dead)
            self.tracks.keep(~dead)

    def _out_of_view(self, rows: np.ndarray) -> np.ndarray | None:
        """Tracks of ``rows`` (bool) whose projected box has less than ``coast_min_visible`` of
        its area inside the image (their car has left the view); None when off or unknown."""
        v = self.cfg.coast_min_visible
        if v <= 0 or self.projection is None or not rows.any():
            return None
        out = np.zeros(len(rows), bool)
        w, h = self.image_size
        for i in np.nonzero(rows)[0]:
            l_, w_, h_ = self.tracks.size[i]
            bottom = kitti_from_centre(self.filter.position[i], h_)
            full = projected_bbox(self.projection, (h_, w_, l_), bottom, float(self.tracks.yaw[i]))
            if full is None:
                out[i] = True
                continue
            x1, y1, x2, y2 = full
            area = (x2 - x1) * (y2 - y1)
            inside = max(0.0, min(x2, w - 1.0) - max(x1, 0.0)) * max(
                0.0, min(y2, h - 1.0) - max(y1, 0.0)
            )
            out[i] = area <= 0 or inside < v * area
        return out

    def _spawn(self, dets: DetectionBatch, matched_cols, R: np.ndarray, det_yaw) -> None:
        """New tracks from the detections no track took that may start one."""
        new = self._may_start(dets)
        new[matched_cols] = False
        if new.any() and len(self.tracks):  # no second track on a car a track holds (#41)
            new &= ~covered_by_tracks(dets.bbox, self._predicted_bboxes(), self.cfg.birth_max_iou)
        idx = np.nonzero(new)[0]
        k = len(idx)
        if not k:
            return
        # the static scene's velocity: zero over the ground (world frame), else unknown
        static_v = np.zeros((k, 3)) if self.world_frame else None
        yaw = det_yaw[idx]
        self.filter.add(dets.position[idx], R[idx], static_v, heading=yaw)
        if self.stationary is not None:
            self.stationary.add(dets.position[idx], R[idx])
        size = dets.size[idx]
        self.tracks.append(
            ids=np.arange(self.next_id, self.next_id + k),
            hits=np.ones(k),
            age=np.ones(k),
            span=np.zeros(k),
            misses=np.zeros(k),
            conf=np.ones(k),
            confirmed=self.lifecycle.born_confirmed(dets.score[idx]),
            size=np.where(np.isfinite(size), size, np.array(self.cfg.mean_size)),
            yaw=wrap(np.where(np.isfinite(yaw), yaw, DEFAULT_YAW)),
            yaw_amb=~np.isfinite(dets.yaw[idx]),
            bin=np.maximum(dets.orientation_bin[idx], 0),
            bbox=dets.bbox[idx],
            box_anchor=self._pixels(dets.position[idx]),
            score=dets.score[idx],
            score_sum=dets.score[idx],
            cls=[dets.class_id[i] for i in idx],
            det_index=idx,
        )
        self.next_id += k

    def _may_start(self, dets: DetectionBatch) -> np.ndarray:
        """Detections that may start a track and take part in the first association stage:
        score >= ``birth_score`` and, when the input gives it, plausibility >=
        ``birth_plausibility``. The others only keep existing tracks alive (second stage)."""
        implausible = dets.plausibility < self.cfg.birth_plausibility  # NaN: unknown, passes
        return (dets.score >= self.cfg.birth_score) & ~implausible

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
        n, m = len(self.tracks), len(dets)
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
                np.column_stack([tpos, self.tracks.size, self.tracks.yaw]),
                np.column_stack([dets.position, dsize, dyaw]),
                near,
            )
            near &= cost <= 1.0 - cfg.min_giou
        return np.where(near, cost, np.inf)

    def _predicted_bboxes(self) -> np.ndarray:
        t = self.tracks
        out = t.bbox.copy()
        if self.projection is None:
            return out
        for i in range(len(t)):
            b = self._project(self.filter.position[i], t.size[i], t.yaw[i])
            if b is not None:
                out[i] = b
        return out

    def _project(self, centre, size, yaw):
        l, w, h = size
        bottom = kitti_from_centre(centre, h)
        return projected_bbox(self.projection, (h, w, l), bottom, float(yaw), self.image_size)

    def _report(self) -> TrackSet:
        t = self.tracks
        amb = t.yaw_amb
        # bin or default yaws: the velocity (over the ground in the world frame: a parked car's
        # is ~0 and leaves its bin yaw alone) resolves the 180-degree ambiguity
        if amb.any():
            t.yaw[amb] = resolve_heading(
                t.yaw[amb], self.filter.velocity[amb], self.cfg.min_heading_speed
            )
        state = self.lifecycle.states(t)
        idx = np.nonzero(self.lifecycle.reported(t, state))[0]
        position = self.filter.position[idx].copy()
        velocity = self.filter.velocity[idx].copy()
        velocity_cov = self.filter.velocity_cov[idx]
        if self.stationary is not None and self.world_frame:
            position = self.stationary.blend(idx, position)
        bbox = self._report_boxes(idx, position)
        shown = ~self._coasting_on_matched(state[idx], position)
        if not shown.all():
            idx, position, velocity = idx[shown], position[shown], velocity[shown]
            velocity_cov, bbox = velocity_cov[shown], bbox[shown]
        yaw, bins = self._reported_yaw(idx, position, velocity, velocity_cov)
        if self.world_frame:  # the filter's velocity is over the ground
            ground, ground_cov = velocity, velocity_cov
            velocity = ground + self._camera_motion.static_point_velocity(position)
        else:
            ground, ground_cov = _nan(velocity.shape), _nan(velocity_cov.shape)
        return TrackSet(
            track_id=t.ids[idx],
            state=state[idx],
            confidence=t.conf[idx],
            position=position,
            position_cov=self.filter.position_cov[idx],
            velocity=velocity,
            velocity_cov=velocity_cov,
            size=t.size[idx].copy(),
            yaw=yaw,
            orientation_bin=bins,
            bbox=bbox,
            age=t.age[idx].copy(),
            frames_since_update=t.misses[idx].copy(),
            score=self.lifecycle.row_score(t, idx),
            class_id=[str(c) for c in t.cls[idx]],
            det_index=t.det_index[idx].copy(),
            velocity_over_ground=ground,
            velocity_over_ground_cov=ground_cov,
        )

    def _coasting_on_matched(self, state: np.ndarray, position: np.ndarray) -> np.ndarray:
        """Which of the reported rows (``state``, ``position``) are coasting tracks whose
        centre is nearer than ``coast_min_distance`` metres over the ground (x-z) to a track
        matched this frame: a second track on a car another track holds (issue #41), hidden
        this frame, not deleted (bool; none when the parameter is 0)."""
        hide = np.zeros(len(state), bool)
        coasting, matched = state == COASTING, state == CONFIRMED
        d = self.cfg.coast_min_distance
        if d <= 0 or not coasting.any() or not matched.any():
            return hide
        a, b = position[coasting][:, [0, 2]], position[matched][:, [0, 2]]
        gap = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
        hide[coasting] = (gap < d).any(axis=1)
        return hide

    def _reported_yaw(self, idx, position, velocity, velocity_cov):
        """(yaw, orientation bin) of the reported tracks ``idx``: the detector's (smoothed bin
        yaw, last bin); in the world frame, a bin-yaw track whose direction of travel over the
        ground is known within ``motion_heading_max_std`` takes the inverse-variance mean of
        both (:func:`.orientation.fuse_heading`), and the bin of the observation angle it
        implies (issue #34)."""
        t, cfg = self.tracks, self.cfg
        yaw, bins = t.yaw[idx].copy(), t.bin[idx].copy()
        if not (self.world_frame and cfg.motion_heading_max_std > 0 and len(idx)):
            return yaw, bins
        heading, std, speed = motion_heading(velocity, velocity_cov)
        use = (
            t.yaw_amb[idx]
            & (speed > cfg.min_heading_speed)
            & (std < np.radians(cfg.motion_heading_max_std))
        )
        if use.any():
            yaw[use] = fuse_heading(yaw[use], np.radians(cfg.bin_yaw_std), heading[use], std[use])
            alpha = yaw[use] - np.arctan2(position[use, 0], position[use, 2])
            bins[use] = alpha_to_bin(alpha)
        return yaw, bins

    def _pixels(self, points: np.ndarray) -> np.ndarray:
        """(N, 3): pixel (u, v) and depth of points (N, 3) with the camera matrix (NaN
        without one, or behind the camera)."""
        pts = np.asarray(points, float).reshape(-1, 3)
        if self.projection is None:
            return np.full((len(pts), 3), np.nan)
        h = np.hstack([pts, np.ones((len(pts), 1))]) @ self.projection.T
        z = h[:, 2:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.where(z > 0.1, h[:, :2] / z, np.nan)
        return np.hstack([uv, np.where(z > 0.1, z, np.nan)])

    def _shifted_boxes(self, last: np.ndarray, anchor: np.ndarray, now: np.ndarray) -> np.ndarray:
        """Boxes ``last`` (N, 4) [px] drawn when their track's centre was at pixel and depth
        ``anchor`` (N, 3), moved to the centre's pixel ``now`` (N, 3) and scaled by the depth
        ratio, clipped to the image; NaN where that is unknown or leaves no box."""
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (anchor[:, 2] / now[:, 2])[:, None]
        b = (last - anchor[:, [0, 1, 0, 1]]) * s + now[:, [0, 1, 0, 1]]
        w, h = self.image_size
        b = np.clip(b, 0.0, [w - 1.0, h - 1.0, w - 1.0, h - 1.0])
        bad = ~np.isfinite(b).all(axis=1) | (b[:, 2] <= b[:, 0]) | (b[:, 3] <= b[:, 1])
        b[bad] = np.nan
        return b

    def _report_boxes(self, idx: np.ndarray, position: np.ndarray) -> np.ndarray:
        """2D boxes of the reported tracks ``idx``: the matched detection's box when matched
        this frame (with ``box_gain`` < 1 the track's smoothed box, :meth:`_update`), else
        (coasting, or a detection without a box) the projection of the filtered 3D box, or
        with ``coast_box: shifted`` the last box moved with the predicted centre's pixel and
        scaled by the depth ratio (a box it cannot place: the projection); NaN (no box) when
        there is no camera matrix to project with, never a stale detection box."""
        t = self.tracks
        bbox = t.bbox[idx].copy()
        need = (t.misses[idx] > 0) | ~np.isfinite(bbox).all(axis=1)
        if self.cfg.matched_box == "projection":
            need[:] = True
        if self.projection is None:
            bbox[need] = np.nan
            return bbox
        shift = need & (t.misses[idx] > 0) & (self.cfg.coast_box == "shifted")
        now = self._pixels(position[shift])
        moved = self._shifted_boxes(bbox[shift], t.box_anchor[idx[shift]], now)
        bbox[need] = np.nan
        bbox[shift] = moved
        for j in np.nonzero(need & ~np.isfinite(bbox).all(axis=1))[0]:
            i = idx[j]
            b = self._project(position[j], t.size[i], t.yaw[i])
            if b is not None:
                bbox[j] = b
        return bbox
