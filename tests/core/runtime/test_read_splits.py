"""A merged read the device refuses with ILLEGAL DATA ADDRESS is split in the same poll and
remembered: real pymodbus servers over TCP,
the bridges' own channel and poller."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from bridge_core.runtime.poller import Poller, PollOutcome
from bridge_core.runtime.reads import read_blocks, read_splits
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import ILLEGAL_VALUE, SimulatedDevice
from bridge_core.wire.channel import DeviceChannel, Priority
from bridge_core.wire.codec import Value
from bridge_core.wire.errors import DeviceException
from bridge_core.wire.planner import plan_reads
from bridge_core.wire.registers import Access, DeviceLimits, Register, RegisterMap, Table, ValueType
from bridge_core.wire.transport import ModbusLink, TcpSettings
from motec_bridge.device import MotecDevice
from motec_bridge.sim import MotecSimDrive

UNIT = 1
# The planner believes the rows 3..5 and 8..9 may be read (read_undefined_ok); the
# device, which serves only its registers, refuses any read through them.
MAP = RegisterMap(
    "gappy",
    (
        Register("a", 0, ValueType.U16, "t", access=Access.READ_WRITE),
        Register("b", 1, ValueType.U32, "t", access=Access.READ_WRITE),
        Register("c", 6, ValueType.U16, "t", access=Access.READ_WRITE),
        Register("d", 7, ValueType.U16, "t", access=Access.READ_WRITE),
        Register("e", 10, ValueType.U16, "t", access=Access.READ_WRITE),
        Register("f", 0, ValueType.U16, "t", table=Table.INPUT),
    ),
    DeviceLimits(read_undefined_ok=True, max_gap=None),
)
VALUES = {"a": 1, "b": 70000, "c": 3, "d": 4, "e": 5, "f": 6}


@contextmanager
def served(device: SimulatedDevice) -> Iterator[DeviceChannel]:
    sim = Simulator([device])
    port = sim.start_tcp()
    link = ModbusLink(TcpSettings(port=port, timeout_s=1.0))
    try:
        yield DeviceChannel(link, device.unit_id, retries=0)
    finally:
        link.close()
        sim.stop()


def spans(device: SimulatedDevice) -> list[tuple[str, int, int]]:
    with device.lock:
        reads = [(r.table.value, r.address, r.count) for r in device.read_log]
        device.read_log.clear()
    return reads


def test_a_refused_merged_read_is_split_in_the_same_poll_and_remembered() -> None:
    device = SimulatedDevice(MAP, UNIT)
    device.log_reads = True
    for name, value in VALUES.items():
        device.set(name, value)
    plan = plan_reads(MAP, list(MAP))
    assert [(r.address, r.count) for r in plan] == [(0, 11), (0, 1)]  # one merged read
    events: list[tuple[PollOutcome, str]] = []
    published: list[dict[str, Value]] = []
    with served(device) as channel:
        poller: Poller[dict[str, Value]] = Poller(
            channel,
            lambda: read_blocks(channel, plan, Priority.POLL)[0],
            published.append,
            rate_hz=10.0,
            report=lambda outcome, text: events.append((outcome, text)),
        )
        # First poll: 0+11 refused, its parts read at once (0+3 and 6+2 and 10+1); the
        # input register's block is not lost.
        assert poller.tick() is PollOutcome.PUBLISHED
        assert spans(device) == [
            ("holding", 0, 11),
            ("holding", 0, 3),
            ("holding", 6, 2),
            ("holding", 10, 1),
            ("input", 0, 1),
        ]
        assert [outcome for outcome, _ in events] == [PollOutcome.SPLIT]
        assert "holding 0+11" in events[0][1] and "0+3, 6+2, 10+1" in events[0][1]
        # Next polls read the parts directly and say nothing more.
        assert poller.tick() is PollOutcome.PUBLISHED
        assert spans(device) == [
            ("holding", 0, 3),
            ("holding", 6, 2),
            ("holding", 10, 1),
            ("input", 0, 1),
        ]
        assert len(events) == 1
        assert poller.publish_pending() == 2
        assert published[-1] == VALUES
        assert len(read_splits(channel)) == 1


def test_a_refused_read_without_gaps_is_the_registers_own_refusal() -> None:
    device = SimulatedDevice(MAP, UNIT)
    device.log_reads = True
    device.forced_exceptions.append((Table.HOLDING, range(7, 8), 0x02))
    plan = plan_reads(MAP, MAP.select(["a", "c", "d"]))
    assert [(r.address, r.count) for r in plan] == [(0, 8)]
    with served(device) as channel:
        with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
            read_blocks(channel, plan)
        # 0+8 refused, split at the gap 1..5: 0+1 is read, 6+2 (c and d, no gap) is
        # refused for d itself and not split further.
        assert spans(device) == [("holding", 0, 8), ("holding", 0, 1), ("holding", 6, 2)]


def test_other_exceptions_are_not_split() -> None:
    device = SimulatedDevice(MAP, UNIT)
    device.log_reads = True
    device.forced_exceptions.append((Table.HOLDING, range(7, 8), ILLEGAL_VALUE))
    plan = plan_reads(MAP, MAP.select(["c", "d"]))
    with served(device) as channel:
        with pytest.raises(DeviceException):
            read_blocks(channel, plan)
        assert spans(device) == [("holding", 6, 2)]
        assert len(read_splits(channel)) == 0


def test_motec_polls_a_drive_that_refuses_the_unnamed_rows() -> None:
    """MOTEC decision: the poll reads through 0x2A-0x2C (no register the manual names); a
    drive that refuses them still gets polled, from the first poll on."""
    drive = MotecSimDrive(UNIT)
    drive.log_reads = True
    drive.forced_exceptions.append((Table.HOLDING, range(0x2A, 0x2D), 0x02))
    with served(drive) as channel:
        motec = MotecDevice(channel)
        motec.poll()
        first = spans(drive)
        assert any(a <= 0x2A < a + n for _t, a, n in first)  # the merged read was tried
        motec.poll()
        second = spans(drive)
        assert not any(a <= 0x2C and a + n > 0x2A for _t, a, n in second), second
        assert len(read_splits(channel)) >= 1
