"""Issue #40: every node parameter is defined once, in its package's pure dataclasses
(tracking_bringup.parameters lists them); no other Python file retypes its default, and the
graph's parameter file holds only parameters the nodes have, with values they accept."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import sys
from pathlib import Path

import yaml
from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.parameters import NODE_PARAMETERS, default, node_defaults
from vehicle_common.node_parameters import check_value

ROOT = Path(__file__).resolve().parents[2]


def _defining_files() -> set[Path]:
    return {
        Path(inspect.getsourcefile(cls)).resolve()
        for entries in NODE_PARAMETERS.values()
        for cls, _, _ in entries
    }


def retyped_defaults(files, root: Path = ROOT) -> list[str]:
    """Calls that pass a node parameter's name and then its default as a literal (``value(node,
    "lockstep", False)``, ``.get("num_threads", 2)``, ``declare_parameter("tracks_frame", "")``)."""
    defaults: dict[str, list] = {}
    for node in NODE_PARAMETERS:
        for name, value in node_defaults(node).items():
            defaults.setdefault(name, []).append(value)
    hits = []
    for path in files:
        for call in ast.walk(ast.parse(path.read_text())):
            if not isinstance(call, ast.Call):
                continue
            args = [*call.args, *(k.value for k in call.keywords)]
            for i, arg in enumerate(args):
                if not (isinstance(arg, ast.Constant) and arg.value in defaults):
                    continue
                for later in args[i + 1 :]:
                    try:
                        lit = ast.literal_eval(later)
                    except ValueError:
                        continue
                    if any(lit == d and type(lit) is type(d) for d in defaults[arg.value]):
                        hits.append(f"{path.relative_to(root)}:{call.lineno}: {arg.value}={lit!r}")
    return hits


def test_no_python_file_retypes_a_node_parameters_default():
    defining = _defining_files()
    files = [
        p
        for p in [*(ROOT / "src").rglob("*.py"), *(ROOT / "bench").glob("*.py")]
        if p.resolve() not in defining
    ]
    hits = retyped_defaults(files)
    assert not hits, "defaults typed again (read them from tracking_bringup.parameters):\n" + (
        "\n".join(hits)
    )


def test_the_check_finds_a_retyped_default(tmp_path):
    bad = tmp_path / "plan.py"
    bad.write_text('lockstep = value(PLAYER, "lockstep", False)\nq = p.get("frame_queue", 1)\n')
    hits = retyped_defaults([bad], tmp_path)
    assert [h.split(": ", 1)[1] for h in hits] == ["lockstep=False", "frame_queue=1"]


def test_parameter_modules_are_pure():
    """The dataclasses load without rclpy (and the detector's without torch)."""
    import subprocess

    code = (
        "import sys, tracking_bringup.parameters; "
        "bad = [m for m in ('rclpy', 'torch') if m in sys.modules]; "
        "sys.exit(', '.join(bad) or None)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_the_parameter_file_holds_only_the_nodes_parameters_with_accepted_values():
    data = yaml.safe_load(Path(PARAMS_FILE).read_text())
    for node in NODE_PARAMETERS:
        section = data[node]["ros__parameters"]
        rules = {
            rename.get(f.name, f.name): dict(f.metadata)
            for cls, _, rename in NODE_PARAMETERS[node]
            for f in dataclasses.fields(cls)
        }
        for name, value in section.items():
            assert name in node_defaults(node), f"{node}: {name} is no parameter of the node"
            check_value(f"{node}.{name}", value, default(node, name), rules[name])


def test_graph_plan_reads_the_nodes_defaults():
    assert default("kitti_player", "lockstep") is False
    assert default("vehicle_tracker", "tracks_frame") == ""
    assert default("stereo_depth", "ranging_method") == "robust"  # renamed field "method"
