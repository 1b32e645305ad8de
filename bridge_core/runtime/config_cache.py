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
from typing import Any, Generic, TypeVar

from ..wire.channel import Priority, RegisterIO
from ..wire.codec import Value
from ..wire.errors import CommandRejected
from ..wire.planner import ReadRequest
from ..wire.registers import RegisterMap
from .rate_groups import GroupedRead, PollGroups
from .reads import read_blocks, read_named
from .stream_guard import StreamGuard

ConfigT = TypeVar("ConfigT")

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


class ConfiguredDevice(Generic[ConfigT]):
    """Base of a device model whose configuration is cached (stepper, MOTEC).

    Reads go through ``read_request`` (bit or register table); ``poll_status`` reads the
    status (``groups``: fast every poll, slow every ``slow_poll_period_s``) stamped by its
    position block, after reading the configuration whole when it is missing and before one
    refresh request when one is due. The configuration is a third group: refreshed a
    request per poll every ``refresh_s``, so no poll is long on a slow line, and updated
    by the bridge's own writes. A subclass builds its typed ``config`` from ``cached()``
    and lists its command streams in ``streams``.
    """

    def __init__(
        self,
        io: RegisterIO,
        register_map: RegisterMap,
        config_plan: Sequence[ReadRequest],
        refresh_s: float,
        clock: Callable[[], float] = time.monotonic,
        *,
        groups: PollGroups,
    ) -> None:
        self.io = io
        self.register_map = register_map
        self.groups = groups.follow(io)
        self.streams: list[StreamGuard[Any]] = []
        self._cache = ConfigCache(config_plan, self.read_request, refresh_s, clock)

    @property
    def config(self) -> ConfigT:
        """The cached configuration, typed; refused (CommandRejected) until it was read."""
        raise NotImplementedError

    def read_config(self, priority: Priority = Priority.POLL) -> ConfigT:
        """Read the whole configuration now (on link up, and whenever asked)."""
        self.read_whole_config(priority)
        return self.config

    def read_named(self, *names: str) -> dict[str, Value]:
        return read_named(self.io, self.register_map, names)

    def invalidate_config(self) -> None:
        """The device may have changed (link came up, a refused read): read it whole next.

        A stream that was running stays "active", so that the node's deadman stops it once
        the link is back; only the values it last sent are forgotten (the device may hold
        others now).
        """
        self.forget_config()
        for stream in self.streams:
            stream.forget_values()

    def read_request(self, request: ReadRequest, priority: Priority) -> dict[str, Value]:
        return read_blocks(self.io, (request,), priority)[0]

    def read_whole_config(self, priority: Priority = Priority.POLL) -> None:
        self._cache.read_all(priority)

    @property
    def has_config(self) -> bool:
        return self._cache.complete

    def cached(self, what: str) -> dict[str, Value]:
        """The cached configuration values; refused until they were read."""
        if not self.has_config:
            raise CommandRejected(f"the {what}'s configuration has not been read yet")
        return self._cache.values

    def forget_config(self) -> None:
        """The device may have changed (reconnect): the next poll reads it whole first."""
        self._cache.clear()

    def poll_status(self, stamp_register: str) -> GroupedRead:
        if not self.has_config:
            self.read_whole_config()
        read = self.groups.read(self.io, stamp_register)
        self._cache.refresh_step()  # one configuration request while a refresh is due
        return read
