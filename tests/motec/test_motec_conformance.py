"""The MOTEC manual's example frames, byte-exact with their CRC, over a real pty pair.

An RTU replay peer on the device end of a socat pty pair answers each request frame the
bridge must send (CRC included) with the reply the step names. Frames are written
without their CRC and completed by pymodbus's RTU framer (never typed by hand); the
manual's own CRC routine (§6, getCRC16) is checked against it. Unit id 3, not the
manuals' usual 1, so the CRCs are specific. Also: the register map against the manual,
and refusals that never reach the wire.
"""

from __future__ import annotations

import itertools
import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import pytest
from pymodbus.framer import FramerRTU

from bridge_core.runtime.goals import Outcome
from bridge_core.runtime.keepalive import Keepalive
from bridge_core.wire.channel import DeviceChannel, Priority
from bridge_core.wire.errors import (
    CommandRejected,
    DeviceException,
    LinkTimeout,
    NotConfirmed,
    NotSent,
)
from bridge_core.wire.registers import Table, ValueType, WordOrder
from bridge_core.wire.transport import ModbusLink, SerialSettings
from motec_bridge.broadcast import disable_all
from motec_bridge.device import MotecDevice
from motec_bridge.lifeguard import DOWN_FEED_RETRY_S, lifeguard_bound_text, lifeguard_min_ms
from motec_bridge.motions import MOVE_TIME_ALLOWANCE_S, MoveToMotion, move_time_limit_s
from motec_bridge.registers import (
    CONTROL_MODE_POSITION,
    CONTROL_MODE_VELOCITY,
    MOTEC_LIMITS,
    MOTEC_MAP,
    fault_text,
    output_coil,
)
from motec_bridge.snapshots import (
    CONFIG_PLAN,
    MODE_PLAN,
    STANDSTILL_SPEED_RPM,
    STATUS_PLAN,
    Modes,
    MotecConfig,
    MotecSnapshot,
)
from motec_bridge.units import DriveScale

from ..support.rtu_replay import RtuReplay, Step
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, socat_pair

BAUD = 115200
UNIT = 3


def frame(text: str, unit: int = UNIT) -> bytes:
    """``unit`` + the hex PDU + the CRC pymodbus computes (low byte first on the wire)."""
    body = bytes([unit]) + bytes.fromhex(text)
    return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")


