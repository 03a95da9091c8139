"""Every node's parameters are typed and validated at start-up: a bad value gives ONE line naming
the node, the parameter and what is wrong, and exit code 2 (never a traceback)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest
from vehicle_common.node_parameters import (
    ParameterError,
    check_value,
    coerce,
    config_from_values,
    param,
)

# (node module, node name, ROS arguments, words the error line must contain)
BAD_STARTS = [
    ("kitti_player_node.node", "kitti_player", ["-p", "rate:=.nan"], ["rate", "finite"]),
    ("kitti_player_node.node", "kitti_player", ["-p", "first_frame:=-3"], ["first_frame", ">= 0"]),
    (
        "kitti_player_node.node",
        "kitti_player",
        ["-p", "lockstep_window:=0"],
        ["lockstep_window", ">= 1"],
    ),
    ("detector_node.node", "vehicle_detector", ["-p", "input_width:=-32"], ["input_width"]),
    ("detector_node.node", "vehicle_detector", ["-p", "nms_iou:=2.0"], ["nms_iou", "<= 1.0"]),
    ("detector_node.node", "vehicle_detector", ["-p", "frame_queue:=0"], ["frame_queue", ">= 1"]),
    ("stereo_depth_node.node", "stereo_depth", ["-p", "wls_lambda:=-5.0"], ["wls_lambda"]),
    ("stereo_depth_node.node", "stereo_depth", ["-p", "downscale:=8.7"], ["downscale"]),
    ("stereo_depth_node.node", "stereo_depth", ["-p", "num_threads:=-2"], ["num_threads", ">= 1"]),
    ("stereo_depth_node.node", "stereo_depth", ["-p", "frame_queue:=1.5"], ["frame_queue"]),
    # inverted or empty row bands (used to be read as the whole image)
    (
        "stereo_depth_node.node",
        "stereo_depth",
        ["-p", "match_rows:=[500, 100]"],
        ["match_rows", "[500, 100]", "0 <= top < bottom"],
    ),
    ("stereo_depth_node.node", "stereo_depth", ["-p", "match_rows:=[5, 5]"], ["match_rows"]),
    (
        "tracker_node.node",
        "vehicle_tracker",
        ["-p", "mahalanobis_gate:=.nan"],
        ["mahalanobis_gate", "finite"],
    ),
    ("tracker_node.node", "vehicle_tracker", ["-p", "process_noise:=abc"], ["process_noise"]),
    ("eval_node.recorder", "bag_recorder", ["-p", "qos_depth:=-1"], ["qos_depth", ">= 1"]),
    ("eval_node.recorder", "bag_recorder", ["-p", "flush_period:=0"], ["flush_period", "> 0"]),
    # every node's cpu_affinity (vehicle_common.node_runtime.apply_process_settings)
    (
        "tracker_node.node",
        "vehicle_tracker",
        ["-p", "cpu_affinity:=4095"],
        ["cpu_affinity", "CPU 4095 not available"],
    ),
    (
        "kitti_player_node.node",
        "kitti_player",
        ["-p", "cpu_affinity:=0-x"],
        ["cpu_affinity", "not a CPU number or range"],
    ),
    ("eval_node.recorder", "bag_recorder", ["-p", "cpu_affinity:=4095"], ["cpu_affinity"]),
    # every node's nice (the same function)
    ("stereo_depth_node.node", "stereo_depth", ["-p", "nice:=25"], ["nice", "<= 19"]),
    ("detector_node.node", "vehicle_detector", ["-p", "nice:=ten"], ["nice", "expected"]),
    (
        "tracker_node.node",
        "vehicle_tracker",
        ["-p", "keep_freed_memory:=maybe"],
        ["keep_freed_memory", "expected"],
    ),
    # a parameter the node does not have (misspelled): ROS leaves it unused without a word
    (
        "tracker_node.node",
        "vehicle_tracker",
        ["-p", "min_hit:=5"],
        ["min_hit: unknown parameter of this node (did you mean min_hits?)"],
    ),
    (
        "detector_node.node",
        "vehicle_detector",
        ["-p", "score_treshold:=0.5"],
        ["score_treshold: unknown parameter", "(did you mean score_threshold?)"],
    ),
    (
        "stereo_depth_node.node",
        "stereo_depth",
        ["-p", "num_thread:=1"],
        ["num_thread: unknown parameter", "(did you mean num_threads?)"],
    ),
    (
        "kitti_player_node.node",
        "kitti_player",
        ["-p", "lockstep_timout:=5.0"],
        ["lockstep_timout: unknown parameter", "(did you mean lockstep_timeout?)"],
    ),
    (
        "eval_node.recorder",
        "bag_recorder",
        ["-p", "compresion:=zstd"],
        ["compresion: unknown parameter", "(did you mean compression?)"],
    ),
    # every node's executor (the same function)
    (
        "stereo_depth_node.node",
        "stereo_depth",
        ["-p", "executor:=multi"],
        ["executor", "'multi' is not one of events, single_threaded"],
    ),
    ("stereo_depth_node.node", "stereo_depth", ["-p", "map_area:=road"], ["map_area"]),
]


@pytest.mark.parametrize("module,node,ros_args,words", BAD_STARTS)
def test_a_bad_parameter_stops_the_node_with_one_line_and_exit_2(
    module, node, ros_args, words, tmp_path
):
    r = subprocess.run(
        [sys.executable, "-m", module, "--ros-args", *ros_args, "-p", f"output:={tmp_path}/b"]
        if module == "eval_node.recorder"
        else [sys.executable, "-m", module, "--ros-args", *ros_args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.returncode == 2, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"error: {node}: parameter ")
    for w in words:
        assert w in lines[0], lines[0]


def test_a_misspelled_parameter_in_a_parameter_file_is_one_line(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("vehicle_detector:\n  ros__parameters:\n    score_treshold: 0.5\n")
    r = subprocess.run(
        [sys.executable, "-m", "detector_node.node", "--ros-args", "--params-file", str(params)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.strip().splitlines() == [
        "error: vehicle_detector: parameter score_treshold: unknown parameter of this node "
        "(did you mean score_threshold?)"
    ]


@pytest.mark.parametrize(
    ("module", "node", "ros_args", "line"),
    [
        (
            "tracker_node.node",
            "vehicle_tracker",
            ["-p", "min_hits:="],
            "error: vehicle_tracker: Couldn't parse parameter override rule: '-p min_hits:='",
        ),
        (
            "kitti_player_node.node",
            "kitti_player",
            ["-r", "__ns:=/rig-2"],
            "error: kitti_player: Couldn't parse remap rule: '-r __ns:=/rig-2' (Expected lexeme",
        ),
        (
            "eval_node.recorder",
            "bag_recorder",
            ["--params-file", "BAD"],
            "error: bag_recorder: Couldn't parse params file: '--params-file BAD' (Error parsing",
        ),
    ],
)
def test_ros_arguments_rcl_refuses_are_one_line(tmp_path, module, node, ros_args, line):
    """rclpy raises rcl's refusal of the command line as a traceback: one line instead."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("vehicle_tracker:\n  ros__parameters:\n    min_hits: [1,\n")
    args = [str(bad) if a == "BAD" else a for a in ros_args]
    r = subprocess.run(
        [sys.executable, "-m", module, "--ros-args", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(line.replace("BAD", str(bad))), r.stderr


def test_yaml_integer_for_a_float_is_accepted_by_the_node(tmp_path, rclpy_context):
    """``process_noise: 16`` (an integer for a float parameter) is accepted."""
    from rclpy.parameter import Parameter
    from tracker_node.node import VehicleTrackerNode

    node = VehicleTrackerNode(
        context=rclpy_context, parameter_overrides=[Parameter("process_noise", value=16)]
    )
    try:
        assert node.config.process_noise == 16.0 and isinstance(node.config.process_noise, float)
    finally:
        node.destroy_node()


def test_every_node_config_refuses_out_of_range_values():
    from detector_node.node import DetectorParameters
    from eval_node.recorder import RecorderParameters
    from kitti_player_node.node import PlayerParameters
    from tracker_node.config import TrackerConfig

    cases = [
        (TrackerConfig, "process_noise", -1.0),
        (TrackerConfig, "decay_rate", 1.5),
        (TrackerConfig, "min_hits", 0),
        (TrackerConfig, "dist_cap", float("inf")),
        (DetectorParameters, "score_threshold", -1.0),
        (DetectorParameters, "input_width", 33),
        (DetectorParameters, "num_threads", -1),
        (DetectorParameters, "oracle_drop_probability", 1.2),
        (PlayerParameters, "lockstep_timeout", -1.0),
        (PlayerParameters, "drop_probability", 2.0),
        (RecorderParameters, "max_bag_size", -1),
        (RecorderParameters, "compression", "lz4"),
    ]
    for cls, name, value in cases:
        with pytest.raises(ParameterError) as err:
            config_from_values(cls, {name: value})
        assert err.value.name == name, (cls, name, err.value)
    # and the defaults are valid
    for cls in {c for c, _, _ in cases}:
        config_from_values(cls, {})


def test_types_integers_for_floats_strict_booleans_whole_integers():
    assert coerce(8, 1.0) == 8.0 and isinstance(coerce(8, 1.0), float)
    assert coerce(3.0, 1) == 3 and isinstance(coerce(3.0, 1), int)
    assert coerce(("Car",), ["Car", "Van"]) == ["Car"]
    assert coerce([0, 1], (0.0, 0.0)) == (0.0, 1.0)
    for value, default in (
        (8.7, 1),
        ("true", False),
        (1, False),
        (True, 1.0),
        ("8", 1.0),
        ("Car", ["Car"]),
        ([1], "x"),
    ):
        with pytest.raises(ValueError):
            coerce(value, default)
    rule = dict(param(1.0, low=0.0, low_open=True).metadata)
    assert check_value("x", 2, 1.0, rule) == 2.0
    for bad in (0.0, float("nan"), -1):
        with pytest.raises(ParameterError, match="x"):
            check_value("x", bad, 1.0, rule)


def test_offline_configs_pass_over_the_process_parameters_of_the_shipped_file():
    """An offline tool builds a core's config from a node's section of the parameter file: the
    section's process parameters (cpu_affinity) are passed over, a misspelt one is refused."""
    import yaml
    from tracker_node.config import TrackerConfig
    from tracking_bringup.environment import PARAMS_FILE

    section = yaml.safe_load(PARAMS_FILE.read_text())["vehicle_tracker"]["ros__parameters"]
    assert "cpu_affinity" in section
    TrackerConfig.from_yaml(PARAMS_FILE)  # no "unknown parameter"

    @dataclasses.dataclass
    class Core:
        gain: float = param(1.0, low=0)

    assert config_from_values(Core, {"gain": 2, "cpu_affinity": "1"}).gain == 2.0
    with pytest.raises(ParameterError, match="cpu_afinity: unknown parameter"):
        config_from_values(Core, {"cpu_afinity": "1"})
