"""What the bridge's services set moving, so that a halt can stop it.

Streams (``stream_guard``) and action goals (``goals``) know their own motion. A service
that starts one (a stepper motor's ``~/motor_<n>/forward``, a MOTEC ``~/move``, the R6's
``~/start``, a ``modbus_bridge`` trigger marked ``starts_motion``) is fire-and-forget: the
ledger remembers it, per axis, with the stop that ends it, so that deactivate, exit,
``read_only`` and a fatal error stop it too ("every motion the bridge starts, the bridge
stops").

- ``started(axis, what, stop)``: a service's start was acknowledged by the device;
- ``stopped(axis)``: a stop of that axis was acknowledged (a stop service, a goal or a
  stream that took the axis over and stopped it): nothing left to stop there;
- ``stop_all()``: every remembered motion's stop is tried once (each, whatever the others
  do); an acknowledged one is forgotten, a failed one kept and marked pending (one
  that went out and was not confirmed, ``NotConfirmed``: kept, not pending);
- ``retry_pending()``: the pending stops again (the node calls it before the first poll
  after a reconnect, as it does for the streams' pending stops).

An entry is kept until a stop of its axis is acknowledged, also when the motion may have
ended by itself (a single run, a cycle): a stop of a motor that stands does nothing, and
the ledger cannot know what the device did meanwhile. Plain Python, no ROS; one lock.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from dataclasses import dataclass

from ..wire.errors import NotConfirmed


@dataclass(frozen=True, eq=False)
class Started:
    """One motion a service started: its words and the stop that ends it."""

    what: str
    stop: Callable[[], object]
    pending: bool = False  # a halt's stop of it failed: tried again on reconnect


@dataclass(frozen=True)
class StopResult:
    axis: Hashable
    what: str
    error: Exception | None  # None: the stop was acknowledged


class MotionLedger:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._started: dict[Hashable, Started] = {}

    def started(self, axis: Hashable, what: str, stop: Callable[[], object]) -> None:
        with self._lock:
            self._started[axis] = Started(what, stop)

    def pending(self) -> bool:
        """Whether a halt's stop of some motion failed and waits to be tried again."""
        with self._lock:
            return any(entry.pending for entry in self._started.values())

    def stopped(self, *axes: Hashable) -> None:
        with self._lock:
            for axis in axes:
                self._started.pop(axis, None)

    def moving(self) -> dict[Hashable, str]:
        """Axes a service set moving and no stop has ended since, with what started them."""
        with self._lock:
            return {axis: entry.what for axis, entry in self._started.items()}

    def stop_all(self) -> list[StopResult]:
        """Try every remembered motion's stop once; forget those acknowledged."""
        return self._stop(lambda entry: True)

    def retry_pending(self) -> list[StopResult]:
        """Try again the stops a halt could not get through."""
        return self._stop(lambda entry: entry.pending)

    def _stop(self, which: Callable[[Started], bool]) -> list[StopResult]:
        with self._lock:
            entries = [(axis, entry) for axis, entry in self._started.items() if which(entry)]
        results: list[StopResult] = []
        for axis, entry in entries:
            try:
                entry.stop()
            except Exception as err:  # every stop is tried, whatever one of them raises
                # A stop that went out but was not confirmed (NotConfirmed) is kept for
                # the next halt, not retried on a timer: the device answered it.
                pending = not isinstance(err, NotConfirmed)
                with self._lock:
                    if self._started.get(axis) is entry:
                        self._started[axis] = Started(entry.what, entry.stop, pending=pending)
                results.append(StopResult(axis, entry.what, err))
                continue
            with self._lock:
                if self._started.get(axis) is entry:  # not a newer start of the axis
                    del self._started[axis]
            results.append(StopResult(axis, entry.what, None))
        return results


__all__ = ["MotionLedger", "Started", "StopResult"]
