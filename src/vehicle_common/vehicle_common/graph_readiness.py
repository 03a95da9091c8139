"""Readiness of every edge of the graph and the per-node report it is decided from, free of ROS.

A message published before its subscription is matched is lost (VOLATILE QoS), and only the
publishing process knows which subscriptions its publisher has matched. So every node reports,
on ``/diagnostics`` (one ``diagnostic_msgs/DiagnosticStatus`` per node), its frame counts and, per
topic it publishes, the number of matched subscriptions (:class:`NodeReport`). The data source
(the player) is told how many subscriptions each topic of the graph must have (``"topic:N,..."``,
computed from ``tracking_bringup.graph``) and publishes its first frame only when every topic,
its own and every other node's, has them (:func:`unready_topics`). That holds whatever the start
order, including all nodes started at once as the ROS launch file does.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from .frame_accounting import FrameCounts

#: DiagnosticStatus.hardware_id of the reports, so that other statuses on /diagnostics are ignored.
REPORT_ID = "stereo_tracking_graph"
_MATCHED = "matched_subscriptions "


def parse_topic_counts(spec: str) -> dict[str, int]:
    """``"/a:2,/b:1"`` -> ``{"/a": 2, "/b": 1}``; raises ValueError naming a malformed entry."""
    counts = {}
    for entry in filter(None, (e.strip() for e in spec.split(","))):
        topic, sep, n = entry.rpartition(":")
        if not sep or not topic or not n.isdigit():
            raise ValueError(f"expected TOPIC:COUNT, got {entry!r}")
        counts[topic] = int(n)
    return counts


def format_topic_counts(counts: Mapping[str, int]) -> str:
    """Inverse of :func:`parse_topic_counts` (topics with a count of 0 are left out)."""
    return ",".join(f"{t}:{n}" for t, n in counts.items() if n)


@dataclass(frozen=True)
class NodeReport:
    """What one node reports: frame counts, whether a frame is in process, per published
    topic the number of matched subscriptions, and the median (wall, CPU) milliseconds its
    worker spent per frame (``processing_ms``; None for a node without a frame worker or
    before its first frame), and the reporting process's id (``pid``; None when not given), so
    that a launcher takes only its own processes' reports: a stray process of the same name on
    the same ROS domain (another graph, one left by an earlier run) must not keep a frozen node
    looking alive."""

    node: str
    counts: FrameCounts = FrameCounts()
    busy: bool = False
    matched: dict[str, int] = field(default_factory=dict)
    processing_ms: tuple[float, float] | None = None
    pid: int | None = None
    #: frames the node could compute on (None: a node that does not say) and the latest cause
    #: of a frame it could not use (vehicle_common.input_usage)
    used: int | None = None
    problem: str = ""

    @property
    def idle(self) -> bool:
        """Nothing in process and nothing waiting."""
        return not self.busy and self.counts.pending <= 0

    def values(self) -> list[tuple[str, str]]:
        """Key/value pairs of the DiagnosticStatus."""
        c = self.counts
        out = [
            ("frames_in", str(c.received)),
            ("frames_out", str(c.published)),
            ("frames_dropped", str(c.dropped)),
            ("busy", "1" if self.busy else "0"),
        ]
        if self.processing_ms is not None:
            out += [
                ("processing_ms_p50", f"{self.processing_ms[0]:.2f}"),
                ("processing_cpu_ms_p50", f"{self.processing_ms[1]:.2f}"),
            ]
        if self.pid is not None:
            out.append(("pid", str(self.pid)))
        if self.used is not None:
            out.append(("frames_used", str(self.used)))
        if self.problem:
            out.append(("problem", self.problem))
        return out + [(_MATCHED + t, str(n)) for t, n in sorted(self.matched.items())]

    @classmethod
    def from_values(cls, node: str, values: Iterable[tuple[str, str]]) -> NodeReport:
        """Inverse of :meth:`values`; raises ValueError for a malformed value."""
        kv = dict(values)
        try:
            counts = FrameCounts(
                int(kv.get("frames_in", 0)),
                int(kv.get("frames_out", 0)),
                int(kv.get("frames_dropped", 0)),
            )
            matched = {k[len(_MATCHED) :]: int(v) for k, v in kv.items() if k.startswith(_MATCHED)}
            timing = None
            if "processing_ms_p50" in kv:
                timing = (float(kv["processing_ms_p50"]), float(kv["processing_cpu_ms_p50"]))
            pid = int(kv["pid"]) if "pid" in kv else None
            used = int(kv["frames_used"]) if "frames_used" in kv else None
        except (ValueError, KeyError) as exc:
            raise ValueError(f"report of {node}: {exc}") from None
        busy = kv.get("busy") == "1"
        problem = kv.get("problem", "")
        return cls(node.lstrip("/"), counts, busy, matched, timing, pid, used, problem)


def unready_topics(
    expected: Mapping[str, int],
    own: Mapping[str, int],
    reports: Iterable[NodeReport],
) -> list[str]:
    """Topics whose publisher has not yet matched the expected number of subscriptions, as
    ``"topic (have/want)"``. ``own``: matched counts of the caller's publishers; ``reports``: the
    latest report of every other node (a topic no report mentions has 0)."""
    matched = dict(own)
    for report in reports:
        for topic, n in report.matched.items():
            if topic not in own:
                matched[topic] = max(matched.get(topic, 0), n)
    return [
        f"{topic} ({matched.get(topic, 0)}/{want})"
        for topic, want in expected.items()
        if matched.get(topic, 0) < want
    ]


def graph_quiescent(reports: Iterable[NodeReport]) -> bool:
    """Every reporting node is idle (used to let the frames in flight drain at shutdown)."""
    return all(r.idle for r in reports)


class ProgressWatch:
    """Which nodes of a graph stopped making progress, from their reports (every node reports
    at least once a second, :class:`vehicle_common.node_runtime.NodeHealth`).

    A node has stalled when, for ``timeout_s``, either no report of it arrived while another
    node's did (so the watcher itself is not the one cut off), or it reported a frame in process
    (``busy``) without any change of its frame counts. Feed every report with :meth:`seen`."""

    def __init__(self, timeout_s: float = 5.0) -> None:
        self.timeout_s = timeout_s
        self._last_report: dict[str, float] = {}
        self._last_change: dict[str, float] = {}
        self._last: dict[str, NodeReport] = {}

    def seen(self, name: str, report: NodeReport, now: float) -> None:
        previous = self._last.get(name)
        if previous is None or previous.counts != report.counts or not previous.busy:
            self._last_change[name] = now
        self._last_report[name] = now
        self._last[name] = report

    def forget(self, name: str) -> None:
        """Stop watching ``name`` (a node that exited)."""
        for table in (self._last_report, self._last_change, self._last):
            table.pop(name, None)

    def busy_s(self, name: str, now: float) -> float:
        """Seconds ``name`` has reported the same frame in process (0 when not busy)."""
        last = self._last.get(name)
        if last is None or not last.busy:
            return 0.0
        return now - self._last_change[name]

    def silent_s(self, name: str, now: float) -> float:
        """Seconds since the last report of ``name`` (0 when it is not watched)."""
        last = self._last_report.get(name)
        return 0.0 if last is None else now - last

    def stalled(self, now: float, names: Iterable[str] | None = None) -> dict[str, str]:
        """``{node: why}`` of the watched nodes (restricted to ``names``) that stalled."""
        watched = [n for n in self._last_report if names is None or n in set(names)]
        newest = max(self._last_report.values(), default=now)
        out = {}
        for name in watched:
            silent = now - self._last_report[name]
            if silent >= self.timeout_s and now - newest < self.timeout_s:
                out[name] = f"no report on /diagnostics for {silent:.1f} s"
            elif self._last[name].busy and now - self._last_change[name] >= self.timeout_s:
                out[name] = (
                    f"a frame in process for {now - self._last_change[name]:.1f} s without "
                    f"progress (frames in {self._last[name].counts.received}, out "
                    f"{self._last[name].counts.published})"
                )
        return out
