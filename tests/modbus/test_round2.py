"""modbus_bridge, round 2, without ROS: 8E1/8O1/8N2 on a pty (the port layer, modbus_sim --pty), the
example descriptions in config/devices/ against modbus_sim (a velocity-only VFD joint that
ramps, f32 in CDAB and ABCD), exit stops of started motion, the keepalive (fed, required,
and the simulator's watchdog), and replies that say what a rounded write wrote."""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from bench.line_relay import REQUEST, LineRelay, silence_violations
from bridge_core.sim.pty_pair import PtyPair
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.codec import encode
from bridge_core.wire.errors import CommandRejected
from bridge_core.wire.registers import Table
from bridge_core.wire.serial_port import ParityTolerantSerial, open_serial
from bridge_core.wire.serial_timing import char_time_s, silence_s
from bridge_core.wire.transport import ModbusLink, SerialSettings
from modbus_bridge.description import Description, DescriptionError, load
from modbus_bridge.device import DescribedDevice
from modbus_bridge.sim import DescribedSimDevice, make_simulator

from .test_modbus_sim import over_tcp, stream_of, wait_for, writes

ROOT = Path(__file__).resolve().parents[2]
VFD = ROOT / "config" / "devices" / "vfd_rtu.yaml"
INVERTER = ROOT / "config" / "devices" / "inverter_tcp_f32.yaml"
MULTIDROP = ROOT / "config" / "devices" / "rtu_multidrop.yaml"
SIM = (sys.executable, "-m", "modbus_bridge.sim")
FRAMINGS = [("E", 1), ("O", 1), ("N", 2), ("E", 2)]


@contextmanager
def pty_pair() -> Iterator[PtyPair]:
    with tempfile.TemporaryDirectory() as tmp:
        pair = PtyPair(Path(tmp) / "bridge")
        try:
            yield pair
        finally:
            pair.close()


# ---------------------------------------------------------------- parity on a pty
@pytest.mark.parametrize(("parity", "stopbits"), FRAMINGS)
def test_a_pty_opens_and_reopens_with_parity_and_a_later_configure(
    parity: str, stopbits: int
) -> None:
    """A pty drops PARENB; a later configure (a timeout set after opening, as pymodbus
    does) and a second open must still work."""
    with pty_pair() as pair:
        for _ in range(2):
            port = open_serial(
                str(pair.device_end), baudrate=9600, parity=parity, stopbits=stopbits, timeout=0.1
            )
            assert isinstance(port, ParityTolerantSerial)
            port.inter_byte_timeout = 0.01
            port.timeout = 0
            assert port.parity == parity  # what was asked, for the line's timing
            port.close()


def test_an_8e1_simulator_on_a_pty_answers_an_8e1_link() -> None:
    """``modbus_sim --pty`` with the VFD's 8E1 (it exited with EINVAL) and a link reading
    its registers; the simulator says once (one INFO line) that its pty dropped parity."""
    with tempfile.TemporaryDirectory() as tmp:
        link_path = Path(tmp) / "vfd"
        stderr = Path(tmp) / "stderr"
        with stderr.open("w") as err:
            proc = subprocess.Popen(
                [*SIM, "--device-file", str(VFD), "--pty", str(link_path), "--baudrate", "19200"],
                cwd=ROOT,
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
            )
        try:
            assert proc.stdout is not None
            banner = proc.stdout.readline()  # printed once serving (or the error, at exit)
            assert banner.startswith(f"modbus_sim vfd (unit 1) listening on {link_path}"), banner
            assert "19200 8E1" in banner, banner
            link = ModbusLink(SerialSettings(str(link_path), 19200, "E", 1, timeout_s=1.0))
            channel = DeviceChannel(link, 1, retries=0)
            try:
                assert channel.read_registers(0x2000, 3) == [0, 0, 0]
                channel.write_register(0x2001, 2500)
                assert channel.read_registers(0x2001, 1) == [2500]
            finally:
                link.close()
        finally:
            proc.terminate()
            proc.wait(10)
        lines = stderr.read_text().splitlines()
        assert len(lines) == 1 and "does not keep the parity bit" in lines[0], lines
        assert lines[0].startswith("[INFO]"), lines


