"""Node subsets, host profiles and DDS settings of the launcher (no processes started)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
from tracking_bringup.dds import MULTIHOST_PROFILE, DdsSettingsError, DiscoverySettings, rtps_ports
from tracking_bringup.environment import FASTDDS_PROFILE, PARAMS_FILE
from tracking_bringup.hosts import HostProfileError, add_arguments, launch_plan, read_host_profiles
from tracking_bringup.launcher import graph_processes, main
from vehicle_common.graph_readiness import parse_topic_counts

from tracking_bringup import graph


def _plan(*argv: str, params: Path = PARAMS_FILE):
    parser = argparse.ArgumentParser()
    parser.add_argument("--params", default=str(params))
    parser.add_argument("--nodes")
    add_arguments(parser)
    return launch_plan(parser.parse_args(list(argv)))


def _wait_for_topics(processes) -> dict[str, int]:
    player = next(p for p in processes if p.name == graph.PLAYER.name)
    value = next(a for a in player.argv if a.startswith("wait_for_topics:="))
    return parse_topic_counts(value.split(":=", 1)[1])


def test_subset_waits_for_the_subscribers_of_the_whole_graph():
    """The player started alone on the camera host still waits for the detector and stereo
    depth elsewhere: counts come from the whole graph, not from the local nodes."""
    local = graph.by_name(["kitti_player", "vehicle_tracker", "bag_recorder"])
    alone = _wait_for_topics(graph_processes(local, PARAMS_FILE))
    whole = _wait_for_topics(graph_processes(local, PARAMS_FILE, graph_nodes=graph.PIPELINE))
    assert graph.LEFT_IMAGE not in alone  # only the local nodes: nobody reads images
    assert whole[graph.LEFT_IMAGE] == 2 and whole[graph.RIGHT_IMAGE] == 1
    assert whole[graph.LEFT_INFO] == 4  # detector (its framing), stereo depth, tracker, recorder
    # the detector's backend, given for a node that runs elsewhere, still shapes the counts
    oracle = graph_processes(
        local, PARAMS_FILE, ["vehicle_detector.backend:=oracle"], graph_nodes=graph.PIPELINE
    )
    assert _wait_for_topics(oracle)[graph.GROUND_TRUTH] == 2  # oracle detector + recorder
    assert len(oracle) == 3


def test_host_profiles_of_the_shipped_parameter_file():
    profiles = read_host_profiles(PARAMS_FILE)
    assert set(profiles) == {"camera", "compute"}
    plan = _plan("--host", "camera", "--peers", "10.0.0.2")
    assert plan.nodes == ["kitti_player", "vehicle_tracker", "bag_recorder"]
    assert plan.graph_nodes == [n.name for n in graph.PIPELINE]  # union of the profiles
    assert plan.discovery == DiscoverySettings("peers", ("10.0.0.2",))
    # the profiles' image_transport is the player's on both hosts
    transport = "kitti_player.image_transport:=raw"
    assert plan.overrides == ["kitti_player.match_settle_time:=3.0", transport]
    compute = _plan("--host", "compute", "--peers", "10.0.0.1")
    assert compute.nodes == ["vehicle_detector", "stereo_depth"]
    # the player runs on the other host: the image consumers subscribe RELIABLE (issue #42)
    reliable = [f"{n}.camera_reliability:=reliable" for n in ("vehicle_detector", "stereo_depth")]
    assert compute.overrides == [transport, *reliable]


def test_one_host_default_is_unchanged():
    plan = _plan()
    assert plan.nodes is None and plan.graph_nodes is None and plan.overrides == []
    env = plan.discovery.environment({})
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(FASTDDS_PROFILE)
    assert "ROS_STATIC_PEERS" not in env


def test_multihost_environment_overrides_inherited_one_host_settings():
    inherited = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": "7"}
    env = DiscoverySettings("peers", ("10.0.0.2", "cam.local")).environment(inherited)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"
    assert env["ROS_STATIC_PEERS"] == "10.0.0.2;cam.local"
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(MULTIHOST_PROFILE)
    assert env["ROS_DOMAIN_ID"] == "7"
    subnet = DiscoverySettings("subnet").environment({"ROS_STATIC_PEERS": "1.2.3.4"})
    assert "ROS_STATIC_PEERS" not in subnet


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--host", "nowhere"], "no host profile 'nowhere'"),
        (["--host", "camera", "--nodes", "kitti_player"], "--nodes and --host"),
        (["--discovery", "peers"], "needs at least one peer"),
        (["--discovery", "localhost", "--peers", "10.0.0.2"], "given with discovery 'localhost'"),
        (["--peers", "10.0.0.2;rm"], "not an address or host name"),
        (["--nodes", "kitti_player", "--graph", "vehicle_tracker"], "does not hold"),
        (["--graph", "kitti_player,warp_drive"], "unknown node(s) warp_drive"),
        (["--transport-profile", "/nonexistent.xml"], "profile file not found"),
    ],
)
def test_bad_options_are_one_clear_error(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err and "\n" not in err


def test_malformed_host_profile_names_the_field(tmp_path):
    bad = tmp_path / "params.yaml"
    bad.write_text(
        "stereo_tracking_launch:\n  ros__parameters:\n    hosts:\n"
        "      camera:\n        nodes: [kitti_player, hovercraft]\n"
    )
    with pytest.raises(
        HostProfileError, match=r"hosts\.camera\.nodes: unknown node\(s\) hovercraft"
    ):
        read_host_profiles(bad)


def test_rtps_ports_follow_the_specification():
    ports = rtps_ports(0)
    assert ports["multicast_discovery"] == [7400]
    assert ports["unicast_discovery"][:2] == [7410, 7412]
    assert ports["unicast_user"][:2] == [7411, 7413]
    assert rtps_ports(5)["multicast_discovery"] == [7400 + 250 * 5]
    with pytest.raises(DdsSettingsError):
        rtps_ports(233)
