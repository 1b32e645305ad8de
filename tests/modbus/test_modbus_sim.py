"""modbus_sim and the device layer, against each other over a real socket and a pty."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.runtime.units import DEG
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import CommandRejected, DeviceException, LinkError, LinkTimeout
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings, TcpSettings
from modbus_bridge.description import Description, load
from modbus_bridge.device import DescribedDevice
from modbus_bridge.sim import DescribedSimDevice, make_simulator
from tests.support.serial_pair import served_on_pty

ROOT = Path(__file__).resolve().parents[2]
MULTIDROP = ROOT / "config" / "devices" / "rtu_multidrop.yaml"
WAIT_S = 20.0

MOVER = """\
device:
  name: mover
  manual: "a test description"
  link: {tcp: {port: 1502}}
  function_codes: [1, 3, 5, 6, 16]
  reply_delay_s: 0.005
registers:
  - {name: position, table: holding, address: 0, type: i32, scale: 1000, unit: deg, manual: t}
  - {name: velocity, table: holding, address: 2, type: i16, scale: 10, unit: deg/s, manual: t}
  - {name: speed_command, table: holding, address: 3, type: i16, scale: 10, unit: deg/s, access: RW, range: [-90, 90], manual: t}
  - {name: target, table: holding, address: 10, type: f32, word_order: low_first, unit: deg, access: RW, range: [-180, 180], manual: t}
  - {name: position_2, table: holding, address: 12, type: f32, unit: deg, manual: t}
  - {name: run, table: coil, address: 0, type: bool, access: RW, manual: t}
  - {name: secret, table: holding, address: 20, type: u16, access: W, manual: t}
joints:
  - {name: j1, position: {register: position}, velocity: {register: velocity}, sim: {command: speed_command}}
  - {name: j2, position: {register: position_2}, sim: {command: target, mode: position, speed: 1.0}}
commands:
  triggers:
    - {name: go, writes: [{register: run, value: true}, {register: speed_command, value: 45}], starts_motion: true}
    - {name: halt, writes: [{register: speed_command, value: 0}], stop: true}
  values:
    - {name: set_target, register: target}
  coils:
    - {name: set_run, register: run, stop_on: false, starts_motion: false}
  topics:
    - {name: cmd_speed, register: speed_command, scale: 57.29577951308232, stop_value: 0}
