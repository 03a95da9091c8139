"""bag_recorder on a disk that fills up (a small tmpfs): one line naming the recorder, the bag
and the cause, exit code 1, and a bag that the project's readers open with what was flushed
(issue #42: chained `OSError: [Errno 28]` tracebacks)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest


@contextlib.contextmanager
def _small_disk(path: Path, size: str):
    """A tmpfs of ``size`` mounted at ``path`` (skips where it cannot be mounted: not root)."""
    path.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
        capture_output=True,
        text=True,
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs to fill ({mounted.stderr.strip()})")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def test_full_disk_is_one_line_exit_1_and_a_readable_bag(tmp_path, rclpy_context):
    import numpy as np
    import rclpy
    from sensor_msgs.msg import Image
    from vehicle_common.bags.reader import open_reader

    with _small_disk(tmp_path / "disk", "3m") as disk:
        bag = disk / "bag"
        proc = subprocess.Popen(
            [sys.executable, "-m", "eval_node.recorder", "--ros-args"]
            + ["-p", f"output:={bag}", "-p", "topics:=['/big:sensor_msgs/msg/Image']"]
            + ["-p", "flush_period:=0.2"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=dict(os.environ),
        )
        node = rclpy.create_node("disk_filler", context=rclpy_context)
        pub = node.create_publisher(Image, "/big", 100)
        rng = np.random.default_rng(0)
        msg = Image(height=100, width=1000, encoding="mono8", step=1000)
        try:
            deadline = time.monotonic() + 90
            while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            sent = 0
            while proc.poll() is None and time.monotonic() < deadline:
                msg.data = rng.integers(0, 255, 100_000, dtype=np.uint8).tobytes()
                msg.header.stamp.sec = sent
                pub.publish(msg)
                sent += 1
                time.sleep(0.02)  # 5 MB/s: the 3 MB disk is full in under a second
            out, err = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            node.destroy_node()
        assert proc.returncode == 1, out + err
        assert "Traceback" not in out + err
        lines = [line for line in err.splitlines() if not line.startswith("[INFO]")]
        assert len(lines) == 1, err  # (rclpy's log lines go to stderr too)
        assert lines[0].startswith(f"error: bag_recorder: cannot write the bag {bag}: ")
        assert "No space left on device (errno 28)" in lines[0]
        reader = open_reader(bag, warn=lambda text: None)  # read up to the last flushed chunk
        try:
            kept = sum(1 for _ in reader.messages())
        finally:
            reader.close()
        assert 0 < kept < sent
