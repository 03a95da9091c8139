"""Full-resolution disparity of one box: matching on the box's region only, box-level refinement.

Pure core (numpy/OpenCV). The frame's disparity map is matched at half resolution and WLS-
filtered (:mod:`.disparity`): cheap, dense, but for a far car (8 px of disparity at 45 m) its
per-pixel noise and the filter's smoothing across the car's outline cost tenths of a pixel,
i.e. metres. What is done here touches the boxes, not the frame:

- :func:`region_disparity`: left SGBM at full resolution on the box's rows and columns only,
  with the disparity search narrowed around the coarse estimate (``d0 * (1 +- search)``);
- :func:`box_disparity`: the median of the region's full-resolution disparities on the car's
  pixels (core of the box, within ``+-tolerance`` in log-disparity of the coarse estimate);
- :func:`refine_shift`: one disparity for the whole masked box: the sub-pixel shift of the right
  image that minimises the mean absolute difference of the masked pixels' intensity gradients
  (parabola through the best of 1/4-px steps), i.e. a box-level match with a pixel mask.

Disparities here are in full-resolution pixels; invalid pixels of a region hold -1.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

REFINE_METHODS = ("none", "region_sgbm", "region_shift")


@dataclass(frozen=True)
class RegionParams:
    """Settings of the box-region matcher (chosen on KITTI 2015, see docs/stereo_depth.md)."""

    block_size: int = 5  # SGBM block (full resolution)
    search: float = 0.35  # disparity search d0 * (1 +- search) around the coarse estimate
    tolerance: float = 0.08  # |log d - log d0| of the pixels that belong to the car
    core_fraction: float = 0.6  # central share of box width and height used
    min_pixels: int = 20  # fewer matched car pixels: keep the coarse estimate


def to_gray(img: np.ndarray) -> np.ndarray:
    """uint8 gray image of an RGB (H, W, 3) or gray (H, W) image."""
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img


def core_rect(box, width: int, height: int, fraction: float) -> tuple[int, int, int, int] | None:
    """(c0, r0, c1, r1) of the central ``fraction`` of a box's width and height, clipped to the
    image; None when under 2 px either way."""
    x1, y1, x2, y2 = (float(v) for v in box)
    cx, cy = 0.5 * (x1 + x2), 0.5 * (y1 + y2)
    hw, hh = 0.5 * (x2 - x1) * fraction, 0.5 * (y2 - y1) * fraction
    c0, c1 = max(int(np.floor(cx - hw)), 0), min(int(np.ceil(cx + hw)), width)
    r0, r1 = max(int(np.floor(cy - hh)), 0), min(int(np.ceil(cy + hh)), height)
    if c1 - c0 < 2 or r1 - r0 < 2:
        return None
    return c0, r0, c1, r1


def region_disparity(
    left_gray: np.ndarray,
    right_gray: np.ndarray,
    rect: tuple[int, int, int, int],
    d0: float,
    params: RegionParams,
) -> np.ndarray:
    """Full-resolution SGBM disparities [px] of the pixels in ``rect`` = (c0, r0, c1, r1) of the
    left image, searched in ``d0 * (1 +- search)``; shape (r1 - r0, c1 - c0), invalid = -1."""
    c0, r0, c1, r1 = rect
    bs = params.block_size
    d_lo = max(0, int(np.floor(d0 * (1.0 - params.search))) - 1)
    n_disp = int(np.ceil((d0 * (1.0 + params.search) + 1 - d_lo) / 16.0)) * 16
    # rows: a block's margin; columns: SGBM leaves the first d_lo + n_disp columns unmatched
    top, bottom = max(r0 - bs, 0), min(r1 + bs, left_gray.shape[0])
    start = c0 - (d_lo + n_disp) - bs
    stop = min(c1 + bs, left_gray.shape[1])
    pad = max(0, -start)
    start = max(start, 0)

    def crop(img: np.ndarray) -> np.ndarray:
        out = img[top:bottom, start:stop]
        return cv2.copyMakeBorder(out, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0) if pad else out

    matcher = cv2.StereoSGBM_create(
        minDisparity=d_lo,
        numDisparities=n_disp,
        blockSize=bs,
        P1=8 * bs * bs,
        P2=32 * bs * bs,
        disp12MaxDiff=1,
        preFilterCap=63,
        uniquenessRatio=10,
        speckleWindowSize=0,
        speckleRange=0,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )
    disp = matcher.compute(crop(left_gray), crop(right_gray)).astype(np.float32) / 16.0
    col0 = c0 - start + pad
    out = disp[r0 - top : r1 - top, col0 : col0 + (c1 - c0)]
    return np.where(out > d_lo, out, -1.0).astype(np.float32)


def car_mask(fine: np.ndarray, d0: float, tolerance: float) -> np.ndarray:
    """Pixels of a region whose disparity lies within ``+-tolerance`` (log) of ``d0``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return (fine > 0) & (np.abs(np.log(np.where(fine > 0, fine, 1.0) / d0)) <= tolerance)


