"""A process launcher for ROS 2 graphs where ``ros2 launch`` is not available (pip-installed ROS).

It starts each node as its own OS process (real DDS between them) with
``--ros-args --params-file FILE``, writes one log file per node, checks readiness (every node's
subscriptions and publications are visible in the ROS graph; ``stereo_tracking_launch`` starts
every process at once, as ``ros2 launch`` does, and the player publishes nothing until every
edge of the graph is matched, see ``graph.edge_counts``; ``GraphLauncher(staged=True)``, the
default for other sources, starts them only once the rest is up), and exits non-zero naming the
node when one dies.

This module ties the parts together (:class:`GraphLauncher`, :func:`run_graph`): process
supervision (:mod:`.supervision`), the processes' command lines (:mod:`.node_processes`), the DDS
observer of the nodes' reports (:mod:`.observer`), the watchdog (:mod:`.watchdog`) and the
command line (:mod:`.cli`); their public names are importable from here too.

A node that stops making progress while the graph runs (no report on /diagnostics, or a frame
in process without progress, for ``stall_timeout`` s; or its process stopped, state T in /proc,
for as long) ends the run with exit code 1 naming it, and is killed (:mod:`.watchdog`).

Stopping (end of the sequence, Ctrl-C or SIGTERM): the sources are stopped first, the frames in
flight are let through the graph (until every node reports on /diagnostics that it holds no
frame, bounded by ``drain_timeout``), then the other nodes get SIGINT in data-flow order (then
SIGTERM, then SIGKILL), so a recorded bag has as many outputs as inputs. Ctrl-C during start-up
stops everything at once. Children are bound to the launcher with PR_SET_PDEATHSIG so none is
orphaned.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from vehicle_common.graph_readiness import NodeReport, ProgressWatch, graph_quiescent
from vehicle_common.node_runtime import reports_from_message

from tracking_bringup import cli, supervision
from tracking_bringup.cli import add_params_arguments, parameter_layers  # noqa: F401
from tracking_bringup.environment import graph_environment
from tracking_bringup.node_processes import (  # noqa: F401
    graph_processes,
    node_command,
    resolve_executable,
)
from tracking_bringup.observer import ReportObserver
from tracking_bringup.run_summary import RunSummary
from tracking_bringup.supervision import (
    CLEAN_EXIT_CODES,
    LaunchError,
    LaunchInterrupted,
    ProcessSpec,
    Running,
)
from tracking_bringup.watchdog import ProcessWatchdog, process_state, starved_not_frozen  # noqa: F401


class GraphLauncher:
    """Runs a set of processes as one graph. Use as a context manager or call
    :meth:`start`, :meth:`wait` and :meth:`shutdown`."""

    def __init__(
        self,
        specs: Sequence[ProcessSpec],
        log_dir: str | os.PathLike,
        env: dict[str, str] | None = None,
        ready_timeout: float = 60.0,
        stop_timeout: float = 15.0,
        echo: bool = False,
        staged: bool = True,
        drain_timeout: float = 5.0,
        stall_timeout: float = 5.0,
    ):
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise LaunchError(f"duplicate node names in {names}")
        self.specs = list(specs)
        self.log_dir = Path(log_dir)
        self.env = graph_environment(env)
        self.ready_timeout = ready_timeout
        self.stop_timeout = stop_timeout
        self.echo = echo
        #: start the sources only once the rest is up (False: everything at once, as ``ros2
        #: launch`` does; the sources' own edge readiness then does the waiting, and the
        #: player's start-up overlaps the detector's: ``stereo_tracking_launch`` and the demo,
        #: whose player waits for every edge of the graph)
        self.staged = staged
        self.drain_timeout = drain_timeout
        self.running: dict[str, Running] = {}
        #: fully qualified node name (no leading "/") -> process name, to file the reports
        self._report_names = {f"{s.namespace}/{s.name}".lstrip("/"): s.name for s in specs}
        #: the latest /diagnostics report of every node (frames in / out / dropped)
        self.reports: dict[str, NodeReport] = {}
        #: called with the reports and the time at every poll while the graph runs
        self.on_poll: Callable[[dict[str, NodeReport], float], None] | None = None
        #: whether the last shutdown let the frames in flight drain (None: nothing to drain)
        self.drained: bool | None = None
        #: nodes that stop making progress (silent on /diagnostics, or busy without progress,
        #: for ``stall_timeout`` s) end the run (:meth:`wait`); they are killed at shutdown
        self.progress = ProgressWatch(stall_timeout)
        self.stalled: dict[str, str] = {}
        #: the launcher's half of the watchdog: the processes' states in /proc
        self.watchdog = ProcessWatchdog(self.progress)
        #: topics of this graph that another publisher outside it also publishes on (once ready)
        self.foreign: list[str] = []
        self._ready = False
        self._stopping = False
        self._observer: ReportObserver | None = None

    # -- lifecycle -----------------------------------------------------------------------

    def __enter__(self) -> GraphLauncher:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()

    def start(self) -> None:
        """Start the non-source processes, wait until their topics are up, then the sources."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        try:
            if self.staged:
                rest = [s for s in self.specs if not s.source]
                sources = [s for s in self.specs if s.source]
                for spec in rest:
                    self._spawn(spec)
                self._open_observer()  # while the nodes start
                self._wait_ready(rest)
                for spec in sources:
                    self._spawn(spec)
                self._wait_ready(sources)
            else:
                for spec in self.specs:
                    self._spawn(spec)
                self._open_observer()  # while the nodes start
                self._wait_ready(self.specs)
            self.foreign = self._foreign_publishers()
            self._ready = True
        except BaseException:
            self.shutdown()
            raise

    def wait(self, until_finished: bool = True, poll: float = 0.2) -> None:
        """Block while the graph runs. Returns when a ``finishes`` process has exited with
        code 0 (if ``until_finished``) or when :meth:`request_stop` was called; raises
        :class:`LaunchError` naming the node when a process dies."""
        while not self._stopping:
            for run in self.running.values():
                code = run.proc.poll()
                if code is None:
                    continue
                if run.spec.finishes and code == 0:
                    if until_finished:
                        return
                    continue
                raise supervision.death(run, code, "died")
            self.spin_reports(poll)
            self._check_progress()
            if self.on_poll is not None:
                self.on_poll(self.reports, time.monotonic())

    def _check_progress(self) -> None:
        """Raise LaunchError naming a running node that stopped making progress (a frozen
        process, a hung callback): see :class:`ProgressWatch` and :mod:`.watchdog`."""
        alive = {n: r.proc.pid for n, r in self.running.items() if r.proc.poll() is None}
        stalled = self.watchdog.stalled(time.monotonic(), alive, self.reports)
        if not stalled:
            return
        self.stalled = stalled
        name, why = next(iter(stalled.items()))
        run = self.running[name]
        raise LaunchError(
            f"node '{name}' stopped making progress: {why} (process {run.proc.pid}: "
            f"{process_state(run.proc.pid)}); it is killed; log: {run.log_path}",
            node=name,
        )

    @property
    def _stopped_since(self) -> dict[str, float]:
        """Node -> when its process was seen stopped (the watchdog's)."""
        return self.watchdog.stopped_since

    def request_stop(self, *_args) -> None:
        """Ask :meth:`wait` to return (signal handler)."""
        self._stopping = True

    def shutdown(self) -> dict[str, int]:
        """Stop every process and return their exit codes (see the module docstring: sources
        first, drain, then the rest in data-flow order; all at once before the graph was
        ready). Idempotent."""
        self._stopping = True
        codes: dict[str, int] = {}
        # a frozen node goes first, before the sources stop and the frames drain: a stopped
        # process keeps its DDS endpoints matched and its shared-memory ports full, and every
        # other node's stop then waits on it (each node took seconds to stop while it lived;
        # once a run exited 73 s after the SIGSTOP)
        for name in self.stalled:
            if name in self.running:
                codes[name] = self._stop(self.running[name])
        if not self._ready:
            codes = self._stop_all(list(self.running.values()))
        else:
            for run in self.running.values():
                if run.spec.source:
                    codes[run.spec.name] = self._stop(run)
            if self.running and self._observer is not None:
                self.drained = self._drain()
            for name, run in self.running.items():
                if name not in codes:
                    codes[name] = self._stop(run)
        for run in self.running.values():
            run.log_file.close()
        self.running = {}
        self._ready = False
        self._close_observer()
        return codes

    # -- internals -----------------------------------------------------------------------

    def _spawn(self, spec: ProcessSpec) -> None:
        self.running[spec.name] = supervision.spawn(spec, self.log_dir, self.env, self.echo)

    def _stop(self, run: Running) -> int:
        return supervision.stop(run, self.stop_timeout, frozen=run.spec.name in self.stalled)

    def _stop_all(self, runs: list[Running]) -> dict[str, int]:
        """Stop processes at once (start-up interrupted): SIGTERM to all, then SIGKILL."""
        return supervision.stop_all(runs, self.stop_timeout)

    def _drain(self, quiet_s: float = 0.5) -> bool | None:
        """Wait until the frames in flight went through: every running node that reports on
        /diagnostics is idle and no report changed for ``quiet_s``. Bounded by
        ``drain_timeout``; None when no node reports (nothing known to drain)."""
        deadline = time.monotonic() + self.drain_timeout
        last, changed = None, time.monotonic()
        while True:
            self.spin_reports(0.05)
            now = time.monotonic()
            live = {
                n: r
                for n, r in self.reports.items()
                if n in self.running
                and self.running[n].proc.poll() is None
                and n not in self.stalled
            }
            if not live:
                return None
            if live != last:
                last, changed = live, now
            elif now - changed >= quiet_s and graph_quiescent(live.values()):
                return True
            if now > deadline:
                return False

    def spin_reports(self, timeout: float) -> None:
        """Take the observer's messages (node reports) for up to ``timeout`` seconds."""
        if self._observer is None:
            time.sleep(timeout)
            return
        self._observer.spin(timeout)

    def _on_reports(self, msg) -> None:
        for report in reports_from_message(msg):
            name = self._report_names.get(report.node)  # this graph's nodes, by short name
            if name is None:
                continue
            run = self.running.get(name)
            # only this launcher's process of that name: a stray one of the same name on the
            # domain (another graph, a leftover of an earlier run) would hide a frozen node
            if run is None or report.pid is None or report.pid == run.proc.pid:
                self.reports[name] = report
                self.progress.seen(name, report, time.monotonic())

    def _open_observer(self) -> None:
        self._observer = ReportObserver(self.env, self._on_reports)

    def _close_observer(self) -> None:
        if self._observer is not None:
            self._observer.close()
            self._observer = None

    def _foreign_publishers(self) -> list[str]:
        """This graph's topics with more publishers than its own (another graph)."""
        return self._observer.foreign_publishers(self.specs)

    def _missing_endpoints(self, specs: Sequence[ProcessSpec]) -> list[str]:
        """Human-readable list of endpoints of ``specs`` not yet visible in the graph."""
        return self._observer.missing_endpoints(specs)

    def _wait_ready(self, specs: Sequence[ProcessSpec]) -> None:
        deadline = time.monotonic() + self.ready_timeout
        while True:
            if self._stopping:
                raise LaunchInterrupted("stopped during start-up")
            waiting = []
            for spec in specs:
                run = self.running[spec.name]
                code = run.proc.poll()
                if code is None:
                    waiting.append(spec)
                elif not (spec.finishes and code == 0):
                    raise supervision.death(run, code, "died during start-up")
                # a finishing node that is already done (a short sequence) is not waited for
            missing = self._missing_endpoints(waiting)
            if not missing:
                return
            if time.monotonic() > deadline:
                node = missing[0].split()[0]
                raise LaunchError(
                    f"graph not ready after {self.ready_timeout:.0f} s: missing "
                    + ", ".join(missing),
                    node=node,
                )
            self.spin_reports(0.1)


