"""In-process tests of the vehicle_detector node: oracle and CNN backends, one output per image."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from detector_node.oracle import OracleDetector, StampPairing
from vehicle_common.kitti import KittiObject

from tests.ros_helpers import spin_until as _spin_until


def _objects():
    return [
        KittiObject("Car", alpha=math.radians(40), bbox=(100.0, 150.0, 220.0, 230.0)),
        KittiObject("Van", alpha=math.radians(-90), bbox=(400.0, 140.0, 480.0, 220.0)),
        KittiObject("Pedestrian", alpha=0.0, bbox=(600.0, 150.0, 620.0, 230.0)),
        KittiObject("DontCare", bbox=(700.0, 150.0, 760.0, 180.0)),
    ]


def test_oracle_core_noise_drop_and_bins():
    exact = OracleDetector(score=0.8).detect(_objects())
    assert [d.box for d in exact] == [(100.0, 150.0, 220.0, 230.0), (400.0, 140.0, 480.0, 220.0)]
    assert [d.orientation_bin for d in exact] == [1, 2]
    assert exact[0].orientation_probs == (0.0, 1.0, 0.0, 0.0) and exact[0].score == 0.8
    cars_only = OracleDetector(positive_types=("Car",)).detect(_objects())
    assert len(cars_only) == 1
    noisy = [OracleDetector(box_noise_px=3.0, seed=5).detect(_objects()) for _ in range(2)]
    assert noisy[0][0].box == noisy[1][0].box  # seeded
    err = np.array(noisy[0][0].box) - np.array(exact[0].box)
    assert 0 < np.abs(err).max() < 15
    dropper = OracleDetector(drop_probability=0.5, seed=1)
    kept = sum(len(dropper.detect(_objects())) for _ in range(200))
    assert 150 < kept < 250  # 400 boxes offered, about half kept


def test_stamp_pairing_any_order_bounded():
    p = StampPairing(max_pending=2, max_labels=3)
    assert p.add_image(1, "img1") == []
    assert p.add_labels(1, "gt1") == [("img1", "gt1")]
    assert p.add_labels(2, "gt2") == []
    assert p.add_image(2, "img2") == [("img2", "gt2")]
    assert p.add_image(3, "img3") == [] and p.add_image(4, "img4") == []
    assert p.add_image(5, "img5") == [("img3", None)]  # the oldest is released unpaired
    assert p.pending_images == 2


def _run_node(context, params, publish):
    """Start the detector with ``params``, wait for matching, call ``publish(pubs, received)``
    and collect the arrays published on /vehicles/detections_2d."""
    from detector_node.node import VehicleDetectorNode
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Image
    from stereo_vehicle_msgs.msg import KittiFrameLabels, VehicleDetection2DArray

    det = VehicleDetectorNode(
        context=context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]
    )
    test = Node("detector_test", context=context)
    got = []
    test.create_subscription(VehicleDetection2DArray, "/vehicles/detections_2d", got.append, 10)
    pubs = {
        "image": test.create_publisher(Image, "/stereo/left/image_rect", 5),
        "gt": test.create_publisher(KittiFrameLabels, "/kitti/ground_truth", 10),
    }
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(det)
    ex.add_node(test)
    need_gt = params.get("backend") == "oracle"
    assert _spin_until(
        ex,
        lambda: (
            pubs["image"].get_subscription_count() > 0
            and (not need_gt or pubs["gt"].get_subscription_count() > 0)
            and det.pub.get_subscription_count() > 0
        ),
        10,
    ), "detector and test node did not match"

    def received(k):  # for a publish that sends one image at a time and waits for its array
        assert _spin_until(ex, lambda: len(got) >= k, 30), f"got {len(got)} of {k} arrays"

    n = publish(pubs, received)
    assert _spin_until(ex, lambda: len(got) >= n, 30), f"got {len(got)} of {n} arrays"
    ex.spin_once(timeout_sec=0.2)
    ex.shutdown()
    det.destroy_node()
    test.destroy_node()
    return got


def _stamp_ns(h):
    return h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


def test_oracle_backend_republishes_ground_truth(rclpy_context):
    from vehicle_common.frame_messages import ground_truth_message, header
    from vehicle_common.image_conversion import numpy_to_image
    from vehicle_common.kitti import stereo_calibration

    calib = stereo_calibration(700.0, 700.0, 620.0, 187.0, 0.54)
    img = np.zeros((375, 1242, 3), np.uint8)

    def publish(pubs, _received):
        s1, s2 = 5_000_000_000, 5_100_000_000
        # frame 1: GT first; frame 2: image first
        pubs["gt"].publish(ground_truth_message("0000", 0, calib, _objects(), s1))
        time.sleep(0.05)
        pubs["image"].publish(numpy_to_image(img, "rgb8", header(s1, "left_camera_optical_frame")))
        pubs["image"].publish(numpy_to_image(img, "rgb8", header(s2, "left_camera_optical_frame")))
        time.sleep(0.05)
        pubs["gt"].publish(ground_truth_message("0000", 1, calib, _objects()[:1], s2))
        return 2

    got = _run_node(rclpy_context, {"backend": "oracle", "oracle_score": 0.9}, publish)
    assert len(got) == 2
    by_stamp = {_stamp_ns(m.header): m for m in got}
    first, second = by_stamp[5_000_000_000], by_stamp[5_100_000_000]
    assert first.header.frame_id == "left_camera_optical_frame"
    assert [d.class_id for d in first.detections] == ["car", "car"]
    d0 = first.detections[0]
    assert (d0.bbox.center_x, d0.bbox.center_y, d0.bbox.size_x, d0.bbox.size_y) == pytest.approx(
        (160.0, 190.0, 120.0, 80.0)
    )
    assert d0.orientation_bin == 1 and d0.score == pytest.approx(0.9)
    assert list(d0.orientation_probs) == pytest.approx([0, 1, 0, 0])
    assert first.detections[1].orientation_bin == 2
    assert len(second.detections) == 1


def test_cnn_backend_named_checkpoint_finds_synthetic_car(rclpy_context, tmp_path):
    """The CNN backend with the previous shipped model by name (``tiny_kitti``, trained on the
    renderer's cars; the default model is for real cameras, checked on a real frame in
    test_detector_pretrained)."""
    from detector_node.boxes import iou_matrix
    from kitti_player_node.synthetic import generate_sequence
    from vehicle_common.frame_messages import header
    from vehicle_common.image_conversion import numpy_to_image
    from vehicle_common.kitti import TrackingSequence

    generate_sequence(tmp_path, "0007", 3, seed=4242)
    seq = TrackingSequence.open(tmp_path, "0007")
    frame = seq.frame_ids[-1]
    rgb = seq.read_stereo(frame)[0]
    cars = [o for o in seq.objects(frame) if o.type == "Car" and o.height_px >= 25]
    assert cars, "the synthetic frame has a labelled car"
    stamp = 7_300_000_000

    def publish(pubs, received):
        bad = numpy_to_image(rgb[:10, :10], "rgb8", header(stamp - 1, "left_camera_optical_frame"))
        bad.encoding = "weird"  # malformed: warning + empty array, node keeps running
        pubs["image"].publish(bad)
        # one at a time: an image still waiting when a newer one arrives would be skipped
        received(1)
        pubs["image"].publish(
            numpy_to_image(rgb, "rgb8", header(stamp, "left_camera_optical_frame"))
        )
        return 2

    got = _run_node(
        rclpy_context, {"backend": "cnn", "num_threads": 2, "checkpoint": "tiny_kitti"}, publish
    )
    assert len(got) == 2
    by_stamp = {_stamp_ns(m.header): m for m in got}
    assert by_stamp[stamp - 1].detections == []
    msg = by_stamp[stamp]
    assert msg.header.frame_id == "left_camera_optical_frame"
    assert msg.detections, "the shipped checkpoint detects something"
    boxes = np.array(
        [
            [
                d.bbox.center_x - d.bbox.size_x / 2,
                d.bbox.center_y - d.bbox.size_y / 2,
                d.bbox.center_x + d.bbox.size_x / 2,
                d.bbox.center_y + d.bbox.size_y / 2,
            ]
            for d in msg.detections
        ]
    )
    ious = iou_matrix(boxes, np.array([c.bbox for c in cars]))
    assert ious.max() >= 0.5, f"no detection near a labelled car (best IoU {ious.max():.2f})"
    for d in msg.detections:
        assert 0.0 <= d.score <= 1.0 and d.class_id == "car"
        assert sum(d.orientation_probs) == pytest.approx(1.0, abs=1e-4)
        assert d.orientation_bin == int(np.argmax(d.orientation_probs))
    assert [d.id for d in msg.detections] == [str(i) for i in range(len(msg.detections))]


def test_bad_checkpoint_device_or_runtime_is_one_line_and_exit_2(tmp_path, capsys):
    """`checkpoint:=/x.pt`, a file that is no checkpoint and `device:=cuda` without CUDA used to
    end the node in a traceback (exit 1)."""
    import torch
    from detector_node.checkpoint import save_checkpoint
    from detector_node.model import YoloV2Passthrough, preset
    from detector_node.node import main

    text = tmp_path / "text.pt"
    text.write_text("not a checkpoint\n")
    noise = tmp_path / "noise.pt"
    noise.write_bytes(np.random.default_rng(0).integers(0, 256, 3000, np.uint8).tobytes())
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    mismatch = tmp_path / "mismatch.pt"
    save_checkpoint(mismatch, YoloV2Passthrough(preset("tiny", input_width=320, input_height=96)))
    state = torch.load(mismatch, weights_only=True)
    first = next(iter(state["state_dict"]))
    state["state_dict"][first] = torch.zeros(1)
    torch.save(state, mismatch)
    cases = [
        ("checkpoint:=/x.pt", "parameter checkpoint: /x.pt: checkpoint not found"),
        (f"checkpoint:={tmp_path}", f"parameter checkpoint: {tmp_path}: is a folder"),
        (f"checkpoint:={text}", f"{text}: not a PyTorch weights-only checkpoint"),
        (f"checkpoint:={noise}", f"{noise}: not a PyTorch weights-only checkpoint"),
        (f"checkpoint:={other}", f"{other}: not a detector checkpoint"),
        (f"checkpoint:={mismatch}", f"{mismatch}: not a usable detector checkpoint"),
        ("device:=gpu", "parameter device: expected auto, cpu, cuda or cuda:N"),
        ("runtime:=onnxruntime -p checkpoint:=tiny_kitti", "parameter runtime: 'onnxruntime'"),
    ]
    if not torch.cuda.is_available():
        cases.append(("device:=cuda", "parameter device: 'cuda' requested but CUDA is not"))
    for setting, message in cases:
        args = [a for item in setting.split(" -p ") for a in ("-p", item)]
        rc = main(["--ros-args", *args])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2, (setting, err)
        assert len(err) == 1 and err[0].startswith("error: vehicle_detector: "), err
        assert message in err[0], err


def test_detector_offline_unwritable_output_is_one_line(tmp_path, capsys):
    from detector_node.offline import main
    from vehicle_common.kitti import write_png

    write_png(tmp_path / "images" / "000000.png", np.zeros((40, 64, 3), np.uint8))
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for out, message in (
        ("/proc/x", "/proc/x: cannot create output folder (No such file or directory)"),
        (str(a_file), f"{a_file}: exists and is not a folder"),
        (str(a_file / "sub"), f"{a_file / 'sub'}: cannot create output folder"),
    ):
        rc = main(["--images", str(tmp_path / "images"), "--output", out, "--checkpoint", "x.pt"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and err[0].startswith(f"error: {message}"), err


def test_burst_of_images_the_newest_is_detected_and_the_older_counted_dropped(rclpy_context):
    """While the CNN works on image 0, five more images arrive at once (the node's executor
    takes them late). The node detects the newest, 5, and counts 1-4 as dropped before any work
    on them: in 6, out 2, dropped 4 (latest-frame policy, issue #33). Each image the CNN
    starts is announced before its array (``vehicles/detections_2d/started``, the stereo node's
    early start), the skipped ones never."""
    import threading

    from detector_node.node import VehicleDetectorNode
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Image
    from std_msgs.msg import Header
    from stereo_vehicle_msgs.msg import VehicleDetection2DArray
    from vehicle_common.frame_messages import header
    from vehicle_common.image_conversion import numpy_to_image

    det = VehicleDetectorNode(
        context=rclpy_context,
        parameter_overrides=[Parameter("checkpoint", value="tiny_kitti")],
    )
    gate, started, seen = threading.Event(), threading.Event(), []
    detect = det.cnn.detect

    def held(rgb):
        seen.append(1)
        if len(seen) == 1:
            started.set()
            gate.wait(10)
        return detect(rgb)

    det.cnn.detect = held
    test = Node("detector_burst_test", context=rclpy_context)
    got = []
    test.create_subscription(VehicleDetection2DArray, "/vehicles/detections_2d", got.append, 10)
    announced = []
    test.create_subscription(Header, "/vehicles/detections_2d/started", announced.append, 10)
    pub = test.create_publisher(Image, "/stereo/left/image_rect", 10)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(det)
    ex.add_node(test)
    img = np.zeros((96, 320, 3), np.uint8)

    def image(k):
        return numpy_to_image(img, "rgb8", header(1_000_000_000 + k, "left_camera_optical_frame"))

    try:
        assert _spin_until(
            ex, lambda: pub.get_subscription_count() > 0 and det.pub.get_subscription_count() > 0
        )
        pub.publish(image(0))
        assert _spin_until(ex, started.is_set)
        assert _spin_until(ex, lambda: len(announced) == 1) and got == []  # before its array
        for k in range(1, 6):  # the burst, while nobody spins the node's executor
            pub.publish(image(k))
        time.sleep(0.2)
        assert _spin_until(ex, lambda: det.frames.snapshot().received == 6)
        gate.set()
        assert _spin_until(ex, lambda: len(got) == 2 and not det.worker.busy, 20)
        ex.spin_once(timeout_sec=0.2)
        assert [_stamp_ns(m.header) - 1_000_000_000 for m in got] == [0, 5]
        assert len(seen) == 2  # the CNN ran on images 0 and 5 only
        assert [_stamp_ns(h) - 1_000_000_000 for h in announced] == [0, 5]
        counts = det.frames.snapshot()
        assert (counts.received, counts.published, counts.dropped) == (6, 2, 4)
    finally:
        gate.set()
        ex.shutdown()
        det.destroy_node()
        test.destroy_node()


@pytest.mark.parametrize("window", [1, 0])
def test_live_camera_back_pressure_waits_for_the_stereo_node(rclpy_context, window):
    """Issue #39: images keep coming while the stereo node (here the test) has not published
    the 3D array of the frame the detector detected. With ``downstream_window`` 1 the detector
    detects none of them; when the 3D array comes it detects the newest and counts the rest as
    dropped, where they were skipped. With 0 (no back-pressure) it detects every image."""
    from detector_node.node import VehicleDetectorNode
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Image
    from stereo_vehicle_msgs.msg import VehicleDetection2DArray, VehicleDetection3DArray
    from vehicle_common.frame_messages import header
    from vehicle_common.image_conversion import numpy_to_image

    det = VehicleDetectorNode(
        context=rclpy_context,
        parameter_overrides=[
            Parameter("checkpoint", value="tiny_kitti"),
            Parameter("downstream_window", value=window),
            # the framing given: no image waits for a CameraInfo
            Parameter("input_width", value=320),
            Parameter("input_height", value=96),
            Parameter("roi_top", value=0.0),
        ],
    )
    test = Node("detector_flow_test", context=rclpy_context)
    got = []
    test.create_subscription(VehicleDetection2DArray, "/vehicles/detections_2d", got.append, 10)
    pub = test.create_publisher(Image, "/stereo/left/image_rect", 10)
    done = test.create_publisher(VehicleDetection3DArray, "/vehicles/detections_3d", 10)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(det)
    ex.add_node(test)
    img = np.zeros((96, 320, 3), np.uint8)

    def stamp(k):
        return header(1_000_000_000 + k * 100_000_000, "left_camera_optical_frame")

    try:
        assert _spin_until(
            ex,
            lambda: (
                pub.get_subscription_count() > 0
                and det.pub.get_subscription_count() > 0
                and (window == 0 or done.get_subscription_count() > 0)
                and det.count_publishers("/vehicles/detections_3d") > 0
            ),
        )
        for k in range(5):  # a 10 Hz camera; the 3D array of frame 0 comes only afterwards
            pub.publish(numpy_to_image(img, "rgb8", stamp(k)))
            _spin_until(ex, lambda: False, 0.1)
        assert _spin_until(ex, lambda: det.frames.snapshot().received == 5)
        _spin_until(ex, lambda: False, 0.3)  # a detection it should not start would come now
        stamps = [(_stamp_ns(m.header) - 1_000_000_000) // 100_000_000 for m in got]
        if window == 0:
            assert _spin_until(ex, lambda: len(got) == 5, 20)
            assert det.frames.snapshot().dropped == 0
            return
        assert stamps == [0]  # frames 1-4 held back: frame 0 is in flight downstream
        out = VehicleDetection3DArray()
        out.header = got[0].header
        done.publish(out)
        assert _spin_until(ex, lambda: len(got) == 2 and not det.worker.busy, 20)
        assert _stamp_ns(got[1].header) == _stamp_ns(stamp(4))  # the newest
        counts = det.frames.snapshot()
        assert (counts.received, counts.published, counts.dropped) == (5, 2, 3)
    finally:
        ex.shutdown()
        det.destroy_node()
        test.destroy_node()
