"""The summary line of a run at a camera rate (issue #39) and the camera's overrides."""

import pytest
from tracking_bringup.frame_summary import FrameLatency, camera_overrides, summary_line


def test_camera_overrides_play_at_the_rate_without_lockstep():
    assert camera_overrides(30) == [
        "kitti_player.rate:=30",
        "kitti_player.rate_multiplier:=1.0",
        "kitti_player.lockstep:=false",
    ]
    with pytest.raises(ValueError, match="--camera-hz"):
        camera_overrides(0)


def test_summary_line_says_tracked_dropped_where_and_latency():
    lat = FrameLatency()
    for k in range(4):
        lat.on_clock(k, 10.0 + k)
    lat.on_tracks(0, 10.1)
    lat.on_tracks(3, 13.3)
    lat.on_tracks(7, 20.0)  # its clock was not seen: no latency
    line = summary_line(4, 2, {"kitti_player": 0, "vehicle_detector": 2}, lat.latencies_ms(), 30)
    assert line.startswith("camera 30 Hz: 2 of 4 frames tracked, 2 dropped (vehicle_detector 2)")
    assert "mean 200 ms" in line
    assert summary_line(4, 4, {}, [], None) == (
        "lockstep: 4 of 4 frames tracked, 0 dropped, no latency measured"
    )