def test_an_8e1_line_keeps_the_silence_of_11_bit_characters() -> None:
    """The VFD at 9600 8E1 over the byte-paced line (bench/line_relay.py, 11 bits per
    character): every frame takes its 11-bit time and no request starts inside t3.5."""
    bits = 11
    with LineRelay(
        9600, bits_per_char=bits, device_turnaround_s=silence_s(9600, parity="E")
    ) as line:
        simulator = make_simulator(load(VFD))
        simulator.start_serial(line.device_path, 9600, "E", 1)
        link = ModbusLink(SerialSettings(line.client_path, 9600, "E", 1, timeout_s=0.5))
        try:
            device = DescribedDevice(DeviceChannel(link, 1, retries=0), load(VFD).device)
            for _ in range(3):
                device.poll()
            device.set_value("set_frequency", 12.5)
        finally:
            link.close()
            simulator.stop()
        frames = line.frames()
    assert line.silence_s == pytest.approx(3.5 * bits / 9600)
    # 3 polls, the slow group as often as it was due, the write and its read-back
    # (decision 19)
    groups = device.groups
    expected = 3 * len(groups.fast) + groups.slow_reads * len(groups.slow) + 2
    assert sum(f.direction == REQUEST for f in frames) == expected
    for f in frames:
        assert f.due_end - f.start == pytest.approx(f.size * bits / 9600)
    assert silence_violations(frames, line.silence_s, 0.1 * line.silence_s) == []


def test_parity_and_two_stop_bits_count_eleven_bits() -> None:
    assert char_time_s(19200, parity="E") == pytest.approx(11 / 19200)
    assert char_time_s(19200, stopbits=2) == pytest.approx(11 / 19200)
    assert (
        SerialSettings("x", 9600, "E").longest_hold_s() > SerialSettings("x", 9600).longest_hold_s()
    )


# ---------------------------------------------------------------- the examples
def test_the_vfd_example_moves_in_the_simulator_and_stops() -> None:
    """A velocity-only joint (no position register): NaN position, the output frequency
    ramps towards the setpoint only while the control word says run."""
    description = load(VFD)
    with over_tcp(description) as (device, sim, _):
        keepalive = device.keepalive
        assert keepalive is not None
        keepalive.arm()
        device.set_value("set_frequency", 25.0)
        assert device.poll().velocities == (0.0,)  # not running: the setpoint alone
        device.trigger("run_forward")
        # 25 Hz on a 4-pole motor: 12.5 rev/s.
        wait_for(lambda: sim.velocities_si["motor"] > 0.5 * 25 * math.pi, "the ramp")
        snapshot = device.poll()
        assert len(snapshot.positions) == 0  # no joint has a position register
        assert 0 < snapshot.velocities[0] <= 25 * math.pi + 1e-9
        assert device.exit_stops == {"motion": "stop"}  # what the node's halts send
        device.trigger(device.exit_stops["motion"])
        assert writes(sim)[-1] == (6, Table.HOLDING, 0x2000, (5,))
        wait_for(lambda: sim.velocities_si["motor"] < 0.01, "the ramp down")


def test_a_velocity_only_joint_publishes_nan_beside_a_joint_with_a_position(
    tmp_path: Path,
) -> None:
    text = VFD.read_text().replace(
        "joints:\n",
        "joints:\n  - {name: dial, position: {register: accel_time_deg}}\n",
    )
    text = text.replace(
        "registers:\n",
        "registers:\n  - {name: accel_time_deg, table: holding, address: 0x0200, type: u16,"
        " unit: deg, manual: t}\n",
    )
    path = tmp_path / "two.yaml"
    path.write_text(text)
    with over_tcp(load(path)) as (device, sim, _):
        sim.tick = lambda dt: None  # type: ignore[method-assign]
        sim.set("accel_time_deg", 90)
        sim.set("output_frequency", 10.0)  # 10 Hz on a 4-pole motor: 5 rev/s
        snapshot = device.poll()
        assert snapshot.positions[0] == pytest.approx(math.pi / 2)
        assert math.isnan(snapshot.positions[1])
        # The velocity array is published too, NaN for the joint without a velocity.
        assert len(snapshot.velocities) == 2
        assert math.isnan(snapshot.velocities[0])
        assert snapshot.velocities[1] == pytest.approx(10 * math.pi)
        assert snapshot.efforts == ()  # no joint has an effort register


