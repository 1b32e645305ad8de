"""Device personalities for modbus_bridge: the described devices' simulator plays a device that does
not obey (``--ignore`` of the file's motion writes) or answers late (``--reply-delay-ms``),
and the bridge reports no success it did not read back (decision 19,
docs/decisions/modbus.md).

The shipped examples are the devices: the inverter on Modbus TCP
(config/devices/inverter_tcp_f32.yaml: ~/start, ~/stop, ~/joint_commands velocities)
and the VFD on RTU 8E1 over a pty (config/devices/vfd_rtu.yaml: ~/run_forward, ~/stop,
its keepalive). For each way motion starts, stops or changes, against a device that
ignores that write: never success; the reply says what was written and what was read
back; a halt (exit, deactivate, read_only) still sends its stop (the simulator's write
log has it, ``ignored``) and the node logs "not confirmed". Against a device answering
late (TCP round trips 0-50 ms; the VFD on RTU 50-300 ms): the bridge connects at start,
polls, reconnects after an outage, and a stop goes out at once, also on a link marked
down.
"""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import LinkTimeout, NotConfirmed
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings, TcpSettings
from modbus_bridge.description import load
from modbus_bridge.device import DescribedDevice
from modbus_bridge.sim import DescribedSimDevice, make_simulator
from msg_defs.msg import DeviceValues
from msg_defs.srv import SetValue, WriteRegister

from ..support.fixtures import client_fixture
from ..support.ros import (
    Bridge,
    Client,
    node_process,
    unique_namespace,
    wait_for,
    wait_subscribed,
)
from .test_exit_stops import SIM_IN_TEST_TIMEOUT_S, WATCHDOG, running_forward, vfd_on_pty

ROOT = Path(__file__).resolve().parents[2]
INVERTER = ROOT / "config" / "devices" / "inverter_tcp_f32.yaml"
VFD = ROOT / "config" / "devices" / "vfd_rtu.yaml"
INVERTER_MAP = load(INVERTER).device.register_map
RUN = INVERTER_MAP["run"].address
SPEED = INVERTER_MAP["speed_setpoint"].address
VFD_MAP = load(VFD).device.register_map
CONTROL_WORD = VFD_MAP["control_word"].address
WAIT_S = 30.0
EXIT_TIMEOUT_S = 20.0
TIMEOUT_S = 1.0
# A device on TCP whose round trip is up to this.
TCP_ROUND_TRIP_MAX_S = 0.05
SIM = (sys.executable, "-m", "modbus_bridge.sim")
# The RTU row's device: a reply delay drawn in this range (the link's timeout_s is
# SIM_IN_TEST_TIMEOUT_S, past a pty's stalls: tests/support/serial_pair.py).
RTU_DELAY_S = (0.05, 0.3)
# The pty row's device delay: far above what a 0.2 s reply timeout allows.
PTY_DELAY_MS = 400.0


# ------------------------------------------------------------------ the simulator
def test_the_ignorable_names_are_the_files_motion_writes() -> None:
    """The VFD's: its triggers that start or stop, and the registers they and its joint
    move by; a write is each name whose write it is (a parameter is none)."""
    simulator = make_simulator(load(VFD))
    device = simulator.device
    assert isinstance(device, DescribedSimDevice)
    assert set(device.IGNORABLE) == {"run_forward", "stop", "control_word", "frequency_setpoint"}
    assert DescribedSimDevice.IGNORABLE == {}  # the instance's own, not the class's

    def names(address: int, *values: int) -> frozenset[str]:
        return device.write_names(WriteRecord(0.0, 1, 6, Table.HOLDING, address, values))

    assert names(CONTROL_WORD, 1) == {"run_forward", "control_word"}
    assert names(CONTROL_WORD, 5) == {"stop", "control_word"}
    assert names(VFD_MAP["frequency_setpoint"].address, 1000) == {"frequency_setpoint"}
    assert names(VFD_MAP["accel_time"].address, 50) == frozenset()


