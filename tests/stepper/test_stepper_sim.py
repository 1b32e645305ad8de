"""The stepper device layer against the stepper simulator over a real socat pty pair (no ROS).

115200 baud and no reply delay, except where the 35 ms delay is the point.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import serial
from pymodbus.framer import FramerRTU

from bridge_core.runtime.goals import Outcome, Verdict
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel, Priority
from bridge_core.wire.errors import CommandRejected, DeviceException, LinkError, NotConfirmed
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings
from stepper_bridge.device import StepperDevice
from stepper_bridge.interpolation import pair_axes
from stepper_bridge.motions import HomeMotion, InterpolationMotion, StepperMotion
from stepper_bridge.registers import STEPPER_MAP, UNDEFINED_HOLDING, holding, motor_coil
from stepper_bridge.sim import START_POSITION, StepperSimDevice, make_simulator
from stepper_bridge.units import JointScale

from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, socat_pair

BAUD = 115200


class Rig:
    """Simulator on one end of a pty pair, a device layer on the other."""

    def __init__(self, sim: Simulator, bridge_end: str, device_end: str) -> None:
        self.sim = sim
        sim_device = sim.device
        assert isinstance(sim_device, StepperSimDevice)
        self.fake = sim_device
        self.device_end = device_end
        # A pty may stall for seconds beside CPU burners: not what these tests are about.
        self.link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        self.channel = DeviceChannel(self.link, 1, retries=0)
        self.device = StepperDevice(self.channel)

    def writes(self) -> list[tuple[int, Table, int, tuple[int, ...]]]:
        return [(r.function_code, r.table, r.address, r.values) for r in self.fake.write_log]

    def raw(self, frame_without_crc: bytes, reply_length: int) -> bytes:
        """Send a raw frame (CRC added) through the bridge's end and return the reply."""
        self.link.close()
        frame = frame_without_crc + FramerRTU.compute_CRC(frame_without_crc).to_bytes(2, "big")
        with serial.Serial(self.link.settings.port, BAUD, timeout=1.0) as port:
            port.write(frame)
            head = bytes(port.read(5))
            if len(head) < 5 or head[1] & 0x80:
                return head  # an exception reply is 5 bytes long
            return head + bytes(port.read(reply_length - 5))


@pytest.fixture
def rig() -> Iterator[Rig]:
    sim = make_simulator(reply_delay_s=0.0, travel=80.0)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        r = Rig(sim, bridge_end, device_end)
        try:
            yield r
        finally:
            r.link.close()
            sim.stop()


def wait_until(predicate: Callable[[], Any], timeout: float = 30.0) -> Any:
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.02)
    return value


def idle(rig: Rig) -> bool:
    return not any(rig.device.poll().running)


def test_poll_reads_status_and_configuration(rig: Rig) -> None:
    rig.fake.set_input(7, True)
    rig.device.set_output(3, True)
    s = rig.device.poll()
    assert s.coordinates == (0.0,) * 5 and s.running == (False,) * 5
    assert s.inputs[6] and sum(s.inputs) == 1
    assert s.outputs[2] and sum(s.outputs) == 1
    m1 = s.config.motors[0]
    assert (m1.step_angle_deg, m1.microstep, m1.speed_rpm, m1.lead) == (1.8, 8, 60, 5.0)
    assert (m1.positive_limit_input, m1.negative_limit_input, m1.home_input) == (1, 2, 2)
    assert s.config.system_mode == 0 and s.config.homing_order == (0,) * 5


def test_a_poll_reads_the_running_flags_before_the_coordinates(rig: Rig) -> None:
    """A coordinate read after a flag that says "stands" is where the motor stopped; read
    the other way round, a motor that stops between the two reads is reported standing
    at a coordinate from before its last step (seen as REACHED at 19.99 for 20)."""
    rig.device.poll()  # the configuration is read whole first
    rig.fake.log_reads = True
    rig.device.poll()
    rig.fake.log_reads = False
    status = [r for r in rig.fake.read_log if r.table is Table.HOLDING]
    running = next(i for i, r in enumerate(status) if r.covers(Table.HOLDING, holding(40168)))
    coordinates = next(i for i, r in enumerate(status) if r.covers(Table.HOLDING, holding(40108)))
    assert running < coordinates


def test_move_by_covers_the_distance_both_ways(rig: Rig) -> None:
    rig.device.set_speed(3, 600)  # 600 rpm x 5.00 per rev = 50 units/s
    rig.device.move_by(3, 12.34)
    wait_until(lambda: idle(rig))
    assert rig.device.poll().coordinates[2] == pytest.approx(12.34)
    rig.device.move_by(3, -2.0)
    wait_until(lambda: idle(rig))
    assert rig.device.poll().coordinates[2] == pytest.approx(10.34)
    s = rig.device.poll()
    assert s.config.motors[2].direction == 1 and s.config.motors[2].run_distance == 2.0


def test_jog_runs_at_the_speed_and_stops(rig: Rig) -> None:
    d = rig.device
    assert d.jog(1, 600.0)
    wait_until(lambda: rig.device.poll().coordinates[0] > 5.0)
    assert not d.jog(1, 600.0)  # unchanged: nothing written
    assert d.jog(1, 300.0)  # speed only, while running
    assert d.jog(1, -300.0)  # reversal: stop, then reverse
    assert d.jog(1, 0.0)
    wait_until(lambda: idle(rig))
    assert rig.writes() == [
        (6, Table.HOLDING, 5, (600,)),
        (5, Table.COIL, 1, (1,)),
        (6, Table.HOLDING, 5, (300,)),
        (5, Table.COIL, 4, (1,)),
        (5, Table.COIL, 2, (1,)),
        (5, Table.COIL, 4, (1,)),
        (6, Table.HOLDING, 5, (60,)),  # after the stop: the configured speed back
    ]
    assert rig.fake.get("motor1_speed") == 60


H, C = Table.HOLDING, Table.COIL
SPEED_1 = (6, H, 5, (60,))  # motor 1's configured speed (the simulator's 60 rpm) back


