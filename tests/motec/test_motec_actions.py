"""MOTEC ``~/move_to`` action (docs/actions.md): an ``rclpy.action.ActionClient`` in this
process, the bridge in its own, the simulated drives on a socat pty pair."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from action_msgs.msg import GoalStatus
from std_srvs.srv import SetBool, Trigger

from bridge_core.wire.registers import Table
from motec_bridge.registers import MOTEC_MAP, START_MOVE, STOP_MOVE
from motec_bridge.sim import MotecSimDrive, MotecSimulator
from msg_defs.action import MoveTo
from msg_defs.msg import MotionOutcome
from msg_defs.srv import SetControlMode

from ..support.fixtures import client_fixture
from ..support.ros import Client, values_of, wait_for
from ..support.sims import motec_on_pty
from .test_motec_ros import BAUD, UNITS, MotecBridge, bridge_params, motec, writes

pytestmark = pytest.mark.ros

START = MOTEC_MAP["start"].address
TURN = 2 * math.pi  # rad per motor turn (10000 counts, gear 1: the bridge's defaults)
SLOW = TURN  # rad/s = 60 rpm: one turn a second
LONG = 20 * TURN  # 20 s at SLOW: cancelled, preempted, timed out long before


client = client_fixture("motec_action_client", diagnostics=True, log=True)


@pytest.fixture
def bus() -> Iterator[tuple[MotecSimulator, str]]:
    """The drives on one simulated bus at the device end of a socat pty pair."""
    with motec_on_pty(UNITS, BAUD) as served:
        yield served


def move_to(b: MotecBridge, unit: int, position: float, **fields: Any) -> Any:
    goal = MoveTo.Goal()
    goal.position = float(position)
    goal.relative = bool(fields.get("relative", False))
    goal.max_velocity = float(fields.get("max_velocity", SLOW))
    goal.timeout_s = float(fields.get("timeout_s", 0.0))
    return b.client.send_goal(MoveTo, f"{b.ns}/motec_{unit}/move_to", goal)


def start_writes(drive: MotecSimDrive, since: int = 0) -> list[int]:
    """The values written to 0x29 (start / stop) since write number ``since``."""
    return [
        values[0]
        for _fc, table, address, values in writes(drive)[since:]
        if table is Table.HOLDING and address == START
    ]


def ready(b: MotecBridge, unit: int) -> None:
    b.wait_connected(unit, True)
    b.ok(unit, SetControlMode, "set_control_mode", mode=SetControlMode.Request.POSITION)
    b.ok(unit, SetBool, "enable", data=True)


def moving_feedback(goal: Any) -> Any:
    return goal.wait_feedback(lambda f: abs(f.velocity) > 0.1)


def test_move_to_reached_cancelled_preempted_timed_out_and_refused(
    bus: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    sim, port = bus
    drive = sim.drive(1)
    with motec(client, tmp_path, bridge_params(port, unit_ids=[1])) as (b, _proc):
        ready(b, 1)

        # Reached: half a turn, feedback on the way, the result where the drive stands.
        goal = move_to(b, 1, math.pi)
        assert goal.accepted
        status, result = goal.result()
        assert status == GoalStatus.STATUS_SUCCEEDED, result.outcome.message
        assert result.outcome.code == MotionOutcome.REACHED and result.outcome.name == "REACHED"
        assert result.position == pytest.approx(math.pi, abs=1e-3)
        assert result.target_counts == 5000
        assert goal.feedback, "no feedback"
        assert goal.feedback[-1].distance_to_go == pytest.approx(0.0, abs=0.01)
        assert start_writes(drive)[-1] == START_MOVE
        assert drive.value("position_actual") == 5000

        # Cancel = stop: 0x29 = 0 on the wire, the drive stands, the result says so.
        mark = len(writes(drive))
        goal = move_to(b, 1, LONG, relative=True)
        moving_feedback(goal)
        b.wait_diagnostic(  # diagnostics name the running goal
            1, lambda s: values_of(s).get("action goals running", "").startswith("move_to by")
        )
        goal.cancel()
        status, result = goal.result()
        assert status == GoalStatus.STATUS_CANCELED
        assert result.outcome.code == MotionOutcome.CANCELLED, result.outcome.message
        assert result.outcome.stop_sent
        assert start_writes(drive, mark) == [START_MOVE, STOP_MOVE]
        wait_for(lambda: drive.value("speed_actual") == 0, 20.0, "drive 1 standing")

        # Preemption: the newer goal stops the older one first, then starts its own move.
        mark = len(writes(drive))
        first = move_to(b, 1, LONG, relative=True)
        moving_feedback(first)
        second = move_to(b, 1, 0.0)
        status, result = first.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.PREEMPTED, result.outcome.message
        assert "preempted by move_to to 0" in result.outcome.message
        status, result = second.result()
        assert result.outcome.code == MotionOutcome.REACHED, result.outcome.message
        assert start_writes(drive, mark) == [START_MOVE, STOP_MOVE, START_MOVE]
        assert drive.value("position_actual") == 0

        # Time limit: stopped and aborted.
        mark = len(writes(drive))
        goal = move_to(b, 1, LONG, relative=True, timeout_s=0.5)
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.TIMED_OUT, result.outcome.message
        assert result.outcome.stop_sent
        assert start_writes(drive, mark) == [START_MOVE, STOP_MOVE]

        # Rejected, nothing written: out of range, bad timeout, read_only. The goal
        # response comes after the check, so the write log is complete when it arrives.
        mark = len(writes(drive))
        assert not move_to(b, 1, 1.0, max_velocity=1e6).accepted
        client.wait_log("motec_1", "move_to goal rejected: velocity")
        assert not move_to(b, 1, 1.0, timeout_s=-1.0).accepted
        assert b.set_param(1, "read_only", True).successful
        assert not move_to(b, 1, 1.0).accepted
        client.wait_log("motec_1", "move_to goal rejected: read_only is set")
        assert b.set_param(1, "read_only", False).successful
        assert writes(drive)[mark:] == []

        # Refused at its start (a check that needs the drive): disabled drive, nothing
        # written by the goal.
        b.ok(1, SetBool, "enable", data=False)
        mark = len(writes(drive))
        goal = move_to(b, 1, 1.0)
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.REFUSED, result.outcome.message
        assert "enabled drive" in result.outcome.message
        assert writes(drive)[mark:] == []


def test_move_to_ended_by_a_fault_by_read_only_and_by_a_lost_link(
    bus: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    sim, port = bus
    with motec(client, tmp_path, bridge_params(port, unit_ids=[1, 2])) as (b, _proc):
        for unit in (1, 2):
            ready(b, unit)

        # A drive fault ends the goal at once with the code and the manual's text.
        goal = move_to(b, 1, LONG, relative=True)
        moving_feedback(goal)
        sim.drive(1).inject_fault(4)
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.FAULT, result.outcome.message
        assert result.outcome.fault_code == 4 and result.outcome.fault_text
        assert "drive fault 4" in result.outcome.message

        # read_only set during a goal: every motion the node started is stopped (HALTED).
        drive = sim.drive(2)
        mark = len(writes(drive))
        goal = move_to(b, 2, LONG, relative=True)
        moving_feedback(goal)
        request = b.set_param(2, "read_only", True)
        assert request.successful
        status, result = goal.result()
        assert result.outcome.code == MotionOutcome.HALTED, result.outcome.message
        assert "read_only was set" in result.outcome.message and result.outcome.stop_sent
        assert start_writes(drive, mark) == [START_MOVE, STOP_MOVE]
        assert b.set_param(2, "read_only", False).successful

        # A lost link: the stop is attempted (one try, nothing answers), then the goal is
        # aborted with LINK_LOST and says the stop did not get through.
        goal = move_to(b, 2, LONG, relative=True)
        moving_feedback(goal)
        sim.unplug(2)
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.LINK_LOST, result.outcome.message
        assert not result.outcome.stop_sent
        assert "stop failed" in result.outcome.message
        assert not move_to(b, 2, 1.0).accepted  # the link is down: rejected
        client.wait_log("motec_2", "move_to goal rejected: not connected")
        plugged = time.monotonic()
        sim.plug(2)
        b.wait_connected(2, True, since=plugged)  # not the connected=True of the start
        reply = b.call(2, Trigger, "stop")
        assert reply.success, reply.message
        wait_for(lambda: sim.drive(2).value("speed_actual") == 0, 20.0, "drive 2 stopped")


def test_move_to_default_time_limit_and_a_stop_that_does_not_take(
    bus: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """A goal without timeout_s ends TIMED_OUT after the move's
    time at its speed limit x move_time_margin + the ramps' allowance; a cancel on a
    drive that takes 0x29 as a start trigger only sees the move go on, releases the
    drive and says so in the result."""
    sim, port = bus
    drive = sim.drive(1)
    with motec(client, tmp_path, bridge_params(port, unit_ids=[1])) as (b, _proc):
        ready(b, 1)
        # 20 turns at one a second: 20 s; x 0.01 + 2 s = 2.2 s.
        assert b.set_param(1, "move_time_margin", 0.01).successful
        goal = move_to(b, 1, LONG, relative=True)
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.TIMED_OUT, result.outcome.message
        assert "default limit" in result.outcome.message, result.outcome.message
        assert result.outcome.stop_sent
        wait_for(lambda: drive.value("speed_actual") == 0, 20.0, "drive 1 standing")
        assert b.set_param(1, "move_time_margin", 0.0).successful  # explicitly none

        drive.start_is_trigger = True
        goal = move_to(b, 1, LONG, relative=True)
        moving_feedback(goal)
        goal.cancel()
        status, result = goal.result()
        assert result.outcome.code == MotionOutcome.CANCELLED, result.outcome.message
        assert "0x29 = 0 did not stop the move" in result.outcome.message, result.outcome.message
        assert "drive released (0x28 = 0, reads 0; " in result.outcome.message
        assert not drive.enabled and drive.value("speed_actual") == 0