def test_an_unknown_ignore_name_is_one_line_naming_the_files_motion_writes() -> None:
    result = subprocess.run(
        [*SIM, "--device-file", str(INVERTER), "--ignore", "start,jump"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 2, result.stderr
    (line,) = result.stderr.splitlines()
    assert line == (
        f"error: --ignore jump: not a motion write of {INVERTER}; "
        "its motion writes: run, speed_setpoint, start, stop"
    )


@contextmanager
def sim_process(*args: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """``modbus_sim`` in its own process; yields it and its banner line."""
    process = subprocess.Popen(
        [*SIM, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        banner = process.stdout.readline()
        assert "listening" in banner, banner + (process.stderr.read() if process.stderr else "")
        yield process, banner
    finally:
        process.terminate()
        process.wait(10)


def test_ignore_on_the_command_line_acknowledges_and_changes_nothing(tmp_path: Path) -> None:
    port_file, log = tmp_path / "port", tmp_path / "writes.jsonl"
    with sim_process(
        "--device-file",
        str(INVERTER),
        "--port",
        "0",
        "--port-file",
        str(port_file),
        "--write-log",
        str(log),
        "--ignore",
        "start",
    ) as (_, banner):
        assert "(ignores start)" in banner
        link = ModbusLink(TcpSettings("127.0.0.1", int(port_file.read_text()), timeout_s=2.0))
        try:
            device = DescribedDevice(DeviceChannel(link, 1, retries=0), load(INVERTER).device)
            with pytest.raises(NotConfirmed, match=r"wrote run = 1, read back run = 0 \("):
                device.trigger("start")
            device.write("speed_setpoint", 100.0)  # not a motion write it ignores
        finally:
            link.close()
    text = log.read_text()
    assert f'"address": {RUN}, "values": [1], "ignored": true' in text, text
    assert f'"address": {SPEED}, "values": [17096, 0], "ignored": false' in text, text


def test_the_reply_delay_applies_on_a_pty(tmp_path: Path) -> None:
    """``--reply-delay-ms`` on ``--pty``: the VFD (its file says no delay) answers after
    400 ms, so a read takes at least that, and a 0.2 s reply timeout misses it."""
    pty = tmp_path / "vfd"
    with sim_process("--device-file", str(VFD), "--pty", str(pty), "--reply-delay-ms", "400"):
        patient = ModbusLink(SerialSettings(str(pty), 19200, "E", 1, timeout_s=5.0))
        try:
            started = time.monotonic()
            DeviceChannel(patient, 1, retries=0).read_registers(CONTROL_WORD, 1)
            assert time.monotonic() - started >= PTY_DELAY_MS / 1000
        finally:
            patient.close()
        hasty = ModbusLink(SerialSettings(str(pty), 19200, "E", 1, timeout_s=0.2))
        try:
            with pytest.raises(LinkTimeout):
                DeviceChannel(hasty, 1, retries=0).read_registers(CONTROL_WORD, 1)
        finally:
            hasty.close()


# ------------------------------------------------------------------ the device layer
@contextmanager
def inverter_device(
    *ignore: str,
) -> Iterator[tuple[DescribedDevice, DescribedSimDevice, Simulator]]:
    description = load(INVERTER)
    simulator = make_simulator(description)
    simulator.ignore(ignore)
    port = simulator.start_tcp()
    sim = simulator.device
    assert isinstance(sim, DescribedSimDevice)
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=2.0))
    try:
        yield DescribedDevice(DeviceChannel(link, 1, retries=0), description.device), sim, simulator
    finally:
        link.close()
        simulator.stop()


def test_a_write_that_reads_back_is_confirmed_and_one_ignored_is_not() -> None:
    with inverter_device("speed_setpoint") as (device, sim, _):
        assert device.trigger("start") == "run = 1"
        with pytest.raises(NotConfirmed) as raised:
            device.write("speed_setpoint", 600.0)
        assert str(raised.value) == (
            "wrote speed_setpoint = 600.0, read back speed_setpoint = 0 rpm (sent, not confirmed)"
        )
        assert sim.write_log[-1].ignored


def test_a_stop_not_confirmed_leaves_the_streams_locked_with_their_stop_pending() -> None:
    with inverter_device("stop") as (device, sim, _):
        from bridge_core.runtime.stream_guard import StreamGuard

        written: list[float] = []
        guard: StreamGuard[str] = StreamGuard(
            ["shaft"], lambda _k, v, _p: written.append(v), lambda _k: None, timeout_s=1.0
        )
        device.attach_joint_stream(guard, "shaft", "speed_setpoint")
        guard.command("shaft", 5.0)
        device.trigger("start")
        with pytest.raises(NotConfirmed, match=r"wrote run = 0, read back run = 1 \("):
            device.trigger("stop")
        assert guard["shaft"].locked and guard["shaft"].stop_pending
        assert sim.write_log[-1].ignored and sim.get("run") == 1


def test_a_write_only_register_is_sent_not_confirmed(tmp_path: Path) -> None:
    """Nothing can read it back: the answer says so instead of success."""
    text = INVERTER.read_text().replace(
        "  - {name: torque_limit,",
        "  - {name: jog_pulse, table: holding, address: 210, type: u16, access: W, "
        'manual: "t"}\n  - {name: torque_limit,',
    )
    path = tmp_path / "inverter.yaml"
    path.write_text(text)
    description = load(path)
    simulator = make_simulator(description)
    port = simulator.start_tcp()
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=2.0))
    try:
        device = DescribedDevice(DeviceChannel(link, 1, retries=0), description.device)
        with pytest.raises(NotConfirmed) as raised:
            device.write("jog_pulse", 3)
        assert str(raised.value) == (
            "wrote jog_pulse = 3; jog_pulse is write only, nothing reads it back "
            "(sent, not confirmed)"
        )
        assert simulator.device.get("jog_pulse") == 3  # it went out
    finally:
        link.close()
        simulator.stop()


# ------------------------------------------------------------------ the node (ROS)
client = client_fixture("modbus_personality_client", log=True, scope="module")


@contextmanager
def inverter_bridge(
    client: Client, tmp_path: Path, *, round_trip_max_s: float = 0.0, **params: Any
) -> Iterator[tuple[Bridge, Any, Simulator, DescribedSimDevice]]:
    """The inverter example served in this process over TCP, the bridge in its own,
    connected."""
    simulator = make_simulator(load(INVERTER))
    simulator.set_round_trip(0.0, round_trip_max_s)
    port = simulator.start_tcp()
    sim = simulator.device
    assert isinstance(sim, DescribedSimDevice)
    values: dict[str, Any] = {
        "device_file": str(INVERTER),
        "port": port,
        "poll_rate_hz": 20.0,
        "timeout_s": TIMEOUT_S,
        "reconnect_max_s": 0.5,
    }
    values.update(params)
    try:
        b = Bridge(client, unique_namespace("inverter"), "modbus_bridge", DeviceValues)
        with node_process("modbus_bridge.node", values, tmp_path, ["-r", f"__ns:={b.ns}"]) as proc:
            b.wait_connected(True, timeout=WAIT_S)
            yield b, proc, simulator, sim
    finally:
        simulator.stop()


def writes(sim: DescribedSimDevice, since: int = 0) -> list[tuple[int, tuple[int, ...], bool]]:
    """The writes after ``since``: (address, values, ignored)."""
    return [(r.address, r.values, r.ignored) for r in sim.write_log[since:]]


def node_log(tmp_path: Path) -> str:
    return (tmp_path / "modbus_bridge_node.log").read_text()


def test_a_start_the_device_ignores_is_not_success_and_still_stopped_on_exit(
    client: Client, tmp_path: Path
) -> None:
    with inverter_bridge(client, tmp_path) as (b, proc, simulator, sim):
        simulator.ignore(["start"])
        reply = b.call(Trigger, "start")
        assert not reply.success
        assert reply.message == (
            "start: not confirmed: wrote run = 1, read back run = 0 (sent, not confirmed)"
        )
        # Written: it may run; the exit stops it all the same.
        before = len(sim.write_log)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(EXIT_TIMEOUT_S) == 0
        assert writes(sim, before) == [(RUN, (0,), False)]


@pytest.mark.parametrize(
    ("service", "fields", "written"),
    [
        ("write", {"name": "run", "value": 1.0}, "wrote run = 1.0, read back run = 0"),
        (
            "set_speed",
            {"value": 600.0},
            "wrote speed_setpoint = 600.0, read back speed_setpoint = 0 rpm",
        ),
    ],
    ids=["write", "set_speed"],
)
def test_a_write_the_device_ignores_is_not_success(
    client: Client, tmp_path: Path, service: str, fields: dict[str, Any], written: str
) -> None:
    with inverter_bridge(client, tmp_path) as (b, _, simulator, sim):
        simulator.ignore(["run", "speed_setpoint"])
        srv = WriteRegister if service == "write" else SetValue
        request = srv.Request()
        for key, value in fields.items():
            setattr(request, key, value)
        reply = client.call(srv, b.service(service), request)
        assert not reply.success
        assert reply.message.endswith(f": not confirmed: {written} (sent, not confirmed)"), (
            reply.message
        )
        assert sim.write_log[-1].ignored


def _deactivate(client: Client, b: Bridge) -> None:
    request = ChangeState.Request()
    request.transition.id = Transition.TRANSITION_DEACTIVATE
    reply = client.call(ChangeState, f"{b.ns}/modbus_bridge/change_state", request)
    assert reply.success


def _read_only(client: Client, b: Bridge) -> None:
    value = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True)
    request = SetParameters.Request(parameters=[Parameter(name="read_only", value=value)])
    reply = client.call(SetParameters, b.service("set_parameters"), request)
    assert reply.results[0].successful, reply.results[0].reason