def speed_at_single_run(rig: Rig, motor: int) -> list[int]:
    """The motor's speed register each time its single-run coil is written (the speed the
    simulator runs the move at)."""
    seen: list[int] = []
    run_once = (C, (motor - 1) * 5)

    def hook(record: Any) -> None:
        if (record.table, record.address) == run_once:
            seen.append(int(rig.fake.get(f"motor{motor}_speed")))

    rig.fake.write_hooks.append(hook)
    return seen


def test_every_end_of_a_jog_gives_the_configured_speed_back(rig: Rig) -> None:
    d = rig.device
    d.read_config()
    ends: list[tuple[str, Callable[[], object]]] = [
        ("a 0", lambda: d.jog(1, 0.0)),
        ("the stop service", lambda: d.motor_action(1, "stop")),
        ("the e-stop", lambda: d.system_command("emergency_stop")),
        ("the deadman / shutdown", lambda: d.jogs.stop_all()),
        ("the deadman", lambda: d.jogs.expire(1)),
    ]
    for what, end in ends:
        d.jog(1, 0.0)  # releases a lock left by the previous stop
        before = len(rig.fake.write_log)
        assert d.jog(1, 300.0)
        end()
        late = rig.writes()[before:]
        assert late[0] == (6, H, 5, (300,)), what
        assert late[-2:] == [(5, C, 4, (1,)), SPEED_1] or late[-2:] == [(5, C, 41, (1,)), SPEED_1]
        assert rig.fake.get("motor1_speed") == 60 and not d.restore_pending(), what
        assert d.poll().config.motors[0].speed_rpm == 60, what


def test_a_move_by_after_a_jog_runs_at_the_configured_speed(rig: Rig) -> None:
    d = rig.device
    d.read_config()
    seen = speed_at_single_run(rig, 1)
    d.jog(1, 600.0)
    d.jog(1, 0.0)
    d.move_by(1, 1.0)
    assert seen == [60]
    # A move_by while the jog runs takes the motor over: the speed goes back first.
    wait_until(lambda: idle(rig))
    d.jog(1, 600.0)
    before = len(rig.fake.write_log)
    d.move_by(1, 1.0)
    assert rig.writes()[before:] == [
        (6, H, 4, (0,)),
        (16, H, 8, (100, 0)),
        SPEED_1,
        (5, C, 0, (1,)),
    ]
    assert seen == [60, 60] and not d.restore_pending()


def test_stop_all_stops_every_jog_before_any_restore(rig: Rig) -> None:
    d = rig.device
    d.read_config()
    d.jog(1, 300.0)
    d.jog(2, -300.0)
    before = len(rig.fake.write_log)
    assert d.jogs.stop_all() == []
    assert rig.writes()[before:] == [(5, C, 4, (1,)), (5, C, 9, (1,)), SPEED_1, (6, H, 15, (60,))]


def test_a_jog_that_keeps_the_speed_restores_nothing(rig: Rig) -> None:
    d = rig.device
    d.read_config()
    d.jog(1, 60.0)  # the configured speed: only the forward coil
    d.jog(1, 0.0)
    assert rig.writes() == [(5, C, 1, (1,)), (5, C, 4, (1,))]


def test_a_speed_configured_during_a_jog_is_the_one_restored(rig: Rig) -> None:
    d = rig.device
    d.read_config()
    d.jog(1, 300.0)
    d.set_speed(1, 120)  # the user's new configured speed (also the running jog's now)
    d.jog(1, 0.0)
    assert rig.writes()[-2:] == [(5, C, 4, (1,)), (6, H, 5, (120,))]


def test_save_parameters_is_refused_while_a_jog_speed_is_in_the_register(rig: Rig) -> None:
    d = rig.device
    d.read_config()
    d.jog(1, 300.0)
    before = len(rig.fake.write_log)
    with pytest.raises(CommandRejected, match="stop the jog before save_parameters"):
        d.system_command("save_parameters")
    assert len(rig.fake.write_log) == before and rig.fake.saves == 0
    d.jog(1, 0.0)
    d.system_command("save_parameters")
    assert rig.fake.saves == 1 and rig.fake.get("motor1_speed") == 60


def test_a_failed_restore_never_fails_the_stop_and_is_retried(rig: Rig) -> None:
    d = rig.device
    d.read_config()
    reported: list[tuple[int, int]] = []
    d.on_speed_restore_failure = lambda motor, rpm, _err: reported.append((motor, rpm))
    refused = (6, H, 5, (60,))
    rig.fake.write_guards.append(
        lambda r: 0x04 if (r.function_code, r.table, r.address, r.values) == refused else None
    )
    d.jog(1, 300.0)
    assert d.jog(1, 0.0)  # the stop went out: no exception
    assert rig.fake.motion[1] is None and rig.fake.get("motor1_speed") == 300
    assert reported == [(1, 60)] and "60 rpm not restored" in d.speed_restore_failures[1]
    # Still refused: a move_by fails before its single run (it would run at 300 rpm).
    before = len(rig.fake.write_log)
    with pytest.raises(LinkError):
        d.move_by(1, 1.0)
    assert (5, C, 0, (1,)) not in rig.writes()[before:]
    rig.fake.write_guards.clear()
    seen = speed_at_single_run(rig, 1)
    d.move_by(1, 1.0)
    assert seen == [60] and not d.speed_restore_failures and not d.restore_pending()


