"""Managed bridge nodes: driven through lifecycle_msgs from a client process.

The stepper bridge started with ``autostart:=false`` waits unconfigured: it polls nothing
and refuses commands. configure -> inactive, activate -> polls and publishes; a jog runs;
deactivate stops it on the wire (the simulator's write log), and polls end; cleanup and
shutdown follow. The MOTEC bus and drive nodes are managed the same way (each its own).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from bridge_core.wire.registers import Table
from stepper_bridge.registers import holding, motor_coil
from stepper_bridge.sim import StepperSimDevice, make_simulator

from ...support.fixtures import client_fixture
from ...support.ros import (
    WAIT_S,
    Client,
    node_process,
    unique_namespace,
    wait_for,
    wait_subscribed,
)
from ...support.serial_pair import served_on_pty

pytestmark = pytest.mark.ros

BAUD = 115200


client = client_fixture("lifecycle_client", scope="module")


def state(client: Client, node: str) -> str:
    reply = client.call(GetState, f"{node}/get_state", GetState.Request())
    return str(reply.current_state.label)


def change(client: Client, node: str, transition: int) -> bool:
    request = ChangeState.Request()
    request.transition.id = transition
    return bool(client.call(ChangeState, f"{node}/change_state", request).success)


def test_a_managed_stepper_bridge_stops_its_jog_when_deactivated(
    client: Client, tmp_path: Path
) -> None:
    simulator = make_simulator(reply_delay_s=0.0)
    device = simulator.device
    assert isinstance(device, StepperSimDevice)
    device.log_reads = True
    ns = unique_namespace("lifecycle")
    node = f"{ns}/stepper_bridge"
    with served_on_pty(simulator, BAUD) as port:
        params = {
            "serial_port": port,
            "baudrate": BAUD,
            "poll_rate_hz": 20.0,
            "timeout_s": 1.0,
            "command_timeout_s": 60.0,  # the deadman must not be what stops the jog
            "autostart": False,
        }
        with node_process("stepper_bridge.node", params, tmp_path, ["-r", f"__ns:={ns}"]) as proc:
            assert state(client, node) == "unconfigured"
            reply = client.call(Trigger, f"{node}/motor_1/forward", Trigger.Request())
            assert not reply.success and "not active" in reply.message, reply.message
            assert device.read_log == [] and device.write_log == []  # nothing on the line
            # A transition the state does not have is refused, and the node lives on.
            assert not change(client, node, Transition.TRANSITION_INACTIVE_SHUTDOWN)
            assert state(client, node) == "unconfigured"
            assert proc.poll() is None

            assert change(client, node, Transition.TRANSITION_CONFIGURE)
            assert state(client, node) == "inactive"
            assert device.read_log == []
            client.subscribe(JointState, f"{ns}/joint_states")
            assert change(client, node, Transition.TRANSITION_ACTIVATE)
            assert state(client, node) == "active"
            client.wait_message(f"{ns}/joint_states")

            jog = client.node.create_publisher(Float64, f"{node}/motor_1/jog", 10)
            wait_subscribed(jog)
            jog.publish(Float64(data=300.0))
            wait_for(lambda: device.motion[1] is not None, WAIT_S, "motor 1 jogging")
            writes = len(device.write_log)
            assert change(client, node, Transition.TRANSITION_DEACTIVATE)
            assert state(client, node) == "inactive"
            late = [(r.table, r.address) for r in device.write_log[writes:]]
            assert late[0] == (Table.COIL, motor_coil(1, "stop")), late
            assert device.motion[1] is None
            # Inactive: commands refused, stops still allowed, and no more polls (two round
            # trips through the node, the read log unchanged across them).
            reads = len(device.read_log)
            reply = client.call(Trigger, f"{node}/motor_1/forward", Trigger.Request())
            assert not reply.success and "not active" in reply.message, reply.message
            reply = client.call(Trigger, f"{node}/motor_1/stop", Trigger.Request())
            assert reply.success, reply.message
            assert state(client, node) == "inactive"
            # The only read: the stop's own read-back of motor 1's running flag (40168,
            # stepper decision 23), no poll.
            assert [r.address for r in device.read_log[reads:]] == [holding(40168)]

            assert change(client, node, Transition.TRANSITION_CLEANUP)
            assert state(client, node) == "unconfigured"
            assert change(client, node, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
            assert state(client, node) == "finalized"
            assert proc.poll() is None  # finalized, not exited: Ctrl-C ends the process
            client.node.destroy_publisher(jog)


def test_motec_bus_and_drive_nodes_are_managed(client: Client, tmp_path: Path) -> None:
    from motec_bridge.sim import make_simulator as make_motec

    simulator = make_motec([1, 2])
    ns = unique_namespace("lifecycle_motec")
    with served_on_pty(simulator, BAUD) as port:
        params = {"serial_port": port, "baudrate": BAUD, "unit_ids": [1, 2], "timeout_s": 1.0}
        with node_process("motec_bridge.node", params, tmp_path, ["-r", f"__ns:={ns}"]):
            for name in ("motec_bridge", "motec_1", "motec_2"):
                assert state(client, f"{ns}/{name}") == "active"  # autostart: true
            assert change(client, f"{ns}/motec_2", Transition.TRANSITION_DEACTIVATE)
            assert state(client, f"{ns}/motec_2") == "inactive"
            assert state(client, f"{ns}/motec_1") == "active"  # each drive on its own
            reply = client.call(Trigger, f"{ns}/motec_2/save_to_flash", Trigger.Request())
            assert not reply.success and "not active" in reply.message, reply.message
            assert simulator.drive(2).write_log == []