def test_the_inverter_example_reads_f32_in_cdab_and_abcd() -> None:
    description = load(INVERTER)
    register_map = description.device.register_map
    with over_tcp(description) as (device, sim, channel):
        sim.tick = lambda dt: None  # type: ignore[method-assign]
        sim.set("motor_speed", 1234.5)
        sim.set("motor_position", -2.25)
        cdab = channel.read_registers(register_map["motor_speed"].address, 2, Table.INPUT)
        abcd = channel.read_registers(register_map["motor_position"].address, 2, Table.INPUT)
        big_endian = encode(register_map["motor_position"], 1234.5)
        assert cdab == big_endian[::-1]  # low word first
        assert abcd == encode(register_map["motor_position"], -2.25)
        snapshot = device.poll()
        assert snapshot.positions[0] == pytest.approx(-2.25 * 2 * math.pi)
        assert snapshot.velocities[0] == pytest.approx(1234.5 * 2 * math.pi / 60)
        device.set_value("set_speed", 600.0)
        before = len(sim.write_log)
        device.trigger("start")
        wait_for(lambda: sim.get("motor_speed") > 300.0, "the inverter's ramp")  # type: ignore[operator]
        assert writes(sim)[before:] == [(6, Table.HOLDING, 202, (1,))]


# ---------------------------------------------------------------- replies, keepalive
def test_a_rounded_write_says_what_was_written() -> None:
    with over_tcp(load(VFD)) as (device, sim, _):
        text = device.set_value("set_accel_time", 12.34)
        assert text == "accel_time = 12.3 s written (12.34 rounded to the register's 0.1 s)"
        assert sim.get("accel_time") == pytest.approx(12.3)
        assert device.set_value("set_accel_time", 12.5) == "accel_time = 12.5"


def test_a_trigger_says_what_it_wrote(tmp_path: Path) -> None:
    """A trigger's value the register's 0.1 s rounds is answered as ``~/write`` answers it:
    with what went on the wire."""
    text = VFD.read_text().replace(
        "  values:\n",
        "    - {name: slow_ramp, writes: [{register: accel_time, value: 12.34},"
        " {register: frequency_setpoint, value: 12.5}], starts_motion: false}\n  values:\n",
        1,
    )
    path = tmp_path / "vfd.yaml"
    path.write_text(text)
    with over_tcp(load(path)) as (device, sim, _):
        assert device.trigger("slow_ramp") == (
            "accel_time = 12.3 s written (12.34 rounded to the register's 0.1 s), "
            "frequency_setpoint = 12.5"
        )
        assert sim.get("accel_time") == pytest.approx(12.3)


def test_motion_is_refused_until_the_keepalive_is_armed_then_fed_and_counted() -> None:
    with over_tcp(load(VFD)) as (device, sim, _):
        with pytest.raises(CommandRejected, match="keepalive is not armed"):
            device.trigger("run_forward")
        assert sim.write_log == []
        keepalive = device.keepalive
        assert keepalive is not None and keepalive.next_feed() == -math.inf  # arm now
        keepalive.due()
        assert keepalive.armed
        keepalive.due()
        keepalive.due()
        assert [r.values for r in sim.write_log] == [(1,), (2,), (3,)]  # a counter
        device.trigger("run_forward")
        assert sim.get("control_word") == 1


def test_a_command_topic_value_is_refused_until_the_keepalive_is_armed(tmp_path: Path) -> None:
    """require_keepalive: a non-zero command-topic value is refused, writing nothing, while
    the keepalive is not armed (converted as the node converts a message, then offered to
    the topic's guard); a 0, the stop, is not held back; once armed the value is taken."""
    text = (
        VFD.read_text()
        .replace(
            "  values:\n",
            "  topics:\n    - {name: cmd_frequency, register: frequency_setpoint}\n  values:\n",
            1,
        )
        .replace(
            "register: frequency_setpoint, description",
            "register: frequency_setpoint, starts_motion: false, description",
            1,
        )
    )
    path = tmp_path / "vfd.yaml"
    path.write_text(text)
    with over_tcp(load(path)) as (device, sim, _):
        topic = device.topics["cmd_frequency"]
        guard = stream_of(device, "cmd_frequency")
        with pytest.raises(CommandRejected, match="cmd_frequency: the device's keepalive is not"):
            guard.command(topic.name, device.stream_value(topic, 10.0))
        assert device.stream_value(topic, 0.0) == 0.0
        device.read(["control_word"])  # a later round trip: anything written is logged by now
        assert sim.write_log == []
        keepalive = device.keepalive
        assert keepalive is not None
        keepalive.arm()
        guard.command(topic.name, device.stream_value(topic, 10.0))
        assert sim.get("frequency_setpoint") == pytest.approx(10.0)


