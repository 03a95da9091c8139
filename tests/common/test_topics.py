"""Relative topic names, resolved in a namespace; the namespace of a recorded bag."""

from vehicle_common.bags.recorded_run import bag_namespace

from vehicle_common import topics


def test_topics_are_relative_and_resolve_in_a_namespace():
    assert all(not t.startswith("/") for t in topics.ALL)
    assert topics.resolve(topics.TRACKS) == "/vehicles/tracks"
    assert topics.resolve(topics.TRACKS, "rig2") == "/rig2/vehicles/tracks"
    assert topics.resolve(topics.TRACKS, "/rig2/") == "/rig2/vehicles/tracks"
    assert topics.resolve("/absolute", "/rig2") == "/absolute"
    assert topics.normalise_namespace("/") == ""


def test_bag_namespace_is_detected_from_recorded_names():
    assert bag_namespace(["/kitti/ground_truth", "/vehicles/tracks"]) == ""
    assert bag_namespace(["/rig2/kitti/ground_truth", "/rig2/clock"]) == "/rig2"
    assert bag_namespace(["/a/b/vehicles/tracks"]) == "/a/b"  # no ground truth: the tracks'
    # two graphs in one bag: ambiguous, the caller must name the namespace
    assert bag_namespace(["/r1/kitti/ground_truth", "/r2/kitti/ground_truth"]) == ""
