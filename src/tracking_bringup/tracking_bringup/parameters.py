"""Where the graph's node parameters are defined: each node's dataclasses in its package's pure
``parameters`` module (``kitti_player_node.parameters``, ``detector_node.parameters``,
``stereo_depth_node.parameters``, ``tracker_node.config`` + ``tracker_node.parameters``,
``eval_node.parameters``), with defaults, allowed values and one-line meanings. The launchers
and :func:`tracking_bringup.graph.plan` read a parameter's default from here (:func:`default`),
never retype it. The process parameters every node takes (``cpu_affinity``, ``nice``, ...) are
``vehicle_common.node_runtime``'s."""

from __future__ import annotations

from functools import cache

from detector_node.parameters import DetectorParameters
from eval_node.parameters import RecorderParameters
from kitti_player_node.parameters import PlayerParameters
from stereo_depth_node.parameters import SECTIONS as STEREO_SECTIONS
from tracker_node.config import TrackerConfig
from tracker_node.parameters import TrackerNodeParameters
from vehicle_common.image_transport import ImageTransportParameters
from vehicle_common.node_parameters import defaults_of

#: node name -> its parameter dataclasses, each with (skipped fields, field -> parameter name)
NODE_PARAMETERS = {
    "kitti_player": ((PlayerParameters, (), {}),),
    "vehicle_detector": (
        (DetectorParameters, (), {}),
        (ImageTransportParameters, (), {}),
    ),
    "stereo_depth": tuple(
        (cls, kw.get("skip", ()), kw.get("rename") or {}) for _, cls, kw in STEREO_SECTIONS
    ),
    "vehicle_tracker": ((TrackerConfig, (), {}), (TrackerNodeParameters, (), {})),
    "bag_recorder": ((RecorderParameters, (), {}),),
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
