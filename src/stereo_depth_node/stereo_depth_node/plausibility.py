"""Stereo plausibility of 2D vehicle detections: metric size and contact with the road.

Pure core. A box that is a vehicle has a vehicle's physical size at its disparity and stands on
the road. Per frame, :class:`GroundEstimator` fits the road plane to the disparity map; per box,
:func:`check_boxes` turns the box's surface depth (the ranging's disparity) into

- ``height``, ``width`` [m]: the 2D box's height and width at that depth;
- ``bottom_height`` [m]: height of the box's bottom edge (box-centre column, bottom row, at the
  surface depth) above the road plane (+ floating, - sunk into the road);
- ``ground_fraction``: share of the box's pixels whose disparity puts them on the road plane
  (within ``ground_tolerance``): a box drawn on the empty road surface is mostly road;

and compares each with its interval (:class:`PlausibilityParams`), widened by ``noise_sigmas``
times the measure's own uncertainty at the box's depth (issue #34: a check in metres must
respect how the stereo depth noise and the road plane's extrapolation grow with range; the
stds per measure: :func:`measure_box`). Edges cut by the image border
switch off the checks they falsify (a box cut at the bottom has no visible bottom edge and may be
short; one cut at the side may be narrow). ``plausible`` = every active check passes;
``plausibility`` = exp(-0.5 sum (violation_i / softness_i)^2), 1 for a plausible box, falling
with the size of the violations (softness = the spread of the quantity on real cars, docs).

Road plane: the plane n.P = h (unit normal n pointing from the camera toward the road, h the
camera's height above it) through the road pixels of the disparity map. Candidates are a sparse
grid of pixels below the horizon row and nearer than ``ground_max_depth``, lifted to 3D; a small
RANSAC over 3-point planes, constrained to a tilt of at most ``ground_max_tilt`` from the prior
plane and a height within ``ground_height_range``, picks the plane with most points within
``ground_tolerance``; a least-squares refit on its inliers follows. A plane fitted per frame
absorbs the camera's pitch and roll and a constant road grade (the plane tilts with them); a
change of grade within the fitted range (a crest or dip) is averaged. When the road is not
visible (too few inliers, or no hypothesis within the limits), the previous frame's plane is kept
for ``ground_keep_frames`` frames, then the prior: level road at ``ground_height`` below the
camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .reprojection import StereoGeometry

PLAUSIBILITY_ACTIONS = ("flag", "score", "reject")
GROUND_SOURCES = ("fit", "previous", "prior")
SCORE_POINTS = 1500  # road candidates a RANSAC hypothesis is scored on


@dataclass(frozen=True)
class PlausibilityParams:
    """Settings of the road-plane fit and the per-box check (defaults chosen on the real tuning
    keyframes, docs/stereo_depth.md section 7)."""

    plausibility_action: str = "reject"  # reject (drop) | score (x plausibility) | flag (fields)
    # reject: drop only a box whose plausibility is below this (clearly no vehicle: far outside
    # the limits); a box between it and 1 is kept with score x plausibility (issue #41: a true
    # car the check is unsure of, e.g. road seen under a car from the side, an uphill grade
    # beyond the fitted road, costs more dropped than a false box kept at a lower score);
    # 1.0: drop every implausible box (before issue #41). Chosen on the tuning keyframes
    # (docs/stereo_depth.md section 11).
    reject_below: float = 0.01
    min_height: float = 1.1  # [m] shorter boxes: not a vehicle (unless cut at top/bottom)
    max_height: float = 4.0  # [m] (trucks, buses; physical limit, not tuned)
    min_width: float = 0.0  # [m] narrower boxes: not a vehicle (unless cut at the left/right)
    max_width: float = 12.0  # [m] (unless cut at the left/right border; a bus, not tuned)
    min_bottom_height: float = -0.6  # [m] bottom edge lower: sunk into the road
    max_bottom_height: float = 0.4  # [m] bottom edge higher: floating
    max_ground_fraction: float = 0.3  # more of the box's pixels on the road: flat on the road

    # scale of the plausibility score beyond the limits: the spread (1.4826 MAD) of the measure
    # on real cars (tuning); the road share's is degenerate (most cars 0): 0.1 by hand
    height_softness: float = 0.2  # [m] of the height
    bottom_softness: float = 0.2  # [m] of the bottom edge's height
    width_softness: float = 0.7  # [m] of the width
    ground_softness: float = 0.1  # of the road share
    # depth-scaled limits (issue #34): every interval is widened by noise_sigmas x the measure's
    # std at the box's depth: the stereo depth std (the ranging's disparity std) and the box's
    # edges (box_edge_std px each, in metres at the depth; 0: exact boxes) propagated to height,
    # width and bottom, and for the bottom the road plane's extrapolation, road_tilt_std [rad]
    # x depth (the growth of the labelled cars' bottom spread with range); chosen on the tuning
    # keyframes (docs section 9); noise_sigmas 0 = fixed limits (before issue #34)
    noise_sigmas: float = 1.0
    road_tilt_std: float = 0.003  # [rad] the road plane's extrapolation: bottom std per metre
    box_edge_std: float = 0.0  # [px] std of a box edge (0: exact boxes)
    ground_fit: bool = True  # fit the road plane per frame (false: the prior plane)
    ground_max_depth: float = 30.0  # [m] road pixels farther than this are not used
    ground_tolerance: float = 0.1  # [m] a pixel this near the plane is road (inlier)
    ground_max_tilt: float = 10.0  # [deg] largest angle between fitted and prior normal
    ground_height_range: tuple[float, float] = (1.0, 2.5)  # [m] accepted camera heights
    ground_min_inliers: int = 150  # fewer road points: the fit is not used
    ground_keep_frames: int = 10  # frames a previous fit stands in before the prior
    ground_iterations: int = 32  # RANSAC hypotheses
    ground_row_step: int = 4  # [px] grid of candidate road pixels
    ground_col_step: int = 12  # [px]

    def validate(self) -> None:
        """Raise ValueError for unusable settings."""
        if self.plausibility_action not in PLAUSIBILITY_ACTIONS:
            raise ValueError(
                f"plausibility_action: {self.plausibility_action!r} not one of "
                f"{PLAUSIBILITY_ACTIONS}"
            )
        for lo, hi in (
            ("min_height", "max_height"),
            ("min_bottom_height", "max_bottom_height"),
            ("min_width", "max_width"),
        ):
            if getattr(self, lo) > getattr(self, hi):
                raise ValueError(f"{lo}, {hi}: {lo} must be <= {hi}")
        h_lo, h_hi = (float(v) for v in self.ground_height_range)
        if not 0 < h_lo <= h_hi:
            raise ValueError("ground_height_range: needs 0 < low <= high")
        for name in (
            "height_softness",
            "bottom_softness",
            "width_softness",
            "ground_softness",
            "ground_tolerance",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: {getattr(self, name)} must be > 0")
        if not 0.0 <= self.reject_below <= 1.0:
            raise ValueError(f"reject_below: {self.reject_below} must be in [0, 1]")
        for name in ("noise_sigmas", "road_tilt_std", "box_edge_std"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name}: {getattr(self, name)} must be >= 0")
        for name in ("ground_iterations", "ground_row_step", "ground_col_step"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: {getattr(self, name)} must be >= 1")


@dataclass(frozen=True)
class GroundPlane:
    """Road plane n.P = offset in the left optical frame: ``normal`` (3,) unit, pointing from
    the camera toward the road (about +y); ``offset`` [m] the camera's height above it;
    ``source`` one of ``fit`` (this frame), ``previous`` (an earlier frame's fit), ``prior``
    (level road at the configured camera height); ``inliers`` road points of the fit."""

    normal: np.ndarray
    offset: float
    source: str = "prior"
    inliers: int = 0

    @classmethod
    def level(cls, camera_height: float, source: str = "prior") -> GroundPlane:
        """The level road ``camera_height`` metres below the camera."""
        return cls(np.array([0.0, 1.0, 0.0]), float(camera_height), source)

    def height_above(self, points) -> np.ndarray:
        """Height [m] of point(s) (..., 3) above the plane (+ on the camera's side)."""
        return self.offset - np.asarray(points, float) @ self.normal

    @property
    def pitch_deg(self) -> float:
        """Angle [deg] of the normal toward +z (+: the road rises along the optical axis in the
        camera frame: the camera pitched down, or an uphill grade ahead)."""
        return math.degrees(math.atan2(self.normal[2], self.normal[1]))

    @property
    def roll_deg(self) -> float:
        """Angle [deg] of the normal toward +x."""
        return math.degrees(math.atan2(self.normal[0], self.normal[1]))


def road_candidates(
    disparity: np.ndarray, geometry: StereoGeometry, params: PlausibilityParams, bias=0.0
) -> np.ndarray:
    """3D points (N, 3) of a sparse pixel grid below the horizon row (cy) with a valid
    disparity and a depth <= ``ground_max_depth``: where the road plane is looked for.
    ``bias`` [px]: the map's disparity bias, a scalar or one value per column (the ranging's
    ``disparity_bias_at``), subtracted as the ranging does."""
    h, w = disparity.shape
    r0 = int(math.ceil(geometry.cy)) + params.ground_row_step
    sub = disparity[r0 :: params.ground_row_step, :: params.ground_col_step]
    col_bias = np.broadcast_to(np.asarray(bias, float), (w,))[:: params.ground_col_step]
    valid = sub > 0
    sub = np.where(valid, sub - col_bias, 0.0)
    d_min = geometry.fx * geometry.baseline / params.ground_max_depth
    rows, cols = np.nonzero(valid & (sub >= d_min))
    d = sub[rows, cols].astype(float)
    z = geometry.fx * geometry.baseline / d
    u = cols * params.ground_col_step
    v = r0 + rows * params.ground_row_step
    return geometry.backproject(u, v, z)


def fit_ground_plane(
    points: np.ndarray,
    prior: GroundPlane,
    params: PlausibilityParams,
    rng: np.random.Generator | None = None,
) -> GroundPlane | None:
    """The road plane through ``points`` (RANSAC + least-squares refit, see module doc), or None
    when none within the tilt/height limits has ``ground_min_inliers`` inliers."""
    pts = np.asarray(points, float).reshape(-1, 3)
    if len(pts) < max(3, params.ground_min_inliers):
        return None
    rng = rng or np.random.default_rng(0)
    h_lo, h_hi = (float(v) for v in params.ground_height_range)
    cos_tilt = math.cos(math.radians(params.ground_max_tilt))
    k = params.ground_iterations
    idx = rng.integers(0, len(pts), size=(k, 3))
    p0, p1, p2 = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    n = np.cross(p1 - p0, p2 - p0)
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n = n[ok] / norm[ok, None]
    n *= np.sign(n @ prior.normal)[:, None]  # toward the road
    off = np.einsum("ij,ij->i", n, p0[ok])
    ok = (n @ prior.normal >= cos_tilt) & (off >= h_lo) & (off <= h_hi)
    if not ok.any():
        return None
    n, off = n[ok], off[ok]
    # hypotheses scored on at most SCORE_POINTS of the points (time), refit on all
    sub = pts[:: max(1, -(-len(pts) // SCORE_POINTS))]
    counts = (np.abs(off[:, None] - n @ sub.T) <= params.ground_tolerance).sum(axis=1)
    best = int(np.argmax(counts))
    inl = pts[np.abs(off[best] - pts @ n[best]) <= params.ground_tolerance]
    for _ in range(2):  # least squares on the inliers: P m = 1 with m = n / offset
        if len(inl) < params.ground_min_inliers:
            return None
        m, *_ = np.linalg.lstsq(inl, np.ones(len(inl)), rcond=None)
        offset = 1.0 / float(np.linalg.norm(m))
        normal = m * offset
        inl = pts[np.abs(offset - pts @ normal) <= params.ground_tolerance]
    if (
        len(inl) < params.ground_min_inliers
        or normal @ prior.normal < cos_tilt
        or not h_lo <= offset <= h_hi
    ):
        return None
    return GroundPlane(normal, offset, "fit", int(len(inl)))


class GroundEstimator:
    """The road plane of successive frames of one camera (see module doc): ``update`` fits it
    to a frame's disparity map, falling back to the previous frame's fit (for
    ``ground_keep_frames`` frames) and then to the level prior at ``camera_height``."""

    def __init__(self, params: PlausibilityParams | None = None, camera_height: float = 1.65):
        self.params = params or PlausibilityParams()
        self.params.validate()
        self.prior = GroundPlane.level(camera_height)
        self._last: GroundPlane | None = None
        self._age = 0
        self._rng = np.random.default_rng(0)

    def reset(self) -> None:
        """Forget the previous fit (e.g. after a jump in the stream)."""
        self._last, self._age = None, 0

    def update(self, disparity: np.ndarray, geometry: StereoGeometry, bias=0.0) -> GroundPlane:
        """The road plane of this frame's disparity map [px] (invalid <= 0; ``bias`` see
        :func:`road_candidates`)."""
        fit = None
        if self.params.ground_fit:
            ref = self._last or self.prior
            pts = road_candidates(np.asarray(disparity), geometry, self.params, bias)
            fit = fit_ground_plane(pts, ref, self.params, self._rng)
            if fit is not None and ref is not self.prior:
                # a drifting chain of fits must stay within the limits of the prior itself
                cos_tilt = math.cos(math.radians(self.params.ground_max_tilt))
                if fit.normal @ self.prior.normal < cos_tilt:
                    fit = None
        if fit is not None:
            self._last, self._age = fit, 0
            return fit
        if self._last is not None and self._age < self.params.ground_keep_frames:
            self._age += 1
            return GroundPlane(self._last.normal, self._last.offset, "previous", 0)
        self._last = None
        return self.prior


@dataclass(frozen=True)
class BoxMeasures:
    """What the check of one box looks at (see module doc)."""

    height: float  # [m] box height at the surface depth
    width: float  # [m]
    bottom_height: float  # [m] above the road plane (nan: bottom cut by the image border)
    ground_fraction: float  # share of the box's pixels on the road plane
    cut_side: bool  # left or right edge at the image border: width unknown
    cut_vertical: bool  # top or bottom edge at the image border: height only an upper bound
    # [m] std of height, width and bottom_height at this depth (stereo depth noise; the bottom
    # also the road plane's extrapolation); 0: exact (fixed limits)
    height_std: float = 0.0
    width_std: float = 0.0
    bottom_std: float = 0.0


@dataclass(frozen=True)
class Plausibility:
    """Outcome of the check of one box: its :class:`BoxMeasures`, the score in (0, 1] (1 =
    plausible) and the flag."""

    measures: BoxMeasures
    plausibility: float
    plausible: bool


def ground_fraction(
    disparity: np.ndarray,
    box,
    geometry: StereoGeometry,
    plane: GroundPlane,
    tolerance: float,
    samples: int = 16,
) -> float:
    """Share of the pixels of ``box`` (a grid of at most ``samples`` x ``samples``) with a valid
    disparity within ``tolerance`` [m] of the road plane. Pixels without a disparity count as
    not road: a car whose own pixels have no disparity (a LiDAR-made map's holes) is not made
    to look like road by the road pixels around it."""
    h, w = disparity.shape
    x1, y1, x2, y2 = (float(v) for v in box)
    us = np.clip(np.linspace(x1, x2, samples).round().astype(int), 0, w - 1)
    vs = np.clip(np.linspace(y1, y2, samples).round().astype(int), 0, h - 1)
    d = disparity[np.ix_(vs, us)].astype(float)
    # height above the plane of pixel (u, v) at disparity d, P = (u-cx, (v-cy) fx/fy, fx) B/d:
    # offset - n.P = offset - (B / d) (nx (u - cx) + ny (v - cy) fx / fy + nz fx)
    g, n = geometry, plane.normal
    lin = n[0] * (us - g.cx)[None, :] + (n[1] * (vs - g.cy) * g.fx / g.fy + n[2] * g.fx)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        heights = plane.offset - g.baseline * lin / d
    return float(np.count_nonzero((d > 0) & (np.abs(heights) <= tolerance)) / d.size)


def measure_box(
    box,
    depth: float,
    geometry: StereoGeometry,
    plane: GroundPlane,
    image_size: tuple[int, int],
    ground_share: float = 0.0,
    border: float = 2.0,
    disparity_std: float = 0.0,
    road_tilt_std: float = 0.0,
    box_edge_std: float = 0.0,
) -> BoxMeasures:
    """The measures of one box (x1, y1, x2, y2) [px] whose visible surface is ``depth`` [m]
    away; ``image_size`` (width, height); ``ground_share`` from :func:`ground_fraction`; an
    edge within ``border`` px of the image border counts as cut. The bottom edge is taken at
    the box-centre column, at the surface depth. Their stds: the depth std
    ``z^2 disparity_std / (f B)`` [m] moves height and width in proportion (dh / h = dz / z)
    and the bottom point along its ray ((y2 - cy) / fy per metre of depth); each box edge is
    ``box_edge_std`` px off (z / f metres per pixel); the road plane, fitted nearer, is
    extrapolated to the box: ``road_tilt_std`` x depth."""
    x1, y1, x2, y2 = (float(v) for v in box)
    width_px, height_px = image_size
    cut_bottom = y2 >= height_px - 1 - border
    bottom = float("nan")
    if not cut_bottom:
        bottom = float(plane.height_above(geometry.backproject(0.5 * (x1 + x2), y2, depth)))
    height = (y2 - y1) * depth / geometry.fy
    width = (x2 - x1) * depth / geometry.fx
    rel = depth * disparity_std / (geometry.fx * geometry.baseline)  # dz / z
    along = (y2 - geometry.cy) / geometry.fy * depth * rel  # the bottom point's y, per dz
    edge_v, edge_u = box_edge_std * depth / geometry.fy, box_edge_std * depth / geometry.fx
    return BoxMeasures(
        height,
        width,
        bottom,
        float(ground_share),
        x1 <= border or x2 >= width_px - 1 - border,
        y1 <= border or cut_bottom,
        math.hypot(height * rel, math.sqrt(2.0) * edge_v),
        math.hypot(width * rel, math.sqrt(2.0) * edge_u),
        math.sqrt(along**2 + (road_tilt_std * depth) ** 2 + edge_v**2),
    )


def _violation(value: float, lo: float, hi: float) -> float:
    if not np.isfinite(value):
        return 0.0
    return max(lo - value, 0.0) + max(value - hi, 0.0)


def judge(m: BoxMeasures, params: PlausibilityParams) -> Plausibility:
    """Compare the measures with their intervals, each widened by ``noise_sigmas`` x the
    measure's std at the box's depth: a cut edge switches off the lower height bound (vertical
    cut) or the width bounds (side cut); a cut bottom has no bottom height."""
    p = params
    k = p.noise_sigmas
    hs, ws, bs = k * m.height_std, k * m.width_std, k * m.bottom_std
    min_h = -np.inf if m.cut_vertical else p.min_height - hs
    lo_w, hi_w = (-np.inf, np.inf) if m.cut_side else (p.min_width - ws, p.max_width + ws)
    terms = (
        (_violation(m.height, min_h, p.max_height + hs), p.height_softness),
        (_violation(m.width, lo_w, hi_w), p.width_softness),
        (
            _violation(m.bottom_height, p.min_bottom_height - bs, p.max_bottom_height + bs),
            p.bottom_softness,
        ),
        (_violation(m.ground_fraction, -np.inf, p.max_ground_fraction), p.ground_softness),
    )
    score = math.exp(-0.5 * sum((v / s) ** 2 for v, s in terms))
    return Plausibility(m, score, all(v == 0.0 for v, _ in terms))


def check_boxes(
    disparity: np.ndarray,
    boxes,
    depths,
    geometry: StereoGeometry,
    plane: GroundPlane,
    params: PlausibilityParams | None = None,
    disparity_stds=None,
) -> list[Plausibility | None]:
    """:func:`measure_box` and :func:`judge` for each box with its surface depth [m] (None /
    nan / <= 0: not ranged, None returned) in a frame's disparity map [px] and road ``plane``;
    ``disparity_stds`` [px]: each box's disparity std as the ranging reports it
    (``RangeResult.disparity_std``; None: exact depths)."""
    params = params or PlausibilityParams()
    disparity = np.asarray(disparity)
    h, w = disparity.shape
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    stds = np.zeros(len(boxes)) if disparity_stds is None else disparity_stds
    out: list[Plausibility | None] = []
    for box, z, sd in zip(boxes, depths, stds, strict=True):
        if z is None or not np.isfinite(z) or z <= 0:
            out.append(None)
            continue
        share = ground_fraction(disparity, box, geometry, plane, params.ground_tolerance)
        m = measure_box(
            box,
            float(z),
            geometry,
            plane,
            (w, h),
            share,
            disparity_std=float(sd) if sd is not None and np.isfinite(sd) else 0.0,
            road_tilt_std=params.road_tilt_std,
            box_edge_std=params.box_edge_std,
        )
        out.append(judge(m, params))
    return out


def published_score(check: Plausibility, score: float, params: PlausibilityParams) -> float | None:
    """The score a ranged detection (detector ``score``) is published with after its
    ``check``, or None when it is dropped: ``flag`` keeps every box at its score; ``score``
    keeps every box at score x plausibility; ``reject`` drops a box whose plausibility is
    below ``reject_below`` and keeps the others, a plausible one at its score and one the
    check is unsure of (not plausible, plausibility >= reject_below) at score x plausibility."""
    action = params.plausibility_action
    if action == "flag" or check.plausible:
        return float(score)
    if action == "reject" and check.plausibility < params.reject_below:
        return None
    return float(score) * check.plausibility


class GroundHeightCheck:
    """Checks the camera height the ranging and the prior plane use (``ground_height``, given
    or assumed: it is not in CameraInfo) against the road planes :class:`GroundEstimator`
    fits: once ``fits`` frames had a fit, ONE report of their median height and pitch and
    whether the height agrees within ``tolerance`` [m]; if ``frames`` frames went by without
    any fit, ONE report that the road was not found within the accepted heights
    (``ground_height_range``). :meth:`add` returns (level "info" | "warning", line) once."""

    def __init__(
        self,
        height: float,
        assumed: bool,
        height_range: tuple[float, float],
        fits: int = 5,
        frames: int = 30,
        tolerance: float = 0.2,
    ) -> None:
        self.height, self.assumed = float(height), bool(assumed)
        self.height_range = tuple(float(v) for v in height_range)
        self.fits, self.frames, self.tolerance = int(fits), int(frames), float(tolerance)
        self._heights: list[float] = []
        self._pitches: list[float] = []
        self._seen = 0
        self.done = False

    def _setting(self) -> str:
        return f"ground_height {self.height:.2f} m ({'assumed' if self.assumed else 'parameter'})"

    def add(self, plane: GroundPlane) -> tuple[str, str] | None:
        if self.done:
            return None
        self._seen += 1
        if plane.source == "fit":
            self._heights.append(plane.offset)
            self._pitches.append(plane.pitch_deg)
        if len(self._heights) >= self.fits:
            self.done = True
            h, pitch = float(np.median(self._heights)), float(np.median(self._pitches))
            measured = (
                f"road plane: camera {h:.2f} m above the road, pitch {pitch:+.1f} deg (median "
                f"of {len(self._heights)} fitted frames)"
            )
            if abs(h - self.height) <= self.tolerance:
                return "info", f"{measured}; {self._setting()} agrees"
            return (
                "warning",
                f"{measured}; {self._setting()} differs by {abs(h - self.height):.2f} m: set "
                f"stereo_depth.ground_height:={h:.2f}",
            )
        if self._seen >= self.frames and not self._heights:
            self.done = True
            lo, hi = self.height_range
            return (
                "warning",
                f"road plane: none found in {self._seen} frames within ground_height_range "
                f"[{lo:g}, {hi:g}] m; {self._setting()} unchecked: if the camera is mounted "
                "lower or higher, set stereo_depth.ground_height and ground_height_range",
            )
        return None
