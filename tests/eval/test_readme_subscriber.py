"""The README's minimal /vehicles/tracks subscriber runs, prints a track and, on Ctrl-C
(SIGINT), exits with code 0 and no traceback."""

from __future__ import annotations

import re
import signal
import time
from pathlib import Path

from tests.ros_helpers import start_script

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_subscriber() -> str:
    text = README.read_text()
    start = text.index("A minimal subscriber")
    m = re.compile(r"```python\n(.*?)```", re.S).search(text, start)
    assert m, "no python block after 'A minimal subscriber' in README.md"
    return m.group(1)


def test_readme_subscriber_prints_tracks_and_stops_cleanly(tmp_path, rclpy_context):
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from stereo_vehicle_msgs.msg import TrackedVehicle, TrackedVehicleArray

    script = tmp_path / "track_printer.py"
    script.write_text(readme_subscriber())
    proc, lines, reader = start_script(script)
    node = rclpy.create_node("readme_test_pub", context=rclpy_context)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(TrackedVehicleArray, "/vehicles/tracks", qos)
    try:
        msg = TrackedVehicleArray()
        v = TrackedVehicle(track_id=7, state=TrackedVehicle.STATE_CONFIRMED)
        v.position.x, v.position.z = 1.5, 12.25
        msg.vehicles = [v]
        deadline = time.monotonic() + 30
        while not any("id 7: x=1.5 z=12.2 m" in line for line in lines):
            assert time.monotonic() < deadline and proc.poll() is None, "".join(lines)
            if pub.get_subscription_count():
                pub.publish(msg)
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(20)
        reader.join(5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        node.destroy_node()
    out = "".join(lines)
    assert rc == 0, out
    assert "Traceback" not in out and "Exception" not in out, out