def test_homing_limits_and_zero(rig: Rig) -> None:
    d, fake = rig.device, rig.fake
    d.set_speed(2, 1200)  # 100 units/s
    d.motor_action(2, "forward")
    # travel 80: the positive limit (input 3) stops it 30 units from the start.
    wait_until(lambda: idle(rig))
    s = d.poll()
    assert s.coordinates[1] == pytest.approx(80.0 - START_POSITION) and s.inputs[2]
    d.motor_action(2, "home")
    wait_until(lambda: idle(rig))
    s = d.poll()
    # Home switch (input 4) at physical 0: coordinate 0 there.
    assert s.coordinates[1] == 0.0 and s.inputs[3] and fake.position[2] == 0.0
    # The negative limit is on: it does not move. The reply is "not confirmed" unless the
    # read-back caught the running flag of the simulator's one tick before the limit
    # ended the motion.
    with contextlib.suppress(NotConfirmed):
        d.motor_action(2, "reverse")
    # The simulator's next tick ended the motion on the limit (a run that ignored the
    # limit would never end); nothing moved on the way.
    wait_until(lambda: fake.motion[2] is None)
    assert idle(rig) and fake.position[2] == 0.0
    d.move_by(2, 7.5)
    wait_until(lambda: idle(rig))
    d.system_command("zero_coordinates")
    assert d.poll().coordinates[1] == 0.0
    d.move_by(2, 2.0)
    wait_until(lambda: idle(rig))
    d.system_command("return_to_zero")
    wait_until(lambda: idle(rig))
    assert d.poll().coordinates[1] == 0.0 and fake.position[2] == pytest.approx(7.5)


def test_home_all_in_order(rig: Rig) -> None:
    d, fake = rig.device, rig.fake
    for motor in (1, 4, 5):
        d.set_speed(motor, 3000)
    d.set_homing_order([4, 1])
    d.system_command("home_all")
    wait_until(lambda: fake.motion[4] is None and fake.motion[1] is None and not fake.homing_queue)
    assert fake.position[4] == 0.0 and fake.position[1] == 0.0
    assert fake.position[5] == START_POSITION  # not in the order: not homed


def test_emergency_stop_stops_everything_and_locks_jog(rig: Rig) -> None:
    d = rig.device
    d.set_all_outputs(True)
    d.jog(1, 60.0)
    d.motor_action(2, "forward")
    assert all(d.poll().outputs) and d.poll().running[:2] == (True, True)
    d.system_command("emergency_stop")
    s = d.poll()
    assert not any(s.running) and not any(s.outputs)
    with pytest.raises(CommandRejected, match="send a 0 jog"):
        d.jog(1, 60.0)
    d.jog(1, 0.0)  # releases the lock
    d.jog(1, 60.0)
    assert d.poll().running[0]


def test_outputs_and_inputs(rig: Rig) -> None:
    d = rig.device
    d.set_output(5, True)
    d.set_output(12, True)
    d.set_output(5, False)
    assert [k + 1 for k, on in enumerate(d.poll().outputs) if on] == [12]
    d.set_all_outputs(False)
    assert not any(d.poll().outputs)
    rig.fake.set_input(13, True)
    assert d.poll().inputs[12]


def test_line_and_arc_interpolation(rig: Rig) -> None:
    d, fake = rig.device, rig.fake
    d.pair_reading = "type_rows"  # the simulator's (pair 3 below)
    for motor in (1, 2, 3):
        d.set_speed(motor, 1200)
    d.line_move(1, (5.0, 10.0), (15.0, 20.0), 1200)
    wait_until(lambda: fake.interpolation is None and idle(rig))
    assert d.poll().coordinates[:2] == (15.0, 20.0)
    # Quarter circle around (5, 20) from (15, 20) to (5, 30), counter-clockwise.
    d.arc_move(1, 0, (15.0, 20.0), (5.0, 30.0), (5.0, 20.0), (0.0, 0.0), True, 1200)
    assert fake.interpolation is not None and fake.interpolation.sweep == pytest.approx(math.pi / 2)
    wait_until(lambda: fake.interpolation is None)
    assert d.poll().coordinates[:2] == (5.0, 30.0)
    # Three points on motors 2 and 3; stop_interpolation ends it early.
    d.set_speed(3, 60)
    d.arc_move(3, 1, (30.0, 0.0), (30.0, 20.0), (0.0, 0.0), (40.0, 10.0), False, 60)
    wait_until(lambda: fake.interpolation is not None)
    d.stop_interpolation()
    assert fake.interpolation is None
    # The interpolation stops, then the own stop of every motor either reading of pair 3
    # names.
    assert rig.writes()[-5:] == [
        (5, Table.COIL, 100, (1,)),
        (5, Table.COIL, 102, (1,)),
        *((5, Table.COIL, motor_coil(m, "stop"), (1,)) for m in (1, 2, 3)),
    ]


def test_factory_reset_and_clear_need_their_name(rig: Rig) -> None:
    d = rig.device
    d.configure(
        1,
        step_angle_deg=0.9,
        microstep=16,
        start_frequency_hz=100,
        accel_frequency_hz=100,
        speed_rpm=10,
        lead=2.0,
    )
    for name in ("factory_reset", "clear_all_parameters"):
        for wrong in ("", "yes", "FACTORY_RESET", "clear_all"):
            with pytest.raises(CommandRejected, match="confirm"):
                d.destructive_command(name, wrong)
    writes = len(rig.fake.write_log)
    d.destructive_command("factory_reset", "factory_reset")
    assert d.read_config().motors[0].step_angle_deg == 1.8
    d.destructive_command("clear_all_parameters", "clear_all_parameters")
    config = d.read_config()
    assert config.motors[0].lead == 0.0 and config.motors[0].home_input == 0
    assert d.read_named("device_id", "baud_rate") == {"device_id": 1, "baud_rate": 9600}
    assert len(rig.fake.write_log) == writes + 2


