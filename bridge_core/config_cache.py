"""A device's configuration registers, cached and refreshed a request at a time.

Why: on a 9600-baud line with 35 ms replies a full configuration read costs several polls'
worth of wire time; reading it whole once, then one request per poll every ``refresh_s``,
keeps the state rate steady, and updating the cache on the bridge's own writes keeps
what the node reports equal to what it wrote. Used by the stepper and MOTEC devices.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

from .channel import Priority
from .codec import Value
from .planner import ReadRequest

ReadFunction = Callable[[ReadRequest, Priority], dict[str, Value]]


class ConfigCache:
    def __init__(
        self,
        plan: Sequence[ReadRequest],
        read: ReadFunction,
        refresh_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.plan = list(plan)
        self.refresh_s = refresh_s
        self.values: dict[str, Value] = {}
        self._read = read
        self._clock = clock
        self._names = {reg.name for request in self.plan for reg in request.registers}
        self._next = 0  # index into plan of the next refresh read
        self._due = math.inf

    @property
    def complete(self) -> bool:
        return self._names <= self.values.keys()

    def read_all(self, priority: Priority = Priority.POLL) -> None:
        values: dict[str, Value] = {}
        for request in self.plan:
            values.update(self._read(request, priority))
        self.values.update(values)
        self._next = 0
        self._due = self._clock() + self.refresh_s

    def refresh_step(self) -> None:
        """One refresh request, when a refresh is due or under way (call once per poll)."""
        if self._clock() >= self._due or self._next:
            self.values.update(self._read(self.plan[self._next], Priority.POLL))
            self._next = (self._next + 1) % len(self.plan)
            if self._next == 0:
                self._due = self._clock() + self.refresh_s

    def refresh_soon(self) -> None:
        """Start a refresh at the next poll (after a write that may or may not have landed)."""
        self._due = 0.0

    def clear(self) -> None:
        self.values.clear()

    def note_written(self, name: str, value: Value) -> None:
        if name in self.values:
            self.values[name] = value
