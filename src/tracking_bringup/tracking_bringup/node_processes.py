"""The processes of a graph: each node's command line (its console script with ``--ros-args``:
node name, namespace, parameter file, ``-p`` overrides) and :func:`graph_processes`, which
reads and checks the parameter files and plans the graph (:func:`graph.plan`) into
:class:`ProcessSpec` s.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from tracking_bringup import graph, parameter_file
from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.supervision import LaunchError, ProcessSpec
from vehicle_common import topics


def resolve_executable(executable: str) -> str:
    """Path of a console script: next to this interpreter (the venv), else on PATH."""
    candidate = Path(sys.executable).parent / executable
    if candidate.is_file():
        return str(candidate)
    found = shutil.which(executable)
    if found is None:
        raise LaunchError(f"executable {executable!r} not found (is the workspace installed?)")
    return found


def node_command(
    spec: graph.NodeSpec,
    params_file: str | os.PathLike | None,
    overrides: Sequence[str] = (),
    namespace: str = "",
) -> list[str]:
    """The command line of one graph node: executable + ``--ros-args`` (node name, namespace,
    parameter file, ``-p name:=value`` overrides)."""
    argv = [resolve_executable(spec.executable), *spec.extra_args, "--ros-args"]
    argv += ["-r", f"__node:={spec.name}"]
    ns = topics.normalise_namespace(namespace)
    if ns:
        argv += ["-r", f"__ns:={ns}"]
    if params_file:
        argv += ["--params-file", str(params_file)]
    for ov in overrides:
        argv += ["-p", ov]
    return argv


def graph_processes(
    nodes: Sequence[graph.NodeSpec],
    params_file: parameter_file.Files | None = PARAMS_FILE,
    overrides: Sequence[str] = (),
    namespace: str = "",
    graph_nodes: Sequence[graph.NodeSpec] | None = None,
    extra_subscriptions: dict[str, int] | None = None,
    params_out: str | os.PathLike | None = None,
) -> list[ProcessSpec]:
    """ProcessSpecs of graph nodes. ``overrides`` are ``node.param:=value`` strings.

    The parameter file is read here (:mod:`.parameter_file`: its sections checked, those that
    address each node in ``namespace`` merged; a list of files, :func:`parameter_file.layers`,
    is merged key by key in order) and written to ``params_out`` (default: a file
    removed when this process exits) with the nodes' fully qualified names as sections, which
    every node is given: a graph in a namespace runs with the file's values too. A bad file,
    section or namespace raises ValueError (one line).

    :func:`graph.plan` (as the ROS launch file) sets the detector's subscriptions from its
    ``backend`` parameter, the player's from its ``lockstep`` parameter (file or override; the
    node's default is off), tells each source node how many subscriptions to wait for on every
    edge of the graph (plus ``extra_subscriptions`` per topic from outside the graph, e.g. a
    progress display), counted over ``graph_nodes``: the whole graph, also the nodes other
    hosts run (default: ``nodes``), and in lockstep gives the latest-frame nodes a
    ``frame_queue`` of the player's ``lockstep_window``. Overrides of nodes that run elsewhere
    only inform those counts. ``namespace`` moves the whole graph; the specs' topics are the
    resolved names."""
    graph_nodes = list(nodes if graph_nodes is None else graph_nodes)
    namespace = parameter_file.check_namespace(namespace)
    per_node: dict[str, list[str]] = {n.name: [] for n in [*graph_nodes, *nodes]}
    for ov in overrides:
        target, sep, rest = ov.partition(".")
        if not sep or ":=" not in rest or target not in per_node:
            raise LaunchError(
                f"bad parameter override {ov!r}: expected NODE.PARAM:=VALUE with NODE one of "
                + ", ".join(per_node)
                + (parameter_file.closest(target, per_node) if sep else "")
            )
        _check_override_value(ov, rest)
        per_node[target].append(rest)
    params = graph.file_parameters(None)
    if params_file is not None:
        names = [n.name for n in graph.PIPELINE]
        params = parameter_file.node_parameters(params_file, names, namespace)
        params_file = parameter_file.write_node_parameters(
            {n.name: params[n.name] for n in nodes},
            namespace,
            params_out or parameter_file.temporary_path("parameters_"),
            source=params_file,
        )
    out = []
    planned = graph.plan(list(nodes), params, per_node, graph_nodes, extra_subscriptions)
    for n, extra in planned:
        argv_overrides = per_node[n.name] + [f"{k}:={v}" for k, v in extra.items()]
        out.append(
            ProcessSpec(
                name=n.name,
                argv=node_command(n, params_file, argv_overrides, namespace),
                subscribes=tuple(topics.resolve(t, namespace) for t in n.subscribes),
                publishes=tuple(topics.resolve(t, namespace) for t in n.publishes),
                source=n.source,
                finishes=n.finishes,
                namespace=topics.normalise_namespace(namespace),
            )
        )
    return out


def _check_override_value(override: str, rest: str) -> None:
    """LaunchError (one line) for a ``-p NODE.PARAM:=VALUE`` whose value rcl cannot take (it
    reads it as YAML; an empty one stopped the node with a traceback)."""
    import yaml

    value = rest.partition(":=")[2]
    if not value.strip():
        raise LaunchError(
            f"bad parameter override {override!r}: no value (an empty string is written '')"
        )
    try:
        yaml.safe_load(value)
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise LaunchError(
            f"bad parameter override {override!r}: not a YAML value ({problem})"
        ) from None