@pytest.mark.parametrize("way", ["service", "exit", "deactivate", "read_only"])
def test_a_stop_the_device_ignores_is_tried_and_said_not_confirmed(
    client: Client, tmp_path: Path, way: str
) -> None:
    """``~/stop`` answers what it wrote and read; each halt still sends the stop (the
    write log has it, ignored) and logs "not confirmed"."""
    with inverter_bridge(client, tmp_path) as (b, proc, simulator, sim):
        reply = b.call(Trigger, "start")
        assert reply.success, reply.message
        simulator.ignore(["stop"])
        before = len(sim.write_log)
        since = time.monotonic()
        if way == "service":
            reply = b.call(Trigger, "stop")
            assert not reply.success
            assert reply.message == (
                "stop: not confirmed: wrote run = 0, read back run = 1 (sent, not confirmed)"
            )
        elif way == "exit":
            proc.send_signal(signal.SIGINT)
            assert proc.wait(EXIT_TIMEOUT_S) == 0
            log = node_log(tmp_path)
            # (the node base's wording around it: "start: its stop went out, not confirmed")
            said = "(the node is exiting): wrote run = 0, read back run = 1 (sent, not confirmed)"
            assert "start: its stop" in log and said in log, log
        else:
            (_deactivate if way == "deactivate" else _read_only)(client, b)
            client.wait_log("modbus_bridge", "read back run = 1 (sent, not confirmed)", since)
        assert writes(sim, before)[0] == (RUN, (0,), True)
        assert sim.get("run") == 1  # the device never stopped: nothing said it did