"""  # noqa: E501


def describe(tmp_path: Path, text: str = MOVER) -> Description:
    path = tmp_path / "mover.yaml"
    path.write_text(text)
    return load(path)


@contextmanager
def over_tcp(
    description: Description,
) -> Iterator[tuple[DescribedDevice, DescribedSimDevice, DeviceChannel]]:
    simulator = make_simulator(description)
    port = simulator.start_tcp()
    sim = simulator.device
    assert isinstance(sim, DescribedSimDevice)
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=2.0))
    channel = DeviceChannel(link, description.device.unit_id, retries=0)
    try:
        yield DescribedDevice(channel, description.device), sim, channel
    finally:
        link.close()
        simulator.stop()


def wait_for(condition: object, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def writes(sim: DescribedSimDevice) -> list[tuple[int, Table, int, tuple[int, ...]]]:
    return [(r.function_code, r.table, r.address, r.values) for r in sim.write_log]


def test_poll_values_and_joints_in_si(tmp_path: Path) -> None:
    with over_tcp(describe(tmp_path)) as (device, sim, _):
        sim.tick = lambda dt: None  # type: ignore[method-assign]
        sim.set("position", -12.345)
        sim.set("velocity", 4.5)
        sim.set("position_2", 90.0)
        sim.set("run", True)
        before = time.time()
        snapshot = device.poll()
        values = dict(zip(snapshot.names, snapshot.values, strict=True))
        assert values["position"] == pytest.approx(-12.345) and values["run"] is True
        assert "secret" not in values  # write only: never read
        assert snapshot.positions == pytest.approx((-12.345 * DEG, 90.0 * DEG))
        # j2 has no velocity register: NaN beside j1's (one entry per joint, decision 14)
        assert snapshot.velocities[0] == pytest.approx(4.5 * DEG)
        assert len(snapshot.velocities) == 2 and math.isnan(snapshot.velocities[1])
        assert snapshot.efforts == ()  # no joint has an effort register
        assert before <= snapshot.read_time <= time.time()
        assert device.read(["velocity", "target"]) == {"velocity": 4.5, "target": 0.0}
        with pytest.raises(CommandRejected, match="write only"):
            device.read(["secret"])


def test_joints_follow_their_command_registers(tmp_path: Path) -> None:
    with over_tcp(describe(tmp_path)) as (device, sim, _):
        device.write("speed_command", 45.0)
        wait_for(lambda: device.poll().positions[0] > 0.1, "j1 to move")
        assert device.read(["velocity"])["velocity"] == pytest.approx(45.0)
        device.write("target", -10.0)  # deg, approached at 1 rad/s
        wait_for(lambda: device.poll().positions[1] < -0.05, "j2 to move")
        wait_for(lambda: device.poll().positions[1] == pytest.approx(-10 * DEG, abs=1e-6), "j2")
        device.write("speed_command", 0.0)
        stopped = device.poll().positions[0]
        sim_position = sim.positions_si["j1"]
        assert stopped == pytest.approx(sim_position, abs=1e-3)


def test_a_joint_stops_at_the_end_of_its_register(tmp_path: Path) -> None:
    """An integrated position past what its register holds (i16 at 0.01 deg: +-327.67)
    is clamped there, as at a hard stop; it never fails to encode (which stopped the
    server)."""
    text = MOVER.replace("type: i32, scale: 1000, unit: deg", "type: i16, scale: 100, unit: deg")
    sim = make_simulator(describe(tmp_path, text)).device
    assert isinstance(sim, DescribedSimDevice)
    sim.set("speed_command", 90.0)
    sim.tick(5.0)  # 450 deg commanded
    assert sim.get("position") == pytest.approx(327.67)
    assert sim.positions_si["j1"] == pytest.approx(327.67 * DEG)
    assert sim.get("velocity") == pytest.approx(327.67 / 5.0, abs=0.1)  # what it moved
    sim.tick(1.0)
    assert sim.get("position") == pytest.approx(327.67)
    assert sim.get("velocity") == 0.0  # held at the end
    sim.set("speed_command", -90.0)
    sim.tick(10.0)
    assert sim.get("position") == pytest.approx(-327.68)


def test_a_failing_tick_is_logged_once_and_the_simulator_keeps_serving(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    with over_tcp(describe(tmp_path)) as (device, sim, _):
        failures: list[float] = []

        def failing(dt: float) -> None:
            failures.append(dt)
            raise ValueError("joint model broken")

        sim.tick = failing  # type: ignore[method-assign]
        wait_for(lambda: len(failures) >= 3, "three failing ticks")
        assert device.read(["target"]) == {"target": 0.0}  # still served
    lines = [line for line in capfd.readouterr().err.splitlines() if "tick failed" in line]
    assert lines == ["simulator: unit 1 tick failed: ValueError: joint model broken"]


def stream_of(device: DescribedDevice, name: str) -> StreamGuard[str]:
    """The guard the node attaches to command topic ``name`` (as modbus_bridge.node)."""
    topic = device.topics[name]
    guard: StreamGuard[str] = StreamGuard(
        [name],
        lambda _key, value, _previous: device.send_stream(topic, value),
        lambda _key: device.stop_stream(topic),
        timeout_s=60.0,
        stop_when_idle=False,
    )
    device.attach_stream(name, guard)
    return guard


TWO_STREAMS = MOVER.replace(
    "  topics:\n", "  topics:\n    - {name: cmd_run, register: run_speed}\n"
).replace(
    "  - {name: secret,",
    "  - {name: run_speed, table: holding, address: 21, type: i16, access: RW, manual: t}\n"
    "  - {name: secret,",
)


def test_stop_services_lock_every_command_stream(tmp_path: Path) -> None:
    """A trigger that is no stop and the coil's other value lock nothing. A stop locks
    every stream: the one whose register it wrote is known stopped (a 0 writes nothing),
    another keeps its motion (a 0 sends its own stop); a non-zero value is refused until
    a 0."""
    with over_tcp(describe(tmp_path, TWO_STREAMS)) as (device, sim, _):
        sim.tick = lambda dt: None  # type: ignore[method-assign]
        speed, other = stream_of(device, "cmd_speed"), stream_of(device, "cmd_run")
        speed.command("cmd_speed", 50.0)
        other.command("cmd_run", 5.0)
        device.trigger("go")
        device.set_coil("set_run", True)
        assert not speed["cmd_speed"].locked and not other["cmd_run"].locked
        device.set_coil("set_run", False)  # a stop that writes no stream's register
        assert speed["cmd_speed"].locked and speed["cmd_speed"].active
        assert other["cmd_run"].locked and other["cmd_run"].active
        with pytest.raises(CommandRejected, match="was stopped"):
            speed.command("cmd_speed", 60.0)
        written = len(sim.write_log)
        assert speed.command("cmd_speed", 0.0)  # unlocks and sends the stream's own stop
        assert [(r.address, r.values) for r in sim.write_log[written:]] == [(3, (0,))]
        speed.command("cmd_speed", 50.0)
        device.trigger("halt")  # writes speed_command
        assert speed["cmd_speed"].locked and not speed["cmd_speed"].may_move
        assert other["cmd_run"].locked and other["cmd_run"].active
        with pytest.raises(CommandRejected, match="was stopped"):
            speed.command("cmd_speed", 60.0)
        written = len(sim.write_log)
        assert not speed.command("cmd_speed", 0.0)  # unlocks; halt stopped it already
        assert len(sim.write_log) == written
        speed.command("cmd_speed", 60.0)
        assert (sim.write_log[-1].address, sim.write_log[-1].values) == (3, (600,))


def test_a_lost_stop_leaves_the_stream_locked_with_its_stop_pending(tmp_path: Path) -> None:
    description = describe(tmp_path)
    simulator = make_simulator(description)
    port = simulator.start_tcp()
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=2.0))
    try:
        device = DescribedDevice(DeviceChannel(link, 1, retries=0), description.device)
        speed = stream_of(device, "cmd_speed")
        speed.command("cmd_speed", 50.0)
        simulator.stop()
        with pytest.raises(LinkError):
            device.trigger("halt")
        state = speed["cmd_speed"]
        assert state.locked and state.stop_pending  # the deadman keeps sending its stop
        with pytest.raises(CommandRejected):
            speed.command("cmd_speed", 60.0)
    finally:
        link.close()
        simulator.stop()


def test_commands_write_what_the_file_says(tmp_path: Path) -> None:
    with over_tcp(describe(tmp_path)) as (device, sim, _):
        assert device.trigger("go") == "run = True, speed_command = 45"
        assert device.set_value("set_target", 12.5) == "target = 12.5"
        device.set_coil("set_run", False)
        topic = device.topics["cmd_speed"]
        device.send_stream(topic, device.stream_value(topic, 0.5))  # rad/s -> 28.6 deg/s
        device.stop_stream(topic)
        assert writes(sim) == [
            (5, Table.COIL, 0, (1,)),
            (6, Table.HOLDING, 3, (450,)),
            (16, Table.HOLDING, 10, (0x0000, 0x4148)),  # 12.5 as f32, low word first
            (5, Table.COIL, 0, (0,)),
            (6, Table.HOLDING, 3, (286,)),
            (6, Table.HOLDING, 3, (0,)),
        ]


@pytest.mark.parametrize(
    ("action", "words"),
    [
        (lambda d: d.write("velocity", 1.0), "read only"),
        (lambda d: d.write("speed_command", 90.1), "outside -90.0..90.0"),
        (lambda d: d.write("speed_command", math.nan), "not a finite"),
        (lambda d: d.write("run", 1), "true or false"),
        (lambda d: d.write("target", True), "takes a number"),
        (lambda d: d.write("nothing", 1), "no register named"),
        (lambda d: d.trigger("nothing"), "no trigger"),
        (lambda d: d.set_value("set_target", 200.0), "outside"),
        (lambda d: d.stream_value(d.topics["cmd_speed"], 2.0), "outside"),  # 114.6 deg/s
    ],
)
def test_refusals_write_nothing(tmp_path: Path, action: object, words: str) -> None:
    with over_tcp(describe(tmp_path)) as (device, sim, _):
        with pytest.raises(CommandRejected, match=words):
            action(device)  # type: ignore[operator]
        device.read(["run"])  # a later round trip: anything written would be logged by now
        assert sim.write_log == []


def test_the_simulator_is_as_strict_as_the_file(tmp_path: Path) -> None:
    with over_tcp(describe(tmp_path)) as (_, sim, channel):

        def code(action: object) -> int:
            with pytest.raises(DeviceException) as caught:
                action()  # type: ignore[operator]
            return caught.value.exception_code

        assert code(lambda: channel.read_registers(0, 1, Table.INPUT)) == 1  # FC 04 not listed
        assert code(lambda: channel.read_bits(0, 1, Table.DISCRETE_INPUT)) == 1  # nor FC 02
        assert code(lambda: channel.read_registers(0, 6)) == 2  # 4-9 are undefined
        assert code(lambda: channel.read_registers(1, 2)) == 2  # cuts position in two
        assert code(lambda: channel.read_registers(20, 1)) == 2  # write only
        assert code(lambda: channel.write_register(2, 5)) == 2  # read only
        assert code(lambda: channel.write_register(3, 901)) == 3  # 90.1 deg/s: out of range
        assert sim.write_log == []
        start = time.monotonic()
        channel.read_registers(0, 4)
        assert time.monotonic() - start >= 0.005  # reply_delay_s


def test_values_are_the_only_writes_the_device_layer_and_the_simulator_take(
    tmp_path: Path,
) -> None:
    text = MOVER.replace(
        "range: [-90, 90], manual", "range: [-90, 90], values: [-45, 0, 45], manual"
    )
    with over_tcp(describe(tmp_path, text)) as (device, sim, channel):
        with pytest.raises(CommandRejected, match="speed_command takes one of -45, 0, 45, not 30"):
            device.write("speed_command", 30)
        topic = device.topics["cmd_speed"]
        with pytest.raises(CommandRejected, match="takes one of"):
            device.stream_value(topic, 0.5)  # 28.6 deg/s
        assert sim.write_log == []
        # The simulator refuses it too (a bridge that skipped the check): 30.0 deg/s.
        with pytest.raises(DeviceException) as caught:
            channel.write_register(3, 300)
        assert caught.value.exception_code == 3  # ILLEGAL DATA VALUE
        assert sim.write_log == [] and sim.get("speed_command") == 0.0
        assert device.write("speed_command", -45) == "speed_command = -45"
        assert device.trigger("go") == "run = True, speed_command = 45"
        assert [r.values for r in sim.write_log if r.address == 3] == [(0xFE3E,), (450,)]


def test_xarm_arm_state_takes_only_the_sdks_set_state_values() -> None:
    """H33: 0 start, 3 pause, 4 stop (xarm_bridge's values); 1 and 2 are in the range
    but no command of the SDK."""
    with over_tcp(load(ROOT / "config" / "devices" / "xarm.yaml")) as (device, sim, channel):
        for value in (1, 2):
            with pytest.raises(CommandRejected, match="arm_state takes one of 0, 3, 4"):
                device.write("arm_state", value)
            with pytest.raises(DeviceException, match="ILLEGAL DATA VALUE"):
                channel.write_register(33, value)
        assert sim.write_log == []
        assert device.trigger("pause") == "arm_state = 3"


def test_undefined_rows_and_limits_as_the_file_says(tmp_path: Path) -> None:
    text = MOVER.replace(
        "  reply_delay_s: 0.005\n",
        "  read_undefined: true\n  max_read_registers: 14\n  max_write_bits: 1\n",
    ).replace("[1, 3, 5, 6, 16]", "[1, 3, 5, 6, 15, 16]")
    with over_tcp(describe(tmp_path, text)) as (device, sim, channel):
        assert channel.read_registers(0, 8)[4:] == [0, 0, 0, 0]  # 4-7 undefined: read 0
        with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
            channel.read_registers(0, 15)  # more than max_read_registers
        with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
            channel.write_coils(0, [True, True])  # more than max_write_bits
        assert sim.write_log == []
        # The holding rows merge through the undefined ones: one request for 0-13.
        assert [(r.table, r.address, r.count) for r in device.groups.fast] == [
            (Table.COIL, 0, 1),
            (Table.HOLDING, 0, 14),
        ]


def test_multidrop_line_on_a_pty() -> None:
    description = load(MULTIDROP)
    simulator: Simulator = make_simulator(description)
    with served_on_pty(simulator, 115200) as port:
        link = ModbusLink(SerialSettings(port, 115200, timeout_s=0.5))
        try:
            channels = [DeviceChannel(link, d.unit_id, retries=0) for d in description.devices]
            devices = [
                DescribedDevice(c, d) for c, d in zip(channels, description.devices, strict=True)
            ]
            simulator.devices[2].set("position_actual", -70000)
            first, second = devices[0].poll(), devices[1].poll()
            assert dict(zip(second.names, second.values, strict=True))["position_actual"] == -70000
            assert dict(zip(first.names, first.values, strict=True))["position_actual"] == 0
            devices[1].trigger("stop")
            assert [r.unit_id for r in simulator.devices[2].write_log] == [2]
            assert simulator.devices[1].write_log == []
            with pytest.raises(LinkTimeout):  # no unit 3 on the line: silence
                DeviceChannel(link, 3, retries=0).read_registers(0xAC, 2)
        finally:
            link.close()


def test_console_script_serves_the_file(tmp_path: Path) -> None:
    description = describe(tmp_path)
    port_file = tmp_path / "port"
    log = tmp_path / "writes.jsonl"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "modbus_bridge.sim",
            "--device-file",
            str(description.path),
            "--port",
            "0",
            "--port-file",
            str(port_file),
            "--write-log",
            str(log),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        assert process.stdout.readline().startswith("modbus_sim mover (unit 1) listening")
        link = ModbusLink(TcpSettings("127.0.0.1", int(port_file.read_text()), timeout_s=2.0))
        try:
            device = DescribedDevice(DeviceChannel(link, 1, retries=0), description.device)
            device.set_coil("set_run", True)
        finally:
            link.close()
        assert '"address": 0, "values": [1]' in log.read_text()
    finally:
        process.terminate()
        process.wait(10)


def test_a_bad_file_is_one_line_and_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(MOVER.replace("address: 20,", "address: 70000,"))
    result = subprocess.run(
        [sys.executable, "-m", "modbus_bridge.sim", "--device-file", str(bad)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 2
    (line,) = result.stderr.splitlines()
    assert line.startswith(f"error: {bad}:14: registers[6].address: ")


@pytest.mark.parametrize("flag", [["--nagle"], ["--one-request-at-a-time"]])
def test_the_tcp_network_options_are_refused_on_a_serial_line(
    flag: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A TCP-only simulator option on an RTU serve says so instead of being ignored."""
    from modbus_bridge.sim import main

    with pytest.raises(SystemExit) as raised:
        main(["--device-file", str(MULTIDROP), "--pty", str(tmp_path / "pty"), *flag])
    assert raised.value.code == 2
    err = capsys.readouterr().err
    assert "do not apply to --serial / --pty" in err
    assert "Traceback" not in err
    assert not (tmp_path / "pty").exists()
