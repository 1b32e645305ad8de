"""Rate groups: read what moves every poll, the rest every ``slow_poll_period_s``.

Why: a bridge that reads its whole map on every poll caps its joint rate at the wire time
of the whole map. On a 9600-baud line with 35 ms replies each request costs ~50 ms
whatever it holds, so the registers that do not move by themselves (configuration, the
outputs the bridge itself switches, identity) are read as a group of their own, whole,
once per period (docs/architecture.md, "The read path"):

- ``FAST``: every poll: what ``joint_states`` and motion safety need;
- ``SLOW``: read whole at the first poll, then at the first poll once the period has
  elapsed, and at the next poll after a write that touches it (``touched_by``) or a
  reconnect (the device may have changed meanwhile);
- ``NEVER``: not polled (read on request only).

A slow value is never older than one period plus one poll while the link is up; after a
loss no value of the slow group is reused, so what is published after a reconnect was read
on the new connection. ``GroupedRead.slow_read_time`` is the wall-clock time the reply to
the slow group's first request arrived (the ``slow_stamp`` of the state messages): the
time of its oldest value.

``plan_groups`` plans the two groups of a register map: a slow register that a fast read
runs through anyway (the planner merges across small gaps) is read with it, every poll.
"""

from __future__ import annotations

import enum
import math
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

from ..wire.channel import DeviceChannel, Priority, RegisterIO
from ..wire.codec import Value
from ..wire.errors import PollIncomplete
from ..wire.link_state import LinkState
from ..wire.planner import ReadRequest, plan_reads
from ..wire.registers import Register, RegisterMap
from ..wire.requests import Span
from .reads import PlanRead, read_plan

SLOW_POLL_PERIOD_DEFAULT_S = 1.0
SLOW_POLL_PERIOD_RANGE_S = (0.1, 3600.0)


def plan_groups(
    register_map: RegisterMap, fast: Sequence[str], slow: Sequence[str]
) -> tuple[list[ReadRequest], list[ReadRequest]]:
    """The fast plan and the slow plan of ``register_map``'s registers ``fast`` and ``slow``.

    A slow register lying inside a fast request's span costs nothing to read there, while
    a request of its own would cost a round trip: it moves to the fast group.
    """
    fast_plan = plan_reads(register_map, register_map.select(list(fast)))
    spans = [Span(r.table, r.address, r.count) for r in fast_plan]
    inside = [name for name in slow if any(_within(register_map[name], span) for span in spans)]
    if inside:
        fast_plan = plan_reads(register_map, register_map.select([*fast, *inside]))
    rest = [name for name in slow if name not in inside]
    return fast_plan, plan_reads(register_map, register_map.select(rest))


def _within(register: Register, span: Span) -> bool:
    return (
        register.table is span.table
        and span.address <= register.address
        and register.end <= span.address + span.count
    )


class RateGroup(enum.Enum):
    FAST = "fast"
    SLOW = "slow"
    NEVER = "never"


@dataclass(frozen=True)
class GroupedRead:
    """One poll's values: the fast group's, just read, and the slow group's newest."""

    values: dict[str, Value]
    read_time: float  # when the stamp register's block was read (fast group)
    first_read_time: float  # when the fast group's first request was answered
    slow_read_time: float  # when the slow group was last read (0.0: it is empty)
    slow_refreshed: bool  # the slow group was read in this poll
    reads: PlanRead | None = None  # each reply's time (``time_of`` a register's block)

    def time_of(self, register_name: str) -> float:
        """When the reply holding ``register_name`` arrived in this poll."""
        stamp = self.reads.time_of(register_name) if self.reads is not None else None
        if stamp is None:
            raise ValueError(f"no block of this poll holds {register_name!r}")
        return stamp

    def last_time(self, requests: Sequence[ReadRequest]) -> float:
        """When the last reply to any of ``requests`` (blocks of the plan) arrived."""
        return self.reads.last_time(requests) if self.reads is not None else 0.0