def _publisher(client: Client, b: Bridge) -> Any:
    publisher = client.node.create_publisher(JointState, b.service("joint_commands"), 10)
    wait_subscribed(publisher)
    return publisher


def _velocity(publisher: Any, value: float) -> None:
    publisher.publish(JointState(name=["shaft"], velocity=[value]))


def test_joint_commands_the_device_ignores_are_said_not_confirmed_and_the_deadman_still_stops(
    client: Client, tmp_path: Path
) -> None:
    """``~/joint_commands`` velocities go to speed_setpoint: one the device ignores is
    refused "not confirmed"; once the stream runs and the device stops obeying, the
    deadman's stop still goes out (ignored) and is logged not confirmed."""
    with inverter_bridge(client, tmp_path, command_timeout_s=0.5) as (b, _, simulator, sim):
        publisher = _publisher(client, b)
        simulator.ignore(["speed_setpoint"])
        since = time.monotonic()
        _velocity(publisher, 1.0)
        client.wait_log("modbus_bridge", "(sent, not confirmed)", since)
        wait_for(lambda: sim.write_log and sim.write_log[-1].ignored, WAIT_S, "the ignored write")
        simulator.ignore([])
        _velocity(publisher, 2.0)
        wait_for(lambda: sim.get("speed_setpoint") != 0, WAIT_S, "the stream's speed")
        simulator.ignore(["speed_setpoint"])
        before = len(sim.write_log)
        since = time.monotonic()
        # silence: the deadman (0.5 s) stops the stream
        client.wait_log("modbus_bridge", "read back speed_setpoint", since)
        assert writes(sim, before)[0] == (SPEED, (0, 0), True)
        assert sim.get("speed_setpoint") != 0


