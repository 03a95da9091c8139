"""The node graph of the stereo tracking pipeline, described once.

Both the project's process launcher (``stereo_tracking_launch``) and the standard ROS launch file
(``launch/stereo_tracking.launch.py``, for users with a full ROS 2 install) build the graph from
this description with :func:`plan` (the detector's subscriptions from its ``backend`` parameter,
the player's ``wait_for_topics`` from the subscriptions of the other nodes), so the two cannot
drift apart. Topic names are relative; both launchers take a namespace that moves the graph.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from vehicle_common import topics


@dataclass(frozen=True)
class NodeSpec:
    """One node process of the graph.

    ``source`` nodes produce the data (the player); the launcher starts them only after every
    other node's subscriptions are up, so no frame is published into an unready graph.
    ``finishes`` nodes may exit on their own with code 0 (the player at the end of a sequence).
    """

    name: str
    package: str
    executable: str
    subscribes: tuple[str, ...] = ()
    publishes: tuple[str, ...] = ()
    source: bool = False
    finishes: bool = False
    optional: bool = False
    extra_args: tuple[str, ...] = field(default=())
    #: parameter through which a source node is told how many subscriptions to wait for per
    #: published topic ("topic:N,topic:N") before it publishes its first message
    wait_parameter: str | None = None


# topic names, relative: resolved in the graph's namespace (vehicle_common.topics)
LEFT_IMAGE = topics.LEFT_IMAGE
RIGHT_IMAGE = topics.RIGHT_IMAGE
LEFT_INFO = topics.LEFT_INFO
RIGHT_INFO = topics.RIGHT_INFO
GROUND_TRUTH = topics.GROUND_TRUTH
DETECTIONS_2D = topics.DETECTIONS_2D
DETECTIONS_3D = topics.DETECTIONS_3D
TRACKS = topics.TRACKS
TRACK_MARKERS = topics.TRACK_MARKERS
DISPARITY = topics.DISPARITY
CLOCK = topics.CLOCK

PLAYER = NodeSpec(
    name="kitti_player",
    package="kitti_player_node",
    executable="kitti_player",
    subscribes=(TRACKS,),  # lockstep
    publishes=(LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO, GROUND_TRUTH, CLOCK),
    source=True,
    finishes=True,
    wait_parameter="wait_for_topics",
)
DETECTOR = NodeSpec(
    name="vehicle_detector",
    package="detector_node",
    executable="vehicle_detector",
    subscribes=(LEFT_IMAGE,),
    publishes=(DETECTIONS_2D,),
)
STEREO = NodeSpec(
    name="stereo_depth",
    package="stereo_depth_node",
    executable="stereo_depth",
    subscribes=(LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO, DETECTIONS_2D),
    publishes=(DETECTIONS_3D, DISPARITY),
)
TRACKER = NodeSpec(
    name="vehicle_tracker",
    package="tracker_node",
    executable="vehicle_tracker",
    subscribes=(DETECTIONS_3D, LEFT_INFO),  # camera info: 2D boxes of coasting tracks
    publishes=(TRACKS, TRACK_MARKERS),
)
RECORDER = NodeSpec(
    name="bag_recorder",
    package="eval_node",
    executable="bag_recorder",
    subscribes=(
        LEFT_INFO,
        RIGHT_INFO,
        GROUND_TRUTH,
        CLOCK,
        DETECTIONS_2D,
        DETECTIONS_3D,
        TRACKS,
        TRACK_MARKERS,
    ),
    optional=True,
)

#: The detector with its ablation backend "oracle", which also reads the ground truth.
ORACLE_DETECTOR = replace(DETECTOR, subscribes=(LEFT_IMAGE, GROUND_TRUTH))

#: The whole pipeline in data-flow order.
PIPELINE: tuple[NodeSpec, ...] = (PLAYER, DETECTOR, STEREO, TRACKER, RECORDER)


def by_name(names: list[str] | None = None) -> list[NodeSpec]:
    """The pipeline's nodes with the given names (all when None), in data-flow order."""
    if names is None:
        return list(PIPELINE)
    known = {n.name: n for n in PIPELINE}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown node(s) {', '.join(unknown)}; known: {', '.join(known)}")
    return [n for n in PIPELINE if n.name in names]


def with_detector_backend(nodes: list[NodeSpec], backend: str) -> list[NodeSpec]:
    """``nodes`` with the detector's subscriptions matching its backend ("cnn" | "oracle")."""
    spec = ORACLE_DETECTOR if backend == "oracle" else DETECTOR
    return [spec if n.name == DETECTOR.name else n for n in nodes]


def expected_subscriptions(source: NodeSpec, nodes: list[NodeSpec]) -> dict[str, int]:
    """For each topic ``source`` publishes: how many of the other ``nodes`` subscribe to it."""
    return {
        topic: sum(topic in n.subscribes for n in nodes if n.name != source.name)
        for topic in source.publishes
    }


def wait_for_topics_value(source: NodeSpec, nodes: list[NodeSpec]) -> str:
    """The ``wait_for_topics`` value of a source node: ``"topic:N,..."`` (relative names)."""
    counts = expected_subscriptions(source, nodes)
    return ",".join(f"{t}:{c}" for t, c in counts.items() if c)


def parameter_value(params_file, overrides: list[str], node: str, name: str, default):
    """A node parameter's value: the last ``name:=value`` in ``overrides`` (that node's
    ``-p`` overrides), else the parameter file's value, else ``default``."""
    for ov in reversed(overrides):
        key, _, value = ov.partition(":=")
        if key == name:
            return value.strip("'\"")
    if params_file and Path(params_file).is_file():
        import yaml

        data = yaml.safe_load(Path(params_file).read_text()) or {}
        return data.get(node, {}).get("ros__parameters", {}).get(name, default)
    return default


def plan(
    nodes: list[NodeSpec],
    params_file=None,
    overrides: dict[str, list[str]] | None = None,
    graph_nodes: list[NodeSpec] | None = None,
) -> list[tuple[NodeSpec, dict[str, str]]]:
    """The graph to start: each node (the detector's subscriptions following its ``backend``
    parameter, from ``overrides[node]`` or the parameter file) with the parameters the
    launchers set on it (a source's ``wait_for_topics``, counted over ``graph_nodes``: the whole
    graph, also the nodes other hosts run; default ``nodes``)."""
    overrides = overrides or {}
    backend = parameter_value(
        params_file, overrides.get(DETECTOR.name, []), DETECTOR.name, "backend", "cnn"
    )
    nodes = with_detector_backend(list(nodes), str(backend))
    whole = nodes if graph_nodes is None else with_detector_backend(list(graph_nodes), backend)
    out = []
    for n in nodes:
        extra = {}
        if n.source and n.wait_parameter:
            extra[n.wait_parameter] = wait_for_topics_value(n, whole)
        out.append((n, extra))
    return out
