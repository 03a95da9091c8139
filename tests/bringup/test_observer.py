"""The launcher's DDS observer (tracking_bringup.observer): it takes the reports on
/diagnostics, lists the graph's endpoints not yet up and the topics another graph publishes on.
One participant in this process (ROS_DOMAIN_ID of the test run)."""

import time

from tracking_bringup.observer import ReportObserver
from tracking_bringup.supervision import ProcessSpec


def test_reports_missing_endpoints_and_foreign_publishers():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from std_msgs.msg import String

    received = []
    observer = ReportObserver({}, received.append)
    try:
        node = observer.node
        assert node.get_name().startswith("graph_launcher_")
        topic = "/observer_test/chatter"
        spec = ProcessSpec("talker", [], subscribes=("/observer_test/in",), publishes=(topic,))
        assert observer.missing_endpoints([spec]) == [
            "talker subscription /observer_test/in",
            f"talker publisher {topic}",
        ]
        first = node.create_publisher(String, topic, 10)
        assert observer.foreign_publishers([spec]) == []  # one publisher, one of the graph's
        second = node.create_publisher(String, topic, 10)
        assert observer.foreign_publishers([spec]) == [f"{topic} (2 publishers, 1 of this graph)"]
        node.destroy_publisher(first)
        node.destroy_publisher(second)

        reports = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        deadline = time.monotonic() + 20
        while not received and time.monotonic() < deadline:
            reports.publish(DiagnosticArray(status=[DiagnosticStatus(name="/x")]))
            observer.spin(0.1)
        assert received and received[0].status[0].name == "/x"
    finally:
        observer.close()
    assert observer.node is None
    observer.close()  # twice: nothing left to close
