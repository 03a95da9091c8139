"""The launchers keep the image consumers in step with the player's ``image_transport``: the
detector and stereo depth get ``image_transport: compressed`` and the image edges the player
waits for are the ``.../compressed`` topics; the multi-host profile's setting reaches both hosts."""

from __future__ import annotations

import argparse

import pytest
from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.hosts import HostProfileError, add_arguments, launch_plan

from tracking_bringup import graph


def _plan(overrides: dict[str, list[str]], nodes=None):
    whole = graph.by_name(None)
    return {n.name: (n, extra) for n, extra in graph.plan(nodes or whole, PARAMS_FILE, overrides)}


@pytest.mark.parametrize("transport", ["png", "jpeg"])
def test_compressed_player_sets_consumers_and_edges(transport):
    planned = _plan({"kitti_player": [f"image_transport:={transport}"]})
    for name in ("vehicle_detector", "stereo_depth"):
        spec, extra = planned[name]
        assert extra["image_transport"] == "compressed"
        assert "stereo/left/image_rect/compressed" in spec.subscribes
        assert "stereo/left/image_rect" not in spec.subscribes
    player, extra = planned["kitti_player"]
    waits = dict(e.split(":") for e in extra["wait_for_topics"].split(","))
    assert waits["stereo/left/image_rect/compressed"] == "2"  # detector + stereo depth
    assert waits["stereo/right/image_rect/compressed"] == "1"
    assert "stereo/left/image_rect" not in waits
    assert "image_transport" not in planned["vehicle_tracker"][1]


def test_raw_is_the_default_and_an_override_wins():
    planned = _plan({})
    assert planned["stereo_depth"][1]["image_transport"] == "raw"
    assert "stereo/left/image_rect" in planned["vehicle_detector"][0].subscribes
    mine = _plan(
        {"kitti_player": ["image_transport:=png"], "stereo_depth": ["image_transport:=raw"]}
    )
    assert "image_transport" not in mine["stereo_depth"][1]  # the user's -p is kept


def _launch_plan(params, *argv):
    parser = argparse.ArgumentParser()
    parser.add_argument("--params", default=str(params))
    parser.add_argument("--nodes")
    add_arguments(parser)
    return launch_plan(parser.parse_args(list(argv)))


def test_host_profile_image_transport_reaches_both_hosts(tmp_path):
    text = PARAMS_FILE.read_text()
    params = tmp_path / "p.yaml"
    assert 'image_transport: "raw"' in text.split("stereo_tracking_launch:")[1]
    params.write_text(
        text.replace(
            'image_transport: "raw"  # multi-host', 'image_transport: "jpeg"  # multi-host'
        )
    )
    for host in ("camera", "compute"):
        plan = _launch_plan(params, "--host", host, "--peers", "10.0.0.9")
        assert "kitti_player.image_transport:=jpeg" in plan.overrides
    params.write_text(
        text.replace('image_transport: "raw"  # multi-host', 'image_transport: "gif"  # multi-host')
    )
    with pytest.raises(
        HostProfileError, match="image_transport: 'gif' is not one of raw, png, jpeg"
    ):
        _launch_plan(params, "--host", "camera", "--peers", "10.0.0.9")
    # one host (no profile): nothing implied
    assert not any("image_transport" in o for o in _launch_plan(PARAMS_FILE).overrides)


@pytest.mark.parametrize("transport", ["raw", "jpeg"])
def test_recorder_records_the_images_where_they_travel(transport):
    """`image_transport:=jpeg` with `include_images:=true` recorded no image: the recorder
    subscribed to the raw topics, which nobody published. With include_images the recorder
    now follows the player's transport like the other image subscribers, and the player waits
    for its image subscriptions too (no image is lost at the start)."""
    planned = _plan(
        {
            "kitti_player": [f"image_transport:={transport}"],
            "bag_recorder": ["include_images:=true"],
        }
    )
    recorder, extra = planned["bag_recorder"]
    suffix = "" if transport == "raw" else "/compressed"
    assert extra["image_transport"] == ("raw" if transport == "raw" else "compressed")
    assert f"stereo/left/image_rect{suffix}" in recorder.subscribes
    assert f"stereo/right/image_rect{suffix}" in recorder.subscribes
    waits = dict(e.split(":") for e in planned["kitti_player"][1]["wait_for_topics"].split(","))
    assert waits[f"stereo/left/image_rect{suffix}"] == "3"  # detector, stereo depth, recorder
    assert waits[f"stereo/right/image_rect{suffix}"] == "2"
    # without include_images the recorder takes no image
    recorder, extra = _plan({"kitti_player": [f"image_transport:={transport}"]})["bag_recorder"]
    assert "image_transport" not in extra and not any("image" in t for t in recorder.subscribes)


