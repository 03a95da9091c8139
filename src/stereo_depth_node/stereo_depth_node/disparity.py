"""Disparity of a rectified stereo pair: semi-global block matching + WLS filtering.

Pure core (numpy/OpenCV, no ROS). A left SGBM matcher and, when ``use_wls`` is set, the matching
right matcher (``cv2.ximgproc.createRightMatcher``) whose disparities are combined by the
weighted-least-squares filter (``cv2.ximgproc.createDisparityWLSFilter``, opencv-contrib), as in
the Stanford stereo tracker (Chan, Galczak & Li, 2019).

The output of :func:`compute_disparity` is a float32 map in pixels of the full-resolution left
image; pixels without a valid disparity hold :data:`INVALID_DISPARITY` (-1.0, below any valid
disparity, as stereo_msgs/DisparityImage documents for invalid values).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

#: Value of pixels without a valid disparity (smaller than any valid disparity).
INVALID_DISPARITY = -1.0

_MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}


@dataclass(frozen=True)
class DisparityParams:
    """Matcher and filter settings (defaults tuned on KITTI 2015, see docs/stereo_depth.md).

    Disparity-related settings (``min_disparity``, ``num_disparities``) are given in pixels of the
    full-resolution image; with ``downscale`` > 1 the matcher runs on images shrunk by that
    factor with the disparity range divided accordingly, and the WLS filter (guided by the
    full-resolution left image) brings the result back to full resolution.
    """

    min_disparity: int = 0  # [px] smallest disparity searched
    num_disparities: int = 96  # full-resolution pixels (z >= f*B/96 = 4.0 m on KITTI)
    block_size: int = 3  # SGBM matching block size (odd)
    p1_factor: float = 8.0  # P1 = p1_factor * channels * block_size^2
    p2_factor: float = 32.0  # P2 = p2_factor * channels * block_size^2
    disp12_max_diff: int = 1  # [px] SGBM left-right check
    pre_filter_cap: int = 63  # SGBM prefilter cap
    uniqueness_ratio: int = 10  # [%] SGBM uniqueness margin of the best match
    speckle_window_size: int = 100  # [px] SGBM speckle filter: largest blob removed
    speckle_range: int = 2  # SGBM speckle filter: disparity variation within a blob
    mode: str = "sgbm_3way"  # sgbm | hh | sgbm_3way | hh4
    use_color: bool = False  # match on RGB (3 channels) instead of grayscale
    use_wls: bool = True  # right matcher + WLS filter (false: plain left SGBM)
    wls_lambda: float = 8000.0  # WLS filter smoothness
    wls_sigma: float = 1.5  # WLS filter colour sensitivity of the guide image
    wls_lrc_thresh: int = 24  # left-right consistency threshold of the filter (1/16 px units)
    wls_min_confidence: float = 0.0  # filtered pixels with a lower confidence (0..255) -> invalid
    downscale: int = 2  # 1 = full resolution, 2 = match at half resolution
    wls_full_res_guide: bool = True  # with downscale: filter at full resolution (else filter at
    # the matching resolution and upsample the result)
    row_band: tuple[int, int] | None = None  # (top, bottom) rows to match; None = all rows
    pad_left: bool = True  # pad images on the left so the leftmost num_disparities columns
    # (which SGBM cannot match) still get disparities where their match lies inside the right view

    def validate(self) -> None:
        """Raise ValueError for settings OpenCV would reject or misuse."""
        if self.mode not in _MODES:
            raise ValueError(f"mode: {self.mode!r} not one of {sorted(_MODES)}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError(f"block_size: {self.block_size} must be odd and >= 1")
        if self.num_disparities < 16:
            raise ValueError(f"num_disparities: {self.num_disparities} must be >= 16")
        if self.downscale not in (1, 2, 4):
            raise ValueError(f"downscale: {self.downscale} must be 1, 2 or 4")


class RowBandError(ValueError):
    """The rows to match (the node's ``match_rows``) do not fit the images; the message names
    the parameter and the image height."""


def check_match_rows(rows) -> None:
    """Raise ValueError (``match_rows: ...``) unless ``rows`` is ``[0, 0]`` (every row) or
    ``[top, bottom]`` with ``0 <= top < bottom`` (rows top..bottom-1 are matched)."""
    top, bottom = (int(v) for v in rows)
    if (top, bottom) != (0, 0) and not 0 <= top < bottom:
        raise ValueError(
            f"match_rows: [{top}, {bottom}]: expected [top, bottom] with 0 <= top < bottom "
            "(rows top..bottom-1 are matched), or [0, 0] for every row"
        )


def min_band_rows(params: DisparityParams) -> int:
    """The fewest rows a band may have for the matcher and filter to give disparities."""
    return 2 * params.block_size * params.downscale


def match_band(
    rows, height: int, params: DisparityParams
) -> tuple[tuple[int, int] | None, str | None]:
    """The ``row_band`` to match in images ``height`` rows tall for the node's ``match_rows``
    (``[0, 0]``: every row), and a warning (or None) when the band reaches below the image and
    was cut at its last row (``[94, 375]`` on a 370-row KITTI frame). Raises RowBandError when
    fewer than :func:`min_band_rows` rows of the band lie in the image: nothing could be
    ranged, and the run would silently produce no vehicle. The one check of the band against
    an image, for the node and for settings derived from a CameraInfo."""
    check_match_rows(rows)
    top, bottom = (int(v) for v in rows)
    if (top, bottom) == (0, 0):
        return None, None
    inside = max(0, min(bottom, height) - top)
    need = min_band_rows(params)
    if inside < need:
        where = "lies below" if top >= height else f"keeps {inside} rows of"
        raise RowBandError(
            f"match_rows: [{top}, {bottom}] {where} the {height}-row image (rows 0..{height - 1}); "
            f"the matcher needs at least {need} rows: nothing could be ranged"
        )
    if bottom > height:
        return (top, height), (
            f"match_rows: [{top}, {bottom}] reaches below the {height}-row image: rows "
            f"{top}..{height - 1} are matched"
        )
    return (top, bottom), None


def _round16(n: float) -> int:
    return max(16, int(np.ceil(n / 16.0)) * 16)


def create_left_matcher(params: DisparityParams, scale: int = 1) -> cv2.StereoSGBM:
    """The left SGBM matcher for images shrunk by ``scale``."""
    channels = 3 if params.use_color else 1
    area = channels * params.block_size * params.block_size
    return cv2.StereoSGBM_create(
        minDisparity=int(params.min_disparity // scale),
        numDisparities=_round16(params.num_disparities / scale),
        blockSize=params.block_size,
        P1=int(params.p1_factor * area),
        P2=int(params.p2_factor * area),
        disp12MaxDiff=params.disp12_max_diff,
        preFilterCap=params.pre_filter_cap,
        uniquenessRatio=params.uniqueness_ratio,
        speckleWindowSize=params.speckle_window_size,
        speckleRange=params.speckle_range,
        mode=_MODES[params.mode],
    )


def _prepare(img: np.ndarray, params: DisparityParams) -> np.ndarray:
    if img.ndim == 2:
        return img if not params.use_color else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if params.use_color:
        return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


def _shrink(img: np.ndarray, scale: int) -> np.ndarray:
    if scale == 1:
        return img
    h, w = img.shape[:2]
    return cv2.resize(img, (w // scale, h // scale), interpolation=cv2.INTER_AREA)


def compute_disparity(
    left_rgb: np.ndarray, right_rgb: np.ndarray, params: DisparityParams | None = None
) -> np.ndarray:
    """Disparity [px] of a rectified pair (RGB uint8 (H, W, 3) or gray (H, W)).

    Returns a float32 (H, W) map; invalid pixels hold :data:`INVALID_DISPARITY`.
    """
    params = params or DisparityParams()
    params.validate()
    if left_rgb.shape != right_rgb.shape:
        raise ValueError(f"left {left_rgb.shape} and right {right_rgb.shape} image shapes differ")
    height, width = left_rgb.shape[:2]
    out = np.full((height, width), INVALID_DISPARITY, np.float32)
    # the band is kept a multiple of the scale so that the filter's resize is exact
    top, bottom = _band_rows(height, params)
    if params.row_band is not None and bottom - top < 2 * params.block_size * params.downscale:
        return out
    left_rgb, right_rgb = left_rgb[top:bottom], right_rgb[top:bottom]
    pad = 0
    if params.pad_left:
        pad = int(disparity_range(params)[1]) + 1
        pad += (-pad) % (16 * params.downscale)

        def padded(img: np.ndarray) -> np.ndarray:
            return cv2.copyMakeBorder(img, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)

        left_rgb, right_rgb = padded(left_rgb), padded(right_rgb)
    left, right = _prepare(left_rgb, params), _prepare(right_rgb, params)
    band = _match(left, right, left_rgb, params)
    out[top:bottom] = band[:, pad:]
    return out


def _match(
    left: np.ndarray, right: np.ndarray, left_guide_rgb: np.ndarray, params: DisparityParams
) -> np.ndarray:
    scale = params.downscale
    left_s, right_s = _shrink(left, scale), _shrink(right, scale)
    matcher = create_left_matcher(params, scale)
    disp_left = matcher.compute(left_s, right_s)  # int16, 1/16 px at the matching scale
    full_h, full_w = left.shape[:2]
    min_d = params.min_disparity
    if not params.use_wls:
        disp = disp_left.astype(np.float32) / 16.0
        valid = disp >= (min_d // scale)
        if scale != 1:
            disp = cv2.resize(disp, (full_w, full_h), interpolation=cv2.INTER_NEAREST) * scale
            valid = cv2.resize(
                valid.astype(np.uint8), (full_w, full_h), interpolation=cv2.INTER_NEAREST
            ).astype(bool)
        valid &= disp > 0
        return np.where(valid, disp, INVALID_DISPARITY).astype(np.float32)

    right_matcher = cv2.ximgproc.createRightMatcher(matcher)
    disp_right = right_matcher.compute(right_s, left_s)
    wls = cv2.ximgproc.createDisparityWLSFilter(matcher)
    wls.setLambda(params.wls_lambda)
    wls.setSigmaColor(params.wls_sigma)
    wls.setLRCthresh(params.wls_lrc_thresh)
    guide = cv2.cvtColor(left_guide_rgb, cv2.COLOR_RGB2BGR) if left_guide_rgb.ndim == 3 else left
    if not params.wls_full_res_guide:
        guide = _shrink(guide, scale)
    # With a full-resolution guide and low-resolution disparities the filter upsamples the
    # disparities (and multiplies them by the scale) itself.
    filtered = wls.filter(disp_left, guide, disparity_map_right=disp_right)
    # in place from here on (the same float32 operations as new arrays: the same values)
    disp = filtered.astype(np.float32)
    disp /= 16.0
    if disp.shape != (full_h, full_w):  # filtered at the matching resolution: upsample
        factor = full_w / disp.shape[1]
        disp = cv2.resize(disp, (full_w, full_h), interpolation=cv2.INTER_LINEAR)
        disp *= factor
    valid = disp > max(0.0, float(min_d))
    roi = wls.getROI()  # (x, y, w, h) of the area where the filter had both views
    if roi is not None and len(roi) == 4 and roi[2] > 0:
        x, y, w, h = (int(v) for v in roi)
        if scale != 1:  # the ROI is reported at the matching scale
            x, y, w, h = x * scale, y * scale, w * scale, h * scale
        mask = np.zeros_like(valid)
        mask[y : y + h, x : x + w] = True
        valid &= mask
    if params.wls_min_confidence > 0:
        conf = wls.getConfidenceMap()
        if conf is not None and conf.size:
            conf = np.asarray(conf, np.float32)
            if conf.shape != valid.shape:
                conf = cv2.resize(conf, (full_w, full_h), interpolation=cv2.INTER_NEAREST)
            valid &= conf >= params.wls_min_confidence
    disp[~valid] = INVALID_DISPARITY
    return disp


#: [px, full resolution] rows of matching context above and below a box's rows, and columns
#: beyond its search range on each side (:func:`box_regions`)
CONTEXT_ROWS = 16
CONTEXT_COLUMNS = 32
#: when the boxes' matching regions cover more than this share of the band, the band is matched
#: whole (as fast, and no region edges)
MAX_REGION_SHARE = 0.7


@dataclass(frozen=True)
class MatchRegion:
    """One rectangle matched on its own (:func:`compute_disparity_in_boxes`): ``crop`` (x1, y1,
    x2, y2) [px, end exclusive] the pixels given to the matcher, ``outputs`` the box rectangles
    inside it whose disparities are kept."""

    crop: tuple[int, int, int, int]
    outputs: tuple[tuple[int, int, int, int], ...]


def _band_rows(height: int, params: DisparityParams) -> tuple[int, int]:
    """The rows [top, bottom) the matcher covers: all, or the band cut to a multiple of the
    scale."""
    if params.row_band is None:
        return 0, height
    top = max(0, int(params.row_band[0]))
    bottom = min(height, int(params.row_band[1]))
    return top, top + max(0, (bottom - top) // params.downscale) * params.downscale


def box_regions(boxes, shape: tuple[int, int], params: DisparityParams) -> list[MatchRegion]:
    """The regions of a frame to match for ``boxes`` ((x1, y1, x2, y2) [px]): each box's pixels
    within the band (rounded outwards), with matching context: :data:`CONTEXT_ROWS` rows above
    and below, and to each side the disparity search range plus :data:`CONTEXT_COLUMNS` (the
    left matcher looks that far left, the right matcher of the WLS filter that far right).
    Boxes whose regions overlap are matched together. Crops start on the half-resolution grid
    of the whole band (even rows from its top, even columns), so that a box's pixels are the
    same pixels of the same matcher as in the whole band's map."""
    height, width = shape
    top, bottom = _band_rows(height, params)
    scale = params.downscale
    reach = int(disparity_range(params)[1]) + 1 + CONTEXT_COLUMNS
    rects = []
    for box in np.asarray(boxes, float).reshape(-1, 4):
        if not np.all(np.isfinite(box)):
            continue
        x1, y1 = max(0, int(np.floor(box[0]))), max(top, int(np.floor(box[1])))
        x2, y2 = min(width, int(np.ceil(box[2])) + 1), min(bottom, int(np.ceil(box[3])) + 1)
        if x2 > x1 and y2 > y1:
            rects.append((x1, y1, x2, y2))

    def crop_of(r):
        x1, y1, x2, y2 = r
        cx1 = max(0, x1 - reach)
        cy1 = max(top, y1 - CONTEXT_ROWS)
        cx1 -= cx1 % scale
        cy1 -= (cy1 - top) % scale
        return cx1, cy1, min(width, x2 + reach), min(bottom, y2 + CONTEXT_ROWS)

    groups = [[r] for r in rects]
    merged = True
    while merged:  # join groups whose crops overlap, until none do
        merged = False
        for i in range(len(groups)):
            a = crop_of(_bounds(groups[i]))
            for j in range(i + 1, len(groups)):
                b = crop_of(_bounds(groups[j]))
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    groups[i] += groups.pop(j)
                    merged = True
                    break
            if merged:
                break
    return [MatchRegion(crop_of(_bounds(g)), tuple(g)) for g in groups]


def _bounds(rects) -> tuple[int, int, int, int]:
    a = np.asarray(rects)
    return int(a[:, 0].min()), int(a[:, 1].min()), int(a[:, 2].max()), int(a[:, 3].max())


def compute_disparity_in_boxes(
    left_rgb: np.ndarray, right_rgb: np.ndarray, boxes, params: DisparityParams | None = None
) -> np.ndarray:
    """The disparity map of :func:`compute_disparity` where the ranging and its check read it:
    inside ``boxes`` (within the band), each matched on its :func:`box_regions` crop with the
    same matcher and filter; every other pixel is :data:`INVALID_DISPARITY`. When the crops
    would cover more than :data:`MAX_REGION_SHARE` of the band, the whole band is matched
    and returned (then every band pixel holds its value)."""
    params = params or DisparityParams()
    params.validate()
    if left_rgb.shape != right_rgb.shape:
        raise ValueError(f"left {left_rgb.shape} and right {right_rgb.shape} image shapes differ")
    height, width = left_rgb.shape[:2]
    regions = box_regions(boxes, (height, width), params)
    top, bottom = _band_rows(height, params)
    area = sum((r.crop[2] - r.crop[0]) * (r.crop[3] - r.crop[1]) for r in regions)
    if area > MAX_REGION_SHARE * width * max(1, bottom - top):
        return compute_disparity(left_rgb, right_rgb, params)
    out = np.full((height, width), INVALID_DISPARITY, np.float32)
    for region in regions:
        x1, y1, x2, y2 = region.crop
        # the crop is its own band; the left border is padded only where it is the image's
        crop_params = replace(params, row_band=None, pad_left=params.pad_left and x1 == 0)
        disp = compute_disparity(left_rgb[y1:y2, x1:x2], right_rgb[y1:y2, x1:x2], crop_params)
        for ox1, oy1, ox2, oy2 in region.outputs:
            out[oy1:oy2, ox1:ox2] = disp[oy1 - y1 : oy2 - y1, ox1 - x1 : ox2 - x1]
    return out


def block_matching_disparity(
    left_gray: np.ndarray, right_gray: np.ndarray, params: DisparityParams | None = None
) -> np.ndarray:
    """The scene map of :func:`block_matching_maps` alone."""
    return block_matching_maps(left_gray, right_gray, params, road=False)[0]


def block_matching_maps(
    left_gray: np.ndarray,
    right_gray: np.ndarray,
    params: DisparityParams | None = None,
    road: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """(scene, road) maps of one block matching. ``scene``: a fast, sparser disparity map of
    the band for what needs the whole scene but not the ranging's accuracy (the visual
    odometry's corners, the road plane): OpenCV block matching
    (``cv2.StereoBM``, 9 x 9 blocks, its texture and uniqueness checks and the left-right check
    ``disp12_max_diff``) at 1/``downscale`` resolution over the band, the left border padded,
    nearest-neighbour back to full resolution. Gray uint8 images; float32 [px], invalid pixels
    :data:`INVALID_DISPARITY`. About a tenth of the cost of :func:`compute_disparity`.

    ``road`` (when asked): the same matches with the speckle filter's ``speckle_range`` read in
    pixels, as SGBM reads it (OpenCV's block matcher reads it in 1/16 px, so on the scene map a
    road, whose disparity changes by a fraction of a pixel from one row to the next, falls into
    blobs smaller than ``speckle_window_size`` and is mostly removed): the road plane's map,
    for the price of a second speckle filtering (the scene map is the same either way)."""
    params = params or DisparityParams()
    params.validate()
    if left_gray.shape != right_gray.shape or left_gray.ndim != 2:
        raise ValueError(f"gray images of one size needed: {left_gray.shape}, {right_gray.shape}")
    height, width = left_gray.shape
    out = np.full((height, width), INVALID_DISPARITY, np.float32)
    top, bottom = _band_rows(height, params)
    scale = params.downscale
    n = _round16(params.num_disparities / scale)
    if bottom - top < 2 * BM_BLOCK * scale:
        return out, (out.copy() if road else None)
    pad = n * scale if params.pad_left else 0

    def prepared(img: np.ndarray) -> np.ndarray:
        img = img[top:bottom]
        if pad:
            img = cv2.copyMakeBorder(img, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0)
        return _shrink(img, scale)

    bm = cv2.StereoBM_create(numDisparities=n, blockSize=BM_BLOCK)
    bm.setMinDisparity(int(params.min_disparity // scale))
    bm.setUniquenessRatio(params.uniqueness_ratio)
    bm.setDisp12MaxDiff(params.disp12_max_diff)
    bm.setSpeckleWindowSize(0)  # filtered below (the same as the matcher's own filter)
    raw = bm.compute(prepared(left_gray), prepared(right_gray))
    # the matcher's value of a pixel its speckle filter removes
    removed = (int(params.min_disparity // scale) - 1) * 16
    ranges = (params.speckle_range, 16 * params.speckle_range) if road else (params.speckle_range,)
    maps = []
    for speckle_range in ranges:
        disp = raw.copy() if road else raw
        if params.speckle_window_size > 0:
            cv2.filterSpeckles(disp, removed, params.speckle_window_size, speckle_range)
        disp = disp[:, pad // scale :].astype(np.float32)
        disp /= 16.0  # in place: the same float32 operations as new arrays
        if scale != 1:
            disp = cv2.resize(disp, (width, bottom - top), interpolation=cv2.INTER_NEAREST)
            disp *= scale
        disp[~(disp > max(0.0, float(params.min_disparity)))] = INVALID_DISPARITY
        full = out.copy()
        full[top:bottom] = disp
        maps.append(full)
    return maps[0], (maps[1] if road else None)


#: block size of :func:`block_matching_disparity` (at the matching resolution)
BM_BLOCK = 9


def coarse_disparity(
    left_rgb: np.ndarray, right_rgb: np.ndarray, params: DisparityParams | None = None
) -> np.ndarray:
    """The map of :func:`compute_disparity` at half its resolution, for a large smooth surface
    (the road plane): the same matchers and filter over the same band at twice the
    ``downscale`` (at most 4), the filter guided at the matching resolution (a quarter of the
    pixels and half the disparities to search). About a third of the cost of the band's map;
    invalid pixels :data:`INVALID_DISPARITY`."""
    params = params or DisparityParams()
    coarse = replace(params, downscale=min(4, 2 * params.downscale), wls_full_res_guide=False)
    return compute_disparity(left_rgb, right_rgb, coarse)


def disparity_range(params: DisparityParams) -> tuple[float, float]:
    """(min, max) disparity in full-resolution pixels the matcher can return."""
    scale = params.downscale
    n = _round16(params.num_disparities / scale) * scale
    lo = float(params.min_disparity)
    return lo, lo + n - 1.0


def d1_error(
    disparity: np.ndarray, ground_truth: np.ndarray, abs_px: float = 3.0, rel: float = 0.05
) -> dict[str, float]:
    """KITTI 2015 D1 figures of a disparity map against ground truth (0 = no ground truth).

    ``d1_all``: share of ground-truth pixels that are bad (|d - gt| > abs_px and > rel * gt),
    counting pixels without an estimate as bad; ``d1_valid``: the same over estimated pixels only;
    ``density``: share of ground-truth pixels with an estimate.
    """
    gt_mask = ground_truth > 0
    est = disparity > 0
    err = np.abs(disparity - ground_truth)
    bad = (err > abs_px) & (err > rel * ground_truth)
    n_gt = int(gt_mask.sum())
    both = gt_mask & est
    n_both = int(both.sum())
    bad_all = int((gt_mask & (~est | bad)).sum())
    return {
        "d1_all": bad_all / max(n_gt, 1),
        "d1_valid": int((both & bad).sum()) / max(n_both, 1),
        "density": n_both / max(n_gt, 1),
        "n_gt": float(n_gt),
    }


def _fill_along_rows(disp: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h, w = disp.shape
    idx = np.where(valid, np.arange(w)[None, :], -1)
    left_idx = np.maximum.accumulate(idx, axis=1)
    ridx = np.where(valid, np.arange(w)[None, :], w)
    right_idx = np.minimum.accumulate(ridx[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    has_l, has_r = left_idx >= 0, right_idx < w
    lv = np.where(has_l, disp[rows, np.clip(left_idx, 0, w - 1)], np.inf)
    rv = np.where(has_r, disp[rows, np.clip(right_idx, 0, w - 1)], np.inf)
    filled = np.minimum(lv, rv)
    ok = has_l | has_r
    return np.where(valid, disp, np.where(ok, filled, 0.0)).astype(np.float32), valid | ok


def interpolate_background(disparity: np.ndarray) -> np.ndarray:
    """Fill invalid pixels as the KITTI devkit does before scoring (each gap of a row takes the
    smaller, i.e. background, of its two bordering disparities; rows without any estimate take the
    nearest row's values), so that D1 of sparse and dense maps can be compared."""
    disp = np.asarray(disparity, np.float32)
    filled, ok = _fill_along_rows(disp, disp > 0)
    # rows with no estimate at all: fill along columns (nearest valid row, background choice)
    filled_t, ok_t = _fill_along_rows(filled.T.copy(), ok.T.copy())
    return np.where(ok_t.T, filled_t.T, 0.0).astype(np.float32)
