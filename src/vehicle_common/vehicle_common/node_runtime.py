"""What every node process of the graph runs with (rclpy side; the logic is in
:mod:`.frame_accounting` and :mod:`.graph_readiness`):

- :class:`NodeHealth`: the node's report on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``,
  one status named after the node: frames in / out / dropped, busy, matched subscriptions per
  published topic), sent when it changes (checked every 0.1 s) and at least once a second, and
  the node's exit line ``frames in N, out M, dropped D``.
- :class:`StopRequest` and :func:`spin_until_stopped`: clean SIGINT/SIGTERM handling. A signal
  during construction (loading a network, say) ends the process at once; once spinning, it lets
  the callback in progress finish and publish (no ``RCLError`` from a context shut down under a
  running callback), drains the node's frame workers, logs the exit line and returns.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
from collections.abc import Callable, Iterable

from .frame_accounting import FrameCounter
from .graph_readiness import REPORT_ID, NodeReport
from .input_usage import InputUsage

DIAGNOSTICS_TOPIC = "/diagnostics"
_IGNORED_TOPICS = {DIAGNOSTICS_TOPIC, "/parameter_events", "/rosout"}


class NodeHealth:
    """Publishes the node's :class:`NodeReport` on ``/diagnostics`` (see module docstring).

    ``busy`` tells whether a frame is in process (e.g. a worker's ``busy``); ``usage``, of a
    processing node, how many frames it could use and why not the others."""

    def __init__(
        self,
        node,
        counter: FrameCounter,
        busy: Callable[[], bool] = lambda: False,
        period_s: float = 1.0,
        check_s: float = 0.1,
        usage: InputUsage | None = None,
    ) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self.node = node
        self.counter = counter
        self._busy = busy
        self._usage = usage
        self._period = period_s
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._last: NodeReport | None = None
        self._last_time = 0.0
        self._timer = node.create_timer(check_s, self._check)

    def report(self) -> NodeReport:
        matched = {
            p.topic_name: p.get_subscription_count()
            for p in self.node.publishers
            if p.topic_name not in _IGNORED_TOPICS
        }
        return NodeReport(
            self.node.get_name(),
            self.counter.snapshot(),
            self._busy(),
            matched,
            self.counter.processing_ms(),
            os.getpid(),
            *(self._usage.snapshot() if self._usage is not None else ()),
        )

    def _check(self) -> None:
        report = self.report()
        # a change of the /diagnostics subscriptions (a new listener) also triggers a report
        listeners = self._pub.get_subscription_count()
        key = (report, listeners)
        now = time.monotonic()
        if key != self._last or now - self._last_time >= self._period:
            self.publish(report)
            self._last, self._last_time = key, now

    def publish(self, report: NodeReport | None = None) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        report = report or self.report()
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if report.counts.dropped else DiagnosticStatus.OK,
            name=self.node.get_fully_qualified_name(),
            message=report.counts.summary(),
            hardware_id=REPORT_ID,
            values=[KeyValue(key=k, value=v) for k, v in report.values()],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._pub.publish(msg)

    def publish_final(self, timeout_s: float = 1.0) -> None:
        """Publish the report one last time and wait (at most ``timeout_s``) until every
        matched subscriber acknowledged it: the process exits right after, and a report still
        in the writer's queue then would be lost (a launcher kept the previous one, with a
        frame pending, although the node had accounted for it)."""
        from rclpy.duration import Duration

        self.publish()
        self._pub.wait_for_all_acked(Duration(nanoseconds=int(timeout_s * 1e9)))

    def exit_line(self) -> str:
        """Log and return the node's exit line."""
        line = self.counter.snapshot().summary()
        self.node.get_logger().info(line)
        return line


def reports_from_message(msg) -> list[NodeReport]:
    """The graph's node reports in a DiagnosticArray (other statuses are skipped)."""
    out = []
    for status in msg.status:
        if status.hardware_id != REPORT_ID:
            continue
        try:
            out.append(
                NodeReport.from_values(status.name, ((v.key, v.value) for v in status.values))
            )
        except ValueError:
            continue
    return out


class StopRequest:
    """SIGINT/SIGTERM handlers of a node process (rclpy initialised with
    ``signal_handler_options=SignalHandlerOptions.NO``). Until :meth:`arm` a signal raises
    KeyboardInterrupt (construction is abandoned at once); afterwards it only sets
    ``requested`` and the spin loop ends after the callback in progress."""

    def __init__(self) -> None:
        self.requested: int | None = None
        self._armed = False

    @classmethod
    def install(cls) -> StopRequest:
        stop = cls()
        signal.signal(signal.SIGINT, stop._handle)
        signal.signal(signal.SIGTERM, stop._handle)
        return stop

    def arm(self) -> None:
        self._armed = True

    def _handle(self, signum, _frame) -> None:
        self.requested = signum
        if not self._armed:
            raise KeyboardInterrupt