def test_recorder_image_topics_follow_its_transport():
    from eval_node.recorder import parse_topics

    assert parse_topics([], True, "compressed") == {
        "stereo/left/image_rect/compressed": "sensor_msgs/msg/CompressedImage",
        "stereo/right/image_rect/compressed": "sensor_msgs/msg/CompressedImage",
        "stereo/disparity": "stereo_msgs/msg/DisparityImage",
        "stereo/points": "sensor_msgs/msg/PointCloud2",
    }
    raw = parse_topics([], True)
    assert raw["stereo/left/image_rect"] == "sensor_msgs/msg/Image" and len(raw) == 4
    assert parse_topics(["/a:std_msgs/msg/String"], False, "compressed") == {
        "/a": "std_msgs/msg/String"
    }


def test_own_camera_compressed_path_expects_the_compressed_topics():
    """Issue #42 failure 5: no player, the consumers told to take compressed images: the
    readiness plan waits for their subscriptions on ``.../compressed``, not the raw topics."""
    nodes = graph.by_name(["vehicle_detector", "stereo_depth", "vehicle_tracker"])
    overrides = {n: ["image_transport:=compressed"] for n in ("vehicle_detector", "stereo_depth")}
    planned = {n.name: (n, e) for n, e in graph.plan(nodes, PARAMS_FILE, overrides)}
    for name in ("vehicle_detector", "stereo_depth"):
        spec = planned[name][0]
        assert "stereo/left/image_rect/compressed" in spec.subscribes
        assert "stereo/left/image_rect" not in spec.subscribes
    assert "stereo/right/image_rect/compressed" in planned["stereo_depth"][0].subscribes


def test_camera_reliability_is_reliable_only_behind_the_graphs_player():
    """Issue #42 item 1: with the graph's own player the image consumers subscribe RELIABLE
    (lockstep loses nothing); with a user's camera they keep their default, "auto", which
    follows the camera's publishers; a user's -p wins."""
    with_player = _plan({})
    for name in ("vehicle_detector", "stereo_depth"):
        assert with_player[name][1]["camera_reliability"] == "reliable"
    assert "camera_reliability" not in with_player["vehicle_tracker"][1]
    own = graph.by_name(["vehicle_detector", "stereo_depth", "vehicle_tracker"])
    for _spec, extra in graph.plan(own, PARAMS_FILE, {}):
        assert "camera_reliability" not in extra
    mine = _plan({"stereo_depth": ["camera_reliability:=best_effort"]})
    assert "camera_reliability" not in mine["stereo_depth"][1]


def test_camera_reliability_across_hosts_follows_the_players_host():
    plan = _launch_plan(PARAMS_FILE, "--graph", ",".join(n.name for n in graph.PIPELINE))
    assert plan.overrides == []  # every node here (with the player): graph.plan sets it
    args = ["--nodes", "vehicle_detector,stereo_depth", "--graph"]
    args.append("kitti_player,vehicle_detector,stereo_depth,vehicle_tracker")
    remote = _launch_plan(PARAMS_FILE, *args)
    assert "stereo_depth.camera_reliability:=reliable" in remote.overrides
    assert "vehicle_detector.camera_reliability:=reliable" in remote.overrides
    own = _launch_plan(PARAMS_FILE, "--nodes", "vehicle_detector,stereo_depth")
    assert not any("camera_reliability" in o for o in own.overrides)
