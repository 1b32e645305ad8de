"""The xArm device layer against the xArm simulator over a real TCP socket (no ROS)."""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator

import pytest

from bridge_core.channel import DeviceChannel
from bridge_core.errors import CommandRejected
from bridge_core.registers import Table
from bridge_core.transport import ModbusLink, TcpSettings
from xarm_bridge.device import XArmDevice, error_text
from xarm_bridge.registers import XARM_MAP
from xarm_bridge.sim import IN_MOTION, PAUSED, SLEEPING, STOPPED, XArmSimDevice, make_simulator


@pytest.fixture
def xarm() -> Iterator[tuple[XArmDevice, XArmSimDevice, DeviceChannel, int]]:
    simulator = make_simulator()
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, XArmSimDevice)
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    channel = DeviceChannel(link, 1, retries=0)
    yield XArmDevice(channel), device, channel, port
    link.close()
    simulator.stop()


def exception_code(port: int, pdu: bytes) -> int | None:
    with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
        s.sendall(struct.pack(">HHHB", 9, 0, len(pdu) + 1, 1) + pdu)
        header = s.recv(7)
        body = s.recv(struct.unpack(">HHH", header[:6])[2] - 1)
    return body[1] if body[0] & 0x80 else None


def test_poll_in_manual_units(xarm) -> None:  # type: ignore[no-untyped-def]
    device, sim, _, _ = xarm
    sim.tick = lambda dt: None
    sim.set("joint_angle_3", -123.4)
    sim.set("joint_speed_7", 55.5)
    sim.set("joint_temperature_2", 41)
    sim.set("tcp_x", 512.3)
    sim.set("tcp_yaw", -90.0)
    sim.set("counter", 70000)
    sim.set("tcp_offset_z", 172.5)
    sim.set("tool_ai_1", 4.321)
    sim.set_input(5, True)
    sim.set_input(33, True)
    sim.set_warning(12)
    s = device.poll()
    assert s.joint_angles_deg[2] == pytest.approx(-123.4)
    assert s.joint_speeds_deg_s[6] == pytest.approx(55.5)
    assert s.joint_temperatures_c[1] == 41
    assert s.tcp_pose["x"] == pytest.approx(512.3) and s.tcp_pose["yaw"] == pytest.approx(-90.0)
    assert s.counter == 70000 and s.tcp_offset["z"] == pytest.approx(172.5)
    assert s.tool_analog_inputs[1] == pytest.approx(4.321)
    assert (
        s.digital_inputs[5] and not s.digital_inputs[4] and s.tool_digital_inputs == (False, True)
    )
    assert s.warning_code == 12 and s.state == SLEEPING and s.enabled == (True,) * 7
    assert s.motion_modes[0] and len(s.motion_modes) == 14


def test_state_machine_through_the_device(xarm) -> None:  # type: ignore[no-untyped-def]
    device, sim, _, _ = xarm
    device.run_offline_task([7])
    assert sim.tasks_started == [[7]] and sim.arm_state == IN_MOTION
    start = device.poll().joint_angles_deg
    deadline = time.monotonic() + 30
    while device.poll().joint_angles_deg == start:
        assert time.monotonic() < deadline, "joints did not move in motion"
    assert device.pause() == (0, PAUSED)
    frozen = device.poll().joint_angles_deg
    assert device.poll().joint_angles_deg == frozen and device.poll().paused
    assert device.resume() == (0, IN_MOTION)
    assert device.stop() == (0, STOPPED) and device.poll().stopped
    assert device.resume() == (0, SLEEPING)
    sim.set_error(22)
    device.run_offline_task([1])
    assert sim.arm_state == STOPPED and error_text(22) == "collision error"
    device.set_mode(4)
    assert device.poll().motion_modes[4]


