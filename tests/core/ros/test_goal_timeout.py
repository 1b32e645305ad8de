"""A goal that gives no ``timeout_s`` still ends by itself: the node's ``goal_timeout_s``.

A client that sent a long goal and vanished (a killed ``ros2 action send_goal``) must not
leave the motor running for ever: with ``timeout_s`` 0 the goal gets the node's live
``goal_timeout_s``; set to 0 (explicitly) it means no limit. An R6 continuous
``run_cycle`` too (R6 decision 27): it must not keep the robot cycling.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters

from bridge_core.wire.registers import Table
from msg_defs.action import RunCycle, StepperMoveBy
from msg_defs.msg import R6State, StepperState
from r6_bridge.registers import COMMANDS, MAX_AXES
from r6_bridge.sim import R6SimDevice, make_simulator
from stepper_bridge.registers import motor_coil

from ...support.fixtures import client_fixture
from ...support.ros import Client, start_bridge
from ...support.serial_pair import PTY_REPLY_TIMEOUT_S
from ...support.sims import stepper_on_pty

pytestmark = pytest.mark.ros

BAUD = 115200
# Twice the distance the motor covers at 5 mm/s in the first goal_timeout_s (1.5 s).
PAST_OLD_LIMIT_M = 0.015
GOAL_TIMEOUT_S = 1.5
# An R6 program of two 15 degree steps: about a second a cycle at 100 % global speed.
R6_PROGRAM = ((15.0,) * MAX_AXES, (0.0,) * MAX_AXES)


client = client_fixture("goal_timeout_client")


def test_a_goal_without_timeout_ends_at_the_nodes_goal_timeout(
    client: Client, tmp_path: Path
) -> None:
    with stepper_on_pty(BAUD) as (device, port):
        params = {
            "serial_port": port,
            "baudrate": BAUD,
            "poll_rate_hz": 20.0,
            "timeout_s": PTY_REPLY_TIMEOUT_S,  # a stalled pty must not end the goal
            "goal_timeout_s": GOAL_TIMEOUT_S,
        }
        with start_bridge(
            client, tmp_path, "stepper_bridge.node", "stepper_bridge", StepperState, params
        ) as (bridge, _proc):
            bridge.wait_connected(True, timeout=30)
            # 400 mm at the default 5 mm/s: far longer than the limit.
            goal = bridge.send_goal(StepperMoveBy, "motor_1/move_by", distance=0.4)
            assert goal.accepted
            _status, result = goal.result(timeout=30)
            goal.close()
            assert result.outcome.name == "TIMED_OUT", result.outcome
            assert device.motion[1] is None
            coils = [r.address for r in device.write_log if r.table == Table.COIL]
            assert coils[-1] == motor_coil(1, "stop")

            # 0, set explicitly, is no limit: the goal runs until cancelled.
            request = SetParameters.Request()
            request.parameters = [
                Parameter(
                    name="goal_timeout_s",
                    value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.0),
                )
            ]
            reply = client.call(SetParameters, bridge.service("set_parameters"), request)
            assert reply.results[0].successful, reply.results[0].reason
            goal = bridge.send_goal(StepperMoveBy, "motor_1/move_by", distance=0.4)
            assert goal.accepted
            first = goal.wait_feedback(lambda f: f.running[0], timeout=30)
            # Past what the old limit allowed (1.5 s at 5 mm/s = 7.5 mm), still running:
            # judged by the motor's own progress, not by the test's clock.
            goal.wait_feedback(
                lambda f: f.running[0] and f.positions[0] - first.positions[0] > PAST_OLD_LIMIT_M,
                timeout=60,
            )
            goal.cancel()
            _status, result = goal.result(timeout=30)
            goal.close()
            assert result.outcome.name == "CANCELLED", result.outcome


def test_a_continuous_run_cycle_without_timeout_ends_at_the_nodes_goal_timeout(
    client: Client, tmp_path: Path
) -> None:
    """R6 decision 27: a continuous run (20003) that gives no ``timeout_s`` is paused
    (20001) and aborted TIMED_OUT at the node's ``goal_timeout_s``, as every goal is."""
    simulator = make_simulator(axis_count=6, io_board_count=1)
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    device.program = R6_PROGRAM
    device.set("global_speed", 100.0)
    port = simulator.start_tcp()
    names = {address: name for name, address in COMMANDS.items()}
    try:
        params = {"port": port, "poll_rate_hz": 50.0, "goal_timeout_s": GOAL_TIMEOUT_S}
        with start_bridge(client, tmp_path, "r6_bridge.node", "r6_bridge", R6State, params) as (
            bridge,
            _proc,
        ):
            client.wait_message(bridge.state, lambda s: s.global_speed_percent == 100.0)
            goal = bridge.send_goal(RunCycle, "run_cycle", single_cycle=False)
            assert goal.accepted
            _status, result = goal.result(timeout=30)
            goal.close()
            assert result.outcome.name == "TIMED_OUT", result.outcome
            assert "pause (20001)" in result.outcome.message, result.outcome.message
            commands = [names[r.address] for r in device.write_log if r.address in names]
            assert commands == ["start", "pause"]
            assert not device.running
    finally:
        simulator.stop()
