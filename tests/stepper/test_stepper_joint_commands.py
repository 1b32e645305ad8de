"""The stepper's ``~/joint_commands`` device side (stepper_bridge/joint_commands.py,
stepper decision 22 of docs/decisions/stepper.md) against the simulator over a real socat
pty pair (no ROS): position targets as single runs sent when the motor stands, and the SI
conversions."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import CommandRejected
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings
from stepper_bridge.device import StepperDevice
from stepper_bridge.joint_commands import MotorTargets, to_rpm, to_target
from stepper_bridge.registers import STEPPER_MAP, motor_coil, motor_register
from stepper_bridge.sim import FACTORY, StepperSimDevice, make_simulator
from stepper_bridge.units import JointScale

from ..support.ros import wait_for
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, socat_pair

BAUD = 115200
TRAVEL = 1000.0  # far beyond the targets: no limit switch stops a motor here
LEAD = FACTORY["lead"]  # units per motor revolution in the simulator (5)
SPEED_UNITS_S = FACTORY["speed"] / 60.0 * LEAD  # the configured speed, units per second
WAIT_S = 20.0
H, C = Table.HOLDING, Table.COIL


@dataclass
class Rig:
    sim: Simulator
    fake: StepperSimDevice
    device: StepperDevice
    targets: MotorTargets

    def writes(self) -> list[tuple[int, Table, int]]:
        return [(r.function_code, r.table, r.address) for r in self.fake.write_log]

    def wait_standing_at(self, motor: int, units: float) -> None:
        wait_for(
            lambda: (
                self.fake.motion[motor] is None
                and math.isclose(self.fake.coordinate(motor), units, abs_tol=1e-6)
            ),
            WAIT_S,
            f"motor {motor} standing at {units}",
        )


@pytest.fixture
def rig() -> Iterator[Rig]:
    sim = make_simulator(reply_delay_s=0.0, travel=TRAVEL)
    fake = sim.device
    assert isinstance(fake, StepperSimDevice)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        device = StepperDevice(DeviceChannel(link, 1, retries=0))
        device.read_config()
        try:
            yield Rig(sim, fake, device, MotorTargets(device))
        finally:
            link.close()
            sim.stop()


def register(motor: int, field: str) -> int:
    return STEPPER_MAP[motor_register(motor, field)].address


def test_a_target_is_a_single_run_from_where_the_motor_stands(rig: Rig) -> None:
    before = len(rig.writes())
    assert rig.targets.guard.command(1, 12.34)
    rig.wait_standing_at(1, 12.34)
    # Direction and run distance every time (as move_by), then the single-run coil.
    assert rig.writes()[before:] == [
        (6, H, register(1, "direction")),
        (16, H, register(1, "run_distance")),
        (5, C, motor_coil(1, "run_once")),
    ]


def test_a_target_behind_writes_the_direction_first(rig: Rig) -> None:
    before = len(rig.writes())
    assert rig.targets.guard.command(2, -3.0)
    rig.wait_standing_at(2, -3.0)
    assert rig.writes()[before:] == [
        (6, H, register(2, "direction")),
        (16, H, register(2, "run_distance")),
        (5, C, motor_coil(2, "run_once")),
    ]


@pytest.mark.parametrize(
    ("direction", "distance", "target"),
    # The cache holds direction 0 and run distance 10 (the simulator's factory values).
    [(1, 12.34, 12.34), (0, 7.0, 10.0), (1, 7.0, 10.0)],
)
def test_a_change_at_the_touch_panel_never_sends_a_target_the_wrong_way(
    rig: Rig, direction: int, distance: float, target: float
) -> None:
    """The direction and run distance the bridge read (its cache, kept up
    to config_refresh_s) may have been changed at the controller since; a target writes
    both every time, so the single run goes where the target is and ends on it."""
    motor = 3
    rig.fake.set(motor_register(motor, "direction"), direction)
    rig.fake.set(motor_register(motor, "run_distance"), distance)
    assert rig.targets.guard.command(motor, target)
    rig.wait_standing_at(motor, target)
    assert rig.fake.get(motor_register(motor, "direction")) == (0 if target > 0 else 1)
    assert rig.fake.get(motor_register(motor, "run_distance")) == pytest.approx(abs(target))


def test_a_newer_target_waits_while_the_motor_runs_the_previous(rig: Rig) -> None:
    guard = rig.targets.guard
    assert guard.command(1, 20.0)  # 4 s at the configured speed
    wait_for(lambda: rig.fake.motion[1] is not None, WAIT_S, "motor 1 running")
    before = len(rig.writes())
    assert not guard.command(1, 25.0)  # deferred: nothing written, offered again
    assert rig.writes()[before:] == [] and guard[1].offered == 25.0
    rig.wait_standing_at(1, 20.0)
    value = guard.take(1)
    assert value == 25.0 and guard.command(1, value)
    rig.wait_standing_at(1, 25.0)


def test_a_motor_running_something_else_refuses_a_target(rig: Rig) -> None:
    rig.device.motor_action(3, "forward")
    wait_for(lambda: rig.fake.motion[3] is not None, WAIT_S, "motor 3 running")
    before = len(rig.writes())
    with pytest.raises(CommandRejected, match="not from joint_commands"):
        rig.targets.guard.command(3, 5.0)
    assert rig.writes()[before:] == []
    rig.device.motor_action(3, "stop")


def test_a_target_within_a_step_writes_nothing(rig: Rig) -> None:
    before = len(rig.writes())
    rig.targets.guard.command(4, 0.0)  # coordinate 0 already
    assert rig.writes()[before:] == []


def test_the_stream_stop_is_the_stop_coil_and_a_stop_service_locks_it(rig: Rig) -> None:
    guard = rig.targets.guard
    guard.command(5, 40.0)
    wait_for(lambda: rig.fake.coordinate(5) > 1.0, WAIT_S, "motor 5 a unit on its way")
    assert guard.stop(5)
    assert rig.writes()[-1] == (5, C, motor_coil(5, "stop"))
    wait_for(lambda: rig.fake.motion[5] is None, WAIT_S, "motor 5 stopped")
    guard.command(5, 0.0)
    wait_for(lambda: rig.fake.motion[5] is not None, WAIT_S, "motor 5 running back")
    rig.device.motor_action(5, "stop")  # the stop service: takes the stream over, locked
    assert guard[5].locked and not guard[5].active
    with pytest.raises(CommandRejected, match="stopped"):
        guard.command(5, 1.0)


def test_positions_convert_as_joint_states_do() -> None:
    millimetres = JointScale("prismatic", 1000.0)
    assert to_target(millimetres, LEAD, 0.01234) == 12.34
    assert millimetres.to_si(to_target(millimetres, LEAD, -0.5), LEAD) == -0.5
    geared = JointScale("revolute", 1000.0, 50.0)  # 50 units per joint revolution
    assert to_target(geared, LEAD, math.pi) == 25.0
    with pytest.raises(CommandRejected, match="out of range"):
        to_target(millimetres, LEAD, 1e9)  # beyond the coordinate register's int32


def test_velocities_convert_to_the_jog_rpm(rig: Rig) -> None:
    device = rig.device
    # 5 mm/s on a 5 mm lead: one motor revolution a second.
    assert to_rpm(device, 1, JointScale("prismatic", 1000.0), LEAD, 0.005) == 60.0
    # No reduction: rad/s of the motor shaft.
    assert to_rpm(device, 1, JointScale("revolute"), LEAD, 2 * math.pi) == 60.0
    # 50 units per joint revolution on a 5-unit lead: 10 motor revolutions per joint one.
    assert to_rpm(device, 1, JointScale("revolute", 1000.0, 50.0), LEAD, -2 * math.pi) == -600.0
    with pytest.raises(CommandRejected):
        to_rpm(device, 1, JointScale("prismatic", 1000.0), LEAD, 100.0)  # 1.2e6 rpm
    with pytest.raises(CommandRejected, match="lead is 0"):
        to_rpm(device, 1, JointScale("prismatic", 1000.0), 0.0, 0.001)


def test_a_target_moves_at_the_configured_speed(rig: Rig) -> None:
    start = time.monotonic()
    rig.targets.guard.command(2, 10.0)
    rig.wait_standing_at(2, 10.0)
    assert time.monotonic() - start >= 10.0 / SPEED_UNITS_S * 0.9