def test_link_settings_round_trips_and_interpolation_are_read_back(rig: Rig) -> None:
    """40212-40214, 40301-40305 and 40182-40211 come with the configuration."""
    d, fake = rig.device, rig.fake
    fake.set("baud_rate", 19200)
    fake.set("motor3_reciprocations", 7)
    config = d.read_config()
    assert (config.device_id, config.baud_rate) == (1, 19200)
    assert [m.reciprocations for m in config.motors] == [0, 0, 7, 0, 0]
    assert config.interpolation.line_pair == 0 and config.interpolation.arc_pair == 0
    d.set_speed(1, 1200)
    d.set_speed(2, 1200)
    d.line_move(1, (1.0, 2.0), (3.5, -4.25), 900)
    d.stop_interpolation()
    d.arc_move(1, 1, (0.0, 0.0), (2.0, 0.0), (0.0, 0.0), (1.0, 1.0), True, 30)
    d.stop_interpolation()
    d.invalidate_config()  # read from the device, not the cache the writes updated
    i = d.read_config().interpolation
    assert (i.line_pair, i.line_start, i.line_end, i.line_speed_rpm) == (
        1,
        (1.0, 2.0),
        (3.5, -4.25),
        900,
    )
    assert (i.arc_pair, i.arc_mode, i.arc_via, i.arc_counterclockwise, i.arc_speed_rpm) == (
        1,
        1,
        (1.0, 1.0),
        True,
        30,
    )


def test_standalone_setters_write_one_register_each(rig: Rig) -> None:
    """Speed, direction, run distance, mode-1 round trips on their own."""
    d = rig.device
    d.set_speed(2, 300)
    d.set_direction(2, 1)
    d.set_run_distance(2, 12.5)
    d.set_round_trips(4, 3)
    H = Table.HOLDING  # noqa: N806
    assert rig.writes() == [
        (6, H, 15, (300,)),  # 40016
        (6, H, 14, (1,)),  # 40015
        (16, H, 18, (1250, 0)),  # 40019-40020, low word first
        (6, H, 303, (3,)),  # 40304
    ]
    m2 = d.read_config().motors[1]
    assert (m2.speed_rpm, m2.direction, m2.run_distance) == (300, 1, 12.5)
    assert d.read_config().motors[3].reciprocations == 3


def test_a_second_interpolation_is_refused_while_one_runs(rig: Rig) -> None:
    """The manual's "插补过程运行中不可调节": the bridge refuses a second line / arc, nothing
    written, until a poll begun after the start shows the motors stopped (or a stop)."""
    d, fake = rig.device, rig.fake
    d.pair_reading = "type_rows"  # pair 3 below: refused for this reason, not the reading
    d.line_move(1, (0.0, 0.0), (40.0, 40.0), 1)  # the approach and path take long
    assert fake.interpolation is not None and d.interpolation_run is not None
    writes = len(fake.write_log)
    arc: tuple[Any, ...] = (1, 0, (0.0, 0.0), (2.0, 0.0), (1.0, 0.0), (0.0, 0.0), False, 60)
    seconds: list[Callable[[], object]] = [
        lambda: d.line_move(1, (0.0, 0.0), (1.0, 1.0), 60),
        lambda: d.line_move(3, (0.0, 0.0), (1.0, 1.0), 60),
        lambda: d.arc_move(*arc),
    ]
    for second in seconds:
        with pytest.raises(CommandRejected, match="插补过程运行中不可调节"):
            second()
        d.poll()  # still running: still refused
    assert len(fake.write_log) == writes
    d.stop_interpolation()
    assert d.interpolation_run is None
    d.arc_move(*arc)
    assert fake.interpolation is not None and fake.interpolation.kind == "arc"
    # Ended behind the bridge's back (another master's stop): the next poll clears it.
    rig.channel.write_coil(STEPPER_MAP["arc_stop"].address, True)
    d.poll()
    assert d.interpolation_run is None
    d.line_move(1, (0.0, 0.0), (1.0, 1.0), 60)


def test_the_simulator_refuses_interpolation_writes_while_one_runs(rig: Rig) -> None:
    """Stepper decision 14 (docs/decisions/stepper.md): while one runs, 40182-40211 and the
    start coils answer ILLEGAL DATA VALUE and change nothing; the stop coils still work."""
    d, fake = rig.device, rig.fake
    d.line_move(1, (0.0, 0.0), (40.0, 40.0), 1)
    blind = StepperDevice(rig.channel)  # a second master: it knows of no running move
    before = fake.get_words(Table.HOLDING, STEPPER_MAP["arc_pair"].address, 30)
    with pytest.raises(DeviceException) as refused:
        blind.line_move(1, (0.0, 0.0), (1.0, 1.0), 60)
    assert refused.value.exception_code == 0x03
    blind.set_speed(3, 10)  # outside 40182-40211: accepted
    with pytest.raises(DeviceException) as refused:
        rig.channel.write_register(STEPPER_MAP["arc_speed"].address, 10)
    assert refused.value.exception_code == 0x03
    for start in ("arc_start", "line_start"):
        with pytest.raises(DeviceException):
            rig.channel.write_coil(STEPPER_MAP[start].address, True)
    assert fake.get_words(Table.HOLDING, STEPPER_MAP["arc_pair"].address, 30) == before
    assert fake.interpolation is not None and fake.interpolation.end == (40.0, 40.0)
    blind.stop_interpolation()
    assert fake.interpolation is None
    blind.line_move(1, (0.0, 0.0), (1.0, 1.0), 60)  # accepted again


def test_clear_all_resets_device_id_and_baud_rate() -> None:
    """Stepper decision 15 (docs/decisions/stepper.md): clear-all ("清零所有参数") leaves id 1
    and 9600 baud (the factory values; 0 is in neither range): a controller at unit 5
    answers unit 1 after it."""
    sim = make_simulator(unit_id=5, reply_delay_s=0.0)
    fake = sim.device
    assert isinstance(fake, StepperSimDevice)
    fake.set("baud_rate", 19200)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=0.3))
        try:
            at_5 = StepperDevice(DeviceChannel(link, 5, retries=0))
            assert at_5.read_named("device_id", "baud_rate") == {
                "device_id": 5,
                "baud_rate": 19200,
            }
            # Unit 5 is gone at once: not even the coil's reply comes back.
            with pytest.raises(LinkError):
                at_5.destructive_command("clear_all_parameters", "clear_all_parameters")
            with pytest.raises(LinkError):
                at_5.read_named("device_id")
            at_1 = StepperDevice(DeviceChannel(link, 1, retries=0))
            assert at_1.read_named("device_id", "baud_rate") == {
                "device_id": 1,
                "baud_rate": 9600,
            }
            assert at_1.read_config().motors[0].lead == 0.0  # the rest is zeroed
        finally:
            link.close()
            sim.stop()


