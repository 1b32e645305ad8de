"""The MOTEC simulator: drive behaviour (ticked directly), and several drives on one bus
driven by the device layer over a real socat pty pair."""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from bridge_core.wire.channel import DeviceChannel, Priority
from bridge_core.wire.errors import CommandRejected, DeviceException, LinkTimeout
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings
from motec_bridge.broadcast import disable_all, start_all
from motec_bridge.device import MotecDevice
from motec_bridge.registers import (
    CONTROL_MODE_POSITION,
    CONTROL_MODE_VELOCITY,
    LIFEGUARD_ACTIVE,
    MOTEC_MAP,
)
from motec_bridge.sim import (
    DEFAULT_ACCEL_RPM_S,
    LIFEGUARD_FAULT_CODE,
    MotecSimDrive,
    MotecSimulator,
    make_simulator,
)

from ..support.serial_pair import socat_pair

BAUD = 115200
LIFEGUARD_TEST_MS = 2000  # a feed stalled by a saturated machine must not trip it
UNITS = (1, 2, 3)
DT = 0.01


def write(drive: MotecSimDrive, name: str, value: int) -> int | None:
    """A write as the bus would deliver it (FC 06 / 16), through guards and hooks."""
    from bridge_core.wire.codec import encode

    reg = MOTEC_MAP[name]
    words = encode(reg, value)
    return drive.write(6 if len(words) == 1 else 16, reg.address, words)


def ready(drive: MotecSimDrive, control_mode: int) -> None:
    assert write(drive, "operation_mode", 0) is None
    assert write(drive, "control_mode", control_mode) is None
    assert write(drive, "enable", 1) is None


# ---------------------------------------------------------------- behaviour, ticked


def test_trapezoid_move_reaches_the_target_exactly() -> None:
    drive = MotecSimDrive(1, counts_per_rev=10000, accel_rpm_s=6000, move_speed_rpm=600)
    ready(drive, CONTROL_MODE_POSITION)
    assert write(drive, "target_distance", 30000) is None
    assert write(drive, "start", 1) is None
    speeds = []
    for _ in range(200):
        drive.tick(DT)
        speeds.append(drive.value("speed_actual"))
        if drive.move is None:
            break
    assert drive.value("position_actual") == 30000 == drive.value("position_setpoint")
    assert drive.value("speed_actual") == 0
    peak = max(speeds)
    assert peak == 600  # the plateau: move_speed_rpm (0xAE is 0)
    rising = speeds[: speeds.index(peak) + 1]
    assert all(b - a <= 60 for a, b in itertools.pairwise(rising))  # 6000 rpm/s
    assert rising[0] == 60
    # Absolute move back, limited by 0xAE = 300 rpm.
    assert write(drive, "speed_setpoint", 300) is None
    assert write(drive, "motion_mode", 1) is None
    assert write(drive, "target_distance", -1000) is None
    assert write(drive, "start", 1) is None
    peak = 0
    while drive.move is not None:
        drive.tick(DT)
        peak = max(peak, abs(drive.value("speed_actual")))
    assert drive.value("position_actual") == -1000 and peak == 300


def test_stop_decelerates_and_velocity_ramps() -> None:
    drive = MotecSimDrive(1, accel_rpm_s=DEFAULT_ACCEL_RPM_S)
    ready(drive, CONTROL_MODE_POSITION)
    write(drive, "target_distance", 10**6)
    write(drive, "start", 1)
    for _ in range(20):
        drive.tick(DT)
    assert drive.value("speed_actual") == 600
    write(drive, "start", 0)
    drive.tick(DT)
    assert 0 < drive.value("speed_actual") < 600
    for _ in range(20):
        drive.tick(DT)
    assert drive.value("speed_actual") == 0 and drive.move is None
    # Velocity control: ramps to 0xAE by the acceleration, both ways.
    write(drive, "control_mode", CONTROL_MODE_VELOCITY)
    write(drive, "speed_setpoint", -1200)
    drive.tick(DT)
    assert drive.value("speed_actual") == -60
    for _ in range(30):
        drive.tick(DT)
    assert drive.value("speed_actual") == -1200
    before = drive.value("position_actual")
    drive.tick(0.1)
    assert drive.value("position_actual") - before == pytest.approx(-20000, abs=1)
    write(drive, "enable", 0)
    drive.tick(DT)
    assert drive.value("speed_actual") == 0


