"""Per-frame trace points of the graph's nodes: when each frame reaches each step, in which
process and thread, with that thread's CPU time. Pure (standard library only).

Off unless the environment variable ``VEHICLE_TRACE_DIR`` names a folder when the node starts;
then every node appends one line per event to ``<folder>/<node>_<pid>.trace``::

    <event> <frame stamp ns> <CLOCK_MONOTONIC ns> <thread CPU ns>

The monotonic clock is the machine's, so the events of all processes on one machine line up;
the thread CPU time tells a step's own work from the time it waited for a core (compare two
events of the same thread only). ``bench/bench_graph.py`` reads the files and prints where a
frame's time goes between the camera's clock and the tracks. The events are the ROS 2
tracing idea (``ros2_tracing`` tracepoints) at the granularity this project needs, without
LTTng. Off, a trace call costs one Python call; on, one buffered line write (about a
microsecond) per event.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

TRACE_ENV = "VEHICLE_TRACE_DIR"
SUFFIX = ".trace"

Tracer = Callable[[str, int], None]


def _off(event: str, stamp_ns: int) -> None:
    """Tracing off: nothing recorded."""


class FileTracer:
    """Appends ``event stamp monotonic_ns thread_cpu_ns`` lines to one file (thread-safe)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "a", buffering=1)  # noqa: SIM115 - held for the process
        self._lock = threading.Lock()

    def __call__(self, event: str, stamp_ns: int) -> None:
        line = f"{event} {int(stamp_ns)} {time.monotonic_ns()} {time.thread_time_ns()}\n"
        with self._lock:
            self._file.write(line)

    def close(self) -> None:
        with self._lock:
            self._file.close()


def frame_tracer(node_name: str, environ: dict | None = None) -> Tracer:
    """The node's tracer: a :class:`FileTracer` in ``$VEHICLE_TRACE_DIR`` when it is set, else
    a function that does nothing."""
    folder = (os.environ if environ is None else environ).get(TRACE_ENV, "")
    if not folder:
        return _off
    return FileTracer(Path(folder) / f"{node_name}_{os.getpid()}{SUFFIX}")


def read_traces(folder: str | os.PathLike) -> dict[int, dict[str, tuple[int, int]]]:
    """``{frame stamp ns: {event: (monotonic ns, thread CPU ns)}}`` of every trace file in
    ``folder`` (an event seen twice for a frame keeps its first time). A line that is cut
    (the node was killed while writing) or malformed is skipped."""
    frames: dict[int, dict[str, tuple[int, int]]] = {}
    for path in sorted(Path(folder).glob(f"*{SUFFIX}")):
        for line in path.read_text(errors="replace").splitlines():
            parts = line.split()
            if len(parts) != 4:
                continue
            try:
                stamp, t, cpu = int(parts[1]), int(parts[2]), int(parts[3])
            except ValueError:
                continue
            frames.setdefault(stamp, {}).setdefault(parts[0], (t, cpu))
    return frames


def span_ms(
    frames: dict[int, dict[str, tuple[int, int]]], start: str, end: str, cpu: bool = False
) -> list[float]:
    """Per frame that has both events: ``end - start`` in ms (wall; with ``cpu`` the thread CPU
    time between them, meaningful when both events come from the same thread)."""
    k = 1 if cpu else 0
    return [
        (ev[end][k] - ev[start][k]) * 1e-6
        for _, ev in sorted(frames.items())
        if start in ev and end in ev
    ]
