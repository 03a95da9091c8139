"""Playback logic of the KITTI player, free of ROS: frame schedule and dataset stamps, image noise
at a given SNR, frame drops, rate pacing and lockstep bookkeeping.

The node (``node.py``) polls a :class:`PlaybackScheduler` from a timer and publishes whatever
frame it hands out; the scheduler only sees monotonic times passed in, so it is testable offline.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from vehicle_common.image_conversion import numpy_to_compressed, numpy_to_image

from vehicle_common import graph_readiness

#: KITTI tracking sequences are recorded at 10 Hz.
KITTI_FRAME_PERIOD_S = 0.1


def stamp_ns(start_time: float, frame: int, loop_pass: int = 0, frames_per_pass: int = 0) -> int:
    """Dataset time of a frame in nanoseconds: ``start_time + (frame + pass * n) * 0.1 s``.

    Later loop passes continue the time line (``frames_per_pass`` frames per pass), so stamps
    never go backwards when the sequence repeats.
    """
    ticks = frame + loop_pass * frames_per_pass
    return int(round(start_time * 1e9)) + ticks * int(round(KITTI_FRAME_PERIOD_S * 1e9))


def select_frames(frame_ids: list[int], first_frame: int = 0, last_frame: int = -1) -> list[int]:
    """Frame ids in ``[first_frame, last_frame]`` (``last_frame < 0``: to the end).

    Raises ValueError when the range holds no frame of the sequence.
    """
    last = math.inf if last_frame < 0 else last_frame
    chosen = [f for f in frame_ids if first_frame <= f <= last]
    if not chosen:
        raise ValueError(
            f"no frame in [{first_frame}, {last_frame}] (sequence has frames "
            f"{frame_ids[0]}..{frame_ids[-1]})"
            if frame_ids
            else "sequence has no frames"
        )
    return chosen


# ----------------------------------------------------------------------------- noise, drops


def snr_enabled(snr_db: float) -> bool:
    """Noise is applied for a finite, positive SNR; ``<= 0`` or ``inf`` disables it."""
    return math.isfinite(snr_db) and snr_db > 0.0


def noise_std(signal_std: float, snr_db: float) -> float:
    """Standard deviation of additive noise giving ``snr_db``: ``signal_std * 10^(-snr/20)``."""
    return float(signal_std) * 10.0 ** (-float(snr_db) / 20.0)


def add_snr_noise(image: np.ndarray, snr_db: float, rng: np.random.Generator) -> np.ndarray:
    """``image`` (uint8) plus Gaussian pixel noise at ``snr_db`` relative to the image's own
    standard deviation, rounded and clipped to uint8. Returns the input when SNR is disabled."""
    if not snr_enabled(snr_db):
        return image
    img = np.asarray(image)
    sigma = noise_std(float(img.std()), snr_db)
    noisy = img.astype(np.float32) + np.float32(sigma) * rng.standard_normal(
        img.shape, dtype=np.float32
    )
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def frame_noise_rng(seed: int, frame: int, loop_pass: int = 0) -> np.random.Generator:
    """Noise generator of one frame: reproducible per (seed, frame, pass), whatever was dropped."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, int(frame), int(loop_pass)])


def drop_rng(seed: int) -> np.random.Generator:
    """Generator of the drop decisions (one uniform draw per scheduled frame)."""
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, 0xD209])


# ----------------------------------------------------------------------------- scheduling


@dataclass(frozen=True)
class FrameEvent:
    """One scheduled frame: its id, loop pass, dataset stamp and whether it is dropped."""

    frame: int
    loop_pass: int
    stamp_ns: int
    dropped: bool


@dataclass
class PlaybackStats:
    """Counts reported in the player's summary."""

    published: int = 0
    dropped: int = 0
    lockstep_timeouts: int = 0