def box_disparity(
    left_gray: np.ndarray,
    right_gray: np.ndarray,
    box,
    d0: float,
    params: RegionParams | None = None,
) -> tuple[float, int]:
    """Median full-resolution disparity of the car's pixels in the core of ``box`` (see module
    doc): (d, n_pixels); d = nan when fewer than ``min_pixels`` pixels match."""
    params = params or RegionParams()
    h, w = left_gray.shape[:2]
    rect = core_rect(box, w, h, params.core_fraction)
    if rect is None or not (np.isfinite(d0) and d0 > 0):
        return float("nan"), 0
    fine = region_disparity(left_gray, right_gray, rect, d0, params)
    vals = fine[car_mask(fine, d0, params.tolerance)]
    if vals.size < params.min_pixels:
        return float("nan"), int(vals.size)
    return float(np.median(vals)), int(vals.size)


def _gradient(img: np.ndarray) -> np.ndarray:
    return cv2.Sobel(img.astype(np.float32), cv2.CV_32F, 1, 0, ksize=3)


def _shift_costs(
    gl: np.ndarray, gr: np.ndarray, mask: np.ndarray, x0: int, shifts: np.ndarray
) -> np.ndarray:
    """Mean absolute difference over ``mask`` between ``gl`` and ``gr`` shifted left by each of
    ``shifts`` [px] (bilinear, border replicated); ``gl``'s first column is ``gr``'s ``x0``. All
    shifts in one remap (it is per pixel), a mean per shift, so each cost is bit-identical to
    its own remap's (the loop this replaced; tests/stereo_depth)."""
    h, w = mask.shape
    k = len(shifts)
    xs = np.arange(x0, x0 + w, dtype=np.float32)
    map_x = np.empty((k, h, w), np.float32)
    np.subtract(xs[None, None, :], shifts.astype(np.float32)[:, None, None], out=map_x)
    map_y = np.empty((k, h, w), np.float32)
    map_y[:] = np.arange(h, dtype=np.float32)[None, :, None]
    warped = cv2.remap(
        gr,
        map_x.reshape(-1, w),
        map_y.reshape(-1, w),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    diff = np.abs(gl[None] - warped.reshape(k, h, w))
    # one mean per shift: a mean along an axis of a 2D array may sum in another order
    return np.array([np.mean(row) for row in diff[:, mask]])


def refine_shift(
    left_gray: np.ndarray,
    right_gray: np.ndarray,
    box,
    d0: float,
    params: RegionParams | None = None,
    max_shift: float = 1.5,
    step: float = 0.25,
) -> tuple[float, int]:
    """Box-level disparity: the shift in ``d0 +- max_shift`` [px] of the right image that best
    matches the masked core pixels of ``box`` (mean absolute difference of horizontal gradients,
    parabola through the best step); mask = full-resolution region disparities within
    ``tolerance`` of ``d0``. Returns (d, n_pixels); d = nan when the mask is too small or the
    minimum lies on the search border."""
    params = params or RegionParams()
    h, w = left_gray.shape[:2]
    rect = core_rect(box, w, h, params.core_fraction)
    if rect is None or not (np.isfinite(d0) and d0 > 0):
        return float("nan"), 0
    c0, r0, c1, r1 = rect
    fine = region_disparity(left_gray, right_gray, rect, d0, params)
    mask = car_mask(fine, d0, params.tolerance)
    if int(mask.sum()) < params.min_pixels:
        return float("nan"), int(mask.sum())
    d_med = float(np.median(fine[mask]))
    pad = int(np.ceil(d_med + max_shift)) + 2
    x_lo = max(c0 - pad, 0)
    gl = _gradient(left_gray[r0:r1, x_lo:c1])[:, c0 - x_lo :]
    gr = _gradient(right_gray[r0:r1, x_lo:c1])
    shifts = d_med + np.arange(-max_shift, max_shift + 1e-9, step)
    costs = [float(c) for c in _shift_costs(gl, gr, mask, c0 - x_lo, shifts)]
    k = int(np.argmin(costs))
    if k == 0 or k == len(costs) - 1:
        return float("nan"), int(mask.sum())
    cm, c, cp = costs[k - 1], costs[k], costs[k + 1]
    denom = cm - 2.0 * c + cp
    offset = 0.5 * (cm - cp) / denom if denom > 0 else 0.0
    return float(shifts[k] + step * offset), int(mask.sum())
