"""Helpers shared by the node and graph tests (rclpy, rosbags; no fixtures)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path


def spin_until(executor, cond, timeout: float = 10.0) -> bool:
    """Spin ``executor`` until ``cond()`` holds or ``timeout`` seconds passed; returns
    ``cond()``."""
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return cond()


def start_script(script) -> tuple[subprocess.Popen, list[str], threading.Thread]:
    """Run a Python script in this interpreter and environment; returns the process, the list
    its output lines (stdout and stderr) are appended to as they come, and the thread that
    appends them (join it after the process ends to have every line)."""
    proc = subprocess.Popen(
        [sys.executable, str(script)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ),
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    return proc, lines, reader


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