def test_motion_needs_network_mode() -> None:
    drive = MotecSimDrive(1)
    assert drive.value("operation_mode") != 0  # powers up outside network mode
    write(drive, "enable", 1)
    write(drive, "target_distance", 5000)
    assert write(drive, "start", 1) == 3  # ILLEGAL DATA VALUE
    write(drive, "operation_mode", 0)
    write(drive, "control_mode", CONTROL_MODE_VELOCITY)
    write(drive, "speed_setpoint", 100)
    write(drive, "operation_mode", 5)  # back out of network mode: the motor stays
    for _ in range(10):
        drive.tick(DT)
    assert drive.value("speed_actual") == 0 and drive.value("position_actual") == 0


def test_a_stalled_simulator_reads_what_arrived_before_it_judges_the_lifeguard() -> None:
    """The simulator's process was not scheduled for 1.2 s (a loaded test machine) while a
    feed waited in its port's buffer: the late tick does not trip the drive; the next one,
    after the feed was read, finds it fed. Without the feed the next tick trips it."""
    for fed in (True, False):
        now = [0.0]
        drive = MotecSimDrive(1, clock=lambda now=now: now[0])  # type: ignore[misc]
        ready(drive, CONTROL_MODE_VELOCITY)
        write(drive, "lifeguard_time", 1000)
        write(drive, "lifeguard_mode", LIFEGUARD_ACTIVE)
        now[0] += 1.2
        drive.tick(1.2)  # the tick after the stall
        assert drive.fault == 0
        if fed:
            write(drive, "lifeguard_time", 1000)  # the feed, read after the stall
        now[0] += DT
        drive.tick(DT)
        assert (drive.fault == 0) is fed, drive.fault


def test_lifeguard_expiry_latches_a_fault_and_releases() -> None:
    now = [0.0]
    drive = MotecSimDrive(1, clock=lambda: now[0])
    ready(drive, CONTROL_MODE_VELOCITY)
    write(drive, "speed_setpoint", 100)
    write(drive, "lifeguard_time", 200)
    write(drive, "lifeguard_mode", LIFEGUARD_ACTIVE)
    for _ in range(5):  # fed by a write every 150 ms: no fault
        now[0] += 0.15
        drive.tick(DT)
        write(drive, "lifeguard_time", 200)
    assert drive.fault == 0 and drive.enabled
    assert drive.read(3, 0xAC, 2) is not None  # reads do not feed it
    now[0] += 0.21
    drive.tick(DT)
    assert drive.value("fault_code") == LIFEGUARD_FAULT_CODE
    # §4.3's "1—有故障" stands beside 0xC8 (decision 7): the flag word.
    assert drive.read(3, 0xC8, 2) == [1, 0]
    assert not drive.enabled and drive.value("speed_actual") == 0
    assert write(drive, "enable", 1) == 3  # refused while the fault is latched
    assert write(drive, "enable", 0) is None  # releasing does not clear it (no reset, §3.4)
    assert drive.value("fault_code") == LIFEGUARD_FAULT_CODE
    assert write(drive, "enable", 1) == 3
    drive.power_cycle()  # a restart does, and brings back the parameters saved to flash
    assert drive.value("fault_code") == 0 and not drive.enabled
    assert drive.value("lifeguard_mode") == 0 and drive.value("operation_mode") == 1
    assert write(drive, "enable", 1) is None


def test_a_restart_brings_back_what_was_saved_to_flash() -> None:
    """§3.5: unsaved parameters are lost on a restart, saved ones kept."""
    drive = MotecSimDrive(1)
    write(drive, "analog_max_speed", 1500)
    write(drive, "save_to_flash", 1)
    write(drive, "analog_max_speed", 2000)
    write(drive, "motion_mode", 1)
    drive.inject_fault(0x31)
    drive.power_cycle()
    assert drive.value("analog_max_speed") == 1500 and drive.value("motion_mode") == 0
    assert drive.fault == 0 and drive.value("fault_code") == 0


