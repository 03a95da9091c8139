"""The workspace builds with a plain ``colcon build`` (the pip toolchain stands in for a full
ROS 2 install), and the ROS launch file stays in sync with the graph, entry points and
parameter file."""

import ast
import importlib.util
import os
import shutil
import subprocess
import sys
import types
from pathlib import Path

import pytest
import yaml
from tracking_bringup.environment import PARAMS_FILE

from tracking_bringup import graph

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILE = REPO / "src" / "tracking_bringup" / "launch" / "stereo_tracking.launch.py"


def console_scripts(package: str) -> set[str]:
    """Console-script names declared in src/<package>/setup.py (read statically)."""
    tree = ast.parse((REPO / "src" / package / "setup.py").read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values, strict=True):
                if isinstance(key, ast.Constant) and key.value == "console_scripts":
                    names |= {e.value.split("=")[0].strip() for e in value.elts}
    return names


class _Recorder:
    """Stands in for a launch/launch_ros class: records its constructor arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _LaunchConfiguration(_Recorder):
    """Stands in for LaunchConfiguration: ``perform(context)`` looks the argument up."""

    def perform(self, context):
        return context[self.args[0]]


def _load_launch_description():
    stubs = {
        "launch": {"LaunchDescription": _Recorder},
        "launch.actions": {"DeclareLaunchArgument": _Recorder, "OpaqueFunction": _Recorder},
        "launch.conditions": {"IfCondition": _Recorder},
        "launch.substitutions": {"LaunchConfiguration": _LaunchConfiguration},
        "launch_ros.actions": {"Node": type("Node", (_Recorder,), {})},
        "launch_ros": {},
        "ament_index_python.packages": {
            "get_package_share_directory": lambda p: str(REPO / "src" / p)
        },
    }
    saved = {name: sys.modules.get(name) for name in stubs}
    try:
        for name, attrs in stubs.items():
            mod = types.ModuleType(name)
            mod.__dict__.update(attrs)
            sys.modules[name] = mod
        spec = importlib.util.spec_from_file_location("launch_under_test", LAUNCH_FILE)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module.generate_launch_description()
    finally:
        for name, mod in saved.items():
            if mod is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = mod


def _launched_nodes(description, params_file=PARAMS_FILE, record="true"):
    """The Node actions the launch file's OpaqueFunction returns for these launch arguments."""
    (opaque,) = [a for a in description.args[0] if "function" in a.kwargs]
    actions = opaque.kwargs["function"]({"params_file": str(params_file), "record": record})
    return [a for a in actions if type(a).__name__ == "Node"]


def test_launch_file_matches_graph_entry_points_and_params():
    description = _load_launch_description()
    nodes = _launched_nodes(description)
    described = [(n.kwargs["name"], n.kwargs["package"], n.kwargs["executable"]) for n in nodes]
    assert described == [(s.name, s.package, s.executable) for s in graph.PIPELINE]
    params = yaml.safe_load(PARAMS_FILE.read_text())
    for name, package, executable in described:
        assert executable in console_scripts(package), f"{package} lacks {executable}"
        assert "ros__parameters" in params.get(name, {}), f"{PARAMS_FILE} lacks {name}"
    # every section of the parameter file belongs to a node of the graph
    assert set(params) == {s.name for s in graph.PIPELINE}