class LockstepAnswers:
    """One answer (the tracks) per published frame, from the graph's one tracker: a second
    answer for a stamp, or an answer for a stamp this player never published, means that
    another graph publishes on the lockstep topic (two graphs on one ROS domain without their
    own namespaces, whose frames and results then mix). The last ``keep`` published stamps are
    remembered; an answer older than those is not judged."""

    def __init__(self, keep: int = 1000) -> None:
        self._published: deque[int] = deque()
        self._known: set[int] = set()
        self._answered: set[int] = set()
        self._keep = keep

    def published(self, stamp_ns: int) -> None:
        self._published.append(stamp_ns)
        self._known.add(stamp_ns)
        while len(self._published) > self._keep:
            old = self._published.popleft()
            self._known.discard(old)
            self._answered.discard(old)

    def answer(self, stamp_ns: int) -> str | None:
        """None for the first answer to a published frame, else what is wrong with it."""
        if stamp_ns in self._answered:
            return f"a second answer for the frame stamped {stamp_ns * 1e-9:.3f} s"
        if stamp_ns not in self._known:
            if self._published and stamp_ns < self._published[0]:
                return None  # older than what is remembered
            return f"an answer for a frame this player did not publish ({stamp_ns * 1e-9:.3f} s)"
        self._answered.add(stamp_ns)
        return None


class PlaybackScheduler:
    """Decides when which frame is due.

    - Pacing: one frame every ``period_s`` seconds of wall time (``period_s <= 0``: no pacing).
    - Lockstep (``lockstep_timeout`` not None): at most ``lockstep_window`` published frames are
      unacknowledged at a time; the next one is held back until :meth:`acknowledge` is called
      with a stamp ``>=`` the oldest one's stamp, or until its timeout passes (counted in
      ``stats.lockstep_timeouts``). A window of 1 is strict lockstep (one frame in the graph at a
      time); a larger window keeps several frames in flight through the pipeline's stages.
      Dropped frames are not waited for.
    - Drops: each frame is dropped with ``drop_probability`` (seeded draws).

    Call :meth:`poll` with the current monotonic time; it returns the next due frame or None.
    """

    def __init__(
        self,
        frames: list[int],
        start_time: float,
        period_s: float,
        loop: bool = False,
        lockstep_timeout: float | None = None,
        drop_probability: float = 0.0,
        seed: int = 0,
        lockstep_window: int = 1,
    ):
        if not frames:
            raise ValueError("no frames to play")
        if lockstep_window < 1:
            raise ValueError(f"lockstep_window {lockstep_window} must be >= 1")
        if not 0.0 <= drop_probability <= 1.0:
            raise ValueError(f"drop_probability {drop_probability} not in [0, 1]")
        self.frames = list(frames)
        self.start_time = float(start_time)
        self.period_s = float(period_s)
        self.loop = bool(loop)
        self.lockstep_timeout = lockstep_timeout
        self.lockstep_window = int(lockstep_window)
        self.drop_probability = float(drop_probability)
        self.frames_per_pass = self.frames[-1] - self.frames[0] + 1
        self.stats = PlaybackStats()
        self._drops = drop_rng(seed)
        self._index = 0
        self._pass = 0
        self._next_due: float | None = None
        self._awaiting: deque[tuple[int, float]] = deque()  # (stamp, published at), oldest first

    @property
    def exhausted(self) -> bool:
        """All frames were handed out (never true when looping)."""
        return self._pass > 0 and not self.loop

    @property
    def finished(self) -> bool:
        """All frames handed out and no acknowledgement pending."""
        return self.exhausted and not self._awaiting

    @property
    def next_frame(self) -> int | None:
        """The frame :meth:`poll` hands out next (None when all were handed out)."""
        return None if self.exhausted else self.frames[self._index]

    @property
    def in_flight(self) -> int:
        """Published frames not yet acknowledged (lockstep)."""
        return len(self._awaiting)

    def acknowledge(self, stamp_ns: int) -> bool:
        """A lockstep answer with ``stamp_ns`` arrived (it acknowledges every frame up to its
        stamp); True when it released at least one frame."""
        released = False
        while self._awaiting and stamp_ns >= self._awaiting[0][0]:
            self._awaiting.popleft()
            released = True
        return released

    def check_timeout(self, now: float) -> bool:
        """Give up waiting for the frames whose lockstep timeout passed; True when one did."""
        if self.lockstep_timeout is None:
            return False
        timed_out = False
        while self._awaiting and now - self._awaiting[0][1] >= self.lockstep_timeout:
            self._awaiting.popleft()
            self.stats.lockstep_timeouts += 1
            timed_out = True
        return timed_out

    def poll(self, now: float) -> FrameEvent | None:
        """The frame due at ``now`` (monotonic seconds), or None when nothing is due yet."""
        if self.exhausted:
            self.check_timeout(now)
            return None
        if len(self._awaiting) >= self.lockstep_window:
            self.check_timeout(now)
            if len(self._awaiting) >= self.lockstep_window:
                return None
        if self._next_due is None:
            self._next_due = now
        if now < self._next_due:
            return None
        frame = self.frames[self._index]
        event = FrameEvent(
            frame=frame,
            loop_pass=self._pass,
            stamp_ns=stamp_ns(self.start_time, frame, self._pass, self.frames_per_pass),
            dropped=bool(self._drops.random() < self.drop_probability),
        )
        if self.period_s > 0:
            # keep the cadence, but never burst to catch up after a long wait
            due = self._next_due + self.period_s
            self._next_due = due if due >= now else now + self.period_s
        self._index += 1
        if self._index == len(self.frames):
            self._index = 0
            self._pass += 1
        if event.dropped:
            self.stats.dropped += 1
        else:
            self.stats.published += 1
            if self.lockstep_timeout is not None:
                self._awaiting.append((event.stamp_ns, now))
        return event


