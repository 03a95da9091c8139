"""3D position of 2D vehicle boxes from a disparity map, with a stereo error covariance.

Pure core. Two estimators of the box's disparity:

- ``median``: the median disparity of all valid pixels in the box (the Stanford tracker's
  baseline). In an occluded box it returns the occluder's distance.
- ``robust``: pixels of the box's core (central ``core_fraction`` of width and height), without
  ground pixels (3D height below the camera more than ``ground_height - ground_margin``); their
  log-disparity histogram gives candidate surfaces (modes, at least ``min_mode_fraction`` of the
  core); each mode is scored by its support, times a prior on the depth from the box height (a
  car of ``prior_height`` metres), times a weight toward the far side
  ``(d_nearest_mode / d_mode)^far_weight``; the best mode's median disparity is taken. An
  occluder is nearer than the occluded car, so the car's own surface wins even when the occluder
  covers most of the core; the core restriction and the minimum support keep the background
  around the car from winning.

The visible surface of a car is nearer than its centre of mass. With ``centre_correction`` the
estimate is moved away from the camera along the viewing ray by the geometric depth of the centre
behind the visible surface of a ``car_length`` x ``car_width`` box seen at the observation angles
of the detection's orientation bin (:func:`centre_depth_behind_surface`, averaged over the bin);
``depth_offset`` (per bin, metres) is added on top.
Covariance: depth std ``z^2 * sigma_d / (f * B)`` (``sigma_d_far`` for far boxes refined at full
resolution, :func:`disparity_std`), x/y from the pixel uncertainty of the box
centre propagated with depth, plus the correlation that a depth error induces along the ray.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from vehicle_common.orientation_bins import BIN_WIDTH, NUM_BINS, alpha_to_bin

from .centre_fit import fit_cut_box, fit_lateral
from .occluder import extend_hidden_sides, full_extent_box, hidden_reach, occluder_sides
from .region_matching import (
    REFINE_METHODS,
    RegionParams,
    box_disparity,
    core_rect,
    refine_shift,
    region_disparity,
)
from .reprojection import StereoGeometry

METHODS = ("robust", "median")
TRUNCATION_BORDER = 2.0  # [px] a box edge this near the image border: cut by the border
SURFACE_MODELS = ("visible", "nearest", "blend")


def centre_depth_behind_surface(
    alpha, length: float, width: float, model: str = "visible", blend: float = 0.5
) -> np.ndarray:
    """Depth [m] of a box's centre behind its visible surface, along the viewing ray.

    The box (``length`` x ``width``, KITTI convention: at yaw 0 the length runs along +x) is seen
    at observation angle ``alpha`` [rad] (KITTI alpha = rotation_y - atan2(x, z)); the length
    axis makes |cos| = |sin alpha| with the ray, the width axis |cos alpha|. With half-extents
    a = length/2, b = width/2:

    - ``nearest``: the nearest point (a corner), a |sin alpha| + b |cos alpha|;
    - ``visible``: the mean depth of the visible faces weighted by their image width (what a
      disparity average over the box sees): the side face (image width 2a|cos alpha|, centre
      depth b|cos alpha|) and the front/back face (2b|sin alpha|, a|sin alpha|) give
      a b / (a |cos alpha| + b |sin alpha|);
    - ``blend``: visible + ``blend`` x (nearest - visible). On real cars (LiDAR surfaces of the
      tracking keyframes, docs section 8) the robust estimate sits a share of the way from the
      visible faces' mean toward the nearest corner: real cars are rounded, their corners are
      not where the box's are.
    """
    if model not in SURFACE_MODELS:
        raise ValueError(f"surface model {model!r} not one of {SURFACE_MODELS}")
    a, b = 0.5 * float(length), 0.5 * float(width)
    s, c = np.abs(np.sin(alpha)), np.abs(np.cos(alpha))
    nearest = a * s + b * c
    if model == "nearest":
        return nearest
    visible = a * b / (a * c + b * s)
    if model == "blend":
        return visible + blend * (nearest - visible)
    return visible


def bin_centre_offsets(
    length: float,
    width: float,
    model: str = "visible",
    spread: float = 0.0,
    samples: int = 46,
    blend: float = 0.5,
) -> np.ndarray:
    """Mean of :func:`centre_depth_behind_surface` over each orientation bin's alpha range
    (bin k: alpha uniform in k*45 +- spread*22.5 deg; spread 0 = the bin's centre angle), shape
    (5,); index 4 holds the mean of the 4 bins (used when a detection has no bin)."""
    t = spread * ((np.arange(samples) + 0.5) / samples - 0.5)  # uniform in +-spread/2
    out = [
        float(
            np.mean(centre_depth_behind_surface((k + t) * BIN_WIDTH, length, width, model, blend))
        )
        for k in range(NUM_BINS)
    ]
    return np.array(out + [float(np.mean(out))])


@dataclass(frozen=True)
class RangingParams:
    """Settings of :func:`range_boxes` (defaults chosen on KITTI tracking 0005, see docs)."""

    method: str = "robust"  # robust (mode of the box's disparities) | median (the paper's)
    sigma_d: float = 0.3  # [px] disparity std of the stereo error model (measured, see docs)
    # [px] the same for boxes refined at full resolution (``refine``) with a disparity below
    # ``far_disparity``: region spread 0.18 px on the KITTI 2015 pairs (60 regions < 20 px;
    # 0.58 px for the 26 at 20-40 px; docs/stereo_depth.md)
    sigma_d_far: float = 0.18
    far_disparity: float = 20.0  # [px]
    sigma_pixel: float = 3.0  # [px] std of the box centre in the image
    depth_offset_std: float = 0.5  # [m] std added to z for the visible-surface -> centre offset
    min_valid_pixels: int = 20  # fewer valid pixels -> no estimate
    min_valid_fraction: float = 0.02  # smaller share of valid pixels in the box -> no estimate
    core_fraction: float = 0.6  # robust: central share of box width and height used
    reject_ground: bool = True  # robust: road pixels (ground_margin) left out of the box
    ground_height: float = 1.65  # [m] camera height above the road
    ground_margin: float = 0.3  # [m] pixels lower than ground_height - margin are ground
    mode_bin: float = 0.04  # robust: histogram bin width in log-disparity
    min_mode_fraction: float = 0.1  # robust: a mode needs this share of the core pixels
    far_weight: float = 4.0  # robust: mode score x (d_nearest_mode / d_mode)^far_weight
    prior_height: float = 1.5  # [m] typical car height for the depth prior from box height
    prior_log_sigma: float = 0.5  # log-depth std of that prior (0 disables the prior)
    centre_correction: bool = True  # move the surface estimate to the car's centre (geometry)
    surface_model: str = "blend"  # centre_depth_behind_surface model: visible | nearest | blend
    truncated_surface_model: str = "visible"  # the same for boxes cut by the image border
    # blend: share of the way from the visible model to the nearest-corner one (real cars)
    surface_blend: float = 0.625
    # [m] depth of the real visible surface behind the model box's faces (rounded cars),
    # subtracted from the centre correction: the median over the real LiDAR surfaces of the
    # tuning keyframes (docs sections 8, 9; 0.2 before issue #34 left the centres 0.1-0.2 m
    # too far at 10-45 m)
    surface_inset: float = 0.32
    car_length: float = 3.9  # [m] mean car length of the centre correction
    car_width: float = 1.6  # [m] mean car width of the centre correction
    correction_bin_spread: float = 0.0  # share of the bin's +-22.5 deg averaged (0: centre)
    depth_offset: tuple[float, float, float, float] = field(
        default_factory=lambda: (0.0, 0.0, 0.0, 0.0)
    )  # [m] per orientation bin (0, 45, 90, 135 deg), added after the centre correction
    lateral_fit: bool = True  # centre_fit.fit_lateral: footprint of the car spans the 2D box
    # boxes cut by the image border: the surface of their visible part (a near one matched at
    # full resolution up to near_max_disparity) and, cut at one side, the centre of the car
    # footprint that keeps the box's inner edge and gives that surface (centre_fit.fit_cut_box);
    # docs section 9
    cut_box_fit: bool = True
    near_max_disparity: float = 160.0  # [px] largest disparity a near cut box is searched at
    # boxes with a side hidden by a NEARER object (an "occluder cut", issue #41; with
    # cut_box_fit and the robust method): a strip beside the box's left, right (or bottom) edge
    # whose valid, non-road pixels are mostly nearer than the car (occluder.occluder_sides);
    # such a side is treated like one cut by the image border (the centre from the visible
    # part, the other edge kept) and the published 2D box (RangeResult.box) is extended on it
    # to the full-extent projection of the fitted mean car (car_length x car_width x
    # prior_height, standing on the road), no farther than the nearer object reaches
    # (occluder.hidden_reach); a box that does not grow keeps its uncut ranging. OFF: it failed
    # its shipping rule on the tuning keyframes (docs section 12); the thresholds below are the
    # best of its grid there (LiDAR maps, the shipped CNN)
    occluder_cut: bool = False
    occluder_strip: float = 0.1  # strip width: this share of the box's width (height), >= 3 px
    occluder_margin: float = 3.0  # [m] a strip pixel this much nearer than the car: occluder
    occluder_share: float = 0.3  # share of the strip's valid non-road pixels that must be nearer
    occluder_bottom: bool = False  # also the bottom side (the road below is often taken for one)
    refine: str = "region_shift"  # none | region_sgbm | region_shift (region_matching.py)
    refine_max_disparity: float = 40.0  # [px] boxes with a larger coarse disparity: not refined
    disparity_bias: float = -0.28  # [px] bias of the estimate on KITTI 2015 (docs), subtracted
    disparity_bias_column: float = -1.80  # [px] its growth x ((u - cx) / fx)^2 to the borders

    def validate(self) -> None:
        """Raise ValueError for unusable settings."""
        if self.method not in METHODS:
            raise ValueError(f"ranging_method: {self.method!r} not one of {METHODS}")
        if not 0.0 < self.core_fraction <= 1.0:
            raise ValueError(f"core_fraction: {self.core_fraction} not in (0, 1]")
        if len(self.depth_offset) != 4:
            raise ValueError("depth_offset: needs 4 values (one per orientation bin)")
        for name in ("sigma_d", "sigma_d_far"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: {getattr(self, name)} must be > 0")
        for name in ("surface_model", "truncated_surface_model"):
            if getattr(self, name) not in SURFACE_MODELS:
                raise ValueError(f"{name}: {getattr(self, name)!r} not one of {SURFACE_MODELS}")
        if not np.isfinite(self.surface_inset):
            raise ValueError("surface_inset: must be finite")
        if self.car_length < 0 or self.car_width < 0:
            raise ValueError("car_length, car_width: must be >= 0")
        if not 0.0 <= self.surface_blend <= 1.0:
            raise ValueError(f"surface_blend: {self.surface_blend} not in [0, 1]")
        if not 0.0 <= self.correction_bin_spread <= 1.0:
            raise ValueError(f"correction_bin_spread: {self.correction_bin_spread} not in [0, 1]")
        if not self.near_max_disparity > 0:
            raise ValueError(f"near_max_disparity: {self.near_max_disparity} must be > 0")
        if self.refine not in REFINE_METHODS:
            raise ValueError(f"refine: {self.refine!r} not one of {REFINE_METHODS}")


@dataclass(frozen=True)
class RangeResult:
    """3D estimate of one box: position [m] (left optical frame), 3x3 covariance [m^2],
    the disparity [px] it came from, the share of box pixels with a valid disparity and the
    disparity's std [px] (the error model's)."""

    position: np.ndarray
    covariance: np.ndarray
    disparity: float
    valid_pixel_fraction: float
    disparity_std: float = 0.0  # [px] of ``disparity`` (disparity_std; the error model's)
    #: the 2D box (x1, y1, x2, y2) [px] to publish when it is not the detection's: a box with
    #: sides hidden by a nearer object, extended to the car's full extent (``occluder_cut``)
    box: tuple[float, float, float, float] | None = None


@dataclass(frozen=True, eq=False)
class RangingSetup:
    """Validated :class:`RangingParams` with their per-bin centre offsets [m] (shape (5,), see
    :func:`bin_centre_offsets`; zeros without ``centre_correction``) and those of boxes cut by
    the image border (``truncated_surface_model``): what depends only on the settings,
    computed once and reused for every frame."""

    params: RangingParams
    centre_offsets: np.ndarray
    truncated_offsets: np.ndarray

    @classmethod
    def from_params(cls, params: RangingParams | None = None) -> RangingSetup:
        """Validate ``params`` (default :class:`RangingParams`) and compute the offsets; raises
        ValueError for unusable settings."""
        params = params or RangingParams()
        params.validate()
        offsets = []
        for model in (params.surface_model, params.truncated_surface_model):
            centre = np.zeros(NUM_BINS + 1)
            if params.centre_correction:
                centre = (
                    bin_centre_offsets(
                        params.car_length,
                        params.car_width,
                        model,
                        params.correction_bin_spread,
                        blend=params.surface_blend,
                    )
                    - params.surface_inset
                )
            centre.setflags(write=False)
            offsets.append(centre)
        return cls(params, *offsets)


def _box_slice(box, width: int, height: int, fraction: float) -> tuple[slice, slice] | None:
    x1, y1, x2, y2 = (float(v) for v in box)
    cx, cy = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
    hw, hh = 0.5 * (x2 - x1) * fraction, 0.5 * (y2 - y1) * fraction
    c0, c1 = int(np.floor(cx - hw)), int(np.ceil(cx + hw))
    r0, r1 = int(np.floor(cy - hh)), int(np.ceil(cy + hh))
    c0, r0 = max(c0, 0), max(r0, 0)
    c1, r1 = min(c1, width), min(r1, height)
    if c1 <= c0 or r1 <= r0:
        return None
    return slice(r0, r1), slice(c0, c1)


def median_disparity(disparity: np.ndarray, box) -> tuple[float, int, int]:
    """Median of the valid disparities in ``box`` (x1, y1, x2, y2): (d, n_valid, n_pixels);
    d = nan when none is valid."""
    h, w = disparity.shape
    sl = _box_slice(box, w, h, 1.0)
    if sl is None:
        return float("nan"), 0, 0
    patch = disparity[sl]
    vals = patch[patch > 0]
    if vals.size == 0:
        return float("nan"), 0, int(patch.size)
    return float(np.median(vals)), int(vals.size), int(patch.size)


def _robust_mode(
    vals: np.ndarray, box_h: float, geometry: StereoGeometry, params: RangingParams, far_weight
) -> tuple[float, np.ndarray]:
    """The robust estimator's choice among valid disparities ``vals`` [px] of a box ``box_h``
    pixels high (module doc): (log-disparity of the winning mode's centre, mask of the values
    within +-1.5 bins of it); (nan, empty mask) when nothing is left."""
    logd = np.log(vals.astype(np.float64))
    lo, hi = logd.min(), logd.max()
    nbins = max(1, int(np.ceil((hi - lo) / params.mode_bin)) + 1)
    hist, edges = np.histogram(logd, bins=nbins, range=(lo, lo + nbins * params.mode_bin))
    # smooth with a 3-bin window so that a surface split across two bins stays one mode
    hp = np.pad(hist.astype(float), 1)
    sm = hp[:-2] + hp[1:-1] + hp[2:]
    padded = np.concatenate([[-1.0], sm, [-1.0]])
    peaks = np.flatnonzero((sm >= padded[:-2]) & (sm > padded[2:]) & (sm > 0))
    if peaks.size == 0:
        peaks = np.array([int(np.argmax(sm))])
    support = sm[peaks] / vals.size
    keep = support >= params.min_mode_fraction
    if keep.any():
        peaks, support = peaks[keep], support[keep]
    centres = 0.5 * (edges[peaks] + edges[peaks + 1])
    score = support.copy()
    if params.prior_log_sigma > 0 and box_h > 1:
        z_prior = geometry.fy * params.prior_height / box_h
        z_mode = geometry.fx * geometry.baseline / np.exp(centres)
        score *= np.exp(-0.5 * ((np.log(z_mode) - np.log(z_prior)) / params.prior_log_sigma) ** 2)
    if far_weight > 0:
        score *= np.exp(far_weight * (centres.max() - centres))
    best = centres[int(np.argmax(score))]
    return float(best), np.abs(logd - best) <= 1.5 * params.mode_bin


def robust_disparity(
    disparity: np.ndarray,
    box,
    geometry: StereoGeometry,
    params: RangingParams,
    columns: bool = False,
):
    """Disparity of the dominant car-consistent surface in ``box`` (see module doc):
    (d, number of pixels supporting it); d = nan when none. With ``columns``, a third item: the
    image columns of the supporting pixels (one entry per pixel)."""
    h, w = disparity.shape
    sl = _box_slice(box, w, h, params.core_fraction)
    none = (float("nan"), 0, np.zeros(0)) if columns else (float("nan"), 0)
    if sl is None:
        return none
    patch = disparity[sl]
    valid = patch > 0
    if params.reject_ground:
        rows = np.arange(sl[0].start, sl[0].stop, dtype=float)[:, None]
        # height below the camera: y = (v - cy) * z / fy = (v - cy) * B * fx / (fy * d)
        with np.errstate(divide="ignore", invalid="ignore"):
            y = (rows - geometry.cy) * geometry.baseline * geometry.fx / (geometry.fy * patch)
        valid &= ~(y > params.ground_height - params.ground_margin)
    vals = patch[valid]
    if vals.size < max(1, params.min_valid_pixels // 2):
        return none
    box_h = float(box[3]) - float(box[1])
    _, in_mode = _robust_mode(vals, box_h, geometry, params, params.far_weight)
    if not in_mode.any():
        return none
    d = float(np.exp(np.median(np.log(vals[in_mode].astype(np.float64)))))
    if columns:
        cols = np.nonzero(valid)[1][in_mode] + sl[1].start
        return d, int(in_mode.sum()), cols
    return d, int(in_mode.sum())


def disparity_std(d: float, refined: bool, params: RangingParams) -> float:
    """Disparity std [px] of a box ranged at disparity ``d``: ``sigma_d_far`` when it was
    refined at full resolution and ``d < far_disparity``, else ``sigma_d``."""
    return params.sigma_d_far if refined and d < params.far_disparity else params.sigma_d


#: [m] depths at which the stereo node's camera line states the ranging's depth std
PRECISION_DEPTHS = (20.0, 40.0, 60.0)


def depth_std_at(z: float, geometry: StereoGeometry, params: RangingParams) -> float:
    """[m] the depth std the ranging reports for a car at depth ``z`` on this camera: the z
    part of :func:`position_covariance` (``z^2 sigma_d / (f B)`` with the refined
    ``sigma_d_far`` where a box would be refined, plus ``depth_offset_std``)."""
    d = geometry.fx * geometry.baseline / z
    refined = params.refine != "none" and d <= params.refine_max_disparity
    sd = disparity_std(d, refined, params)
    cov = position_covariance(geometry.cx, geometry.cy, z, geometry, params, sd)
    return math.sqrt(cov[2, 2])


def precision_line(geometry: StereoGeometry, params: RangingParams) -> str:
    """One clause for the camera's log line: the depth std a car is ranged with at
    :data:`PRECISION_DEPTHS` on this camera, from its f x B and the error model measured on
    KITTI (385 px m there); a shorter f x B ranges far cars worse (README)."""
    stds = " / ".join(f"{depth_std_at(z, geometry, params):.1f}" for z in PRECISION_DEPTHS)
    at = " / ".join(f"{z:.0f}" for z in PRECISION_DEPTHS)
    fB = geometry.fx * geometry.baseline
    return (
        f"ranging depth std {stds} m at {at} m (f x baseline {fB:.0f} px m, KITTI's about 385; "
        "the error model measured on KITTI)"
    )


def position_covariance(
    u: float,
    v: float,
    z: float,
    geometry: StereoGeometry,
    params: RangingParams,
    sigma_d: float | None = None,
) -> np.ndarray:
    """3x3 covariance of the point at pixel (u, v) and depth z [m^2] (first-order propagation of
    sigma_pixel in u, v and of the stereo depth std z^2 sigma_d / (f B) plus depth_offset_std;
    ``sigma_d`` [px] defaults to ``params.sigma_d``, see :func:`disparity_std`)."""
    f, B = geometry.fx, geometry.baseline
    sd = params.sigma_d if sigma_d is None else sigma_d
    var_z = (z * z * sd / (f * B)) ** 2 + params.depth_offset_std**2
    J = np.array(
        [
            [z / geometry.fx, 0.0, (u - geometry.cx) / geometry.fx],
            [0.0, z / geometry.fy, (v - geometry.cy) / geometry.fy],
            [0.0, 0.0, 1.0],
        ]
    )
    S = np.diag([params.sigma_pixel**2, params.sigma_pixel**2, var_z])
    return J @ S @ J.T


def refined_disparity(
    d: float, box, images, params: RangingParams, region: RegionParams | None = None
) -> float:
    """The box's disparity after the full-resolution refinement ``params.refine`` on the
    (left, right) gray ``images`` (d itself when off, not applicable or failing); no bias
    correction (:func:`disparity_bias_at`)."""
    if params.refine != "none" and images is not None and 0 < d <= params.refine_max_disparity:
        refine = refine_shift if params.refine == "region_shift" else box_disparity
        d_fine, _ = refine(images[0], images[1], box, d, region)
        if np.isfinite(d_fine) and d_fine > 0:
            d = d_fine
    return d


def disparity_bias_at(u, geometry: StereoGeometry, params: RangingParams):
    """Measured disparity bias [px] at image column(s) ``u``: ``disparity_bias +
    disparity_bias_column * ((u - cx) / fx)^2`` (it grows toward the image borders, docs)."""
    x = (np.asarray(u, dtype=float) - geometry.cx) / geometry.fx
    return params.disparity_bias + params.disparity_bias_column * x * x


def observation_angles_of(angles, variances) -> np.ndarray:
    """Continuous observation angles [rad] for :func:`range_boxes` from a detector's outputs:
    ``angles`` with their ``variances`` [rad^2]; a variance < 0 (or a non-finite value) means
    not provided (old checkpoints) and gives nan (the bin's centre angle is used)."""
    a = np.asarray(angles, float).reshape(-1)
    var = np.asarray(variances, float).reshape(-1)
    return np.where(np.isfinite(a) & np.isfinite(var) & (var >= 0), a, np.nan)


@dataclass(frozen=True)
class _BorderCut:
    """Which image borders a box touches (within :data:`TRUNCATION_BORDER` px)."""

    left: bool
    right: bool
    bottom: bool

    @classmethod
    def of(cls, box, width: int, height: int) -> _BorderCut:
        return cls(
            box[0] <= TRUNCATION_BORDER,
            box[2] >= width - 1 - TRUNCATION_BORDER,
            box[3] >= height - 1 - TRUNCATION_BORDER,
        )

    @property
    def side(self) -> bool:
        """Cut on the left or the right."""
        return self.left or self.right


def _box_disparity(
    disparity: np.ndarray,
    box,
    geometry: StereoGeometry,
    params: RangingParams,
    images,
    visible_part: bool,
    u: float,
) -> tuple[float, bool, np.ndarray, float] | None:
    """(disparity [px] of the box's surface, refined and bias-corrected; whether refined; the
    visible part's columns; the share of valid pixels), or None when there is none."""
    d_med, n_valid, n_pix = median_disparity(disparity, box)
    frac = n_valid / n_pix if n_pix else 0.0
    enough = n_valid >= params.min_valid_pixels and frac >= params.min_valid_fraction
    refined, columns = False, np.zeros(0)
    if visible_part:
        d, refined, columns = _cut_box_disparity(
            disparity, box, geometry, params, images, d_med if enough else math.nan
        )
    elif not enough:
        return None
    elif params.method == "median":
        d = d_med
    else:
        d, _ = robust_disparity(disparity, box, geometry, params)
        if not np.isfinite(d):
            d = d_med
    if np.isfinite(d) and d > 0:
        if not visible_part:
            d_coarse = d
            d = refined_disparity(d, box, images, params)
            refined = d != d_coarse
        d -= float(disparity_bias_at(u, geometry, params))
    if not (np.isfinite(d) and d > 0):
        return None
    return d, refined, columns, frac


def _centre_offset(setup: RangingSetup, cut: bool, b: int, alpha: float):
    """(offset [m] along the ray from the visible surface to the car's centre, bin, angle):
    at the continuous angle ``alpha`` when finite (its bin), else at bin ``b``'s centre angle,
    else (no or an invalid bin) the mean over all angles with bin 0's ``depth_offset``."""
    params = setup.params
    centre = setup.truncated_offsets if cut else setup.centre_offsets
    if math.isfinite(alpha):  # the continuous angle: the correction at that angle
        b = alpha_to_bin(alpha)
        offset = params.depth_offset[b]
        if params.centre_correction:
            model = params.truncated_surface_model if cut else params.surface_model
            offset += float(
                centre_depth_behind_surface(
                    alpha, params.car_length, params.car_width, model, params.surface_blend
                )
                - params.surface_inset
            )
    elif 0 <= b < NUM_BINS:
        offset = float(centre[b] + params.depth_offset[b])
        alpha = b * BIN_WIDTH
    else:  # no bin, or an invalid one: the mean correction over all angles
        offset = float(centre[NUM_BINS] + params.depth_offset[0])
    return offset, b, alpha


@dataclass(frozen=True, eq=False)
class _Surface:
    """A box's visible surface: its disparity [px] (refined, bias-corrected), whether refined,
    the visible part's columns (cut boxes), the share of valid pixels, the box centre [px] and
    the borders it touches."""

    d: float
    refined: bool
    columns: np.ndarray
    frac: float
    u: float
    v: float
    cut: _BorderCut  # cut by the image border or hidden by a nearer object
    one_side: bool  # cut on one side and fitted by its visible part (_fit_cut_centre)
    hidden: _BorderCut | None = None  # the sides hidden by a nearer object (occluder cut)
    plain: _Surface | None = None  # with hidden sides: the surface as if none were hidden


def _box_surface(
    disparity: np.ndarray, box, geometry: StereoGeometry, params: RangingParams, images, size
) -> _Surface | None:
    """The surface of one box of a (height, width) ``size`` map, or None when the box is empty
    or has no usable disparity."""
    if not np.all(np.isfinite(box)) or box[2] <= box[0] or box[3] <= box[1]:
        return None
    cut = _BorderCut.of(box, size[1], size[0])
    # boxes cut by a border: the visible part's surface (_cut_box_disparity); one side
    # cut: also the centre of the car from its visible part (_fit_cut_centre)
    visible_part = params.cut_box_fit and (cut.side or cut.bottom) and params.method == "robust"
    one_side = visible_part and cut.left != cut.right
    u, v = 0.5 * (box[0] + box[2]), 0.5 * (box[1] + box[3])
    found = _box_disparity(disparity, box, geometry, params, images, visible_part, u)
    if found is None:
        return None
    hidden = None
    if params.occluder_cut and params.cut_box_fit and params.method == "robust":
        # the car's surface in the map's terms (the bias put back) against the strips beside
        d_map = found[0] + float(disparity_bias_at(u, geometry, params))
        sides = occluder_sides(
            disparity,
            box,
            d_map,
            geometry,
            params.occluder_strip,
            params.occluder_margin,
            params.occluder_share,
            params.ground_height,
            params.ground_margin,
            (cut.left, cut.right, cut.bottom or not params.occluder_bottom),
        )
        if any(sides):  # hidden sides: ranged like sides cut by the border
            plain = _Surface(*found, u, v, cut, one_side)
            hidden = _BorderCut(*sides)
            cut = _BorderCut(cut.left or sides[0], cut.right or sides[1], cut.bottom or sides[2])
            if not visible_part:
                again = _box_disparity(disparity, box, geometry, params, images, True, u)
                found = again if again is not None else found
            one_side = cut.left != cut.right
            return _Surface(*found, u, v, cut, one_side, hidden, plain)
    return _Surface(*found, u, v, cut, one_side)


def _box_result(
    surface: _Surface, box, geometry: StereoGeometry, setup: RangingSetup, b: int, alpha, size
) -> RangeResult:
    """The car's centre behind ``surface`` with its bin ``b`` (NUM_BINS: none) and angle
    ``alpha`` (nan: none), its covariance and, for sides hidden by a nearer object, the 2D box
    extended there to the fitted car's full extent; ``size``: (height, width) of the map."""
    params = setup.params
    width = size[1]
    sides = (surface.cut.left, surface.cut.right)
    z_surface = float(geometry.fx * geometry.baseline / surface.d)
    offset, b, alpha = _centre_offset(setup, surface.cut.side, b, alpha)
    ray = geometry.backproject(surface.u, surface.v, 1.0)
    point = ray * z_surface + offset * ray / np.linalg.norm(ray)
    if params.lateral_fit and math.isfinite(alpha):
        point = fit_lateral(
            point,
            box,
            alpha,
            params.car_length,
            params.car_width,
            geometry,
            width,
            TRUNCATION_BORDER,
            cut=sides,
        )
    if surface.one_side and params.centre_correction and math.isfinite(alpha):
        if surface.cut.bottom:  # the box's centre row is not the car's: on the road
            point[1] = params.ground_height - 0.5 * params.prior_height
        fitted = _fit_cut_centre(
            z_surface, surface.columns, box, alpha, point, geometry, params, width, sides
        )
        if fitted is not None:
            point = fitted + np.array([0.0, 0.0, params.depth_offset[b]])
    sd = disparity_std(surface.d, surface.refined, params)
    cov = position_covariance(surface.u, surface.v, float(point[2]), geometry, params, sd)
    extended = None
    if surface.hidden is not None and math.isfinite(alpha):
        # the mean car standing on the road at the fitted centre, seen at its angle
        bottom = (float(point[0]), params.ground_height, float(point[2]))
        full = full_extent_box(
            bottom, alpha, params.car_length, params.car_width, params.prior_height, geometry
        )
        if full is not None:
            hidden = (surface.hidden.left, surface.hidden.right, surface.hidden.bottom)
            extended = extend_hidden_sides(box, hidden, full, size)
    return RangeResult(point, cov, float(surface.d), float(surface.frac), float(sd), extended)


def range_boxes(
    disparity: np.ndarray,
    boxes,
    geometry: StereoGeometry,
    params: RangingParams | RangingSetup | None = None,
    orientation_bins=None,
    images=None,
    observation_angles=None,
) -> list[RangeResult | None]:
    """Range each box (x1, y1, x2, y2) [px] of the left image in a disparity map [px].

    Returns one entry per box: a :class:`RangeResult`, or None when the box has too few valid
    disparities. ``params``: settings, or a :class:`RangingSetup` prepared once from them (same
    results, without re-validating and recomputing the offsets per call). ``orientation_bins``
    (0..3 per box) selects the per-bin centre correction and ``depth_offset``; without bins, and
    for a bin outside 0..3, the correction's mean over all angles and bin 0's offset.
    ``images``: the (left, right) uint8 gray images of the pair, for ``params.refine`` (without
    them the map's estimate is used, bias-corrected all the same). ``observation_angles``: the
    continuous observation angle alpha [rad] per box (any folding modulo pi; nan = not given):
    where given, the centre correction and the lateral fit use it instead of the bin's centre
    angle (:func:`observation_angles_of` turns detector outputs with a variance into these).
    """
    setup = params if isinstance(params, RangingSetup) else RangingSetup.from_params(params)
    size = disparity.shape if np.ndim(disparity) == 2 else (0, 0)
    disparity = np.asarray(disparity, np.float32)
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    results: list[RangeResult | None] = []
    for i, box in enumerate(boxes):
        surface = _box_surface(disparity, box, geometry, setup.params, images, size)
        if surface is None:
            results.append(None)
            continue
        b = int(orientation_bins[i]) if orientation_bins is not None else NUM_BINS
        alpha = float(observation_angles[i]) if observation_angles is not None else math.nan
        result = _box_result(surface, box, geometry, setup, b, alpha, size)
        if surface.hidden is not None:
            result = _hidden_result(result, surface, box, disparity, geometry, setup, b, alpha)
        results.append(result)
    return results


def _hidden_result(result, surface, box, disparity, geometry, setup, b, alpha) -> RangeResult:
    """The result of a box with sides hidden by a nearer object: its extended box cut back to
    where the nearer object reaches (:func:`.occluder.hidden_reach`); when that leaves the box
    as it was (the car does not reach beyond its box), the result as if nothing were hidden."""
    if result.box is not None:
        p = setup.params
        d_map = surface.d + float(disparity_bias_at(surface.u, geometry, p))
        reach = hidden_reach(
            disparity,
            box,
            result.box,
            d_map,
            geometry,
            0.0,  # nearer than the car: an occluder's side face may be within the margin
            p.occluder_share,
            p.ground_height,
            p.ground_margin,
        )
        if np.max(np.abs(np.subtract(reach, box))) > 0.5:
            return dataclasses.replace(result, box=reach)
    return _box_result(surface.plain, box, geometry, setup, b, alpha, disparity.shape)


def _mode_disparity(vals, box_h: float, geometry: StereoGeometry, params: RangingParams):
    """The robust estimator without far weighting on disparity values [px]: (d, support
    mask); d = nan when none."""
    vals = np.asarray(vals, float)
    if not vals.size:
        return float("nan"), np.zeros(0, bool)
    best, in_mode = _robust_mode(vals, box_h, geometry, params, 0.0)
    if not in_mode.any():
        return float("nan"), in_mode
    return float(np.exp(np.median(np.log(vals[in_mode])))), in_mode


def _cut_box_disparity(
    disparity: np.ndarray, box, geometry: StereoGeometry, params: RangingParams, images, d_med
) -> tuple[float, bool, np.ndarray]:
    """Disparity [px] (no bias correction) of the visible part of a car cut by the border:
    the robust estimator on the map, refined as other boxes when far; a near box (coarse
    disparity or the box height's prior above ``refine_max_disparity``) is matched at full
    resolution on its core over [0.6 x the lower, 1.6 x the higher of the two] (at most
    ``near_max_disparity``; the
    estimator without far weighting there: the window leaves the background out): the map's
    range ends at its number of disparities, and near the left border only the columns beyond
    the disparity are seen by the right camera. Returns (d, refined, image columns of the
    supporting pixels)."""
    d, _, cols = robust_disparity(disparity, box, geometry, params, columns=True)
    if not np.isfinite(d):
        d, cols = d_med, np.zeros(0)
    box_h = float(box[3]) - float(box[1])
    fb = geometry.fx * geometry.baseline
    d_prior = fb * box_h / (geometry.fy * params.prior_height) if box_h > 1 else math.nan
    near = max(np.nan_to_num(d, nan=0.0), np.nan_to_num(d_prior, nan=0.0))
    if images is not None and params.refine != "none" and near > params.refine_max_disparity:
        h, w = images[0].shape[:2]
        rect = core_rect(box, w, h, params.core_fraction)
        lo = 0.6 * min(v for v in (d, d_prior) if np.isfinite(v) and v > 0)
        hi = min(params.near_max_disparity, 1.6 * near)
        if rect is not None and hi > lo:
            region = RegionParams(search=(hi - lo) / (hi + lo))
            fine = region_disparity(images[0], images[1], rect, 0.5 * (hi + lo), region)
            c0, r0, c1, r1 = rect
            rr, cc = np.nonzero(fine > 0)
            vals = fine[rr, cc]
            if params.reject_ground and vals.size:
                y = (rr + r0 - geometry.cy) * fb / (geometry.fy * vals)
                keep = ~(y > params.ground_height - params.ground_margin)
                rr, cc, vals = rr[keep], cc[keep], vals[keep]
            if vals.size >= params.min_valid_pixels:
                d_fine, in_mode = _mode_disparity(vals, box_h, geometry, params)
                if np.isfinite(d_fine):
                    return d_fine, True, cc[in_mode] + c0
        return d, False, cols
    if np.isfinite(d) and d > 0:
        d_fine = refined_disparity(d, box, images, params)
        return d_fine, d_fine != d, cols
    return d, False, cols


def _fit_cut_centre(
    z_surface: float, columns, box, alpha: float, start, geometry, params, width: int, cut=None
):
    """:func:`centre_fit.fit_cut_box` with the ranging's estimator (no far weighting) as the
    statistic of the model car's visible surface over the measured columns, whose real surface
    lies ``surface_inset`` behind a box's faces."""
    cols = np.unique(np.asarray(columns, int))
    if not len(cols) or not params.car_length > 0 or not params.car_width > 0:
        return None
    counts = np.bincount(np.asarray(columns, int) - cols[0])[cols - cols[0]]
    fb = geometry.fx * geometry.baseline
    box_h = float(box[3]) - float(box[1])

    def statistic(z):
        hit = np.isfinite(z)
        d, _ = _mode_disparity(np.repeat(fb / z[hit], counts[hit]), box_h, geometry, params)
        return fb / d if np.isfinite(d) and d > 0 else math.nan

    return fit_cut_box(
        statistic,
        z_surface - params.surface_inset,
        cols + 0.5,
        box,
        alpha,
        params.car_length,
        params.car_width,
        geometry,
        width,
        np.asarray(start, float),
        TRUNCATION_BORDER,
        cut=cut,
    )
