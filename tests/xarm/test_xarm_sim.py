"""The xArm device layer against the xArm simulator over a real TCP socket (no ROS)."""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from bridge_core.runtime.units import (
    euler_xyz_deg_to_quaternion,
    quaternion_angle_deg,
    rotation_vector_deg_to_quaternion,
)
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import (
    CommandRejected,
    ConfigurationError,
    DeviceException,
    NotConfirmed,
)
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, TcpSettings
from xarm_bridge.device import POLL_PLAN, XArmDevice, poll_plan
from xarm_bridge.registers import COIL_PAUSED, COIL_STOPPED, XARM_MAP, error_text
from xarm_bridge.sim import IN_MOTION, PAUSED, SLEEPING, STOPPED, XArmSimDevice, make_simulator


@contextmanager
def connected(
    joints: int = 7, user_coils: range = range(0)
) -> Iterator[tuple[XArmDevice, XArmSimDevice, DeviceChannel, int]]:
    simulator = make_simulator(joints)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, XArmSimDevice)
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    channel = DeviceChannel(link, 1, retries=0)
    try:
        yield XArmDevice(channel, joints, user_coils), device, channel, port
    finally:
        link.close()
        simulator.stop()


@pytest.fixture
def xarm() -> Iterator[tuple[XArmDevice, XArmSimDevice, DeviceChannel, int]]:
    with connected() as parts:
        yield parts


def writes(sim: XArmSimDevice) -> list[tuple[int, Table, int, tuple[int, ...]]]:
    return [(r.function_code, r.table, r.address, r.values) for r in sim.write_log]


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
    assert "state 3 (paused)" in device.pause() and sim.arm_state == PAUSED
    frozen = device.poll().joint_angles_deg
    assert device.poll().joint_angles_deg == frozen and device.poll().paused
    assert "mode 0 (position), state 1 (in motion)" in device.resume()
    assert "state 4 (stopped)" in device.stop() and device.poll().stopped
    assert "mode 0 (position), state 2 (sleeping)" in device.resume()
    sim.set_error(22)
    with pytest.raises(NotConfirmed, match=r"state 4 \(stopped\), error 22 \(collision error\)"):
        device.run_offline_task([1])  # decision 20: an arm in error does not move
    assert sim.arm_state == STOPPED and error_text(22) == "collision error"
    device.set_mode(4)
    with pytest.raises(NotConfirmed, match=r"wrote H33 = 0; reads mode 0 .*state 4"):
        device.resume()  # an error: the start is refused, mode 0 stays
    assert device.poll().motion_modes[0]
    sim.set_error(0)
    assert "mode 4 (joint velocity), state 2 (sleeping)" in device.resume()
    assert device.poll().motion_modes == (False,) * 4 + (True,) + (False,) * 9


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
        (lambda d: d.set_reduced_mode(False), "confirm: 'set_reduced_mode'"),  # decision 17
        (lambda d: d.set_fence_mode(False, "set_reduced_mode"), "confirm: 'set_fence_mode'"),
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


# ------------------------------------------------- modes, joint count, outputs, user coils, enables
def test_a_new_mode_takes_effect_after_set_state_0(xarm) -> None:  # type: ignore[no-untyped-def]
    """H32 takes the mode; H32 and C146-159 read the old one until set_state 0."""
    device, sim, channel, _ = xarm
    device.set_mode(1)
    s = device.poll()
    assert (s.mode, s.motion_modes[0], s.motion_modes[1]) == (0, True, False)
    assert device.set_state(0) == (1, SLEEPING)
    s = device.poll()
    assert (s.mode, s.motion_modes[0], s.motion_modes[1]) == (1, False, True)
    # The manual's FC 0x17 example writes mode 6 and state 4 (stop) at once: no start.
    assert channel.read_write_registers(3, 2, 32, [6, 4]) == [0, 0]
    assert device.poll().mode == 1 and sim.arm_state == STOPPED
    assert "mode 6 (joint online trajectory), state 2 (sleeping)" in device.resume()


@pytest.mark.parametrize("joints", [5, 6])
def test_joint_count_publishes_the_arm_joints_only(joints: int) -> None:
    with connected(joints) as (device, sim, _, _):
        sim.tick = lambda dt: None  # type: ignore[method-assign]
        sim.set(f"joint_angle_{joints}", 12.5)
        s = device.poll()
        per_joint = (
            s.joint_angles_deg,
            s.joint_speeds_deg_s,
            s.joint_temperatures_c,
            s.brakes,
            s.enabled,
        )
        assert [len(t) for t in per_joint] == [joints] * 5
        assert s.joint_angles_deg[-1] == pytest.approx(12.5)
        assert s.enabled == (True,) * joints and s.brakes == (True,) * joints
        # The rows of a joint the arm lacks read 0 on the simulator, and are not read.
        assert not sim.get("enable_7") and len(device.plan) == len(POLL_PLAN) == 8
        read = {r.name for request in device.plan for r in request.registers}
        assert "joint_angle_7" not in read and f"joint_angle_{joints}" in read


