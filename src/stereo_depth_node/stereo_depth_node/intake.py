"""A stereo node's frame intake (pure, no rclpy): its three inputs into one set per stamp.

A frame is the complete set of its left image, right image and 2D detection array with one stamp
(:class:`.stamp_sync.ExactStampSync`, in order); a right image goes into the set of the left one
it pairs with, within a tolerance (:class:`.stamp_sync.StereoPairing`). A complete set goes to
``submit``; a set that can no longer complete (a newer one did, the camera's time went back, or
the run ended) is dropped before any work on it, counted and its cause given to ``warn``.
``on_pair(stamp)`` (optional) is told when a set has both its images and waits for its 2D
array (:mod:`.early_start`), and :meth:`FrameIntake.pair_of` gives them.
"""

from __future__ import annotations

from collections.abc import Callable

from vehicle_common.frame_accounting import FrameCounter
from vehicle_common.input_usage import InputUsage

from vehicle_common import topics

from .stamp_sync import ExactStampSync, StereoPairing

#: the inputs of one frame, paired by stamp
FRAME_SLOTS = ("left", "right", "detections")


def stamp_text(ns: int) -> str:
    """A stamp in nanoseconds as seconds, e.g. ``12.000000500``."""
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


class FrameIntake:
    """The node's inputs -> complete frames (``submit((left, right, detections))``), the sets
    that cannot complete dropped and counted (``frames``, ``usage``) with one ``warn`` line."""

    def __init__(
        self,
        cache_size: int,
        stereo_sync_tolerance: float,
        frames: FrameCounter,
        usage: InputUsage,
        submit: Callable[[tuple], object],
        warn: Callable[[str], object],
        on_pair: Callable[[int], object] | None = None,
    ) -> None:
        # a frame = its left image, right image and 2D detection array (one stamp; in order)
        self.frame_sync = ExactStampSync(FRAME_SLOTS, cache_size, in_order=True)
        # a right image goes into the set of the left one it pairs with (within a tolerance)
        tolerance = -1 if stereo_sync_tolerance < 0 else round(stereo_sync_tolerance * 1e9)
        self.pairing = StereoPairing(tolerance, max_pending=cache_size)
        self.frames = frames
        self.usage = usage
        self._submit = submit
        self._warn = warn
        self._on_pair = on_pair
        self._last_left_stamp: int | None = None  # a jump back: a restarted camera
        self.dropped_detection_arrays = 0  # whose images never arrived (lost or superseded)
        self._last_frame_stamp: int | None = None  # the worker's

    def frame_went_back(self, stamp: int) -> int | None:
        """The previous frame's stamp when the worker's frame at ``stamp`` is older (a restarted
        camera or bag: its odometry starts afresh), else None."""
        last, self._last_frame_stamp = self._last_frame_stamp, stamp
        return last if last is not None and stamp < last else None

    def add(self, slot: str, stamp: int, msg) -> None:
        """A left image or a 2D detection array: into the frame's set; a complete set goes to
        ``submit``, and the sets it leaves behind (older, never to complete) are dropped."""
        if slot == "detections":
            self.frames.received()
        pairs = []
        if slot == "left":
            self._check_time(stamp)
            pairs = self.pairing.add_left(stamp)
        self._add_to_set(stamp, slot, msg)
        for left_stamp, right in pairs:
            self._add_to_set(left_stamp, "right", right)

    def add_right(self, stamp: int, msg) -> None:
        """A right image: into the set of the left image it pairs with (``pairing``)."""
        for left_stamp, right in self.pairing.add_right(stamp, msg):
            self._add_to_set(left_stamp, "right", right)

    def _check_time(self, stamp: int) -> None:
        """A left stamp older than the previous one (a restarted camera or bag): the sets of
        the previous stream still waiting can no longer complete (the worker resets the
        odometry when it meets the new stream's first frame)."""
        last, self._last_left_stamp = self._last_left_stamp, stamp
        if last is not None and stamp < last:
            for ev in self.frame_sync.take_pending():
                self._drop_incomplete(ev, "the camera's time went back")

    def _add_to_set(self, stamp: int, slot: str, msg) -> None:
        """Into the frame's set; a complete set goes to ``submit``, and the sets it leaves
        behind (older, never to complete) are dropped with their cause."""
        group = self.frame_sync.add(stamp, slot, msg)
        for ev in self.frame_sync.take_evicted():
            self._drop_incomplete(ev, "lost, or superseded by a newer one")
        if group is not None:
            self._submit((group["left"], group["right"], group["detections"]))
        elif self._on_pair is not None and slot != "detections" and self.pair_of(stamp):
            self._on_pair(stamp)

    def pair_of(self, stamp: int) -> tuple | None:
        """The (left, right) images of the set at ``stamp`` while it waits for its 2D array,
        else None."""
        group = self.frame_sync.waiting(stamp)
        if group is None or "left" not in group or "right" not in group:
            return None
        return group["left"], group["right"]

    def _drop_incomplete(self, ev, why: str) -> None:
        """A frame whose set cannot complete: counted as dropped, its cause logged."""
        if "detections" not in ev.values:
            return  # images of a frame the detector skipped (it counted it)
        self.frames.dropped()
        self.dropped_detection_arrays += 1
        cause = self._missing_cause(ev, why)
        self.usage.skipped(cause)
        self._warn(
            f"{topics.DETECTIONS_2D}: detection array at stamp {stamp_text(ev.stamp)} "
            f"dropped: {cause}; {self.dropped_detection_arrays} so far"
        )

    def _missing_cause(self, ev, why: str) -> str:
        """Why a frame's set is incomplete: a right image too far from its left one, or an
        image that never arrived (``why``)."""
        missing = ev.missing(FRAME_SLOTS)
        offset = self.pairing.nearest_right(ev.stamp) if "right" in missing else None
        tolerance = self.pairing.tolerance()
        if offset is not None and abs(offset) > tolerance:
            return (
                f"no right image within {tolerance / 1e6:.1f} ms of its left one (the nearest "
                f"is {offset / 1e6:+.1f} ms away; parameter stereo_sync_tolerance)"
            )
        return f"its {' and '.join(missing)} image never arrived ({why})"

    def drop_pending(self) -> None:
        """At the end of the run: the sets still waiting are dropped, each with its cause
        (every frame in is then out or dropped)."""
        for ev in self.frame_sync.take_pending():
            self._drop_incomplete(ev, "the run ended first")
