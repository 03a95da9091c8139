"""The road plane's map (``road_map``): "shared" fits the plane to the odometry's scene map
and computes no map of its own; "own" computes its half-resolution map (issue #39 item 3)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from plausibility_scenes import CAMERA_HEIGHT, GEO, H, Road, W, render
from stereo_depth_node.parameters import stereo_config_from_values
from stereo_depth_node.pipeline import FrameBoxes, StereoPipeline

from stereo_depth_node import pipeline as pipeline_module

P_LEFT = np.array([[GEO.fx, 0, GEO.cx, 0], [0, GEO.fy, GEO.cy, 0], [0, 0, 1, 0]])
P_RIGHT = P_LEFT - np.array([[0, 0, 0, GEO.fx * GEO.baseline], [0] * 4, [0] * 4])[:3]


def road_pair() -> tuple[np.ndarray, np.ndarray]:
    """An RGB stereo pair of a textured level road CAMERA_HEIGHT below the camera (the sky:
    far, 1 px of disparity): the right image is the left one shifted by the road's
    disparity (``plausibility_scenes.render``)."""
    disparity = render(Road(), [])
    disparity = np.where(disparity > 0, disparity, 1.0).astype(np.float32)
    rng = np.random.default_rng(3)
    texture = rng.integers(0, 256, (H // 2, W // 2), dtype=np.uint8)
    left = cv2.GaussianBlur(cv2.resize(texture, (W, H), interpolation=cv2.INTER_CUBIC), (3, 3), 0)
    u = np.arange(W, dtype=np.float32)[None, :] + disparity
    v = np.repeat(np.arange(H, dtype=np.float32)[:, None], W, axis=1)
    # right pixel (u - d, v) sees left pixel (u, v): sample the left image at u + d
    right = cv2.remap(left, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return (np.dstack([left] * 3), np.dstack([right] * 3))


def process_road_pair(pipe: StereoPipeline) -> None:
    """One frame of :func:`road_pair` with one box through ``pipe`` (its camera from the
    pair's projections)."""
    left, right = road_pair()
    pipe.camera_from_projections(left, P_LEFT, P_RIGHT)
    geometry, settings = pipe.camera()
    params = pipe.disparity_params_for(H, settings)
    boxes = FrameBoxes([(500.0, 150.0, 600.0, 200.0)], [0], [np.nan], [-1.0], [0.9], ["0"])
    pipe.process(1, left, right, geometry, params, boxes)


@pytest.mark.parametrize("road_map, own_maps", [("shared", 0), ("own", 1)])
def test_road_plane_on_the_shared_map_fits_a_synthetic_road(monkeypatch, road_map, own_maps):
    calls = []
    own = pipeline_module.coarse_disparity
    monkeypatch.setattr(
        pipeline_module, "coarse_disparity", lambda *a, **k: calls.append(1) or own(*a, **k)
    )
    pipe = StereoPipeline.from_config(stereo_config_from_values({"road_map": road_map}))
    process_road_pair(pipe)
    assert len(calls) == own_maps
    plane = pipe.ground._last
    assert plane is not None and plane.source == "fit"
    assert abs(plane.offset - CAMERA_HEIGHT) < 0.05
    assert abs(plane.pitch_deg) < 0.5 and abs(plane.roll_deg) < 0.5


def test_the_road_map_starts_before_the_scene_map_and_the_odometry(monkeypatch):
    """With ``road_map: own`` the helper thread takes the road plane's map first (it needs only
    the pair, and the check waits for it), before the scene map is computed and the odometry,
    which waits for that map, is queued behind it: the order of the frame's critical path
    (docs/ARCHITECTURE.md, "A frame's path"). The serial executor runs each job when it is
    submitted, so the calls' order is the submission order."""
    calls = []
    for name in ("coarse_disparity", "block_matching_maps"):
        real = getattr(pipeline_module, name)
        monkeypatch.setattr(
            pipeline_module, name, lambda *a, _n=name, _r=real, **k: calls.append(_n) or _r(*a, **k)
        )
    points = []
    pipe = StereoPipeline.from_config(
        stereo_config_from_values({"road_map": "own"}),
        trace=lambda point, stamp: points.append(point),
    )
    process_road_pair(pipe)
    assert calls == ["coarse_disparity", "block_matching_maps"]
    assert points.index("road_end") < points.index("scene_start")
    if "odometry_start" in points:
        assert points.index("scene_end") < points.index("odometry_start")
