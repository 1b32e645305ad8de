"""The xArm bridge node in its own process, driven by an rclpy client in this one."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from std_srvs.srv import Trigger

from bridge_core.wire.registers import Table
from msg_defs.msg import XArmState
from msg_defs.srv import (
    RunOfflineTask,
    SetChannelValue,
    SetInteger,
    SetJointEnable,
    SetOutput,
    SetOutputs,
    SetSafetyMode,
)
from xarm_bridge.sim import IN_MOTION, PAUSED, SLEEPING, STOPPED, XArmSimDevice, make_simulator

from ..support.fixtures import client_fixture
from ..support.ros import Client, refused_at_start, start_bridge, values_of

pytestmark = pytest.mark.ros

# Far above what scheduling on a loaded machine can delay a reply by.
TIMEOUT_S = 1.0


client = client_fixture("xarm_client", diagnostics=True, scope="module")


@pytest.fixture
def sim(request: pytest.FixtureRequest) -> Iterator[tuple[XArmSimDevice, int]]:
    simulator = make_simulator(getattr(request, "param", 7))
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, XArmSimDevice)
    yield device, port
    simulator.stop()


def bridge(client: Client, tmp_path: Path, port: int, **params: Any):  # type: ignore[no-untyped-def]
    defaults = {
        "port": port,
        "poll_rate_hz": 50.0,
        "timeout_s": TIMEOUT_S,
        "reconnect_max_s": 1.0,
    }
    defaults.update(params)
    return start_bridge(client, tmp_path, "xarm_bridge.node", "xarm_bridge", XArmState, defaults)


def call(client: Client, b: Any, srv_type: Any, name: str, **fields: Any) -> Any:
    request = srv_type.Request()
    for key, value in fields.items():
        setattr(request, key, value)
    return client.call(srv_type, b.service(name), request)


def test_topics_in_si_units(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    device.tick = lambda dt: None
    device.set("joint_angle_1", 90.0)
    device.set("joint_angle_7", -45.5)
    device.set("joint_speed_2", 180.0)
    device.set("tcp_x", 250.0)
    device.set("tcp_z", 1000.5)
    device.set_orientation(90.0, 0.0, 0.0)
    device.set("tcp_speed", 123.4)
    device.set("joint_temperature_3", 45)
    device.set("tcp_offset_z", 172.0)
    device.set("tcp_offset_yaw", 90.0)
    device.set("tcp_load_center_z", 30.0)
    device.set("controller_ai_1", 2.5)
    device.set_input(3, True)
    device.set_error(22)
    started = time.monotonic()
    with bridge(client, tmp_path, port, frame_id="link_base") as (b, _):
        js = client.wait_message(b.joint_states)
        assert js.name == [f"joint{j}" for j in range(1, 8)]
        assert js.position[0] == pytest.approx(math.pi / 2)
        assert js.position[6] == pytest.approx(math.radians(-45.5))
        assert js.velocity[1] == pytest.approx(math.pi)
        pose = client.wait_message(b.pose)
        assert pose.header.frame_id == "link_base"
        p = pose.pose.position
        assert (p.x, p.y, p.z) == pytest.approx((0.25, 0.0, 1.0005))
        q = pose.pose.orientation
        assert (q.x, q.y, q.z, q.w) == pytest.approx((math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)))
        st = client.wait_message(b.state)
        assert (st.state, st.state_name) == (STOPPED, "stopped") and st.stopped
        assert (st.error_code, st.error_text) == (22, "collision error")
        assert st.tcp_speed == pytest.approx(0.1234)
        assert st.joint_temperatures[2] == 45 and len(st.joint_temperatures) == 7
        assert (
            st.digital_inputs[3]
            and len(st.digital_inputs) == 16
            and len(st.tool_digital_inputs) == 2
        )
        assert st.analog_inputs[1] == pytest.approx(2.5)
        assert st.tcp_offset[2] == pytest.approx(0.172) and st.tcp_offset[5] == pytest.approx(
            math.pi / 2
        )
        assert st.tcp_load_center[2] == pytest.approx(0.03)
        assert list(st.enabled) == [True] * 7 and list(st.brakes) == [True] * 7
        # Roll 90 alone: the rotation vector is (90 deg, 0, 0).
        assert list(st.tcp_rotation_vector) == pytest.approx([math.pi / 2, 0.0, 0.0], abs=1e-3)
        assert list(st.user_coils) == [] and st.user_coil_first == 256  # none by default
        status = b.wait_diagnostic(2, started, port)  # controller error -> ERROR
        assert "collision error" in status.message
        assert values_of(status)["link state"] == "connected"
        device.set_error(0)
        status = b.wait_diagnostic(0, time.monotonic(), port, where=lambda v: "state" in v)
        assert values_of(status)["state"].startswith("4")


def test_services_write_what_they_should(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge(client, tmp_path, port, user_coil_first=300, user_coil_count=8) as (b, _):
        b.wait_connected(True)
        reply = call(client, b, RunOfflineTask, "run_offline_task", projects=[3, 12])
        assert reply.success, reply.message
        assert device.arm_state == IN_MOTION
        reply = call(client, b, Trigger, "pause")
        assert reply.success and "state 3 (paused)" in reply.message and device.arm_state == PAUSED
        assert call(client, b, Trigger, "resume").success and device.arm_state == IN_MOTION
        assert call(client, b, Trigger, "stop").success and device.arm_state == STOPPED
        assert (
            call(client, b, SetInteger, "set_state", value=0).success
            and device.arm_state == SLEEPING
        )
        reply = call(client, b, SetInteger, "set_mode", value=1)
        assert reply.success and "in force after set_state 0" in reply.message
        assert device.mode == 0  # not yet
        reply = call(client, b, SetInteger, "set_state", value=0)
        assert reply.success and "mode 1 (servo)" in reply.message, reply.message
        assert call(
            client, b, SetOutput, "set_digital_output", board=0, index=7, state=True
        ).success
        reply = call(
            client,
            b,
            SetOutputs,
            "set_digital_outputs",
            indexes=[5, 0, 1],
            states=[True, True, False],
        )
        assert reply.success and "(DO 0-1 on off, DO 5 on)" in reply.message, reply.message
        reply = call(
            client, b, SetOutputs, "set_user_coils", indexes=[301, 307], states=[True, True]
        )
        assert reply.success and "(C 301 on, C 307 on)" in reply.message, reply.message
        reply = call(client, b, SetJointEnable, "set_joint_enable", joint=2, enable=False)
        assert reply.success and "joint 2 disable" in reply.message, reply.message
        assert call(client, b, SetJointEnable, "set_joint_enable", joint=0, enable=True).success
        assert call(
            client, b, SetOutput, "set_tool_digital_output", board=0, index=1, state=True
        ).success
        assert call(client, b, SetChannelValue, "set_analog_output", channel=1, value=2.5).success
        assert call(client, b, SetSafetyMode, "set_reduced_mode", data=True).success
        reply = call(client, b, SetSafetyMode, "set_fence_mode", data=False)
        assert not reply.success and "confirm: 'set_fence_mode'" in reply.message  # decision 17
        confirmed = {"data": False, "confirm": "set_fence_mode"}
        reply = call(client, b, SetSafetyMode, "set_fence_mode", **confirmed)
        assert reply.success and "C143 reads 0" in reply.message, reply.message
        log = [(r.function_code, r.table, r.address, r.values) for r in device.write_log]
        assert log == [
            (16, Table.HOLDING, 0x30, (3, 12)),
            (5, Table.COIL, 144, (1,)),  # decision 6: the coils the manual names,
            (23, Table.HOLDING, 33, (3,)),  # and H33 at once (decision 19)
            (23, Table.HOLDING, 33, (0,)),
            (5, Table.COIL, 145, (1,)),
            (23, Table.HOLDING, 33, (4,)),
            (23, Table.HOLDING, 33, (0,)),
            (6, Table.HOLDING, 32, (1,)),
            (23, Table.HOLDING, 33, (0,)),
            (5, Table.COIL, 7, (1,)),
            (15, Table.COIL, 0, (1, 0)),
            (15, Table.COIL, 5, (1,)),
            (15, Table.COIL, 301, (1,)),
            (15, Table.COIL, 307, (1,)),
            (5, Table.COIL, 136, (0,)),
            (15, Table.COIL, 135, (1,) * 7),
            (5, Table.COIL, 33, (1,)),
            (6, Table.HOLDING, 4, (2500,)),
            (5, Table.COIL, 142, (1,)),
            (5, Table.COIL, 143, (0,)),
        ]
        st = client.wait_message(b.state, lambda m: m.digital_outputs[7] and m.reduced_mode)
        assert st.tool_digital_outputs[1] and st.analog_outputs[1] == pytest.approx(2.5)
        assert st.mode == 1 and st.motion_modes[1]
        assert [k for k, on in enumerate(st.digital_outputs) if on] == [0, 5, 7]
        assert st.user_coil_first == 300 and len(st.user_coils) == 8
        assert [300 + k for k, on in enumerate(st.user_coils) if on] == [301, 307]
        assert list(st.enabled) == [True] * 7 and list(st.brakes) == [True] * 7


REFUSALS: list[tuple[Any, str, dict[str, Any], str]] = [
    (
        SetOutput,
        "set_digital_output",
        {"board": 0, "index": 16, "state": True},
        "digital output 16",
    ),
    (SetOutput, "set_digital_output", {"board": 1, "index": 0, "state": True}, "board 1"),
    (
        SetOutput,
        "set_tool_digital_output",
        {"board": 0, "index": 2, "state": True},
        "tool digital output 2",
    ),
    (SetChannelValue, "set_analog_output", {"channel": 2, "value": 1.0}, "analog output 2"),
    (SetChannelValue, "set_analog_output", {"channel": 0, "value": 10.01}, "outside"),
    (SetChannelValue, "set_analog_output", {"channel": 0, "value": -0.5}, "outside"),
    (SetInteger, "set_mode", {"value": 14}, "mode 14"),
    (SetInteger, "set_state", {"value": 1}, "state 1"),
    (RunOfflineTask, "run_offline_task", {"projects": []}, "1-16"),
    (RunOfflineTask, "run_offline_task", {"projects": [0]}, "project number 0"),
    (
        SetOutputs,
        "set_digital_outputs",
        {"indexes": [1, 16], "states": [True, True]},
        "digital output 16",
    ),
    (
        SetOutputs,
        "set_digital_outputs",
        {"indexes": [1, 2], "states": [True]},
        "2 indexes but 1 states",
    ),
    (
        SetOutputs,
        "set_digital_outputs",
        {"indexes": [4, 4], "states": [True, False]},
        "given twice",
    ),
    (SetOutputs, "set_user_coils", {"indexes": [255], "states": [True]}, "user coil 255"),
    (SetOutputs, "set_user_coils", {"indexes": [264], "states": [True]}, "user coil 264"),
    (SetJointEnable, "set_joint_enable", {"joint": 8, "enable": True}, "joint 8 outside 0-7"),
]


def test_refusals_write_nothing(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge(client, tmp_path, port, user_coil_count=8) as (b, _):
        b.wait_connected(True)
        for srv_type, name, fields, reason in REFUSALS:
            reply = call(client, b, srv_type, name, **fields)
            assert not reply.success and "refused" in reply.message and reason in reply.message, (
                reply.message
            )
        assert device.write_log == []


def test_read_only_refuses_every_write(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge(client, tmp_path, port, read_only=True, user_coil_count=1) as (b, _):
        b.wait_connected(True)
        replies = [call(client, b, Trigger, n) for n in ("pause", "stop", "resume")]
        replies += [
            call(client, b, SetInteger, "set_mode", value=0),
            call(client, b, SetInteger, "set_state", value=0),
            call(client, b, SetOutput, "set_digital_output", board=0, index=0, state=True),
            call(client, b, SetOutput, "set_tool_digital_output", board=0, index=0, state=True),
            call(client, b, SetChannelValue, "set_analog_output", channel=0, value=1.0),
            call(client, b, SetSafetyMode, "set_reduced_mode", data=True),
            call(client, b, SetSafetyMode, "set_fence_mode", data=True),
            call(client, b, RunOfflineTask, "run_offline_task", projects=[1]),
            call(client, b, SetOutputs, "set_digital_outputs", indexes=[0], states=[True]),
            call(client, b, SetOutputs, "set_user_coils", indexes=[256], states=[True]),
            call(client, b, SetJointEnable, "set_joint_enable", joint=1, enable=False),
            call(client, b, SetJointEnable, "set_joint_enable", joint=0, enable=True),
        ]
        for reply in replies:
            assert not reply.success and "read_only" in reply.message
        assert device.write_log == []


@pytest.mark.parametrize("sim", [6], indirect=True)
def test_a_six_axis_arm_has_no_phantom_joint(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge(client, tmp_path, port, joint_count=6, joint_prefix="lite6_") as (b, _):
        js = client.wait_message(b.joint_states)
        assert js.name == [f"lite6_joint{j}" for j in range(1, 7)]
        assert len(js.position) == len(js.velocity) == 6
        st = client.wait_message(b.state)
        assert [len(st.brakes), len(st.enabled), len(st.joint_temperatures)] == [6, 6, 6]
        reply = call(client, b, SetJointEnable, "set_joint_enable", joint=7, enable=False)
        assert not reply.success and "joint 7 outside 0-6" in reply.message
        reply = call(client, b, SetJointEnable, "set_joint_enable", joint=0, enable=False)
        assert reply.success, reply.message
        assert [(w.address, w.values) for w in device.write_log] == [(135, (0,) * 6)]
        st = client.wait_message(b.state, lambda m: not any(m.enabled))
        assert list(st.brakes) == [False] * 6  # engaged: the brakes followed


@pytest.mark.parametrize(
    ("params", "words"),
    [
        ({"joint_count": 4}, ["joint_count", "4"]),
        ({"user_coil_first": 500, "user_coil_count": 16}, ["user_coil_first 500", "511"]),
        ({"user_coil_count": 257}, ["user_coil_count", "257"]),
    ],
)
def test_bad_start_up_values_exit_2_with_one_line(params: dict[str, Any], words: list[str]) -> None:
    args = [a for name, value in params.items() for a in ("-p", f"{name}:={value}")]
    line = refused_at_start("xarm_bridge.node", ["--ros-args", *args])
    assert all(word in line for word in words), line
