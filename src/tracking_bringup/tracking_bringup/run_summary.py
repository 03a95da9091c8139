"""The launcher's console lines about input the graph cannot use (issue #42: a run must never
end silently with no tracks). Pure: fed the nodes' latest /diagnostics reports
(:class:`vehicle_common.graph_readiness.NodeReport`).

The processing nodes (detector, stereo depth) report how many frames they could use and the
latest cause of one they could not (``used`` and ``problem``, vehicle_common.input_usage): a
camera_info of zeros or of another size, an unsupported encoding, a right image too far from its
left one, a publisher whose QoS cannot match. While the graph runs, :meth:`RunSummary.check` says
on the console, once per node and cause:

- a node that finished frames (published or dropped them) for ``silent_s`` and used none:
  ``stereo_depth: 0 of 48 frames used: left image is 1242x375 but ...``;
- a node that has received no frame for ``silent_s`` since the graph was ready.

At the end of the run :meth:`RunSummary.final` says it for every node that used no frame at
all (or received none), and returns exit code 1 then: no frame went through the pipeline, so
the run tracked nothing. A run whose frames were used exits 0 even if no vehicle was in view.
Nodes that do not report ``used`` (the tracker, the player, the recorder) are not judged.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from vehicle_common.graph_readiness import NodeReport

#: s with frames coming in and none used, or with no frame at all, before the console says so
#: (a camera at 1 Hz still delivers several frames; the graph's start-up is over by then)
SILENT_S = 10.0
#: frames finished unused, with no cause reported, before the console says so (a slow node's
#: first frames superseded while it starts are not a fault)
UNEXPLAINED_FRAMES = 3
#: exit code of a run that tracked nothing (no frame was used)
EXIT_NOTHING_USED = 1


def usage_line(node: str, report: NodeReport) -> str | None:
    """The line for a node that used none of its frames or received none; None otherwise."""
    if report.used is None:
        return None
    cause = f": {report.problem}" if report.problem else ""
    if report.counts.received == 0:
        return f"{node}: no input frame received{cause or ' (nothing published on its topics?)'}"
    if report.used == 0:
        return f"{node}: 0 of {report.counts.received} frames used{cause}"
    return None


def _done(report: NodeReport) -> int:
    return report.counts.published + report.counts.dropped


@dataclass
class _Progress:
    since: float  # when ``used`` last changed (or the first report)
    done: int  # frames finished (published or dropped) then
    used: int


@dataclass
class RunSummary:
    """Says on ``announce`` what the nodes could not use (module docstring)."""

    announce: Callable[[str], None] = print
    silent_s: float = SILENT_S
    _progress: dict[str, _Progress] = field(default_factory=dict)
    _said: set[tuple[str, str]] = field(default_factory=set)

    def check(self, reports: Mapping[str, NodeReport], now: float) -> None:
        """While the graph runs (called at every poll)."""
        for node, r in reports.items():
            if r.used is None:
                continue
            p = self._progress.get(node)
            if p is None or r.used != p.used:
                self._progress[node] = _Progress(now, _done(r), r.used)
                continue
            if now - p.since < self.silent_s:
                continue
            if r.counts.received == 0:
                line = f"{node}: no input frame received in {now - p.since:.0f} s"
                line += f": {r.problem}" if r.problem else " (nothing published on its topics?)"
                self._say(node, r.problem or "no input", f"warning: {line}")
            elif _done(r) - p.done >= (1 if r.problem else UNEXPLAINED_FRAMES):
                line = f"{node}: 0 of the last {_done(r) - p.done} frames used"
                line += f": {r.problem}" if r.problem else ""
                self._say(node, r.problem, f"warning: {line}")

    def final(self, reports: Mapping[str, NodeReport]) -> int:
        """At the end of the run: one line per node that used no frame; the exit code (0, or
        :data:`EXIT_NOTHING_USED` when no frame was used)."""
        lines = [line for n, r in reports.items() if (line := usage_line(n, r))]
        for line in lines:
            self.announce(f"error: the run tracked nothing: {line}")
        return EXIT_NOTHING_USED if lines else 0

    def _say(self, node: str, cause: str, line: str) -> None:
        if (node, cause) not in self._said:
            self._said.add((node, cause))
            self.announce(line)