@pytest.mark.slow
def test_colcon_build_of_the_workspace(tmp_path):
    colcon = Path(sys.executable).parent / "colcon"
    if not colcon.is_file():
        pytest.skip("colcon is not installed in this environment")
    ws = tmp_path / "ws"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build", "install", "log")
    shutil.copytree(REPO / "msg_defs", ws / "msg_defs", ignore=ignore)
    shutil.copytree(REPO / "src", ws / "src", ignore=ignore)
    shutil.copy(REPO / "colcon.meta", ws / "colcon.meta")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(Path(sys.executable).parent.parent))
    result = subprocess.run(
        [str(colcon), "build"], cwd=ws, env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    for spec in graph.PIPELINE:
        for exe in console_scripts(spec.package):
            assert (ws / "install" / spec.package / "lib" / spec.package / exe).is_file()
    share = ws / "install" / "tracking_bringup" / "share" / "tracking_bringup"
    assert (share / "launch" / "stereo_tracking.launch.py").is_file()
    assert (share / "config" / "pipeline.params.yaml").is_file()
    models = ws / "install" / "detector_node" / "share" / "detector_node" / "models"
    assert (models / "tiny_synthetic.pt").is_file()
    # the generated Python interface imports from the colcon install
    site = next((ws / "install" / "stereo_vehicle_msgs" / "lib").glob("python3*/site-packages"))
    check = subprocess.run(
        [sys.executable, "-c", "import stereo_vehicle_msgs.msg as m; print(m.__file__)"],
        env=dict(env, PYTHONPATH=str(site)),
        capture_output=True,
        text=True,
    )
    assert check.returncode == 0, check.stderr
    assert check.stdout.startswith(str(site)), check.stdout


def test_launch_file_gives_the_player_every_edge_of_the_graph(tmp_path):
    """ros2 launch starts every node at once: the player must be told every edge of the graph
    actually launched (recorder or not, detector backend and lockstep from the parameter file)."""
    description = _load_launch_description()

    def player_wait(nodes):
        (player,) = [n for n in nodes if n.kwargs["name"] == graph.PLAYER.name]
        return player.kwargs["parameters"][1]["wait_for_topics"]

    full = player_wait(_launched_nodes(description))
    assert "/vehicles/detections_3d:2" in full  # stereo -> tracker and recorder
    assert "/vehicles/tracks:2" in full  # tracker -> recorder and the player (lockstep)
    assert "/vehicles/detections_2d:2" in full
    no_bag = _launched_nodes(description, record="false")
    assert graph.RECORDER.name not in [n.kwargs["name"] for n in no_bag]
    assert "/vehicles/detections_3d:1" in player_wait(no_bag)
    assert "/clock" not in player_wait(no_bag)  # only the recorder subscribes to it
    params = yaml.safe_load(PARAMS_FILE.read_text())
    params["kitti_player"]["ros__parameters"]["lockstep"] = False
    params["vehicle_detector"]["ros__parameters"]["backend"] = "oracle"
    other = tmp_path / "params.yaml"
    other.write_text(yaml.safe_dump(params))
    wait = player_wait(_launched_nodes(description, params_file=other))
    assert "/vehicles/tracks:1" in wait  # no lockstep subscription to wait for
    assert "/kitti/ground_truth:2" in wait  # the oracle detector reads the ground truth


def test_lockstep_window_sets_the_frame_queue_of_latest_frame_nodes():
    """K frames in flight in lockstep: the detector and stereo keep K waiting frames (nothing
    skipped); a -p override of the user's wins; off in real-time playback."""
    from tracking_bringup.launcher import graph_processes

    def argv_of(overrides):
        procs = graph_processes(graph.PIPELINE, PARAMS_FILE, overrides)
        return {p.name: " ".join(p.argv) for p in procs}

    on = argv_of(["kitti_player.lockstep:=true", "kitti_player.lockstep_window:=3"])
    assert "frame_queue:=3" in on[graph.DETECTOR.name]
    assert "frame_queue:=3" in on[graph.STEREO.name]
    assert "frame_queue" not in on[graph.TRACKER.name]
    mine = argv_of(
        [
            "kitti_player.lockstep:=true",
            "kitti_player.lockstep_window:=3",
            "stereo_depth.frame_queue:=1",
        ]
    )[graph.STEREO.name]
    assert mine.index("frame_queue:=3") < mine.index("frame_queue:=1")  # the later one wins
    off = argv_of(["kitti_player.lockstep:=false", "kitti_player.lockstep_window:=3"])
    assert "frame_queue" not in off[graph.DETECTOR.name]
