"""Synthetic KITTI generator: labels agree with the geometry and the rendering."""

from __future__ import annotations

import math

import numpy as np
import pytest
from kitti_player_node.synthetic import build_renderer, generate_sequence, synthetic_calibration
from kitti_player_node.synthetic_render import VEHICLE_ID0, StereoRenderer
from kitti_player_node.synthetic_scene import (
    LANE_EGO,
    LANE_RIGHT,
    Path,
    Scene,
    Vehicle,
    VehicleShape,
    random_scene,
)
from vehicle_common.box3d import project_points, projected_bbox
from vehicle_common.kitti import TrackingSequence, alpha_from_rotation_y, wrap_angle


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    generate_sequence(root, sequence="0001", frames=4, seed=11)
    return TrackingSequence.open(root, "0001")


def test_label_rows_are_consistent_with_3d_boxes(written):
    calib = written.calib
    size = (1242, 375)
    n_checked = 0
    for k in written.frame_ids:
        objs = written.objects(k)
        ids = [o.track_id for o in objs if not o.is_dontcare]
        assert len(ids) == len(set(ids))
        for o in objs:
            x1, y1, x2, y2 = o.bbox
            assert 0 <= x1 < x2 <= 1241 and 0 <= y1 < y2 <= 374
            if o.is_dontcare:
                assert o.track_id == -1
                continue
            n_checked += 1
            assert o.type in ("Car", "Van")
            assert o.location[1] == pytest.approx(1.65)
            expected = projected_bbox(calib.P2, o.dimensions, o.location, o.rotation_y, size)
            np.testing.assert_allclose(o.bbox, expected, atol=1e-3)
            u, v = project_points(calib.P2, o.centre_of_mass[None, :])[0]
            assert x1 <= u <= x2 and y1 <= v <= y2
            alpha = alpha_from_rotation_y(o.rotation_y, o.location[0], o.location[2])
            assert abs(wrap_angle(o.alpha - alpha)) < 1e-5
            assert 0.0 <= o.truncated <= 1.0 and o.occluded in (0, 1, 2)
            assert o.height_px >= 15 and o.location[2] <= 70
    assert n_checked >= 4


def test_labels_match_rendered_pixels():
    r = build_renderer(frames=60, seed=2, vehicles=14)
    seen = 0
    for frame in (0, 30, 59):
        left = r.render(frame, 0)
        for o in r.labels(frame, left):
            if o.is_dontcare:
                continue
            mask = left.ids == VEHICLE_ID0 + o.track_id
            vs, us = np.nonzero(mask)
            assert len(us) >= 12
            # every pixel showing the vehicle lies in its 2D box (pixel centres, 1 px slack)
            x1, y1, x2, y2 = o.bbox
            assert us.min() >= x1 - 1 and us.max() <= x2 + 1
            assert vs.min() >= y1 - 1 and vs.max() <= y2 + 1
            # and the box is tight around the wholly visible ones: horizontally exact (the body
            # spans the whole footprint), vertically up to the cabin / ground-clearance margins
            if len(us) == left.silhouette[o.track_id] and o.truncated == 0:
                assert o.occluded == 0
                assert us.min() <= x1 + 1.5 and us.max() >= x2 - 1.5
                assert vs.max() - vs.min() >= 0.75 * (y2 - y1)
            # depth of the visible pixels within the 3D box's depth range
            z = left.depth[mask]
            h, w, length = o.dimensions
            radius = 0.5 * math.hypot(w, length) + 0.1
            assert z.min() >= o.location[2] - radius and z.max() <= o.location[2] + radius
            seen += 1
    assert seen >= 5


def test_track_ids_follow_the_same_vehicle(written):
    """A track's 3D position moves smoothly (one vehicle, not swapped ids)."""
    pos: dict[int, list[np.ndarray]] = {}
    for k in written.frame_ids:
        for o in written.objects(k):
            if not o.is_dontcare:
                pos.setdefault(o.track_id, []).append(np.asarray(o.location))
    longest = max(len(p) for p in pos.values())
    assert longest >= 3
    for p in pos.values():
        steps = np.linalg.norm(np.diff(np.asarray(p), axis=0), axis=1) if len(p) > 1 else [0]
        assert np.max(steps) < 3.5  # < 35 m/s relative speed at 10 Hz


def _car(track_id, x, z, heading=(0.0, 1.0)):
    return Vehicle(
        track_id=track_id,
        type="Car",
        dimensions=(1.5, 1.7, 4.2),
        colour=(0.6, 0.1, 0.1),
        shape=VehicleShape(0.55, 0.55, -0.05, 0.88),
        path=Path([(x, z), (x + heading[0], z + heading[1])]),
        s0=0.0,
        speed=0.0,
    )


def test_occlusion_levels_from_rendering():
    walls = random_scene(0, 2).walls
    vehicles = [
        _car(0, LANE_EGO, 12.0),  # in front
        _car(1, LANE_EGO + 0.3, 20.0),  # behind car 0, mostly hidden
        _car(2, LANE_RIGHT + 1.5, 30.0),  # alone on the right
    ]
    scene = Scene(frames=2, seed=0, ego_speed=0.0, junction_z=500.0, vehicles=vehicles)
    scene.walls = walls
    r = StereoRenderer(scene, synthetic_calibration(), 1242, 375)
    left = r.render(0, 0)
    labels = {o.track_id: o for o in r.labels(0, left)}
    assert labels[0].occluded == 0
    assert labels[1].occluded >= 1
    assert labels[2].occluded == 0
    assert labels[0].truncated == 0.0
    # the hidden car's visible pixels are fewer than its silhouette
    vis = int((left.ids == VEHICLE_ID0 + 1).sum())
    assert vis < 0.8 * left.silhouette[1]


def test_truncated_and_offscreen_vehicles():
    vehicles = [
        _car(0, -4.5, 4.5),  # close on the left: cut by the image border
        _car(1, 0.0, -10.0),  # behind the camera: no label
        _car(2, 60.0, 20.0),  # far outside the field of view: no label
    ]
    scene = Scene(frames=1, seed=0, ego_speed=0.0, junction_z=500.0, vehicles=vehicles)
    r = StereoRenderer(scene, synthetic_calibration(), 1242, 375)
    rows = r.labels(0, r.render(0, 0))
    assert [o.track_id for o in rows if not o.is_dontcare] in ([0], [])
    cut = [o for o in rows if o.track_id == 0]
    if cut:
        assert cut[0].truncated > 0.05 and cut[0].bbox[0] == 0.0
    assert all(o.track_id not in (1, 2) for o in rows)
    assert len(rows) == 1  # the cut car is either labelled or a DontCare region


def test_all_orientation_bins_occur():
    """Alpha folded to [0, 180) deg covers the four bins centred on 0/45/90/135 deg."""
    r = build_renderer(frames=100, seed=0, width=621, height=188)
    bins = set()
    for frame in range(0, 100, 3):
        for o in r.labels(frame, r.render(frame, 0)):
            if not o.is_dontcare:
                a = math.degrees(o.alpha) % 180.0
                bins.add(int(((a + 22.5) % 180.0) // 45.0))
    assert bins == {0, 1, 2, 3}
