"""Rate groups: the fast plan every poll, the slow plan whole once per period, after a write
that touches it, and after every link edge (a real ``DeviceChannel`` on a TCP socket to a
pymodbus simulator; the period runs on a fake monotonic clock)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import LinkError, PollIncomplete
from bridge_core.wire.planner import plan_reads
from bridge_core.wire.registers import Access, Register, RegisterMap, Table, ValueType
from bridge_core.wire.requests import Span
from bridge_core.wire.transport import ModbusLink, TcpSettings

from ...support.fakes import FakeClock

MAP = RegisterMap(
    "groups",
    (
        Register("position", 0, ValueType.I32, "test"),
        Register("status", 2, ValueType.U16, "test"),
        Register("setting", 20, ValueType.U16, "test", access=Access.READ_WRITE),
        Register("firmware", 21, ValueType.U16, "test"),
        Register("speed", 30, ValueType.U16, "test", access=Access.READ_WRITE),
        Register("output_on", 5, ValueType.BOOL, "test", table=Table.COIL, access=Access.WRITE),
    ),
)
FAST = plan_reads(MAP, MAP.select(["position", "status"]))
SLOW = plan_reads(MAP, MAP.select(["setting", "firmware"]))
OUTPUT_COIL = Span(Table.COIL, 5)


class Rig:
    """A simulated device over TCP, a channel to it, and the groups under test."""

    def __init__(self, period_s: float = 1.0) -> None:
        self.device = SimulatedDevice(MAP, 1)
        self.device.log_reads = True
        self.sim = Simulator([self.device])
        self.sim.start_tcp()
        self.link = ModbusLink(TcpSettings(port=self.sim.port, timeout_s=1.0))
        self.channel = DeviceChannel(self.link, 1, retries=0, reconnect_max_s=0.3)
        self.clock = FakeClock(100.0)
        self.groups = PollGroups(
            FAST, SLOW, period_s=period_s, touched_by=[OUTPUT_COIL], clock=self.clock
        )
        self.unwatch = self.groups.watch(self.channel)

    def slow_reads(self) -> int:
        """Requests that read the slow block (address 20) so far."""
        return sum(1 for r in self.device.read_log if r.address == 20)

    def close(self) -> None:
        self.unwatch()
        self.link.close()
        self.sim.stop()


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.close()


def test_the_slow_group_is_read_at_the_first_poll_then_once_per_period(rig: Rig) -> None:
    rig.device.set("setting", 7)
    first = rig.groups.read(rig.channel, "position")
    assert first.slow_refreshed and first.values["setting"] == 7
    assert rig.slow_reads() == 1
    rig.device.set("setting", 8)
    rig.device.set("position", 1234)
    rig.clock.now += 0.5
    second = rig.groups.read(rig.channel, "position")
    assert not second.slow_refreshed
    assert second.values["position"] == 1234  # fast: read again
    assert second.values["setting"] == 7  # slow: the value of the first poll
    assert second.slow_read_time == first.slow_read_time
    assert rig.slow_reads() == 1
    rig.clock.now += 0.5
    third = rig.groups.read(rig.channel, "position")
    assert third.slow_refreshed and third.values["setting"] == 8
    assert third.slow_read_time > first.slow_read_time
    assert rig.slow_reads() == 2


def test_the_stamp_is_the_fast_read_and_the_slow_stamp_its_own(rig: Rig) -> None:
    read = rig.groups.read(rig.channel, "position")
    # The slow group is read first: the fast stamp is the newer one.
    assert 0.0 < read.slow_read_time <= read.read_time


def test_a_write_to_a_slow_register_is_read_back_at_the_next_poll(rig: Rig) -> None:
    rig.groups.read(rig.channel, "position")
    rig.channel.write_register(MAP["setting"].address, 42)
    assert rig.groups.read(rig.channel, "position").values["setting"] == 42
    assert rig.slow_reads() == 2


def test_a_write_that_touches_the_slow_group_elsewhere_refreshes_it(rig: Rig) -> None:
    rig.groups.read(rig.channel, "position")
    rig.channel.write_coil(OUTPUT_COIL.address, True)
    assert rig.groups.read(rig.channel, "position").slow_refreshed


def test_a_write_to_a_fast_register_leaves_the_slow_group_alone(rig: Rig) -> None:
    rig.groups.read(rig.channel, "position")
    rig.channel.write_register(MAP["speed"].address, 5)
    assert not rig.groups.read(rig.channel, "position").slow_refreshed
    assert rig.slow_reads() == 1


def test_after_a_link_loss_no_slow_value_is_reused(rig: Rig) -> None:
    rig.device.set("setting", 1)
    rig.groups.read(rig.channel, "position")
    rig.channel.mark_down("cable pulled")
    rig.device.set("setting", 2)
    rig.clock.now += 0.1  # well within the period
    after = rig.groups.read(rig.channel, "position")
    assert after.slow_refreshed and after.values["setting"] == 2


def test_a_failed_slow_read_fails_the_poll(rig: Rig) -> None:
    rig.groups.read(rig.channel, "position")
    rig.sim.stop()
    rig.clock.now += 1.0
    with pytest.raises(LinkError):
        rig.groups.read(rig.channel, "position")
    assert not rig.channel.connected


def test_an_edge_between_the_slow_read_and_the_fast_one_gives_no_snapshot(rig: Rig) -> None:
    # A command lost the link after the slow read: its values are of the old connection.
    rig.groups.forget()
    groups = rig.groups

    class LosesAfterSlow:
        def __init__(self) -> None:
            self.inner = rig.channel

        def read_registers(
            self, address: int, count: int, *args: object, **kw: object
        ) -> list[int]:
            values = self.inner.read_registers(address, count)
            if address == MAP["setting"].address:
                groups.forget()
            return values

        def read_bits(self, *args: object, **kw: object) -> list[bool]:
            raise AssertionError("no bits polled")

    with pytest.raises(PollIncomplete):
        groups.read(LosesAfterSlow(), "position")  # type: ignore[arg-type]


def test_the_period_is_live_and_validated(rig: Rig) -> None:
    rig.groups.read(rig.channel, "position")
    rig.groups.period_s = 10.0
    rig.clock.now += 5.0
    assert not rig.groups.read(rig.channel, "position").slow_refreshed
    rig.groups.period_s = 2.0  # the next refresh: 2 s after the last one, i.e. now
    assert rig.groups.read(rig.channel, "position").slow_refreshed
    for bad in (0.0, -1.0, math.nan, 1e9):
        with pytest.raises(ValueError, match="slow poll period"):
            rig.groups.period_s = bad
    assert rig.groups.period_s == 2.0


def test_an_empty_slow_group_reads_only_the_fast_plan(rig: Rig) -> None:
    only_fast = PollGroups(FAST, clock=rig.clock)
    read = only_fast.read(rig.channel, "position")
    assert read.slow_read_time == 0.0 and not read.slow_refreshed
    assert "setting" not in read.values
