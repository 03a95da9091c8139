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

    def pending_stamps(self) -> list[Hashable]:
        """Stamps waiting for more slots, oldest first."""
        return list(self._pending)