def _has_fileno(stream) -> bool:
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation: both
        return False
    return True


def make_executor(kind: str, context):
    """The executor that spins a node's process (its ``executor`` parameter): ``events``,
    rclpy's EventsExecutor (its wait on the middleware's events is in C++: on this project's
    nodes about a sixth of the SingleThreadedExecutor's CPU while idle, a quarter per message;
    docs/ARCHITECTURE.md, "CPU affinity, priority and memory"), or ``single_threaded``."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        # its constructor enables faulthandler on sys.stderr, which needs a file descriptor:
        # not there when stderr is replaced (pytest's capture, a host application's stream)
        if _has_fileno(sys.stderr):
            return EventsExecutor(context=context)
        if _has_fileno(sys.__stderr__):
            with contextlib.redirect_stderr(sys.__stderr__):
                return EventsExecutor(context=context)
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor(context=context)


#: InvalidHandle errors in a row the spin loop steps over (:func:`spin_until_stopped`)
MAX_INVALID_HANDLES = 10


def spin_until_stopped(
    node,
    stop: StopRequest,
    health: NodeHealth | None = None,
    on_stop: Iterable[Callable[[], object]] = (),
    done: Callable[[], bool] = lambda: False,
) -> None:
    """Spin ``node`` until a stop signal (or ``done()``), then call ``on_stop`` (e.g. drain the
    frame workers), publish the final report and log the exit line. rclpy is left initialised
    (the caller destroys the node and calls ``rclpy.try_shutdown``)."""
    from rclpy.exceptions import InvalidHandle

    executor = make_executor(getattr(node, "executor_kind", "events"), node.context)
    executor.add_node(node)
    stop.arm()
    invalid = 0  # InvalidHandle in a row
    try:
        while stop.requested is None and node.context.ok() and not done():
            try:
                executor.spin_once(timeout_sec=0.1)
                invalid = 0
            except InvalidHandle:
                # an entity destroyed while its event was pending (a camera subscription
                # re-created with its publishers' reliability drops its QoS event handler):
                # rclpy skips destroyed timers and subscriptions itself, not event handlers;
                # that work is dropped. Over and over: the node itself is gone.
                invalid += 1
                if invalid > MAX_INVALID_HANDLES:
                    raise
        for fn in on_stop:
            fn()
        if health is not None:
            health.publish_final()
            health.exit_line()
    finally:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=1.0)


def apply_process_settings(node) -> None:
    """Declare the process parameters every node takes and apply them to the whole process:

    - ``cpu_affinity``: a ``taskset -c`` CPU list ("1", "0-3"; "" = every CPU); the process's
      threads move onto those CPUs (:mod:`.cpu_affinity`);
    - ``nice``: the niceness of its threads, as ``nice -n`` (0 = as started; 1..19 lower
      priority), and of its session group where it leads one (:mod:`.process_priority`);
    - ``keep_freed_memory`` (true): freed memory stays in the process for reuse, so that a
      frame's large buffers cost no fresh pages (:mod:`.malloc_policy`);
    - ``executor``: ``events`` (rclpy's EventsExecutor, the default) or ``single_threaded``,
      the executor :func:`spin_until_stopped` spins the node with (``node.executor_kind``).

    numpy's BLAS runs on one thread in every node (:mod:`.blas_threads`: its idle threads spun
    after each small matrix product; the nodes' parallel work is in OpenCV and ONNX Runtime).

    Called first in each node's construction, so that the threads started later inherit them.
    A value this process cannot take is a ParameterError naming the parameter; a platform
    without affinities, priorities or ``mallopt`` logs a warning and runs on."""
    from .blas_threads import set_blas_threads
    from .cpu_affinity import check_cpu_list, pin_process
    from .malloc_policy import keep_freed_memory
    from .node_parameters import (
        CPU_AFFINITY_PARAMETER,
        KEEP_FREED_MEMORY_PARAMETER,
        NICE_PARAMETER,
        ParameterError,
        ProcessParameters,
        declare_config,
    )
    from .process_priority import set_process_nice

    settings = declare_config(node, ProcessParameters)
    text, nice, keep = settings.cpu_affinity, settings.nice, settings.keep_freed_memory
    node.executor_kind = settings.executor
    try:
        cpus = check_cpu_list(text)
    except ValueError as exc:
        raise ParameterError(CPU_AFFINITY_PARAMETER, str(exc)) from None
    set_blas_threads(1)
    if keep:
        try:
            keep_freed_memory()
        except RuntimeError as exc:
            node.get_logger().warning(f"{KEEP_FREED_MEMORY_PARAMETER} not applied: {exc}")
    if cpus:
        try:
            pin_process(cpus)
            node.get_logger().info(f"running on CPU {text}")
        except RuntimeError as exc:
            node.get_logger().warning(f"{CPU_AFFINITY_PARAMETER} {text!r} not applied: {exc}")
    if nice:
        try:
            _, group = set_process_nice(nice)
        except PermissionError as exc:
            raise ParameterError(NICE_PARAMETER, str(exc)) from None
        except RuntimeError as exc:
            node.get_logger().warning(f"{NICE_PARAMETER} {nice} not applied: {exc}")
            return
        node.get_logger().info(
            f"running at niceness {nice}" + (" (its session group too)" if group else "")
        )


def init_rclpy(args: list[str] | None, node_name: str) -> bool:
    """``rclpy.init`` with this module's signal handling (StopRequest). False, after one line
    ``error: <node>: <what>`` on stderr, when rcl refuses the command line's ROS arguments (an
    empty ``-p NAME:=``, a namespace that is no ROS name, a parameter file that is not valid
    YAML), which rclpy raises as a traceback."""
    import os
    import sys
    import tempfile

    import rclpy
    from rclpy.signals import SignalHandlerOptions

    # rcl logs its own "Failed to parse global arguments" line to stderr: it is held back, and
    # passed on only when the initialisation succeeds
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            refused = None
        except Exception as exc:
            if type(exc).__name__ != "RCLError":
                raise
            refused = ros_arguments_error(str(exc))
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if refused is not None:
            print(f"error: {node_name}: {refused}", file=sys.stderr)
            return False
        held.seek(0)
        sys.stderr.write(held.read().decode(errors="replace"))
    return True


def ros_arguments_error(text: str) -> str:
    """rcl's message for refused ROS arguments, without its prefix and source locations:
    ``failed to initialize rcl: Couldn't parse params file: '--params-file F'. Error: Error
    parsing a event near line 3, at /.../parse.c:782, ...`` -> ``Couldn't parse params file:
    '--params-file F' (Error parsing a event near line 3)``."""
    text = text.removeprefix("failed to initialize rcl: ")
    what, sep, detail = text.partition(". Error: ")
    detail = detail.split(", at /")[0].strip()
    if not sep or not detail or detail == "error not set":
        return what.split(", at /")[0]
    return f"{what} ({detail})"


def run_node(
    make_node: Callable[[], object],
    node_name: str,
    args: list[str] | None = None,
    on_stop: Callable[[object], Iterable[Callable[[], object]]] = lambda node: (),
) -> int:
    """The ``main`` of a node process: initialise rclpy with this module's signal handling,
    build the node with ``make_node()`` (a ParameterError -> one line naming the node and the
    parameter, exit code 2; a signal during start-up -> exit 0), spin it until stopped with
    ``on_stop(node)`` as the drain steps, then destroy it. Returns the exit code.

    A node may set ``fatal_error`` (a ParameterError) while it runs: a parameter that turns
    out not to fit the data, known only at the first frame (stereo_depth's ``match_rows``
    against the image height). The node then stops as on a signal and the process ends with
    that parameter's one line and exit code 2, instead of running on producing nothing."""
    import sys

    import rclpy

    from .node_parameters import EXIT_BAD_PARAMETER, ParameterError, parameter_error_line

    if not init_rclpy(args if args is not None else sys.argv, node_name):
        return EXIT_BAD_PARAMETER
    stop = StopRequest.install()
    try:
        node = make_node()
    except ParameterError as exc:
        print(parameter_error_line(node_name, exc), file=sys.stderr)
        rclpy.try_shutdown()
        return EXIT_BAD_PARAMETER
    except KeyboardInterrupt:  # stopped during start-up
        rclpy.try_shutdown()
        return 0

    def fatal() -> ParameterError | None:
        return getattr(node, "fatal_error", None)

    try:
        spin_until_stopped(
            node, stop, node.health, on_stop=list(on_stop(node)), done=lambda: fatal() is not None
        )
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    if fatal() is not None:
        print(parameter_error_line(node_name, fatal()), file=sys.stderr)
        return EXIT_BAD_PARAMETER
    return 0