def test_the_vfd_on_rtu_stop_ignored_on_exit_is_tried_and_said_not_confirmed(
    client: Client, tmp_path: Path
) -> None:
    with running_forward(client, tmp_path) as (_, proc, _, device):
        device.ignore = frozenset({"stop"})
        before = len(device.write_log)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(EXIT_TIMEOUT_S) == 0
        stops = [r for r in device.write_log[before:] if r.address == CONTROL_WORD]
        assert [(r.values, r.ignored) for r in stops] == [((5,), True)]
        log = node_log(tmp_path)
        said = (
            "(the node is exiting): wrote control_word = 5, read back control_word = 1 "
            "(sent, not confirmed)"
        )
        assert "run_forward: its stop" in log and said in log, log


def test_the_vfd_run_forward_ignored_is_not_success(client: Client, tmp_path: Path) -> None:
    with running_forward(client, tmp_path) as (b, _, _, device):
        # The velocity-only joint's position is NaN (one per name, as
        # sensor_msgs/JointState wants), not an empty array; a field no joint has is empty.
        states = client.wait_message(b.joint_states, timeout=WAIT_S)
        assert len(states.name) == 1 and len(states.velocity) == 1
        assert len(states.position) == 1 and math.isnan(states.position[0]), states
        assert list(states.effort) == []
        assert b.call(Trigger, "stop").success
        device.ignore = frozenset({"run_forward"})
        reply = b.call(Trigger, "run_forward")
        assert not reply.success
        assert reply.message == (
            "run_forward: not confirmed: wrote control_word = 1, read back control_word = 5 "
            "(sent, not confirmed)"
        )


# ------------------------------------------------------------------ a late TCP device
def test_a_tcp_device_answering_up_to_50_ms_late(client: Client, tmp_path: Path) -> None:
    """Round trips drawn in 0-50 ms: the bridge connects at start, polls, reconnects
    after an outage, and a stop goes out at once, also while the link is down."""
    with inverter_bridge(client, tmp_path, round_trip_max_s=TCP_ROUND_TRIP_MAX_S) as (
        b,
        _,
        simulator,
        sim,
    ):
        since = time.monotonic()
        wait_for(lambda: len(client.received(b.joint_states, since)) >= 10, WAIT_S, "polls")
        assert b.call(Trigger, "start").success
        reply = b.call(Trigger, "stop")
        assert reply.success, reply.message
        assert sim.get("run") == 0
        cut = time.monotonic()
        simulator.withhold_replies = True
        b.wait_connected(False, since=cut, timeout=WAIT_S)
        heard = len(simulator.withheld_writes)
        reply = b.call(Trigger, "stop")  # tried at once on a link marked down
        assert not reply.success
        wait_for(lambda: simulator.withheld_writes[heard:], WAIT_S, "the stop, heard")
        assert [(r.address, r.values) for r in simulator.withheld_writes[heard:]] == [(RUN, (0,))]
        back = time.monotonic()
        simulator.withhold_replies = False
        b.wait_connected(True, since=back, timeout=WAIT_S)
        wait_for(lambda: len(client.received(b.joint_states, back)) >= 10, WAIT_S, "polls again")


