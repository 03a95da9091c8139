"""Compressed images through the graph: the player sends sensor_msgs/CompressedImage (PNG or
JPEG) on ``.../image_rect/compressed``, the detector (oracle) and stereo depth take them with
``image_transport: compressed``. PNG is lossless: the same 3D detections and disparities as raw
images; JPEG moves them a little. Nodes in-process, one executor."""

from __future__ import annotations

import numpy as np
import pytest

from tests.ros_helpers import spin_until

FRAMES = 4


@pytest.fixture(scope="module")
def small_sequence(tmp_path_factory):
    from kitti_player_node.synthetic import generate_sequence

    root = tmp_path_factory.mktemp("compressed")
    return generate_sequence(root, "0000", frames=FRAMES, seed=2, width=416, height=128)


def _graph_outputs(context, root, transport: str, quality: int = 90, consumers: str = ""):
    """(3D arrays, disparity images) of one play of the sequence through player, oracle
    detector and stereo depth with the player's ``image_transport`` (the consumers' follows
    it, as the launchers set it, unless ``consumers`` names it)."""
    from detector_node.node import VehicleDetectorNode
    from kitti_player_node.node import KittiPlayerNode
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from stereo_depth_node.node import StereoDepthNode
    from stereo_msgs.msg import DisparityImage
    from stereo_vehicle_msgs.msg import VehicleDetection3DArray
    from vehicle_common.image_transport import subscriber_transport

    def params(**kv):
        return [Parameter(k, value=v) for k, v in kv.items()]

    sub_transport = consumers or subscriber_transport(transport)
    detector = VehicleDetectorNode(
        context=context,
        parameter_overrides=params(
            backend="oracle", image_transport=sub_transport, frame_queue=FRAMES
        ),
    )
    stereo = StereoDepthNode(
        context=context,
        parameter_overrides=params(
            image_transport=sub_transport,
            frame_queue=FRAMES,
            num_disparities=32,
            visual_odometry=False,
            # every ranged box is published: the JPEG run is compared box by box with the raw
            # one, and a box at the plausibility limits may pass in one and not the other
            plausibility_action="flag",
        ),
    )
    io = Node("compressed_test_io", context=context)
    det3d, disp = [], []
    io.create_subscription(VehicleDetection3DArray, "/vehicles/detections_3d", det3d.append, 10)
    io.create_subscription(DisparityImage, "/stereo/disparity", disp.append, 10)
    ex = SingleThreadedExecutor(context=context)
    for n in (detector, stereo, io):
        ex.add_node(n)
    image = "stereo/left/image_rect" + ("" if transport == "raw" else "/compressed")
    right = image.replace("left", "right")
    wait = f"{image}:2,{right}:1,stereo/left/camera_info:1,stereo/right/camera_info:1"
    wait += ",kitti/ground_truth:1"
    player = KittiPlayerNode(
        context=context,
        parameter_overrides=params(
            dataset_root=str(root),
            sequence="0000",
            rate=5.0,
            image_transport=transport,
            jpeg_quality=quality,
            wait_for_topics=wait,
        ),
    )
    ex.add_node(player)
    sent_on = [p.topic_name for p in (player.pub_left, player.pub_right)]
    try:
        if consumers and consumers != subscriber_transport(transport):
            assert not spin_until(ex, lambda: player.done, 3)  # waits for its subscribers
            return det3d, disp, sent_on
        assert spin_until(ex, lambda: player.done, 30), "player did not finish"
        stereo.worker.wait_idle(5.0)
        assert spin_until(ex, lambda: len(det3d) == FRAMES and len(disp) == FRAMES, 20), (
            len(det3d),
            len(disp),
        )
        return det3d, disp, sent_on
    finally:
        ex.shutdown()
        for n in (player, detector, stereo, io):
            n.destroy_node()


def _positions(arrays) -> list[list[tuple[float, float, float]]]:
    return [
        [(d.position.x, d.position.y, d.position.z) for d in a.detections]
        for a in sorted(arrays, key=lambda a: (a.header.stamp.sec, a.header.stamp.nanosec))
    ]


def _disparities(images) -> list[np.ndarray]:
    from vehicle_common.image_conversion import image_to_numpy

    ordered = sorted(images, key=lambda m: (m.header.stamp.sec, m.header.stamp.nanosec))
    return [image_to_numpy(m.image) for m in ordered]


def test_png_and_jpeg_images_reach_detector_and_stereo(rclpy_context, small_sequence):
    raw3d, raw_disp, _ = _graph_outputs(rclpy_context, small_sequence, "raw")
    ref = _positions(raw3d)
    assert sum(map(len, ref)) >= FRAMES  # cars ranged in the raw run
    png3d, png_disp, sent_on = _graph_outputs(rclpy_context, small_sequence, "png")
    assert sent_on == [
        "/stereo/left/image_rect/compressed",
        "/stereo/right/image_rect/compressed",
    ]
    assert _positions(png3d) == ref  # lossless: the very same ranging
    for a, b in zip(_disparities(png_disp), _disparities(raw_disp), strict=True):
        np.testing.assert_array_equal(a, b)
    jpg3d, jpg_disp, _ = _graph_outputs(rclpy_context, small_sequence, "jpeg", quality=75)
    jpg = _positions(jpg3d)
    assert [len(f) for f in jpg] == [len(f) for f in ref]  # the same cars ranged
    rel = [
        abs(pj[2] - pr[2]) / pr[2]
        for fj, fr in zip(jpg, ref, strict=True)
        for pj, pr in zip(fj, fr, strict=True)
    ]
    assert np.median(rel) < 0.05  # most within a few % (far cars: one disparity step, more)
    assert not all(
        np.array_equal(a, b)
        for a, b in zip(_disparities(jpg_disp), _disparities(raw_disp), strict=True)
    )  # lossy: it did go through JPEG


def test_mismatched_transport_receives_nothing(rclpy_context, small_sequence):
    """Consumers left on raw while the player sends PNG: the player waits for its compressed
    topics' subscribers and nothing flows (the launchers keep them in step:
    tests/bringup/test_image_transport_plan.py)."""
    det3d, _, _ = _graph_outputs(rclpy_context, small_sequence, "png", consumers="raw")
    assert det3d == []


def test_bad_transport_parameters_are_one_line_errors(rclpy_context, small_sequence):
    from kitti_player_node.node import KittiPlayerNode
    from rclpy.parameter import Parameter
    from stereo_depth_node.node import StereoDepthNode
    from vehicle_common.node_parameters import ParameterError

    with pytest.raises(ParameterError, match="image_transport"):
        StereoDepthNode(
            context=rclpy_context,
            parameter_overrides=[Parameter("image_transport", value="png")],
        )
    with pytest.raises(ParameterError, match="jpeg_quality"):
        KittiPlayerNode(
            context=rclpy_context,
            parameter_overrides=[
                Parameter("dataset_root", value=str(small_sequence)),
                Parameter("image_transport", value="jpeg"),
                Parameter("jpeg_quality", value=0),
            ],
        )