class FramePrefetcher:
    """Reads the next frame in a background thread while the graph works on the current one, so
    that reading (PNG decoding, ~20 ms per KITTI pair) is off the critical path.

    ``get(frame)`` returns ``read(frame)``, from the prefetch when it was for that frame;
    ``prefetch(frame)`` starts reading one (None: nothing). Errors surface in ``get``.

    ``preload(frames, budget_bytes)`` reads whole sequences into memory before playback, as a
    camera hands over decoded frames: the decoding then takes no CPU from the graph while it
    runs. In the background thread; ``preloaded`` says when it is over. It reads the first
    frame, estimates the sequence's size from it and stops (prefetching as before) when the
    frames would take more than ``budget_bytes``; a frame that cannot be read ends the preload
    and its error surfaces in ``get`` of that frame, as without preloading."""

    def __init__(self, read: Callable[[int], object]):
        self._read = read
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="prefetch")
        self._pending: tuple[int, Future] | None = None
        self._cache: dict[int, object] = {}
        self._preload: Future | None = None
        self._closing = threading.Event()  # a preload stops at the next frame

    def preload(self, frames: list[int], budget_bytes: int) -> None:
        self._preload = self._pool.submit(self._read_all, list(dict.fromkeys(frames)), budget_bytes)

    def _read_all(self, frames: list[int], budget_bytes: int) -> tuple[int, int]:
        """Reads ``frames`` into the cache; returns (frames held, bytes held)."""
        held = 0
        for i, frame in enumerate(frames):
            if self._closing.is_set():
                break
            try:
                data = self._read(frame)
            except Exception:  # noqa: BLE001 - read again (and raised) by get()
                break
            size = _nbytes(data)
            if i == 0 and size * len(frames) > budget_bytes:
                return 0, 0
            self._cache[frame] = data
            held += size
        return len(self._cache), held

    @property
    def preloaded(self) -> bool:
        """True when no preload is running (over, stopped or never started)."""
        return self._preload is None or self._preload.done()

    def preload_result(self) -> tuple[int, int]:
        """(frames, bytes) held in memory once the preload is over ((0, 0) without one)."""
        return self._preload.result() if self._preload is not None else (0, 0)

    def prefetch(self, frame: int | None) -> None:
        if frame is None or frame in self._cache or (self._pending and self._pending[0] == frame):
            return
        self._pending = (frame, self._pool.submit(self._read, frame))

    def get(self, frame: int):
        if self._preload is not None and not self._preload.done():
            self._preload.result()
        if frame in self._cache:
            return self._cache[frame]
        pending, self._pending = self._pending, None
        if pending is not None and pending[0] == frame:
            return pending[1].result()
        return self._read(frame)

    def close(self) -> None:
        self._closing.set()
        self._pool.shutdown(wait=True, cancel_futures=True)


