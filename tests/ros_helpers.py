"""Helpers shared by the node and graph tests (rclpy, rosbags; no fixtures)."""

from __future__ import annotations

import time
from pathlib import Path


def spin_until(executor, cond, timeout: float = 10.0) -> bool:
    """Spin ``executor`` until ``cond()`` holds or ``timeout`` seconds passed; returns
    ``cond()``."""
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return cond()


def bag_counts(bag: Path, namespace: str = "") -> dict[str, int]:
    """Messages per topic of a recorded graph in ``namespace``, by the graph's relative names
    (the bag holds the resolved ones)."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        return {
            c.topic.removeprefix(namespace + "/"): c.msgcount
            for c in reader.connections
            if c.topic.startswith(namespace + "/")
        }
