"""The dependency rules of docs/ARCHITECTURE.md, checked on the source tree.

1. Node packages do not import each other (eval_node may use the tracker CORE, never a node
   module); vehicle_common imports no node package.
2. Core modules (everything but the node modules, the recorder node and the bringup package)
   do not import rclpy at import time; vehicle_common imports neither rclpy nor torch.
3. bench/ and tracking_bringup import package APIs, never a node module. In bench/, a helper
   module (no ``__main__``) serves one bench, and no bench imports another: code that several
   benches share lives in a package.
4. No import circle in src/ (module-level or function-level imports).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
NODE_PACKAGES = (
    "kitti_player_node",
    "detector_node",
    "stereo_depth_node",
    "tracker_node",
    "eval_node",
)
COMMON = "vehicle_common"
#: allowed imports between node packages: importer -> {package: modules it may import}
ALLOWED = {"eval_node": {"tracker_node": {"config", "conversions", "offline", "tracker"}}}
#: modules that ARE ROS nodes (may import rclpy at module level)
NODE_MODULES = {
    "kitti_player_node.node",
    "kitti_player_node.bag_player",
    "detector_node.node",
    "stereo_depth_node.node",
    "tracker_node.node",
    "eval_node.recorder",
}


def _modules(package: str) -> list[tuple[str, Path]]:
    """(dotted module name, file) of every module of ``package``, its subpackages' included
    (``vehicle_common.bags.reader``)."""
    root = SRC / package / package
    out = []
    for p in sorted(root.rglob("*.py")):
        parts = p.relative_to(root).with_suffix("").parts
        out.append((".".join((package, *parts[: -1 if parts[-1] == "__init__" else None])), p))
    return out


def _relative_base(path: Path, package: str, level: int) -> str:
    """The package a relative import of ``level`` dots in ``path`` starts from (``package``:
    the top-level package the file belongs to)."""
    parts = path.parent.relative_to(SRC / package / package).parts
    return ".".join((package, *parts[: len(parts) - (level - 1)]))


def _imports(path: Path, package: str) -> list[tuple[str, int, bool]]:
    """(absolute module name, line, at module level) of every import in a file."""
    tree = ast.parse(path.read_text())
    top = set(map(id, tree.body))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno, id(node) in top) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: inside the same package
                base = _relative_base(path, package, node.level)
                out.append((f"{base}.{node.module}" if node.module else base, node.lineno, True))
            else:
                mods = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
                out += [(m, node.lineno, id(node) in top) for m in mods]
    return out


def test_node_packages_do_not_import_each_other():
    bad = []
    for package in (*NODE_PACKAGES, COMMON):
        for _module, path in _modules(package):
            for name, line, _ in _imports(path, package):
                target = name.split(".")[0]
                if target == package or target not in NODE_PACKAGES:
                    continue
                allowed = ALLOWED.get(package, {}).get(target, set())
                sub = name.split(".")[1] if "." in name else None
                if sub is None and name.count(".") == 0:
                    continue  # "from tracker_node import x" is checked through its submodule
                if sub not in allowed:
                    bad.append(f"{path.relative_to(SRC)}:{line} imports {name}")
    assert not bad, "node packages import each other:\n" + "\n".join(bad)


def test_the_rule_checker_sees_a_forbidden_import(tmp_path):
    f = tmp_path / "x.py"
    f.write_text("from tracker_node.node import VehicleTrackerNode\nimport rclpy\n")
    names = [n for n, _, _ in _imports(f, "eval_node")]
    assert "tracker_node.node" in names and "rclpy" in names


def _core_modules() -> list[str]:
    return [
        m
        for package in (COMMON, *NODE_PACKAGES)
        for m, _ in _modules(package)
        if m not in NODE_MODULES
    ]


def test_core_modules_do_not_import_rclpy_at_import_time():
    code = (
        "import importlib, sys\n"
        f"for m in {_core_modules()!r}:\n"
        "    importlib.import_module(m)\n"
        "    if 'rclpy' in sys.modules:\n"
        "        print(m); sys.exit(1)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"importing {r.stdout.strip()} imports rclpy: {r.stderr[-2000:]}"


def test_vehicle_common_imports_neither_rclpy_nor_torch():
    mods = [m for m, _ in _modules(COMMON)]
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "bad = [n for n in ('rclpy', 'torch') if n in sys.modules]\n"
        "print(','.join(bad)); sys.exit(1 if bad else 0)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, f"vehicle_common imports {r.stdout.strip()} {r.stderr[-2000:]}"


@pytest.mark.parametrize("module", sorted(NODE_MODULES))
def test_node_modules_define_a_module_level_node_class(module):
    package, name = module.split(".")
    tree = ast.parse((SRC / package / package / f"{name}.py").read_text())
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    assert any(any(getattr(b, "id", None) == "Node" for b in c.bases) for c in classes), (
        f"{module} has no module-level rclpy Node subclass"
    )
    funcs = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert "_make_node_class" not in funcs


BENCH = SRC.parent / "bench"
BRINGUP = "tracking_bringup"


def test_bench_and_bringup_use_package_apis_not_node_modules():
    """bench/ and tracking_bringup run the packages' cores (pipelines, loaders, offline tools,
    parameters), never a node module's internals (its Node class is started as a process)."""
    files = [(p, "bench") for p in sorted(BENCH.glob("*.py"))]
    files += [(p, BRINGUP) for _, p in _modules(BRINGUP)]
    bad = [
        f"{path.relative_to(SRC.parent)}:{line} imports {name}"
        for path, package in files
        for name, line, _ in _imports(path, package)
        if any(name == m or name.startswith(m + ".") for m in NODE_MODULES)
    ]
    assert not bad, "imports of node modules:\n" + "\n".join(bad)