@pytest.mark.parametrize("count", [4, 8, True, 0])
def test_joint_count_outside_5_to_7_is_refused(count: object) -> None:
    with pytest.raises(ConfigurationError, match="joint_count"):
        XArmDevice(None, count)  # type: ignore[arg-type]


def test_several_digital_outputs_one_fc0f_per_run(xarm) -> None:  # type: ignore[no-untyped-def]
    device, sim, _, _ = xarm
    written = device.set_digital_outputs([9, 2, 3, 15], [True, True, False, True])
    assert written == "DO 2-3 on off, DO 9 on, DO 15 on"
    assert writes(sim) == [
        (15, Table.COIL, 2, (1, 0)),
        (15, Table.COIL, 9, (1,)),
        (15, Table.COIL, 15, (1,)),
    ]
    s = device.poll()
    assert [k for k, on in enumerate(s.digital_outputs) if on] == [2, 9, 15]


def test_do_word_bit_n_is_do_n(xarm) -> None:  # type: ignore[no-untyped-def]
    """xArm decision 9 (docs/decisions/xarm.md): bit n of H0 is DO n, on both paths of the
    simulator (coils written, word read; word mask-written, coils read)."""
    device, _, _, _ = xarm
    device.set_digital_outputs([2, 9], [True, True])
    assert device.read_named("controller_do_word_0")["controller_do_word_0"] == 0x0204
    device.change_digital_outputs({0: True, 9: False})
    assert device.read_named("controller_do_word_0")["controller_do_word_0"] == 0x0005
    s = device.poll()
    assert [k for k, on in enumerate(s.digital_outputs) if on] == [0, 2]


def test_user_coils_read_in_the_poll_and_written(xarm) -> None:  # type: ignore[no-untyped-def]
    _, sim, channel, _ = xarm
    device = XArmDevice(channel, 7, range(300, 316))
    assert len(device.plan) == len(POLL_PLAN) + 1  # one FC 01 request more per poll
    whole = poll_plan(7, range(256, 512))  # all 256 user coils: still one request more
    assert len(whole) == len(POLL_PLAN) + 1
    assert [(r.address, r.count) for r in whole if r.table is Table.COIL][-1] == (256, 256)
    sim.set("user_coil_44", True)  # C300
    sim.set("user_coil_59", True)  # C315
    s = device.poll()
    assert len(s.user_coils) == 16 and s.user_coils[0] and s.user_coils[15]
    assert not any(s.user_coils[1:15])
    assert (
        device.set_user_coils([302, 301, 310], [True, True, False]) == "C 301-302 on on, C 310 off"
    )
    assert writes(sim) == [(15, Table.COIL, 301, (1, 1)), (15, Table.COIL, 310, (0,))]
    assert device.poll().user_coils[1:3] == (True, True)
    for address in (299, 316, 0, 512):
        with pytest.raises(CommandRejected, match=f"user coil {address} outside 300-315"):
            device.set_user_coils([address], [True])
    with pytest.raises(ConfigurationError, match="outside 256-511"):
        XArmDevice(channel, 7, range(500, 520))


def test_write_failing_after_others_says_what_was_written(xarm) -> None:  # type: ignore[no-untyped-def]
    device, sim, _, _ = xarm
    sim.write_guards.append(lambda record: 0x04 if record.address == 9 else None)
    with pytest.raises(DeviceException, match=r"written before it: DO 2 on$"):
        device.set_digital_outputs([2, 9], [True, True])
    assert writes(sim) == [(15, Table.COIL, 2, (1,))]


def test_enables_and_brakes_follow_their_coils(xarm) -> None:  # type: ignore[no-untyped-def]
    device, sim, channel, _ = xarm
    device.set_joint_enable(3, False)
    s = device.poll()
    assert s.enabled == (True, True, False, True, True, True, True)
    assert s.brakes == (True, True, False, True, True, True, True)  # J3's brake engaged
    with pytest.raises(NotConfirmed, match=r"state 2 \(sleeping\)"):
        device.run_offline_task([1])
    assert sim.arm_state == SLEEPING  # not ready: the task does not start
    with pytest.raises(NotConfirmed, match=r"state 4 \(stopped\)"):
        device.resume()  # nor does set_state 0
    device.set_joint_enable(0, True)  # every joint: one FC 0F
    assert device.poll().brakes == (True,) * 7
    assert "state 2 (sleeping)" in device.resume()
    device.run_offline_task([2])
    assert sim.arm_state == IN_MOTION
    device.set_joint_enable(2, False)  # a joint disabled in motion stops the arm
    assert sim.arm_state == STOPPED and sim.task_seconds_left == 0
    device.set_joint_enable(2, True)
    assert "state 2 (sleeping)" in device.resume()
    # A brake coil written (not by the bridge: it never writes C128-134) stays as written
    # and, engaged in motion, stops the arm like a disable.
    device.run_offline_task([3])
    channel.write_coil(128 + 4, False)
    assert sim.arm_state == STOPPED and device.poll().brakes[4] is False
    assert device.poll().enabled[4] is True
    assert [w for w in writes(sim) if w[1] is Table.COIL] == [
        (5, Table.COIL, 137, (0,)),
        (15, Table.COIL, 135, (1,) * 7),
        (5, Table.COIL, 136, (0,)),
        (5, Table.COIL, 136, (1,)),
        (5, Table.COIL, 132, (0,)),
    ]


