"""Stepper actions (docs/actions.md): move_by, home, home_all, return_to_zero, line_move
and arc_move as goals from an ``rclpy.action.ActionClient`` in this process, the bridge in
its own, the simulator on a socat pty pair."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from action_msgs.msg import GoalStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from std_srvs.srv import Trigger

from bridge_core.wire.registers import Table
from msg_defs.action import ArcMotion, LineMotion, StepperMoveBy, StepperRun
from msg_defs.msg import MotionOutcome
from msg_defs.srv import LineMove, SetHomingOrder
from stepper_bridge.registers import MOTORS, motor_coil, motor_register
from stepper_bridge.sim import START_POSITION, TRAVEL, StepperSimDevice

from ..support.fixtures import client_fixture
from ..support.ros import Client
from ..support.sims import stepper_on_pty
from .test_stepper_ros import BAUD, bridge, writes

pytestmark = pytest.mark.ros

FAST_RPM = 600  # x lead 5.00 = 50 units (mm) a second
MM = 0.001  # m per controller unit (units_per_meter 1000)


client = client_fixture("stepper_action_client", log=True)


@pytest.fixture
def sim() -> Iterator[tuple[StepperSimDevice, str]]:
    with stepper_on_pty(BAUD) as (device, bridge_end):
        for motor in range(1, MOTORS + 1):
            device.set(motor_register(motor, "speed"), FAST_RPM)
        yield device, bridge_end


def outcome_of(goal: Any, status: int = GoalStatus.STATUS_ABORTED, fed: bool = True) -> Any:
    """The result, after at least one feedback when ``fed`` (every poll begun after the
    start sends one, the poll that ends the goal too)."""
    got_status, result = goal.result()
    assert got_status == status, result.outcome.message
    assert goal.feedback or not fed, "no feedback before the result"
    return result


def coil_writes(device: StepperSimDevice, since: int = 0) -> list[int]:
    return [address for _fc, table, address, _v in writes(device)[since:] if table is Table.COIL]


def running_feedback(goal: Any, motor: int) -> Any:
    return goal.wait_feedback(lambda f: f.running[motor - 1])


def test_stepper_actions(sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path) -> None:
    device, port = sim
    device.position[2] = TRAVEL - 10.0  # coordinate 440: 10 units from its positive limit
    device.position[3] = START_POSITION + 20.0  # 20 units above its home switch
    device.offset[3] = START_POSITION  # coordinate 20
    with bridge(client, tmp_path, port) as (b, _proc):
        client.wait_message(b.state)

        # move_by reached: feedback on the way, the coordinate at the end.
        goal = b.send_goal(StepperMoveBy, "motor_1/move_by", distance=20 * MM)
        assert goal.accepted
        result = outcome_of(goal, GoalStatus.STATUS_SUCCEEDED)
        assert result.outcome.code == MotionOutcome.REACHED
        assert result.positions[0] == pytest.approx(20 * MM)
        assert goal.feedback and len(goal.feedback[-1].positions) == MOTORS
        assert device.coordinate(1) == pytest.approx(20.0)

        # Cancel = the motor's stop coil, and the motor stands.
        mark = len(writes(device))
        goal = b.send_goal(StepperMoveBy, "motor_1/move_by", distance=400 * MM)
        running_feedback(goal, 1)
        goal.cancel()
        result = outcome_of(goal, GoalStatus.STATUS_CANCELED)
        assert result.outcome.code == MotionOutcome.CANCELLED and result.outcome.stop_sent
        assert coil_writes(device, mark) == [
            motor_coil(1, "run_once"),
            motor_coil(1, "stop"),
        ]
        assert device.motion[1] is None

        # Preempted by a new goal on the same motor: stopped first, then homed.
        mark = len(writes(device))
        first = b.send_goal(StepperMoveBy, "motor_1/move_by", distance=400 * MM)
        running_feedback(first, 1)
        home = b.send_goal(StepperRun, "motor_1/home")
        result = outcome_of(first)
        assert result.outcome.code == MotionOutcome.PREEMPTED, result.outcome.message
        result = outcome_of(home, GoalStatus.STATUS_SUCCEEDED)
        assert result.positions[0] == pytest.approx(0.0)
        assert coil_writes(device, mark) == [
            motor_coil(1, "run_once"),
            motor_coil(1, "stop"),
            motor_coil(1, "home"),
        ]

        # A limit switch ends a move as LIMIT, naming the switch.
        goal = b.send_goal(StepperMoveBy, "motor_2/move_by", distance=50 * MM)
        result = outcome_of(goal)
        assert result.outcome.code == MotionOutcome.LIMIT, result.outcome.message
        assert "motor 2 stopped at its positive limit switch (IN3)" in result.outcome.message
        assert result.positions[1] == pytest.approx((TRAVEL - START_POSITION) * MM)

        # Homing one motor: its coordinate ends at 0.
        goal = b.send_goal(StepperRun, "motor_3/home")
        result = outcome_of(goal, GoalStatus.STATUS_SUCCEEDED)
        assert device.coordinate(3) == pytest.approx(0.0)

        # A time limit: stopped and aborted.
        mark = len(writes(device))
        goal = b.send_goal(StepperMoveBy, "motor_4/move_by", distance=400 * MM, timeout_s=0.5)
        result = outcome_of(goal, fed=False)  # a loaded machine may poll less in 0.5 s
        assert result.outcome.code == MotionOutcome.TIMED_OUT and result.outcome.stop_sent
        assert coil_writes(device, mark)[-1] == motor_coil(4, "stop")

        # The e-stop ends a goal as LIMIT.
        goal = b.send_goal(StepperMoveBy, "motor_5/move_by", distance=400 * MM)
        running_feedback(goal, 5)
        reply = b.call(Trigger, "emergency_stop")
        assert reply.success, reply.message
        result = outcome_of(goal)
        assert result.outcome.code == MotionOutcome.LIMIT, result.outcome.message
        assert "e-stop" in result.outcome.message

        # home_all needs a homing order: rejected (nothing written) without one.
        mark = len(writes(device))
        assert not b.send_goal(StepperRun, "home_all").accepted
        client.wait_log("stepper_bridge", "home_all goal rejected: the homing order")
        assert writes(device)[mark:] == []
        reply = b.call(SetHomingOrder, "set_homing_order", motors=[4, 5])
        assert reply.success, reply.message
        outcome_of(b.send_goal(StepperRun, "home_all"), GoalStatus.STATUS_SUCCEEDED)
        assert device.coordinate(4) == pytest.approx(0.0)
        assert device.coordinate(5) == pytest.approx(0.0)

        # Return to zero: every coordinate back at 0 (motor 2 first put back near home,
        # as if moved by hand: 450 units would take 9 s).
        device.position[2] = device.offset[2] + 10.0
        b.send_goal(StepperMoveBy, "motor_1/move_by", distance=30 * MM).result()
        outcome_of(b.send_goal(StepperRun, "return_to_zero"), GoalStatus.STATUS_SUCCEEDED)
        assert [device.coordinate(m) for m in range(1, MOTORS + 1)] == pytest.approx([0.0] * 5)

        # Line, then arc interpolation of pair 1 (motors 1 and 2 under both readings).
        goal = b.send_goal(
            LineMotion, "line_move", pair=1, start=[0.0, 0.0], end=[0.02, 0.01], speed_rpm=600
        )
        result = outcome_of(goal, GoalStatus.STATUS_SUCCEEDED)
        assert result.positions[:2] == pytest.approx([0.02, 0.01])
        goal = b.send_goal(
            ArcMotion,
            "arc_move",
            pair=1,
            mode=ArcMotion.Goal.MODE_CENTER,
            start=[0.02, 0.01],
            end=[0.0, 0.01],
            center=[0.01, 0.01],
            speed_rpm=600,
        )
        result = outcome_of(goal, GoalStatus.STATUS_SUCCEEDED)
        assert result.positions[:2] == pytest.approx([0.0, 0.01], abs=1e-4)

        # Out of range: rejected, nothing written.
        mark = len(writes(device))
        assert not b.send_goal(StepperMoveBy, "motor_1/move_by", distance=float("nan")).accepted
        assert not b.send_goal(LineMotion, "line_move", pair=9, speed_rpm=600).accepted
        assert writes(device)[mark:] == []

        # Deactivate during a goal: stopped (HALTED); goals are then rejected.
        goal = b.send_goal(StepperMoveBy, "motor_1/move_by", distance=400 * MM)
        running_feedback(goal, 1)
        request = ChangeState.Request()
        request.transition.id = Transition.TRANSITION_DEACTIVATE
        reply = client.call(ChangeState, f"{b.ns}/stepper_bridge/change_state", request)
        assert reply.success
        result = outcome_of(goal)
        assert result.outcome.code == MotionOutcome.HALTED, result.outcome.message
        assert "deactivated" in result.outcome.message and result.outcome.stop_sent
        assert device.motion[1] is None
        mark = len(writes(device))
        assert not b.send_goal(StepperMoveBy, "motor_1/move_by", distance=10 * MM).accepted
        client.wait_log("stepper_bridge", "move_by goal rejected: the node is not active")
        assert writes(device)[mark:] == []


def test_a_line_on_the_wrong_motors_is_stopped_and_homing_needs_no_zero(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path
) -> None:
    """Configured for the type rows (pair 2 = motors 1+3) on a controller that
    follows the point rows (2+3): motor 2 moves, the goal is stopped (the interpolation
    stop coils) and aborted, its result naming the motor; a matching one says which moved.
    A controller that leaves the coordinate at home: the home goal succeeds (home input on,
    motor stopped) with the coordinate there, nothing zeroed (zero_after_home false)."""
    device, port = sim
    device.pair_reading = "point_rows"
    with bridge(client, tmp_path, port, interpolation_pair_reading="type_rows") as (b, _proc):
        client.wait_message(b.state)
        goal = b.send_goal(
            LineMotion, "line_move", pair=2, start=[0.005, 0.004], end=[0.009, 0.012], speed_rpm=600
        )
        assert goal.accepted
        result = outcome_of(goal, fed=False)
        outcome = result.outcome
        assert outcome.code == MotionOutcome.HALTED and outcome.stop_sent, outcome.message
        assert "motor 2 0 ->" in outcome.message and "type_rows" in outcome.message
        assert device.interpolation is None
        # Arc stop 00101, line stop 00103, then the own stop of motors 1-3 (every motor
        # either reading of pair 2 names).
        assert coil_writes(device)[-5:] == [100, 102, 4, 9, 14]
        device.pair_reading = "type_rows"
        goal = b.send_goal(
            LineMotion, "line_move", pair=2, start=[0.0, 0.0], end=[0.004, 0.002], speed_rpm=600
        )
        result = outcome_of(goal, GoalStatus.STATUS_SUCCEEDED)
        assert result.outcome.message.endswith("motors moved: 1+3 (coordinates read back)")
        # The same line from the service: no goal follows it, the node stops it itself.
        device.pair_reading = "point_rows"
        mark, called = len(writes(device)), time.monotonic()
        reply = b.call(
            LineMove, "line_move", pair=2, start=[0.01, 0.0], end=[0.012, 0.004], speed_rpm=600
        )
        assert reply.success, reply.message
        client.wait_log(
            "stepper_bridge", "line / arc stopped: a motor outside the pair moved", since=called
        )
        assert coil_writes(device, mark)[-5:] == [100, 102, 4, 9, 14]
        assert device.interpolation is None
        device.zero_at_home = False
        mark = len(writes(device))
        result = outcome_of(b.send_goal(StepperRun, "motor_4/home"), GoalStatus.STATUS_SUCCEEDED)
        assert "motor 4 IN8 on at coordinate -50" in result.outcome.message
        assert result.positions[3] == pytest.approx(-START_POSITION * MM)
        assert coil_writes(device, mark) == [motor_coil(4, "home")]