def test_writes_refused_where_the_drive_would() -> None:
    drive = MotecSimDrive(1)
    assert drive.write(6, 0x28, [2]) == 3  # enable: 0 or 1
    assert drive.write(6, 0x2D, [2]) == 3  # motion mode: 0 or 1
    assert drive.write(6, 0x2A, [1]) == 2  # an unnamed parameter
    assert drive.write(6, 0x26, [1]) == 2  # half of the 32-bit distance
    assert drive.write(6, 0xAC, [1]) == 2  # read-only position
    assert drive.write(5, 3, [1]) == 2  # no OUTPUT4
    assert drive.read(3, 0x2A, 3) == [0, 0, 0]  # unnamed parameters read as 0
    assert drive.read(3, 0x114, 2) == 2  # past the end of the table
    assert write(drive, "save_to_flash", 1) is None
    # Cleared "when done" (the next tick), so the FC 06 reply, built
    # from what the register holds after the write, echoes §3.5's printed 00 01.
    assert drive.value("save_to_flash") == 1 and drive.saves == 1
    drive.tick(DT)
    assert drive.value("save_to_flash") == 0
    assert drive.write(6, 0x79, [0b1010]) is None  # FC 06 on the output word: low 3 bits
    assert drive.value("output_state") == 0b010 == drive.value("output_word")
    assert drive.read(1, 0, 3) == [0, 1, 0]
    assert drive.write(6, 0xC6, [0b101]) is None
    assert drive.read(1, 0, 3) == [1, 0, 1]
    assert drive.write_log[-1].address == 0xC6


# ---------------------------------------------------------------- a bus of three drives


@dataclass
class Bus:
    sim: MotecSimulator
    link: ModbusLink
    devices: dict[int, MotecDevice]
    channels: dict[int, DeviceChannel]


@pytest.fixture
def bus() -> Iterator[Bus]:
    sim = make_simulator(UNITS)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        # Far above a reply's few ms: the simulator shares this process, and a loaded
        # machine can stall its thread for tens of ms.
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=0.5))
        channels = {u: DeviceChannel(link, u, retries=0) for u in (*UNITS, 9)}
        try:
            yield Bus(sim, link, {u: MotecDevice(channels[u]) for u in UNITS}, channels)
        finally:
            link.close()
            sim.stop()


def test_three_drives_move_independently(bus: Bus) -> None:
    d1, d2, d3 = (bus.devices[u] for u in UNITS)
    bus.sim.drive(3).set_input(2, True)
    bus.sim.drive(3).set_analog(-321)
    bus.sim.drive(2).inject_fault(0x31)
    d1.set_control_mode(CONTROL_MODE_POSITION)
    d1.enable(True)
    d1.move(20000, relative=True)
    deadline = time.monotonic() + 30
    while (s := d1.poll()).position_actual != 20000 or s.moving:
        assert time.monotonic() < deadline, s
        time.sleep(0.02)
    assert s.modes.enabled and s.modes.network and s.fault_code == 0
    s2, s3 = d2.poll(), d3.poll()
    assert s2.fault_code == 0x31 and s2.position_actual == 0
    assert s3.inputs[1] and s3.input_word == 2 and s3.analog_input == -321
    assert d3.read_inputs()[1]
    # Writes landed on drive 1 only, with the unit id of the request.
    assert [r.unit_id for r in bus.sim.drive(1).write_log] == [1] * 6
    assert bus.sim.drive(2).write_log == bus.sim.drive(3).write_log == []


def test_start_outside_position_mode_is_refused_by_the_drive(bus: Bus) -> None:
    channel = bus.channels[1]
    with pytest.raises(DeviceException, match="ILLEGAL DATA VALUE"):
        channel.write_register(0x29, 1)
    with pytest.raises(DeviceException, match="ILLEGAL FUNCTION"):
        channel.read_registers(0, 1, Table.INPUT, Priority.COMMAND)  # FC 04
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
        channel.read_registers(0x115, 1, Table.HOLDING, Priority.COMMAND)