REFUSED: list[tuple[str, Callable[[StepperDevice], object]]] = [
    ("motor 0", lambda d: d.motor_action(0, "forward")),
    ("motor 6", lambda d: d.move_by(6, 1.0)),
    ("action", lambda d: d.motor_action(1, "spin")),
    ("nan distance", lambda d: d.move_by(1, math.nan)),
    ("tiny distance", lambda d: d.move_by(1, 0.004)),
    ("huge distance", lambda d: d.move_by(1, 5e7)),
    ("jog inf", lambda d: d.jog(1, math.inf)),
    ("jog too fast", lambda d: d.jog(1, 70000.0)),
    (
        "step angle 0",
        lambda d: d.configure(
            1,
            step_angle_deg=0.0,
            microstep=8,
            start_frequency_hz=1,
            accel_frequency_hz=1,
            speed_rpm=1,
            lead=1.0,
        ),
    ),
    (
        "microstep 0",
        lambda d: d.configure(
            1,
            step_angle_deg=1.8,
            microstep=0,
            start_frequency_hz=1,
            accel_frequency_hz=1,
            speed_rpm=1,
            lead=1.0,
        ),
    ),
    (
        "lead nan",
        lambda d: d.configure(
            1,
            step_angle_deg=1.8,
            microstep=8,
            start_frequency_hz=1,
            accel_frequency_hz=1,
            speed_rpm=1,
            lead=math.nan,
        ),
    ),
    ("speed 70000", lambda d: d.set_speed(1, 70000)),
    ("speed 1.5", lambda d: d.set_speed(1, 1.5)),  # type: ignore[arg-type]
    ("direction 2", lambda d: d.set_direction(1, 2)),
    ("direction motor 6", lambda d: d.set_direction(6, 0)),
    ("run distance -1", lambda d: d.set_run_distance(1, -1.0)),
    ("run distance nan", lambda d: d.set_run_distance(1, math.nan)),
    ("round trips -1", lambda d: d.set_round_trips(1, -1)),
    ("round trips 65536", lambda d: d.set_round_trips(5, 65536)),
    ("round trips motor 0", lambda d: d.set_round_trips(0, 1)),
    ("output 0", lambda d: d.set_output(0, True)),
    ("output 13", lambda d: d.set_output(13, True)),
    ("limit input 14", lambda d: d.set_limit_inputs(1, 1, 14, 2)),
    ("homing twice", lambda d: d.set_homing_order([1, 1])),
    ("homing motor 6", lambda d: d.set_homing_order([6])),
    ("system mode 6", lambda d: d.set_system_mode(6)),
    ("pair 0", lambda d: d.line_move(0, (0.0, 0.0), (1.0, 1.0), 60)),
    ("pair 4", lambda d: d.line_move(4, (0.0, 0.0), (1.0, 1.0), 60)),
    ("line speed 0", lambda d: d.line_move(1, (0.0, 0.0), (1.0, 1.0), 0)),
    ("line zero length", lambda d: d.line_move(1, (1.0, 1.0), (1.0, 1.0), 60)),
    (
        "arc same points",
        lambda d: d.arc_move(1, 0, (0.0, 0.0), (1.0, 0.0), (0.0, 0.0), (0.0, 0.0), False, 60),
    ),
    (
        "arc collinear",
        lambda d: d.arc_move(2, 1, (0.0, 0.0), (2.0, 0.0), (0.0, 5.0), (1.0, 0.0), False, 60),
    ),
    (
        "arc mode 2",
        lambda d: d.arc_move(1, 2, (0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.0, 1.0), False, 60),
    ),
    ("destructive", lambda d: d.destructive_command("factory_reset", "no")),
    ("system", lambda d: d.system_command("self_destruct")),
]


@pytest.mark.parametrize("check", [pytest.param(c, id=name) for name, c in REFUSED])
def test_refusals_write_nothing(rig: Rig, check: Callable[[StepperDevice], object]) -> None:
    rig.device.read_config()
    with pytest.raises(CommandRejected):
        check(rig.device)
    assert rig.fake.write_log == []


def test_reply_delay_is_kept() -> None:
    sim = make_simulator(reply_delay_s=0.035)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        try:
            channel = DeviceChannel(link, 1, retries=0)
            device = StepperDevice(channel)
            device.poll()
            device.motor_action(1, "stop")
            assert min(channel.stats.latencies_s) >= 0.035
        finally:
            link.close()
            sim.stop()


# ---------------------------------------------------------------- what the simulator refuses


def exception_of(reply: bytes, function: int) -> int:
    assert len(reply) == 5, reply.hex(" ")
    assert FramerRTU.check_CRC(reply[:3], int.from_bytes(reply[3:], "big"))
    assert reply[1] == function | 0x80, reply.hex(" ")
    return reply[2]


@pytest.mark.parametrize(
    ("function", "body"),
    [
        (0x01, "00 00 00 08"),  # read coils: the device has no coil read
        (0x02, "00 00 00 08"),
        (0x04, "00 00 00 02"),
        (0x0F, "00 00 00 02 01 03"),
    ],
)
def test_function_codes_the_device_lacks(rig: Rig, function: int, body: str) -> None:
    reply = rig.raw(bytes([1, function]) + bytes.fromhex(body), 5)
    assert exception_of(reply, function) == 0x01