def bench_importers(files) -> dict[str, set[str]]:
    """bench module name -> the bench files (stems) that import it, over ``files``."""
    stems = {p.stem for p in files}
    out: dict[str, set[str]] = {}
    for path in files:
        for name, _, _ in _imports(path, "bench"):
            if name in stems and name != path.stem:
                out.setdefault(name, set()).add(path.stem)
    return out


def bench_sharing(files) -> list[str]:
    """The breaches of rule 3's bench/ part among ``files``: a bench script (it has a
    ``__main__``) imported by another file, or a helper imported by several."""
    scripts = {p.stem for p in files if '__name__ == "__main__"' in p.read_text()}
    out = []
    for module, users in sorted(bench_importers(files).items()):
        if module in scripts:
            out.append(f"bench {module} imported by {sorted(users)}")
        elif len(users) > 1:
            out.append(f"helper {module} imported by several benches: {sorted(users)}")
    return out


def test_code_several_benches_share_lives_in_a_package():
    bad = bench_sharing(sorted(BENCH.glob("*.py")))
    assert not bad, "move the shared code to a package:\n" + "\n".join(bad)


def test_the_bench_rule_sees_shared_code(tmp_path):
    (tmp_path / "helper.py").write_text("X = 1\n")
    (tmp_path / "bench_a.py").write_text("import helper\n")
    (tmp_path / "bench_b.py").write_text(
        'from helper import X\nif __name__ == "__main__":\n    pass\n'
    )
    (tmp_path / "bench_c.py").write_text("import bench_b\n")
    assert bench_sharing(sorted(tmp_path.glob("*.py"))) == [
        "bench bench_b imported by ['bench_c']",
        "helper helper imported by several benches: ['bench_a', 'bench_b']",
    ]


def _module_graph(packages) -> dict[str, set[str]]:
    """module -> the modules of ``packages`` it imports (at module level or inside functions;
    ``from . import x`` and ``from pkg import x`` resolved to the submodule x when it is one)."""
    modules = {m: p for package in packages for m, p in _modules(package)}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for module, path in modules.items():
        package = module.split(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _relative_base(path, package, node.level) if node.level else ""
                target = ".".join(x for x in (base, node.module) if x)
                names = [target] + [f"{target}.{a.name}" for a in node.names]
            for name in names:
                if name in modules and name != module and name != package:
                    graph[module].add(name)
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_package_imports_itself_in_a_circle():
    """No import circle in src/ (module-level or inside functions), e.g. the former
    onnx_backend <-> onnx_detector."""
    cycles = import_cycles(_module_graph((COMMON, *NODE_PACKAGES, BRINGUP)))
    assert not cycles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_subpackages_are_checked_with_their_relative_imports():
    """A subpackage (vehicle_common.bags) is under the same rules: its modules are listed and
    its relative imports resolved (``..kitti`` from bags/reader.py is vehicle_common.kitti)."""
    graph = _module_graph((COMMON,))
    assert "vehicle_common.bags.mcap_scan" in graph["vehicle_common.bags.recovery"]
    assert "vehicle_common.kitti" in graph["vehicle_common.bags.reader"]


def test_the_circle_checker_sees_a_circle():
    graph = {"p.a": {"p.b"}, "p.b": {"p.c"}, "p.c": {"p.a"}, "p.d": {"p.a"}}
    assert import_cycles(graph) == [["p.a", "p.b", "p.c"]]


def test_the_readme_stays_a_newcomers_page():
    """Issue #40's bar: the README at most 300 lines (dates, loads and history go to
    docs/RESULTS.md and CHANGELOG.md)."""
    lines = (SRC.parent / "README.md").read_text().splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines (at most 300)"