def test_broadcast_reaches_every_drive_and_nobody_answers(bus: Bus) -> None:
    for u in UNITS:
        bus.devices[u].set_control_mode(CONTROL_MODE_POSITION)
        bus.devices[u].enable(True)
    broadcast = DeviceChannel(bus.link, 0, retries=0)
    drives = {u: bus.channels[u] for u in UNITS}
    # Drive 2 misses the frame; the read-back finds it still enabled and
    # it gets a write of its own; the answer comes from what every drive reads.
    bus.sim.deaf_to_broadcast.add(2)
    ok, seen = disable_all(broadcast, drives)
    assert ok, seen
    assert "drive 2: 0x28 = 0, 0x29 = 0, 0xAA = 0, 0xAF = 0 rpm (missed the broadcast" in seen
    assert broadcast.stats.timeouts == 0
    for u in UNITS:
        assert not bus.devices[u].poll().modes.enabled
        last = bus.sim.drive(u).write_log[-1]
        assert (last.address, last.values) == (0x28, (0,))
    bus.sim.unplug(3)  # a drive that does not answer: its state is unknown, no success
    ok, seen = disable_all(broadcast, drives)
    assert not ok and "drive 3: did not answer" in seen


def test_unplugged_and_unknown_drives_are_silent(bus: Bus) -> None:
    bus.sim.unplug(2)
    with pytest.raises(LinkTimeout):
        bus.devices[2].poll()
    with pytest.raises(LinkTimeout):
        bus.channels[9].read_registers(0x24, 1)
    assert bus.devices[1].poll().modes.operation_mode == 1  # the others answer
    assert bus.devices[3].poll().fault_code == 0
    disable_all(DeviceChannel(bus.link, 0, retries=0), {})  # an unplugged drive misses it
    assert bus.sim.drive(2).write_log == []
    bus.sim.plug(2)
    assert bus.devices[2].poll().fault_code == 0


def test_reply_delay_and_withheld_replies(bus: Bus) -> None:
    channel = bus.channels[1]
    bus.sim.reply_delay_s = 0.03
    started = time.perf_counter()
    channel.read_registers(0x24, 1)
    assert time.perf_counter() - started >= 0.03
    bus.sim.reply_delay_s = 0.0
    bus.sim.withhold_replies = True
    with pytest.raises(LinkTimeout):
        channel.read_registers(0x24, 1)
    bus.sim.withhold_replies = False
    assert channel.read_registers(0x24, 1) == [1]


def test_lifeguard_over_the_bus(bus: Bus) -> None:
    d = bus.devices[1]
    d.set_control_mode(CONTROL_MODE_VELOCITY)
    d.enable(True)
    # 2 s, fed every few ms: a loaded machine's scheduling stalls stay far below it.
    d.arm_lifeguard(LIFEGUARD_TEST_MS)
    deadline = time.monotonic() + 2 * LIFEGUARD_TEST_MS / 1000
    while time.monotonic() < deadline:  # the bridge's feed keeps it alive
        d.feed_lifeguard(LIFEGUARD_TEST_MS)
        time.sleep(0.01)
    assert d.poll().fault_code == 0
    deadline = time.monotonic() + 30
    # Polls alone do not feed it. A poll that straddles the moment it fires may see the
    # fault code but the modes read just before (still enabled): wait for the next one.
    while not ((s := d.poll()).fault_code and not s.modes.enabled):
        assert time.monotonic() < deadline, "the lifeguard did not fire"
        time.sleep(0.05)
    assert s.fault_code == LIFEGUARD_FAULT_CODE
    assert s.config.lifeguard_armed and s.config.lifeguard_time_ms == LIFEGUARD_TEST_MS
    with pytest.raises(DeviceException, match="ILLEGAL DATA VALUE"):
        d.enable(True)
    d.enable(False)
    assert d.poll().fault_code == LIFEGUARD_FAULT_CODE  # no Modbus reset (§3.4)
    bus.sim.power_cycle(1)
    assert d.poll().fault_code == 0


# ------------------------------------------------- parameters by number, broadcast start, IO tables