def test_illegal_addresses_and_values(rig: Rig) -> None:
    def read(address: int, count: int) -> bytes:
        request = bytes([1, 3]) + address.to_bytes(2, "big") + count.to_bytes(2, "big")
        return rig.raw(request, 5 + 2 * count)

    assert len(read(1, 49)) == 5 + 98  # 49 registers: fine
    assert exception_of(read(0, 50)[:5], 3) == 0x02  # "<50"
    for first, last in UNDEFINED_HOLDING:
        assert exception_of(read(holding(first), 1)[:5], 3) == 0x02, first
        assert exception_of(read(holding(first) - 1, last - first + 2)[:5], 3) == 0x02, first
    assert exception_of(read(107, 1)[:5], 3) == 0x02  # half a coordinate
    # A read that cuts a 32-bit value is still refused (the run distance at 8-9, read 9-10).
    assert exception_of(read(9, 2)[:5], 3) == 0x02
    # 50 registers in one write: refused.
    fifty = bytes([1, 0x10, 0, 0, 0, 50, 100]) + bytes(100)
    assert exception_of(rig.raw(fifty, 8)[:5], 0x10) == 0x02
    # Values outside the manual's ranges: ILLEGAL DATA VALUE.
    for address, value in (
        (STEPPER_MAP["motor1_direction"].address, 2),
        (STEPPER_MAP["motor2_home_input"].address, 14),
        (STEPPER_MAP["homing_order_1"].address, 6),
        (STEPPER_MAP["system_mode"].address, 6),
        (STEPPER_MAP["device_id"].address, 0),
    ):
        request = bytes([1, 6]) + address.to_bytes(2, "big") + value.to_bytes(2, "big")
        assert exception_of(rig.raw(request, 8)[:5], 6) == 0x03, address
    # 0 microsteps: the manual states no range; the non-zero minimum is the bridge's own.
    zero = bytes([1, 6]) + STEPPER_MAP["motor1_microstep"].address.to_bytes(2, "big") + bytes(2)
    assert rig.raw(zero, 8)[:6] == zero
    rig.fake.write_log.clear()
    baud = bytes.fromhex("01 10 00 D4 00 02 04 E1 00 00 01")  # 57600: not a listed rate
    assert exception_of(rig.raw(baud, 8)[:5], 0x10) == 0x03
    assert rig.fake.write_log == []


def test_the_manuals_own_fc10_example_is_answered_as_the_manual_shows(rig: Rig) -> None:
    """§6(3): `01 10 00 09 00 02 04 00 C8 00 00` is answered `01 10 00 09 00 02 91 CA`. It
    cuts two values under the table's reading (decision 2): the device stores the words
    where they land (motor 1's run distance high word, motor 2's step angle)."""
    example = bytes.fromhex("01 10 00 09 00 02 04 00 C8 00 00")
    reply = rig.raw(example, 8)
    assert reply == bytes.fromhex("01 10 00 09 00 02 91 CA")
    assert rig.fake.get_words(Table.HOLDING, 9, 2) == [0x00C8, 0x0000]
    assert [(r.address, r.values) for r in rig.fake.write_log] == [(9, (0x00C8, 0x0000))]


def test_joint_scale() -> None:
    mm = JointScale("prismatic", 1000.0)
    assert mm.to_si(250.0, 5.0) == pytest.approx(0.25)
    assert mm.to_units(-0.0125, 5.0) == pytest.approx(-12.5)
    rev = JointScale("revolute")
    assert rev.to_si(7.5, 5.0) == pytest.approx(3 * math.pi)  # 1.5 turns
    assert rev.to_units(math.pi, 360.0) == pytest.approx(180.0)
    assert math.isnan(rev.to_si(1.0, 0.0))
    with pytest.raises(CommandRejected):
        rev.to_units(1.0, 0.0)
    with pytest.raises(ValueError):
        JointScale("helical")


def test_joint_scale_with_a_reduction() -> None:
    """units_per_revolution: user units per joint revolution (lead 5 per motor turn, 1:10)."""
    geared = JointScale("revolute", units_per_revolution=50.0)
    assert geared.to_si(25.0, 5.0) == pytest.approx(math.pi)
    assert geared.to_units(math.pi, 5.0) == pytest.approx(25.0)
    assert geared.to_si(25.0, 0.0) == pytest.approx(math.pi)  # the lead is not used
    assert not geared.needs_lead() and JointScale("revolute").needs_lead()
    assert JointScale("revolute", units_per_revolution=0.0).to_si(2.5, 5.0) == pytest.approx(
        math.pi
    )  # 0: the lead, as before
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="units_per_revolution"):
            JointScale("revolute", units_per_revolution=bad)


class PriorityRecorder:
    """The rig's channel, with the priority of every coil write recorded."""

    def __init__(self, channel: DeviceChannel) -> None:
        self.channel = channel
        self.coils: list[tuple[int, Priority]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.channel, name)

    def write_coil(self, address: int, on: bool, priority: Priority = Priority.COMMAND) -> None:
        self.coils.append((address, priority))
        self.channel.write_coil(address, on, priority)


def test_stops_go_at_stop_priority(rig: Rig) -> None:
    """On a shared line every stop coil goes in the next free slot
    (Priority.STOP), before other controllers' commands and polls; motions do not."""
    io = PriorityRecorder(rig.channel)
    d = StepperDevice(io)
    d.poll()
    d.motor_action(1, "forward")
    d.motor_action(1, "stop")
    d.jog(2, 60.0)
    d.jog_stop(2)
    d.line_move(1, (1.0, 1.0), (2.0, 2.0), 60)
    d.stop_interpolation()
    d.system_command("emergency_stop")
    stop, command = Priority.STOP, Priority.COMMAND
    assert io.coils == [
        (motor_coil(1, "forward"), command),
        (motor_coil(1, "stop"), stop),
        (motor_coil(2, "forward"), command),
        (motor_coil(2, "stop"), stop),
        (STEPPER_MAP["line_start"].address, command),
        (STEPPER_MAP["arc_stop"].address, stop),
        (STEPPER_MAP["line_stop"].address, stop),
        (motor_coil(1, "stop"), stop),  # the pair's own stops
        (motor_coil(2, "stop"), stop),
        (STEPPER_MAP["emergency_stop"].address, stop),
    ]


