"""The graph description knows the odometry and TF edges: the recorder records the stereo
node's odometry, /tf and /tf_static; the tracker subscribes to /tf and /tf_static only with a
``tracks_frame``; without the visual odometry (or with an output off) there is no such edge to
wait for."""

from __future__ import annotations

from tracking_bringup.environment import PARAMS_FILE
from vehicle_common.graph_readiness import parse_topic_counts

from tracking_bringup import graph


def _wait(overrides: dict[str, list[str]] | None = None) -> dict[str, int]:
    planned = graph.plan(list(graph.PIPELINE), PARAMS_FILE, overrides or {})
    (player,) = [extra for spec, extra in planned if spec.name == graph.PLAYER.name]
    return parse_topic_counts(player["wait_for_topics"])


def test_the_recorder_records_odometry_and_tf():
    wait = _wait()
    assert wait[graph.ODOMETRY] == 1 and wait[graph.TF] == 1 and wait[graph.TF_STATIC] == 1
    # vision_msgs topics are outputs for other software, recorded since issue #42: the
    # recorder is their one subscriber in the graph
    assert wait["vehicles/vision/tracks"] == 1 and wait["vehicles/vision/detections_2d"] == 1


def test_tracks_in_odom_add_the_trackers_tf_subscriptions():
    wait = _wait({"vehicle_tracker": ["tracks_frame:=odom"]})
    assert wait[graph.TF] == 2 and wait[graph.TF_STATIC] == 2
    assert wait[graph.ODOMETRY] == 1


def test_no_odometry_edges_without_the_visual_odometry_or_an_output():
    wait = _wait(
        {"stereo_depth": ["visual_odometry:=false"], "vehicle_tracker": ["tracks_frame:=odom"]}
    )
    assert not {graph.ODOMETRY, graph.TF, graph.TF_STATIC} & set(wait)
    wait = _wait({"stereo_depth": ["publish_tf:=false"]})
    assert graph.TF not in wait and wait[graph.ODOMETRY] == 1 and wait[graph.TF_STATIC] == 1


def test_back_pressure_edge_only_for_a_live_camera_and_off_in_lockstep():
    """Issue #39: without lockstep the detector subscribes to the 3D arrays (its back-pressure)
    and the player waits for that edge; in lockstep the launchers set downstream_window 0."""
    # the shipped file plays in lockstep: tracker + recorder take the 3D arrays
    planned = graph.plan(list(graph.PIPELINE), PARAMS_FILE, {})
    (det,) = [extra for spec, extra in planned if spec.name == graph.DETECTOR.name]
    assert det["downstream_window"] == 0 and _wait()[graph.DETECTIONS_3D] == 2
    live = {"kitti_player": ["lockstep:=false"]}
    planned = graph.plan(list(graph.PIPELINE), PARAMS_FILE, live)
    (det,) = [extra for spec, extra in planned if spec.name == graph.DETECTOR.name]
    assert "downstream_window" not in det and _wait(live)[graph.DETECTIONS_3D] == 3
    off = {**live, "vehicle_detector": ["downstream_window:=0"]}
    assert _wait(off)[graph.DETECTIONS_3D] == 2
