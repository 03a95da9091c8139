"""Stereo visual odometry: the left camera's motion between two frames. Pure core (OpenCV).

The steps, each a standard OpenCV building block:

1. Shi-Tomasi corners in the earlier left image, away from the vehicle boxes (vehicles may move;
   the motion wanted is the camera's against the static scene).
2. Pyramidal Lucas-Kanade tracking of the corners into the later left image, kept only when
   tracking back lands within ``max_fb_error`` px of the start (forward-backward check).
3. The corners lifted to 3D with the earlier frame's disparity map (the map the ranging uses;
   disparities below ``min_disparity`` are dropped: beyond ~70 m at KITTI's baseline a pixel
   of disparity error is metres of depth).
4. PnP with RANSAC (``cv2.solvePnPRansac``) of the 3D points against their tracked pixels, then
   an iterative refinement on the inliers.

The result is the rigid transform ``X_later = R X_earlier + t`` of a static point's coordinates
in the left optical frame (x right, y down, z forward); a car driving forward at 12 m/s for 0.1 s
gives ``t`` of about (0, 0, -1.2) m. None when too few points survive (textureless, dark or
blurred images, or a scene filled by moving vehicles): the caller then has no camera motion for
that frame.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import cv2
import numpy as np
from vehicle_common.camera_motion import CameraMotion

from .reprojection import StereoGeometry


@dataclass(frozen=True)
class OdometryParams:
    """Settings of :func:`estimate_camera_motion` (OpenCV's usual values for KITTI-sized images)."""

    scale: float = 0.5  # corners are found and tracked on images resized by this factor
    max_corners: int = 400  # Shi-Tomasi corners detected in the earlier image
    corner_quality: float = 0.01  # relative corner-strength threshold
    min_corner_distance: int = 5  # [px, resized]
    lk_window: int = 11  # [px, resized] Lucas-Kanade window side (15 before issue #33: the
    # same accuracy against ORB-SLAM3 on 0005, half the tracking's CPU; docs/stereo_depth.md)
    lk_levels: int = 3  # pyramid levels above the image
    max_fb_error: float = 0.5  # [px, resized] forward-backward tracking error
    min_disparity: float = 1.0  # [px] nearer than f * B / min_disparity only
    box_margin: float = 4.0  # [px] around vehicle boxes, no corners there
    ransac_error: float = 1.0  # [px] reprojection error of a PnP inlier
    ransac_iterations: int = 200
    min_inliers: int = 30  # fewer: no estimate


def _exclusion_rects(shape: tuple[int, int], boxes, margin: float):
    """The (c1, r1, c2, r2) pixel rectangles [end exclusive] of a full-resolution image where
    no corners are taken: the boxes with ``margin``, clipped (the empty ones left out)."""
    h, w = shape
    for x1, y1, x2, y2 in boxes:
        c1, r1 = max(0, int(x1 - margin)), max(0, int(y1 - margin))
        c2, r2 = min(w, int(np.ceil(x2 + margin))), min(h, int(np.ceil(y2 + margin)))
        if c2 > c1 and r2 > r1:
            yield c1, r1, c2, r2


def _box_key(boxes) -> tuple:
    """Boxes as a comparable value (which boxes a reference's corners keep away from)."""
    return tuple(tuple(b) for b in boxes)


def _scaled(gray: np.ndarray, p: OdometryParams, interpolation=cv2.INTER_AREA) -> np.ndarray:
    if p.scale == 1.0:
        return gray
    h, w = gray.shape
    size = (max(1, round(w * p.scale)), max(1, round(h * p.scale)))
    return cv2.resize(gray, size, interpolation=interpolation)


@dataclass(frozen=True)
class ReferenceCorners:
    """Step 1 of :func:`estimate_camera_motion` for an earlier frame, done ahead (it needs
    nothing of the later frame): its gray image at the tracking scale and its Shi-Tomasi
    corners (None: none found) away from ``exclude_boxes``."""

    gray: np.ndarray
    corners: np.ndarray | None
    exclude_boxes: tuple


def reference_corners(
    earlier_gray: np.ndarray,
    earlier_disparity: np.ndarray,
    exclude_boxes=(),
    params: OdometryParams | None = None,
    scaled: np.ndarray | None = None,
) -> ReferenceCorners:
    """The corners of the earlier frame that :func:`estimate_camera_motion` tracks;
    ``scaled``: its gray image at the tracking scale, when made already."""
    p = params or OdometryParams()
    small = _scaled(earlier_gray, p) if scaled is None else scaled
    corners = cv2.goodFeaturesToTrack(
        small,
        p.max_corners,
        p.corner_quality,
        p.min_corner_distance,
        mask=_scaled_corner_mask(earlier_disparity, exclude_boxes, p),
    )
    return ReferenceCorners(small, corners, _box_key(exclude_boxes))


@functools.lru_cache(maxsize=8)
def _nearest_pixels(height: int, width: int, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of a (height, width) image that its nearest-neighbour resize to the
    tracking scale (:func:`_scaled`) picks, asked of OpenCV itself (one resize of the row and
    of the column indices: its nearest mapping is separable and the same for every type)."""
    p = OdometryParams(scale=scale)
    rows = _scaled(np.arange(height, dtype=np.float32)[:, None], p, cv2.INTER_NEAREST)
    cols = _scaled(np.arange(width, dtype=np.float32)[None, :], p, cv2.INTER_NEAREST)
    rows, cols = rows[:, 0].astype(np.intp), cols[0].astype(np.intp)
    rows.setflags(write=False)
    cols.setflags(write=False)
    return rows, cols


def _scaled_corner_mask(disparity: np.ndarray, boxes, p: OdometryParams) -> np.ndarray:
    """The corner mask at the tracking scale: pixels with a disparity >= ``min_disparity``,
    away from ``boxes`` (``box_margin``). Built on the pixels the nearest-neighbour resize
    of the full-resolution mask picks (:func:`_nearest_pixels`), so bit-identical to that
    resize of the full-resolution mask (the way it was built before; tests/stereo_depth), for
    a quarter of the work."""
    h, w = disparity.shape
    rows, cols = _nearest_pixels(h, w, p.scale)
    d = disparity[rows[:, None], cols[None, :]]
    mask = np.where(np.isfinite(d) & (d >= p.min_disparity), np.uint8(255), np.uint8(0))
    for c1, r1, c2, r2 in _exclusion_rects((h, w), boxes, p.box_margin):
        i1, i2 = np.searchsorted(rows, (r1, r2))  # the picked pixels inside the rectangle
        j1, j2 = np.searchsorted(cols, (c1, c2))
        mask[i1:i2, j1:j2] = 0
    return mask


def estimate_camera_motion(
    earlier_gray: np.ndarray,
    earlier_disparity: np.ndarray,
    later_gray: np.ndarray,
    geometry: StereoGeometry,
    exclude_boxes=(),
    params: OdometryParams | None = None,
    disparity_bias=0.0,
    reference: ReferenceCorners | None = None,
    later_scaled: Callable[[np.ndarray], np.ndarray] | None = None,
) -> CameraMotion | None:
    """The camera's motion from the earlier frame (gray left image and its disparity map, same
    size) to the later one (gray left image); ``exclude_boxes``: (x1, y1, x2, y2) boxes of the
    earlier image where no corners are taken; ``disparity_bias``: the map's known bias [px]
    (a number, or one per image column), subtracted before the points are lifted to 3D (a
    biased far point scales the translation); ``reference``: the earlier frame's
    :func:`reference_corners` with the same boxes, when done ahead (else computed here);
    ``later_scaled(later_gray)``: the later image at the tracking scale (a caller that keeps
    it for the later frame's own corners). None when it cannot be estimated."""
    p = params or OdometryParams()
    if not 0.0 < p.scale <= 1.0:
        raise ValueError(f"scale: {p.scale} is not in (0, 1]")
    if earlier_gray.shape != later_gray.shape or earlier_disparity.shape != earlier_gray.shape:
        raise ValueError(
            f"image sizes differ: earlier {earlier_gray.shape}, later {later_gray.shape}, "
            f"disparity {earlier_disparity.shape}"
        )
    h, w = earlier_gray.shape
    if reference is None:
        reference = reference_corners(earlier_gray, earlier_disparity, exclude_boxes, p)
    earlier_gray, corners = reference.gray, reference.corners
    if corners is None or len(corners) < p.min_inliers:
        return None
    later_gray = (later_scaled or partial(_scaled, p=p))(later_gray)
    lk = {
        "winSize": (p.lk_window, p.lk_window),
        "maxLevel": p.lk_levels,
        "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
    }
    ahead, ok1, _ = cv2.calcOpticalFlowPyrLK(earlier_gray, later_gray, corners, None, **lk)
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(later_gray, earlier_gray, ahead, None, **lk)
    fb = np.linalg.norm((back - corners).reshape(-1, 2), axis=1)
    keep = (ok1.ravel() == 1) & (ok2.ravel() == 1) & (fb <= p.max_fb_error)
    uv1 = ahead.reshape(-1, 2) / p.scale  # full-resolution pixels from here on
    keep &= (uv1[:, 0] >= 0) & (uv1[:, 0] <= w - 1) & (uv1[:, 1] >= 0) & (uv1[:, 1] <= h - 1)
    if int(keep.sum()) < p.min_inliers:
        return None
    uv0 = np.clip(corners.reshape(-1, 2)[keep] / p.scale, 0, [w - 1, h - 1])
    uv1 = uv1[keep]
    col = uv0[:, 0].round().astype(int)
    d = earlier_disparity[uv0[:, 1].round().astype(int), col]
    bias = np.asarray(disparity_bias, float)
    d = d - (bias[col] if bias.ndim else float(bias))
    good = d >= p.min_disparity
    if int(good.sum()) < p.min_inliers:
        return None
    uv0, uv1, d = uv0[good], uv1[good], d[good]
    pts = geometry.backproject(uv0[:, 0], uv0[:, 1], geometry.depth(d))
    K = np.array(
        [[geometry.fx, 0.0, geometry.cx], [0.0, geometry.fy, geometry.cy], [0.0, 0.0, 1.0]]
    )
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        pts,
        uv1,
        K,
        None,
        iterationsCount=p.ransac_iterations,
        reprojectionError=p.ransac_error,
        confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or inl is None or len(inl) < p.min_inliers:
        return None
    inl = inl.ravel()
    ok, rvec, tvec = cv2.solvePnP(
        pts[inl], uv1[inl], K, None, rvec, tvec, True, flags=cv2.SOLVEPNP_ITERATIVE
    )
    if not ok or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        return None
    R, _ = cv2.Rodrigues(rvec)
    return CameraMotion(R, tvec.ravel().astype(float), inliers=int(len(inl)))


class FrameToFrameOdometry:
    """Visual odometry over a stream of stereo frames: each frame's camera motion since the
    previous one it was given (the stereo node's state, usable offline the same way).

    :meth:`step` keeps the frame as the next reference and returns the motion with its ``dt``,
    or None (first frame, a stamp not after the reference's, a size change, too few points);
    :meth:`reset` drops the reference (a lost frame: the next one has no earlier frame).
    ``step`` is :meth:`estimate` (needs only the new frame's gray image, so it can run while
    that frame's disparity map is computed) followed by :meth:`set_reference`; :meth:`begin`
    does both in the other order (the next frame may start before this one's motion is
    estimated). :meth:`prepare` finds the reference's corners ahead, in idle time."""

    def __init__(self, params: OdometryParams | None = None):
        self.params = params or OdometryParams()
        self._ref: tuple[int, np.ndarray, np.ndarray] | None = None
        self._prepared: tuple[tuple, ReferenceCorners] | None = None  # (reference, its corners)
        # (gray image, it at the tracking scale): the latest estimate's later image, which is
        # the next reference (made once for its tracking and its corners; the one thread that
        # runs the estimates and the corners ahead reads and writes it)
        self._scaled: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        self._ref = None

    @property
    def reference(self) -> tuple | None:
        """The current reference (stamp, gray image, disparity map), or None: compared by
        identity to know whether an estimate made ahead was made against it."""
        return self._ref

    def step(
        self,
        stamp_ns: int,
        gray: np.ndarray,
        disparity: np.ndarray,
        geometry: StereoGeometry,
        reference_boxes=(),
        disparity_bias=0.0,
    ) -> CameraMotion | None:
        """The motion from the previous frame to this one (``stamp_ns``, gray left image, its
        disparity map). ``reference_boxes``: vehicle boxes (x1, y1, x2, y2) in the previous
        frame, kept free of corners (the latest known ones do: vehicles move little from one
        frame to the next). ``disparity_bias`` as in :func:`estimate_camera_motion` (the same
        at every frame: the camera's)."""
        motion = self.estimate(stamp_ns, gray, geometry, reference_boxes, disparity_bias)
        self.set_reference(stamp_ns, gray, disparity)
        return motion

    def estimate(
        self,
        stamp_ns: int,
        gray: np.ndarray,
        geometry: StereoGeometry,
        reference_boxes=(),
        disparity_bias=0.0,
    ) -> CameraMotion | None:
        """The motion from the reference frame to this one, without changing the reference."""
        return self.estimate_from(
            self._ref, stamp_ns, gray, geometry, reference_boxes, disparity_bias
        )

    def begin(
        self, stamp_ns: int, gray: np.ndarray, disparity: np.ndarray
    ) -> Callable[..., CameraMotion | None]:
        """Make this frame the next reference at once and return the estimate of its motion
        from the previous reference, to run later (e.g. in another thread, while the caller
        goes on with the next frame): ``job(geometry, reference_boxes=(), disparity_bias=0.0)``
        gives what :meth:`step` would have given."""
        ref = self._ref
        self.set_reference(stamp_ns, gray, disparity)
        return partial(self.estimate_from, ref, stamp_ns, gray)

    def prepare(self, reference_boxes=()) -> Callable[[], None]:
        """Return a job that finds the current reference's corners away from
        ``reference_boxes`` ahead (:func:`reference_corners`), to run in idle time in the
        thread that runs the estimates; the next estimate against this reference with the same
        boxes uses them (with other boxes it finds its own: the motion is the same either
        way)."""
        return partial(self._prepare_from, self._ref, _box_key(reference_boxes))

    def _prepare_from(self, ref, boxes: tuple) -> None:
        if ref is not None:
            corners = reference_corners(ref[1], ref[2], boxes, self.params, self._scaled_of(ref[1]))
            self._prepared = (ref, corners)

    def _scaled_of(self, gray: np.ndarray) -> np.ndarray | None:
        """``gray`` at the tracking scale if the latest estimate made it (else None)."""
        kept = self._scaled
        return kept[1] if kept is not None and kept[0] is gray else None

    def _scale(self, gray: np.ndarray) -> np.ndarray:
        """``gray`` at the tracking scale, kept for its own corners as the next reference."""
        small = _scaled(gray, self.params)
        self._scaled = (gray, small)
        return small

    def estimate_from(
        self, ref, stamp_ns: int, gray, geometry, reference_boxes=(), disparity_bias=0.0
    ) -> CameraMotion | None:
        """The motion from ``ref`` (a :attr:`reference` taken earlier) to this frame, without
        changing the reference: e.g. a frame's estimate made before it is known to be used
        (the stereo node, while the detector runs on that frame)."""
        if ref is None or ref[0] >= stamp_ns or ref[1].shape != gray.shape:
            return None
        prepared = self._prepared
        corners = None
        if (
            prepared is not None
            and prepared[0] is ref
            and prepared[1].exclude_boxes == _box_key(reference_boxes)
        ):
            corners = prepared[1]
        else:  # not found ahead: found now, on the reference's scaled image if made already
            corners = reference_corners(
                ref[1], ref[2], reference_boxes, self.params, self._scaled_of(ref[1])
            )
        motion = estimate_camera_motion(
            ref[1],
            ref[2],
            gray,
            geometry,
            reference_boxes,
            self.params,
            disparity_bias,
            corners,
            self._scale,
        )
        return None if motion is None else replace(motion, dt=(stamp_ns - ref[0]) * 1e-9)

    def set_reference(self, stamp_ns: int, gray: np.ndarray, disparity: np.ndarray) -> None:
        """Keep this frame (gray left image and its disparity map) as the next reference."""
        self._ref = (int(stamp_ns), gray, disparity)