def _nbytes(data) -> int:
    """Bytes of an array or of a tuple of arrays (a stereo pair)."""
    if isinstance(data, (tuple, list)):
        return sum(_nbytes(d) for d in data)
    return int(getattr(data, "nbytes", 0))


#: s between the player's ticks in unpaced lockstep (start of playback, lockstep timeouts)
LOCKSTEP_TICK_S = 0.02


def plan_playback(
    p: dict, frame_ids: list[int]
) -> tuple[list[int], PlaybackScheduler, float, float]:
    """The player's parameters ``p`` (as a dict) over a sequence's ``frame_ids``: (frames,
    scheduler, period [s], 0 unpaced; tick [s]). ValueError naming the parameters at fault."""
    try:
        frames = select_frames(frame_ids, p["first_frame"], p["last_frame"])
    except ValueError as exc:
        raise ValueError(f"first_frame/last_frame: {exc}") from None
    hz = float(p["rate"]) * float(p["rate_multiplier"])
    period = 1.0 / hz if hz > 0 and math.isfinite(hz) else 0.0
    try:
        scheduler = PlaybackScheduler(
            frames,
            start_time=float(p["start_time"]),
            period_s=period,
            loop=bool(p["loop"]),
            lockstep_timeout=float(p["lockstep_timeout"]) if p["lockstep"] else None,
            drop_probability=float(p["drop_probability"]),
            seed=int(p["seed"]),
            lockstep_window=int(p["lockstep_window"]),
        )
    except ValueError as exc:
        raise ValueError(f"drop_probability/lockstep_window: {exc}") from None
    # the tick's period: the pacing's resolution when paced; unpaced in lockstep, each
    # acknowledgement starts the next frames at once (_on_lockstep) and the tick only
    # starts playback and notices timeouts (a 2 ms tick cost ~8 % of a core for nothing);
    # unpaced without lockstep it sets the rate
    if period > 0:
        tick = min(0.01, period / 2)
    else:
        tick = LOCKSTEP_TICK_S if p["lockstep"] else 0.002
    return frames, scheduler, period, tick


class StartGate:
    """When playback starts: the left image's subscribers and every expected edge matched, then
    ``settle_s`` more with all matched; a waiting line at most every 2 s meanwhile."""

    def __init__(self, settle_s: float) -> None:
        self.settle_s = settle_s
        self._last_wait_log = 0.0
        self._matched_at: float | None = None

    def check(
        self, now: float, have: int, want: int, unmatched: list[str]
    ) -> tuple[bool, str | None]:
        """(whether to start now, a waiting line to log or None)."""
        # every edge of the graph must be matched, so that no node misses the first frame
        if have < want or unmatched:
            line = None
            if now - self._last_wait_log > 2.0:
                self._last_wait_log = now
                line = f"waiting for subscribers: left image {have}/{want}" + (
                    f", not yet matched on {', '.join(unmatched)}" if unmatched else ""
                )
            self._matched_at = None
            return False, line
        self._matched_at = self._matched_at or now
        return now - self._matched_at >= self.settle_s, None


def noisy_pair(left, right, snr_db: float, seed: int, event: FrameEvent):
    """The frame's images with the ``snr_db`` noise of its frame and pass (unchanged when
    off)."""
    if snr_enabled(snr_db):
        rng = frame_noise_rng(seed, event.frame, event.loop_pass)
        left, right = add_snr_noise(left, snr_db, rng), add_snr_noise(right, snr_db, rng)
    return left, right