def test_outputs_write_the_documented_registers(xarm) -> None:  # type: ignore[no-untyped-def]
    device, sim, _, _ = xarm
    device.set_digital_output(15, True)
    device.set_tool_digital_output(1, True)
    device.set_analog_output(1, 9.5)
    device.set_reduced_mode(True)
    device.set_fence_mode(True)
    device.change_digital_outputs({0: True, 15: False})
    log = [(r.function_code, r.table, r.address, r.values) for r in sim.write_log]
    assert log == [
        (5, Table.COIL, 15, (1,)),
        (5, Table.COIL, 33, (1,)),
        (6, Table.HOLDING, 4, (9500,)),
        (5, Table.COIL, 142, (1,)),
        (5, Table.COIL, 143, (1,)),
        (22, Table.HOLDING, 0, (0x0001,)),
    ]
    s = device.poll()
    assert s.digital_outputs[0] and not s.digital_outputs[15] and s.tool_digital_outputs[1]
    assert s.analog_outputs[1] == pytest.approx(9.5) and s.reduced_mode and s.fence_mode


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda d: d.set_digital_output(16, True), "digital output 16"),
        (lambda d: d.set_digital_output(-1, True), "digital output -1"),
        (lambda d: d.set_tool_digital_output(2, True), "tool digital output 2"),
        (lambda d: d.set_analog_output(2, 1.0), "analog output 2"),
        (lambda d: d.set_analog_output(0, 10.5), "outside"),
        (lambda d: d.set_analog_output(0, float("nan")), "outside"),
        (lambda d: d.set_analog_outputs([1.0, 2.0, 3.0]), "analog output 2"),
        (lambda d: d.write_digital_outputs(14, [True, True, True]), "digital output 16"),
        (lambda d: d.change_digital_outputs({20: True}), "digital output 20"),
        (lambda d: d.set_mode(14), "mode"),
        (lambda d: d.set_state(2), "state 2"),
        (lambda d: d.run_offline_task(list(range(1, 18))), "1-16"),
        (lambda d: d.run_offline_task([0]), "project number 0"),
    ],
)
def test_refusals_write_nothing(xarm, call, match) -> None:  # type: ignore[no-untyped-def]
    device, sim, channel, _ = xarm
    before = channel.stats.transactions
    with pytest.raises(CommandRejected, match=match):
        call(device)
    assert sim.write_log == [] and channel.stats.transactions == before


def test_simulator_refuses_reserved_and_unsupported(xarm) -> None:  # type: ignore[no-untyped-def]
    _, _, _, port = xarm
    assert exception_code(port, struct.pack(">BHH", 1, 0, 40)) is None  # coils 0-39
    assert exception_code(port, struct.pack(">BHH", 1, 0, 41)) == 2  # into reserved 40
    assert exception_code(port, struct.pack(">BHH", 1, 160, 1)) == 2
    assert exception_code(port, struct.pack(">BHH", 2, 40, 1)) == 2
    assert exception_code(port, struct.pack(">BHH", 3, 11, 1)) == 2
    assert exception_code(port, struct.pack(">BHH", 4, 36, 1)) == 2  # "36 ~ 63" reserved
    assert exception_code(port, struct.pack(">BHH", 4, 111, 1)) == 2
    assert exception_code(port, struct.pack(">BHH", 4, 96, 7)) is None  # temperatures 96-102
    # Offline tasks only with FC 10 at 0x30.
    assert exception_code(port, struct.pack(">BHH", 6, 0x30, 1)) == 1
    assert exception_code(port, struct.pack(">BHHB", 16, 0x31, 1, 2) + b"\x00\x01") == 2
    # Invalid mode and state values.
    assert exception_code(port, struct.pack(">BHH", 6, 32, 14)) == 3
    assert exception_code(port, struct.pack(">BHH", 6, 33, 1)) == 3
    # A function code the manual does not list: FC 0x2B (device identification).
    assert exception_code(port, bytes([0x2B, 0x0E, 0x01, 0x00])) == 1


def test_map_follows_the_appendix() -> None:
    expect = {
        ("controller_do_0", 0),
        ("tool_do_0", 32),
        ("brake_1", 128),
        ("enable_7", 141),
        ("reduced_mode", 142),
        ("fence_mode", 143),
        ("paused", 144),
        ("stopped", 145),
        ("motion_mode_0", 146),
        ("motion_mode_13", 159),
        ("user_coil_0", 256),
        ("controller_ao_0", 3),
        ("tool_ao_3", 10),
        ("arm_mode", 32),
        ("arm_state", 33),
        ("offline_task_0", 48),
        ("error_code", 32),
        ("warning_code", 33),
        ("counter", 34),
        ("tcp_x", 64),
        ("tcp_rz", 72),
        ("tcp_load_mass", 73),
        ("tcp_offset_x", 77),
        ("base_offset_x", 83),
        ("joint_angle_1", 89),
        ("joint_angle_7", 95),
        ("joint_temperature_1", 96),
        ("joint_temperature_7", 102),
        ("joint_speed_1", 103),
        ("tcp_speed", 110),
    }
    for name, address in expect:
        assert XARM_MAP[name].address == address, name
    for name in ("joint_angle_1", "tcp_x", "joint_speed_1", "tcp_speed", "tcp_offset_x"):
        assert XARM_MAP[name].scale == 10 and XARM_MAP[name].value_type.signed
    for name in ("controller_ao_0", "controller_ai_0", "tcp_load_mass"):
        assert XARM_MAP[name].scale == 1000 and XARM_MAP[name].value_type.signed
