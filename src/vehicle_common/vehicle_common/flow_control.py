"""Back-pressure between two stages of the graph, free of ROS: a window of frames in flight.

A live camera does not wait for the graph (lockstep makes the player wait; a camera cannot).
When the camera is faster than the graph, a stage that takes every frame it can does work that
the next stage throws away: issue #39 measured the detector detecting every frame while the
stereo node took only the newest complete set, so most detections were wasted, and on one core
that waste took the core from the stereo node.

:class:`InFlightWindow` is the upstream stage's account of the frames it has started and the
downstream stage has not finished yet. A frame is *in flight* from the moment the upstream stage
starts working on it until the downstream stage's output with a stamp at or after it arrives
(the downstream stage processes its frames in stamp order, so an output at stamp S also ends
every older frame: one it dropped, or one whose output was lost). The upstream stage starts a
new frame only while fewer than ``window`` are in flight; otherwise the frame waits, and a newer
one arriving meanwhile supersedes it (the latest-frame policy: skipped and counted where it is
skipped). A frame whose end never comes (the downstream node stopped, a message lost) leaves the
window after a timeout, counted as ``expired``, so the upstream stage never stops for good: 5 x
``timeout_s`` until a frame's time in flight is known, then the larger of ``timeout_s`` and
twice the longest of the last frames' times in flight (a starved machine, where a frame takes
seconds, must not see every frame expire and lose the back-pressure; measured on a 2-core
machine at load 25-36: 5-12 s per frame).

``window`` 1: one frame in the pipeline after the camera, like lockstep with window 1 for the
player: no frame is started that the next stage could not take at once, and on one core no
stage's work competes with another's. ``window`` 0: no back-pressure.
With a lead (``admit(stamp, lead_s)``, the detector's ``downstream_lead``, off by default) one
more frame may start ``lead_s`` (the upstream stage's own time) before the newest frame in
flight is expected to end: it reaches the next stage as that stage frees, and the two stages
work side by side. On 2 cores that cost latency (docs/ARCHITECTURE.md, "Frame flow").

:class:`CameraCadence` is the other half of a fresh frame: when the window frees, the newest
image has waited on average half a camera period (a quarter of the graph's cycle at a camera
twice its capacity: issue #39 measured 41 ms of a 145 ms lockstep latency at 2x). When the
camera's next image is due within a share of its period (``next_frame_wait``, 0.5: the mean
wait is an eighth of the period, and so is the mean age of the frame taken), the stage waits for
that image instead: its frames are fresher at a small cost in frames (at most 1 / (1 + P / 8T),
P the camera period and T the graph's cycle: 6 % at 2x, 4 % at 3x).
"""

from __future__ import annotations

import statistics
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable


