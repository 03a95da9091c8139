"""Frame accounting of one node and the latest-frame policy, free of ROS.

A camera does not wait for the graph. A node that is slower than its input must not let a queue
grow (latency grows with it) nor lose frames silently (a DDS KEEP_LAST queue overwrites the oldest
sample and nobody knows): it processes the newest frame and counts every frame it skips.

- :class:`FrameCounter`: frames in / out / dropped of one node (thread-safe), the figures a node
  reports on ``/diagnostics`` and in its exit line, and the time its worker spent on each of
  the last frames (wall and CPU of the worker thread: the stage's own time in the graph, to set
  beside the same work alone).
- :class:`LatestFrameWorker`: a thread that processes what the receiving callbacks submit, in
  order, so that they return at once; a frame that is superseded by a newer one before its turn
  is skipped and counted as dropped. ``stop()`` finishes what is in hand and waiting (drain),
  then joins.
"""

from __future__ import annotations

import statistics
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class FrameCounts:
    """A snapshot of a :class:`FrameCounter`."""

    received: int = 0
    published: int = 0
    dropped: int = 0

    @property
    def pending(self) -> int:
        """Frames received and neither published nor dropped yet (in process or queued)."""
        return self.received - self.published - self.dropped

    def summary(self) -> str:
        """``frames in 16, out 15, dropped 1`` (the node's exit line and diagnostics message)."""
        return f"frames in {self.received}, out {self.published}, dropped {self.dropped}"


class FrameCounter:
    """Frames in / out / dropped of one node. Every frame counted in must end up counted out or
    dropped, so that ``pending`` is what the node still holds."""

    #: frames whose processing time is kept (the median reported is over these)
    TIMED_FRAMES = 100

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._received = 0
        self._published = 0
        self._dropped = 0
        self._times: deque[tuple[float, float]] = deque(maxlen=self.TIMED_FRAMES)

    def received(self, n: int = 1) -> None:
        with self._lock:
            self._received += n

    def published(self, n: int = 1) -> None:
        with self._lock:
            self._published += n

    def dropped(self, n: int = 1) -> None:
        with self._lock:
            self._dropped += n

    def snapshot(self) -> FrameCounts:
        with self._lock:
            return FrameCounts(self._received, self._published, self._dropped)

    def processed(self, wall_s: float, cpu_s: float) -> None:
        """One frame's processing took ``wall_s`` seconds, ``cpu_s`` of them on a CPU (the
        processing thread's CPU time; a library's own threads are not counted)."""
        with self._lock:
            self._times.append((wall_s, cpu_s))

    def processing_ms(self) -> tuple[float, float] | None:
        """Median (wall, CPU) milliseconds per frame over the last :attr:`TIMED_FRAMES`
        processed frames; None before the first."""
        with self._lock:
            times = list(self._times)
        if not times:
            return None
        return (
            1e3 * statistics.median(t[0] for t in times),
            1e3 * statistics.median(t[1] for t in times),
        )


class LatestFrameWorker:
    """Processes submitted items in order in its own thread, skipping stale frames.

    Items are submitted as frames (``frame=True``: superseded by newer frames) or as other
    items (always processed, e.g. the small messages a frame is combined with). When the worker
    takes a frame while ``max_waiting`` newer frames are already waiting, it calls
    ``skip(item)`` instead of ``process(item)`` and counts a drop on ``counter``: with the
    default of 1, the newest frame is processed and the queue of frames never grows beyond one;
    lockstep playback with K frames in flight uses ``max_waiting = K`` and never skips. An
    exception in ``process`` goes to ``on_error(exc, item)`` (default: one line on stderr) and
    the worker goes on. Each processed frame's wall and thread-CPU time is booked on
    ``timing`` (default: ``counter``).

    ``admit(item)`` (optional) is the back-pressure of the stage after this one
    (:class:`vehicle_common.flow_control.InFlightWindow`): asked before a frame that is not
    stale starts, it returns None to start it, or the seconds to wait before asking again; the
    frame then waits (a newer one supersedes it, skipped and counted as above) until
    :meth:`wake` is called or that time has passed. Items that are not frames, and every item
    once the worker is stopping, are not held back.
    """

    def __init__(
        self,
        process: Callable[[Any], None],
        counter: FrameCounter | None = None,
        name: str = "frame-worker",
        on_error: Callable[[BaseException, Any], None] | None = None,
        skip: Callable[[Any], None] | None = None,
        max_waiting: int = 1,
        timing: FrameCounter | None = None,
        admit: Callable[[Any], float | None] | None = None,
    ) -> None:
        if max_waiting < 1:
            raise ValueError(f"max_waiting {max_waiting} must be >= 1")
        self.max_waiting = int(max_waiting)
        self._process = process
        self._skip = skip
        self._admit = admit
        self._on_error = on_error or _print_error
        self.counter = counter
        self._timing = timing or counter  # books each processed frame's wall / CPU time
        self._cond = threading.Condition()
        self._queue: deque[tuple[Any, bool]] = deque()
        self._frames_waiting = 0
        self._busy = False
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, item: Any, frame: bool = True) -> None:
        with self._cond:
            self._queue.append((item, frame))
            self._frames_waiting += frame
            self._cond.notify_all()

    @property
    def busy(self) -> bool:
        """An item is in process or waiting."""
        with self._cond:
            return self._busy or bool(self._queue)

    def wake(self) -> None:
        """Ask ``admit`` again now (the stage after this one finished a frame)."""
        with self._cond:
            self._cond.notify_all()

    def _next(self) -> tuple[bool, Any, bool, bool]:
        """(ok, item, is a frame, stale) of the next item; ok is False once closed and empty."""
        with self._cond:
            while True:
                self._cond.wait_for(lambda: self._queue or self._closed)
                if not self._queue:
                    return False, None, False, False
                item, frame = self._queue[0]
                stale = frame and self._frames_waiting - 1 >= self.max_waiting
                if frame and not stale and self._admit is not None and not self._closed:
                    wait = self._admit(item)
                    if wait is not None:  # held back: woken by a newer item, wake() or time
                        self._cond.wait(wait)
                        continue
                self._queue.popleft()
                self._frames_waiting -= frame
                self._busy = True
                return True, item, frame, stale

    def _run(self) -> None:
        while True:
            ok, item, frame, stale = self._next()
            if not ok:
                return
            try:
                if stale:
                    if self.counter is not None:
                        self.counter.dropped()
                    if self._skip is not None:
                        self._skip(item)
                else:
                    t0, c0 = time.perf_counter(), time.thread_time()
                    self._process(item)
                    if frame and self._timing is not None:
                        self._timing.processed(time.perf_counter() - t0, time.thread_time() - c0)
            except Exception as exc:  # noqa: BLE001 (reported, the worker keeps running)
                self._on_error(exc, item)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Wait until nothing is in process or waiting; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._busy and not self._queue, timeout)

    def stop(self, timeout: float = 10.0) -> bool:
        """Process what is in hand and waiting, then end the thread; False if it did not end
        within ``timeout`` seconds."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout)
        return not self._thread.is_alive()


def _print_error(exc: BaseException, _item: Any) -> None:
    print(f"error: frame processing failed: {type(exc).__name__}: {exc}", file=sys.stderr)
