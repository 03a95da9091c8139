"""The stereo node's frame path as a pure core (no rclpy): one frame set in, its ranged and
checked detections and camera motion out.

:class:`StereoPipeline` holds the frame path's state (the camera's geometry and derived
settings, the match band's settings, the visual odometry's reference, the road plane, the column
bias model) and runs one frame: its disparity map where the ranging reads it (``map_area``:
the boxes, or the whole band), meanwhile its visual odometry and the road plane's map in the
side executor, then the ranging, the plausibility check against the road plane, and the
plausibility action (reject or score); :meth:`StereoPipeline.begin` starts a frame's work
that needs no boxes before they arrive (:mod:`.early_start`). The ROS node (:mod:`.node`)
converts messages and calls it; the offline tool (:mod:`.offline`) and ``bench/bench_graph.py``
call the same class. The
side executor is any ``concurrent.futures`` executor (the node's: one helper thread); with
:class:`SerialExecutor` everything runs in the caller's thread, in order (the results are the
same).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from concurrent.futures import Executor, Future
from functools import partial

import cv2
import numpy as np
from vehicle_common.camera_motion import CameraMotion
from vehicle_common.camera_settings import (
    DERIVED_ROWS,
    KITTI_CAMERA_HEIGHT,
    CameraModel,
    StereoSettings,
    stereo_settings,
)
from vehicle_common.frame_messages import stamp_ns

from .disparity import (
    DisparityParams,
    block_matching_maps,
    coarse_disparity,
    compute_disparity,
    compute_disparity_in_boxes,
    match_band,
)
from .occluder import map_boxes
from .plausibility import (
    GroundEstimator,
    GroundHeightCheck,
    PlausibilityParams,
    check_boxes,
    published_score,
)
from .ranging import (
    RangingParams,
    RangingSetup,
    disparity_bias_at,
    observation_angles_of,
    precision_line,
    range_boxes,
)
from .region_matching import to_gray
from .reprojection import StereoGeometry
from .visual_odometry import FrameToFrameOdometry

#: log(level, line): level "debug" | "info" | "warning"
Log = Callable[[str, str], None]


def _no_log(level: str, line: str) -> None:
    pass


def _no_trace(point: str, stamp: int) -> None:
    pass


@dataclasses.dataclass(frozen=True)
class _Ready:
    """A result already computed, read like a Future's."""

    value: object

    def result(self):
        return self.value


class SerialExecutor(Executor):
    """Runs each submitted job at once in the caller's thread (offline tools, benches)."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as exc:  # read by result(), as a thread's would be
            future.set_exception(exc)
        return future


class NoGeometry(ValueError):
    """No usable stereo geometry (no CameraInfo yet, or a bad calibration)."""


@dataclasses.dataclass
class FrameBoxes:
    """A frame's 2D detections as the ranging reads them (one entry per detection)."""

    boxes: list  # (x1, y1, x2, y2) [px] in the left image
    bins: list  # orientation bin 0..3
    angles: list  # continuous observation angle [rad] (nan: not given)
    angle_variances: list  # its variance [rad^2] (< 0: not given)
    scores: list
    ids: list  # names in log lines

    def __len__(self) -> int:
        return len(self.boxes)

    @classmethod
    def from_detections(cls, dets) -> FrameBoxes:
        """The boxes of a detector's detections (``box``, ``orientation_bin``,
        ``observation_angle``, ``observation_angle_variance``, ``score``), named by index."""
        return cls(
            [d.box for d in dets],
            [d.orientation_bin for d in dets],
            [d.observation_angle for d in dets],
            [d.observation_angle_variance for d in dets],
            [d.score for d in dets],
            [str(i) for i in range(len(dets))],
        )


@dataclasses.dataclass
class FrameResult:
    """One processed frame: ``kept`` = (detection index, RangeResult, Plausibility, score or
    None: the 2D detection's) of the detections that go into its 3D array, in order."""

    disparity: np.ndarray  # the ranging's map (the whole band's when ``full_map``)
    full_map: bool
    params: DisparityParams
    geometry: StereoGeometry
    kept: list
    motion: CameraMotion | None