class InFlightWindow:
    """Frames started upstream and not yet finished downstream, keyed by stamp (thread-safe)."""

    def __init__(
        self, window: int, timeout_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        if window < 0:
            raise ValueError(f"window {window} must be >= 0 (0: no back-pressure)")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s {timeout_s} must be > 0")
        self.window = int(window)
        self.timeout_s = float(timeout_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._started: OrderedDict[int, float] = OrderedDict()  # stamp -> start time
        self.finished = 0  # frames ended by a downstream output
        self.expired = 0  # frames whose end never came within the timeout
        self._times: deque[float] = deque(maxlen=self.TIMED_FRAMES)  # [s] start -> own output
        self._expired_starts: OrderedDict[int, float] = OrderedDict()  # stamp -> start time

    #: frames whose time in flight sets the timeout
    TIMED_FRAMES = 8
    #: the timeout until a frame's time in flight is known: timeout_s x this (the first frame
    #: of a graph is slower, and at load 20 on one core it took 7 s: with 1 s every frame of
    #: the first seconds expired and the stereo node got a backlog of 4-6 frames)
    FIRST_TIMEOUT_FACTOR = 5.0

    @property
    def timeout(self) -> float:
        """[s] after which a frame in flight expires: ``timeout_s`` x :attr:`FIRST_TIMEOUT_FACTOR`
        until a frame's time is known, then ``timeout_s``, or twice the longest of
        the last :attr:`TIMED_FRAMES` frames' times from start to their own output (also of a
        frame that had expired: a stage slower than the timeout is learnt from it)."""
        if not self._times:  # the first frames (a cold start, a starved machine): longer
            return self.FIRST_TIMEOUT_FACTOR * self.timeout_s
        return max(self.timeout_s, 2.0 * max(self._times))

    @property
    def in_flight(self) -> int:
        with self._lock:
            self._expire(self._clock())
            return len(self._started)

    def _expire(self, now: float) -> None:
        timeout = self.timeout
        while self._started:
            stamp, t0 = next(iter(self._started.items()))
            if now - t0 < timeout:
                return
            del self._started[stamp]
            self.expired += 1
            # its output may still come: its time in flight then sets the timeout
            self._expired_starts[stamp] = t0
            while len(self._expired_starts) > self.TIMED_FRAMES:
                self._expired_starts.popitem(last=False)

    def _room_in(self, now: float, lead_s: float) -> float:
        """[s] until a frame may start (0: now); call with the lock held, expired frames gone.

        Full window: when the oldest frame in flight expires. With ``lead_s`` > 0 and the
        window full by exactly ``window`` frames whose time in flight is known, one more frame
        may start ``lead_s`` before the newest one in flight is expected to end (its start plus
        the median of the last frames' times in flight): a stage that takes ``lead_s`` to do
        its part hands its frame over just as the stage after it can take it."""
        if not self.window or len(self._started) < self.window:
            return 0.0
        oldest = next(iter(self._started.values()))
        expires = max(oldest + self.timeout - now, 1e-3)
        if lead_s > 0 and len(self._started) == self.window and self._times:
            newest = next(reversed(self._started.values()))
            start_at = newest + statistics.median(self._times) - lead_s
            if now >= start_at:
                return 0.0
            return max(min(start_at - now, expires), 1e-3)
        return expires

    def room_in(self, lead_s: float = 0.0) -> float:
        """[s] until :meth:`admit` would start a frame (0: now), nothing started."""
        with self._lock:
            now = self._clock()
            self._expire(now)
            return self._room_in(now, lead_s)

    def admit(self, stamp: int, lead_s: float = 0.0) -> float | None:
        """Start the frame at ``stamp`` if the window has room (then None), else the seconds
        after which to ask again (the oldest frame in flight expires; with ``lead_s``: one more
        frame may start, :meth:`_room_in`), or when a frame ends."""
        with self._lock:
            now = self._clock()
            self._expire(now)
            wait = self._room_in(now, lead_s)
            if wait > 0:
                return wait
            self._started[int(stamp)] = now
            self._started.move_to_end(int(stamp))
            return None

    def finish(self, stamp: int) -> int:
        """The downstream stage's output at ``stamp``: every frame in flight at or before it
        ends. Returns how many ended (0: an output of a frame not started here)."""
        with self._lock:
            ended = [s for s in self._started if s <= stamp]
            t0 = self._started.get(stamp, self._expired_starts.pop(stamp, None))
            if t0 is not None:
                self._times.append(self._clock() - t0)
            for s in ended:
                del self._started[s]
            self.finished += len(ended)
            return len(ended)

    def clear(self) -> None:
        """Forget the frames in flight (the downstream stage went away)."""
        with self._lock:
            self._started.clear()


class CameraCadence:
    """When a camera's next image is due: the median of the last :attr:`INTERVALS` intervals
    between its images' arrivals (thread-safe; arrival times on ``clock``, not the stamps, so a
    camera whose clock differs from ours is measured all the same)."""

    #: intervals whose median is the camera period
    INTERVALS = 8
    #: intervals needed before a period is given
    MIN_INTERVALS = 3

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._last: float | None = None
        self._intervals: deque[float] = deque(maxlen=self.INTERVALS)

    def arrived(self) -> None:
        """An image arrived now."""
        with self._lock:
            now = self._clock()
            if self._last is not None:
                self._intervals.append(now - self._last)
            self._last = now

    def _period(self) -> float | None:
        """The median interval (call with the lock held)."""
        if len(self._intervals) < self.MIN_INTERVALS:
            return None
        return sorted(self._intervals)[len(self._intervals) // 2]

    @property
    def period(self) -> float | None:
        """[s] the camera period, None until :attr:`MIN_INTERVALS` intervals were seen."""
        with self._lock:
            return self._period()

    def _due(self) -> tuple[float | None, float | None]:
        """(period, seconds until the next image is due; negative: overdue), Nones while the
        period is unknown (one lock, one median)."""
        with self._lock:
            period = self._period()
            if period is None or self._last is None:
                return None, None
            return period, self._last + period - self._clock()

    #: share of the period an image may come late (the middleware's jitter) and still be
    #: waited for
    LATE = 0.25

    def wait_for_next(self, share: float) -> float | None:
        """[s] to wait for the next image when it is due within ``share`` of the period (it is
        then fresher than the newest one by nearly a period), else None: take the newest now.
        The wait lasts until :attr:`LATE` of a period after it is due; an image later than that
        (a camera that stopped) is not waited for again."""
        if share <= 0:
            return None
        period, due = self._due()
        if period is None:
            return None
        if not -self.LATE * period < due <= share * period:
            return None
        return due + self.LATE * period
