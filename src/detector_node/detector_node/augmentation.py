"""Training augmentation for a small real set: geometric (flip, scale jitter + crop keeping the
frame's aspect), photometric (colour, gamma, blur, noise) and copy-paste (real car crops onto real
backgrounds at a size plausible for their image row; the 352x352 supplementary crops pasted back at
their native position).

Every function takes and returns :class:`~detector_node.dataset.Sample` (image + boxes in the
pixels of that image). Orientation bins of -1 mean "unknown" (labels without alpha) and stay -1.
Geometric functions run on full-resolution frames before the resize to the network input;
photometric ones after it (cheaper on the small image, same effect).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from vehicle_common.box2d import overlap_over_first
from vehicle_common.orientation_bins import flip_alpha, flip_bin

from .dataset import Sample, box_view, sample_alphas, sample_view, select_boxes

#: A box cut by a crop stays a positive when at least this share of its area is kept; less
#: visible boxes become ignore regions (neither positive nor background).
MIN_VISIBLE_FRACTION = 0.5


def _truncation(sample: Sample) -> np.ndarray:
    t = sample.truncation
    return np.zeros(len(sample.boxes), np.float32) if t is None else t


def flip_sample(sample: Sample) -> Sample:
    """Horizontal flip: boxes mirrored, orientation bins 45 <-> 135 (alpha -> pi - alpha), the
    boxes' view (:attr:`~detector_node.dataset.Sample.view`) mirrored (x -> 1 - x)."""
    w = sample.image.shape[1]
    b = sample.boxes.copy()
    b[:, [0, 2]] = w - sample.boxes[:, [2, 0]]
    d = sample.dontcare.copy()
    d[:, [0, 2]] = w - sample.dontcare[:, [2, 0]]
    view = None
    if sample.view is not None:
        view = sample.view.copy()
        view[:, 0] = 1.0 - view[:, 0]
    return replace(
        sample,
        image=np.ascontiguousarray(sample.image[:, ::-1]),
        boxes=b,
        bins=flip_bin(sample.bins),
        dontcare=d,
        alphas=None if sample.alphas is None else flip_alpha(sample.alphas).astype(np.float32),
        view=view,
    )