def test_parameters_by_number_over_the_bus(bus: Bus) -> None:
    """§3.1 / §3.2 / §5.2: Pr.N at address N, FC 06 or FC 16 high word first, the manual's
    ranges; anything else refused before a write (and the simulator refuses it too)."""
    d, drive = bus.devices[1], bus.sim.drive(1)
    drive.set_position(-70000)
    assert d.read_parameter(0xAC) == -70000  # 32-bit, read whole
    d.write_parameter(0x6D, 1500)
    d.write_parameter(38, -5)  # Pr.38/39 = 0x26-0x27, the distance
    d.write_parameter(0x2D, 1)
    assert d.read_parameter(0x6D) == 1500 and d.read_parameter(38) == -5
    assert [(r.function_code, r.address, r.values) for r in drive.write_log] == [
        (6, 0x6D, (1500,)),
        (16, 0x26, (0xFFFF, 0xFFFB)),
        (6, 0x2D, (1,)),
    ]
    refusals = [
        (39, 0, "low word of the 32-bit Pr.38"),
        (0x2A, 0, "not a parameter the manual names"),
        (0xAC, 0, "read only"),
        (0x28, 1, "~/enable"),
        (0x29, 1, "start_all"),
        (0x112, 500, "lifeguard_ms"),
        (0x6D, 70000, "outside"),
        (0x2D, 2, "outside"),
    ]
    for number, value, reason in refusals:
        with pytest.raises(CommandRejected, match=reason):
            d.write_parameter(number, value)
    # Any Pr.N reads (no range needed); past the table the drive says 02.
    assert d.read_parameter(0x2A) == 0
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
        d.read_parameter(0x115)
    with pytest.raises(CommandRejected, match=r"low word of the 32-bit Pr\.38"):
        d.read_parameter(39)
    with pytest.raises(CommandRejected, match="parameter number 65536"):
        d.read_parameter(0x10000)
    # Unlisted writes only with the opt-in; the drive checks the value (it refuses this
    # one: the simulator never writes an unnamed parameter, 02).
    opted = MotecDevice(bus.channels[1], allow_unlisted_parameters=True)
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
        opted.write_parameter(0x2A, -1)
    for number, value, reason in [
        (0x2A, 70000, "outside"),
        (39, 0, "low word"),
        (0x28, 1, "~/enable"),
    ]:
        with pytest.raises(CommandRejected, match=reason):
            opted.write_parameter(number, value)
    assert len(drive.write_log) == 3
    # The drive itself: an unnamed parameter 0x02, out of range 0x03, half a value 0x02.
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
        bus.channels[1].write_register(0x2A, 1)
    with pytest.raises(DeviceException, match="ILLEGAL DATA VALUE"):
        bus.channels[1].write_register(0x2D, 2)
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
        bus.channels[1].write_register(0x27, 1)


def test_broadcast_start_moves_every_ready_drive_and_gets_no_reply(bus: Bus) -> None:
    broadcast = DeviceChannel(bus.link, 0, retries=0)
    drives = {u: bus.channels[u] for u in UNITS}
    with pytest.raises(CommandRejected, match="drive 1 is in operation mode other"):
        start_all(broadcast, drives)
    for u in UNITS:
        bus.devices[u].set_control_mode(CONTROL_MODE_POSITION)
        bus.devices[u].enable(True)
        bus.devices[u].write_parameter(0x26, 1000 * u)
    bus.sim.unplug(3)
    with pytest.raises(CommandRejected, match="drive 3 did not answer"):
        start_all(broadcast, drives)
    bus.sim.plug(3)
    # ~/move's checks and each drive node's read_only.
    with pytest.raises(CommandRejected, match="drive 2's node is read_only"):
        start_all(broadcast, drives, read_only=[2])
    bus.channels[3].write_register(0xAE, 0)
    with pytest.raises(CommandRejected, match="drive 3's speed limit 0xAE is 0 rpm"):
        start_all(broadcast, drives)
    bus.channels[3].write_register(0xAE, 600)
    assert all(r.address != 0x29 for u in UNITS for r in bus.sim.drive(u).write_log)
    ok, seen = start_all(broadcast, drives)
    assert ok, seen
    assert broadcast.stats.timeouts == 0
    for u in UNITS:  # read back after the broadcast: every drive took it
        assert f"drive {u}: 0x28 = 1, 0x29 = 1" in seen
    deadline = time.monotonic() + 30
    while any((s := bus.devices[u].poll()).position_actual != 1000 * u or s.moving for u in UNITS):
        assert time.monotonic() < deadline
        time.sleep(0.02)
    # A drive that misses the start: not synchronised, the others are stopped.
    for u in UNITS:
        bus.devices[u].write_parameter(0x26, 100_000)
    bus.sim.deaf_to_broadcast.add(2)
    ok, seen = start_all(broadcast, drives)
    assert not ok and "drives [2] did not take the start" in seen, seen
    assert "drive 1: move stopped" in seen and "drive 3: move stopped" in seen
    while any(bus.devices[u].poll().speed_actual_rpm for u in UNITS):
        assert time.monotonic() < deadline
        time.sleep(0.02)
    assert all(bus.devices[u].poll().position_actual < 1000 * u + 100_000 for u in (1, 3))
    bus.sim.drive(1).inject_fault(0x10031)
    with pytest.raises(CommandRejected, match="drive 1 has fault 65585"):
        start_all(broadcast, drives)


