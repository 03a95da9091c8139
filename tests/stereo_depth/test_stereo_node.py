"""In-process test of the stereo_depth node: stamps, one 3D array per 2D array, robustness."""

from __future__ import annotations

import contextlib
import math
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from stereo_depth_node.plausibility import PlausibilityParams  # noqa: E402
from stereo_depth_node.ranging import RangingParams, bin_centre_offsets  # noqa: E402
from vehicle_common.image_conversion import (  # noqa: E402
    camera_info_from_projection,
    numpy_to_image,
)

FX, B, DISP = 700.0, 0.5, 20
H, W = 120, 320


def textured_pair():
    rng = np.random.default_rng(3)
    big = cv2.GaussianBlur(rng.integers(0, 256, (H, W + DISP, 3), dtype=np.uint8), (3, 3), 0)
    return np.ascontiguousarray(big[:, :W]), np.ascontiguousarray(big[:, DISP:])


class Harness:
    def __init__(self, ctx, **params):
        from sensor_msgs.msg import CameraInfo, Image
        from stereo_depth_node.node import StereoDepthNode
        from stereo_msgs.msg import DisparityImage
        from stereo_vehicle_msgs.msg import VehicleDetection2DArray, VehicleDetection3DArray

        # the test scene is one fronto-parallel textured plane, no road: the plausibility
        # check only flags here (tests of the check itself set the action)
        params = {"plausibility_action": "flag", **params}
        overrides = [Parameter("num_disparities", value=48)]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = StereoDepthNode(context=ctx, parameter_overrides=overrides)
        self.io = __import__("rclpy").create_node("stereo_depth_test_io", context=ctx)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.io)
        pub = self.io.create_publisher
        self.pubs = {
            "left": pub(Image, "/stereo/left/image_rect", 5),
            "right": pub(Image, "/stereo/right/image_rect", 5),
            "linfo": pub(CameraInfo, "/stereo/left/camera_info", 5),
            "rinfo": pub(CameraInfo, "/stereo/right/camera_info", 5),
            "det": pub(VehicleDetection2DArray, "/vehicles/detections_2d", 10),
        }
        self.det3d, self.disp = [], []
        self.io.create_subscription(
            VehicleDetection3DArray, "/vehicles/detections_3d", self.det3d.append, 10
        )
        self.io.create_subscription(DisparityImage, "/stereo/disparity", self.disp.append, 5)
        self.spin_until(
            lambda: (
                all(p.get_subscription_count() > 0 for p in self.pubs.values())
                and self.io.count_publishers("/vehicles/detections_3d") > 0
                # the disparity image is built only for a matched subscriber
                and self.node.outputs.disparity.get_subscription_count() > 0
            )
        )
        K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1]])
        self.infos = (
            camera_info_from_projection(np.hstack([K, np.zeros((3, 1))]), W, H),
            camera_info_from_projection(np.hstack([K, [[-FX * B], [0], [0]]]), W, H),
        )
        self.left, self.right = textured_pair()

    def spin_until(self, cond, timeout=10.0):
        """Spin until ``cond()``, checked when the node's worker thread has settled (what it
        received is processed: its counters and outputs are complete)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.node.worker.wait_idle(1.0)
            if cond():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return cond()

    def header(self, sec):
        from std_msgs.msg import Header

        h = Header(frame_id="left_camera_optical_frame")
        h.stamp.sec, h.stamp.nanosec = sec, 500
        return h

    def send_frame(self, sec, bad_step=False, wait=True):
        hdr = self.header(sec)
        for name, info in zip(("linfo", "rinfo"), self.infos, strict=True):
            info.header = hdr
            self.pubs[name].publish(info)
        if wait:
            self.spin_until(lambda: self.node.left_info is not None, 2.0)
        left = numpy_to_image(self.left, "rgb8", hdr)
        if bad_step:
            left.step = left.step - 3  # inconsistent with width * 3
        self.pubs["left"].publish(left)
        self.pubs["right"].publish(numpy_to_image(self.right, "rgb8", hdr))

    def send_detections(self, sec, boxes):
        from stereo_vehicle_msgs.msg import VehicleDetection2D, VehicleDetection2DArray

        msg = VehicleDetection2DArray(header=self.header(sec))
        for i, (x1, y1, x2, y2) in enumerate(boxes):
            d = VehicleDetection2D(id=str(i), class_id="car", score=0.9, orientation_bin=2)
            d.bbox.center_x, d.bbox.center_y = (x1 + x2) / 2, (y1 + y2) / 2
            d.bbox.size_x, d.bbox.size_y = float(x2 - x1), float(y2 - y1)
            d.orientation_probs = [0.1, 0.1, 0.7, 0.1]
            msg.detections.append(d)
        self.pubs["det"].publish(msg)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.io.destroy_node()


@pytest.fixture
def harness(rclpy_context):
    # synthetic pair shifted by an exact integer disparity: no real-camera bias to correct; the
    # centre stays on the box-centre ray (lateral_fit is tested in test_stereo_centre_fit.py)
    h = Harness(
        rclpy_context,
        sync_cache_size=3,
        disparity_bias=0.0,
        disparity_bias_column=0.0,
        lateral_fit=False,
    )
    yield h
    h.close()


def test_publishes_one_3d_detection_per_rangeable_2d_detection(harness):
    harness.send_frame(7)
    harness.send_detections(7, [(150, 30, 250, 90), (400, 30, 450, 90)])  # 2nd is off-image
    assert harness.spin_until(lambda: harness.det3d and harness.disp)
    arr = harness.det3d[0]
    assert (arr.header.stamp.sec, arr.header.stamp.nanosec) == (7, 500)
    assert arr.header.frame_id == "left_camera_optical_frame"
    assert harness.node.frames_failed == 0
    assert [d.id for d in arr.detections] == ["0"]
    det = arr.detections[0]
    z = FX * B / DISP  # 17.5 m to the visible surface
    # centre correction (default): bin 2 (rear view) moves the point l/2 = 1.95 m along the ray
    p = np.array([det.position.x, det.position.y, det.position.z])
    ray = p / p[2]
    offset = bin_centre_offsets(RangingParams().car_length, RangingParams().car_width)[2]
    assert offset == pytest.approx(1.95)
    assert np.linalg.norm(p) == pytest.approx(z * np.linalg.norm(ray) + offset, rel=0.03)
    assert det.position.x == pytest.approx((200 - W / 2) * det.position.z / FX, rel=1e-6)
    assert det.disparity == pytest.approx(DISP, abs=0.5)
    assert det.valid_pixel_fraction > 0.9
    assert (det.class_id, det.score, det.orientation_bin) == ("car", 0.9, 2)
    assert det.bbox.size_x == 100.0
    cov = np.array(det.position_covariance).reshape(3, 3)
    assert np.allclose(cov, cov.T) and cov[2, 2] > 0
    assert harness.node.pipeline.unranged_detections == 1
    disp = harness.disp[0]
    assert disp.header.stamp.sec == 7 and disp.image.encoding == "32FC1"
    assert (disp.f, disp.t) == (FX, pytest.approx(B))
    img = np.frombuffer(bytes(disp.image.data), np.float32).reshape(H, W)
    assert np.median(img[20:-20, 60:-20]) == pytest.approx(DISP, abs=0.5)


def test_malformed_image_is_skipped_and_node_keeps_working(harness):
    harness.send_frame(1, bad_step=True)
    harness.send_detections(1, [(150, 30, 250, 90)])
    assert harness.spin_until(lambda: len(harness.det3d) == 1)
    assert harness.node.frames_failed == 1
    assert harness.det3d[0].header.stamp.sec == 1 and harness.det3d[0].detections == []
    harness.send_frame(2)
    harness.send_detections(2, [(150, 30, 250, 90)])
    assert harness.spin_until(lambda: len(harness.det3d) == 2)
    assert harness.det3d[1].header.stamp.sec == 2 and len(harness.det3d[1].detections) == 1


def test_camera_motion_is_published_from_the_second_frame_and_restarts_after_a_lost_one(harness):
    from vehicle_common.frame_messages import read_transform

    for sec in (1, 2):  # the same images twice: a camera standing still
        harness.send_frame(sec)
        harness.send_detections(sec, [(150, 30, 250, 90)])
        assert harness.spin_until(lambda s=sec: len(harness.det3d) == s)
    first, second = harness.det3d
    assert first.camera_motion_dt == 0.0  # no earlier frame
    assert second.camera_motion_dt == pytest.approx(1.0)
    R, t = read_transform(second.camera_motion)
    assert np.allclose(R, np.eye(3), atol=1e-3) and np.linalg.norm(t) < 0.01
    harness.send_frame(3, bad_step=True)  # lost: the chain restarts
    harness.send_detections(3, [])
    for sec in (3, 4):
        if sec == 4:
            harness.send_frame(4)
            harness.send_detections(4, [])
        assert harness.spin_until(lambda s=sec: len(harness.det3d) == s)
    assert [a.camera_motion_dt for a in harness.det3d[2:]] == [0.0, 0.0]


def test_camera_motion_spans_the_gap_to_the_previous_3d_array(harness):
    """The detector skipped frame 2: the stereo pair of frame 2 arrives, its 2D array never
    does. Frame 3's camera motion must span the 2 s since frame 1, the previous frame the
    tracker got, as the tracker predicts over that gap (before issue #33 the odometry had moved
    on to pair 2 and frame 3 carried 1 s of motion for a 2 s gap)."""
    harness.send_frame(1)
    harness.send_detections(1, [])
    assert harness.spin_until(lambda: len(harness.det3d) == 1)
    harness.send_frame(2)  # no detections for frame 2
    assert harness.spin_until(lambda: len(harness.node.intake.frame_sync) == 1)
    harness.send_frame(3)
    harness.send_detections(3, [])
    assert harness.spin_until(lambda: len(harness.det3d) == 2)
    assert [a.header.stamp.sec for a in harness.det3d] == [1, 3]
    assert harness.det3d[1].camera_motion_dt == pytest.approx(2.0)


def test_visual_odometry_off_publishes_no_camera_motion(rclpy_context):
    h = Harness(rclpy_context, visual_odometry=False, sync_cache_size=3)
    try:
        for sec in (1, 2):
            h.send_frame(sec)
            h.send_detections(sec, [])
            assert h.spin_until(lambda s=sec: len(h.det3d) == s)
        assert [a.camera_motion_dt for a in h.det3d] == [0.0, 0.0]
    finally:
        h.close()


def test_detections_whose_images_never_arrive_are_dropped_and_counted(harness):
    harness.send_detections(50, [(150, 30, 250, 90)])  # stereo frame 50 never comes
    assert harness.spin_until(lambda: len(harness.node.intake.frame_sync) == 1)
    for sec in (51, 52, 53):  # images without detections fill the cache (size 3)
        harness.send_frame(sec)
        assert harness.spin_until(
            lambda s=sec: len(harness.node.intake.frame_sync) == min(3, s - 49)
        )
    assert harness.spin_until(lambda: harness.node.intake.dropped_detection_arrays == 1)
    assert len(harness.node.intake.frame_sync) == 3
    counts = harness.node.frames.snapshot()
    assert (counts.received, counts.published, counts.dropped) == (1, 0, 1)
    assert harness.det3d == [] and harness.node.pipeline.frames_processed == 0
    harness.send_detections(53, [(150, 30, 250, 90)])  # completes frame 53
    assert harness.spin_until(lambda: len(harness.det3d) == 1)
    assert harness.det3d[0].header.stamp.sec == 53 and len(harness.det3d[0].detections) == 1
    # the older incomplete frames can no longer complete: gone from the cache
    assert len(harness.node.intake.frame_sync) == 0
    counts = harness.node.frames.snapshot()
    assert (counts.received, counts.published, counts.dropped) == (2, 1, 1)


def test_frame_whose_image_is_lost_is_dropped_when_a_newer_one_completes(harness):
    """Right image of frame 60 lost: once frame 61 is complete, frame 60 can never be; it is
    dropped and counted (no 3D array: the tracker gets no frame without its detections), and
    frame 61 is ranged at once (no stall waiting for the cache to overflow)."""
    hdr = harness.header(60)
    for name, info in zip(("linfo", "rinfo"), harness.infos, strict=True):
        info.header = hdr
        harness.pubs[name].publish(info)
    harness.pubs["left"].publish(numpy_to_image(harness.left, "rgb8", hdr))
    harness.send_detections(60, [(150, 30, 250, 90)])
    assert harness.spin_until(lambda: len(harness.node.intake.frame_sync) == 1)
    assert harness.det3d == []
    harness.send_frame(61)
    harness.send_detections(61, [(150, 30, 250, 90)])
    assert harness.spin_until(lambda: len(harness.det3d) == 1)
    assert harness.det3d[0].header.stamp.sec == 61 and len(harness.det3d[0].detections) == 1
    assert harness.node.intake.frame_sync.dropped == {"left": 1, "right": 0, "detections": 1}
    assert harness.node.intake.dropped_detection_arrays == 1
    counts = harness.node.frames.snapshot()
    assert (counts.received, counts.published, counts.dropped) == (2, 1, 1)
    assert harness.node.pipeline.frames_processed == 1 and harness.node.frames_failed == 0
    assert len(harness.node.intake.frame_sync) == 0


def test_newest_complete_frame_is_processed_after_a_burst(harness, monkeypatch):
    """While the node works on frame 1, the pairs of frames 2..6 arrive with the 2D arrays of
    frames 3 and 5 only (the detector skipped the others), all at once. The node then ranges
    frame 5, the newest complete one, and counts frame 3 as dropped: it does no work on the
    pairs without detections nor on the superseded frame. (Before issue #33 the node matched
    the newest PAIR, 6, whose detections never came, and dropped the detections of 3 and 5 with
    their skipped pairs: nothing of the burst was ranged.)"""
    import threading

    import stereo_depth_node.pipeline as stereo_pipeline

    gate, started, done = threading.Event(), threading.Event(), []

    def held(compute):
        def wrapped(*args, **kwargs):
            done.append(1)
            if len(done) == 1:  # frame 1: the node is busy until the burst is in
                started.set()
                gate.wait(10)
            return compute(*args, **kwargs)

        return wrapped

    # the harness subscribes to the disparity image: the node matches the whole band
    monkeypatch.setattr(
        stereo_pipeline, "compute_disparity", held(stereo_pipeline.compute_disparity)
    )
    harness.send_frame(1)
    harness.send_detections(1, [(150, 30, 250, 90)])
    end = time.monotonic() + 10
    while not started.is_set() and time.monotonic() < end:
        harness.executor.spin_once(timeout_sec=0.05)
    assert started.is_set()
    for sec in (2, 3, 4, 5, 6):  # the burst, taken while the worker is busy
        harness.send_frame(sec, wait=False)
        if sec in (3, 5):
            harness.send_detections(sec, [(150, 30, 250, 90)])
    end = time.monotonic() + 10
    while harness.node.frames.snapshot().received < 3 and time.monotonic() < end:
        harness.executor.spin_once(timeout_sec=0.05)
    end = time.monotonic() + 1.0  # the burst's images too
    while time.monotonic() < end:
        harness.executor.spin_once(timeout_sec=0.05)
    gate.set()
    assert harness.spin_until(lambda: len(harness.det3d) == 2)
    assert harness.spin_until(lambda: harness.node.worker.wait_idle(1.0))
    assert [a.header.stamp.sec for a in harness.det3d] == [1, 5]
    assert len(harness.det3d[1].detections) == 1
    assert len(done) == 2  # maps of frames 1 and 5 only
    counts = harness.node.frames.snapshot()
    assert (counts.received, counts.published, counts.dropped) == (3, 2, 1)
    assert harness.node.pipeline.frames_processed == 2
    assert harness.node.intake.frame_sync.pending_stamps() == [6 * 10**9 + 500]


def test_geometry_is_built_once_per_calibration_and_a_bad_one_skips_frames(harness):
    harness.send_frame(1)
    harness.send_detections(1, [(150, 30, 250, 90)])
    assert harness.spin_until(lambda: len(harness.det3d) == 1)
    geometry = harness.node.pipeline.geometry
    assert geometry.fx == FX and geometry.baseline == pytest.approx(B)
    harness.send_frame(2)  # same calibration again: the geometry object is kept
    harness.send_detections(2, [(150, 30, 250, 90)])
    assert harness.spin_until(lambda: len(harness.det3d) == 2)
    assert harness.node.pipeline.geometry is geometry and len(harness.det3d[1].detections) == 1
    K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1]])
    bad_right = camera_info_from_projection(np.hstack([K, np.zeros((3, 1))]), W, H)
    harness.pubs["rinfo"].publish(bad_right)  # zero baseline
    assert harness.spin_until(lambda: harness.node.pipeline.geometry is None)
    harness.infos = (harness.infos[0], bad_right)
    harness.send_frame(3)  # no geometry: the frame is skipped, its output is empty
    harness.send_detections(3, [(150, 30, 250, 90)])
    assert harness.spin_until(lambda: len(harness.det3d) == 3)
    assert harness.node.pipeline.geometry is None and harness.node.frames_failed == 1
    assert harness.det3d[2].header.stamp.sec == 3 and harness.det3d[2].detections == []


def test_parameters_accept_yaml_integers_and_reach_the_core(rclpy_context):
    from stereo_depth_node.node import StereoDepthNode

    node = StereoDepthNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter("p1_factor", value=6),
            Parameter("depth_offset", value=[0, 0, 1, 0]),
            Parameter("ranging_method", value="median"),
            Parameter("downscale", value=1),
        ],
    )
    try:
        assert (
            node.pipeline.disparity_params.p1_factor == 6.0
            and node.pipeline.disparity_params.downscale == 1
        )
        assert node.pipeline.ranging_params.depth_offset == (0.0, 0.0, 1.0, 0.0)
        assert node.pipeline.ranging_params.method == "median"
    finally:
        node.destroy_node()
    with pytest.raises(ValueError):
        StereoDepthNode(context=rclpy_context, parameter_overrides=[Parameter("mode", value="x")])


def test_disparity_image_is_built_only_while_someone_subscribes(rclpy_context, monkeypatch):
    import stereo_depth_node.node as stereo_node

    built = []
    real = stereo_node.disparity_message
    monkeypatch.setattr(
        stereo_node, "disparity_message", lambda *a: built.append(a[-1].stamp.sec) or real(*a)
    )
    h = Harness(rclpy_context)
    try:
        h.send_frame(3)  # the harness subscribes to /stereo/disparity
        h.send_detections(3, [])
        assert h.spin_until(lambda: h.disp) and built == [3]
        h.io.destroy_subscription(
            next(s for s in h.io.subscriptions if s.topic_name == "/stereo/disparity")
        )
        assert h.spin_until(lambda: h.node.outputs.disparity.get_subscription_count() == 0)
        h.send_frame(4)
        h.send_detections(4, [])
        assert h.spin_until(lambda: h.node.pipeline.frames_processed == 2)
        assert built == [3]  # no one listens: nothing built for frame 4
    finally:
        h.close()


def test_point_cloud_is_published_when_enabled(rclpy_context):
    from sensor_msgs.msg import PointCloud2

    h = Harness(rclpy_context, publish_points=True, points_decimation=8, points_rgb=True)
    clouds = []
    h.io.create_subscription(PointCloud2, "/stereo/points", clouds.append, 5)
    try:
        assert h.spin_until(lambda: h.node.outputs.points.get_subscription_count() > 0)
        h.send_frame(9)
        h.send_detections(9, [])
        assert h.spin_until(lambda: clouds)
        cloud = clouds[0]
        assert cloud.header.stamp.sec == 9
        assert [f.name for f in cloud.fields] == ["x", "y", "z", "rgb"]
        pts = np.frombuffer(bytes(cloud.data), np.float32).reshape(-1, 4)
        assert cloud.width == pts.shape[0] > 0.8 * (H // 8) * (W // 8)
        assert np.median(pts[:, 2]) == pytest.approx(FX * B / DISP, rel=0.03)
    finally:
        h.close()


@pytest.mark.parametrize("area", ["band", "boxes"])
def test_node_ranges_real_kitti_like_the_offline_core(rclpy_context, kitti_tracking_root, area):
    """offline == node: the node's 3D detections equal range_boxes on compute_disparity (the
    band's map: someone subscribes to the disparity image) or on compute_disparity_in_boxes
    (nobody does: the map only where the ranging reads it)."""
    from stereo_depth_node.disparity import (
        DisparityParams,
        compute_disparity,
        compute_disparity_in_boxes,
    )
    from stereo_depth_node.ranging import RangingParams, range_boxes
    from stereo_depth_node.region_matching import to_gray
    from stereo_depth_node.reprojection import StereoGeometry
    from vehicle_common.kitti import TrackingSequence

    seq = TrackingSequence.open(kitti_tracking_root, "0005")
    left, right = seq.read_stereo(0)
    cars = [o for o in seq.objects(0) if o.type == "Car"]
    h = Harness(rclpy_context)
    try:
        h.left, h.right = left, right
        h.infos = (
            camera_info_from_projection(seq.calib.P2, left.shape[1], left.shape[0]),
            camera_info_from_projection(seq.calib.P3, left.shape[1], left.shape[0]),
        )
        if area == "boxes":
            h.io.destroy_subscription(
                next(s for s in h.io.subscriptions if s.topic_name == "/stereo/disparity")
            )
            assert h.spin_until(lambda: h.node.outputs.disparity.get_subscription_count() == 0)
        h.send_frame(3)
        h.send_detections(3, [o.bbox for o in cars])
        assert h.spin_until(lambda: h.det3d, timeout=20.0)
        got = h.det3d[0].detections
        geo = StereoGeometry.from_projections(seq.calib.P2, seq.calib.P3)
        boxes = [o.bbox for o in cars]
        params = DisparityParams(num_disparities=48)
        if area == "band":
            disp = compute_disparity(left, right, params)
        else:
            disp = compute_disparity_in_boxes(left, right, boxes, params)
        images = (to_gray(left), to_gray(right))  # the node refines far boxes on them too
        want = range_boxes(disp, boxes, geo, RangingParams(), [2] * len(cars), images)
        assert len(got) == sum(w is not None for w in want) > 0
        for g, w in zip(got, [w for w in want if w is not None], strict=True):
            np.testing.assert_allclose(
                [g.position.x, g.position.y, g.position.z], w.position, rtol=1e-5
            )
        # and the estimates are near the labels (centre of mass, left frame)
        for g in got:
            gt = seq.calib.cam0_to_left(cars[int(g.id)].centre_of_mass)
            assert abs(g.position.z - gt[2]) < 0.15 * gt[2]
    finally:
        h.close()


@contextlib.contextmanager
def _checked_frame(ctx, action: str, boxes, **params):
    """A harness with ``plausibility_action``, one frame and its detections: (harness, the
    published 3D detections)."""
    h = Harness(ctx, plausibility_action=action, disparity_bias=0.0, **params)
    try:
        h.send_frame(3)
        h.send_detections(3, boxes)
        assert h.spin_until(lambda: h.det3d)
        yield h, list(h.det3d[0].detections)
    finally:
        h.close()


def test_floating_box_is_kept_lower_or_rejected_by_reject_below(rclpy_context):
    """The test scene has no road: the level prior 1.65 m below the camera stands in. The box's
    bottom edge (row 90, 30 px below the principal point) at the plane's 17.5 m is 0.75 m below
    the camera, 0.9 m above that road: floating. The default action (reject, reject_below
    0.01, issue #41) keeps a box the check is unsure of at score x plausibility; with
    reject_below 1.0 (before issue #41) it is dropped and counted."""
    assert PlausibilityParams().plausibility_action == "reject"
    with _checked_frame(rclpy_context, "reject", [(150, 30, 250, 90)]) as (h, dets):
        (det,) = dets
        assert 0.01 <= det.plausibility < 0.2
        assert det.score == pytest.approx(0.9 * det.plausibility)
        assert h.node.pipeline.implausible_detections == 0
    with _checked_frame(rclpy_context, "reject", [(150, 30, 250, 90)], reject_below=1.0) as (
        h,
        dets,
    ):
        assert dets == []
        assert h.node.pipeline.implausible_detections == 1


def test_flag_action_publishes_the_check_and_its_inputs(rclpy_context):
    # floating box, and one whose bottom edge (row 113 at 17.5 m: 1.33 m below the camera) is
    # 0.32 m above the road: it stands on the road
    boxes = [(150, 30, 250, 90), (60, 53, 140, 113)]
    # fixed limits (the depth-scaled ones: test_stereo_plausibility.py)
    with _checked_frame(rclpy_context, "flag", boxes, noise_sigmas=0.0) as (h, dets):
        floating, standing = dets
        z = FX * B / DISP
        assert floating.metric_height == pytest.approx(60 * z / FX, rel=0.03)
        assert floating.metric_width == pytest.approx(100 * z / FX, rel=0.03)
        assert floating.bottom_height == pytest.approx(1.65 - 30 * z / FX, abs=0.05)
        excess = floating.bottom_height - PlausibilityParams().max_bottom_height
        assert not floating.plausible
        assert floating.plausibility == pytest.approx(
            math.exp(-0.5 * (excess / 0.2) ** 2), rel=1e-4
        )
        assert standing.bottom_height == pytest.approx(1.65 - 53 * z / FX, abs=0.05)
        assert standing.plausible and standing.plausibility == 1.0
        assert floating.score == standing.score == pytest.approx(0.9)
        assert h.node.pipeline.implausible_detections == 0


def test_score_action_lowers_the_score_of_an_implausible_box(rclpy_context):
    with _checked_frame(rclpy_context, "score", [(150, 30, 250, 90)]) as (_, dets):
        (det,) = dets
        # 0.9 m above the road at 17.5 m: beyond the depth-scaled limit (0.4 m + 2 x 0.06 m)
        assert det.score == pytest.approx(0.9 * det.plausibility) and det.plausibility < 0.2


def test_bad_plausibility_parameter_is_refused(rclpy_context):
    from stereo_depth_node.node import StereoDepthNode
    from vehicle_common.node_parameters import ParameterError

    with pytest.raises(ParameterError, match="plausibility_action"):
        StereoDepthNode(
            context=rclpy_context,
            parameter_overrides=[Parameter("plausibility_action", value="drop")],
        )


def test_continuous_observation_angle_moves_the_centre_when_given(rclpy_context):
    """With the detector's observation_angle (variance >= 0) the centre offset is the one at
    that angle; a variance < 0 (old checkpoints) keeps the bin's centre angle. Runs once
    VehicleDetection2D has the fields (interfaces: added by the detector's issue)."""
    from stereo_depth_node.ranging import centre_depth_behind_surface
    from stereo_vehicle_msgs.msg import VehicleDetection2D, VehicleDetection2DArray

    if not hasattr(VehicleDetection2D(), "observation_angle_variance"):
        pytest.skip("VehicleDetection2D has no observation_angle yet (detector's issue)")
    h = Harness(rclpy_context, disparity_bias=0.0, disparity_bias_column=0.0, lateral_fit=False)
    try:
        h.send_frame(6)
        msg = VehicleDetection2DArray(header=h.header(6))
        for i, var in enumerate((0.01, -1.0)):
            d = VehicleDetection2D(id=str(i), class_id="car", score=0.9, orientation_bin=2)
            d.bbox.center_x, d.bbox.center_y, d.bbox.size_x, d.bbox.size_y = (
                200.0,
                60.0,
                100.0,
                60.0,
            )
            d.orientation_probs = [0.1, 0.1, 0.7, 0.1]
            d.observation_angle, d.observation_angle_variance = math.radians(-70.0), var
            msg.detections.append(d)
        h.pubs["det"].publish(msg)
        assert h.spin_until(lambda: h.det3d)
        given, absent = h.det3d[0].detections
        rp = RangingParams()
        shift = centre_depth_behind_surface(
            math.radians(90.0), 3.9, 1.6, "blend", rp.surface_blend
        ) - centre_depth_behind_surface(math.radians(-70.0), 3.9, 1.6, "blend", rp.surface_blend)
        assert shift > 0.1
        # the same ray: the distance differs by the two offsets
        dist = [
            math.dist((0, 0, 0), (p.position.x, p.position.y, p.position.z))
            for p in (given, absent)
        ]
        assert dist[1] - dist[0] == pytest.approx(shift, abs=0.02)
    finally:
        h.close()


def test_a_match_band_outside_the_images_stops_the_node_and_one_partly_outside_is_cut(
    rclpy_context, capfd
):
    """`match_rows` is checked against the images at the first pair (the image size is only
    known then): a band below the image sets the node's fatal error (node_runtime.run_node
    then exits 2 with its line); a band reaching below the image is cut there, with a warning
    naming the parameter and the image height."""
    h = Harness(rclpy_context, match_rows=[20, 400], disparity_bias=0.0, lateral_fit=False)
    try:
        h.send_frame(1)
        h.send_detections(1, [(150, 30, 250, 90)])
        assert h.spin_until(lambda: len(h.det3d) == 1)
        assert len(h.det3d[0].detections) == 1 and h.node.fatal_error is None
        assert h.node.pipeline._band_params[1].row_band == (20, H)
        err = capfd.readouterr().err
        assert err.count("match_rows: [20, 400] reaches below the 120-row image") == 1
    finally:
        h.close()
    h = Harness(rclpy_context, match_rows=[200, 300])
    try:
        h.send_frame(1)
        h.send_detections(1, [(150, 30, 250, 90)])
        assert h.spin_until(lambda: h.node.fatal_error is not None)
        assert h.node.fatal_error.name == "match_rows"
        assert h.node.fatal_error.problem.startswith("[200, 300] lies below the 120-row image")
    finally:
        h.close()


def test_stereo_depth_process_exits_2_naming_match_rows_at_its_first_pair(tmp_path):
    """End to end: the node process, given a 375-row pair with `match_rows:=[400, 500]`, stops
    with one error line and exit code 2 (it used to run on, publishing nothing). A frame is its
    two images and its 2D detection array (issue #33): the test sends all three."""
    import subprocess
    import sys

    import rclpy
    from rclpy.context import Context
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header
    from stereo_vehicle_msgs.msg import VehicleDetection2DArray

    proc = subprocess.Popen(
        [sys.executable, "-m", "stereo_depth_node.node", "--ros-args", "-p",
         "match_rows:=[400, 500]", "-p", "visual_odometry:=false"],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=tmp_path,
    )  # fmt: skip
    ctx = Context()
    rclpy.init(context=ctx)
    io = rclpy.create_node("match_rows_test_io", context=ctx)
    try:
        pubs = {
            topic: io.create_publisher(cls, topic, 5)
            for topic, cls in (
                ("/stereo/left/camera_info", CameraInfo),
                ("/stereo/right/camera_info", CameraInfo),
                ("/stereo/left/image_rect", Image),
                ("/stereo/right/image_rect", Image),
                ("/vehicles/detections_2d", VehicleDetection2DArray),
            )
        }
        deadline = time.monotonic() + 60
        while any(p.get_subscription_count() == 0 for p in pubs.values()):
            assert proc.poll() is None and time.monotonic() < deadline, "node did not come up"
            time.sleep(0.05)
        K = np.array([[721.5, 0, 609.6], [0, 721.5, 172.9], [0, 0, 1]])
        hdr = Header(frame_id="left_camera_optical_frame")
        hdr.stamp.sec = 1
        left_info = camera_info_from_projection(np.hstack([K, np.zeros((3, 1))]), 1242, 375)
        right_info = camera_info_from_projection(np.hstack([K, [[-389.6], [0], [0]]]), 1242, 375)
        img = np.zeros((375, 1242, 3), np.uint8)
        # a camera streams: frames go on until the node stops (a pair taken before its
        # CameraInfo is skipped, as the node does, so one frame alone could race the infos)
        while proc.poll() is None:
            assert time.monotonic() < deadline, "the node did not stop"
            hdr.stamp.sec += 1
            for topic, msg in (
                ("/stereo/left/camera_info", left_info),
                ("/stereo/right/camera_info", right_info),
                ("/stereo/left/image_rect", numpy_to_image(img, "rgb8", hdr)),
                ("/stereo/right/image_rect", numpy_to_image(img, "rgb8", hdr)),
                ("/vehicles/detections_2d", VehicleDetection2DArray()),
            ):
                msg.header = hdr
                pubs[topic].publish(msg)
            time.sleep(0.2)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        io.destroy_node()
        ctx.try_shutdown()
    assert proc.returncode == 2, err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert lines == [
        "error: stereo_depth: parameter match_rows: [400, 500] lies below the 375-row image "
        "(rows 0..374); the matcher needs at least 12 rows: nothing could be ranged"
    ], err
    assert "Traceback" not in err


def test_settings_are_derived_from_the_camera_info_and_follow_a_change(rclpy_context, capfd):
    """With no camera settings given, the disparity range and rows come from the CameraInfo
    pair (one log line); a CameraInfo that changes mid-run is reported, the settings are
    derived again, the matcher runs with them and the odometry starts afresh."""
    h = Harness(
        rclpy_context,
        num_disparities=0,  # derived (the harness's default gives 48)
        match_rows=[-1, -1],
        disparity_bias=0.0,
        disparity_bias_column=0.0,
        lateral_fit=False,
    )
    try:
        h.send_frame(1)
        h.send_detections(1, [(150, 30, 250, 90)])
        assert h.spin_until(lambda: len(h.det3d) == 1)
        s = h.node.pipeline.settings
        # 700 px x 0.5 m / 4.05 m = 86.4 -> 96; not KITTI's camera: every row; 1.65 m assumed
        assert s.num_disparities == 96 and s.match_rows == (0, 0)
        assert s.ground_height == 1.65 and s.ground_height_assumed
        assert len(h.det3d[0].detections) == 1
        h.send_frame(2)
        h.send_detections(2, [(150, 30, 250, 90)])
        assert h.spin_until(lambda: len(h.det3d) == 2)
        assert h.det3d[1].camera_motion_dt == pytest.approx(1.0)
        # the camera changes: baseline 0.1 m (70 px m: 32 px); the images stay 20 px apart
        K = np.array([[FX, 0, W / 2], [0, FX, H / 2], [0, 0, 1]])
        h.infos = (
            h.infos[0],
            camera_info_from_projection(np.hstack([K, [[-FX * 0.1], [0], [0]]]), W, H),
        )
        h.send_frame(3)
        h.send_detections(3, [(150, 30, 250, 90)])
        assert h.spin_until(lambda: len(h.det3d) == 3)
        assert h.node.pipeline.settings.num_disparities == 32
        third = h.det3d[2]
        assert len(third.detections) == 1  # ranged with the new camera
        # the surface 20 px away: 17.5 m with the first baseline, 3.5 m with the new one (plus
        # the same visible-surface -> centre correction)
        z1, z3 = (a.detections[0].position.z for a in (h.det3d[0], third))
        assert z1 - z3 == pytest.approx(FX * (0.5 - 0.1) / DISP, rel=0.05)
        assert third.camera_motion_dt == 0.0  # another camera: the odometry chain restarts
        h.send_frame(4)
        h.send_detections(4, [(150, 30, 250, 90)])
        assert h.spin_until(lambda: len(h.det3d) == 4)
        assert h.det3d[3].camera_motion_dt == pytest.approx(1.0)
    finally:
        h.close()
    err = capfd.readouterr().err
    assert err.count("num_disparities 96") == 1 and "match_rows all" in err
    assert "camera_info changed" in err and "num_disparities 32" in err
    # each camera line states the ranging's depth std on that camera: worse on the shorter one
    lines = [ln for ln in err.splitlines() if "ranging depth std" in ln]
    assert len(lines) == 2 and "f x baseline 70 px m" in lines[1]
