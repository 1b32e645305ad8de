"""The wire budget: a device's fast cycle measured from its polls, the slow refresh from
its plan, the load at the rates asked, and one WARN per start or rate change (a stand-in
channel whose transactions cost set figures; the rate groups are the real ones)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import pytest

from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.runtime.wire_budget import (
    Budget,
    WireBudget,
    budget_values,
    line_load,
    line_text,
)
from bridge_core.wire.channel import Priority
from bridge_core.wire.link_stats import WireTally
from bridge_core.wire.planner import plan_reads
from bridge_core.wire.registers import Register, RegisterMap, Table, ValueType
from bridge_core.wire.requests import ReadRegisters, Request

from ...support.fakes import FakeClock

MAP = RegisterMap(
    "budget",
    (
        Register("position", 0, ValueType.I32, "test"),
        Register("speed", 10, ValueType.I32, "test"),
        Register("setting", 40, ValueType.U16, "test"),
        Register("firmware", 60, ValueType.U16, "test"),
    ),
)
FAST = plan_reads(MAP, MAP.select(["position", "speed"]))  # two reads (a gap of 8)
SLOW = plan_reads(MAP, MAP.select(["setting", "firmware"]))  # two reads
FRAME_PER_REGISTER_S = 0.001  # the stand-in link's frame time: 1 ms a register + 2 ms
FRAME_BASE_S = 0.002
TURNAROUND_S = 0.010


class CostedChannel:
    """Reads answer zeros; each costs its frames plus TURNAROUND_S, noted as a real
    channel notes them."""

    def __init__(self) -> None:
        self.wire = WireTally()

    def frame_time_s(self, request: Request) -> float:
        assert isinstance(request, ReadRegisters)
        return FRAME_BASE_S + FRAME_PER_REGISTER_S * request.count

    def read_registers(
        self,
        address: int,
        count: int,
        table: Table = Table.HOLDING,
        priority: Priority = Priority.POLL,
    ) -> list[int]:
        frame = self.frame_time_s(ReadRegisters(address, count, table))
        self.wire.note(frame, frame + TURNAROUND_S, priority is Priority.POLL)
        return [0] * count


class Rig:
    def __init__(self, rate_hz: float = 10.0, period_s: float = 1.0) -> None:
        self.clock = FakeClock()
        self.channel = CostedChannel()
        self.groups = PollGroups(FAST, SLOW, period_s=period_s, clock=self.clock)
        self.rate_hz = rate_hz
        self.budget = WireBudget(self.channel, lambda: self.groups, lambda: self.rate_hz)

    def poll(self) -> None:
        self.budget.around(lambda: self.groups.read(self.channel))  # type: ignore[arg-type]


def cost(plan: Sequence[object]) -> float:
    return sum(
        FRAME_BASE_S + FRAME_PER_REGISTER_S * r.count + TURNAROUND_S  # type: ignore[attr-defined]
        for r in plan
    )


def test_no_budget_before_a_poll_without_the_slow_group() -> None:
    rig = Rig()
    assert rig.budget.budget() is None
    rig.poll()  # the first poll reads the slow group too
    assert rig.budget.budget() is None
    rig.poll()
    budget = rig.budget.budget()
    assert budget is not None
    assert budget.fast_cycle_s == pytest.approx(cost(FAST))
    assert budget.slow_refresh_s == pytest.approx(cost(SLOW))
    assert budget.turnaround_s == pytest.approx(TURNAROUND_S)


def test_a_poll_that_refreshes_the_slow_group_keeps_the_last_fast_cycle() -> None:
    rig = Rig()
    rig.poll()
    rig.poll()
    rig.clock.now += 5.0  # the slow group is due again
    rig.poll()
    budget = rig.budget.budget()
    assert budget is not None and budget.fast_cycle_s == pytest.approx(cost(FAST))


def test_load_and_achievable_rate() -> None:
    budget = Budget(
        fast_cycle_s=0.05,
        slow_refresh_s=0.2,
        poll_rate_hz=30.0,
        slow_period_s=1.0,
        turnaround_s=0.035,
    )
    assert budget.load == pytest.approx(0.05 * 30 + 0.2)
    assert budget.exceeded
    assert budget.achievable_hz == pytest.approx(0.8 / 0.05)
    free = Budget(0.0, 0.0, 1000.0, 1.0, 0.0)
    assert math.isinf(free.achievable_hz) and not free.exceeded


def test_an_exceeded_budget_is_said_once_and_again_after_a_rate_change() -> None:
    rig = Rig(rate_hz=100.0)  # a fast cycle of ~43 ms cannot run at 100 Hz
    rig.poll()
    assert rig.budget.warning("dev") is None  # nothing measured yet: wait
    rig.poll()
    text = rig.budget.warning("dev")
    assert text is not None and "poll_rate_hz 100" in text and "carries about" in text
    achievable = (1.0 - cost(SLOW) / 1.0) / cost(FAST)
    assert f"{achievable:.1f} Hz" in text
    rig.poll()
    assert rig.budget.warning("dev") is None  # once
    rig.rate_hz = 1.0
    rig.budget.rearm()
    rig.poll()
    assert rig.budget.warning("dev") is None  # judged again: within the budget
    rig.rate_hz = 200.0
    rig.budget.rearm()
    assert rig.budget.warning("dev") is not None


def test_line_sums_its_devices() -> None:
    a = Budget(0.02, 0.0, 30.0, 1.0, 0.001)  # 60 %
    b = Budget(0.01, 0.0, 60.0, 1.0, 0.001)  # 60 %
    assert line_load([a, b]) == pytest.approx(1.2)
    text = line_text("line /dev/x", [a, b])
    assert "120%" in text and "25.0, 50.0 Hz" in text


def test_diagnostics_values_name_the_turnaround_by_link_kind() -> None:
    budget = Budget(0.05, 0.0, 10.0, 1.0, 0.035)
    rtu = dict(budget_values(budget, serial=True))
    assert rtu["wire load (%)"] == "50.0" and rtu["reply delay (ms)"] == "35.0"
    assert rtu["achievable poll rate (Hz)"] == "20.0"
    tcp = dict(budget_values(None, serial=False))
    assert tcp["round trip (ms)"] == "n/a"