def run_graph(
    processes: Sequence[ProcessSpec],
    log_dir: str | os.PathLike,
    until_finished: bool = True,
    ready_timeout: float = 60.0,
    echo: bool = False,
    announce=print,
    env: dict[str, str] | None = None,
    stall_timeout: float = 5.0,
    summary: Callable[[dict], str] | None = None,
) -> int:
    """Run processes as a graph until a finishing node is done, Ctrl-C or SIGTERM.
    Returns the exit code: 0 on a clean run, 1 when a node died (named in the message), 2 when
    a node refused its parameters or input (its one line is the message), 130 when stopped
    during start-up. ``summary(reports)``: the last line announced, from the nodes' last
    reports."""
    # every process at once: the player waits for every edge of the graph itself, and its
    # start-up overlaps the detector's (first tracks sooner, docs/RESULTS.md section 11)
    launcher = GraphLauncher(
        processes,
        log_dir,
        env=env,
        ready_timeout=ready_timeout,
        echo=echo,
        stall_timeout=stall_timeout,
        staged=False,
    )
    previous = {
        sig: signal.signal(sig, launcher.request_stop) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    failed = None  # the node the error names (its exit is not reported again)
    usage = RunSummary(announce)  # input the nodes cannot use (run_summary.py)
    launcher.on_poll = usage.check
    codes = None
    try:
        launcher.start()
        announce(f"graph ready: {', '.join(p.name for p in processes)} (logs in {log_dir})")
        if launcher.foreign:
            announce(
                "warning: another graph publishes on this ROS domain without its own namespace "
                f"(or a node of one was killed in the last 20 s): {', '.join(launcher.foreign)}; "
                "their frames and results mix: give each graph its own --namespace or "
                "ROS_DOMAIN_ID"
            )
        launcher.wait(until_finished=until_finished)
        codes = launcher.shutdown()  # drained first: the reports' counts are the run's
        return usage.final(launcher.reports)
    except LaunchInterrupted:
        announce("interrupted during start-up: every node stopped")
        return 130
    except LaunchError as exc:
        failed = exc.node
        announce(f"error: {exc}")
        return exc.exit_code
    finally:
        codes = launcher.shutdown() if codes is None else codes
        if launcher.drained is False:
            announce(
                f"warning: frames still in flight after {launcher.drain_timeout:.0f} s at shutdown"
            )
        unclean = {n: c for n, c in codes.items() if c not in CLEAN_EXIT_CODES and n != failed}
        if unclean:
            announce(
                "warning: unclean exit of "
                + ", ".join(f"{n} (code {c})" for n, c in unclean.items())
            )
        if summary is not None:
            announce(summary(launcher.reports))
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def main(argv: Sequence[str] | None = None) -> int:
    """``stereo_tracking_launch`` (:mod:`.cli`)."""
    return cli.main(argv, graph_processes=graph_processes, run_graph=run_graph)


_Running = Running  # its former name

if __name__ == "__main__":
    sys.exit(main())
