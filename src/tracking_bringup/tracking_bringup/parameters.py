"""Where the graph's node parameters are defined: each node's dataclasses in its package's pure
``parameters`` module (``kitti_player_node.parameters``, ``detector_node.parameters``,
``stereo_depth_node.parameters``, ``tracker_node.config`` + ``tracker_node.parameters``,
``eval_node.parameters``), with defaults, allowed values and one-line meanings. The launchers
and :func:`tracking_bringup.graph.plan` read a parameter's default from here (:func:`default`),
never retype it. The process parameters every node takes (``cpu_affinity``, ``nice``, ...) are
``vehicle_common.node_parameters.ProcessParameters``.

The graph's parameter file ``config/pipeline.params.yaml`` is generated from these dataclasses
(:mod:`tracking_bringup.parameter_docs`): every parameter at its node's default, except the
graph's own values (:data:`GRAPH_VALUES`, each with its reason) and the parameters the launchers
set for each run (:data:`LAUNCHER_SET`, left out of the file)."""

from __future__ import annotations

from functools import cache

from detector_node.parameters import DetectorParameters
from eval_node.parameters import RecorderParameters
from kitti_player_node.parameters import PlayerParameters
from stereo_depth_node.parameters import SECTIONS as STEREO_SECTIONS
from tracker_node.config import TrackerConfig
from tracker_node.parameters import TrackerNodeParameters
from vehicle_common.image_transport import ImageTransportParameters
from vehicle_common.node_parameters import ProcessParameters, defaults_of

#: node name -> its parameter dataclasses, each with (skipped fields, field -> parameter name)
_PROCESS = (ProcessParameters, (), {})
NODE_PARAMETERS = {
    "kitti_player": (_PROCESS, (PlayerParameters, (), {})),
    "vehicle_detector": (
        _PROCESS,
        (DetectorParameters, (), {}),
        (ImageTransportParameters, (), {}),
    ),
    "stereo_depth": (
        _PROCESS,
        *((cls, kw.get("skip", ()), kw.get("rename") or {}) for _, cls, kw in STEREO_SECTIONS),
    ),
    "vehicle_tracker": (_PROCESS, (TrackerConfig, (), {}), (TrackerNodeParameters, (), {})),
    "bag_recorder": (_PROCESS, (RecorderParameters, (), {})),
}

#: The graph's own values, where the shipped graph (config/pipeline.params.yaml) differs from a
#: node's default: node -> parameter -> (value, why). The node's default serves the node alone
#: (offline tools, another graph); these were chosen for the stereo graph on the data named.
GRAPH_VALUES = {
    "kitti_player": {
        "dataset_root": (
            "data/synthetic",
            "the synthetic scene (kitti_synth, stereo_tracking_demo); real KITTI: "
            "-p kitti_player.dataset_root:=.../tracking/training",
        ),
        "lockstep": (
            True,
            "the player waits for the tracks of each frame before the next: no frame is lost "
            'and a run is reproducible (README, "What a run promises")',
        ),
    },
    "vehicle_detector": {
        "num_threads": (1, "the stereo matcher runs beside it: on 2 cores one thread each"),
    },
    "stereo_depth": {
        "nice": (
            10,
            'the matcher yields to the detector\'s serial step (ARCHITECTURE.md, "CPU affinity")',
        ),
        "num_threads": (
            1,
            "on 2 cores the CNN holds one core while the map is computed: one thread gives the "
            "same latency with less CPU (2 threads on one core cost 15 % more)",
        ),
    },
    # the tracker's graph values: chosen on the camera benchmark's tuning sequences for the
    # shipped CenterNet's stereo detections (docs/tracker.md); the node's defaults are the
    # paper's / the offline LiDAR setting
    "vehicle_tracker": {
        "dist_cap": (12.0, "stereo: far cars range metres off (4.0 for LiDAR, offline)"),
        "init_velocity_var": (
            23.0,
            "the labelled cars' E[v_z^2] over the ground on the tuning sequences: velocity RMSE "
            "2.18 -> 2.02 m/s, MOTA / HOTA equal",
        ),
        "birth_max_speed": (
            15.0,
            "velocity hypotheses at birth: velocity RMSE tuning 1.63 -> 1.55, reporting "
            '2.85 -> 2.10 m/s (docs/tracker.md, "Velocity hypotheses at birth")',
        ),
        "stationary_prior": (
            0.8,
            "1 - birth_moving_prior: parked-car model on (issue #41): position jitter of matched "
            "cars 7.9 -> 6.9 x the labels'",
        ),
        "max_staleness": (
            6,
            "issue #34: a confirmed track lives 6 missed frames, reported for 3 (decay_rate, "
            "restoration_conf_threshold), then kept hidden for re-association",
        ),
        "coast_box": ("shifted", "the coasting 2D box keeps the detector's box shape (issue #34)"),
        "birth_score": (
            0.35,
            "issue #23: the shipped CNN's weaker detections only keep tracks alive",
        ),
        "min_hits": (3, "issue #23: confirmation rule for the shipped CNN's detections"),
        "min_hits_span": (
            0.2,
            "issue #39: min_hits 3 at KITTI's 10 Hz span 0.2 s; under overload (every 2nd or "
            "3rd frame processed) 2 matches over as long confirm (docs/tracker.md)",
        ),
        "motion_heading_max_std": (
            20.0,
            "issue #34: the heading of travel in the reported yaw once known within 20 deg",
        ),
        "bin_yaw_std": (10.0, "issue #34: the bins' yaw weighed at 10 deg against it"),
        "coast_min_distance": (
            2.0,
            "issue #41: a coasting track within 2 m of a matched one is not reported (a second "
            "track on its car); camera benchmark tuning precision 95.3 -> 96.4 % with "
            "coast_min_score (docs/tracker.md)",
        ),
        "coast_min_score": (
            0.42,
            "issue #41: a coasting track of weak detections (the CNN's false ones score 0.33-0.40) "
            "is not reported; recall 84.7 -> 84.5 %",
        ),
        "mahalanobis_gate": (
            50.0,
            "issue #41: a wider association gate with the robust update (camera benchmark, "
            "tuning, three draws: HOTA 2D / 3D +1.1 / +1.1, ID switches -23 of 29-72; velocity "
            "over the ground like for like +0.01 m/s; docs/tracker.md, fourth round)",
        ),
        "robust_update_k": (
            3.0,
            "issue #41: a detection more than 3 std off its track is taken with a wider "
            "covariance (Huber), so the wider gate's far matches move the state less",
        ),
        "world_entry_hypotheses": (
            True,
            "issue #41: tracks alive when the odometry starts (a robot switched on in traffic) "
            "take the birth hypotheses too; camera benchmark, tuning, 16-frame cold starts, three "
            "draws: velocity over the ground like for like -0.06 m/s (docs/tracker.md)",
        ),
        "box_gain": (
            0.3,
            "issue #41: a matched track's 2D box smoothed over frames (off-the-box false rows "
            "243 -> 88 on the camera benchmark's tuning sequences; real 0005 re-tracked: MOTA "
            "equal, HOTA 2D 70.4 -> 71.7; docs/tracker.md)",
        ),
    },
}

