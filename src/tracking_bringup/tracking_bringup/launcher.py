"""A process launcher for ROS 2 graphs where ``ros2 launch`` is not available (pip-installed ROS).

It starts each node as its own OS process (real DDS between them) with
``--ros-args --params-file FILE``, writes one log file per node, checks readiness (every node's
subscriptions and publications are visible in the ROS graph; ``stereo_tracking_launch`` starts
every process at once, as ``ros2 launch`` does, and the player publishes nothing until every
edge of the graph is matched, see ``graph.edge_counts``; ``GraphLauncher(staged=True)``, the
default for other sources, starts them only once the rest is up), and exits non-zero naming the
node when one dies.

A node that stops making progress while the graph runs (no report on /diagnostics, or a frame
in process without progress, for ``stall_timeout`` s: a frozen or hung process; or its process
stopped, state T in /proc, for as long: SIGSTOP, a debugger) ends the run with exit code 1
naming it, and is killed (``ProgressWatch``). The process state is read as well because the
launcher's DDS participant sometimes never receives one node's reports (the other nodes do:
seen in 3 of 16 runs here, and once in CI), which left a stopped node unnoticed.

Stopping (end of the sequence, Ctrl-C or SIGTERM): the sources are stopped first, the frames in
flight are let through the graph (until every node reports on /diagnostics that it holds no
frame, bounded by ``drain_timeout``), then the other nodes get SIGINT in data-flow order (then
SIGTERM, then SIGKILL), so a recorded bag has as many outputs as inputs. Ctrl-C during start-up
stops everything at once. Children are bound to the launcher with PR_SET_PDEATHSIG so none is
orphaned.

Command line: ``stereo_tracking_launch [--params FILE] [--nodes a,b] [-p node.param:=value] ...``
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import ctypes
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from vehicle_common.graph_readiness import NodeReport, ProgressWatch, graph_quiescent
from vehicle_common.node_runtime import DIAGNOSTICS_TOPIC, reports_from_message
from vehicle_common.option_checks import first_problem, number_problem

from tracking_bringup import graph, hosts, parameter_file
from tracking_bringup.environment import PARAMS_FILE, graph_environment
from tracking_bringup.frame_summary import (
    LatencyProbe,
    camera_overrides,
    dropped_by_node,
    summary_line,
)
from tracking_bringup.run_summary import RunSummary
from vehicle_common import topics

_PR_SET_PDEATHSIG = 1
_CLEAN_EXIT_CODES = {0, -signal.SIGINT, 128 + signal.SIGINT, -signal.SIGTERM, 128 + signal.SIGTERM}


#: a node's (and the launcher's) exit code for a bad parameter, argument or input file
EXIT_BAD_INPUT = 2


class LaunchError(RuntimeError):
    """The graph could not be started, or a node died. ``node`` names it when known;
    ``exit_code`` is the launcher's: 1, or 2 when the node refused its parameters or input
    (it exited with code 2 and said why in one line)."""

    def __init__(self, message: str, node: str | None = None, exit_code: int = 1):
        super().__init__(message)
        self.node = node
        self.exit_code = exit_code


class LaunchInterrupted(LaunchError):
    """A stop was requested (Ctrl-C, SIGTERM) before the graph was ready."""


@dataclass
class ProcessSpec:
    """One process to run: its name (the ROS node name), command line and graph role."""

    name: str
    argv: list[str]
    subscribes: tuple[str, ...] = ()
    publishes: tuple[str, ...] = ()
    source: bool = False
    finishes: bool = False
    namespace: str = ""  # the node's ROS namespace ("" or "/rig2")


@dataclass
class _Running:
    spec: ProcessSpec
    proc: subprocess.Popen
    log_path: Path
    log_file: object = field(repr=False)


def _bind_to_parent() -> None:
    """In the child before exec: die with SIGTERM when the launcher dies (Linux)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


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