def test_a_pending_stream_stop_the_device_ignores_does_not_stop_the_polls(
    client: Client, tmp_path: Path
) -> None:
    """A ``~/joint_commands`` stop lost in an outage is pending; when the link is back it
    goes out first, and the device ignores it: said "not confirmed", and the bridge polls
    on (the deadman keeps sending the stop) instead of failing its link-up for ever."""
    with inverter_bridge(client, tmp_path, command_timeout_s=0.5) as (b, _, simulator, sim):
        publisher = _publisher(client, b)
        _velocity(publisher, 2.0)
        wait_for(lambda: sim.get("speed_setpoint") != 0, WAIT_S, "the stream's speed")
        cut = time.monotonic()
        simulator.withhold_replies = True
        b.wait_connected(False, since=cut, timeout=WAIT_S)
        heard = len(simulator.withheld_writes)
        # silence: the deadman's stop goes out on the dead link, and stays pending
        wait_for(lambda: len(simulator.withheld_writes) > heard, WAIT_S, "the lost stop")
        simulator.ignore(["speed_setpoint"])
        back = time.monotonic()
        simulator.withhold_replies = False
        b.wait_connected(True, since=back, timeout=WAIT_S)
        wait_for(lambda: len(client.received(b.joint_states, back)) >= 10, WAIT_S, "polls again")
        client.wait_log("modbus_bridge", "read back speed_setpoint", back)
        assert sim.get("speed_setpoint") != 0


def test_an_rtu_device_answering_50_to_300_ms_late(client: Client, tmp_path: Path) -> None:
    """The VFD on its pty answering 50-300 ms after each request: the bridge connects at
    start, polls, its commands are confirmed, it reconnects after an outage, and a stop
    goes out at once while the link is marked down."""
    with vfd_on_pty() as (simulator, device, port):
        simulator.set_reply_delay(*RTU_DELAY_S)
        params = {
            "device_file": str(VFD),
            "serial_port": port,
            "poll_rate_hz": 10.0,
            "reconnect_max_s": 0.5,
            "timeout_s": SIM_IN_TEST_TIMEOUT_S,
        }
        b = Bridge(client, unique_namespace("vfd_late"), "modbus_bridge", DeviceValues)
        with node_process("modbus_bridge.node", params, tmp_path, ["-r", f"__ns:={b.ns}"]):
            b.wait_connected(True, timeout=WAIT_S)
            since = time.monotonic()
            wait_for(lambda: len(client.received(b.state, since)) >= 5, WAIT_S, "polls")
            wait_for(lambda: device.writes_to(WATCHDOG), WAIT_S, "the keepalive armed")
            reply = b.call_sent(Trigger, "run_forward")
            assert reply.success, reply.message
            reply = b.call_sent(Trigger, "stop")
            assert reply.success, reply.message
            cut = time.monotonic()
            simulator.withhold_replies = True
            b.wait_connected(False, since=cut, timeout=WAIT_S)
            heard = len(simulator.withheld_writes)
            reply = b.call(Trigger, "stop")  # tried at once on a link marked down
            assert not reply.success

            def stops() -> list[tuple[int, tuple[int, ...]]]:
                return [
                    (r.address, r.values)
                    for r in simulator.withheld_writes[heard:]
                    if r.address == CONTROL_WORD
                ]

            # heard by the silent device (a stalled pty may hand it over after the reply)
            wait_for(stops, WAIT_S, "the stop on the silent line")
            assert stops() == [(CONTROL_WORD, (5,))]
            back = time.monotonic()
            simulator.withhold_replies = False
            b.wait_connected(True, since=back, timeout=WAIT_S)
            wait_for(lambda: len(client.received(b.state, back)) >= 5, WAIT_S, "polls again")
