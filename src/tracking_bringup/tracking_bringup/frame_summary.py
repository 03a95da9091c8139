"""A run's frames at a camera rate: tracked, dropped and where, and the latency (issue #39).

``stereo_tracking_demo --camera-hz 30`` and ``stereo_tracking_launch --camera-hz 30`` play the
KITTI sequence as a camera publishing at that rate, without lockstep (the player's ``rate``; the
sequence's stamps stay dataset time), so a user sees what their camera does to the graph. At the
end one line says how many frames were tracked, how many were dropped by which node (their
/diagnostics counts) and the latency image -> tracks: the player's ``/clock`` message of a frame
(published just before its images) to the tracks of that stamp, both seen by
:class:`LatencyProbe` in the launching process (the method of bench/bench_graph.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from tracking_bringup import graph


def camera_overrides(camera_hz: float) -> list[str]:
    """The player as a camera at ``camera_hz`` (> 0): paced, not waiting for the graph."""
    if not camera_hz > 0:
        raise ValueError(f"--camera-hz: {camera_hz:g} must be > 0")
    return [
        f"{graph.PLAYER.name}.rate:={camera_hz:g}",
        f"{graph.PLAYER.name}.rate_multiplier:=1.0",
        f"{graph.PLAYER.name}.lockstep:=false",
    ]


class FrameLatency:
    """Arrival times of each frame's clock and tracks (monotonic seconds), by stamp."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.clock: dict[int, float] = {}
        self.tracks: dict[int, float] = {}

    def on_clock(self, stamp: int, t: float) -> None:
        with self._lock:
            self.clock.setdefault(stamp, t)

    def on_tracks(self, stamp: int, t: float) -> None:
        with self._lock:
            self.tracks.setdefault(stamp, t)

    def latencies_ms(self) -> np.ndarray:
        """Image -> tracks [ms] of every tracked frame whose clock was seen."""
        with self._lock:
            return np.array(
                [1e3 * (t - self.clock[s]) for s, t in self.tracks.items() if s in self.clock]
            )


def summary_line(
    published: int,
    tracked: int,
    dropped: dict[str, int],
    latencies_ms,
    camera_hz: float | None = None,
) -> str:
    """``camera 30 Hz: 54 of 108 frames tracked, 54 dropped (vehicle_detector 52, stereo_depth
    2), latency image -> tracks mean 95 ms, p50 90, p95 120``."""
    where = ", ".join(f"{n} {d}" for n, d in dropped.items() if d)
    total = sum(dropped.values())
    lat = np.asarray(latencies_ms, dtype=float)
    latency = (
        f"latency image -> tracks mean {lat.mean():.0f} ms, p50 {np.percentile(lat, 50):.0f}, "
        f"p95 {np.percentile(lat, 95):.0f}"
        if lat.size
        else "no latency measured"
    )
    head = f"camera {camera_hz:g} Hz" if camera_hz else "lockstep"
    return (
        f"{head}: {tracked} of {published} frames tracked, {total} dropped"
        + (f" ({where})" if where else "")
        + f", {latency}"
    )


def dropped_by_node(reports: dict) -> dict[str, int]:
    """Frames each node dropped (player: by ``drop_probability``), from its last report
    (``GraphLauncher.reports``), in data-flow order."""
    order = [n.name for n in graph.PIPELINE]
    names = sorted(reports, key=lambda n: order.index(n) if n in order else len(order))
    return {n: reports[n].counts.dropped for n in names}


class LatencyProbe:
    """Subscribes to ``/clock`` and the tracks (relative to ``namespace``) in its own context
    and thread, filling a :class:`FrameLatency`; ``on_tracks(msg)`` is called for each tracks
    message (a progress display). Its two subscriptions are edges the player waits for
    (``extra_subscriptions``: :data:`EDGES`)."""

    EDGES = {graph.CLOCK: 1, graph.TRACKS: 1}

    def __init__(self, namespace: str = "", on_tracks: Callable | None = None) -> None:
        import rclpy
        from rclpy.context import Context
        from rosgraph_msgs.msg import Clock
        from stereo_vehicle_msgs.msg import TrackedVehicleArray

        self.frames = FrameLatency()
        self._user = on_tracks
        self._ctx = Context()
        rclpy.init(context=self._ctx, args=[])
        self._node = rclpy.create_node(
            "frame_latency_probe", namespace=namespace or "/", context=self._ctx
        )
        self._node.create_subscription(Clock, graph.CLOCK, self._on_clock, 100)
        self._node.create_subscription(TrackedVehicleArray, graph.TRACKS, self._on_tracks, 100)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on_clock(self, msg) -> None:
        self.frames.on_clock(msg.clock.sec * 10**9 + msg.clock.nanosec, time.monotonic())

    def _on_tracks(self, msg) -> None:
        s = msg.header.stamp
        self.frames.on_tracks(s.sec * 10**9 + s.nanosec, time.monotonic())
        if self._user is not None:
            self._user(msg)

    def _spin(self) -> None:
        from rclpy.executors import SingleThreadedExecutor

        executor = SingleThreadedExecutor(context=self._ctx)
        executor.add_node(self._node)
        while not self._stop.is_set() and self._ctx.ok():
            executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._node.destroy_node()
        self._ctx.try_shutdown()
