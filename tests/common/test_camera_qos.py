"""Any camera's QoS (issue #42 item 1): the image and camera_info subscriptions follow their
publishers' reliability ("auto", as rosbag2 does), so a BEST_EFFORT driver (the sensor-data QoS)
and a RELIABLE one both deliver, and a RELIABLE one keeps its resends of lost fragments."""

from __future__ import annotations

import pytest
from rclpy.qos import ReliabilityPolicy
from vehicle_common.image_transport import publishers_reliability

from tests.ros_helpers import spin_until

R, B = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT


def test_the_reliability_that_receives_most():
    assert publishers_reliability([]) is None
    assert publishers_reliability([R, R]) == "reliable"
    assert publishers_reliability([R, B]) == "best_effort"
    assert publishers_reliability([B]) == "best_effort"


@pytest.mark.parametrize("publisher", ["reliable", "best_effort"])
def test_auto_subscription_follows_and_receives_its_publisher(rclpy_context, publisher):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import CameraInfo
    from vehicle_common.image_transport import camera_qos, subscribe_camera

    node = Node("camera_qos_sub", context=rclpy_context)
    source = Node("camera_qos_pub", context=rclpy_context)
    got, lines = [], []
    sub = subscribe_camera(node, CameraInfo, "/qos_test/camera_info", got.append, 5, lines.append)
    assert sub.reliability == "reliable"  # until a publisher is seen (the graph's player)
    pub = source.create_publisher(CameraInfo, "/qos_test/camera_info", camera_qos(5, publisher))
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(node)
    ex.add_node(source)
    try:
        assert spin_until(ex, lambda: sub.reliability == publisher, 5.0)
        assert spin_until(ex, lambda: pub.get_subscription_count() == 1, 5.0)
        qos = sub.subscription.qos_profile
        assert qos.reliability == (R if publisher == "reliable" else B) and qos.depth == 5
        pub.publish(CameraInfo(width=7))
        assert spin_until(ex, lambda: len(got) == 1, 5.0)
        assert got[0].width == 7 and lines == []
    finally:
        ex.shutdown()
        node.destroy_node()
        source.destroy_node()