@dataclasses.dataclass
class EarlyFrame:
    """A frame's work that needs no 2D boxes, begun before they arrive
    (:meth:`StereoPipeline.begin`): its gray images; in the executor, the scene's
    block-matching map, the odometry's estimate against the reference of that time and the
    road plane's map. :meth:`StereoPipeline.process` takes it for the frame of its stamp when it was
    made with the frame's camera and settings; an estimate made against another reference or
    other reference boxes is made again there (the results are the same either way)."""

    stamp: int
    camera_generation: int
    geometry: StereoGeometry
    params: DisparityParams
    gray: np.ndarray
    gray_right: np.ndarray
    reference: tuple | None  # the odometry's reference the estimate is made against
    reference_boxes: list  # the vehicle boxes masked in that reference
    scene: Future  # -> (scene map, the road plane's map with "shared" or None)
    motion: Future | None  # -> the odometry's estimate (None: no odometry)
    road: Future  # -> the road plane's map ("own": its half-resolution map; "shared": scene's)


class StereoPipeline:
    """The frame path of the stereo node (see the module's docstring). ``ground_height``: the
    camera's height above the road as given (0: KITTI's 1.65 m assumed and checked against the
    fitted road plane); with ``num_disparities`` and ``match_rows`` (0 / [-1, -1]: derived from
    the camera, :mod:`vehicle_common.camera_settings`) the camera-dependent settings as given.
    ``executor`` runs the odometry, the road plane's map and the corners found ahead (the
    node: one helper thread); ``trace(point, stamp)`` marks the stages; ``log(level, line)``
    reports."""

    def __init__(
        self,
        disparity_params: DisparityParams,
        ranging_params: RangingParams,
        plausibility: PlausibilityParams,
        *,
        ground_height: float = 0.0,
        num_disparities: int = 0,
        match_rows: tuple = DERIVED_ROWS,
        map_area: str = "boxes",
        road_map: str = "own",
        visual_odometry: bool = True,
        executor: Executor | None = None,
        trace: Callable[[str, int], None] | None = None,
        log: Log | None = None,
    ) -> None:
        self.disparity_params = disparity_params
        height = ground_height or KITTI_CAMERA_HEIGHT
        ranging_params = dataclasses.replace(ranging_params, ground_height=height)
        # validated by the caller (a bad value is a ParameterError naming the parameter)
        self.ranging = RangingSetup.from_params(ranging_params)
        self.ranging_params = self.ranging.params
        self.plausibility = plausibility
        self.ground = GroundEstimator(plausibility, height)
        self.ground_check = GroundHeightCheck(
            height, ground_height <= 0, plausibility.ground_height_range
        )
        self.given = (num_disparities, tuple(match_rows), ground_height)
        self.map_area = map_area
        self.road_map = road_map
        self.odometry = FrameToFrameOdometry() if visual_odometry else None
        self.executor = executor or SerialExecutor()
        self.trace = trace or _no_trace
        self.log = log or _no_log
        self.implausible_detections = 0
        self.unranged_detections = 0
        self.frames_processed = 0
        self._band_params: tuple | None = None  # ((height, settings), params)
        self._vehicle_boxes: list = []  # of the previous processed frame (the odometry's mask)
        self._bias_key: tuple | None = None  # (width, geometry) of the cached column bias
        self._bias: np.ndarray | None = None
        self.geometry: StereoGeometry | None = None  # of the current camera
        #: the settings derived from it (vehicle_common.camera_settings)
        self.settings: StereoSettings | None = None
        self.geometry_error = "no CameraInfo received yet on both camera_info topics"
        self.calibration_key = None  # (left P, right P, sizes) the geometry was built from
        #: camera changes seen (set_camera) / handled by the frame path (odometry, road plane)
        self._camera_generation = 0
        self._worker_generation = 0

    @classmethod
    def from_config(cls, config, **kwargs) -> StereoPipeline:
        """The pipeline of the node's parameters (:class:`.parameters.StereoConfig`);
        ``kwargs``: executor, trace, log."""
        p = config.node
        return cls(
            config.disparity,
            config.ranging,
            config.plausibility,
            ground_height=p.ground_height,
            num_disparities=p.num_disparities,
            match_rows=tuple(p.match_rows),
            map_area=p.map_area,
            road_map=p.road_map,
            visual_odometry=p.visual_odometry,
            **kwargs,
        )

    # ------------------------------------------------------------------ the camera
    def update_camera(self, left_info, right_info, source: str) -> tuple | None:
        """Rebuild the stereo geometry and the settings derived from the camera when the
        calibration of the CameraInfo pair changes (a bad one is reported once per change; its
        frames then fail with NoGeometry). A change after the first is reported with what it
        changed; the odometry and the road plane then start afresh at the next frame. Returns
        None (nothing new) or (taken, level, line): the camera was taken (the rig's transforms
        may have changed), and the line to report; ``source`` names the CameraInfo topics."""
        if left_info is None or right_info is None:
            return None
        key = tuple((tuple(i.p), int(i.width), int(i.height)) for i in (left_info, right_info))
        if key == self.calibration_key:
            return None
        stamps = {stamp_ns(i.header) for i in (left_info, right_info)}
        if self.geometry is not None and len(stamps) == 2 and 0 not in stamps:
            return None  # one side of a new pair: judged when the other side's arrives
        first = self.calibration_key is None
        self.calibration_key = key
        previous = self.settings
        try:
            camera = CameraModel.from_camera_info(left_info, right_info)
            geometry = StereoGeometry.from_camera_infos(left_info, right_info)
            settings = stereo_settings(camera, *self.given)
        except ValueError as exc:
            self.geometry = None
            self.geometry_error = f"{source}: {exc}"
            return False, "warning", f"{self.geometry_error}; frames skipped until it changes"
        self.geometry, self.settings = geometry, settings
        line = self._camera_line()
        if first or previous is None:
            return True, "info", line
        self._camera_generation += 1
        return True, "warning", f"camera_info changed: {line}"

    def camera_from_projections(self, left: np.ndarray, p_left, p_right) -> str:
        """The camera of a rectified calibration (offline tools: a KITTI calibration's P2 and
        P3) for images like ``left``: its geometry and derived settings, as from the CameraInfo
        pair; returns the settings' line."""
        height, width = left.shape[:2]
        camera = CameraModel.from_projections(width, height, p_left, p_right)
        self.geometry = StereoGeometry.from_projections(p_left, p_right)
        self.settings = stereo_settings(camera, *self.given)
        return self._camera_line()

    def _camera_line(self) -> str:
        """The camera's log line: the derived settings and the depth std of the ranging."""
        return f"{self.settings.text}; {precision_line(self.geometry, self.ranging_params)}"

    def camera(self) -> tuple[StereoGeometry, StereoSettings]:
        """The camera a frame is processed with (raises :class:`NoGeometry`); after a camera
        change, the previous frame and road plane are dropped first."""
        geometry, settings = self.geometry, self.settings
        if geometry is None or settings is None:
            raise NoGeometry(self.geometry_error)
        if self._worker_generation != self._camera_generation:
            # another camera: the previous frame and road plane are not this camera's
            self._worker_generation = self._camera_generation
            self.ground.reset()
            if self.odometry is not None:
                self.odometry.reset()
        return geometry, settings

    def frame_lost(self) -> None:
        """A frame that could not be used: it breaks the odometry's chain."""
        if self.odometry is not None:
            self.odometry.reset()

    def disparity_params_for(self, height: int, settings: StereoSettings) -> DisparityParams:
        """The disparity settings of the camera (its disparity range) with the match band of
        images ``height`` rows tall. A band cut at the image's last row is warned about once; a
        band that leaves nothing to match raises RowBandError (``match_rows``)."""
        key = (height, settings)
        if self._band_params is None or self._band_params[0] != key:
            band, note = match_band(settings.match_rows, height, self.disparity_params)
            if note:
                self.log("warning", note)
            params = dataclasses.replace(
                self.disparity_params, num_disparities=settings.num_disparities, row_band=band
            )
            self._band_params = (key, params)
        return self._band_params[1]

    # ------------------------------------------------------------------ one frame
    def begin(self, stamp: int, left: np.ndarray, right: np.ndarray) -> EarlyFrame | None:
        """Begin a frame's work that needs no boxes (the node: while the detector runs on the
        same frame): its gray images here, then in the executor the scene's map and the
        odometry's estimate against the current reference (the frame is not made the
        reference: it may never be used), and the road plane's map. None when it cannot be
        begun ahead: ``map_area`` "band", no camera yet or a camera change not yet taken by a
        frame, or images of a size no frame has had yet (their match band is settled by the
        first)."""
        band = self._band_params
        geometry, settings = self.geometry, self.settings
        if (
            self.map_area == "band"
            or geometry is None
            or self._worker_generation != self._camera_generation
            or band is None
            or band[0] != (left.shape[0], settings)
        ):
            return None
        params = band[1]
        reference = self.odometry.reference if self.odometry is not None else None
        reference_boxes = list(self._vehicle_boxes)
        gray, gray_right = to_gray(left), to_gray(right)
        shared = self.road_map == "shared"
        scene = self.executor.submit(self._scene_map, stamp, gray, gray_right, params, shared)
        motion = None
        if self.odometry is not None:
            bias = self._column_bias(gray.shape[1], geometry)
            job = partial(self.odometry.estimate_from, reference, stamp, gray)
            motion = self.executor.submit(
                self._estimate_motion, stamp, job, geometry, reference_boxes, bias
            )
        if shared:
            road = self.executor.submit(lambda: scene.result()[1])
        else:
            road = self.executor.submit(self._road_map, stamp, left, right, params)
        return EarlyFrame(
            stamp, self._camera_generation, geometry, params, gray, gray_right, reference,
            reference_boxes, scene, motion, road,
        )  # fmt: skip

    def _scene_map(self, stamp, gray, gray_right, params, shared: bool) -> tuple:
        """The executor's scene map of a frame begun ahead (with ``shared``, also the road
        plane's), traced as scene_start / scene_end."""
        self.trace("scene_start", stamp)
        try:
            return block_matching_maps(gray, gray_right, params, road=shared)
        finally:
            self.trace("scene_end", stamp)

    def _usable(self, early: EarlyFrame | None, stamp: int, geometry, params) -> bool:
        """Whether ``early`` is this frame's work, made with its camera and settings."""
        return (
            early is not None
            and early.stamp == stamp
            and early.camera_generation == self._camera_generation
            and early.geometry is geometry
            and early.params is params
        )

    def _early_odometry(self, early: EarlyFrame, stamp: int, geometry) -> Future | None:
        """The frame's odometry from its early work (the frame made the reference now), or
        started now when the reference or its boxes changed since (the same motion as without
        early work)."""
        if self.odometry is None:
            return None
        scene = early.scene.result()[0]
        boxes = list(self._vehicle_boxes)
        if early.reference is not self.odometry.reference or early.reference_boxes != boxes:
            return self._start_odometry(stamp, early.gray, scene, geometry)
        self.odometry.set_reference(stamp, early.gray, scene)
        return early.motion

    def process(
        self,
        stamp: int,
        left: np.ndarray,
        right: np.ndarray,
        geometry: StereoGeometry,
        params: DisparityParams,
        dets: FrameBoxes,
        full_map: bool = False,
        disparity: np.ndarray | None = None,
        early: EarlyFrame | None = None,
    ) -> FrameResult:
        """One frame (RGB pair, its :meth:`camera` and :meth:`disparity_params_for`): its
        disparity map where the ranging reads it (``full_map``: the whole band's, whatever
        ``map_area``; ``disparity``: that map, computed already, e.g. beside the CNN), its
        odometry and road plane's map in the executor meanwhile (or taken from ``early``,
        :meth:`begin`'s work on this frame), the ranging and check, and the camera motion
        (waited for). Call :meth:`frame_done` once its output is out."""
        boxes = dets.boxes
        full_map = self.map_area == "band" or full_map or disparity is not None
        if not full_map and self._usable(early, stamp, geometry, params):
            # the scene's map, the odometry and the road plane's map begun ahead (waited for
            # by the check and at the end)
            self.trace("disparity_start", stamp)
            disparity = self._box_map(left, right, boxes, params)
            self.trace("disparity_end", stamp)
            road = early.road if boxes else None
            odometry = partial(self._early_odometry, early, stamp, geometry)
            return self._finish(stamp, dets, disparity, road, geometry, params, odometry,
                                (early.gray, early.gray_right), False)  # fmt: skip
        gray, gray_right = to_gray(left), to_gray(right)
        if full_map:
            # the band's map for the ranging, the road plane and the odometry
            self.trace("disparity_start", stamp)
            if disparity is None:
                disparity = compute_disparity(left, right, params)
            self.trace("disparity_end", stamp)
            odometry = self._start_odometry(stamp, gray, disparity, geometry)
            road = _Ready(disparity)
        else:
            # in the helper thread first, the road plane's own map (``road_map`` "own": the
            # map's algorithm at half its resolution, when there are boxes to check): it
            # needs only the pair, and the check waits for it; meanwhile here the odometry's
            # map of the scene (block matching over the band; with "shared" also the road
            # plane's, its speckle filter read in pixels), then the odometry in the helper
            # thread beside the map in the boxes and the ranging (its motion is waited for
            # only at the end)
            shared = self.road_map == "shared" and bool(boxes)
            road = None
            if boxes and not shared:
                road = self.executor.submit(self._road_map, stamp, left, right, params)
            self.trace("scene_start", stamp)
            scene, road_scene = block_matching_maps(gray, gray_right, params, road=shared)
            self.trace("scene_end", stamp)
            odometry = self._start_odometry(stamp, gray, scene, geometry)
            if shared:
                road = _Ready(road_scene)
            self.trace("disparity_start", stamp)
            disparity = self._box_map(left, right, boxes, params)
            self.trace("disparity_end", stamp)
        return self._finish(stamp, dets, disparity, road, geometry, params, lambda: odometry,
                            (gray, gray_right), full_map)  # fmt: skip

    def _box_map(self, left, right, boxes, params) -> np.ndarray:
        """The ranging's map in the boxes (with the occluder cut, also the strips beside the
        boxes it judges)."""
        r = self.ranging_params
        area = map_boxes(boxes, r.occluder_strip) if r.occluder_cut and boxes else boxes
        return compute_disparity_in_boxes(left, right, area, params)

    def _finish(
        self, stamp, dets, disparity, road, geometry, params, odometry, grays, full_map
    ) -> FrameResult:
        """The ranging and check of the frame's boxes, then its camera motion (``odometry()``:
        its future, waited for)."""
        self.trace("pair_end", stamp)
        self.frames_processed += 1
        images = grays if self.ranging_params.refine != "none" else None
        kept = self._range_and_check(stamp, dets, disparity, road, geometry, images)
        motion = self._camera_motion(odometry())
        # the next frame's odometry masks these boxes in this frame, its reference now (set
        # here, before the output: the next frame's early work may begin right after it)
        self._vehicle_boxes = list(dets.boxes)
        return FrameResult(disparity, full_map, params, geometry, kept, motion)

    def frame_done(self, boxes) -> None:
        """After a frame's output: the next odometry's corners on this frame, away from its
        ``boxes`` (the reference boxes, set when its motion was done), are found now, in idle
        time, in the executor."""
        if self.odometry is not None:
            self.executor.submit(self.odometry.prepare(boxes))

    def _road_map(self, stamp: int, left, right, params) -> np.ndarray:
        """The helper thread's map for the road plane (traced as road_start / road_end)."""
        self.trace("road_start", stamp)
        try:
            return coarse_disparity(left, right, params)
        finally:
            self.trace("road_end", stamp)

    def _range_and_check(self, stamp, dets: FrameBoxes, disparity, road, geometry, images):
        """Range and check the frame's boxes (``road.result()``: the map the road plane is
        fitted to, None without boxes); apply the plausibility action (reject or score)."""
        self.trace("ranging_start", stamp)
        boxes = dets.boxes
        results, checks = [None] * len(dets), [None] * len(dets)
        if len(dets):
            # the detector's continuous observation angle where it gives one (variance >= 0)
            alphas = observation_angles_of(dets.angles, dets.angle_variances)
            results = range_boxes(
                disparity, boxes, geometry, self.ranging, dets.bins, images, alphas
            )
            checks = self._check(disparity, road.result(), geometry, boxes, results)
        self.trace("ranging_end", stamp)
        action = self.plausibility.plausibility_action
        kept = []
        for i, (r, c) in enumerate(zip(results, checks, strict=True)):
            if r is None:
                self.unranged_detections += 1
                self.log(
                    "debug",
                    f"detection {dets.ids[i]!r}: no valid depth in its box "
                    f"({self.unranged_detections} unranged so far)",
                )
                continue
            published = published_score(c, dets.scores[i], self.plausibility)
            if published is None:  # reject: clearly no vehicle (plausibility < reject_below)
                self.implausible_detections += 1
                self.log(
                    "debug",
                    f"detection {dets.ids[i]!r}: not a vehicle's size or ground contact (height "
                    f"{c.measures.height:.2f} m, bottom {c.measures.bottom_height:+.2f} m); "
                    f"dropped ({self.implausible_detections} so far)",
                )
                continue
            # None: the detector's score; an unsure box (reject) is kept at score x plausibility
            if action == "score":
                score = dets.scores[i] * c.plausibility
            else:
                score = None if published == dets.scores[i] else published
            kept.append((i, r, c, score))
        return kept

    def _column_bias(self, width: int, geometry: StereoGeometry) -> np.ndarray:
        """The ranging's disparity bias model per image column [px] (read-only); it depends
        only on the calibration and the parameters, so it is computed once per geometry."""
        key = (width, geometry)
        if self._bias_key != key:
            bias = np.asarray(
                disparity_bias_at(np.arange(width), geometry, self.ranging_params), dtype=float
            )
            bias.setflags(write=False)
            self._bias_key, self._bias = key, bias
        return self._bias

    def _check(self, disparity, road, geo: StereoGeometry, boxes, results) -> list:
        """Plausibility of the ranged boxes (:mod:`.plausibility`, on the ranging's map)
        against this frame's road plane (fitted to the ``road`` map with the ranging's bias
        model subtracted)."""
        bias = self._column_bias(disparity.shape[1], geo)
        plane = self.ground.update(road, geo, bias)
        report = self.ground_check.add(plane)
        if report is not None:
            self.log(*report)
        fb = geo.fx * geo.baseline
        depths = [fb / r.disparity if r is not None else None for r in results]
        stds = [r.disparity_std if r is not None else None for r in results]
        return check_boxes(disparity, boxes, depths, geo, plane, self.plausibility, stds)

    def _start_odometry(self, stamp: int, gray: np.ndarray, scene: np.ndarray, geometry):
        """Start the visual odometry of a frame (the camera's motion since the previous
        processed frame: the span the tracker predicts over, however long) in its thread; the
        frame, with its scene map, becomes the next reference at once. None without odometry."""
        if self.odometry is None:
            return None
        job = self.odometry.begin(stamp, gray, scene)
        bias = self._column_bias(gray.shape[1], geometry)
        return self.executor.submit(
            self._estimate_motion, stamp, job, geometry, list(self._vehicle_boxes), bias
        )

    def _estimate_motion(self, stamp: int, job, *args) -> CameraMotion | None:
        """The helper thread's odometry (traced as odometry_start / odometry_end)."""
        self.trace("odometry_start", stamp)
        try:
            return job(*args)
        finally:
            self.trace("odometry_end", stamp)

    def _camera_motion(self, odometry) -> CameraMotion | None:
        """The frame's camera motion, once its odometry is done (None: no odometry, or it
        failed: reported)."""
        if odometry is None:
            return None
        try:
            return odometry.result()
        except (ValueError, cv2.error) as exc:
            self.log("warning", f"visual odometry failed: {exc}")
            return None
