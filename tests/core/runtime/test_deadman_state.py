"""A lost stop or speed write must keep the deadman on the motor (no ROS, fake link)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from bridge_core.wire.channel import Priority
from bridge_core.wire.errors import LinkTimeout
from bridge_core.wire.registers import Table
from motec_bridge.device import MotecDevice
from stepper_bridge.device import StepperDevice
from stepper_bridge.registers import STEPPER_MAP, motor_register


class FlakyIO:
    """Records writes; the next ``fail`` writes time out (as a lost RS-485 frame would)."""

    def __init__(self) -> None:
        self.writes: list[tuple[str, int, Any]] = []
        self.fail = 0
        self.registers: dict[int, int] = {}

    def _write(self, kind: str, address: int, value: Any) -> None:
        if self.fail:
            self.fail -= 1
            raise LinkTimeout("no reply")
        self.writes.append((kind, address, value))

    def write_coil(self, address: int, on: bool, priority: Priority = Priority.COMMAND) -> None:
        self._write("coil", address, on)

    def write_register(
        self, address: int, value: int, priority: Priority = Priority.COMMAND
    ) -> None:
        self._write("register", address, value)
        self.registers[address] = value

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        self._write("registers", address, tuple(values))

    def read_registers(
        self, address: int, count: int, table: Table = Table.HOLDING, priority: Any = None
    ) -> list[int]:
        return [self.registers.get(address + i, 0) for i in range(count)]


def test_stepper_stop_lost_keeps_the_deadman_on_the_motor() -> None:
    io = FlakyIO()
    device = StepperDevice(io)  # type: ignore[arg-type]
    assert device.jog(1, 100)
    assert device.jogging(1)
    io.fail = 1
    with pytest.raises(LinkTimeout):
        device.jog_stop(1)
    assert device.jogging(1)  # the stop may not have landed: still the deadman's
    assert device.jog_stop(1)  # the retry goes out and is acknowledged
    assert not device.jogging(1)


def test_stepper_failed_jog_start_is_treated_as_running() -> None:
    io = FlakyIO()
    device = StepperDevice(io)  # type: ignore[arg-type]
    io.fail = 1
    with pytest.raises(LinkTimeout):
        device.jog(2, -50)
    assert device.jogging(2)
    assert device.jog_stop(2) and not device.jogging(2)


def test_stepper_repeated_zero_jogs_send_one_stop() -> None:
    io = FlakyIO()
    device = StepperDevice(io)  # type: ignore[arg-type]
    running = STEPPER_MAP[motor_register(3, "running")].address
    io.registers[running] = 1  # the controller shows the single run (stepper decision 23)
    device.motor_action(3, "run_once")
    io.registers[running] = 0  # and the stop that follows
    before = len(io.writes)
    assert device.jog(3, 0)  # the motor may be running the single run: stop once
    assert not device.jog(3, 0) and not device.jog(3, 0)
    assert len(io.writes) == before + 1


def test_motec_failed_first_velocity_write_keeps_the_deadman_on() -> None:
    io = FlakyIO()
    device = MotecDevice(io)  # type: ignore[arg-type]
    # network mode (0x24 = 0), velocity control (0x25 = 1), enabled (0x28 = 1)
    io.registers.update({0x24: 0, 0x25: 1, 0x28: 1})
    io.fail = 1
    with pytest.raises(LinkTimeout):
        device.velocity(100)
    assert device.streaming  # 0xAE may hold 100 rpm: the deadman must zero it
    assert device.velocity_stop() and not device.streaming
    assert io.writes[-1] == ("register", 0xAE, 0)


@pytest.mark.parametrize("which", ["motor stop", "emergency stop"])
def test_stepper_a_failed_stop_service_leaves_the_jogs_stop_pending(which: str) -> None:
    """A stop service that fails on the link must not make the guard forget the
    jog it meant to end: that jog's own stop stays pending (sent first when the link is
    back) and the jog is locked, so a joystick still held cannot restart the motor."""
    io = FlakyIO()
    device = StepperDevice(io)  # type: ignore[arg-type]
    assert device.jog(1, 100)
    io.fail = 1
    with pytest.raises(LinkTimeout):
        if which == "motor stop":
            device.motor_action(1, "stop")
        else:
            device.system_command("emergency_stop")
    assert device.jogs.pending_stops() == [1] and device.jogging(1)
    assert device.jogs[1].locked
    before = len(io.writes)
    assert device.jog_stop(1)  # what the reconnect (or the deadman) does
    assert io.writes[before][0:2] == ("coil", 4)  # motor 1's stop coil (00005)
    assert not device.jogging(1) and device.jogs.pending_stops() == []


@pytest.mark.parametrize("which", ["stop", "disable"])
def test_motec_a_failed_stop_service_leaves_the_streams_stop_pending(which: str) -> None:
    io = FlakyIO()
    device = MotecDevice(io)  # type: ignore[arg-type]
    io.registers.update({0x24: 0, 0x25: 1, 0x28: 1})  # network, velocity control, enabled
    assert device.velocity(100)
    io.fail = 1
    with pytest.raises(LinkTimeout):
        device.stop() if which == "stop" else device.enable(False)
    assert device.stream.pending_stops() == [0] and device.streaming
    assert device.velocity_stop() and not device.streaming
    assert io.writes[-1] == ("register", 0xAE, 0)
