"""The node graph of the stereo tracking pipeline, described once.

Both the project's process launcher (``stereo_tracking_launch``) and the standard ROS launch file
(``launch/stereo_tracking.launch.py``, for users with a full ROS 2 install) build the graph from
this description, so the two cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace


@dataclass(frozen=True)
class NodeSpec:
    """One node process of the graph.

    ``source`` nodes produce the data (the player). They are told, through ``wait_parameter``,
    how many subscriptions every topic of the graph must have matched (:func:`edge_counts`) and
    publish nothing before (the other nodes report their matches on /diagnostics), so no frame
    is published into an unready graph whatever the start order; the process launcher also
    starts them last.
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
    #: topic of the graph ("topic:N,topic:N") before it publishes its first message
    wait_parameter: str | None = None
    #: the node processes the newest frame and skips older waiting ones (``frame_queue``
    #: parameter: how many newest frames may wait)
    latest_frame: bool = False


LEFT_IMAGE = "/stereo/left/image_rect"
RIGHT_IMAGE = "/stereo/right/image_rect"
LEFT_INFO = "/stereo/left/camera_info"
RIGHT_INFO = "/stereo/right/camera_info"
GROUND_TRUTH = "/kitti/ground_truth"
DETECTIONS_2D = "/vehicles/detections_2d"
DETECTIONS_3D = "/vehicles/detections_3d"
TRACKS = "/vehicles/tracks"
TRACK_MARKERS = "/vehicles/track_markers"
DISPARITY = "/stereo/disparity"
CLOCK = "/clock"

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
    latest_frame=True,
)
STEREO = NodeSpec(
    name="stereo_depth",
    package="stereo_depth_node",
    executable="stereo_depth",
    subscribes=(LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO, DETECTIONS_2D),
    publishes=(DETECTIONS_3D, DISPARITY),
    latest_frame=True,
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


def with_lockstep(nodes: list[NodeSpec], lockstep: bool) -> list[NodeSpec]:
    """``nodes`` with the player's lockstep subscription (the tracks) only when it is on."""
    spec = PLAYER if lockstep else replace(PLAYER, subscribes=())
    return [spec if n.name == PLAYER.name else n for n in nodes]


def as_bool(value) -> bool:
    """A boolean parameter value from a YAML file or a ``-p`` override string."""
    return value if isinstance(value, bool) else str(value).strip().lower() == "true"


def edge_counts(nodes: list[NodeSpec], extra: dict[str, int] | None = None) -> dict[str, int]:
    """For every topic published by one of ``nodes``: how many of the other ``nodes`` subscribe
    to it (plus ``extra`` subscribers outside the graph, e.g. the demo's progress display). Topics
    nobody subscribes to are left out. These are the edges a source waits for."""
    counts: dict[str, int] = {}
    for pub in nodes:
        for topic in pub.publishes:
            n = sum(topic in s.subscribes for s in nodes if s.name != pub.name)
            n += (extra or {}).get(topic, 0)
            if n:
                counts[topic] = max(counts.get(topic, 0), n)
    return counts


def source_parameters(
    nodes: list[NodeSpec], extra: dict[str, int] | None = None
) -> dict[str, dict[str, str]]:
    """``{source node: {wait_parameter: "topic:N,..."}}`` for the sources among ``nodes``: every
    edge of the graph (:func:`edge_counts`) must be matched before they publish."""
    spec = ",".join(f"{t}:{n}" for t, n in edge_counts(nodes, extra).items())
    return {n.name: {n.wait_parameter: spec} for n in nodes if n.source and n.wait_parameter}


def parameter_value(params_file, node: str, name: str, default):
    """A parameter's value in a ROS parameter YAML file (``default`` when absent)."""
    from pathlib import Path

    if not params_file or not Path(params_file).is_file():
        return default
    import yaml

    data = yaml.safe_load(Path(params_file).read_text()) or {}
    return data.get(node, {}).get("ros__parameters", {}).get(name, default)


def frame_queue_parameters(nodes: list[NodeSpec], lockstep_window: int) -> dict[str, dict]:
    """In lockstep with ``lockstep_window`` K frames in flight, up to K frames may wait at a
    latest-frame node: ``{node: {"frame_queue": K}}`` so that none is skipped."""
    return {n.name: {"frame_queue": int(lockstep_window)} for n in nodes if n.latest_frame}