def get_crc16(data: bytes) -> int:
    """The manual's appendix §6 routine, transcribed: CRC-16, poly 0xA001, init 0xFFFF."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


# ---------------------------------------------------------------- RTU replay peer


@contextmanager
def replay(steps: Sequence[Step], unit: int = UNIT) -> Iterator[tuple[MotecDevice, DeviceChannel]]:
    with socat_pair() as (bridge_end, device_end, _):
        peer = RtuReplay(device_end, list(steps))
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        channel = DeviceChannel(link, unit, retries=0)
        try:
            yield MotecDevice(channel), channel
        finally:
            link.close()
            peer.close()
    assert peer.mismatches == []
    assert peer.received == [s.request for s in steps]


def run(steps: Sequence[Step], action: Callable[[MotecDevice], Any]) -> Any:
    with replay(steps) as (device, _):
        return action(device)


def echo(pdu: str, meaning: str) -> Step:
    """FC 05 / 06: the reply repeats the request (§2.4, §2.5)."""
    return Step(frame(pdu), frame(pdu), meaning)


def modes_read(operation: int, control: int, enabled: int, target: int = 0, start: int = 0) -> Step:
    """The fresh mode read (0x24-0x29) some commands do first, and its reply."""
    words = [operation, control, target >> 16 & 0xFFFF, target & 0xFFFF, enabled, start]
    data = "".join(f"{w:04X}" for w in words)
    return Step(frame("03 00 24 00 06"), frame(f"03 0C {data}"), "read 0x24-0x29")


def motion_read(setpoint: int, speed: int, position: int | None = None) -> Step:
    """A stop's check: 0xAA-0xAF (setpoint, actual position: the setpoint unless given,
    speed limit, actual speed)."""
    actual = setpoint if position is None else position
    words = [setpoint >> 16 & 0xFFFF, setpoint & 0xFFFF, actual >> 16 & 0xFFFF, actual & 0xFFFF]
    words += [300, speed & 0xFFFF]
    data = "".join(f"{w:04X}" for w in words)
    return Step(frame("03 00 AA 00 06"), frame(f"03 0C {data}"), "read 0xAA-0xAF")


# ---------------------------------------------------------------- CRC


def test_manual_crc_routine_is_pymodbus_crc_low_byte_first() -> None:
    # §6's getCRC16 returns the CRC; the §2 tables list "CRC 校验码高位" first, but the
    # drive is "与 MODBUS RTU 通讯规约相兼容" (§1.2): the low byte goes first on the wire.
    for text in ("06 00 24 00 00", "06 01 14 27 0F", "10 00 26 00 02 04 12 34 56 78"):
        for unit in (1, 3, 31):
            body = bytes([unit]) + bytes.fromhex(text)
            wire = frame(text, unit)
            assert wire[-2:] == get_crc16(body).to_bytes(2, "little")
            assert FramerRTU.check_CRC(body, int.from_bytes(wire[-2:], "big"))


# ---------------------------------------------------------------- §4.1 position mode


def test_position_mode_sequence_of_section_4_1() -> None:
    steps = [
        motion_read(0, 0),  # a mode change is refused while the motor turns: read fresh
        echo("06 00 24 00 00", "step 1: network operation mode"),
        echo("06 00 25 00 02", "step 2: position control"),
        modes_read(0, CONTROL_MODE_POSITION, 0),  # read back
        modes_read(0, CONTROL_MODE_POSITION, 0),
        echo("06 00 28 00 01", "step 4: enable"),
        modes_read(0, CONTROL_MODE_POSITION, 1),  # read back
        modes_read(0, CONTROL_MODE_POSITION, 1),
        Step(
            frame("03 00 AE 00 01"),
            frame("03 02 02 58"),
            "no max velocity given: the drive's own speed limit 0xAE is read (600 rpm)",
        ),
        motion_read(0, 0),  # where the motor is before the move
        echo("06 00 2D 00 00", "step 3: relative"),
        Step(
            frame("10 00 26 00 02 04 12 34 56 78"),
            frame("10 00 26 00 02"),
            "step 5: distance 0x12345678, high word first (§3.1.2 note)",
        ),
        echo("06 00 29 00 01", "step 6: start"),
        modes_read(0, CONTROL_MODE_POSITION, 1, 0x12345678, 1),  # read back
        motion_read(60, 60),  # it moves: the start is confirmed
    ]

    def act(d: MotecDevice) -> None:
        d.set_control_mode(CONTROL_MODE_POSITION)
        d.enable(True)
        d.move(0x12345678, relative=True)

    run(steps, act)


def test_absolute_move_with_a_speed_limit_and_stop() -> None:
    steps = [
        modes_read(0, CONTROL_MODE_POSITION, 1),
        echo("06 00 AE 01 2C", "speed limit 300 rpm"),
        motion_read(0, 0),
        echo("06 00 2D 00 01", "absolute"),
        Step(
            frame("10 00 26 00 02 04 FF FF EC 78"),
            frame("10 00 26 00 02"),
            "target -5000",
        ),
        echo("06 00 29 00 01", "start"),
        modes_read(0, CONTROL_MODE_POSITION, 1, -5000, 1),
        motion_read(-20, -30),
        modes_read(0, CONTROL_MODE_POSITION, 1),
        echo("06 00 29 00 00", "stop: 0x29 is the move / stop register"),
        motion_read(-1000, -300),
        motion_read(-1200, -120),  # the speed falls: the stop took, read on
        motion_read(-1210, -2),  # within the standstill band: stopped (decision 22)
    ]

    def act(d: MotecDevice) -> str:
        d.move(-5000, relative=False, speed_rpm=300.0)
        return d.stop()

    assert run(steps, act) == (
        "move stopped (0x29 = 0; 0xAC -1000 -> -1210, 0xAF -300 -> -2 rpm over 3 reads)"
    )


def test_a_position_stop_that_does_not_take_releases_the_drive() -> None:
    """A drive that takes 0x29 as a start trigger only runs on after
    0x29 = 0; within two reads the setpoint still advances at full speed: released."""
    steps = [
        echo("06 00 29 00 00", "stop"),
        motion_read(1000, 300),
        motion_read(1500, 300),
        motion_read(2000, 301),
        echo("06 00 28 00 00", "release: the stop the manual gives for every mode"),
        modes_read(0, CONTROL_MODE_POSITION, 0),
        motion_read(2000, 0),  # released, and it stands
    ]
    said = run(steps, lambda d: d.stop_move())
    assert said == (
        "0x29 = 0 did not stop the move (0xAC 1000 -> 2000, 0xAF 300 -> 301 rpm over 3 "
        "reads): drive released (0x28 = 0, reads 0; 0xAC 2000 -> 2000, 0xAF 0 -> 0 rpm)"
    )


def test_an_unchanged_setpoint_at_full_speed_is_not_a_stop() -> None:
    """A drive whose 0xAA holds the move's target (the other reading of
    "位置设定值", decision 22) shows an unchanged 0xAA while 0xAF reads full speed: not
    stopped. The speed does not fall: released, and the release checked."""
    steps = [
        echo("06 00 29 00 00", "stop"),
        motion_read(50_000, 600, position=1000),
        motion_read(50_000, 600, position=2000),
        motion_read(50_000, 599, position=3000),
        echo("06 00 28 00 00", "release"),
        modes_read(0, CONTROL_MODE_POSITION, 0),
        motion_read(50_000, 0, position=3100),
    ]
    said = run(steps, lambda d: d.stop_move())
    assert said.startswith("0x29 = 0 did not stop the move (0xAC 1000 -> 3000, 0xAF 600 -> 599")
    assert said.endswith("drive released (0x28 = 0, reads 0; 0xAC 3100 -> 3100, 0xAF 0 -> 0 rpm)")


def test_a_stop_that_ramps_down_slowly_is_read_until_the_drive_stands() -> None:
    """Hole 4: stopped means |0xAF| within the band; a speed that keeps falling is read on
    (up to STOP_SETTLE_S), not taken as stopped on its first fall."""
    speeds = [900, 700, 500, 300, 100, 1]
    steps = [echo("06 00 29 00 00", "stop")]
    steps += [motion_read(50_000, v, position=1000 + 10 * k) for k, v in enumerate(speeds)]
    said = run(steps, lambda d: d.stop_move())
    assert said == "move stopped (0x29 = 0; 0xAC 1000 -> 1050, 0xAF 900 -> 1 rpm over 6 reads)"


def test_a_release_that_is_ignored_is_not_confirmed() -> None:
    """A drive that ignores 0x29 = 0 and 0x28 = 0: the stop raises ``NotConfirmed`` with
    what was written and read (never a success)."""
    steps = [
        echo("06 00 29 00 00", "stop"),
        motion_read(1000, 600),
        motion_read(1500, 600),
        motion_read(2000, 600),
        echo("06 00 28 00 00", "release"),
        modes_read(0, CONTROL_MODE_POSITION, 1),
        motion_read(2500, 600),
        motion_read(3000, 600),
        motion_read(3500, 600),
    ]
    with pytest.raises(
        NotConfirmed,
        match=r"sent, not confirmed: wrote 0x28 = 0 \(release\), "
        r"read 0x28 = 1 \(0xAC 2500 -> 3500, 0xAF 600 -> 600 rpm over 3 reads\)",
    ):
        run(steps, lambda d: d.stop_move())


def test_setpoint_position_speed_and_fault_reads() -> None:
    steps = [
        Step(frame("03 00 AA 00 02"), frame("03 04 FF FF FF 9C"), "§4.1 step 7: setpoint -100"),
        Step(frame("03 00 AC 00 02"), frame("03 04 12 34 56 78"), "§3.2: position 0x12345678"),
        Step(frame("03 00 AF 00 01"), frame("03 02 FF 38"), "§4.2 step 5: -200 rpm"),
        Step(frame("03 00 C8 00 02"), frame("03 04 00 00 00 01"), "§4.3: fault 1"),
        Step(frame("03 01 09 00 01"), frame("03 02 01 F4"), "§3.3.4: analog input 500"),
    ]

    def act(d: MotecDevice) -> list[Any]:
        names = ("position_setpoint", "position_actual", "speed_actual", "fault_code")
        values = [d.read_named(name)[name] for name in names]
        return [*values, d.read_named("analog_input")["analog_input"]]

    assert run(steps, act) == [-100, 0x12345678, -200, 1, 500]
    assert fault_text(1) == "fault (有故障)" and fault_text(0) == "no fault (无故障)"


# ---------------------------------------------------------------- §4.2 velocity mode


def test_velocity_mode_sequence_of_section_4_2() -> None:
    steps = [
        motion_read(0, 0),  # not turning (read fresh)
        echo("06 00 24 00 00", "network operation mode"),
        echo("06 00 AE 00 00", "speed setpoint 0 before velocity control (decision)"),
        echo("06 00 25 00 01", "velocity control"),
        modes_read(0, CONTROL_MODE_VELOCITY, 0),  # read back
        Step(frame("03 00 AE 00 01"), frame("03 02 00 00"), "0xAE read back"),
        modes_read(0, CONTROL_MODE_VELOCITY, 0),
        echo("06 00 AE 00 00", "speed 0 again: enabling must not start the motor"),
        echo("06 00 28 00 01", "enable"),
        modes_read(0, CONTROL_MODE_VELOCITY, 1),  # read back
        modes_read(0, CONTROL_MODE_VELOCITY, 1),
        echo("06 00 AE FE D4", "-300 rpm (sign = direction)"),
        echo("06 00 AE 00 00", "deadman: 0 rpm"),
        Step(frame("03 00 AE 00 01"), frame("03 02 00 00"), "0xAE read back"),
        echo("06 00 28 00 00", "release"),
        modes_read(0, CONTROL_MODE_VELOCITY, 0),  # read back
    ]

    def act(d: MotecDevice) -> None:
        d.set_control_mode(CONTROL_MODE_VELOCITY)
        d.enable(True)
        assert d.velocity(-300.2)
        assert not d.velocity(-299.6)  # the same rpm: nothing sent
        assert d.velocity_stop()
        d.enable(False)

    run(steps, act)


# ---------------------------------------------------------------- §3.3 IO


def test_io_frames_of_section_3_3() -> None:
    steps = [
        Step(frame("01 00 00 00 03"), frame("01 01 07"), "FC 01: OUTPUT1-3 all on"),
        Step(frame("02 00 00 00 08"), frame("02 01 C0"), "FC 02: INPUT7, INPUT8"),
        echo("05 00 02 FF 00", "§3.3.3's frame: coil 2 = OUTPUT3 on (decision)"),
        echo("05 00 02 00 00", "OUTPUT3 off"),
        echo("05 00 00 FF 00", "OUTPUT1 on"),
    ]

    def act(d: MotecDevice) -> tuple[Any, Any]:
        outputs, inputs = d.read_outputs(), d.read_inputs()
        d.set_output(3, True)
        d.set_output(3, False)
        d.set_output(1, True)
        return outputs, inputs

    outputs, inputs = run(steps, act)
    assert outputs == (True, True, True)
    assert inputs == (False,) * 6 + (True, True)
    assert [output_coil(n) for n in (1, 2, 3)] == [0, 1, 2]


def test_manual_nine_bit_reads_decode_with_the_bridge_bit_order() -> None:
    # §3.3.1 / §3.3.2 read 9 bits from 0 and get 2 bytes: 07 00 and C0 00.
    steps = [
        Step(frame("01 00 00 00 09"), frame("01 02 07 00"), "§3.3.1"),
        Step(frame("02 00 00 00 09"), frame("02 02 C0 00"), "§3.3.2"),
    ]
    with replay(steps) as (_, channel):
        outputs = channel.read_bits(0, 9, Table.COIL, Priority.COMMAND)
        inputs = channel.read_bits(0, 9, Table.DISCRETE_INPUT, Priority.COMMAND)
    assert outputs == [True, True, True] + [False] * 6  # OUTPUT1-3
    assert inputs == [False] * 6 + [True, True, False]  # INPUT7, INPUT8


# ---------------------------------------------------------------- §3.1, §3.4, §3.5


def test_lifeguard_save_and_analog_max_speed_frames() -> None:
    steps = [
        echo("06 01 12 01 F4", "§3.4.1: lifeguard time 500 ms"),
        echo("06 01 14 27 0F", "§3.4.2: lifeguard mode 9999"),
        echo("06 00 35 00 01", "§3.5: save to flash"),
        echo("06 00 6D 0B B8", "§3.1.1: analog max speed 3000"),
    ]

    def act(d: MotecDevice) -> None:
        d.arm_lifeguard(500)
        d.save_to_flash()
        d.set_analog_max_speed(3000)

    run(steps, act)


def test_broadcast_disable_gets_no_reply() -> None:
    steps = [Step(frame("06 00 28 00 00", unit=0), b"", "broadcast release")]
    with replay(steps, unit=0) as (_, channel):
        disable_all(channel, {})
        assert channel.stats.timeouts == 0


def test_exception_reply_comes_back_by_name() -> None:
    steps = [Step(frame("03 00 AC 00 02"), frame("83 02"), "refused read")]
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS") as raised:
        run(steps, lambda d: d.read_named("position_actual"))
    assert (raised.value.function_code, raised.value.exception_code) == (3, 2)


# ---------------------------------------------------------------- the map against the manual


def test_map_addresses_types_and_word_order() -> None:
    expected = {
        "operation_mode": (0x24, ValueType.U16),
        "control_mode": (0x25, ValueType.U16),
        "target_distance": (0x26, ValueType.I32),
        "enable": (0x28, ValueType.U16),
        "start": (0x29, ValueType.U16),
        "motion_mode": (0x2D, ValueType.U16),
        "save_to_flash": (0x35, ValueType.U16),
        "analog_max_speed": (0x6D, ValueType.U16),
        "output_word": (0x79, ValueType.U16),
        "position_setpoint": (0xAA, ValueType.I32),
        "position_actual": (0xAC, ValueType.I32),
        "speed_setpoint": (0xAE, ValueType.I16),
        "speed_actual": (0xAF, ValueType.I16),
        "input_word": (0xC5, ValueType.U16),
        "output_state": (0xC6, ValueType.U16),
        "fault_code": (0xC8, ValueType.U32),
        "analog_input": (0x109, ValueType.I16),
        "lifeguard_time": (0x112, ValueType.U16),
        "lifeguard_mode": (0x114, ValueType.U16),
    }
    holding = {r.name: r for r in MOTEC_MAP.in_table(Table.HOLDING)}
    assert set(holding) == set(expected)
    for name, (address, kind) in expected.items():
        assert (holding[name].address, holding[name].value_type) == (address, kind), name
    for reg in MOTEC_MAP:
        assert reg.word_order is WordOrder.HIGH_FIRST
        assert "§" in reg.doc, reg.name
    read_only = {"position_setpoint", "position_actual", "speed_actual", "input_word"}
    read_only |= {"fault_code", "analog_input"}
    assert {n for n, r in holding.items() if not r.access.writable} == read_only
    coils = MOTEC_MAP.in_table(Table.COIL)
    inputs = MOTEC_MAP.in_table(Table.DISCRETE_INPUT)
    assert [(r.name, r.address) for r in coils] == [(f"output_{n}", n - 1) for n in (1, 2, 3)]
    assert [(r.name, r.address) for r in inputs] == [(f"input_{n}", n - 1) for n in range(1, 9)]
    assert MOTEC_MAP["target_distance"].minimum == -(2**31 - 1)  # §5.1
    assert MOTEC_LIMITS.function_codes == frozenset({1, 2, 3, 5, 6, 16})


def test_parameter_numbers_of_sections_3_4_and_5() -> None:
    # Address = parameter number; a touch panel adds 1 (§5.2).
    assert MOTEC_MAP["lifeguard_time"].address == 274  # Pr.274
    assert MOTEC_MAP["lifeguard_mode"].address == 276  # Pr.276
    assert MOTEC_MAP["enable"].address == 4100 // 100 - 1 == 40  # panel 4100 -> Pr.40
    assert MOTEC_MAP["start"].address == 4200 // 100 - 1 == 41  # panel 4200 -> Pr.41
    assert MOTEC_MAP["target_distance"].address == 39 - 1 == 38  # panel 39 -> Pr.38-39
    assert MOTEC_MAP["speed_setpoint"].address == 175 - 1 == 174  # panel 175 -> Pr.174


def test_poll_plans() -> None:
    assert [(r.address, r.count) for r in STATUS_PLAN] == [
        (0x24, 10),
        (0xAA, 6),
        (0xC5, 5),
        (0x109, 1),
    ]
    assert [(r.address, r.count) for r in CONFIG_PLAN] == [(0x6D, 1), (0x112, 3)]
    assert [(r.address, r.count) for r in MODE_PLAN] == [(0x24, 6)]


# ---------------------------------------------------------------- refusals write nothing


class FakeIO:
    """A RegisterIO that answers mode reads with ``modes`` and records writes."""

    def __init__(
        self, operation: int = 0, control: int = 2, enabled: int = 1, speed_limit: int = 0
    ) -> None:
        self.modes = [operation, control, 0, 0, enabled, 0]
        self.speed_limit = speed_limit  # 0xAE
        self.speed = 0  # 0xAF
        self.writes: list[tuple[str, int, Any]] = []
        self.priorities: list[Priority] = []

    def read_registers(
        self, address: int, count: int, table: Table = Table.HOLDING, priority: Any = None
    ) -> list[int]:
        if (address, count) == (0xAE, 1):
            return [self.speed_limit & 0xFFFF]
        if (address, count) == (0xAA, 6):
            return [0, 0, 0, 0, self.speed_limit & 0xFFFF, self.speed & 0xFFFF]
        assert (address, count) == (0x24, 6)
        return list(self.modes)

    def read_bits(self, *args: Any, **kwargs: Any) -> list[bool]:
        raise AssertionError("no bit reads expected")

    def write_register(
        self, address: int, value: int, priority: Priority = Priority.COMMAND
    ) -> None:
        self.writes.append(("06", address, value))
        self.priorities.append(priority)
        if 0x24 <= address <= 0x29:
            self.modes[address - 0x24] = value
        elif address == 0xAE:
            self.speed_limit = value

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        self.writes.append(("16", address, list(values)))
        if address == 0x26:
            self.modes[2:4] = list(values)

    def write_coil(self, address: int, on: bool, priority: Priority = Priority.COMMAND) -> None:
        self.writes.append(("05", address, on))

    def write_coils(self, address: int, values: Sequence[bool]) -> None:
        raise AssertionError("the drive has no FC 15")

    def mask_write_register(self, address: int, and_mask: int, or_mask: int) -> None:
        raise AssertionError("the drive has no FC 22")

    def read_write_registers(self, *args: Any) -> list[int]:
        raise AssertionError("the drive has no FC 23")


@pytest.mark.parametrize(
    ("modes", "action", "reason"),
    [
        ((0, 2, 1), lambda d: d.move(2**31, relative=True), "outside"),
        ((0, 2, 1), lambda d: d.move(1.5, relative=True), "whole number"),
        ((0, 2, 1), lambda d: d.move(10, relative=True, speed_rpm=math.nan), "finite"),
        ((0, 2, 1), lambda d: d.move(10, relative=True, speed_rpm=5000), "max_speed_rpm"),
        ((0, 2, 1), lambda d: d.move(10, relative=True, speed_rpm=-5), "negative"),
        ((1, 2, 1), lambda d: d.move(10, relative=True), "network mode"),
        ((0, 1, 1), lambda d: d.move(10, relative=True), "position control"),
        ((0, 2, 0), lambda d: d.move(10, relative=True), "disabled"),
        # max velocity 0 keeps 0xAE, which FakeIO holds at 0: the move could not run.
        ((0, 2, 1), lambda d: d.move(10, relative=True), "0xAE, which is 0 rpm"),
        ((0, 1, 0), lambda d: d.velocity(100), "velocity control"),
        ((0, 2, 1), lambda d: d.velocity(100), "velocity control"),
        ((0, 1, 1), lambda d: d.velocity(math.inf), "finite"),
        ((0, 1, 1), lambda d: d.velocity(3000.6), "outside"),
        ((0, 1, 1), lambda d: d.set_control_mode(3), "control mode 3"),
        ((0, 1, 1), lambda d: d.set_output(4, True), "output 4"),
        ((0, 1, 1), lambda d: d.set_output(0, True), "output 0"),
        ((0, 1, 1), lambda d: d.set_analog_max_speed(-1), "outside"),
        ((0, 1, 1), lambda d: d.set_analog_max_speed(65536), "outside"),
        ((0, 1, 1), lambda d: d.set_analog_max_speed(1.5), "whole number"),
        ((0, 1, 1), lambda d: d.arm_lifeguard(10), "lifeguard time 10"),
    ],
)
def test_refused_commands_write_nothing(
    modes: tuple[int, int, int], action: Callable[[MotecDevice], Any], reason: str
) -> None:
    io = FakeIO(*modes)
    with pytest.raises(CommandRejected, match=reason):
        action(MotecDevice(io))
    assert io.writes == []


def test_stop_locks_the_velocity_stream_until_zero() -> None:
    io = FakeIO(0, CONTROL_MODE_VELOCITY, 1)
    d = MotecDevice(io)
    assert d.velocity(100)
    assert d.stop().startswith("speed setpoint 0 (0xAE reads 0; ")
    with pytest.raises(CommandRejected, match="stopped"):
        d.velocity(100)
    assert not d.velocity(0)  # unlocks, writes nothing
    assert d.velocity(100)
    assert io.writes == [("06", 0xAE, 100), ("06", 0xAE, 0), ("06", 0xAE, 100)]


def test_stop_outside_network_mode_releases_the_drive() -> None:
    io = FakeIO(1, CONTROL_MODE_POSITION, 1)
    assert "released" in MotecDevice(io).stop()
    assert io.writes == [("06", 0x28, 0)]


def test_a_move_without_a_speed_limit_keeps_the_drives_own() -> None:
    io = FakeIO(speed_limit=600)
    MotecDevice(io).move(-10, relative=True)
    assert io.writes == [("06", 0x2D, 0), ("16", 0x26, [0xFFFF, 0xFFF6]), ("06", 0x29, 1)]
    io = FakeIO(speed_limit=-300)  # left negative by a velocity session
    with pytest.raises(CommandRejected, match="which is -300 rpm"):
        MotecDevice(io).move(10, relative=True)
    assert io.writes == []


def test_lifeguard_floor_follows_the_bus() -> None:
    # 1.5 x (0.1 s wake-up + drives x the longest transaction), in whole ms.
    assert lifeguard_min_ms(3, 0.124) == 708
    assert lifeguard_min_ms(1, 0.124) == 336
    assert lifeguard_min_ms(1, 0.01) == 165
    # The defaults of config/motec.yaml: 3 drives, 115200 8N1, timeout_s 0.1.
    hold = SerialSettings("/dev/null", 115200, timeout_s=0.1).longest_hold_s()
    assert lifeguard_min_ms(3, hold) == math.ceil(1.5 * (0.1 + 3 * hold) * 1000) == 708
    assert "3 drive(s) x 0.124 s" in lifeguard_bound_text(3, hold)


def test_lifeguard_disarm_and_feeds_go_first() -> None:
    io = FakeIO()
    d = MotecDevice(io)
    assert d.feed_lifeguard(500)
    d.disarm_lifeguard()
    # §3.4's frame disarms with 0x112 = 0; 0x114 = 0 only after it.
    assert io.writes == [("06", 0x112, 500), ("06", 0x112, 0), ("06", 0x114, 0)]
    assert io.priorities == [Priority.KEEPALIVE, Priority.COMMAND, Priority.COMMAND]


def test_a_drive_is_armed_unless_its_lifeguard_time_reads_0() -> None:
    """A non-zero 0x112 with any mode may be watching (decision 9)."""
    assert MotecConfig(0, 500, 0).lifeguard_armed
    assert MotecConfig(0, 500, 9999).lifeguard_armed
    assert not MotecConfig(0, 0, 9999).lifeguard_armed


class SlowIO(FakeIO):
    """A FakeIO whose writes take ``write_s`` on ``now`` and may time out."""

    def __init__(self, now: list[float], write_s: float) -> None:
        super().__init__()
        self.now, self.write_s, self.fail, self.not_sent = now, write_s, False, False

    def write_register(
        self, address: int, value: int, priority: Priority = Priority.COMMAND
    ) -> None:
        if self.not_sent:
            raise NotSent("the link was lost while the command waited; not sent")
        self.now[0] += self.write_s
        if self.fail:
            raise LinkTimeout("no reply")
        super().write_register(address, value, priority)


def test_lifeguard_feeds_count_from_the_request_and_go_on_while_down() -> None:
    """The next feed is due a feed period after the last write's
    request (not its reply), and a feed that failed (line down) is tried again a feed
    period after its own request: never waiting for a reconnect, never in a burst."""
    now = [100.0]
    io = SlowIO(now, write_s=0.04)
    d = MotecDevice(io, clock=lambda: now[0])
    assert d.feed_lifeguard(300)  # request at 100.0, reply at 100.04
    assert d.next_feed(300) == pytest.approx(100.1)
    io.fail = True
    now[0] = 100.1
    with pytest.raises(LinkTimeout):
        d.feed_lifeguard(300, down=True)  # request at 100.1, timed out at 100.14
    assert not d.feed_lifeguard(300, down=True)  # not again at once
    # Within the lifeguard time since the last write: again after DOWN_FEED_RETRY_S (less
    # than a feed period here, so the feed period).
    assert d.next_feed(300, down=True) == pytest.approx(100.2)
    now[0] = 100.2
    io.fail = False
    assert d.feed_lifeguard(300, down=True)
    assert d.next_feed(300) == pytest.approx(100.3)
    # A feed refused before it went out (the session's link was lost): due again at once.
    now[0] = 100.3
    io.not_sent = True
    with pytest.raises(NotSent):
        d.feed_lifeguard(300)
    assert d.next_feed(300) == pytest.approx(100.3)


def test_hole11_a_line_back_late_in_the_lifeguard_time_is_fed_at_once() -> None:
    """Lifeguard 1000 ms, last write at 100.0, the line down from just
    after it. Before, the tries sat on the 1/3 s grid of the last write (100.333,
    100.667, 101.0), so a line back at 100.8 got its first write at 101.0, when the drive
    trips. Now the tries come every DOWN_FEED_RETRY_S within the lifeguard time, and
    once the drive answers (a probe: the node asks with down=False) the overdue feed is
    due at once. After the lifeguard time they go back to one per feed period."""
    now = [100.0]
    io = SlowIO(now, write_s=0.0)
    d = MotecDevice(io, clock=lambda: now[0])
    assert d.feed_lifeguard(1000)  # the last write, at 100.0
    io.fail = True
    tries: list[float] = []

    def tick_until(end: float) -> None:  # the keepalive, looking every 10 ms
        while now[0] < end - 1e-9:
            now[0] = round(now[0] + 0.01, 6)
            if now[0] >= d.next_feed(1000, down=True):
                tries.append(now[0])
                with pytest.raises(LinkTimeout):
                    d.feed_lifeguard(1000, down=True)

    tick_until(100.8)
    assert tries[0] == pytest.approx(100.34)  # a feed period after the last write
    assert all(b - a <= DOWN_FEED_RETRY_S + 0.011 for a, b in itertools.pairwise(tries))
    io.fail = False  # the line answers again at 100.8
    while not d.feed_lifeguard(1000, down=True):
        now[0] = round(now[0] + 0.01, 6)
    assert now[0] - 100.8 <= DOWN_FEED_RETRY_S + 0.011 and now[0] < 101.0
    # A probe found the drive before a feed did (the last try failed at 100.75): the node
    # asks the up schedule, and the overdue feed is due at once (before: 101.083).
    d.last_write, d.last_feed_try = 100.0, 100.75
    assert d.next_feed(1000) == pytest.approx(100.0 + 1 / 3)
    # Past the lifeguard time without a write: one try per feed period.
    d.last_write, d.last_feed_try = 100.0, 101.05
    assert d.next_feed(1000, down=True) == pytest.approx(101.05 + 1 / 3)


def test_the_first_lifeguard_feed_goes_at_once_with_the_clock_near_zero() -> None:
    """A host booted a moment ago (a fresh VM, a CI runner): the monotonic clock is near 0.
    A drive never written is due its first feed now, not a feed period after boot (a
    "last write at 0" would leave the drive unfed for 20 s here, past its lifeguard)."""
    started = time.monotonic()

    def clock() -> float:
        return time.monotonic() - started  # 0.0 at the start of the test

    io = FakeIO()
    d = MotecDevice(io, clock=clock)
    lifeguard_ms = 60_000  # a feed period of 20 s
    assert d.next_feed(lifeguard_ms) <= clock()
    fed = threading.Event()
    errors: list[Exception] = []

    def feed() -> None:
        d.feed_lifeguard(lifeguard_ms)
        fed.set()

    keepalive = Keepalive(
        "test-near-zero", lambda: d.next_feed(lifeguard_ms), feed, errors.append, clock=clock
    )
    keepalive.start()
    try:
        assert fed.wait(5.0), "the first feed did not go at once"
    finally:
        keepalive.close()
    assert io.writes[0] == ("06", 0x112, lifeguard_ms) and not errors


def test_lifeguard_feed_only_when_nothing_else_was_written() -> None:
    now = [100.0]
    io = FakeIO()
    d = MotecDevice(io, clock=lambda: now[0])
    assert d.feed_lifeguard(300)  # nothing written yet
    now[0] += 0.05
    assert not d.feed_lifeguard(300)  # within a third of 300 ms
    d.save_to_flash()
    now[0] += 0.09
    assert not d.feed_lifeguard(300)  # the save fed it
    now[0] += 0.02
    assert d.feed_lifeguard(300)
    assert not d.feed_lifeguard(0)
    assert io.writes == [("06", 0x112, 300), ("06", 0x35, 1), ("06", 0x112, 300)]


def test_drive_scale() -> None:
    s = DriveScale(counts_per_rev=10000, gear_ratio=10)
    assert s.position(25000) == pytest.approx(math.pi / 2)
    assert s.velocity(600) == pytest.approx(2 * math.pi)  # 600 motor rpm = 1 joint rev/s
    assert s.to_counts(math.pi / 2) == 25000
    assert s.to_rpm(2 * math.pi) == pytest.approx(600)
    for bad in (math.nan, math.inf, 1e9):
        with pytest.raises(CommandRejected):
            s.to_counts(bad)
    with pytest.raises(ValueError, match="counts_per_rev"):
        DriveScale(counts_per_rev=0)


def snapshot(setpoint: int, actual: int, speed: int) -> MotecSnapshot:
    """A poll of a drive in network mode, position control, enabled, no fault."""
    return MotecSnapshot(
        read_time=0.0,
        slow_read_time=0.0,
        modes=Modes(0, CONTROL_MODE_POSITION, True),
        motion_mode=1,
        target_distance=10000,
        start=1,
        position_setpoint=setpoint,
        position_actual=actual,
        speed_setpoint_rpm=600,
        speed_actual_rpm=speed,
        input_word=0,
        output_word=0,
        fault_code=0,
        analog_input=0,
        config=MotecConfig(0, 0, 0),
    )


def move_to(tolerance: int = 10, margin: float = 0.0) -> MoveToMotion:
    return MoveToMotion(
        MotecDevice(FakeIO()),
        DriveScale(),
        2 * math.pi,  # 10000 counts
        relative=False,
        max_velocity_rad_s=2 * math.pi * 10,  # 600 rpm
        tolerance_counts=tolerance,
        time_limit_margin=margin,
    )


def test_move_to_ends_on_a_servo_that_rests_a_few_counts_off() -> None:
    """A real servo at rest dithers (0xAF +-1-2 rpm, 0xAC 1-2 counts
    from 0xAA); "stands" is a band, seen on two polls in a row, REACHED too."""
    motion = move_to()
    assert STANDSTILL_SPEED_RPM >= 2
    # ~/set_control_mode refuses a turning motor, not 0xAF noise.
    assert not snapshot(0, 0, -2).turning and snapshot(0, 0, STANDSTILL_SPEED_RPM + 1).turning
    assert motion.judge(snapshot(5000, 4990, 600), 1.0) is None  # running
    assert motion.judge(snapshot(10000, 9998, -2), 1.1) is None  # stands: once
    verdict = motion.judge(snapshot(10000, 10001, 1), 1.2)  # twice
    assert verdict is not None and verdict.outcome is Outcome.REACHED, verdict
    motion = move_to()
    assert motion.judge(snapshot(5000, 4990, 600), 1.0) is None
    assert motion.judge(snapshot(10000, 9998, -2), 1.1) is None
    assert motion.judge(snapshot(10000, 9970, 0), 1.2) is None  # 30 counts behind: moving
    assert motion.judge(snapshot(10000, 10002, 0), 1.3) is None
    verdict = motion.judge(snapshot(10000, 10002, 2), 1.4)
    assert verdict is not None and verdict.outcome is Outcome.REACHED


def test_move_to_has_a_default_time_limit() -> None:
    """Without a goal timeout_s the move is limited to its time at the
    speed limit x the margin + the ramps' allowance; a margin 0 (explicit) gives none."""
    # 100000 counts at 600 rpm (10 turns a second) of a 10000-count motor: 1 s; x 2 +
    # the allowance.
    limit = 2 + MOVE_TIME_ALLOWANCE_S
    assert move_time_limit_s(100_000, 600, 10000, 2.0) == pytest.approx(limit)
    assert move_time_limit_s(10000, 0, 10000, 2.0) == math.inf
    motion = move_to(margin=2.0)
    motion.time_limit_s = move_time_limit_s(100_000, 600, 10000, 2.0)
    assert motion.judge(snapshot(5000, 4990, 600), limit - 0.1) is None
    verdict = motion.judge(snapshot(9000, 9000, 0), limit + 0.1)
    assert verdict is not None and verdict.outcome is Outcome.TIMED_OUT
    assert "default limit" in verdict.message
    assert move_to(margin=0.0).time_limit_s == math.inf
