"""``read_blocks``: what a device reads, and the time its poll is stamped with (fake IO and a
fake clock, no sockets)."""

from __future__ import annotations

import pytest

from bridge_core.runtime.reads import read_blocks
from bridge_core.wire.channel import Priority
from bridge_core.wire.planner import plan_reads
from bridge_core.wire.registers import Register, RegisterMap, Table, ValueType

from ...support.fakes import FakeClock

MAP = RegisterMap(
    "test",
    (
        Register("status", 0, ValueType.U16, "test"),
        Register("position", 10, ValueType.I32, "test"),
        Register("speed", 20, ValueType.U16, "test"),
    ),
)


class TimedIO:
    """Answers reads with zeros and advances a fake clock by each request's duration."""

    def __init__(self, clock: FakeClock, durations: dict[int, float]) -> None:
        self.clock = clock
        self.durations = durations
        self.reads: list[tuple[int, float]] = []

    def read_registers(
        self,
        address: int,
        count: int,
        table: Table = Table.HOLDING,
        priority: Priority = Priority.POLL,
    ) -> list[int]:
        self.clock.now += self.durations.get(address, 0.001)
        self.reads.append((address, self.clock.now))
        return [0] * count

    def read_bits(
        self,
        address: int,
        count: int,
        table: Table = Table.COIL,
        priority: Priority = Priority.POLL,
    ) -> list[bool]:
        raise AssertionError("no bit reads in this map")


def test_stamp_is_the_read_time_of_the_position_block_not_the_first_or_last() -> None:
    clock = FakeClock(1000.0)
    # The first block is slow (retried), the last one slower still.
    io = TimedIO(clock, {0: 0.5, 10: 0.002, 20: 0.7})
    requests = plan_reads(MAP, MAP.select(["status", "position", "speed"]))
    assert [r.address for r in requests] == [0, 10, 20]
    values, stamp = read_blocks(io, requests, stamp_register="position", clock=clock)  # type: ignore[arg-type]
    position_reply = dict(io.reads)[10]
    assert stamp == position_reply
    assert values == {"status": 0, "position": 0, "speed": 0}


def test_stamp_register_must_be_in_the_plan() -> None:
    clock = FakeClock(1000.0)
    io = TimedIO(clock, {})
    requests = plan_reads(MAP, MAP.select(["status"]))
    with pytest.raises(ValueError, match="position"):
        read_blocks(io, requests, stamp_register="position", clock=clock)  # type: ignore[arg-type]