def test_io_tables_fault_halves_and_output_numbering(bus: Bus) -> None:
    """0x29, 0x79, FC 01 / FC 02 in the snapshot; 0xC8 / 0xC9 apart; OUTPUT1 at coil 1."""
    drive = bus.sim.drive(1)
    drive.set_input(3, True)
    drive.inject_fault(0x0001_0031)
    plain = bus.devices[1].poll()
    assert plain.coil_outputs is None and plain.discrete_inputs is None
    d = MotecDevice(bus.channels[1], read_io_tables=True, output1_coil=1)
    d.set_output(2, True)  # the §3.3.3 example's reading: OUTPUT2 at coil 2
    assert (drive.write_log[-1].function_code, drive.write_log[-1].address) == (5, 2)
    s = d.poll()
    assert (s.fault_flag, s.fault_detail, s.fault_code) == (1, 0x31, 0x0001_0031)
    assert s.start == 0 and s.output_word_79 == 0b100 == s.output_word
    assert s.outputs == (False, True, False) == s.coil_outputs
    assert s.discrete_inputs == (False, False, True, False, False, False, False, False)
    assert bus.devices[1].poll().outputs == (False, False, True)  # default numbering


# --------------------------------- save echo, frames pymodbus cannot cut, a stop that does not take


def rtu(body: str, unit: int = 1) -> bytes:
    """An RTU frame: unit, PDU, Modbus CRC low byte first (§6, decision 2)."""
    data = bytes([unit]) + bytes.fromhex(body)
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return data + crc.to_bytes(2, "little")


def test_save_echo_and_a_function_code_pymodbus_cannot_frame() -> None:
    """Item 12: §3.5's save reply echoes ``00 01`` as printed; FC 0x41 (no length
    pymodbus knows) gets exception 01 and the next request its answer."""
    import serial

    sim = make_simulator(UNITS)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        port = serial.Serial(bridge_end, BAUD, timeout=0.05)
        try:

            def exchange(request: bytes, size: int) -> bytes:
                port.reset_input_buffer()
                port.write(request)
                reply = b""
                deadline = time.monotonic() + 5
                while len(reply) < size and time.monotonic() < deadline:
                    reply += port.read(size - len(reply))
                return reply

            save = rtu("06 00 35 00 01")
            assert exchange(save, 8) == save
            assert sim.drive(1).saves == 1
            assert exchange(rtu("41 00 00 00 01"), 5) == rtu("C1 01")
            assert exchange(rtu("03 00 24 00 01"), 7) == rtu("03 02 00 01")
        finally:
            port.close()
            sim.stop()


def test_a_position_stop_that_does_not_take_releases_the_drive(bus: Bus) -> None:
    """Item 7: on a drive that takes 0x29 as a start trigger only, 0x29 = 0 leaves the
    move running; the check sees it and releases the drive, and says so."""
    d, drive = bus.devices[1], bus.sim.drive(1)
    d.set_control_mode(CONTROL_MODE_POSITION)
    d.enable(True)
    d.move(10_000_000, relative=True, speed_rpm=600)
    deadline = time.monotonic() + 30
    while d.poll().speed_actual_rpm < 600:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    said = d.stop()
    assert said.startswith("move stopped (0x29 = 0;"), said  # the simulator's reading
    while d.poll().speed_actual_rpm:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    drive.start_is_trigger = True
    d.move(10_000_000, relative=True, speed_rpm=600)
    while d.poll().speed_actual_rpm < 600:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    said = d.stop()
    assert said.startswith("0x29 = 0 did not stop the move (0xAC "), said
    assert "drive released (0x28 = 0, reads 0; " in said, said
    assert not drive.enabled and drive.speed == 0
