"""How a device reads its registers: a plan's blocks, a few named registers.

``read_blocks`` returns the values and the wall-clock time the reply of the block holding
a named register (the joint positions) arrived, so every snapshot is stamped with the read
time of its positions (docs/architecture.md, "The read path"), not with the time of the
first or last request of the poll. A merged read the device refuses is split at once and
remembered (``ReadSplits``).

Plain Python over ``RegisterIO``: the device modules use it, and the poller only reports
what was split.
"""

from __future__ import annotations

import collections
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

from ..wire.channel import Priority, RegisterIO
from ..wire.codec import Value
from ..wire.errors import ILLEGAL_DATA_ADDRESS, DeviceException, FrameError
from ..wire.planner import ReadRequest, decode_reply, plan_reads, split_request
from ..wire.registers import RegisterMap, Table
from ..wire.requests import ReadBits, ReadRegisters, Reply, Request


@dataclass
class PlanRead:
    """A plan's values, and when the reply of each request arrived (wall clock)."""

    values: dict[str, Value] = field(default_factory=dict)
    # In arrival order: the request read, the plan's request it reads (itself, or the
    # merged read it is a part of), the time its reply arrived.
    times: list[tuple[ReadRequest, ReadRequest, float]] = field(default_factory=list)

    def time_of(self, register_name: str) -> float | None:
        """When the reply holding ``register_name`` arrived (None: none did)."""
        for request, _origin, when in self.times:
            if register_name in request.names:
                return when
        return None

    def last_time(self, requests: Iterable[ReadRequest]) -> float:
        """When the last reply to any of the plan's ``requests`` arrived (0.0: none did)."""
        wanted = {id(r) for r in requests}
        times = [when for _request, origin, when in self.times if id(origin) in wanted]
        return times[-1] if times else 0.0


def read_plan(
    io: RegisterIO,
    plan: Sequence[ReadRequest],
    priority: Priority = Priority.POLL,
    clock: Callable[[], float] = time.time,
) -> PlanRead:
    """Read every block of ``plan`` in order; the values and each reply's time.

    Through the channel's ``transact_many`` where it pipelines (a TCP link with
    ``max_in_flight`` > 1), else one ``read_registers`` / ``read_bits`` after another,
    exactly as before (and for a test's stand-in). A refused merged
    read is replaced by its parts, read next. A request split later keeps the times of its
    parts (each part its own reply's).
    """
    splits = read_splits(io)
    # A real channel's reply times are taken under its link lock; ``clock()`` here would
    # come after the lock is released, when a stop may already have gone on the wire.
    replied_at: Callable[[], float] = getattr(io, "replied_at", clock)
    pending = collections.deque((request, request) for request in plan)  # read, origin
    sent: list[tuple[ReadRequest, ReadRequest]] = []
    result = PlanRead()
    failure: list[BaseException] = []

    def next_read() -> tuple[ReadRequest, ReadRequest] | None:
        while pending and not failure:
            request, origin = pending.popleft()
            replaced = splits.replacement(request)
            if replaced is not None:
                pending.extendleft((part, origin) for part in reversed(replaced))
                continue
            sent.append((request, origin))
            return request, origin
        return None

    def answered(item: tuple[ReadRequest, ReadRequest], outcome: Reply | DeviceException) -> None:
        request, origin = item
        if failure:
            return  # the batch failed: the replies still in flight are dropped
        if isinstance(outcome, DeviceException):
            # A merged read the device refuses (a row between its registers it does not
            # serve): read its parts now, so this poll still ends, and from now on.
            parts = split_request(request)
            if outcome.exception_code != ILLEGAL_DATA_ADDRESS or not parts:
                failure.append(outcome)
                return
            splits.remember(request, parts, outcome)
            pending.extendleft((part, origin) for part in reversed(parts))
            return
        if not isinstance(outcome, list) or len(outcome) < request.count:
            got = len(outcome) if isinstance(outcome, list) else 0
            failure.append(FrameError(f"short reply: {got} of {request.count} values"))
            return
        result.times.append((request, origin, replied_at()))
        result.values.update(decode_reply(request, outcome[: request.count]))

    # One at a time, the reads go as they always did (``read_registers`` / ``read_bits``).
    transact_many = getattr(io, "transact_many", None) if getattr(io, "pipelines", False) else None
    if transact_many is not None:

        def next_request() -> Request | None:
            item = next_read()
            return None if item is None else as_request(item[0])

        transact_many(next_request, lambda index, outcome: answered(sent[index], outcome), priority)
    else:
        while (item := next_read()) is not None:
            try:
                raw = _read(io, item[0], priority)
            except DeviceException as err:
                answered(item, err)
                continue
            answered(item, list(raw))
    if failure:
        raise failure[0]
    return result


