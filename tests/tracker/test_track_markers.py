"""Track markers for RViz: a DELETEALL first (no stale boxes after a restart) and a finite
lifetime on every added marker (boxes vanish when the tracker stops)."""

from __future__ import annotations

import numpy as np


def _tracks(n: int):
    from tracker_node.tracker import TrackSet

    return TrackSet(
        track_id=np.arange(1, n + 1),
        state=np.ones(n, int),
        confidence=np.full(n, 0.9),
        position=np.tile([1.0, 1.5, 12.0], (n, 1)),
        position_cov=np.tile(np.eye(3), (n, 1, 1)),
        velocity=np.tile([0.0, 0.0, 1.0], (n, 1)),
        velocity_cov=np.tile(np.eye(3), (n, 1, 1)),
        size=np.tile([3.9, 1.6, 1.5], (n, 1)),
        yaw=np.zeros(n),
        orientation_bin=np.zeros(n, int),
        bbox=np.tile([10.0, 10.0, 50.0, 40.0], (n, 1)),
        age=np.ones(n, int),
        frames_since_update=np.zeros(n, int),
        score=np.full(n, 0.9),
        class_id=["car"] * n,
        det_index=np.arange(n),
        velocity_over_ground=np.full((n, 3), np.nan),
        velocity_over_ground_cov=np.full((n, 3, 3), np.nan),
    )


def test_markers_clear_first_and_expire():
    from std_msgs.msg import Header
    from tracker_node.conversions import MARKER_LIFETIME_S, markers_for
    from visualization_msgs.msg import Marker

    header = Header(frame_id="left_camera_optical_frame")
    arr = markers_for(_tracks(2), header, ended_ids=[5])
    first, rest = arr.markers[0], arr.markers[1:]
    assert first.action == Marker.DELETEALL and first.header.frame_id == header.frame_id
    added = [m for m in rest if m.action == Marker.ADD]
    assert len(added) == 6  # box, label, arrow per track
    for m in added:
        life = m.lifetime.sec + m.lifetime.nanosec * 1e-9
        assert life == MARKER_LIFETIME_S and 0.2 <= life <= 1.0  # a few 10 Hz frame periods
    assert [m.id for m in rest if m.action == Marker.DELETE] == [5, 5, 5]
    empty = markers_for(_tracks(0), header, ended_ids=[])
    assert [m.action for m in empty.markers] == [Marker.DELETEALL]