def summary_line(stats: PlaybackStats) -> str:
    """The player's last line (a warning when a lockstep answer timed out)."""
    return (
        f"done: {stats.published} frames published, {stats.dropped} dropped, "
        f"{stats.lockstep_timeouts} lockstep timeouts"
    )


class PreloadWatch:
    """The reading of the frames before playback: all of them into memory within
    ``preload_mib`` (none: each read ahead), its end reported once (:meth:`done`)."""

    def __init__(
        self, reader: FramePrefetcher, preload_mib: int, frames: list[int], scheduler
    ) -> None:
        self.reader = reader
        self.preload_mib = preload_mib
        self._t0 = time.monotonic()
        self._logged = preload_mib <= 0
        if preload_mib > 0:
            reader.preload(frames, int(preload_mib) * 2**20)
        else:
            reader.prefetch(scheduler.next_frame)

    def done(self, scheduler) -> tuple[bool, str | None]:
        """(False while the frames are being read into memory, the line reporting the preload
        the first time it is over, else None); without it the next frame is read ahead."""
        if not self.reader.preloaded:
            return False, None
        if self._logged:
            return True, None
        self._logged = True
        n, size = self.reader.preload_result()
        if n:
            return True, (
                f"{n} frames in memory ({size / 2**20:.0f} MiB, read in "
                f"{time.monotonic() - self._t0:.1f} s)"
            )
        self.reader.prefetch(scheduler.next_frame)
        return True, (
            f"frames not preloaded (more than preload_mib {self.preload_mib} "
            "MiB, or the first frame unreadable): each is read ahead while the graph works"
        )


def expected_topics(
    wait_for_topics: str, external_subscribers: str, resolve: Callable[[str], str]
) -> dict[str, int]:
    """The subscriptions each topic must have matched before playback (parameters
    ``wait_for_topics`` plus ``external_subscribers``, ``"/a:2,/b:1"``; names resolved with
    ``resolve``). ValueError naming the parameter for a malformed entry."""

    def counts(spec: str, name: str) -> dict[str, int]:
        try:
            return graph_readiness.parse_topic_counts(spec)
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None

    expected = {resolve(t): n for t, n in counts(wait_for_topics, "wait_for_topics").items()}
    for topic, n in counts(external_subscribers, "external_subscribers").items():
        name = resolve(topic)
        expected[name] = expected.get(name, 0) + n
    return expected


def mixed_runs_line(node: str, topic: str, problem: str, publishers: int) -> str:
    """The fatal line for a lockstep answer no frame of this run asked for (``problem``)."""
    return (
        f"{node}: {topic}: {problem}: another graph publishes on this ROS domain "
        f"({publishers} publishers on {topic}), and the runs mix; "
        "give each graph its own namespace (--namespace) or ROS_DOMAIN_ID"
    )


def progress_line(stats: PlaybackStats, frame: int) -> str | None:
    """Every 10th frame published or dropped: the progress line (else None)."""
    if (stats.published + stats.dropped) % 10 == 0:
        return f"frame {frame}: {stats.published} published, {stats.dropped} dropped"
    return None


def playing_line(sequence, frames: list[int], period: float, p: dict) -> str:
    """The player's first line: the sequence, its frames, the pacing and the lockstep."""
    return (
        f"sequence {sequence.sequence}: {len(frames)} frames "
        f"({frames[0]}..{frames[-1]}) from {sequence.root}, "
        f"{'unpaced' if period == 0 else f'{1 / period:.2f} Hz'}"
        f"{', lockstep on ' + p['lockstep_topic'] if p['lockstep'] else ''}"
    )


def image_message(rgb, hdr, transport: str, jpeg_quality: int):
    """The image as the ``image_transport`` parameter says: raw rgb8, PNG or JPEG."""
    if transport == "raw":
        return numpy_to_image(rgb, "rgb8", hdr)
    return numpy_to_compressed(rgb, transport, jpeg_quality, hdr)
