"""The detector node's frame admission and framing (pure: no rclpy).

:class:`DownstreamAdmission` is the back-pressure: the worker's question before it detects an
image, answered from the frames in flight downstream (:class:`vehicle_common.flow_control.
InFlightWindow`); :class:`CameraWait` is the camera the CNN's images are framed for, and
:func:`apply_framing` their framing.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from vehicle_common.camera_settings import CameraModel, detector_framing
from vehicle_common.flow_control import CameraCadence, InFlightWindow
from vehicle_common.frame_messages import stamp_ns

from vehicle_common import topics

DOWNSTREAM_TOPIC = topics.DETECTIONS_3D  # back-pressure: a frame's end downstream
#: [s] between two looks at whether anyone publishes the 3D arrays
DOWNSTREAM_CHECK_S = 0.5


class DownstreamAdmission:
    """Back-pressure: an image waits while the stereo node has no room for it (``window``
    frames in flight, each freed after ``timeout`` s). ``publishers()``: how many publish the
    3D arrays; ``warn``: a warning line (a frame's place freed by its timeout). When there is
    room and the camera's next image is due within ``next_frame_wait`` of its period, the
    worker waits for that image (:class:`vehicle_common.flow_control.CameraCadence`; the images'
    arrivals are given with :meth:`arrived`). ``lead()``: the CNN's time per frame [s] (None
    while unknown): one more frame may start that long before the newest frame in flight is
    expected to end downstream (``downstream_lead``; :meth:`InFlightWindow.room_in`)."""

    def __init__(
        self,
        window: int,
        timeout: float,
        publishers: Callable[[], int],
        warn: Callable[[str], object],
        next_frame_wait: float = 0.0,
        lead: Callable[[], float | None] | None = None,
    ) -> None:
        self.flow = InFlightWindow(window, timeout)
        self._lead = lead  # [s] the CNN's time per frame (None: not known yet); None: no lead
        self.cadence = CameraCadence()
        self.next_frame_wait = float(next_frame_wait)
        self.waited_for_next = 0  # times a fresher image was waited for
        self._downstream = (False, float("-inf"))  # (publisher seen, checked at)
        self._expired_seen = 0
        self._publishers = publishers
        self._warn = warn

    def admit(self, msg) -> float | None:
        """The worker's question before it detects ``msg`` (back-pressure): None to start it,
        else seconds to wait for a frame's end downstream. No one publishing the 3D arrays
        (checked every DOWNSTREAM_CHECK_S): no back-pressure."""
        seen, at = self._downstream
        now = time.monotonic()
        if now - at >= DOWNSTREAM_CHECK_S:
            seen = self._publishers() > 0
            if not seen:
                self.flow.clear()
            self._downstream = (seen, now)
        if not seen:
            return None
        lead = (self._lead() or 0.0) if self._lead is not None else 0.0
        if self.next_frame_wait > 0 and self.flow.room_in(lead) == 0:
            fresher = self.cadence.wait_for_next(self.next_frame_wait)
            if fresher is not None:
                self.waited_for_next += 1
                return fresher
        wait = self.flow.admit(stamp_ns(msg.header), lead)
        if self.flow.expired > self._expired_seen:
            self._expired_seen = self.flow.expired
            self._warn(
                f"{DOWNSTREAM_TOPIC}: no 3D array for a detected frame within "
                f"{self.flow.timeout:.1f} s ({self.flow.expired} so far); its place in the "
                "window is freed"
            )
        return wait

    def arrived(self) -> None:
        """An image arrived (the camera's cadence)."""
        self.cadence.arrived()

    def finish(self, msg, wake: Callable[[], object]) -> None:
        """A 3D array: the frames detected up to its stamp are done downstream (``wake``: the
        worker, when one was)."""
        if self.flow.finish(stamp_ns(msg.header)):
            wake()


class CameraWait:
    """The CNN's camera for its framing, from the left CameraInfo (derived from it unless every
    part of the framing is given: ``derive``); an image that arrives before the first
    CameraInfo waits for it (``held``; a newer one supersedes it)."""

    def __init__(self, derive: bool) -> None:
        self.derive = derive
        self.camera: CameraModel | None = None
        self.error: str | None = None
        self.held = None  # an image that waits for the first CameraInfo
        self.lock = threading.Lock()

    def bad(self, exc: Exception) -> bool:
        """A CameraInfo that gives no camera: True when ``exc`` is not the error before."""
        if str(exc) == self.error:
            return False
        self.error = str(exc)
        return True

    def changed(self, camera: CameraModel) -> tuple[bool, CameraModel | None]:
        """A CameraInfo's camera: (whether its size or fx changed, the camera before)."""
        key = (camera.width, camera.height, camera.fx)
        with self.lock:
            old = self.camera
            if old is not None and (old.width, old.height, old.fx) == key:
                return False, old
            self.camera, self.error = camera, None
        return True, old

    def take_held(self):
        """The waiting image (None: none), no longer waiting."""
        with self.lock:
            held, self.held = self.held, None
        return held


def apply_framing(cnn, p, camera: CameraModel | None, old: CameraModel | None) -> tuple[str, str]:
    """Frame ``cnn``'s images for ``camera`` (vehicle_common.camera_settings; parameters ``p``)
    and the ONE line to log, (level, line): what was derived and from what (a changed camera:
    also what it was)."""
    framing = detector_framing(
        camera, *cnn.checkpoint_framing(), (p.input_width, p.input_height), p.roi_top
    )
    before = (cnn.config.input_width, cnn.config.input_height, cnn.roi_top)
    cnn.set_framing(framing.input_width, framing.input_height, framing.roi_top)
    if old is None:
        return "info", framing.text
    where = f"below the top {100 * before[2]:.0f} %" if before[2] > 0 else "whole image"
    was = f"was {before[0]}x{before[1]}, {where}"
    return "warning", f"camera_info changed ({was}): {framing.text}"
