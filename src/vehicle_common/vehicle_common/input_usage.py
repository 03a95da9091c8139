"""How many of a node's input frames it could use, and why it could not use the others (issue
#42: a run must never end silently with no tracks). Pure, thread-safe (the executor and a
frame worker both report).

A processing node calls :meth:`InputUsage.used` for each frame it computed on and
:meth:`InputUsage.skipped` with the one-line cause for each frame it could not use (a
camera_info of another size, an unsupported encoding, a left image with no right one);
:meth:`InputUsage.note` records a cause that concerns no frame (a publisher whose QoS cannot
match). The node's report on /diagnostics carries the count and the latest cause
(:class:`vehicle_common.graph_readiness.NodeReport`), and the launcher says it on its console
(tracking_bringup.run_summary).
"""

from __future__ import annotations

import threading
from collections import Counter


class InputUsage:
    """Frames used, and the causes of the frames not used (latest first in :attr:`problem`)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._used = 0
        self._problem = ""
        self.causes: Counter[str] = Counter()  # cause -> frames skipped for it

    def used(self) -> None:
        with self._lock:
            self._used += 1

    def skipped(self, cause: str) -> None:
        with self._lock:
            self.causes[cause] += 1
            self._problem = cause

    def note(self, cause: str) -> None:
        """A cause that concerns no frame in particular (reported while nothing is used)."""
        with self._lock:
            self._problem = cause

    def snapshot(self) -> tuple[int, str]:
        """(frames used, the latest cause; "" when none)."""
        with self._lock:
            return self._used, self._problem
