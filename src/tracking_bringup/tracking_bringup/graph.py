"""The node graph of the stereo tracking pipeline, described once.

Both the project's process launcher (``stereo_tracking_launch``) and the standard ROS launch file
(``launch/stereo_tracking.launch.py``, for users with a full ROS 2 install) build the graph from
this description with :func:`plan` (the detector's subscriptions from its ``backend`` parameter,
the player's from its ``lockstep``, the stereo node's odometry and TF outputs from its
``visual_odometry`` / ``publish_*`` parameters, the tracker's TF subscriptions from its
``tracks_frame``, the player's ``wait_for_topics`` from every edge of the graph,
the latest-frame nodes' ``frame_queue`` from the player's ``lockstep_window``), so the two cannot
drift apart. Topic names are relative; both launchers take a namespace that moves the graph.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from vehicle_common.graph_readiness import format_topic_counts
from vehicle_common.image_transport import subscriber_transport

from tracking_bringup import parameter_file
from vehicle_common import topics


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
ODOMETRY = topics.ODOMETRY
TF = topics.TF
TF_STATIC = topics.TF_STATIC
IMAGES = (LEFT_IMAGE, RIGHT_IMAGE)

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
    subscribes=(LEFT_IMAGE, LEFT_INFO),  # camera info: the framing derived from the camera
    # the started frames: the CNN's (the stereo node begins their work that needs no boxes)
    publishes=(DETECTIONS_2D, topics.VISION_DETECTIONS_2D, topics.DETECTIONS_2D_STARTED),
    latest_frame=True,
)
STEREO = NodeSpec(
    name="stereo_depth",
    package="stereo_depth_node",
    executable="stereo_depth",
    subscribes=(
        LEFT_IMAGE,
        RIGHT_IMAGE,
        LEFT_INFO,
        RIGHT_INFO,
        DETECTIONS_2D,
        topics.DETECTIONS_2D_STARTED,
    ),
    publishes=(DETECTIONS_3D, DISPARITY, ODOMETRY, TF, TF_STATIC),
    latest_frame=True,
)
TRACKER = NodeSpec(
    name="vehicle_tracker",
    package="tracker_node",
    executable="vehicle_tracker",
    subscribes=(DETECTIONS_3D, LEFT_INFO),  # camera info: 2D boxes of coasting tracks
    publishes=(TRACKS, TRACK_MARKERS, topics.VISION_TRACKS),
)
RECORDER = NodeSpec(
    name="bag_recorder",
    package="eval_node",
    executable="bag_recorder",
    subscribes=topics.RECORDED,
    optional=True,
)

#: The detector with its ablation backend "oracle", which also reads the ground truth.
ORACLE_DETECTOR = replace(
    DETECTOR,
    subscribes=(LEFT_IMAGE, GROUND_TRUTH),
    publishes=(DETECTIONS_2D, topics.VISION_DETECTIONS_2D),  # no CNN time: announces nothing
)

#: the nodes that compute on the camera's images (parameters image_transport and
#: camera_reliability, vehicle_common.image_transport)
IMAGE_CONSUMERS = (DETECTOR.name, STEREO.name)

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


def with_back_pressure(nodes: list[NodeSpec], on: bool) -> list[NodeSpec]:
    """``nodes`` with the detector subscribing to the 3D arrays when its back-pressure is on
    (a live camera: ``downstream_window`` > 0 with the CNN, not in lockstep), the end of each
    frame it detected (vehicle_common.flow_control)."""
    if not on:
        return nodes
    return [
        replace(n, subscribes=(*n.subscribes, DETECTIONS_3D)) if n.name == DETECTOR.name else n
        for n in nodes
    ]


def with_recorded_images(nodes: list[NodeSpec], include_images: bool) -> list[NodeSpec]:
    """``nodes`` with the recorder subscribing to the camera images when it records them
    (``include_images``): the sources then wait for its image subscriptions too, and
    :func:`with_image_transport` moves them to the topics the images travel on."""
    if not include_images:
        return nodes
    spec = replace(RECORDER, subscribes=(*RECORDER.subscribes, *IMAGES))
    return [spec if n.name == RECORDER.name else n for n in nodes]


def with_odometry_outputs(
    nodes: list[NodeSpec], odometry: bool, tf: bool, static_tf: bool
) -> list[NodeSpec]:
    """``nodes`` with the stereo node's odometry (``stereo/odometry``), ``tf`` and ``tf_static``
    publishers only where its parameters create them (``visual_odometry`` and each
    ``publish_*``): an edge nobody publishes would keep the player waiting."""
    off = {ODOMETRY: not odometry, TF: not tf, TF_STATIC: not static_tf}
    spec = replace(STEREO, publishes=tuple(t for t in STEREO.publishes if not off.get(t, False)))
    return [spec if n.name == STEREO.name else n for n in nodes]


def with_tracks_frame(nodes: list[NodeSpec], tracks_frame: str) -> list[NodeSpec]:
    """``nodes`` with the tracker's /tf and /tf_static subscriptions when it publishes its
    tracks in another frame than the camera's (``tracks_frame`` not "")."""
    if not tracks_frame:
        return list(nodes)
    spec = replace(TRACKER, subscribes=(*TRACKER.subscribes, TF, TF_STATIC))
    return [spec if n.name == TRACKER.name else n for n in nodes]