class GraphLauncher:
    """Runs a set of processes as one graph. Use as a context manager or call
    :meth:`start`, :meth:`wait` and :meth:`shutdown`."""

    _observers = 0  # observer nodes made in this process

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
        self.running: dict[str, _Running] = {}
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
        self._stopped_since: dict[str, float] = {}  # node -> when its process was seen stopped
        #: node -> recent (time, main thread state, main thread CPU s) samples of its process
        self._samples: dict[str, collections.deque] = {}
        #: node -> recent (time, "R" when one of its other threads was runnable else "S", CPU s
        #: of the whole process) samples, taken while it reports a frame in process
        self._worker_samples: dict[str, collections.deque] = {}
        #: topics of this graph that another publisher outside it also publishes on (once ready)
        self.foreign: list[str] = []
        self._ready = False
        self._stopping = False
        self._observer = None
        self._context = None
        self._executor = None

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
                raise _death(run, code, "died")
            self.spin_reports(poll)
            self._check_progress()
            if self.on_poll is not None:
                self.on_poll(self.reports, time.monotonic())

    def _check_progress(self) -> None:
        """Raise LaunchError naming a running node that stopped making progress (a frozen
        process, a hung callback): see :class:`ProgressWatch`."""
        now = time.monotonic()
        alive = [n for n, r in self.running.items() if r.proc.poll() is None]
        window = self.progress.timeout_s
        states = {}  # node -> its process's state letter (its main thread's, in /proc)
        for name in alive:
            sample = _main_thread_sample(self.running[name].proc.pid)
            if sample is not None:
                states[name] = sample[0]
                samples = self._samples.setdefault(name, collections.deque(maxlen=200))
                samples.append((now, *sample))
            report = self.reports.get(name)
            if report is not None and report.busy:  # its frame worker's threads, too
                sample = _worker_threads_sample(self.running[name].proc.pid)
                if sample is not None:
                    workers = self._worker_samples.setdefault(name, collections.deque(maxlen=200))
                    workers.append((now, *sample))
        stalled = self.progress.stalled(now, alive)
        for name, why in list(stalled.items()):
            silent = self.progress.silent_s(name, now)
            if (
                why.startswith("no report")
                and silent < STARVED_LIMIT * window
                and starved_not_frozen(self._samples.get(name, ()), now, window)
            ):
                del stalled[name]  # waiting for a CPU (a loaded machine, nice 10), not frozen
            elif (
                why.startswith("a frame in process")
                and self.progress.busy_s(name, now) < STARVED_LIMIT * window
                and starved_not_frozen(self._worker_samples.get(name, ()), now, window)
            ):
                # its frame's worker waits for a CPU: stereo_depth (nice 10) took over 5 s for
                # its first frame of real 0005 on a 2-core machine at load 30, and was killed
                del stalled[name]
        for name in alive:
            if states.get(name) in ("T", "t"):
                since = self._stopped_since.setdefault(name, now)
                if now - since >= self.progress.timeout_s and name not in stalled:
                    stalled[name] = f"its process has been stopped for {now - since:.1f} s"
            else:
                self._stopped_since.pop(name, None)
        if not stalled:
            return
        self.stalled = stalled
        name, why = next(iter(stalled.items()))
        run = self.running[name]
        raise LaunchError(
            f"node '{name}' stopped making progress: {why} (process {run.proc.pid}: "
            f"{_process_state(run.proc.pid)}); it is killed; log: {run.log_path}",
            node=name,
        )

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
        log_path = self.log_dir / f"{spec.name}.log"
        # this run's log only: a death report never quotes an earlier run's lines
        log_file = open(log_path, "wb", buffering=0)  # noqa: SIM115 (closed in shutdown)
        log_file.write(f"$ {' '.join(spec.argv)}\n".encode())
        proc = subprocess.Popen(
            spec.argv,
            stdin=subprocess.DEVNULL,
            stdout=None if self.echo else log_file,
            stderr=subprocess.STDOUT if not self.echo else None,
            env=self.env,
            start_new_session=True,  # Ctrl-C reaches the launcher only; it stops the children
            preexec_fn=_bind_to_parent,
        )
        self.running[spec.name] = _Running(spec, proc, log_path, log_file)

    def _stop(self, run: _Running) -> int:
        proc = run.proc
        if proc.poll() is not None:
            return proc.returncode
        if run.spec.name in self.stalled:  # a frozen process takes no SIGINT: no drain
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            return proc.wait()
        for sig, timeout in (
            (signal.SIGINT, self.stop_timeout),
            (signal.SIGTERM, 5.0),
            (signal.SIGKILL, 5.0),
        ):
            try:
                proc.send_signal(sig)
            except ProcessLookupError:
                break
            try:
                return proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                continue
        return proc.wait()

    def _stop_all(self, runs: list[_Running]) -> dict[str, int]:
        """Stop processes at once (start-up interrupted): SIGTERM to all, then SIGKILL."""
        for sig, timeout in ((signal.SIGTERM, self.stop_timeout), (signal.SIGKILL, 5.0)):
            alive = [r for r in runs if r.proc.poll() is None]
            for run in alive:
                with contextlib.suppress(ProcessLookupError):
                    run.proc.send_signal(sig)
            deadline = time.monotonic() + timeout
            for run in alive:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    run.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        return {r.spec.name: r.proc.wait() for r in runs}

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
        if self._executor is None:
            time.sleep(timeout)
            return
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            self._executor.spin_once(timeout_sec=left)

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
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        # The observer must join the children's DDS domain with the same transport settings;
        # rmw reads them from this process's environment when the participant is created.
        os.environ.update(
            {k: v for k, v in self.env.items() if k.startswith(("ROS_", "RMW_", "FASTRTPS_"))}
        )
        self._context = Context()
        rclpy.init(context=self._context, args=[])
        GraphLauncher._observers += 1  # one name per observer, also with two in one process
        self._observer = rclpy.create_node(
            f"graph_launcher_{os.getpid()}_{GraphLauncher._observers}",
            context=self._context,
            start_parameter_services=False,
        )
        self._observer.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_reports, 50)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._observer)

    def _close_observer(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(timeout_sec=1.0)
            self._executor = None
        if self._observer is not None:
            self._observer.destroy_node()
            self._observer = None
        if self._context is not None:
            self._context.try_shutdown()
            self._context = None

    def _foreign_publishers(self) -> list[str]:
        """This graph's topics that have more publishers in the ROS graph than this graph's
        processes: another graph on the same ROS domain without its own namespace (or the
        publisher of a process killed in the last seconds, which discovery still lists)."""
        ours: dict[str, int] = {}
        for spec in self.specs:
            for topic in spec.publishes:
                ours[topic] = ours.get(topic, 0) + 1
        out = []
        for topic, n in sorted(ours.items()):
            have = self._observer.count_publishers(topic)
            if have > n:
                out.append(f"{topic} ({have} publishers, {n} of this graph)")
        return out

    def _missing_endpoints(self, specs: Sequence[ProcessSpec]) -> list[str]:
        """Human-readable list of endpoints of ``specs`` not yet visible in the graph."""
        obs = self._observer
        missing = []
        for spec in specs:
            for topic in spec.subscribes:
                nodes = {i.node_name for i in obs.get_subscriptions_info_by_topic(topic)}
                if spec.name not in nodes:
                    missing.append(f"{spec.name} subscription {topic}")
            for topic in spec.publishes:
                nodes = {i.node_name for i in obs.get_publishers_info_by_topic(topic)}
                if spec.name not in nodes:
                    missing.append(f"{spec.name} publisher {topic}")
        return missing

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
                    raise _death(run, code, "died during start-up")
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


def _death(run: _Running, code: int, what: str) -> LaunchError:
    """The error of a node that exited: with code 2 (a bad parameter or input, which the node
    named in one ``error:`` line) that line, and the launcher exits 2; else the node, its
    exit code and the end of its log, and the launcher exits 1."""
    name = run.spec.name
    line = _error_line(run.log_path)
    if code == EXIT_BAD_INPUT and line:
        return LaunchError(line.removeprefix("error: "), node=name, exit_code=EXIT_BAD_INPUT)
    reason = f": {line.removeprefix('error: ')}" if line else ""
    return LaunchError(
        f"node '{name}' {what} (exit code {code}){reason}; log: {run.log_path}\n"
        + _tail(run.log_path),
        node=name,
    )


#: a node silent on /diagnostics whose process waits for a CPU is given this many
#: ``stall_timeout`` before it counts as stalled all the same
STARVED_LIMIT = 6.0


def _main_thread_sample(pid: int) -> tuple[str, float] | None:
    """(state letter, CPU seconds) of a process's main thread (the executor's, which runs the
    report timer), from /proc (Linux); None when unreadable."""
    try:
        fields = Path(f"/proc/{pid}/task/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return fields[0], (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def _worker_threads_sample(pid: int) -> tuple[str, float] | None:
    """("R" when a thread other than the main one is runnable, else "S"; CPU seconds of the
    whole process), from /proc (Linux); None when unreadable. A frame worker that computes is
    R (waiting for a CPU or on one), a deadlocked one sleeps."""
    try:
        runnable = False
        for task in Path(f"/proc/{pid}/task").iterdir():
            if task.name != str(pid):
                state = (task / "stat").read_text().rsplit(")", 1)[1].split()[0]
                runnable = runnable or state == "R"
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None
    return ("R" if runnable else "S"), cpu


def starved_not_frozen(samples, now: float, window: float) -> bool:
    """Whether a node silent on /diagnostics for ``window`` s is only short of CPU: its main
    thread was runnable (state R) at least once in that window and used under half a core
    (a stopped process is T, a deadlocked one sleeps, S, a callback spinning forever keeps its
    thread busy). Under two busy loops at nice 0 the graph's stereo_depth, at nice 10, went 5 s
    without a report while working, and the watchdog killed it (a fresh-clone suite run).
    ``samples``: (time, state, main-thread CPU s), oldest first."""
    recent = [s for s in samples if s[0] >= now - window]
    if len(recent) < 2:
        return False
    span = recent[-1][0] - recent[0][0]
    if span < 0.5 * window:
        return False
    runnable = any(state == "R" for _, state, _ in recent)
    cpu = recent[-1][2] - recent[0][2]
    return runnable and cpu < 0.5 * span


def _process_state(pid: int) -> str:
    """``stopped (T)``, ``running (R)``, ... of a process, from /proc (Linux)."""
    names = {
        "R": "running",
        "S": "sleeping",
        "D": "in uninterruptible wait",
        "T": "stopped",
        "t": "stopped by a debugger",
    }
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return "state unknown"
    return f"{names.get(state, 'state')} ({state})"


def _error_line(path: Path) -> str | None:
    """The last ``error: ...`` line of a node's log (its one-line reason for exit code 2)."""
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return None
    found = [line.strip() for line in lines if line.startswith("error: ")]
    return found[-1] if found else None


def _tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace").splitlines()
    except OSError:
        return ""
    return "\n".join("    " + line for line in text[-lines:])


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
        unclean = {n: c for n, c in codes.items() if c not in _CLEAN_EXIT_CODES and n != failed}
        if unclean:
            announce(
                "warning: unclean exit of "
                + ", ".join(f"{n} (code {c})" for n, c in unclean.items())
            )
        if summary is not None:
            announce(summary(launcher.reports))
        for sig, handler in previous.items():
            signal.signal(sig, handler)


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


def main(argv: Sequence[str] | None = None) -> int:
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
    args = parser.parse_args(argv)
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
    summary = None
    if probe:
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


if __name__ == "__main__":
    sys.exit(main())
