"""The command line of ``stereo_tracking_launch``: its options, their checks (one line and exit
code 2 for one that cannot be used), the run's log folder and :func:`main`, which plans the
graph (:mod:`tracking_bringup.hosts`, ``graph_processes``) and runs it (``run_graph``);
``tracking_bringup.launcher.main`` calls it with the launcher's.

Command line: ``stereo_tracking_launch [--params FILE] [--nodes a,b] [-p node.param:=value] ...``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from vehicle_common.option_checks import first_problem, number_problem

from tracking_bringup import graph, hosts, parameter_file
from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.frame_summary import (
    LatencyProbe,
    camera_overrides,
    dropped_by_node,
    summary_line,
)
from tracking_bringup.supervision import EXIT_BAD_INPUT, LaunchError


def run_log_dir(root: str | os.PathLike = "output/logs") -> Path:
    """A new folder for one run's logs: ``root/<date>-<time>_<pid>``."""
    return Path(root) / f"{time.strftime('%Y%m%d-%H%M%S')}_{os.getpid()}"


def add_params_arguments(parser: argparse.ArgumentParser) -> None:
    """``--params FILE`` (on top of the pipeline file, key by key) and ``--params-replace``."""
    parser.add_argument(
        "--params",
        default=None,
        help="ROS parameter YAML file read on top of the pipeline file "
        f"({PARAMS_FILE.name}), key by key as -p does (default: the pipeline file alone)",
    )
    parser.add_argument(
        "--params-replace",
        action="store_true",
        help="use the --params file instead of the pipeline file (parameters it does not set "
        "are the nodes' defaults)",
    )


def parameter_layers(args) -> str | None:
    """Replace ``args.params`` by the run's parameter files in the order they apply
    (:func:`parameter_file.layers`); one line (no file, a missing one) or None."""
    try:
        args.params = parameter_file.layers(args.params, args.params_replace)
    except ValueError as exc:
        return str(exc)
    return parameter_file.missing_file(args.params)


#: the shortest ``--stall-timeout`` [s]: every node reports on /diagnostics once a second, so a
#: shorter limit names healthy nodes (0 killed a node after its first frame)
MIN_STALL_TIMEOUT = 1.0


def check_arguments(args) -> str | None:
    """One line for the first option that cannot be used, else None (``args.params`` becomes
    the run's parameter files): --ready-timeout and --stall-timeout finite and positive,
    --nodes / --graph naming at least one node, the parameter files."""
    for option, text in (("--nodes", args.nodes), ("--graph", args.graph)):
        if text is not None and not [n for n in text.split(",") if n.strip()]:
            return (
                f"{option} {text!r}: no node named (comma-separated names of "
                + ", ".join(n.name for n in graph.PIPELINE)
                + ")"
            )
    return first_problem(
        number_problem("--ready-timeout", args.ready_timeout, above=0.0, why="seconds"),
        number_problem(
            "--stall-timeout",
            args.stall_timeout,
            minimum=MIN_STALL_TIMEOUT,
            why="seconds; every node reports once a second",
        ),
        parameter_layers(args),
    )


def make_log_dir(log_dir: Path) -> str | None:
    """Create the run's log folder; one line when it cannot be (a file in the way, no
    permission, a read-only disk), else None."""
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        return f"--log-dir {log_dir}: cannot create the log folder (a file is in the way)"
    except OSError as exc:
        return f"--log-dir {log_dir}: cannot create the log folder ({exc.strerror})"
    return None


