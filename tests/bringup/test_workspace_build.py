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
from vehicle_common.graph_readiness import parse_topic_counts

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
    """Stands in for launch's LaunchConfiguration: ``perform`` reads the fake context."""

    def perform(self, context):
        return context[self.args[0]]


def _load_launch_description():
    stubs = {
        "launch": {"LaunchDescription": _Recorder},
        "launch.actions": {
            "DeclareLaunchArgument": _Recorder,
            "OpaqueFunction": type("OpaqueFunction", (_Recorder,), {}),
        },
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


def _launch_nodes(description, **arguments):
    """The Node actions the launch file creates for the given launch arguments (defaults from
    its DeclareLaunchArgument actions)."""
    context = {}
    for a in description.args[0]:
        if type(a).__name__ == "_Recorder" and "default_value" in a.kwargs:
            context[a.args[0]] = a.kwargs["default_value"]
    context.update(arguments)
    opaque = [a for a in description.args[0] if type(a).__name__ == "OpaqueFunction"]
    assert len(opaque) == 1
    fn = opaque[0].kwargs["function"]
    return fn(context, *opaque[0].kwargs.get("args", []))


def test_launch_file_matches_graph_entry_points_and_params():
    description = _load_launch_description()
    nodes = _launch_nodes(description)
    described = [(n.kwargs["name"], n.kwargs["package"], n.kwargs["executable"]) for n in nodes]
    assert described == [(s.name, s.package, s.executable) for s in graph.PIPELINE]
    params = yaml.safe_load(PARAMS_FILE.read_text())
    for name, package, executable in described:
        assert executable in console_scripts(package), f"{package} lacks {executable}"
        assert "ros__parameters" in params.get(name, {}), f"{PARAMS_FILE} lacks {name}"
    # every section of the parameter file belongs to a node of the graph, or is the launcher's
    # (host profiles, read by stereo_tracking_launch only)
    from tracking_bringup.hosts import LAUNCH_SECTION

    assert set(params) - {LAUNCH_SECTION} == {s.name for s in graph.PIPELINE}
    no_recorder = _launch_nodes(description, record="false")
    assert [n.kwargs["name"] for n in no_recorder] == [s.name for s in graph.PIPELINE[:-1]]


def _argv_parameters(argv: list[str]) -> dict[str, str]:
    """The ``-p name:=value`` overrides of a command line."""
    return dict(argv[i + 1].split(":=", 1) for i, a in enumerate(argv) if a == "-p")


@pytest.mark.parametrize("backend", ["cnn", "oracle"])
@pytest.mark.parametrize("namespace", ["", "/rig2"])
def test_launch_file_and_launcher_agree_on_namespace_wait_for_topics_and_oracle(
    tmp_path, backend, namespace
):
    """Same nodes, namespace and launcher-set parameters (the player's wait_for_topics, which
    counts the oracle detector's ground-truth subscription) from both launchers."""
    from tracking_bringup.launcher import graph_processes

    params = yaml.safe_load(PARAMS_FILE.read_text())
    params["vehicle_detector"]["ros__parameters"]["backend"] = backend
    params_file = tmp_path / "params.yaml"
    params_file.write_text(yaml.safe_dump(params))
    nodes = _launch_nodes(
        _load_launch_description(), params_file=str(params_file), namespace=namespace
    )
    processes = graph_processes(list(graph.PIPELINE), params_file, namespace=namespace)
    assert [n.kwargs["name"] for n in nodes] == [p.name for p in processes]
    for node, proc in zip(nodes, processes, strict=True):
        assert node.kwargs["namespace"] == namespace
        ns_args = [proc.argv[i + 1] for i, a in enumerate(proc.argv) if a == "-r"]
        assert (f"__ns:={namespace}" in ns_args) == bool(namespace)
        extra = {k: str(v) for d in node.kwargs["parameters"][1:] for k, v in d.items()}
        assert extra == _argv_parameters(proc.argv)
        # both hand every node the file's section under its fully qualified name (rcl reads a
        # plain "vehicle_tracker:" section as /vehicle_tracker only: issue #35)
        given = yaml.safe_load(Path(node.kwargs["parameters"][0]).read_text())
        launched = proc.argv[proc.argv.index("--params-file") + 1]
        assert given == yaml.safe_load(Path(launched).read_text())
        fqn = f"{namespace}/{node.kwargs['name']}"
        assert given[fqn]["ros__parameters"] == params[node.kwargs["name"]]["ros__parameters"]
        # the readiness check looks for the namespaced topics
        assert all(t.startswith(namespace + "/") for t in (*proc.subscribes, *proc.publishes))
    player = _argv_parameters(processes[0].argv)["wait_for_topics"]
    gt = parse_topic_counts(player)[graph.GROUND_TRUTH]
    assert gt == (2 if backend == "oracle" else 1)  # recorder (+ oracle detector)


@pytest.mark.slow
def test_colcon_build_of_the_workspace(tmp_path):
    colcon = Path(sys.executable).parent / "colcon"
    if not colcon.is_file():
        pytest.skip("colcon is not installed in this environment")
    ws = tmp_path / "ws"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build", "install", "log")
    shutil.copytree(REPO / "msg_defs", ws / "msg_defs", ignore=ignore)
    shutil.copytree(REPO / "src", ws / "src", ignore=ignore)
    # upstream interface packages for the pip install: colcon must not build a second
    # vision_msgs / tf2_msgs beside a ROS install's (their folder has a COLCON_IGNORE)
    shutil.copytree(REPO / "third_party_msgs", ws / "third_party_msgs", ignore=ignore)
    shutil.copy(REPO / "colcon.meta", ws / "colcon.meta")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(Path(sys.executable).parent.parent))
    result = subprocess.run(
        [str(colcon), "build"], cwd=ws, env=env, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    built = {p.name for p in (ws / "install").iterdir() if p.is_dir()}
    assert not built & {"vision_msgs", "tf2_msgs"}, built
    assert {"stereo_vehicle_msgs", *(s.package for s in graph.PIPELINE)} <= built
    for spec in graph.PIPELINE:
        for exe in console_scripts(spec.package):
            assert (ws / "install" / spec.package / "lib" / spec.package / exe).is_file()
    share = ws / "install" / "tracking_bringup" / "share" / "tracking_bringup"
    assert (share / "launch" / "stereo_tracking.launch.py").is_file()
    assert (share / "config" / "pipeline.params.yaml").is_file()
    models = ws / "install" / "detector_node" / "share" / "detector_node" / "models"
    from detector_node.checkpoint import SHIPPED_CHECKPOINT

    assert (models / SHIPPED_CHECKPOINT.name).is_file()
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


def test_colcon_sees_no_second_vision_msgs_or_tf2_msgs_in_the_repository(monkeypatch):
    """The packages colcon discovers at the repository root (what ``colcon build`` there
    builds): the project's, not the upstream interface copies that setup.sh builds for the pip
    install (third_party_msgs/, COLCON_IGNORE), which would shadow a ROS install's."""
    import argparse

    discovery = pytest.importorskip("colcon_core.package_discovery")
    from colcon_core.package_identification import get_package_identification_extensions

    parser = argparse.ArgumentParser()
    discovery.add_package_discovery_arguments(parser)
    monkeypatch.chdir(REPO)
    found = discovery.discover_packages(
        parser.parse_args([]),
        get_package_identification_extensions(),
        discovery_extensions=discovery.get_package_discovery_extensions(),
    )
    names = {d.name for d in found}
    assert {"stereo_vehicle_msgs", *(s.package for s in graph.PIPELINE)} <= names
    assert not names & {"vision_msgs", "tf2_msgs"}, names
    # and the copies are there to be found without the marker
    assert (REPO / "third_party_msgs" / "vision_msgs" / "package.xml").is_file()


def test_launch_file_gives_the_player_every_edge_of_the_graph(tmp_path):
    """ros2 launch starts every node at once: the player must be told every edge of the graph
    actually launched (recorder or not, detector backend and lockstep from the parameter file)."""
    description = _load_launch_description()

    def player_wait(nodes):
        (player,) = [n for n in nodes if n.kwargs["name"] == graph.PLAYER.name]
        return parse_topic_counts(player.kwargs["parameters"][1]["wait_for_topics"])

    full = player_wait(_launch_nodes(description))
    assert full[graph.DETECTIONS_3D] == 2  # stereo -> tracker and recorder
    assert full[graph.TRACKS] == 2  # tracker -> recorder and the player (lockstep)
    assert full[graph.DETECTIONS_2D] == 2
    no_bag = _launch_nodes(description, record="false")
    assert graph.RECORDER.name not in [n.kwargs["name"] for n in no_bag]
    assert player_wait(no_bag)[graph.DETECTIONS_3D] == 1
    assert graph.CLOCK not in player_wait(no_bag)  # only the recorder subscribes to it
    params = yaml.safe_load(PARAMS_FILE.read_text())
    params["kitti_player"]["ros__parameters"]["lockstep"] = False
    params["vehicle_detector"]["ros__parameters"]["backend"] = "oracle"
    other = tmp_path / "params.yaml"
    other.write_text(yaml.safe_dump(params))
    wait = player_wait(_launch_nodes(description, params_file=str(other)))
    assert wait[graph.TRACKS] == 1  # no lockstep subscription to wait for
    assert wait[graph.GROUND_TRUTH] == 2  # the oracle detector reads the ground truth


def test_lockstep_window_sets_the_frame_queue_of_latest_frame_nodes():
    """K frames in flight in lockstep: the detector and stereo keep K waiting frames (nothing
    skipped); a -p override of the user's wins (the launchers then set none); off in real-time
    playback; the launch file sets the same."""
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
    assert "frame_queue:=1" in mine and "frame_queue:=3" not in mine
    off = argv_of(["kitti_player.lockstep:=false", "kitti_player.lockstep_window:=3"])
    assert "frame_queue" not in off[graph.DETECTOR.name]
    bad = argv_of(["kitti_player.lockstep:=true", "kitti_player.lockstep_window:=0"])
    assert "frame_queue" not in bad[graph.DETECTOR.name]  # the player reports the bad value
