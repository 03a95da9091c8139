"""In-process vehicle_tracker node test: one tracked array per detection array, same header;
a NaN position is logged and skipped without crashing."""

from __future__ import annotations

import math

from tests.ros_helpers import spin_until as _spin_until


def test_node_publishes_one_track_array_per_detection_array(rclpy_context):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from stereo_vehicle_msgs.msg import (
        TrackedVehicle,
        TrackedVehicleArray,
        VehicleDetection3D,
        VehicleDetection3DArray,
    )
    from tracker_node.node import VehicleTrackerNode
    from visualization_msgs.msg import Marker, MarkerArray

    node = VehicleTrackerNode(context=rclpy_context)
    helper = Node("tracker_test_helper", context=rclpy_context)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pub = helper.create_publisher(VehicleDetection3DArray, "/vehicles/detections_3d", qos)
    got, markers = [], []
    helper.create_subscription(TrackedVehicleArray, "/vehicles/tracks", got.append, qos)
    helper.create_subscription(MarkerArray, "/vehicles/track_markers", markers.append, qos)
    ex = SingleThreadedExecutor(context=rclpy_context)
    ex.add_node(node)
    ex.add_node(helper)
    try:
        assert _spin_until(
            ex,
            lambda: (
                pub.get_subscription_count() > 0
                and node.pub.get_subscription_count() > 0
                and node.marker_pub.get_subscription_count() > 0
            ),
        )
        n_frames = 11
        for k in range(n_frames):
            msg = VehicleDetection3DArray()
            msg.header.frame_id = "left_camera_optical_frame"
            msg.header.stamp.sec = 1000 + k // 10
            msg.header.stamp.nanosec = (k % 10) * 100_000_000
            if k < 6:  # the car disappears after frame 5
                d = VehicleDetection3D()
                d.id, d.class_id, d.score = "0", "car", 0.9
                d.position.x, d.position.y, d.position.z = 1.0 + 0.5 * k, 1.0, 15.0
                d.position_covariance = [0.04, 0, 0, 0, 0.04, 0, 0, 0, 0.25]
                d.bbox.center_x, d.bbox.center_y, d.bbox.size_x, d.bbox.size_y = (
                    700.0,
                    190.0,
                    80.0,
                    60.0,
                )
                d.orientation_bin = 0
                msg.detections.append(d)
            if k == 2:  # a malformed detection alongside a good one
                bad = VehicleDetection3D()
                bad.id = "1"
                bad.position.x, bad.position.y, bad.position.z = math.nan, 0.0, 10.0
                msg.detections.append(bad)
            pub.publish(msg)
            assert _spin_until(ex, lambda k=k: len(got) == k + 1), f"no tracks for frame {k}"
            out = got[-1]
            assert out.header.stamp == msg.header.stamp
            assert out.header.frame_id == "left_camera_optical_frame"
        assert len(got) == n_frames
        first = got[0].vehicles
        assert len(first) == 1 and first[0].track_id == 1
        assert first[0].state == TrackedVehicle.STATE_TENTATIVE
        v5 = got[5].vehicles[0]
        assert v5.track_id == 1 and v5.state == TrackedVehicle.STATE_CONFIRMED
        assert abs(v5.position.x - 3.5) < 0.2 and abs(v5.velocity.x - 5.0) < 1.5
        assert (v5.size.x, v5.size.y) == (3.88, 1.63) or abs(v5.size.x - 3.88) < 1e-5
        assert v5.bbox.size_y == 60.0
        assert len(got[2].vehicles) == 1  # the NaN detection was skipped, no new track
        coast = got[6].vehicles
        assert len(coast) == 1 and coast[0].state == TrackedVehicle.STATE_COASTING
        assert coast[0].frames_since_update == 1
        assert _spin_until(ex, lambda: len(markers) >= n_frames)
        kinds = {m.type for m in markers[5].markers}
        assert {Marker.LINE_LIST, Marker.TEXT_VIEW_FACING, Marker.ARROW} <= kinds
        assert [m.text for m in markers[5].markers if m.type == Marker.TEXT_VIEW_FACING] == ["1"]
        deleted = [m for ma in markers for m in ma.markers if m.action == Marker.DELETE]
        assert deleted and all(m.id == 1 for m in deleted)  # the track ended after coasting
        assert len(got[-1].vehicles) == 0
    finally:
        ex.shutdown()
        helper.destroy_node()
        node.destroy_node()
