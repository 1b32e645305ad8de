"""Several stepper controllers on one RS-485 line (40212 "主-从模式的多机通信"):
``python -m stepper_bridge.bus`` in its own process against two simulated controllers on
one socat pty pair, driven by an rclpy client in this process."""

from __future__ import annotations

import functools
from pathlib import Path

import pytest

from bridge_core.wire.registers import Table
from msg_defs.msg import StepperState
from msg_defs.srv import MoveBy
from stepper_bridge.sim import StepperSimDevice, make_bus_simulator

from ..support.fixtures import client_fixture
from ..support.ros import (
    WAIT_S,
    Bridge,
    Client,
    node_process,
    refused_at_start,
    ros_args,
    unique_namespace,
    values_of,
    wait_for,
)
from ..support.serial_pair import served_on_pty

pytestmark = pytest.mark.ros

BAUD = 115200
UNITS = (1, 3)


client = client_fixture("stepper_bus_client", diagnostics=True, scope="module")


def params_file(tmp_path: Path, port: str) -> Path:
    """The bus's link and unit ids for every node; a joint prefix per controller."""
    path = tmp_path / "stepper_bus.yaml"
    path.write_text(
        f"""/**:
  ros__parameters:
    serial_port: "{port}"
    baudrate: {BAUD}
    unit_ids: [{", ".join(map(str, UNITS))}]
    timeout_s: 1.0
    reconnect_max_s: 1.0
    poll_rate_hz: 10.0
/**/stepper_1:
  ros__parameters:
    joint_prefix: "a_"
/**/stepper_3:
  ros__parameters:
    joint_prefix: "b_"
"""
    )
    return path


def test_two_controllers_share_one_line(client: Client, tmp_path: Path) -> None:
    simulator = make_bus_simulator(UNITS, reply_delay_s=0.0)
    fakes = simulator.devices
    first, third = fakes[1], fakes[3]
    assert isinstance(first, StepperSimDevice) and isinstance(third, StepperSimDevice)
    third.set("motor2_speed", 123)
    ns = unique_namespace("stepper_bus")
    bridges = {unit: Bridge(client, ns, f"stepper_{unit}", StepperState) for unit in UNITS}
    with (
        served_on_pty(simulator, BAUD) as port,
        node_process(
            "stepper_bridge.bus",
            {},
            tmp_path,
            ["--params-file", str(params_file(tmp_path, port)), "-r", f"__ns:={ns}"],
        ) as proc,
    ):
        # Each node polls its own controller: unit 3's speed shows on stepper_3 only.
        st3 = client.wait_message(bridges[3].state)
        st1 = client.wait_message(bridges[1].state)
        assert (st3.speed_rpm[1], st1.speed_rpm[1]) == (123, 60)
        wait_for(
            lambda: (
                {m.name[0] for m in client.received(bridges[1].joint_states)}
                >= {"a_motor_1", "b_motor_1"}
            ),
            WAIT_S,
            "joint_states of both controllers",
        )

        def device_id(unit: int) -> str | None:
            for status in reversed(bridges[unit].diagnostics()):
                if "device id" in values_of(status):
                    return values_of(status)["device id"]
            return None

        for unit in UNITS:
            found = wait_for(functools.partial(device_id, unit), WAIT_S, "device id")
            assert found == str(unit)
        # A command on one node reaches its own controller only.
        reply = bridges[3].call(MoveBy, "motor_1/move_by", distance=0.001)
        assert reply.success, reply.message
        assert [(r.table, r.address) for r in third.write_log] == [
            (Table.HOLDING, 4),
            (Table.HOLDING, 8),
            (Table.COIL, 0),
        ]
        assert first.write_log == []
        assert proc.poll() is None


@pytest.mark.parametrize(
    ("params", "text"),
    [
        ({"unit_ids": list(range(1, 13))}, "fewer than 12"),
        ({"unit_ids": [1, 2]}, "joint_prefix"),
        ({"unit_ids": [0]}, "unit id 0"),
        ({"unit_ids": [250]}, "unit id 250 outside 1-247"),
        ({"unit_ids": [1], "baudrate": 4800, "timeout_s": 0.15}, "below 0.26 s"),
    ],
)
def test_bus_settings_refused_at_start(params: dict[str, object], text: str) -> None:
    line = refused_at_start("stepper_bridge.bus", ros_args(params))
    assert text in line, line
