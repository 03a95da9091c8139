"""Helpers shared by the node tests (rclpy, no fixtures)."""

from __future__ import annotations

import time


def spin_until(executor, cond, timeout: float = 10.0) -> bool:
    """Spin ``executor`` until ``cond()`` holds or ``timeout`` seconds passed; returns
    ``cond()``."""
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return cond()
