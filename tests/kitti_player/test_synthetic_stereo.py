"""Synthetic KITTI generator: the right image is the left one shifted by the true disparity."""

from __future__ import annotations

import numpy as np
import pytest
from kitti_player_node.synthetic import build_renderer, render_stereo_frame, to_uint8
from kitti_player_node.synthetic_render import GROUND_ID, VEHICLE_ID0


@pytest.fixture(scope="module")
def stereo():
    r = build_renderer(frames=40, seed=4, vehicles=14)
    frame = 20
    left = r.render(frame, 0)
    right = r.render(frame, 1)
    rng = np.random.default_rng(0)
    gl = to_uint8(left.image, rng).astype(np.float32).mean(axis=2)
    gr = to_uint8(right.image, rng).astype(np.float32).mean(axis=2)
    return r, left, right, gl, gr


def _pixels(mask, rng, n, margin=8, w=1242, h=375):
    vs, us = np.nonzero(mask)
    ok = (us >= margin + 100) & (us < w - margin) & (vs >= margin) & (vs < h - margin)
    vs, us = vs[ok], us[ok]
    pick = rng.choice(len(us), size=min(n, len(us)), replace=False)
    return vs[pick], us[pick]


def test_true_disparity_maps_vehicle_pixels_to_the_same_vehicle(stereo):
    r, left, right, _, _ = stereo
    fx, baseline = r.calib.fx, r.calib.baseline
    vehicle = left.ids >= VEHICLE_ID0
    assert vehicle.sum() > 2000
    vs, us = _pixels(vehicle, np.random.default_rng(1), 400)
    d = fx * baseline / left.depth[vs, us]
    ur = np.rint(us - d).astype(int)
    same = right.ids[vs, ur] == left.ids[vs, us]
    assert same.mean() > 0.9  # the rest are occluded in the right view or on silhouette edges
    # the depth seen by the right camera at the corresponding pixel is the same surface
    dz = np.abs(right.depth[vs, ur] - left.depth[vs, us])[same]
    assert np.median(dz) < 0.05


@pytest.mark.parametrize("surface", ["vehicle", "ground"])
def test_image_content_matches_at_true_disparity(stereo, surface):
    r, left, _, gl, gr = stereo
    fx, baseline = r.calib.fx, r.calib.baseline
    if surface == "vehicle":
        mask = left.ids >= VEHICLE_ID0
    else:
        mask = (left.ids == GROUND_ID) & (left.depth < 25.0)
    vs, us = _pixels(mask, np.random.default_rng(2), 800)
    half, wins, tested = 3, 0, 0
    for v, u in zip(vs, us, strict=True):
        patch = gl[v - half : v + half + 1, u - half : u + half + 1]
        if np.abs(np.diff(patch, axis=1)).mean() < 3.0:  # no horizontal texture: ambiguous
            continue
        z = left.depth[v - half : v + half + 1, u - half : u + half + 1]
        if z.max() - z.min() > 0.05 * z.min():  # straddles a depth edge: half-occluded
            continue
        d_true = fx * baseline / left.depth[v, u]
        costs = {}
        for d in range(0, 100):
            ur = u - d
            if ur - half < 0:
                break
            costs[d] = np.abs(patch - gr[v - half : v + half + 1, ur - half : ur + half + 1]).mean()
        if not costs:
            continue
        tested += 1
        best = min(costs, key=costs.get)
        wins += abs(best - d_true) <= 1.0
    assert tested >= 40
    assert wins / tested > 0.9


def test_render_stereo_frame_is_deterministic():
    r1 = build_renderer(frames=5, seed=9, width=320, height=100)
    r2 = build_renderer(frames=5, seed=9, width=320, height=100)
    a = render_stereo_frame(r1, 3)
    b = render_stereo_frame(r2, 3)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert a[2] == b[2]