class PollGroups:
    """A device's poll split into a fast plan (every poll) and a slow plan (every period).

    ``touched_by``: spans whose writes change a slow register although they do not overlap
    its block (e.g. a coil that switches an output whose state is a holding register); the
    slow blocks' own spans count anyway. ``watch`` (``follow``) ties it to a channel: every
    write the channel puts on the wire goes to ``note_write``, every edge of its link to
    ``forget``; the device that reads through the channel does it when it is made.
    """

    def __init__(
        self,
        fast: Sequence[ReadRequest],
        slow: Sequence[ReadRequest] = (),
        *,
        period_s: float = SLOW_POLL_PERIOD_DEFAULT_S,
        touched_by: Iterable[Span] = (),
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        self._touched_by = list(touched_by)
        self.fast: list[ReadRequest] = []
        self.slow: list[ReadRequest] = []
        self._touching: list[Span] = []
        self._clock = clock
        self._wall_clock = wall_clock
        self._lock = threading.Lock()
        self._values: dict[str, Value] = {}
        self._read_time = 0.0
        self._due = -math.inf  # read at the first poll
        self._writes = 0  # writes that touched the slow group (a read under way is old)
        self._edges = 0  # link edges (a read under way belongs to a closed connection)
        self._period_s = SLOW_POLL_PERIOD_DEFAULT_S
        self.period_s = period_s
        self.slow_reads = 0  # times the slow group was read (diagnostics, tests)
        self.set_plans(fast, slow)

    def set_plans(self, fast: Sequence[ReadRequest], slow: Sequence[ReadRequest]) -> None:
        """New plans (a device re-planned its poll): the slow group is read whole next."""
        with self._lock:
            self.fast = list(fast)
            self.slow = list(slow)
            self._touching = [Span(r.table, r.address, r.count) for r in self.slow]
            self._touching += self._touched_by
            # The slow stamp is the reply time of the group's first block: its oldest value.
            self._slow_stamp = min(self.slow[0].names) if self.slow else None
        self.forget()

    @property
    def period_s(self) -> float:
        return self._period_s

    @period_s.setter
    def period_s(self, value: float) -> None:
        """Live: the next refresh is one new period after the last one."""
        low, high = SLOW_POLL_PERIOD_RANGE_S
        if not low <= value <= high:  # also refuses NaN
            raise ValueError(f"slow poll period {value} s outside {low}..{high} s")
        with self._lock:
            if math.isfinite(self._due):
                self._due += value - self._period_s
            self._period_s = float(value)

    def follow(self, io: RegisterIO) -> PollGroups:
        """``watch`` ``io`` if it is a channel (a device reads through it); a test's
        stand-in is not followed. Returns self (``PollGroups(...).follow(io)``)."""
        if isinstance(io, DeviceChannel):
            self.watch(io)
        return self

    def watch(self, channel: WatchedChannel) -> Callable[[], None]:
        """Follow ``channel``'s writes and link edges; returns the function that stops it."""
        unwatch_writes = channel.add_write_listener(self.note_write)
        unwatch_link = channel.link_state.add_listener(lambda _event, _text: self.forget())

        def unwatch() -> None:
            unwatch_writes()
            unwatch_link()

        return unwatch

    def note_write(self, span: Span) -> None:
        """A write (landed or not) to ``span``: re-read the slow group at the next poll if
        it may have changed one of its registers."""
        if any(span.overlaps(touching) for touching in self._touching):
            self.refresh_soon()

    def refresh_soon(self) -> None:
        with self._lock:
            self._due = -math.inf
            self._writes += 1

    def forget(self) -> None:
        """The link went down or came up: no slow value is reused; it is read whole next."""
        with self._lock:
            self._values = {}
            self._read_time = 0.0
            self._due = -math.inf
            self._edges += 1

    @property
    def slow_read_time(self) -> float:
        """Wall-clock time the slow group was last read on this connection (0.0: not yet)."""
        with self._lock:
            return self._read_time

    @property
    def slow_due(self) -> bool:
        with self._lock:
            return bool(self.slow) and self._clock() >= self._due

    def read(
        self,
        io: RegisterIO,
        stamp_register: str | None = None,
        priority: Priority = Priority.POLL,
    ) -> GroupedRead:
        """The slow group when due (first, so the fast stamp is the newest), then the fast
        group; a failure of either raises as ``read_blocks`` does (the link is marked the
        same way, and nothing of this poll is published)."""
        refreshed = False
        slow_due = self.slow_due
        with self._lock:
            writes, edges = self._writes, self._edges
            slow, fast = (list(self.slow) if slow_due else []), list(self.fast)
        # One batch (pipelined where the channel does: ``reads.read_plan``), each reply
        # timed: the slow group first, so the fast stamp is the newest.
        read = read_plan(io, [*slow, *fast], priority, self._wall_clock)
        if slow:
            with self._lock:
                if self._edges == edges:  # else read on a connection that has ended
                    names = set().union(*(r.names for r in slow))
                    self._values = {k: v for k, v in read.values.items() if k in names}
                    assert self._slow_stamp is not None
                    self._read_time = read.time_of(self._slow_stamp) or 0.0
                    refreshed = True
                    if self._writes == writes:  # else read again at the next poll
                        self._due = self._clock() + self._period_s
            self.slow_reads += 1
        # The first block apart: its reply time stamps what a device reads first (the
        # stepper's running flags: ~/state), the stamp register's that of its block.
        first, rest = fast[:1], fast[1:]
        in_first = stamp_register is not None and any(stamp_register in r.names for r in first)
        stamp = read.time_of(stamp_register) if stamp_register is not None else None
        first_time = stamp if in_first and stamp is not None else read.last_time(first)
        if stamp_register is None:
            read_time = read.last_time(fast)
        elif stamp is None or not (in_first or rest):
            raise ValueError(f"no block of the plan holds {stamp_register!r}")
        else:
            read_time = stamp
        values = read.values
        with self._lock:
            if self.slow and not self._values:
                # The link went down or came up since the slow read: nothing slow to show.
                raise PollIncomplete("the link changed while the slow group was read")
            merged = {**self._values, **values}
            slow_time = self._read_time
        return GroupedRead(merged, read_time, first_time, slow_time, refreshed, read)


class WatchedChannel(Protocol):
    """What ``PollGroups.watch`` needs of a ``DeviceChannel``."""

    @property
    def link_state(self) -> LinkState: ...
    def add_write_listener(self, listener: Callable[[Span], None]) -> Callable[[], None]: ...


__all__ = [
    "SLOW_POLL_PERIOD_DEFAULT_S",
    "SLOW_POLL_PERIOD_RANGE_S",
    "GroupedRead",
    "PollGroups",
    "RateGroup",
    "WatchedChannel",
    "plan_groups",
]