def read_blocks(
    io: RegisterIO,
    plan: Sequence[ReadRequest],
    priority: Priority = Priority.POLL,
    stamp_register: str | None = None,
    clock: Callable[[], float] = time.time,
) -> tuple[dict[str, Value], float]:
    """Read every block of ``plan``; the values, and the time ``stamp_register`` was read.

    The time is taken when the reply to the block holding ``stamp_register`` arrived: the
    device sampled the registers between that request's arrival and its reply, so the
    stamp is within one transaction time of the read, also when that block or any other
    one was retried. Without ``stamp_register`` it is the time of the last reply.
    """
    read = read_plan(io, plan, priority, clock)
    if stamp_register is None:
        return read.values, read.times[-1][2] if read.times else 0.0
    stamp = read.time_of(stamp_register)
    if stamp is None:
        raise ValueError(f"no block of the plan holds {stamp_register!r}")
    return read.values, stamp


def as_request(read: ReadRequest) -> Request:
    """The request a planned read goes out as."""
    if read.table.is_bit:
        return ReadBits(read.address, read.count, read.table)
    return ReadRegisters(read.address, read.count, read.table)


def _read(
    io: RegisterIO, request: ReadRequest, priority: Priority
) -> Sequence[int] | Sequence[bool]:
    if request.table.is_bit:
        return io.read_bits(request.address, request.count, request.table, priority=priority)
    return io.read_registers(request.address, request.count, request.table, priority=priority)


class ReadSplits:
    """The merged reads one device refused with ILLEGAL DATA ADDRESS, and their parts.

    A map may merge reads through rows a real device does not serve (MOTEC's unnamed
    0x2A-0x2C, a described device with ``read_undefined: true``), and such a device would
    refuse every poll. ``read_blocks`` splits a refused merged read at once (the poll goes
    on with its other blocks) and remembers it here, so the next polls read the parts
    directly; what was split is said once (``news``, which the poller logs).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._parts: dict[tuple[Table, int, int, frozenset[str]], tuple[ReadRequest, ...]] = {}
        self._news: list[str] = []

    @staticmethod
    def _key(request: ReadRequest) -> tuple[Table, int, int, frozenset[str]]:
        return (request.table, request.address, request.count, request.names)

    def replacement(self, request: ReadRequest) -> tuple[ReadRequest, ...] | None:
        with self._lock:
            return self._parts.get(self._key(request))

    def remember(
        self, request: ReadRequest, parts: Sequence[ReadRequest], err: DeviceException
    ) -> None:
        spans = ", ".join(f"{part.address}+{part.count}" for part in parts)
        with self._lock:
            self._parts[self._key(request)] = tuple(parts)
            self._news.append(
                f"the device refused the merged read of {request.table.value} "
                f"{request.address}+{request.count} ({err.name}): reading it as {spans} "
                "from now on"
            )

    def __len__(self) -> int:
        with self._lock:
            return len(self._parts)

    def news(self) -> list[str]:
        """What was split since the last call (each split once)."""
        with self._lock:
            news, self._news = self._news, []
        return news


_SPLITS: weakref.WeakKeyDictionary[object, ReadSplits] = weakref.WeakKeyDictionary()
_SPLITS_LOCK = threading.Lock()


def read_splits(io: object) -> ReadSplits:
    """The refused merged reads of the device behind ``io`` (its channel), kept as long as
    the channel lives; a fresh, unkept one for an ``io`` that cannot be a weak key."""
    with _SPLITS_LOCK:
        try:
            splits = _SPLITS.get(io)
            if splits is None:
                splits = _SPLITS[io] = ReadSplits()
        except TypeError:
            return ReadSplits()
    return splits


def read_named(io: RegisterIO, register_map: RegisterMap, names: Iterable[str]) -> dict[str, Value]:
    """Values of named registers, at command priority, in as few requests as the device
    allows (the map's limits); the read a service makes on request."""
    plan = plan_reads(register_map, register_map.select(list(names)))
    return read_blocks(io, plan, Priority.COMMAND)[0]


def holds(request: ReadRequest, register_name: str) -> bool:
    return register_name in request.names


__all__ = [
    "PlanRead",
    "ReadSplits",
    "as_request",
    "holds",
    "read_blocks",
    "read_named",
    "read_plan",
    "read_splits",
]