def crop_sample(
    sample: Sample, x0: int, y0: int, width: int, height: int, min_visible=MIN_VISIBLE_FRACTION
) -> Sample:
    """Cut the window [x0, x0+width) x [y0, y0+height) (it may extend past the image: the outside
    is filled with the image's mean colour). Boxes are clipped and shifted; a box keeping less
    than ``min_visible`` of its area becomes an ignore region; the truncation of a kept box grows
    to 1 - (1 - t) * kept fraction."""
    img = sample.image
    h, w = img.shape[:2]
    out = np.empty((height, width, 3), np.uint8)
    out[:] = np.array(cv2.mean(img)[:3]).astype(np.uint8)
    sx0, sy0, sx1, sy1 = max(x0, 0), max(y0, 0), min(x0 + width, w), min(y0 + height, h)
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = img[sy0:sy1, sx0:sx1]
    # content outside the source image is padding: clip to the source image, then to the window
    lo = np.array([sx0, sy0, sx0, sy0], np.float32)
    hi = np.array([sx1, sy1, sx1, sy1], np.float32)
    shift = np.array([x0, y0, x0, y0], np.float32)

    def clip(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = np.clip(boxes, lo, hi)
        area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        kept = np.maximum(c[:, 2] - c[:, 0], 0) * np.maximum(c[:, 3] - c[:, 1], 0)
        return c - shift, kept / np.maximum(area, 1e-6)

    boxes, frac = clip(sample.boxes.reshape(-1, 4))
    dc, dc_frac = clip(sample.dontcare.reshape(-1, 4))
    keep = frac >= min_visible
    lost = (frac > 0) & ~keep
    trunc = 1.0 - (1.0 - _truncation(sample)) * frac
    cropped = replace(
        sample,
        image=out,
        boxes=boxes,
        truncation=trunc.astype(np.float32),
        dontcare=np.concatenate([dc[dc_frac > 0], boxes[lost]]).astype(np.float32),
    )
    return select_boxes(cropped, keep)


def crop_roi_top(sample: Sample, roi_top: float) -> Sample:
    """The frame below its top ``roi_top`` (fraction of its height), as inference frames it
    (:meth:`detector_node.inference.CnnDetector.detect`); the sample itself when 0."""
    if roi_top <= 0:
        return sample
    h, w = sample.image.shape[:2]
    top = int(round(roi_top * h))
    out = crop_sample(sample, 0, top, w, h - top)
    if out.view is not None:  # the framing is inference's: the view is relative to it
        view = out.view.copy()
        view[:, 1] = (view[:, 1] * h - top) / (h - top)
        out = replace(out, view=view)
    return out


def random_crop(
    sample: Sample,
    rng: np.random.Generator,
    min_scale: float = 0.6,
    max_scale: float = 1.0,
) -> Sample:
    """Scale jitter keeping the frame's aspect ratio: a window of ``s`` times the frame size
    (s uniform in [min_scale, max_scale]; s > 1 zooms out with mean-colour padding) at a random
    position. After the resize to the network input, objects appear 1/s times larger."""
    h, w = sample.image.shape[:2]
    s = rng.uniform(min_scale, max_scale)
    cw, ch = max(int(round(w * s)), 1), max(int(round(h * s)), 1)
    x0 = int(rng.integers(min(0, w - cw), max(0, w - cw) + 1))
    y0 = int(rng.integers(min(0, h - ch), max(0, h - ch) + 1))
    return crop_sample(sample, x0, y0, cw, ch)


def resize_sample(sample: Sample, width: int, height: int) -> Sample:
    """Resize image and boxes to (width, height); ``scale`` is multiplied accordingly."""
    h, w = sample.image.shape[:2]
    sx, sy = width / w, height / h
    s = np.array([sx, sy, sx, sy], np.float32)
    img = cv2.resize(sample.image, (width, height), interpolation=cv2.INTER_AREA)
    return replace(
        sample,
        image=img,
        boxes=sample.boxes * s,
        dontcare=sample.dontcare * s,
        scale=(sample.scale[0] * sx, sample.scale[1] * sy),
    )


def colour_jitter(image: np.ndarray, rng: np.random.Generator, strength: float = 0.3) -> np.ndarray:
    """Random saturation, contrast, brightness, per-channel gain (white balance) and gamma
    (uint8 RGB in, uint8 out). The linear part is one 3x4 colour matrix, the gamma a lookup
    table."""
    s = rng.uniform(1 - strength, 1 + strength)  # saturation: towards/away from the pixel's grey
    c = rng.uniform(1 - strength, 1 + strength)  # contrast around the image mean
    k = rng.uniform(1 - strength, 1 + strength)  # brightness (exposure)
    gain = k * rng.uniform(1 - strength / 3, 1 + strength / 3, size=3)  # white balance
    gamma = rng.uniform(0.7, 1.4)
    sat = s * np.eye(3) + (1 - s) / 3.0 * np.ones((3, 3))
    mean = float(np.mean(cv2.mean(image)[:3]))
    m = np.empty((3, 4))
    m[:, :3] = gain[:, None] * c * sat
    m[:, 3] = gain * (1 - c) * mean
    out = cv2.transform(image, m)
    lut = np.clip(255.0 * (np.arange(256) / 255.0) ** gamma + 0.5, 0, 255).astype(np.uint8)
    return cv2.LUT(out, lut)


def blur(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Gaussian blur (sigma 0.5-1.2 px) or horizontal/diagonal motion blur (3-7 px)."""
    if rng.random() < 0.5:
        return cv2.GaussianBlur(image, (0, 0), rng.uniform(0.5, 1.2))
    n = int(rng.integers(3, 8))
    k = np.zeros((n, n), np.float32)
    if rng.random() < 0.7:
        k[n // 2, :] = 1.0
    else:
        np.fill_diagonal(k, 1.0)
    return cv2.filter2D(image, -1, k / k.sum())


def add_noise(image: np.ndarray, rng: np.random.Generator, max_sigma: float = 8.0) -> np.ndarray:
    """Gaussian sensor noise with a random standard deviation up to ``max_sigma`` grey levels."""
    cv2.setRNGSeed(int(rng.integers(2**31)))
    noise = np.empty(image.shape, np.int16)
    cv2.randn(noise, 0.0, float(rng.uniform(1.0, max_sigma)))
    return cv2.add(image.astype(np.int16), noise).clip(0, 255).astype(np.uint8)


def photometric(
    sample: Sample, rng: np.random.Generator, p_blur: float = 0.25, p_noise: float = 0.3
) -> Sample:
    """Colour jitter always; blur and noise with the given probabilities. Boxes unchanged."""
    img = colour_jitter(sample.image, rng)
    if rng.random() < p_blur:
        img = blur(img, rng)
    if rng.random() < p_noise:
        img = add_noise(img, rng)
    return replace(sample, image=img)


# ----------------------------------------------------------------------------- copy-paste


@dataclass
class RowSizeModel:
    """Plausible car box height for its bottom row on a flat road: h = slope * (y2 - horizon),
    fitted on real boxes; ``spread`` = std of log(h / fitted h)."""

    slope: float
    horizon: float
    spread: float
    y2_range: tuple[float, float]

    @classmethod
    def fit(cls, boxes: np.ndarray) -> RowSizeModel:
        """Least squares h = a * y2 + b on (N, 4) boxes (N >= 2, bottom rows spread >= 1 px)."""
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
        y2, h = boxes[:, 3], boxes[:, 3] - boxes[:, 1]
        if len(boxes) < 2 or np.ptp(y2) < 1.0:
            raise ValueError("RowSizeModel.fit: need boxes at 2 or more distinct bottom rows")
        a, b = np.polyfit(y2, h, 1)
        a = max(a, 1e-3)
        horizon = -b / a
        pred = np.maximum(a * (y2 - horizon), 1.0)
        spread = float(np.std(np.log(np.maximum(h, 1.0) / pred)))
        return cls(float(a), float(horizon), spread, (float(y2.min()), float(y2.max())))

    def height(self, y2: float) -> float:
        return self.slope * (y2 - self.horizon)


@dataclass
class CarCrop:
    """A fully visible car cut from a real frame: its pixels, orientation bin and angle, and
    where it was seen (its :attr:`~detector_node.dataset.Sample.view` in its frame)."""

    patch: np.ndarray
    bin: int
    alpha: float = float("nan")
    view: tuple[float, float] = (0.5, 0.5)


def collect_car_crops(samples: list[Sample], min_height: float = 25.0) -> list[CarCrop]:
    """Cars worth pasting: not truncated, not occluded (``occluded`` flags in ``sample.occluded``
    when known), at least ``min_height`` px tall, not overlapping any other labelled box or
    DontCare region, known orientation."""
    crops = []
    for s in samples:
        if not len(s.boxes):
            continue
        others = np.concatenate([s.boxes, s.dontcare]) if len(s.dontcare) else s.boxes
        ov = overlap_over_first(s.boxes, others)
        trunc = _truncation(s)
        occl = s.occluded if s.occluded is not None else np.zeros(len(s.boxes), np.int64)
        for i, b in enumerate(s.boxes):
            ov[i, i] = 0.0
            x1, y1, x2, y2 = (int(round(v)) for v in b)
            if (
                s.bins[i] < 0
                or trunc[i] > 0.05
                or occl[i] > 0
                or y2 - y1 < min_height
                or ov[i].max() > 0.0
                or x1 < 0
                or y1 < 0
                or x2 > s.image.shape[1]
                or y2 > s.image.shape[0]
            ):
                continue
            alpha = float(sample_alphas(s)[i])
            view = tuple(float(v) for v in sample_view(s)[i])
            crops.append(CarCrop(s.image[y1:y2, x1:x2].copy(), int(s.bins[i]), alpha, view))
    return crops


def _feathered_mask(h: int, w: int, border: int) -> np.ndarray:
    """(h, w, 1) float mask: 1 inside, ramping to 0 over ``border`` px at the edges."""
    yy = np.minimum(np.arange(h), np.arange(h)[::-1])[:, None]
    xx = np.minimum(np.arange(w), np.arange(w)[::-1])[None, :]
    m = np.clip((np.minimum(yy, xx) + 0.5) / max(border, 1), 0.0, 1.0)
    return m[..., None].astype(np.float32)


def paste_cars(
    sample: Sample,
    crops: list[CarCrop],
    rows: RowSizeModel,
    rng: np.random.Generator,
    count: int,
    tries: int = 10,
) -> Sample:
    """Paste up to ``count`` random car crops (randomly mirrored) onto the frame: bottom row y2
    uniform in the rows seen in real labels, height from ``rows`` (with its spread), x uniform,
    not touching any existing box, DontCare region or earlier paste. Pasted cars are positives
    with truncation 0 and their crop's (mirrored) orientation bin, angle and view (where the car
    was seen: its angle belongs to that viewing ray, not to the place it is pasted at)."""
    if not crops or count <= 0:
        return sample
    img = sample.image.copy()
    H, W = img.shape[:2]
    boxes, bins, alphas = [sample.boxes.reshape(-1, 4)], [sample.bins], [sample_alphas(sample)]
    views = [sample_view(sample)]
    occupied = np.concatenate([sample.boxes.reshape(-1, 4), sample.dontcare.reshape(-1, 4)])
    added = 0
    for _ in range(count * tries):
        if added == count:
            break
        crop = crops[int(rng.integers(len(crops)))]
        y2 = rng.uniform(*rows.y2_range)
        h = rows.height(y2) * float(np.exp(rng.normal(0.0, rows.spread)))
        ph, pw = crop.patch.shape[:2]
        w = h * pw / ph
        if h < 12 or w >= W or y2 - h < 0 or y2 > H:
            continue
        x1 = rng.uniform(0, W - w)
        box = np.array([[x1, y2 - h, x1 + w, y2]], np.float32)
        if len(occupied) and overlap_over_first(box, occupied).max() > 0.0:
            continue
        bx = np.round(box[0]).astype(int)
        bw, bh = bx[2] - bx[0], bx[3] - bx[1]
        if bw < 4 or bh < 4:
            continue
        patch, obin, alpha, view = crop.patch, crop.bin, crop.alpha, crop.view
        if rng.random() < 0.5:
            patch, obin, alpha = patch[:, ::-1], flip_bin(obin), flip_alpha(alpha)
            view = (1.0 - view[0], view[1])
        patch = cv2.resize(np.ascontiguousarray(patch), (bw, bh), interpolation=cv2.INTER_AREA)
        mask = _feathered_mask(bh, bw, max(1, min(bw, bh) // 12))
        region = img[bx[1] : bx[3], bx[0] : bx[2]].astype(np.float32)
        img[bx[1] : bx[3], bx[0] : bx[2]] = (mask * patch + (1 - mask) * region).astype(np.uint8)
        box = bx[None].astype(np.float32)
        boxes.append(box)
        bins.append(np.array([obin], np.int64))
        alphas.append(np.array([alpha], np.float32))
        views.append(np.array([view], np.float32))
        occupied = np.concatenate([occupied, box])
        added += 1
    if not added:
        return sample
    n_new = sum(len(b) for b in boxes[1:])
    return replace(
        sample,
        image=img,
        boxes=np.concatenate(boxes).astype(np.float32),
        bins=np.concatenate(bins),
        alphas=np.concatenate(alphas).astype(np.float32),
        view=np.concatenate(views).astype(np.float32),
        truncation=np.concatenate([_truncation(sample), np.zeros(n_new, np.float32)]),
        occluded=None
        if sample.occluded is None
        else np.concatenate([sample.occluded, np.zeros(n_new, np.int64)]),
    )


def paste_native_crop(background: Sample, crop: Sample, x0: int, y0: int) -> Sample:
    """Paste a native-resolution crop with incomplete labels (object_crops352: Car only) into a
    full real frame at (x0, y0). The crop's labelled cars become positives; the whole crop area
    becomes an ignore region for the background term (its unlabelled vans, trucks and DontCare
    areas must not be taught as background); the background's objects touching the crop area
    become ignore regions too."""
    img = background.image.copy()
    H, W = img.shape[:2]
    ch, cw = crop.image.shape[:2]
    x0, y0 = min(max(x0, 0), W - cw), min(max(y0, 0), H - ch)
    img[y0 : y0 + ch, x0 : x0 + cw] = crop.image
    region = np.array([[x0, y0, x0 + cw, y0 + ch]], np.float32)
    touch = overlap_over_first(background.boxes.reshape(-1, 4), region).reshape(-1) > 0
    cboxes = crop.boxes.reshape(-1, 4) + np.array([x0, y0, x0, y0], np.float32)
    return replace(
        background,
        image=img,
        boxes=np.concatenate([background.boxes[~touch], cboxes]).astype(np.float32),
        bins=np.concatenate([background.bins[~touch], crop.bins]),
        alphas=np.concatenate([sample_alphas(background)[~touch], sample_alphas(crop)]),
        view=np.concatenate([sample_view(background)[~touch], box_view(cboxes, W, H)]),
        truncation=np.concatenate([_truncation(background)[~touch], _truncation(crop)]),
        occluded=None,
        dontcare=np.concatenate(
            [background.dontcare.reshape(-1, 4), background.boxes[touch], region]
        ).astype(np.float32),
        name=f"{background.name}+{crop.name}",
    )