def test_pairs_2_and_3_are_refused_until_the_reading_is_set() -> None:
    """Pairs 2 and 3 are motors 1+3 / 2+3 by the manual's type rows and 2+3 /
    1+3 by its point rows; pair 1 is 1+2 either way."""
    for reading in ("unset", "type_rows", "point_rows"):
        assert pair_axes(1, reading) == (1, 2)
    assert (pair_axes(2, "type_rows"), pair_axes(3, "type_rows")) == ((1, 3), (2, 3))
    assert (pair_axes(2, "point_rows"), pair_axes(3, "point_rows")) == ((2, 3), (1, 3))
    for pair in (2, 3):
        with pytest.raises(CommandRejected, match="interpolation_pair_reading") as refused:
            pair_axes(pair, "unset")
        assert "\n" not in str(refused.value) and "docs/decisions/stepper.md" in str(refused.value)
    with pytest.raises(CommandRejected, match="pair 4"):
        pair_axes(4, "type_rows")


def test_pairs_2_and_3_write_nothing_while_the_reading_is_unset(rig: Rig) -> None:
    d = rig.device
    d.set_speed(1, 600)
    mark = len(rig.writes())
    for pair in (2, 3):
        with pytest.raises(CommandRejected, match="interpolation_pair_reading"):
            d.line_move(pair, (1.0, 1.0), (2.0, 2.0), 60)
        with pytest.raises(CommandRejected, match="interpolation_pair_reading"):
            d.arc_move(pair, 0, (1.0, 0.0), (0.0, 1.0), (0.0, 0.0), (0.0, 0.0), True, 60)
    assert rig.writes()[mark:] == []
    d.line_move(1, (1.0, 1.0), (2.0, 2.0), 60)  # pair 1: the same under both readings


def follow(rig: Rig, motion: StepperMotion) -> Verdict:
    """Start ``motion`` and judge every poll after it, as the node's goal thread does."""
    motion.start()
    return follow_started(rig, motion)


def follow_started(rig: Rig, motion: StepperMotion) -> Verdict:
    started = time.monotonic()
    while True:
        snapshot = rig.device.poll()
        verdict = motion.judge(snapshot, time.monotonic() - started)
        if verdict is not None:
            return verdict
        assert time.monotonic() - started < 30.0, "the motion never ended"
        time.sleep(0.02)


def line_goal(rig: Rig, pair: int) -> InterpolationMotion:
    d = rig.device
    start, end = (5.0, 4.0), (9.0, 12.0)
    return InterpolationMotion(
        d,
        [JointScale()] * 5,
        pair,
        end,
        f"line_move pair {pair}",
        lambda: d.line_move(pair, start, end, 1200),
        tolerance=0.01,
    )


@pytest.mark.parametrize("reading", ["type_rows", "point_rows"])
def test_a_line_on_other_motors_than_the_configured_reading_is_stopped(
    rig: Rig, reading: str
) -> None:
    """A controller that follows the other reading moves a motor outside the
    configured pair; the goal ends HALTED (its stop sent) naming it, not REACHED."""
    d, fake = rig.device, rig.fake
    for motor in (1, 2, 3):
        d.set_speed(motor, 1200)
    d.pair_reading = reading
    fake.pair_reading = "point_rows" if reading == "type_rows" else "type_rows"
    motion = line_goal(rig, 2)
    wrong = 2 if reading == "type_rows" else 1  # the first motor of the other reading
    verdict = follow(rig, motion)
    assert verdict.outcome is Outcome.HALTED, verdict.message
    assert f"motor {wrong} 0 ->" in verdict.message and reading in verdict.message
    motion.stop()  # what the node's goal thread sends for a HALTED verdict
    assert fake.interpolation is None
    # The interpolation stops, then the stop of every motor either reading names.
    assert rig.writes()[-5:] == [
        (5, Table.COIL, 100, (1,)),
        (5, Table.COIL, 102, (1,)),
        *((5, Table.COIL, motor_coil(m, "stop"), (1,)) for m in (1, 2, 3)),
    ]


def test_a_wrong_motor_ends_the_goal_even_after_it_was_seen_running(rig: Rig) -> None:
    """The wrong-motor verdict is not held back for the idle polls a running line waits
    for (a goal that had seen its motors run never ended: found by a flaky ROS test)."""
    d, fake = rig.device, rig.fake
    for motor in (1, 2, 3):
        d.set_speed(motor, 60)
    d.pair_reading, fake.pair_reading = "type_rows", "point_rows"
    motion = line_goal(rig, 2)
    motion.start()
    d.stop_interpolation()  # the snapshots below are made up from this one
    here = d.poll()
    running = dataclasses.replace(here, running=(True, True, True, False, False))
    assert motion.judge(dataclasses.replace(running, coordinates=(0.0,) * 5), 1.0) is None
    assert motion.seen_running
    moved = dataclasses.replace(running, coordinates=(0.0, 0.5, 0.2, 0.0, 0.0))
    verdict = motion.judge(moved, 1.1)
    assert verdict is not None and verdict.outcome is Outcome.HALTED, verdict
    assert "motor 2 0 -> 0.5" in verdict.message


def test_a_line_service_on_other_motors_is_flagged_for_a_stop(rig: Rig) -> None:
    """The same for a line started by the service (no goal follows it): a poll flags it,
    once, for the node to stop."""
    d, fake = rig.device, rig.fake
    for motor in (1, 2, 3):
        d.set_speed(motor, 1200)
    d.pair_reading, fake.pair_reading = "type_rows", "point_rows"
    d.line_move(2, (5.0, 4.0), (9.0, 12.0), 1200)
    why = wait_until(lambda: d.poll() and d.take_wrong_pair())
    assert "motor 2 0 ->" in why and "names motors 1+3 for pair 2" in why and "\n" not in why
    d.poll()
    assert d.take_wrong_pair() is None  # once per line
    d.stop_interpolation()
    assert fake.interpolation is None