def test_the_simulated_watchdog_trips_when_the_feeds_stop_and_stops_the_drive() -> None:
    with over_tcp(load(VFD)) as (device, sim, _):
        keepalive = device.keepalive
        assert keepalive is not None
        keepalive.arm()
        device.set_value("set_frequency", 10.0)
        device.trigger("run_forward")
        assert sim.keepalive_fed_at is not None and sim.keepalive_trips == 0
        wait_for(lambda: sim.keepalive_trips == 1, "the watchdog (2 s without a feed)")
        assert sim.get("control_word") == 5  # the stop trigger's value: the drive stops
        wait_for(lambda: sim.velocities_si["motor"] < 0.01, "the ramp down")


def test_a_period_read_from_a_register_and_a_value_written_back(tmp_path: Path) -> None:
    """The MOTEC example: the lifeguard time (ms) is the watchdog time and the value fed
    back; a drive whose time is 0 is not fed at all."""
    description = load(MULTIDROP)
    device_spec = description.devices[0]
    keepalive = device_spec.keepalive
    assert keepalive is not None and keepalive.period_register == "lifeguard_time"
    assert keepalive.period_to_s == pytest.approx(1e-3)
    text = """\
device:
  name: drive
  manual: t
  link: {tcp: {port: 1502}}
registers:
  - {name: lifeguard_time, table: holding, address: 0x112, type: u16, unit: ms, access: RW,
     manual: t}
  - {name: speed, table: holding, address: 0xAE, type: i16, unit: rpm, access: RW, manual: t}
commands:
  triggers:
    - {name: stop, writes: [{register: speed, value: 0}], stop: true}
keepalive: {register: lifeguard_time, period_from: lifeguard_time}
"""
    path = tmp_path / "drive.yaml"
    path.write_text(text)
    with over_tcp(load(path)) as (device, sim, _):
        feeder = device.keepalive
        assert feeder is not None
        feeder.arm()
        assert not feeder.armed and feeder.next_feed() is None and sim.write_log == []
        device.write("lifeguard_time", 600)  # the user sets the drive's time
        assert feeder.period_s == pytest.approx(0.6) and feeder.next_feed() is not None
        feeder.due()
        assert feeder.armed
        assert [r.values for r in sim.write_log] == [(600,), (600,)]
        sim.set("speed", 100)
        wait_for(lambda: sim.keepalive_trips == 1, "the lifeguard")
        assert sim.get("speed") == 0


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        (
            "starts_motion: true, description",
            "starts_motion: true, group: belt, description",
            "nothing stops group 'belt'",
        ),
        ("stop: true, description", "stop: true, starts_motion: true, description", "not both"),
        ("period_s: 2.0}", "period_s: 2.0, period_from: accel_time}", "exactly one of"),
        (
            "register: comm_watchdog, mode: counter",
            "register: accel_time, mode: toggle, value: 1",
            "writes its own values",
        ),
        ("register: comm_watchdog,", "register: output_current,", "read only"),
        (
            "velocity: {register: output_frequency, per_revolution: 2}",
            "velocity: {register: output_current}",
            "not a revolute velocity",
        ),
        (
            "      per_revolution: 2\n      time_constant_s",
            "      per_revolution: 2\n      mode: position\n      time_constant_s",
            "moves by velocity",
        ),
    ],
)
def test_new_keys_are_checked(tmp_path: Path, old: str, new: str, words: str) -> None:
    text = VFD.read_text()
    assert old in text
    path = tmp_path / "vfd.yaml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(DescriptionError) as caught:
        load(path)
    assert any(words in line for line in caught.value.lines()), caught.value.lines()


def test_exit_stops_are_the_first_stop_of_each_started_group() -> None:
    description: Description = load(VFD)
    assert description.device.exit_stops() == {"motion": "stop"}
    assert isinstance(make_simulator(description).device, DescribedSimDevice)
