"""The processes' command lines (tracking_bringup.node_processes); graph_processes with real
parameter files is in test_parameter_file.py and test_launch_plan.py."""

import sys
from pathlib import Path

import pytest
from tracking_bringup.node_processes import graph_processes, node_command, resolve_executable
from tracking_bringup.supervision import LaunchError

from tracking_bringup import graph


def test_a_console_script_is_found_next_to_the_interpreter_or_named_when_missing():
    python = Path(sys.executable).name
    assert resolve_executable(python) == str(Path(sys.executable).parent / python)
    with pytest.raises(LaunchError, match="executable 'no_such_node_xyz' not found"):
        resolve_executable("no_such_node_xyz")


def test_node_command_has_name_namespace_file_and_overrides():
    argv = node_command(graph.TRACKER, "/tmp/p.yaml", ["a:=1"], namespace="rig2")
    assert argv[0] == resolve_executable(graph.TRACKER.executable)
    i = argv.index("--ros-args")
    assert argv[i + 1 :] == [
        "-r",
        f"__node:={graph.TRACKER.name}",
        "-r",
        "__ns:=/rig2",
        "--params-file",
        "/tmp/p.yaml",
        "-p",
        "a:=1",
    ]
    assert "__ns" not in " ".join(node_command(graph.TRACKER, None))


@pytest.mark.parametrize(
    "override, message",
    [
        ("vehicle_tracker.x", "expected NODE.PARAM:=VALUE"),
        ("nobody.x:=1", "expected NODE.PARAM:=VALUE"),
        ("vehicle_tracker.x:=", "no value"),
        ("vehicle_tracker.x:=[1, 2", "not a YAML value"),
    ],
)
def test_a_bad_override_is_one_line(override, message):
    with pytest.raises(LaunchError, match=message) as err:
        graph_processes([graph.TRACKER], None, [override])
    assert "\n" not in str(err.value)