def build_parser() -> argparse.ArgumentParser:
    """The options of ``stereo_tracking_launch``."""
    parser = argparse.ArgumentParser(
        prog="stereo_tracking_launch",
        description="Start the stereo tracking graph as separate processes (one per node).",
    )
    add_params_arguments(parser)
    parser.add_argument(
        "--nodes",
        default=None,
        help="comma-separated node names (default: all: "
        + ",".join(n.name for n in graph.PIPELINE)
        + ")",
    )
    parser.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NODE.PARAM:=VALUE",
        help="override one node parameter (repeatable)",
    )
    parser.add_argument(
        "--namespace", default="", help="ROS namespace of the whole graph, e.g. /rig2"
    )
    parser.add_argument(
        "--log-dir",
        default=None,
        help="folder of this run's per-node logs and parameter file (default: a new folder "
        "output/logs/<date>-<time>_<pid> per run; the logs of a given folder are replaced)",
    )
    parser.add_argument(
        "--ready-timeout",
        type=float,
        default=60.0,
        help="s the graph has to come up (every node's topics visible) before the run fails",
    )
    parser.add_argument(
        "--stall-timeout",
        type=float,
        default=5.0,
        help="s without a node's report (or with a frame in process and no progress) after "
        "which the run fails naming the node (every node reports at least once a second, so "
        f"at least {MIN_STALL_TIMEOUT:g})",
    )
    parser.add_argument(
        "--keep-running",
        action="store_true",
        help="keep the graph up after the player finished (stop with Ctrl-C)",
    )
    parser.add_argument("--echo", action="store_true", help="print node output to the console")
    parser.add_argument(
        "--camera-hz",
        type=float,
        default=0.0,
        help="the player as a camera at this rate, not waiting for the graph (e.g. 30); the "
        "last line: frames tracked, dropped and where, latency",
    )
    hosts.add_arguments(parser)
    return parser


def _summary(args) -> Callable[[dict], str]:
    """The last line of a ``--camera-hz`` run (frames tracked, dropped, latency), from the
    nodes' reports and a latency probe subscribed in this process."""
    latency = LatencyProbe(args.namespace)

    def summary(reports: dict) -> str:
        latency.close()
        player = reports.get(graph.PLAYER.name)
        tracker = reports.get(graph.TRACKER.name)
        return summary_line(
            player.counts.published if player else 0,
            tracker.counts.published if tracker else 0,
            dropped_by_node(reports),
            latency.frames.latencies_ms(),
            args.camera_hz,
        )

    return summary


def main(argv: Sequence[str] | None, graph_processes: Callable, run_graph: Callable) -> int:
    """``stereo_tracking_launch``: the graph planned by ``graph_processes`` and run by
    ``run_graph`` (:func:`tracking_bringup.launcher.main` passes its own)."""
    args = build_parser().parse_args(argv)
    problem = check_arguments(args)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return EXIT_BAD_INPUT
    log_dir = Path(args.log_dir) if args.log_dir else run_log_dir()
    problem = make_log_dir(log_dir)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        plan = hosts.launch_plan(args)
        nodes = graph.by_name(plan.nodes)
        whole = graph.by_name(plan.graph_nodes)  # the player waits for nodes elsewhere too
        camera = camera_overrides(args.camera_hz) if args.camera_hz else []
        overrides = [*plan.overrides, *camera, *args.param]
        # the summary's latency probe (this process): where the player and tracker run here
        probe = bool(args.camera_hz) and {graph.PLAYER.name, graph.TRACKER.name} <= {
            n.name for n in nodes
        }
        processes = graph_processes(
            nodes,
            args.params,
            overrides,
            args.namespace,
            graph_nodes=whole,
            params_out=log_dir / "parameters.yaml",
            extra_subscriptions=LatencyProbe.EDGES if probe else None,
        )
    except (ValueError, LaunchError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    summary = _summary(args) if probe else None
    elsewhere = [n.name for n in whole if n not in nodes]
    if elsewhere and any(n.source for n in nodes):
        print(f"expecting on other hosts: {', '.join(elsewhere)} (the player waits for them)")
    return run_graph(
        processes,
        log_dir,
        until_finished=not args.keep_running,
        ready_timeout=args.ready_timeout,
        echo=args.echo,
        env=plan.discovery.environment(),
        stall_timeout=args.stall_timeout,
        summary=summary,
    )
