"""Issue #39 item 3: the stereo node's CPU cuts give bit-identical outputs. Each cut is
checked against the code it replaced (kept here as the reference): on synthetic images, and
on real 0005's 16 frames through the whole frame path (3D positions, covariances, checks and
camera motions compared with ==)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from stereo_depth_node.parameters import stereo_config_from_values
from stereo_depth_node.pipeline import StereoPipeline
from stereo_depth_node.visual_odometry import OdometryParams, _exclusion_rects, _scaled
from vehicle_common.kitti import TrackingSequence

from stereo_depth_node import offline, region_matching, visual_odometry


def loop_shift_costs(gl, gr, mask, x0, shifts):
    """The refinement's costs as computed before: one remap per shift."""
    h, w = mask.shape
    xs = np.arange(x0, x0 + w, dtype=np.float32)
    base_x = np.broadcast_to(xs[None, :], mask.shape)
    map_y = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], mask.shape).astype(np.float32)
    costs = []
    for s in shifts:
        map_x = (base_x - np.float32(s)).astype(np.float32)
        warped = cv2.remap(gr, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        costs.append(np.mean(np.abs(gl - warped)[mask]))
    return np.array(costs)


def full_size_corner_mask(disparity, boxes, p: OdometryParams):
    """The corner mask as built before: at full resolution, then resized (nearest)."""
    valid = np.isfinite(disparity) & (disparity >= p.min_disparity)
    mask = np.full(disparity.shape, 255, np.uint8)
    for c1, r1, c2, r2 in _exclusion_rects(disparity.shape, boxes, p.box_margin):
        mask[r1:r2, c1:c2] = 0
    mask[~valid] = 0
    return _scaled(mask, p, cv2.INTER_NEAREST)


def _textured(h, w, seed):
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (h, w), dtype=np.uint8), (5, 5), 0)


@pytest.mark.parametrize("seed", range(4))
def test_shift_costs_equal_one_remap_per_shift(seed):
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(5, 90)), int(rng.integers(5, 200))
    gl = rng.normal(0, 40, (h, w)).astype(np.float32)
    gr = rng.normal(0, 40, (h, w + 37)).astype(np.float32)
    mask = rng.random((h, w)) < 0.6
    shifts = rng.uniform(3, 30) + np.arange(-1.5, 1.5 + 1e-9, 0.25)
    got = region_matching._shift_costs(gl, gr, mask, 29, shifts)
    want = loop_shift_costs(gl, gr, mask, 29, shifts)
    assert got.dtype == want.dtype and np.array_equal(got, want)


@pytest.mark.parametrize(
    "shape,scale", [((375, 1242), 0.5), ((370, 1224), 0.5), ((101, 77), 0.37), ((50, 60), 1.0)]
)
def test_scaled_corner_mask_equals_the_resized_full_mask(shape, scale):
    rng = np.random.default_rng(shape[0])
    disparity = rng.uniform(-1.0, 60.0, shape).astype(np.float32)
    disparity[rng.random(shape) < 0.01] = np.nan
    h, w = shape
    boxes = [(-5.0, 3.3, 40.2, 30.9), (w * 0.5, h * 0.4, w + 9.0, h - 0.5), (10.0, 10.0, 10.5, 11)]
    p = OdometryParams(scale=scale)
    got = visual_odometry._scaled_corner_mask(disparity, boxes, p)
    want = full_size_corner_mask(disparity, boxes, p)
    assert got.dtype == want.dtype and np.array_equal(got, want)


def _frame_path(seq, frames, boxes_of):
    """Every output of the frame path on ``frames``: kept detections (index, position,
    covariance, disparity, plausibility) and camera motions."""
    pipeline = StereoPipeline.from_config(stereo_config_from_values({}))
    out = []
    for frame in frames:
        left, right = seq.read_stereo(frame)
        if pipeline.settings is None:
            pipeline.camera_from_projections(left, seq.calib.P2, seq.calib.P3)
        boxes = boxes_of(frame)
        geometry, settings = pipeline.camera()
        params = pipeline.disparity_params_for(left.shape[0], settings)
        r = pipeline.process(frame * offline.FRAME_NS, left, right, geometry, params, boxes)
        for i, rr, c, score in r.kept:
            out.append((frame, i, rr.position.tobytes(), rr.covariance.tobytes(), rr.disparity))
            out.append((c.plausibility, c.measures.height, c.measures.bottom_height, score))
        m = r.motion
        out.append(None if m is None else (m.rotation.tobytes(), m.translation.tobytes(), m.dt))
        pipeline.frame_done(boxes.boxes)
    return out


def test_real_0005_outputs_are_bit_identical_to_the_replaced_code(kitti_tracking_root, monkeypatch):
    """The labels' boxes on 0005's 16 stereo frames: the same 3D detections, checks and camera
    motions, to the bit, with the cuts as with the code they replaced."""
    seq = TrackingSequence.open(kitti_tracking_root, "0005")

    def boxes_of(frame):
        return offline.oracle_boxes(seq, frame, ("Car", "Van"))

    new = _frame_path(seq, seq.frame_ids, boxes_of)
    monkeypatch.setattr(region_matching, "_shift_costs", loop_shift_costs)
    monkeypatch.setattr(visual_odometry, "_scaled_corner_mask", full_size_corner_mask)
    old = _frame_path(seq, seq.frame_ids, boxes_of)
    assert sum(x is not None and len(x) == 5 for x in new) >= 40  # ranged boxes
    assert sum(x is not None and len(x) == 3 for x in new) >= 14  # motions
    assert new == old
