"""The stepper manual's example RTU frames, byte-exact with their CRC, over a real pty pair.

What the bridge sends is captured by an RTU replay peer on the device end of a socat pty
pair: each step names the request frame the bridge must send (CRC included) and the
reply to answer with. CRCs come from pymodbus's RTU framer (never typed by hand), and the
manual's own CRCs are checked against it. Also here: the register map against the
manual's tables, and the decisions on the example/table contradictions
(Stepper decisions 2-4, docs/decisions/stepper.md).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from pymodbus.framer import FramerRTU

from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import DeviceException
from bridge_core.wire.registers import Table, ValueType, WordOrder
from bridge_core.wire.transport import ModbusLink, SerialSettings
from stepper_bridge.device import StepperDevice
from stepper_bridge.registers import (
    MAX_REGISTERS_PER_REQUEST,
    MOTOR_ACTIONS,
    REPLY_DELAY_S,
    STEPPER_LIMITS,
    STEPPER_MAP,
    SYSTEM_COILS,
    UNDEFINED_HOLDING,
    coil,
    holding,
    motor_register,
)

from ..support.rtu_replay import RtuReplay, Step
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, socat_pair

BAUD = 115200


def hexbytes(text: str) -> bytes:
    return bytes.fromhex(text)


def with_crc(text: str) -> bytes:
    """A frame without its CRC -> the frame with the CRC pymodbus computes (low byte first)."""
    body = hexbytes(text)
    return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")


# The manual's frames as printed (§6), CRC included.
MANUAL_FRAMES = {
    "FC 03 read 40001-40002": "01 03 00 00 00 02 C4 0B",
    "FC 03 reply 1.80 deg, microstep 8": "01 03 04 00 B4 00 08 BB D3",
    "FC 06 microstep 4": "01 06 00 01 00 04 D9 C9",
    "FC 10 example at address 9": "01 10 00 09 00 02 04 00 C8 00 00 B2 3B",
    "FC 10 example reply": "01 10 00 09 00 02 91 CA",
    "FC 05 coil address 7 on": "01 05 00 07 FF 00 3D FB",
}


@pytest.mark.parametrize("name", list(MANUAL_FRAMES))
def test_manual_crcs_are_what_pymodbus_computes(name: str) -> None:
    frame = hexbytes(MANUAL_FRAMES[name])
    assert with_crc(frame[:-2].hex()) == frame
    assert FramerRTU.check_CRC(frame[:-2], int.from_bytes(frame[-2:], "big"))


# ---------------------------------------------------------------- RTU replay peer


@contextmanager
def replay(steps: list[Step]) -> Iterator[tuple[StepperDevice, RtuReplay]]:
    with socat_pair() as (bridge_end, device_end, _):
        peer = RtuReplay(device_end, steps)
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        try:
            yield StepperDevice(DeviceChannel(link, 1, retries=0)), peer
        finally:
            link.close()
            peer.close()
    assert peer.mismatches == []
    assert peer.received == [s.request for s in steps]


def run(steps: list[tuple[bytes, bytes, str]], action: Callable[[StepperDevice], Any]) -> Any:
    with replay([Step(req, rep, meaning) for req, rep, meaning in steps]) as (device, _):
        return action(device)


def echo(frame: bytes, meaning: str) -> tuple[bytes, bytes, str]:
    """FC 05 / 06: the reply is the request (§6: "和发送的数据一样")."""
    return (frame, frame, meaning)


# ---------------------------------------------------------------- the manual's examples


def test_fc03_read_step_angle_and_microstep() -> None:
    values = run(
        [
            (
                hexbytes(MANUAL_FRAMES["FC 03 read 40001-40002"]),
                hexbytes(MANUAL_FRAMES["FC 03 reply 1.80 deg, microstep 8"]),
                "read 40001-40002",
            )
        ],
        lambda d: d.read_named("motor1_step_angle", "motor1_microstep"),
    )
    assert values == {"motor1_step_angle": pytest.approx(1.80), "motor1_microstep": 8}


def test_fc06_write_microstep_4() -> None:
    frame = hexbytes(MANUAL_FRAMES["FC 06 microstep 4"])
    run([echo(frame, "microstep 4")], lambda d: d.set_motor_parameter(1, "microstep", 4))


def test_fc10_run_distance_200_goes_to_the_table_address() -> None:
    # Stepper decision 2: the table's 40009-40010 = address 8-9, low word first.
    request = with_crc("01 10 00 08 00 02 04 00 C8 00 00")
    reply = with_crc("01 10 00 08 00 02")
    run([(request, reply, "run distance 2.00 (raw 200)")], lambda d: d.set_run_distance(1, 2.00))


def test_fc10_example_address_would_cut_two_values() -> None:
    # The example writes address 9-10: motor 1's distance HIGH word and motor 2's step
    # angle. The bridge never produces it: no register starts at 9.
    assert STEPPER_MAP.owner_at(Table.HOLDING, 9) == STEPPER_MAP["motor1_run_distance"]
    assert STEPPER_MAP["motor1_run_distance"].address == 8
    assert STEPPER_MAP.owner_at(Table.HOLDING, 10) == STEPPER_MAP["motor2_step_angle"]
    assert all(reg.address != 9 for reg in STEPPER_MAP.in_table(Table.HOLDING))


def test_fc05_example_frame_is_motor_2_reverse() -> None:
    # Stepper decision 3: coil address 7 = coil 00008 = motor 2 reverse.
    frame = hexbytes(MANUAL_FRAMES["FC 05 coil address 7 on"])
    steps = [
        (
            with_crc("01 03 00 6D 00 02"),
            with_crc("01 03 04 00 00 00 00"),
            "motor 2 coordinate (40110-40111) before: 0",
        ),
        echo(frame, "motor 2 reverse"),
        (
            with_crc("01 03 00 A8 00 01"),
            with_crc("01 03 02 00 01"),
            "motor 2 running (40169) read back: 1, the start is confirmed",
        ),
    ]
    said = run(steps, lambda d: d.motor_action(2, "reverse"))
    assert said == "wrote motor 2 reverse (coil 00008 = ON); read motor 2 running (40169) = 1"
    assert STEPPER_MAP["motor2_reverse"].address == 7
    assert STEPPER_MAP["motor1_run_once"].address == 0


def test_move_by_is_direction_distance_then_single_run() -> None:
    steps = [
        echo(with_crc("01 06 00 0E 00 01"), "motor 2 direction 1 (negative)"),
        (
            with_crc("01 10 00 12 00 02 04 86 A0 00 01"),
            with_crc("01 10 00 12 00 02"),
            "motor 2 distance 1000.00 = 100000 = 0x000186A0, low word first",
        ),
        (
            with_crc("01 03 00 0E 00 06"),
            with_crc("01 03 0C 00 01 00 3C 01 F4 00 00 86 A0 00 01"),
            "40015-40020 read back: direction 1, speed 60, lead 5.00, distance 1000.00",
        ),
        echo(with_crc("01 05 00 05 FF 00"), "motor 2 single run (coil 00006)"),
    ]
    said = run(steps, lambda d: d.move_by(2, -1000.0, confirm=False))
    assert said == (
        "wrote motor 2 direction (40015) = 1, motor 2 run distance (40019) = 1000 (read back); "
        "wrote motor 2 run once (coil 00006 = ON)"
    )


def test_outputs_are_coil_pairs() -> None:
    # Stepper decision 4: output n on = 0xFF00 to coil 00049+2(n-1), off = 0xFF00 to
    # coil 00050+2(n-1).
    steps = [
        echo(with_crc("01 05 00 30 FF 00"), "output 1 on: coil 00049"),
        echo(with_crc("01 05 00 31 FF 00"), "output 1 off: coil 00050"),
        echo(with_crc("01 05 00 47 FF 00"), "output 12 off: coil 00072"),
    ]

    def act(d: StepperDevice) -> None:
        d.set_output(1, True)
        d.set_output(1, False)
        d.set_output(12, False)

    run(steps, act)


def test_jog_is_speed_then_direction_coil() -> None:
    """Without a configuration read yet, the jog reads the configured speed first (to write
    it back after the stop)."""
    steps = [
        (
            with_crc("01 03 00 05 00 01"),
            with_crc("01 03 02 00 3C"),
            "motor 1 speed (40006): 60 rpm configured",
        ),
        echo(with_crc("01 06 00 05 00 78"), "motor 1 speed 120 rpm"),
        echo(with_crc("01 05 00 02 FF 00"), "motor 1 reverse"),
        echo(with_crc("01 05 00 04 FF 00"), "motor 1 stop"),
        (
            with_crc("01 03 00 A7 00 01"),
            with_crc("01 03 02 00 00"),
            "motor 1 running (40168) read back: 0, the stop is confirmed",
        ),
        echo(with_crc("01 06 00 05 00 3C"), "motor 1 speed 60 rpm again"),
    ]

    def act(d: StepperDevice) -> None:
        assert d.jog(1, -120.0)
        assert not d.jog(1, -120.2)  # same command: nothing sent
        assert d.jog(1, 0.0)

    run(steps, act)


def test_configure_is_two_writes_around_the_direction() -> None:
    steps = [
        (
            with_crc("01 10 00 1E 00 04 08 00 5A 00 10 01 F4 0F A0"),
            with_crc("01 10 00 1E 00 04"),
            "motor 4: 0.90 deg, microstep 16, 500 Hz, 4000 Hz",
        ),
        (
            with_crc("01 10 00 23 00 03 06 01 2C 04 B0 00 00"),
            with_crc("01 10 00 23 00 03"),
            "motor 4: 300 rpm, lead 12.00 (1200, low word first)",
        ),
    ]
    run(
        steps,
        lambda d: d.configure(
            4,
            step_angle_deg=0.9,
            microstep=16,
            start_frequency_hz=500,
            accel_frequency_hz=4000,
            speed_rpm=300,
            lead=12.0,
        ),
    )


def test_exception_reply_comes_back_by_name() -> None:
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS") as raised:
        run(
            [(with_crc("01 03 00 00 00 02"), with_crc("01 83 02"), "refused read")],
            lambda d: d.read_named("motor1_step_angle", "motor1_microstep"),
        )
    assert (raised.value.function_code, raised.value.exception_code) == (3, 2)


# ---------------------------------------------------------------- the map against the manual


def test_holding_addresses_follow_the_plc_numbers() -> None:
    expected = {
        "motor1_step_angle": 40001,
        "motor1_microstep": 40002,
        "motor1_start_frequency": 40003,
        "motor1_accel_frequency": 40004,
        "motor1_direction": 40005,
        "motor1_speed": 40006,
        "motor1_lead": 40007,
        "motor1_run_distance": 40009,
        "motor2_step_angle": 40011,
        "motor2_run_distance": 40019,
        "motor5_run_distance": 40049,
        "motor1_positive_limit_input": 40081,
        "motor1_negative_limit_input": 40082,
        "motor1_home_input": 40083,
        "motor5_home_input": 40095,
        "motor1_coordinate": 40108,
        "motor5_coordinate": 40116,
        "input_1": 40124,
        "input_13": 40136,
        "output_1": 40148,
        "output_12": 40159,
        "motor1_running": 40168,
        "motor5_running": 40172,
        "homing_order_1": 40177,
        "homing_order_5": 40181,
        "arc_pair": 40182,
        "arc_mode": 40183,
        "arc_start_a": 40184,
        "arc_via_b": 40198,
        "arc_direction": 40200,
        "arc_speed": 40201,
        "line_pair": 40202,
        "line_end_b": 40209,
        "line_speed": 40211,
        "device_id": 40212,
        "baud_rate": 40213,
        "system_mode": 40300,
        "motor1_reciprocations": 40301,
        "motor5_reciprocations": 40305,
    }
    for name, plc in expected.items():
        assert STEPPER_MAP[name].address == holding(plc) == plc - 40001, name
    # Every 32-bit value is low word first; coordinates and points are signed.
    for reg in STEPPER_MAP:
        if reg.value_type.words == 2:
            assert reg.word_order is WordOrder.LOW_FIRST, reg.name
    assert STEPPER_MAP["motor3_coordinate"].value_type is ValueType.I32
    assert STEPPER_MAP["motor3_lead"].scale == 100
    assert STEPPER_MAP["motor3_step_angle"].scale == 100
    assert STEPPER_MAP["motor3_coordinate"].scale == 100


def test_every_holding_row_of_the_manual_is_mapped_and_nothing_else() -> None:
    defined = {a for r in STEPPER_MAP.in_table(Table.HOLDING) for a in r.addresses()}
    manual_rows = (
        set(range(40001, 40051))
        | set(range(40081, 40096))
        | set(range(40108, 40118))
        | set(range(40124, 40137))
        | set(range(40148, 40160))
        | set(range(40168, 40173))
        | set(range(40177, 40215))
        | set(range(40300, 40306))
    )
    assert defined == {holding(plc) for plc in manual_rows}
    for first, last in UNDEFINED_HOLDING:
        assert not any(holding(plc) in defined for plc in range(first, last + 1))


def test_every_coil_of_the_manual_is_mapped() -> None:
    coils = {r.name: r.address for r in STEPPER_MAP.in_table(Table.COIL)}
    for motor in range(1, 6):
        for k, action in enumerate(MOTOR_ACTIONS):
            assert coils[motor_register(motor, action)] == coil(1 + 5 * (motor - 1) + k)
    assert coils["emergency_stop"] == coil(42)
    assert coils["zero_coordinates"] == coil(44)
    assert coils["return_to_zero"] == coil(45)
    assert coils["home_all"] == coil(46)
    assert coils["factory_reset"] == coil(73)
    assert coils["save_parameters"] == coil(96)
    assert coils["clear_all_parameters"] == coil(97)
    assert (coils["all_outputs_on"], coils["all_outputs_off"]) == (coil(98), coil(99))
    assert (coils["arc_start"], coils["arc_stop"]) == (coil(100), coil(101))
    assert (coils["line_start"], coils["line_stop"]) == (coil(102), coil(103))
    for n in range(1, 13):
        assert coils[f"output_{n}_on"] == coil(49 + 2 * (n - 1))
        assert coils[f"output_{n}_off"] == coil(50 + 2 * (n - 1))
    assert len(coils) == 25 + len(SYSTEM_COILS) + 24
    # No coil is readable: the device has no FC 01.
    assert all(not r.access.readable for r in STEPPER_MAP.in_table(Table.COIL))


def test_device_limits() -> None:
    assert STEPPER_LIMITS.max_read_registers == MAX_REGISTERS_PER_REQUEST == 49
    assert STEPPER_LIMITS.max_write_registers == 49
    assert STEPPER_LIMITS.function_codes == frozenset({3, 5, 6, 16})
    assert STEPPER_LIMITS.reply_delay_s == REPLY_DELAY_S == 0.035
    assert not STEPPER_LIMITS.read_undefined_ok
