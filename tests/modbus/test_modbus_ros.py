"""The modbus_bridge node in its own process against modbus_sim (TCP and a pty), driven by
an rclpy client in this one: each command kind writes what the file says (the simulator's
write log), refusals write nothing, stale data and reconnect."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from rcl_interfaces.srv import ListParameters
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from bridge_core.runtime.units import DEG
from bridge_core.sim.serving import Simulator
from bridge_core.wire.registers import Table
from modbus_bridge.description import (
    NODE_PARAMETERS,
    TOPIC_PARAMETER_SUFFIXES,
    Description,
    load,
)
from modbus_bridge.sim import DescribedSimDevice, make_simulator
from msg_defs.msg import DeviceValues
from msg_defs.srv import ReadRegisters, SetValue, WriteRegister

from ..support.fixtures import client_fixture
from ..support.ros import (
    Client,
    refused_at_start,
    start_bridge,
    wait_for,
    wait_stream_refusals,
    wait_subscribed,
)
from ..support.serial_pair import served_on_pty
from .test_modbus_sim import MOVER

pytestmark = pytest.mark.ros

TIMEOUT_S = 1.0
RTU_BAUD = 115200
MULTIDROP = Path(__file__).resolve().parents[2] / "config" / "devices" / "rtu_multidrop.yaml"


client = client_fixture("modbus_client", diagnostics=True, scope="module")


def describe(tmp_path: Path, text: str = MOVER) -> Description:
    path = tmp_path / "mover.yaml"
    path.write_text(text)
    return load(path)


@pytest.fixture
def sim(tmp_path: Path) -> Iterator[tuple[Description, DescribedSimDevice, int]]:
    description = describe(tmp_path)
    simulator = make_simulator(description)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, DescribedSimDevice)
    device.tick = lambda dt: None  # type: ignore[method-assign]  # still joints: exact values
    yield description, device, port
    simulator.stop()


def bridge(client: Client, tmp_path: Path, device_file: Path, **params: Any):  # type: ignore[no-untyped-def]
    defaults: dict[str, Any] = {
        "device_file": str(device_file),
        "poll_rate_hz": 50.0,
        "timeout_s": TIMEOUT_S,
        "reconnect_max_s": 1.0,
    }
    defaults.update(params)
    return start_bridge(
        client, tmp_path, "modbus_bridge.node", "modbus_bridge", DeviceValues, defaults
    )


def call(b: Any, srv_type: Any, service: str, **fields: Any) -> Any:
    """``b.call`` for requests with a ``name`` field (Bridge.call's own argument)."""
    request = srv_type.Request()
    for key, value in fields.items():
        setattr(request, key, value)
    return b.client.call(srv_type, b.service(service), request)


def log_of(device: DescribedSimDevice) -> list[tuple[int, Table, int, tuple[int, ...]]]:
    return [(r.function_code, r.table, r.address, r.values) for r in device.write_log]


def test_joint_states_and_state_in_si(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    description, device, port = sim
    device.set("position", -12.345)
    device.set("velocity", 4.5)
    device.set("position_2", 90.0)
    device.set("run", True)
    with bridge(client, tmp_path, description.path, port=port, joint_prefix="arm_") as (b, _):
        js = client.wait_message(b.joint_states)
        assert list(js.name) == ["arm_j1", "arm_j2"]
        assert list(js.position) == pytest.approx([-12.345 * DEG, math.pi / 2])
        # j2 has no velocity register: NaN beside j1's (one entry per name, decision 14)
        assert js.velocity[0] == pytest.approx(4.5 * DEG)
        assert len(js.velocity) == 2 and math.isnan(js.velocity[1])
        assert list(js.effort) == []  # no joint has an effort register
        state = client.wait_message(b.state)
        assert list(state.names) == [
            "position",
            "velocity",
            "speed_command",
            "target",
            "position_2",
            "run",
        ]
        values = dict(zip(state.names, state.values, strict=True))
        assert values["position"] == pytest.approx(-12.345) and values["run"] == 1.0
        assert list(state.units) == ["deg", "deg/s", "deg/s", "deg", "deg", ""]
        # One poll, one read time: the state of js's poll has js's stamp (the first state
        # received may be of the poll before, whose joint_states came before the
        # subscription matched: seen once, 40 ms apart at 50 Hz).
        client.wait_message(b.state, lambda m: m.header.stamp == js.header.stamp)
        status = b.wait_diagnostic(0, 0.0, port, where=lambda v: "device" in v)
        assert dict((kv.key, kv.value) for kv in status.values)["device"] == "mover"
        # The description's reserved parameter names are every one the node declares
        # besides its command topics' own.
        reply = b.client.call(
            ListParameters, b.service("list_parameters"), ListParameters.Request()
        )
        declared = set(reply.result.names)
        generated = {f"cmd_speed{suffix}" for suffix in TOPIC_PARAMETER_SUFFIXES}
        assert generated <= declared and "poll_rate_hz" in declared, declared
        assert declared - generated <= NODE_PARAMETERS, declared - generated - NODE_PARAMETERS


def test_every_command_kind_writes_what_the_file_says(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    description, device, port = sim
    device.set("target", 3.5)
    with bridge(client, tmp_path, description.path, port=port, cmd_speed_timeout_s=0.3) as (b, _):
        b.wait_connected(True)
        reply = call(b, ReadRegisters, "read", names=["target", "run"])
        assert reply.success and list(reply.values) == [3.5, 0.0], reply.message
        assert list(reply.units) == ["deg", ""]
        reply = call(b, WriteRegister, "write", name="speed_command", value=10.0)
        assert reply.success and reply.message == "speed_command = 10.0: done", reply.message
        assert call(b, WriteRegister, "write", name="run", value=1.0).success
        reply = call(b, Trigger, "go")
        assert reply.success, reply.message
        assert call(b, SetValue, "set_target", value=12.5).success
        assert call(b, SetBool, "set_run", data=False).success
        expected = [
            (6, Table.HOLDING, 3, (100,)),
            (5, Table.COIL, 0, (1,)),
            (5, Table.COIL, 0, (1,)),  # go: run, then speed_command 45 deg/s
            (6, Table.HOLDING, 3, (450,)),
            (16, Table.HOLDING, 10, (0x0000, 0x4148)),  # 12.5 f32, low word first
            (5, Table.COIL, 0, (0,)),
        ]
        assert log_of(device) == expected
        # The command topic: rad/s x 57.3 -> deg/s in speed_command; the deadman writes
        # the stop value after 0.3 s of silence. set_run false (a stop) locked the stream:
        # a 0 unlocks it, writing nothing (nothing moved; silence never unlocks).
        topic = client.node.create_publisher(Float64, f"{b.ns}/modbus_bridge/cmd_speed", 10)
        wait_subscribed(topic)
        topic.publish(Float64(data=0.0))
        time.sleep(0.3)  # taken before the next (a depth-1 subscription)
        topic.publish(Float64(data=0.5))
        wait_for(lambda: len(device.write_log) >= len(expected) + 2, 20.0, "the deadman stop")
        assert log_of(device)[len(expected) :] == [
            (6, Table.HOLDING, 3, (286,)),
            (6, Table.HOLDING, 3, (0,)),
        ]
        client.node.destroy_publisher(topic)


SPEED_0 = (6, Table.HOLDING, 3, (0,))


@pytest.mark.parametrize(
    ("srv_type", "service", "fields", "stop_writes", "own_stop"),
    [
        # halt writes speed_command: the stream is known stopped.
        (Trigger, "halt", {}, [SPEED_0], []),
        # set_run false writes the coil: the stream is locked and, once a held joystick's
        # value is refused, its own stop goes out.
        (SetBool, "set_run", {"data": False}, [(5, Table.COIL, 0, (0,))], [SPEED_0]),
        # A plain ~/write of 0 is no stop service: it locks nothing (shows the check fails).
        (WriteRegister, "write", {"name": "speed_command", "value": 0.0}, [SPEED_0], None),
    ],
)
def test_a_stop_service_locks_the_command_stream(  # type: ignore[no-untyped-def]
    sim,
    client: Client,
    tmp_path: Path,
    srv_type: Any,
    service: str,
    fields: Any,
    stop_writes: list[Any],
    own_stop: list[Any] | None,
) -> None:
    """After a stop service the joystick still held (a new non-zero value) writes no
    motion; a 0 unlocks."""
    description, device, port = sim
    with bridge(client, tmp_path, description.path, port=port, cmd_speed_timeout_s=30.0) as (
        b,
        _,
    ):
        b.wait_connected(True)
        topic = client.node.create_publisher(Float64, f"{b.ns}/modbus_bridge/cmd_speed", 10)
        wait_subscribed(topic)
        topic.publish(Float64(data=0.5))
        wait_for(lambda: len(device.write_log) >= 1, 20.0, "the streamed speed")
        reply = call(b, srv_type, service, **fields)
        assert reply.success, reply.message
        stopped = [(6, Table.HOLDING, 3, (286,)), *stop_writes]
        assert log_of(device) == stopped
        if own_stop is None:
            topic.publish(Float64(data=0.7))
            wait_for(lambda: len(device.write_log) > len(stopped), 20.0, "the stream going on")
            assert log_of(device)[len(stopped)] == (6, Table.HOLDING, 3, (401,))
            client.node.destroy_publisher(topic)
            return
        since = time.monotonic()
        topic.publish(Float64(data=0.7))
        wait_stream_refusals(client, "modbus_bridge", 1, since)  # the 0.7 was handled
        expected = stopped + own_stop
        wait_for(lambda: len(device.write_log) >= len(expected), 20.0, "the stream's stop")
        assert log_of(device) == expected  # no motion write after the stop

        def resumed() -> bool:
            if len(device.write_log) > len(expected):
                return True
            # A 0 then a new speed (a pair is sent again if the two coalesced).
            topic.publish(Float64(data=0.0))
            topic.publish(Float64(data=0.7))
            return False

        wait_for(resumed, 20.0, "the stream after a 0")
        assert log_of(device)[len(expected)] == (6, Table.HOLDING, 3, (401,))
        client.node.destroy_publisher(topic)


@pytest.mark.parametrize(
    ("srv_type", "service", "fields", "words"),
    [
        (WriteRegister, "write", {"name": "velocity", "value": 1.0}, "velocity is read only"),
        (WriteRegister, "write", {"name": "speed_command", "value": 95.0}, "outside"),
        (WriteRegister, "write", {"name": "speed_command", "value": math.nan}, "not a finite"),
        (WriteRegister, "write", {"name": "run", "value": 2.0}, "takes 0 or 1"),
        (WriteRegister, "write", {"name": "nothing", "value": 1.0}, "no register named"),
        (SetValue, "set_target", {"value": 500.0}, "outside"),
        (ReadRegisters, "read", {"names": ["secret"]}, "write only"),
    ],
)
def test_refusals_write_nothing(  # type: ignore[no-untyped-def]
    sim, client: Client, tmp_path: Path, srv_type: Any, service: str, fields: Any, words: str
) -> None:
    description, device, port = sim
    with bridge(client, tmp_path, description.path, port=port) as (b, _):
        b.wait_connected(True)
        reply = call(b, srv_type, service, **fields)
        assert not reply.success and "refused" in reply.message and words in reply.message, (
            reply.message
        )
        assert call(b, ReadRegisters, "read", names=["run"]).success  # a later round trip
        assert device.write_log == []


def test_read_only_refuses_every_write_but_reads(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    description, device, port = sim
    with bridge(client, tmp_path, description.path, port=port, read_only=True) as (b, _):
        b.wait_connected(True)
        for srv_type, service, fields in (
            (Trigger, "go", {}),
            (SetBool, "set_run", {"data": True}),
            (WriteRegister, "write", {"name": "run", "value": 1.0}),
        ):
            reply = call(b, srv_type, service, **fields)
            assert not reply.success and "read_only" in reply.message, reply.message
        assert call(b, ReadRegisters, "read", names=["run"]).success
        assert device.write_log == []


def test_stale_data_and_reconnect(tmp_path: Path, client: Client) -> None:
    description = describe(tmp_path)
    simulator = make_simulator(description)
    port = simulator.start_tcp()
    with bridge(client, tmp_path, description.path, port=port) as (b, _):
        b.wait_connected(True)
        client.wait_message(b.joint_states)
        lost = time.monotonic()  # before the stop: the node may see the loss while it joins
        simulator.stop()
        b.wait_connected(False, lost)
        down = time.monotonic()
        reply = call(b, WriteRegister, "write", name="run", value=1.0)
        assert not reply.success and "not connected" in reply.message, reply.message
        # A stop is tried on the wire at once (and says nothing went out), not refused.
        reply = call(b, Trigger, "halt")
        assert not reply.success and "halt failed" in reply.message, reply.message
        assert "nothing was sent" in reply.message, reply.message
        # A coil service is a stop for its stop_on value only.
        reply = call(b, SetBool, "set_run", data=True)
        assert not reply.success and "not connected" in reply.message, reply.message
        reply = call(b, SetBool, "set_run", data=False)
        assert not reply.success and "nothing was sent" in reply.message, reply.message
        assert client.received(b.joint_states, down) == []  # nothing stale published
        b.wait_diagnostic(2, down, port)
        again: Simulator = make_simulator(description)
        again.start_tcp(port=port)
        try:
            back = time.monotonic()
            b.wait_connected(True, back)
            client.wait_message(b.joint_states, since=back)
            assert call(b, WriteRegister, "write", name="run", value=1.0).success
            assert [r.address for r in again.device.write_log] == [0]
        finally:
            again.stop()


def test_on_a_pty_at_the_files_line_settings(tmp_path: Path, client: Client) -> None:
    # The file's unit id is the node's default too (the simulator answers only unit 7).
    text = MOVER.replace(
        "link: {tcp: {port: 1502}}", f"link: {{rtu: {{baudrate: {RTU_BAUD}}}}}\n  unit_id: 7"
    )
    description = describe(tmp_path, text)
    simulator = make_simulator(description)
    device = simulator.device
    assert isinstance(device, DescribedSimDevice)
    device.tick = lambda dt: None  # type: ignore[method-assign]
    device.set("position_2", -45.0)
    with (
        served_on_pty(simulator, RTU_BAUD) as pty,
        bridge(client, tmp_path, description.path, serial_port=pty, poll_rate_hz=10.0) as (b, _),
    ):
        js = client.wait_message(b.joint_states)
        assert js.position[1] == pytest.approx(-math.pi / 4)
        assert call(b, Trigger, "go").success
        assert log_of(device) == [(5, Table.COIL, 0, (1,)), (6, Table.HOLDING, 3, (450,))]
        assert {record.unit_id for record in device.write_log} == {7}


def test_bad_description_is_one_line_and_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        MOVER.replace(
            "type: i16, scale: 10, unit: deg/s, manual", "type: i17, scale: 10, unit: deg/s, manual"
        )
    )
    line = refused_at_start("modbus_bridge.node", ["--ros-args", "-p", f"device_file:={bad}"])
    assert line.startswith(f"error: {bad}:9: registers[1].type: Input should be"), line
    line = refused_at_start("modbus_bridge.node", ["--ros-args"])
    assert "device_file" in line
    multidrop = Path(__file__).resolve().parents[2] / "config" / "devices" / "rtu_multidrop.yaml"
    line = refused_at_start("modbus_bridge.node", ["--ros-args", "-p", f"device_file:={multidrop}"])
    assert "2 devices on one line" in line


def test_several_devices_on_one_rtu_line(tmp_path: Path, client: Client) -> None:
    """The multi-drop example: one bus owner, a node per device, each writing to its
    own unit only; the command topic's deadman stops its own drive."""
    description = load(MULTIDROP)
    simulator = make_simulator(description)
    units = simulator.devices
    units[2].set("position_actual", -70000)
    with (
        served_on_pty(simulator, RTU_BAUD) as pty,
        start_bridge(
            client,
            tmp_path,
            "modbus_bridge.bus",
            "drive_1",
            DeviceValues,
            {"device_file": str(MULTIDROP), "serial_port": pty, "poll_rate_hz": 10.0},
        ) as (b, _),
    ):
        second = f"{b.ns}/drive_2/state"
        client.subscribe(DeviceValues, second)
        state = client.wait_message(second)
        assert dict(zip(state.names, state.values, strict=True))["position_actual"] == -70000
        assert client.wait_message(b.state).values[1] == 0.0
        reply = client.call(Trigger, f"{b.ns}/drive_2/stop", Trigger.Request())
        assert reply.success, reply.message
        # A stop retried after a late reply (a loaded machine) writes the same 0 again.
        drive_2_writes = [(r.unit_id, r.address, r.values) for r in units[2].write_log]
        assert drive_2_writes and set(drive_2_writes) == {(2, 0xAE, (0,))}
        topic = client.node.create_publisher(Float64, f"{b.ns}/drive_1/cmd_speed", 10)
        wait_subscribed(topic)
        topic.publish(Float64(data=300.0))
        wait_for(lambda: len(units[1].write_log) >= 2, 20.0, "drive_1's deadman stop")
        writes = [(r.address, r.values) for r in units[1].write_log]
        assert writes[0] == (0xAE, (300,))
        assert set(writes[1:]) == {(0xAE, (0,))}
        assert set((r.address, r.values) for r in units[2].write_log) == {(0xAE, (0,))}
        client.node.destroy_publisher(topic)


def test_bus_process_refuses_a_single_device_file(tmp_path: Path) -> None:
    path = tmp_path / "mover.yaml"
    path.write_text(MOVER)
    line = refused_at_start("modbus_bridge.bus", ["--ros-args", "-p", f"device_file:={path}"])
    assert "run modbus_bridge for it" in line