def test_joint_enable_on_a_six_axis_arm() -> None:
    with connected(6) as (device, sim, _, _):
        device.set_joint_enable(0, False)
        assert [w.values for w in sim.write_log] == [(0,) * 6]
        s = device.poll()
        assert s.enabled == (False,) * 6 and s.brakes == (False,) * 6
        with pytest.raises(CommandRejected, match="joint 7 outside 0-6"):
            device.set_joint_enable(7, True)


def test_rotation_vector_is_the_pose_orientation(xarm) -> None:  # type: ignore[no-untyped-def]
    device, sim, _, _ = xarm
    sim.tick = lambda dt: None
    sim.set_orientation(180.0, 0.0, 90.0)
    s = device.poll()
    # Roll 180 then yaw 90 about fixed axes: a half turn about (1, 1, 0) / sqrt 2.
    half = 180.0 / 2**0.5
    assert s.tcp_rotation_vector_deg == pytest.approx((half, half, 0.0), abs=0.06)
    sim.set_orientation(-35.2, 12.9, 150.0)
    s = device.poll()
    p = s.tcp_pose
    assert (
        quaternion_angle_deg(
            euler_xyz_deg_to_quaternion(p["roll"], p["pitch"], p["yaw"]),
            rotation_vector_deg_to_quaternion(*s.tcp_rotation_vector_deg),
        )
        < 0.2
    )


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda d: d.set_digital_outputs([16], [True]), "digital output 16"),
        (lambda d: d.set_digital_outputs([1, 16], [True, True]), "digital output 16"),
        (lambda d: d.set_digital_outputs([3, 3], [True, False]), "digital output 3 given twice"),
        (lambda d: d.set_digital_outputs([1, 2], [True]), "2 indexes but 1 states"),
        (lambda d: d.set_digital_outputs([*range(17)], [True] * 17), "^17 indexes, at most 16$"),
        (lambda d: d.set_digital_outputs([], []), "no outputs"),
        (lambda d: d.set_user_coils([256], [True]), "no user coils configured"),
        (lambda d: d.set_joint_enable(8, True), "joint 8 outside 0-7"),
        (lambda d: d.set_joint_enable(-1, False), "joint -1"),
    ],
)
def test_bad_outputs_and_joints_are_refused_and_write_nothing(xarm, call, match) -> None:  # type: ignore[no-untyped-def]
    device, sim, channel, _ = xarm
    before = channel.stats.transactions
    with pytest.raises(CommandRejected, match=match):
        call(device)
    assert sim.write_log == [] and channel.stats.transactions == before


def test_stop_and_pause_go_through_c145_and_c144_and_h33_and_are_read_back(xarm) -> None:  # type: ignore[no-untyped-def]
    """Decisions 6 and 19: the coils the manual names and H33 at once, the reply from
    the state read back."""
    device, sim, _, _ = xarm
    device.run_offline_task([7])
    said = device.pause()
    assert writes(sim)[-2:] == [
        (5, Table.COIL, COIL_PAUSED, (1,)),
        (23, Table.HOLDING, 33, (3,)),
    ]
    assert said.startswith("wrote C144 = 1 and H33 = 3; ") and "state 3 (paused)" in said
    device.resume()
    said = device.stop()
    assert writes(sim)[-2:] == [
        (5, Table.COIL, COIL_STOPPED, (1,)),
        (23, Table.HOLDING, 33, (4,)),
    ]
    assert "state 4 (stopped)" in said and sim.arm_state == STOPPED


def test_safety_modes_switch_off_only_when_confirmed(xarm) -> None:  # type: ignore[no-untyped-def]
    """Decision 17: reduced / fence mode off needs confirm; the coil is read back."""
    device, _, _, _ = xarm
    assert "C142 reads 1" in device.set_reduced_mode(True)
    assert "C142 reads 0" in device.set_reduced_mode(False, "set_reduced_mode")
    assert "C143 reads 1" in device.set_fence_mode(True)
    assert "C143 reads 0" in device.set_fence_mode(False, "set_fence_mode")