@pytest.mark.parametrize(("pair", "moved"), [(1, "1+2"), (2, "1+3"), (3, "2+3")])
def test_a_line_on_the_configured_motors_says_which_moved(rig: Rig, pair: int, moved: str) -> None:
    d, fake = rig.device, rig.fake
    for motor in (1, 2, 3):
        d.set_speed(motor, 1200)
    d.pair_reading = fake.pair_reading = "type_rows"
    verdict = follow(rig, line_goal(rig, pair))
    assert verdict.outcome is Outcome.REACHED, verdict.message
    assert verdict.message.endswith(f"motors moved: {moved} (coordinates read back)")


def home_goal(rig: Rig, motor: int, **kwargs: Any) -> HomeMotion:
    rig.device.poll()  # the configuration, as the node has it before any goal
    return HomeMotion(rig.device, [JointScale()] * 5, "home", (motor,), tolerance=0.01, **kwargs)


def test_homing_is_judged_by_the_home_input_not_a_zero_coordinate(rig: Rig) -> None:
    """A controller that does not zero the coordinate at home ends the homing
    REACHED (home input on, motor stopped) with the coordinate it reads; it used to end
    LIMIT (home is wired to the reverse limit input)."""
    d, fake = rig.device, rig.fake
    fake.zero_at_home = False
    d.set_speed(2, 1200)
    verdict = follow(rig, home_goal(rig, 2))
    assert verdict.outcome is Outcome.REACHED, verdict.message
    assert "motor 2 IN4 on at coordinate -50" in verdict.message
    assert verdict.message.endswith("coordinates not zeroed (zero_after_home)")
    assert fake.position[2] == 0.0 and d.poll().coordinates[1] == -START_POSITION
    assert (5, Table.COIL, 43, (1,)) not in rig.writes()  # no zero coordinates coil


def test_homing_reports_the_coordinate_of_a_second_idle_poll(rig: Rig) -> None:
    """A poll reads the coordinates before the running flags: the coordinate of the poll
    that first shows the motor stopped may predate the controller's zero at the switch
    (the result once said -50 for a motor at 0); REACHED waits for a second idle poll."""
    d = rig.device
    motion = home_goal(rig, 2)
    motion.start()
    d.motor_action(2, "stop")  # the snapshots below are made up from this one
    here = d.poll()
    inputs = tuple(n == 4 for n in range(1, 14))  # IN4: motor 2's home input
    running = dataclasses.replace(here, running=(False, True, False, False, False))
    assert motion.judge(running, 1.0) is None
    torn = dataclasses.replace(here, inputs=inputs, coordinates=(0.0, -50.0, 0.0, 0.0, 0.0))
    assert motion.judge(torn, 1.1) is None
    settled = dataclasses.replace(torn, coordinates=(0.0,) * 5)
    verdict = motion.judge(settled, 1.2)
    assert verdict is not None and verdict.outcome is Outcome.REACHED, verdict
    assert "motor 2 IN4 on at coordinate 0" in verdict.message


def test_zero_after_home_sends_the_zero_coil_and_checks_it(rig: Rig) -> None:
    d, fake = rig.device, rig.fake
    fake.zero_at_home = False
    d.set_speed(3, 1200)

    def zero(motors: Any) -> tuple[bool, str, dict[int, float]]:
        return True, "", d.zero_coordinates(motors)

    verdict = follow(rig, home_goal(rig, 3, zero=zero))
    assert verdict.outcome is Outcome.REACHED, verdict.message
    assert "coordinates zeroed (coil 00044" in verdict.message
    assert rig.writes()[-1] == (5, Table.COIL, 43, (1,)) and d.poll().coordinates[2] == 0.0
    # A coil that leaves a coordinate off 0 (here: answered, ignored) is a FAULT.
    fake.position[3] = 10.0
    d.poll()

    def ignored(motors: Any) -> tuple[bool, str, dict[int, float]]:
        return True, "", {3: 1.5}

    verdict = follow(rig, home_goal(rig, 3, zero=ignored))
    assert verdict.outcome is Outcome.FAULT and "motor 3 reads 1.5" in verdict.message


def test_homing_that_ends_off_the_home_input(rig: Rig) -> None:
    d, fake = rig.device, rig.fake
    d.set_speed(4, 60)  # 5 units/s: stopped on the way
    motion = home_goal(rig, 4)
    motion.start()
    wait_until(lambda: d.poll().running[3])
    d.motor_action(4, "stop")
    verdict = follow_started(rig, motion)
    assert verdict.outcome is Outcome.STOPPED and "home input IN8 off" in verdict.message
    d.set_limit_inputs(5, 9, 10, 0)
    with pytest.raises(CommandRejected, match="motor 5 has no home input"):
        home_goal(rig, 5)
    assert fake.motion[5] is None


def test_stepper_sim_cli_on_its_own_pty(tmp_path: Path) -> None:
    """`stepper_sim --pty LINK`: socat pty pair, 9600 baud, the manual's 35 ms reply delay."""
    from bridge_core.sim.logs import read_write_log

    from ..support.ros import ROOT

    link_path, log = tmp_path / "stepper", tmp_path / "writes.jsonl"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "stepper_bridge.sim",
            "--pty",
            str(link_path),
            "--write-log",
            str(log),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().decode()
        assert "listening on" in line and "reply delay 35 ms" in line, line
        # Not a test of the reply timeout: a loaded machine stalls a pty for seconds.
        link = ModbusLink(SerialSettings(str(link_path), 9600, timeout_s=PTY_REPLY_TIMEOUT_S))
        channel = DeviceChannel(link, 1, retries=0)
        device = StepperDevice(channel)
        assert device.poll().config.motors[0].lead == 5.0
        device.set_output(2, True)
        assert device.poll().outputs[1]
        assert min(channel.stats.latencies_s) >= 0.035
        link.close()
        records = read_write_log(log)
        assert [(r.function_code, r.address, r.values) for r in records] == [(5, 50, (1,))]
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(10)
    assert not link_path.exists()  # socat cleaned up
