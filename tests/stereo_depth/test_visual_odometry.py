"""Stereo visual odometry (stereo_depth_node.visual_odometry) against exact ego-motion: the
synthetic generator's ego car drives straight along +z at a known speed, and real KITTI 0005
(when ../shared is present) against the labelled motion of its parked cars."""

import cv2
import numpy as np
import pytest
from kitti_player_node.synthetic import build_renderer, render_stereo_frame
from kitti_player_node.synthetic_scene import FRAME_DT
from stereo_depth_node.disparity import compute_disparity
from stereo_depth_node.region_matching import to_gray
from stereo_depth_node.reprojection import StereoGeometry
from stereo_depth_node.visual_odometry import (
    FrameToFrameOdometry,
    OdometryParams,
    estimate_camera_motion,
)
from vehicle_common.camera_motion import CameraMotion


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(R)[0])))


@pytest.fixture(scope="module")
def synthetic_pair():
    r = build_renderer(sequence="0002", frames=10)  # ego car at 10.9 m/s
    frames = [render_stereo_frame(r, k, "0002") for k in (3, 4)]
    g = StereoGeometry.from_projections(r.calib.P2, r.calib.P3)
    d = compute_disparity(frames[0][0], frames[0][1])
    boxes = [o.bbox for o in frames[0][2] if o.type != "DontCare"]
    return r.scene.ego_speed, g, to_gray(frames[0][0]), d, to_gray(frames[1][0]), boxes


def test_odometry_recovers_the_synthetic_ego_motion(synthetic_pair):
    speed, g, gray0, d0, gray1, boxes = synthetic_pair
    m = estimate_camera_motion(gray0, d0, gray1, g, boxes)
    assert m is not None and m.inliers >= 30
    expected = np.array([0.0, 0.0, -speed * FRAME_DT])  # the scene moves toward the camera
    assert np.linalg.norm(m.translation - expected) < 0.05 * speed * FRAME_DT + 0.02
    assert _angle_deg(m.rotation) < 0.2


def test_a_static_camera_gives_no_motion(synthetic_pair):
    _, g, gray0, d0, _, boxes = synthetic_pair
    m = estimate_camera_motion(gray0, d0, gray0, g, boxes)
    assert m is not None
    assert np.linalg.norm(m.translation) < 0.01 and _angle_deg(m.rotation) < 0.01


def test_no_estimate_without_texture_or_depth(synthetic_pair):
    _, g, gray0, d0, gray1, _ = synthetic_pair
    flat = np.full_like(gray0, 128)
    assert estimate_camera_motion(flat, d0, flat, g) is None
    no_depth = np.full_like(d0, -1.0)
    assert estimate_camera_motion(gray0, no_depth, gray1, g) is None
    whole = [(0, 0, gray0.shape[1], gray0.shape[0])]  # every corner inside a vehicle box
    assert estimate_camera_motion(gray0, d0, gray1, g, whole) is None


def test_bad_input_is_a_clear_error(synthetic_pair):
    _, g, gray0, d0, gray1, _ = synthetic_pair
    with pytest.raises(ValueError, match="sizes differ"):
        estimate_camera_motion(gray0, d0[:-1], gray1, g)
    with pytest.raises(ValueError, match="scale"):
        estimate_camera_motion(gray0, d0, gray1, g, params=OdometryParams(scale=0.0))


def test_frame_to_frame_odometry_chains_frames_and_restarts_after_a_lost_one(synthetic_pair):
    speed, g, gray0, d0, gray1, boxes = synthetic_pair
    d1 = d0  # the later frame's map only serves as the next reference
    odo = FrameToFrameOdometry()
    assert odo.step(0, gray0, d0, g) is None  # no earlier frame
    m = odo.step(100_000_000, gray1, d1, g, boxes)  # the earlier frame's vehicle boxes
    assert m is not None and m.dt == pytest.approx(0.1)
    assert m.translation[2] == pytest.approx(-speed * FRAME_DT, rel=0.05)
    assert odo.step(100_000_000, gray1, d1, g) is None  # stamp not after the reference's
    odo.reset()  # a lost frame
    assert odo.step(300_000_000, gray1, d1, g) is None
    assert odo.step(400_000_000, gray0[:-2], d0[:-2], g) is None  # size changed


def test_begin_moves_the_reference_before_the_estimate_runs(synthetic_pair):
    """The stereo node starts a pair's odometry once its disparity map is done and goes on
    with the next pair meanwhile: ``begin`` makes the pair the reference at once, and its
    deferred estimate gives what ``step`` gives (against the reference before it)."""
    _, g, gray0, d0, gray1, boxes = synthetic_pair
    stepped, begun = FrameToFrameOdometry(), FrameToFrameOdometry()
    stepped.step(0, gray0, d0, g)
    want = stepped.step(100_000_000, gray1, d0, g, boxes)
    assert begun.begin(0, gray0, d0)(g) is None  # no earlier frame
    job = begun.begin(100_000_000, gray1, d0)
    # the next frame (same image again) already measures against the begun one
    assert begun.estimate(200_000_000, gray1, g).translation == pytest.approx(0.0, abs=0.01)
    got = job(g, boxes)  # later, e.g. in the odometry thread
    assert got is not None and got.dt == pytest.approx(0.1)
    np.testing.assert_array_equal(got.translation, want.translation)
    np.testing.assert_array_equal(got.rotation, want.rotation)