def with_image_transport(nodes: list[NodeSpec], transport: str) -> list[NodeSpec]:
    """``nodes`` with the image topics of the player's ``image_transport``: the raw topics for
    "raw", ``.../compressed`` (sensor_msgs/CompressedImage) for "png" and "jpeg"."""
    swap = {t: topics.image_topic(t, transport) for t in IMAGES}

    def swapped(names: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(swap.get(t, t) for t in names)

    return [
        replace(n, subscribes=swapped(n.subscribes), publishes=swapped(n.publishes)) for n in nodes
    ]


def with_own_transport(node: NodeSpec, transport: str) -> NodeSpec:
    """``node`` subscribed to the images on the topics of its own ``image_transport`` ("raw" or
    "compressed"; a camera of the user's, no player: issue #42's compressed path)."""
    swap = {}
    for t in IMAGES:
        swap[t] = swap[topics.image_topic(t, "compressed")] = topics.image_topic(t, transport)
    return replace(node, subscribes=tuple(swap.get(t, t) for t in node.subscribes))


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


def wait_for_topics_value(nodes: list[NodeSpec], extra: dict[str, int] | None = None) -> str:
    """The ``wait_for_topics`` value of a source node: ``"topic:N,..."`` over every edge of the
    graph :func:`edge_counts` (relative names)."""
    return format_topic_counts(edge_counts(nodes, extra))


def node_overrides(overrides, node: str) -> list[str]:
    """``PARAM:=VALUE`` of the ``NODE.PARAM:=VALUE`` overrides that address ``node``."""
    return [ov.split(".", 1)[1] for ov in overrides if ov.startswith(node + ".")]


def file_parameters(params, namespace: str = "") -> dict[str, dict]:
    """``{node: {parameter: value}}`` of the graph's nodes: ``params`` itself when it is such
    a mapping already, else the parameter file ``params`` as the nodes read it in
    ``namespace`` (:func:`parameter_file.node_parameters`; a list of files: layered; {} per
    node for None or a missing file)."""
    if isinstance(params, Mapping):
        return {n.name: dict(params.get(n.name, {})) for n in PIPELINE}
    files = [f for f in parameter_file.as_files(params or []) if f.is_file()]
    if files:  # several: the layers of a run (parameter_file.layers), key by key
        return parameter_file.node_parameters(files, [n.name for n in PIPELINE], namespace)
    return {n.name: {} for n in PIPELINE}


_NODE_DEFAULT = object()


def node_default(node: str, name: str):
    """A node parameter's own default, from the dataclass that defines it
    (:mod:`tracking_bringup.parameters`; imported when first needed: the node packages)."""
    from tracking_bringup.parameters import default

    return default(node, name)


def parameter_value(params, overrides: list[str], node: str, name: str, default=_NODE_DEFAULT):
    """A node parameter's value: the last ``name:=value`` in ``overrides`` (that node's
    ``-p`` overrides), else the parameter file's value (``params``: a file, or its
    :func:`file_parameters`), else ``default`` (omitted: the node's own default,
    :func:`tracking_bringup.parameters.default`)."""
    for ov in reversed(overrides):
        key, _, value = ov.partition(":=")
        if key == name:
            return value.strip("'\"")
    if default is _NODE_DEFAULT:
        default = node_default(node, name)
    return file_parameters(params).get(node, {}).get(name, default)


def _lockstep_window(value) -> int | None:
    """The player's ``lockstep_window`` as the launchers read it; None when it is no whole
    number >= 1 (the player then stops with its own one-line parameter error)."""
    try:
        window = int(str(value).strip())
    except ValueError:
        return None
    return window if window >= 1 else None


def _check_unpaced(rate, multiplier, whole: list[NodeSpec]) -> None:
    """ValueError (one line) for an unpaced player (``rate`` or ``rate_multiplier`` <= 0)
    without lockstep in a graph with a latest-frame node: the player then publishes far
    faster than that node takes frames and its input queues (KEEP_LAST) overwrite frames that
    no node ever sees or counts (issue #42: 0005, the player 16 out, the detector 8 in)."""
    try:
        hz = float(str(rate).strip("'\"")) * float(str(multiplier).strip("'\""))
    except ValueError:
        return  # the player refuses the value itself, with its own line
    consumers = [n.name for n in whole if n.latest_frame]
    if hz <= 0 and consumers:
        raise ValueError(
            f"{PLAYER.name}: rate {rate} x rate_multiplier {multiplier} (unpaced) without "
            f"lockstep: the player would publish faster than {', '.join(consumers)} take "
            "frames, and their input queues would lose frames that no node counts; set "
            f"{PLAYER.name}.lockstep:=true (as fast as the graph allows), or a rate > 0"
        )


def plan(
    nodes: list[NodeSpec],
    params_file=None,
    overrides: dict[str, list[str]] | None = None,
    graph_nodes: list[NodeSpec] | None = None,
    extra_subscriptions: dict[str, int] | None = None,
) -> list[tuple[NodeSpec, dict[str, str | int]]]:
    """The graph to start: each node (the detector's subscriptions following its ``backend``
    parameter, the player's its ``lockstep`` parameter, from ``overrides[node]`` or the
    parameter file ``params_file``, a path or its :func:`file_parameters`) with the parameters
    the launchers set on it:

    - a source's ``wait_for_topics``: every edge of the graph (:func:`edge_counts`), counted
      over ``graph_nodes`` (the whole graph, also the nodes other hosts run; default ``nodes``)
      plus ``extra_subscriptions`` per topic from outside the graph (a progress display);
    - in lockstep with ``lockstep_window`` K frames in flight, ``frame_queue: K`` on the
      latest-frame nodes, so that none of the K frames waiting there is skipped (unless the
      node's ``frame_queue`` is overridden), and ``downstream_window: 0`` on the detector (no
      back-pressure: the player paces the graph); without lockstep, the detector's
      back-pressure edge (:func:`with_back_pressure`);
    - on the nodes that subscribe to the images (the recorder too when its
      ``include_images`` is on), ``image_transport`` "raw" or "compressed" as the player's
      ``image_transport`` ("raw" | "png" | "jpeg") says (unless overridden), and the image
      edges on the matching topics (a detector or stereo node given its own
      ``image_transport``: that one's topics);
    - on the detector and stereo nodes, ``camera_reliability: reliable`` when the graph's own
      player, started with them, is the camera (lockstep loses no frame; unless overridden;
      across hosts :class:`tracking_bringup.hosts.LaunchPlan` sets it). Without it they keep
      their default, "auto": the reliability of the camera's publishers, any camera."""
    overrides = overrides or {}
    params = file_parameters(params_file)

    def value(node: NodeSpec, name: str, default=_NODE_DEFAULT):
        return parameter_value(params, overrides.get(node.name, []), node.name, name, default)

    backend = str(value(DETECTOR, "backend"))
    lockstep = as_bool(value(PLAYER, "lockstep"))
    transport = str(value(PLAYER, "image_transport"))
    images = as_bool(value(RECORDER, "include_images"))
    odometry = as_bool(value(STEREO, "visual_odometry"))
    outputs = [
        odometry and as_bool(value(STEREO, f"publish_{k}")) for k in ("odometry", "tf", "static_tf")
    ]
    tracks_frame = str(value(TRACKER, "tracks_frame") or "")

    def own_transport(n: NodeSpec) -> NodeSpec:
        own = value(n, "image_transport", None) if n.name in IMAGE_CONSUMERS else None
        return n if own is None else with_own_transport(n, str(own))

    # the detector's back-pressure: off in lockstep (the player paces the graph)
    back_pressure = backend == "cnn" and not lockstep
    back_pressure = back_pressure and int(value(DETECTOR, "downstream_window")) > 0

    def shaped(specs: list[NodeSpec]) -> list[NodeSpec]:
        specs = with_lockstep(with_detector_backend(list(specs), backend), lockstep)
        specs = with_back_pressure(specs, back_pressure)
        specs = with_tracks_frame(with_odometry_outputs(specs, *outputs), tracks_frame)
        specs = with_image_transport(with_recorded_images(specs, images), transport)
        return [own_transport(n) for n in specs]

    nodes = shaped(nodes)
    whole = nodes if graph_nodes is None else shaped(graph_nodes)
    if not lockstep and any(n is PLAYER or n.name == PLAYER.name for n in nodes):
        _check_unpaced(value(PLAYER, "rate"), value(PLAYER, "rate_multiplier"), whole)
    window = _lockstep_window(value(PLAYER, "lockstep_window")) if lockstep else None
    player = any(n.name == PLAYER.name for n in nodes)  # started here (else: hosts.py)
    return [
        (n, _launch_parameters(n, overrides, window, transport, player, whole, extra_subscriptions))
        for n in nodes
    ]


def _launch_parameters(
    n: NodeSpec, overrides, window, transport: str, player: bool, whole, extra_subscriptions
) -> dict[str, str | int]:
    """The parameters :func:`plan` sets on node ``n`` (see there), those in ``overrides``
    left out."""
    extra: dict[str, str | int] = {}
    overridden = {ov.partition(":=")[0] for ov in overrides.get(n.name, [])}
    if window is not None and n.latest_frame and "frame_queue" not in overridden:
        extra["frame_queue"] = window
    if window is not None and n.name == DETECTOR.name and "downstream_window" not in overridden:
        extra["downstream_window"] = 0  # lockstep: nothing changes
    images_in = any(topics.image_topic(t, transport) in n.subscribes for t in IMAGES)
    if images_in and "image_transport" not in overridden:
        extra["image_transport"] = subscriber_transport(transport)
    if player and n.name in IMAGE_CONSUMERS and "camera_reliability" not in overridden:
        extra["camera_reliability"] = "reliable"
    if n.source and n.wait_parameter:
        extra[n.wait_parameter] = wait_for_topics_value(whole, extra_subscriptions)
    return extra
