"""node_runtime.spin_until_stopped steps over an entity destroyed while its event was pending
(a camera subscription re-created for its publishers' reliability: rclpy's executors skip a
destroyed timer or subscription, but an event handler's take_data raises InvalidHandle; before,
the node died with a traceback, seen once in a loaded CI run)."""

from __future__ import annotations

import pytest
from rclpy.exceptions import InvalidHandle

from vehicle_common import node_runtime


class _Context:
    def ok(self) -> bool:
        return True


class _Node:
    context = _Context()
    executor_kind = "single_threaded"


class _Executor:
    """spin_once raises InvalidHandle ``raises`` times, then asks the loop to stop."""

    def __init__(self, raises: int, stop: node_runtime.StopRequest) -> None:
        self.raises, self.stop, self.spins = raises, stop, 0

    def add_node(self, node) -> None:
        pass

    def remove_node(self, node) -> None:
        pass

    def shutdown(self, timeout_sec=None) -> None:
        pass

    def spin_once(self, timeout_sec=None) -> None:
        self.spins += 1
        if self.spins <= self.raises:
            raise InvalidHandle("cannot use Destroyable because destruction was requested")
        self.stop.requested = 2


def _spin(monkeypatch, raises: int) -> _Executor:
    stop = node_runtime.StopRequest()
    ex = _Executor(raises, stop)
    monkeypatch.setattr(node_runtime, "make_executor", lambda kind, context: ex)
    node_runtime.spin_until_stopped(_Node(), stop)
    return ex


def test_a_destroyed_entity_s_pending_event_is_stepped_over(monkeypatch):
    assert _spin(monkeypatch, 2).spins == 3  # two dropped, then spun on until the stop


def test_invalid_handles_over_and_over_are_raised(monkeypatch):
    with pytest.raises(InvalidHandle):
        _spin(monkeypatch, node_runtime.MAX_INVALID_HANDLES + 5)
