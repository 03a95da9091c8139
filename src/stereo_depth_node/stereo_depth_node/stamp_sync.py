"""Exact-stamp synchroniser with a bounded cache (what message_filters' TimeSynchronizer does).

Pure core, no ROS: stamps are any hashable key (the node uses the stamp in nanoseconds). Messages
of several named slots are collected per stamp; once every slot of a stamp is filled the group is
returned and forgotten. At most ``cache_size`` incomplete stamps are kept: adding a new one beyond
that evicts the oldest (by first arrival), and the eviction is counted per slot it held so that a
caller can report, e.g., detection arrays whose stereo frame never arrived. With ``in_order``
(every slot's values arrive in stamp order, as on one ROS topic; stamps must then be ordered), a
complete stamp also evicts the pending stamps older than it at once: their missing values can no
longer come.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Evicted:
    """An incomplete group dropped from the cache: its stamp, the slots it had, and their values."""

    stamp: Hashable
    values: dict[str, Any]

    def missing(self, slots: Iterable[str]) -> list[str]:
        """Slots that never arrived for this stamp."""
        return [s for s in slots if s not in self.values]


@dataclass
class ExactStampSync:
    """Groups values of ``slots`` that carry the same stamp; bounded to ``cache_size`` stamps."""

    slots: tuple[str, ...]
    cache_size: int = 10
    in_order: bool = False  # a complete stamp evicts the older pending ones
    evicted: list[Evicted] = field(default_factory=list)  # recent evictions (drained by caller)
    dropped: dict[str, int] = field(default_factory=dict)  # evicted groups per slot they held
    _pending: OrderedDict = field(default_factory=OrderedDict)

    def __post_init__(self) -> None:
        if self.cache_size < 1:
            raise ValueError(f"cache_size: {self.cache_size} must be >= 1")
        if len(set(self.slots)) != len(self.slots) or not self.slots:
            raise ValueError(f"slots: {self.slots} must be distinct names")
        self.dropped = {s: 0 for s in self.slots}

    def add(self, stamp: Hashable, slot: str, value: Any) -> dict[str, Any] | None:
        """Store ``value`` for ``slot`` at ``stamp``; return the full group once complete.

        A second value for the same slot and stamp replaces the first."""
        if slot not in self.slots:
            raise KeyError(f"unknown slot {slot!r}")
        group = self._pending.get(stamp)
        if group is None:
            group = {}
            self._pending[stamp] = group
            while len(self._pending) > self.cache_size:
                self._evict(next(iter(self._pending)))
        group[slot] = value
        if all(s in group for s in self.slots):
            del self._pending[stamp]
            if self.in_order:
                for old in [t for t in self._pending if t < stamp]:
                    self._evict(old)
            return group
        return None

    def _evict(self, stamp: Hashable) -> None:
        old = self._pending.pop(stamp)
        self.evicted.append(Evicted(stamp, old))
        for s in old:
            self.dropped[s] += 1

    def take_evicted(self) -> list[Evicted]:
        """The groups evicted since the last call (and forget them)."""
        out, self.evicted = self.evicted, []
        return out

    def __len__(self) -> int:
        return len(self._pending)

    def waiting(self, stamp: Hashable) -> dict[str, Any] | None:
        """The values of the incomplete group at ``stamp`` so far (not to be changed), or
        None when no group waits at that stamp."""
        return self._pending.get(stamp)

    def pending_stamps(self) -> list[Hashable]:
        """Stamps waiting for more slots, oldest first."""
        return list(self._pending)

    def take_pending(self) -> list[Evicted]:
        """Every incomplete group still waiting (oldest first), forgotten and counted as
        dropped, as an eviction would (the run ends: they can no longer complete)."""
        out = []
        while self._pending:
            self._evict(next(iter(self._pending)))
            out.append(self.evicted.pop())
        return out


#: default tolerance of :class:`StereoPairing`, as a fraction of the camera's frame period: a
#: right image within a quarter period of a left one is the only one that can be its pair (the
#: next is three quarters away), with room for the jitter of two free-running drivers
PAIR_TOLERANCE_FRACTION = 0.25


@dataclass
class StereoPairing:
    """Pairs each left image stamp with the right image nearest to it within a tolerance, as
    message_filters' ApproximateTime does for two unsynchronised drivers (left and right a few
    ms apart). Equal stamps pair at once, whatever the tolerance.

    ``tolerance_ns``: < 0 derives it, ``fraction`` of the camera's frame period (the median
    interval of the last left stamps; until two left images arrived only equal stamps pair);
    0: equal stamps only. Below half a period a right image within it of a left one is the
    only candidate, so it pairs as soon as both are in. Both streams arrive in stamp order;
    a left stamp older than the previous one (a restarted camera) starts afresh. At most
    ``max_pending`` unpaired images per side are kept (the oldest go first)."""

    tolerance_ns: int = -1
    fraction: float = PAIR_TOLERANCE_FRACTION
    max_pending: int = 10
    _lefts: list = field(default_factory=list)  # unpaired left stamps, oldest first
    _rights: list = field(default_factory=list)  # unpaired (stamp, right message)
    _left_history: list = field(default_factory=list)  # recent left stamps (the period)
    _right_history: list = field(default_factory=list)  # recent right stamps (for causes)

    def period_ns(self) -> int | None:
        """The camera's frame period: the median interval of the recent left stamps."""
        steps = sorted(
            b - a for a, b in zip(self._left_history[:-1], self._left_history[1:], strict=True)
        )
        steps = [s for s in steps if s > 0]
        return steps[len(steps) // 2] if steps else None

    def tolerance(self) -> int:
        """The tolerance in force [ns] (0: equal stamps only)."""
        if self.tolerance_ns >= 0:
            return self.tolerance_ns
        period = self.period_ns()
        return int(period * self.fraction) if period else 0

    def add_left(self, stamp: int) -> list[tuple[int, Any]]:
        """A left image's stamp; returns the (left stamp, right message) pairs now formed."""
        if self._left_history and stamp < self._left_history[-1]:
            self.reset()  # time went back: the previous stream's images cannot pair
        self._left_history = (self._left_history + [stamp])[-10:]
        self._lefts.append(stamp)
        del self._lefts[: -self.max_pending]
        return self._match()

    def add_right(self, stamp: int, msg: Any) -> list[tuple[int, Any]]:
        """A right image; returns the (left stamp, right message) pairs now formed."""
        if self._right_history and stamp < self._right_history[-1]:
            self._rights.clear()
            self._right_history.clear()
        self._right_history = (self._right_history + [stamp])[-50:]
        self._rights.append((stamp, msg))
        del self._rights[: -self.max_pending]
        return self._match()

    def _match(self) -> list[tuple[int, Any]]:
        tol = self.tolerance()
        out = []
        for left in list(self._lefts):
            best = min(self._rights, key=lambda r: abs(r[0] - left), default=None)
            if best is None or abs(best[0] - left) > tol:
                continue
            self._lefts.remove(left)
            self._rights.remove(best)
            out.append((left, best[1]))
        return out

    def nearest_right(self, left: int) -> int | None:
        """The offset [ns] of the right stamp seen nearest to ``left`` (right minus left), or
        None when no right image arrived lately."""
        if not self._right_history:
            return None
        return min((r - left for r in self._right_history), key=abs)

    def reset(self) -> None:
        self._lefts.clear()
        self._rights.clear()
        self._left_history.clear()
        self._right_history.clear()
