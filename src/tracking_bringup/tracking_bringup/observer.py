"""The launcher's DDS observer: one ROS node in its own rclpy context, on the children's DDS
domain with their transport settings, that takes the nodes' reports on /diagnostics and sees
which of the graph's endpoints are up (readiness) and whether another graph publishes on the
same topics. (The discovery settings themselves are :mod:`tracking_bringup.dds`'s.)
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence

from vehicle_common.node_runtime import DIAGNOSTICS_TOPIC

from tracking_bringup.supervision import ProcessSpec


class ReportObserver:
    """Subscribes ``on_reports`` to /diagnostics; :meth:`spin` delivers the messages."""

    _made = 0  # observer nodes made in this process

    def __init__(self, env: dict[str, str], on_reports: Callable[[object], None]):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        # The observer must join the children's DDS domain with the same transport settings;
        # rmw reads them from this process's environment when the participant is created.
        os.environ.update(
            {k: v for k, v in env.items() if k.startswith(("ROS_", "RMW_", "FASTRTPS_"))}
        )
        self._context = Context()
        rclpy.init(context=self._context, args=[])
        ReportObserver._made += 1  # one name per observer, also with two in one process
        self.node = rclpy.create_node(
            f"graph_launcher_{os.getpid()}_{ReportObserver._made}",
            context=self._context,
            start_parameter_services=False,
        )
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, on_reports, 50)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self.node)

    def spin(self, timeout: float) -> None:
        """Take the messages (node reports) for up to ``timeout`` seconds."""
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            self._executor.spin_once(timeout_sec=left)

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(timeout_sec=1.0)
            self._executor = None
        if self.node is not None:
            self.node.destroy_node()
            self.node = None
        if self._context is not None:
            self._context.try_shutdown()
            self._context = None

    def foreign_publishers(self, specs: Sequence[ProcessSpec]) -> list[str]:
        """The topics of ``specs`` that have more publishers in the ROS graph than ``specs``:
        another graph on the same ROS domain without its own namespace (or the publisher of a
        process killed in the last seconds, which discovery still lists)."""
        ours: dict[str, int] = {}
        for spec in specs:
            for topic in spec.publishes:
                ours[topic] = ours.get(topic, 0) + 1
        out = []
        for topic, n in sorted(ours.items()):
            have = self.node.count_publishers(topic)
            if have > n:
                out.append(f"{topic} ({have} publishers, {n} of this graph)")
        return out

    def missing_endpoints(self, specs: Sequence[ProcessSpec]) -> list[str]:
        """Human-readable list of endpoints of ``specs`` not yet visible in the graph."""
        obs = self.node
        missing = []
        for spec in specs:
            for topic in spec.subscribes:
                nodes = {i.node_name for i in obs.get_subscriptions_info_by_topic(topic)}
                if spec.name not in nodes:
                    missing.append(f"{spec.name} subscription {topic}")
            for topic in spec.publishes:
                nodes = {i.node_name for i in obs.get_publishers_info_by_topic(topic)}
                if spec.name not in nodes:
                    missing.append(f"{spec.name} publisher {topic}")
        return missing
