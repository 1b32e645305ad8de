"""``read_blocks``: what a device reads, and the time its poll is stamped with (fake IO and a
fake clock, or a real channel over a scripted transport; no sockets)."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest

from bridge_core.runtime.reads import read_blocks
from bridge_core.wire.channel import DeviceChannel, Priority
from bridge_core.wire.planner import plan_reads
from bridge_core.wire.registers import Register, RegisterMap, Table, ValueType

from ...support.fakes import FakeClock, ScriptedBus

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


class StopAfterTheFirstRead(DeviceChannel):
    """A channel whose first read is followed by a stop from another thread that takes the
    link lock as soon as the read releases it, before the polling thread goes on."""

    stop_sent: float | None = None

    def read_registers(self, *args: Any, **kwargs: Any) -> list[int]:
        values = super().read_registers(*args, **kwargs)
        if self.stop_sent is None:
            stop = threading.Thread(target=self.write_coil, args=(5, True, Priority.STOP))
            stop.start()
            stop.join(10)
            self.stop_sent = time.time()
            time.sleep(0.01)  # the polling thread scheduled out a little longer
        return values


def test_a_stop_sent_between_two_reads_comes_after_the_first_reads_stamp() -> None:
    """A read is stamped when its reply arrived, under the link lock: a stop that takes
    the lock as soon as the poll releases it, before the polling thread looks at a clock,
    is sent after that time. Stamped after the lock, a state stamped after the stop would
    show flags read before it (the stepper flood test's rare failure)."""
    bus = ScriptedBus()
    channel = StopAfterTheFirstRead(bus, 1, retries=0)
    requests = plan_reads(MAP, MAP.select(["status", "position"]))
    bus.script[1] = [[0], [], [0, 0]]  # the stop takes the middle step
    values, stamp = read_blocks(channel, requests, stamp_register="status")
    assert [type(r).__name__ for _, r in bus.executed] == [
        "ReadRegisters",
        "WriteCoil",
        "ReadRegisters",
    ]
    assert channel.stop_sent is not None and stamp < channel.stop_sent
    assert values == {"status": 0, "position": 0}