#: Parameters the launchers set on each run from the graph's description (graph.plan,
#: hosts.LaunchPlan), left out of the parameter file: a value there would stand for the user's
#: own and keep the launchers from setting it. node -> parameter -> how it is set.
LAUNCHER_SET = {
    "kitti_player": {
        "wait_for_topics": "every edge of the graph (graph.wait_for_topics_value)",
    },
    "vehicle_detector": {
        "image_transport": "raw or compressed, as the player's image_transport",
        "camera_reliability": "reliable behind the launchers' own player (lockstep), else auto",
    },
    "stereo_depth": {
        "image_transport": "raw or compressed, as the player's image_transport",
        "camera_reliability": "reliable behind the launchers' own player (lockstep), else auto",
    },
    "bag_recorder": {
        "image_transport": "with include_images: as the player's (recorded where they travel)",
    },
}

#: The launcher's own section of the parameter file (``stereo_tracking_launch``, read by
#: tracking_bringup.hosts; no node reads it): the host profiles of ``--host NAME`` and the
#: images on the link between hosts.
LAUNCH_PROFILES = {
    "image_transport": "raw",
    "hosts": {
        "camera": {
            "nodes": ["kitti_player", "vehicle_tracker", "bag_recorder"],
            "discovery": "peers",
        },
        "compute": {"nodes": ["vehicle_detector", "stereo_depth"], "discovery": "peers"},
    },
}


@cache
def node_defaults(node: str) -> dict:
    """Parameter name -> default of every parameter ``node`` declares from a dataclass."""
    out = {}
    for cls, skip, rename in NODE_PARAMETERS[node]:
        for name, value in defaults_of(cls).items():
            if name not in skip:
                out[rename.get(name, name)] = value
    return out


def default(node: str, name: str):
    """The default of ``node``'s parameter ``name`` (KeyError: no such parameter)."""
    try:
        return node_defaults(node)[name]
    except KeyError:
        raise KeyError(f"{node}: no parameter {name!r} in its dataclasses") from None


def graph_values(node: str) -> dict:
    """Parameter name -> value of every parameter the graph's file gives ``node``: its defaults
    with :data:`GRAPH_VALUES` applied, without :data:`LAUNCHER_SET`."""
    values = dict(node_defaults(node))
    for name, (value, _why) in GRAPH_VALUES.get(node, {}).items():
        if name not in values:
            raise KeyError(f"GRAPH_VALUES: {node} has no parameter {name!r}")
        values[name] = value
    for name in LAUNCHER_SET.get(node, {}):
        del values[name]
    return values