def test_corners_prepared_ahead_give_the_same_motion(synthetic_pair):
    """The stereo node finds the reference's corners after publishing its 3D array (idle
    time); the next estimate uses them only when they are of its reference and boxes."""
    _, g, gray0, d0, gray1, boxes = synthetic_pair
    want = estimate_camera_motion(gray0, d0, gray1, g, boxes)
    odo = FrameToFrameOdometry()
    odo.begin(0, gray0, d0)
    odo.prepare(boxes)()
    prepared = odo._prepared[1]
    assert prepared.exclude_boxes == tuple(tuple(b) for b in boxes)
    assert prepared.corners is not None and len(prepared.corners) >= 30
    got = odo.begin(100_000_000, gray1, d0)(g, boxes)
    np.testing.assert_array_equal(got.translation, want.translation)
    # prepared with other boxes: not used (the estimate finds its own corners)
    other = FrameToFrameOdometry()
    other.begin(0, gray0, d0)
    other.prepare([])()
    wrong = estimate_camera_motion(gray0, d0, gray1, g, boxes, reference=other._prepared[1])
    assert not np.array_equal(wrong.translation, want.translation)  # they would show
    got = other.begin(100_000_000, gray1, d0)(g, boxes)
    np.testing.assert_array_equal(got.translation, want.translation)
    # the prepared corners are the ones the estimate would find
    fresh = estimate_camera_motion(gray0, d0, gray1, g, boxes, reference=prepared)
    np.testing.assert_array_equal(fresh.translation, want.translation)


def test_static_point_velocity():
    m = CameraMotion(np.eye(3), np.array([0.0, 0.0, -1.5]), dt=0.1)
    v = m.static_point_velocity(np.array([[2.0, 1.0, 30.0], [-5.0, 1.0, 10.0]]))
    assert np.allclose(v, [[0, 0, -15.0]] * 2)
    yaw = cv2.Rodrigues(np.array([0.0, 0.1, 0.0]))[0]  # turning: points sweep sideways
    v = CameraMotion(yaw, np.zeros(3), dt=0.1).static_point_velocity(np.array([[0.0, 0, 20.0]]))
    assert v[0, 0] == pytest.approx(20.0 * np.sin(0.1) / 0.1, rel=1e-6)
    with pytest.raises(ValueError, match="dt"):
        CameraMotion(np.eye(3), np.zeros(3)).static_point_velocity(np.zeros((1, 3)))


def test_real_kitti_odometry_matches_the_parked_cars(kitti_tracking_root):
    """0005: the labelled parked cars approach 1.75 m per frame; odometry with the ranging's
    KITTI disparity-bias model is within 6 % of it and turns less than 0.3 degrees."""
    from stereo_depth_node.ranging import RangingParams, disparity_bias_at
    from vehicle_common.kitti import read_calib, read_png, read_tracking_labels

    KITTI = kitti_tracking_root

    cal = read_calib(KITTI / "calib" / "0005.txt")
    g = StereoGeometry.from_projections(cal.P2, cal.P3)
    labels = read_tracking_labels(KITTI / "label_02" / "0005.txt")
    parked = [0, 1]  # track ids of the two parked cars

    def z(frame, tid):
        return next(o.location[2] for o in labels[frame] if o.track_id == tid)

    img = [read_png(KITTI / f"image_0{c}" / "0005" / "000002.png") for c in (2, 3)]
    nxt = read_png(KITTI / "image_02" / "0005" / "000003.png")
    d = compute_disparity(img[0], img[1])
    bias = disparity_bias_at(np.arange(d.shape[1]), g, RangingParams())
    boxes = [o.bbox for o in labels[2] if o.type != "DontCare"]
    m = estimate_camera_motion(to_gray(img[0]), d, to_gray(nxt), g, boxes, disparity_bias=bias)
    assert m is not None
    step = np.mean([z(3, t) - z(2, t) for t in parked])
    assert m.translation[2] == pytest.approx(step, rel=0.06)
    assert _angle_deg(m.rotation) < 0.3


def test_each_image_is_scaled_once_for_its_tracking_and_its_corners(synthetic_pair, monkeypatch):
    """Issue #39 item 3: the later image scaled for the tracking is the next reference's
    image for its corners (found ahead), not scaled again; the motions are unchanged."""
    from stereo_depth_node import visual_odometry

    _, g, gray0, d0, gray1, boxes = synthetic_pair
    want = [estimate_camera_motion(a, d0, b, g, boxes) for a, b in ((gray0, gray1), (gray1, gray0))]
    scaled = []
    real = visual_odometry._scaled
    monkeypatch.setattr(
        visual_odometry,
        "_scaled",
        lambda img, p, *a: scaled.append(img is gray0 or img is gray1) or real(img, p, *a),
    )
    odo = FrameToFrameOdometry()
    odo.begin(0, gray0, d0)
    odo.prepare(boxes)()
    got = []
    for k, gray in enumerate((gray1, gray0), start=1):
        got.append(odo.begin(k * 100_000_000, gray, d0)(g, boxes))
        odo.prepare(boxes)()
    for m, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(m.translation, w.translation)
    assert sum(scaled) == 3  # gray0, gray1, gray0 again (a new frame): once each (was 5)
