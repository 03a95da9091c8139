"""The stereo node's early start (pure, no rclpy): a frame's work that needs no 2D boxes, begun
while the detector runs on the same frame (issue #39; docs/stereo_depth.md section 17).

The detector announces each frame it starts on ``vehicles/detections_2d/started`` (the image's
header). When the stereo node has both that announcement and the frame's two images (in either
order), it starts ``work(stamp, left, right)`` in its helper thread: the images' conversion and
:meth:`.pipeline.StereoPipeline.begin` (scene map, odometry estimate, road plane's map). Only
frames the detector started are worked on, so a frame the detector skips costs nothing here;
only the newest announced frame is kept (an older one's work not yet started is cancelled).
When the frame's 2D array arrives, the worker :meth:`take`\\ s the work of its stamp. A detector
that announces nothing (another one than the graph's) leaves every frame to the usual path.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Executor, Future
from typing import Any


class EarlyStart:
    """Announced frames x complete image pairs -> ``executor.submit(work, stamp, left,
    right)``. ``pair_of(stamp)``: the frame's (left, right) images while its set waits for its
    2D array, else None (:meth:`.intake.FrameIntake.pair_of`)."""

    def __init__(
        self,
        executor: Executor,
        work: Callable[[int, Any, Any], Any],
        pair_of: Callable[[int], tuple | None],
    ) -> None:
        self._executor = executor
        self._work = work
        self._pair_of = pair_of
        self._lock = threading.Lock()
        self._announced: int | None = None  # the newest frame the detector started
        self._job: tuple[int, Future] | None = None  # (stamp, its work)
        self.started = 0  # frames whose work began ahead
        self.cancelled = 0  # begun ahead but superseded before they ran

    def announce(self, stamp: int) -> None:
        """The detector started the frame at ``stamp`` (its work starts once its images are
        here)."""
        with self._lock:
            if stamp == self._announced:
                return  # a repeat (an earlier stamp: a restarted camera, taken as it comes)
            self._announced = stamp
            pair = self._pair_of(stamp)
            if pair is not None:
                self._start(stamp, pair)

    def pair_ready(self, stamp: int) -> None:
        """The frame at ``stamp`` has both its images (its work starts if it was announced)."""
        with self._lock:
            if stamp != self._announced or (self._job is not None and self._job[0] == stamp):
                return
            pair = self._pair_of(stamp)
            if pair is not None:
                self._start(stamp, pair)

    def _start(self, stamp: int, pair: tuple) -> None:
        if self._job is not None and self._job[1].cancel():
            self.cancelled += 1  # superseded before it ran
        self._job = (stamp, self._executor.submit(self._work, stamp, *pair))
        self.started += 1

    def take(self, stamp: int) -> Future | None:
        """The work begun ahead on the frame at ``stamp`` (a Future that has run or runs now),
        or None: none begun, or not started yet (then cancelled: the caller does it all
        itself rather than wait behind the helper thread's queue). Work on an older frame is
        dropped; on a newer one it is kept for that frame."""
        with self._lock:
            job = self._job
            if job is None or job[0] > stamp:
                return None
            self._job = None
        if job[1].cancel():
            self.cancelled += 1
            return None
        return job[1] if job[0] == stamp else None
