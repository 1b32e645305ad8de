"""R6 actions (docs/actions.md): ``~/run_cycle`` and ``~/upload_points`` as goals from an
``rclpy.action.ActionClient`` in this process, the bridge in its own, the simulator
serving TCP on a thread here (its write log and program are the test's to read)."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from action_msgs.msg import GoalStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from std_srvs.srv import Trigger

from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.transport import ModbusLink, TcpSettings
from msg_defs.action import PointUpload, RunCycle
from msg_defs.msg import MotionOutcome, R6State
from msg_defs.srv import ClearAlarmAndNext, ReadDataSource, UploadPoints
from r6_bridge.registers import COMMANDS, MAX_AXES, R6_MAP
from r6_bridge.sim import R6SimDevice, make_simulator

from ..support.fixtures import client_fixture
from ..support.ros import (
    Bridge,
    Client,
    node_process,
    start_bridge,
    unique_namespace,
)

pytestmark = pytest.mark.ros

TIMEOUT_S = 1.0
EXIT_TIMEOUT_S = 20.0  # Ctrl-C to exit on a loaded machine (a bound, not a measure)
# Two steps of 15 degrees: a cycle of about a second at 100 % global speed.
PROGRAM = ((15.0,) * MAX_AXES, (0.0,) * MAX_AXES)
POINT_COUNT = R6_MAP["point_count"].address
FRAME_DELAY_S = 0.01  # the simulated controller takes this long over each point frame


client = client_fixture("r6_action_client", log=True)


@pytest.fixture
def sim() -> Iterator[tuple[R6SimDevice, int]]:
    simulator: Simulator = make_simulator(axis_count=6, io_board_count=1)
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    device.program = PROGRAM
    device.set("global_speed", 100.0)
    port = simulator.start_tcp()
    yield device, port
    simulator.stop()


def r6(client: Client, tmp_path: Path, port: int) -> Any:
    params = {"port": port, "poll_rate_hz": 50.0, "timeout_s": TIMEOUT_S, "reconnect_max_s": 1.0}
    return start_bridge(client, tmp_path, "r6_bridge.node", "r6_bridge", R6State, params)


def upload(b: Bridge, source: int, values: list[int], **fields: Any) -> Any:
    """A PointUpload goal of 6-value points for axes 1-6."""
    return b.send_goal(
        PointUpload,
        "upload_points",
        data_source_id=source,
        values_per_point=6,
        axis_mask=0x3F,
        values=values,
        **fields,
    )


def commands(device: R6SimDevice, since: int = 0) -> list[str]:
    names = {address: name for name, address in COMMANDS.items()}
    return [names[r.address] for r in device.write_log[since:] if r.address in names]


def test_run_cycle(sim: tuple[R6SimDevice, int], client: Client, tmp_path: Path) -> None:
    device, port = sim
    with r6(client, tmp_path, port) as (b, _proc):
        client.wait_message(b.state, lambda s: s.global_speed_percent == 100.0)

        # A single cycle: done when the program stands still again.
        cycles = device.cycles_completed
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=True)
        assert goal.accepted
        status, result = goal.result()
        assert status == GoalStatus.STATUS_SUCCEEDED, result.outcome.message
        assert result.outcome.code == MotionOutcome.REACHED
        assert device.cycles_completed == cycles + 1
        assert any(f.moving for f in goal.feedback)
        assert result.last_cycle_time_ms > 0
        assert commands(device) == ["single_cycle"]

        # A continuous run, cancelled: pause (20001) on the wire, the program stands at
        # its step (a stop would send the next start back to step 1 from wherever the arm
        # stands).
        mark = len(device.write_log)
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=False)
        goal.wait_feedback(lambda f: f.moving)
        goal.cancel()
        status, result = goal.result()
        assert status == GoalStatus.STATUS_CANCELED
        assert result.outcome.code == MotionOutcome.CANCELLED and result.outcome.stop_sent
        assert "pause (20001)" in result.outcome.message
        assert commands(device, mark) == ["start", "pause"]
        assert not device.running

        # A single cycle stopped by another client half-way: moving ends, but no cycle
        # ended (the last cycle time did not change): aborted STOPPED, never REACHED.
        assert b.call(Trigger, "stop").success  # from step 1 again
        client.wait_message(b.state, lambda s: not s.moving and s.current_cycle_time_ms == 0)
        cycles = device.cycles_completed
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=True)
        goal.wait_feedback(lambda f: f.moving and f.current_cycle_time_ms > 100)
        mark = len(device.write_log)
        other = ModbusLink(TcpSettings(port=port, timeout_s=TIMEOUT_S))
        DeviceChannel(other, 1).write_register(COMMANDS["stop"], 1)  # another client's stop
        other.close()
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.STOPPED, result.outcome.message
        assert "could not prove the cycle finished" in result.outcome.message
        assert device.cycles_completed == cycles and commands(device, mark) == ["stop"]

        # An alarm ends the goal with its code; a goal is then rejected until it is cleared.
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=False)
        goal.wait_feedback(lambda f: f.moving)
        device.set_alarm(0x325)
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.FAULT, result.outcome.message
        assert result.outcome.fault_code == 0x325
        client.wait_message(b.state, lambda s: s.alarm_code == 0x325)
        mark = len(device.write_log)
        assert not b.send_goal(RunCycle, "run_cycle", single_cycle=True).accepted
        client.wait_log("r6_bridge", "run_cycle goal rejected: alarm 805 is active")
        assert device.write_log[mark:] == []
        cleared = time.monotonic()
        assert b.call(ClearAlarmAndNext, "clear_alarm_and_next", skip_failed_step=True).success
        assert b.call(Trigger, "stop").success

        # A time limit on a continuous run: stopped, aborted.
        client.wait_message(b.state, lambda s: s.alarm_code == 0 and not s.moving, since=cleared)
        mark = len(device.write_log)
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=False, timeout_s=0.5)
        assert goal.accepted
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.TIMED_OUT, result.outcome.message
        assert commands(device, mark) == ["start", "pause"]

        # Global speed 0: the program would not move; rejected, nothing written.
        device.set("global_speed", 0.0)
        client.wait_message(b.state, lambda s: s.global_speed_percent == 0.0)
        mark = len(device.write_log)
        assert not b.send_goal(RunCycle, "run_cycle", single_cycle=True).accepted
        assert device.write_log[mark:] == []


def test_upload_points_with_progress_and_cancel(
    sim: tuple[R6SimDevice, int], client: Client, tmp_path: Path
) -> None:
    device, port = sim

    def slow_frames(record: WriteRecord) -> None:
        if record.address == POINT_COUNT:
            time.sleep(FRAME_DELAY_S)  # the controller's own pace: each frame takes a while

    device.write_hooks.append(slow_frames)
    points = 2000  # 6 values a point, 10 points a 256-byte frame: 200 frames
    values = [k % 1000 for k in range(6 * points)]
    with r6(client, tmp_path, port) as (b, _proc):
        client.wait_message(b.state)

        # The whole upload: feedback per frame, every point stored.
        goal = upload(b, 7, values[: 6 * 100])
        status, result = goal.result()
        assert status == GoalStatus.STATUS_SUCCEEDED, result.outcome.message
        assert (result.frames_sent, result.frames_total) == (10, 10)
        assert [f.frames_sent for f in goal.feedback] == list(range(1, 11))
        assert device.points[7] == values[: 6 * 100]

        # Cancelled part-way: it stops between frames and says how far it got.
        goal = upload(b, 8, values)
        goal.wait_feedback(lambda f: f.frames_sent >= 3)
        # Between its frames the point-data rows are the goal's: the services are refused.
        refused = (
            b.call(ReadDataSource, "read_data_source", source_id=7),
            b.call(
                UploadPoints, "upload_points", data_source_id=3, values_per_point=6, values=[1] * 6
            ),
        )
        for reply in refused:
            assert not reply.success and "using the point-data rows" in reply.message
        goal.cancel()
        status, result = goal.result()
        assert status == GoalStatus.STATUS_CANCELED
        assert result.outcome.code == MotionOutcome.CANCELLED
        assert 3 <= result.frames_sent < result.frames_total == 200
        assert f"({result.frames_sent} of 200 sent)" in result.outcome.message
        # The part that went out is cleared (decision 25): no path cut short stays.
        assert "source 8 cleared" in result.outcome.message, result.outcome.message
        assert device.points[8] == [] and result.points_held == 0

        # A newer upload preempts a running one between two frames.
        first = upload(b, 9, values)
        first.wait_feedback(lambda f: f.frames_sent >= 2)
        second = upload(b, 10, values[:60])
        status, result = first.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.PREEMPTED, result.outcome.message
        assert result.frames_sent < 200
        status, result = second.result()
        assert result.outcome.code == MotionOutcome.REACHED, result.outcome.message
        assert device.points[10] == values[:60]
        assert device.points[9] == []  # cleared before the newer upload began

        # A time limit ends an upload between frames.
        goal = upload(b, 11, values, timeout_s=0.3)
        status, result = goal.result()
        assert result.outcome.code == MotionOutcome.TIMED_OUT, result.outcome.message
        assert result.frames_sent < 200
        assert device.points.get(11, []) == [] and result.points_held == 0


@pytest.mark.parametrize("end", ["deactivate", "exit"])
def test_a_halt_pauses_a_running_cycle(
    sim: tuple[R6SimDevice, int], client: Client, tmp_path: Path, end: str
) -> None:
    """Deactivate and exit end a run_cycle goal through the node's halt
    (``stop_all``), not its cancel: that path too sends pause (20001), which keeps the
    program's step, and never stop (20000), which would send the operator's next start
    back to step 1 from wherever the arm stands."""
    device, port = sim
    b = Bridge(client, unique_namespace(f"r6_halt_{end}"), "r6_bridge", R6State)
    params = {"port": port, "poll_rate_hz": 50.0, "timeout_s": TIMEOUT_S, "reconnect_max_s": 1.0}
    with node_process("r6_bridge.node", params, tmp_path, ["-r", f"__ns:={b.ns}"]) as proc:
        client.wait_message(b.state, lambda s: s.global_speed_percent == 100.0)
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=False)
        assert goal.accepted
        goal.wait_feedback(lambda f: f.moving)
        mark = len(device.write_log)
        if end == "deactivate":
            request = ChangeState.Request()
            request.transition.id = Transition.TRANSITION_DEACTIVATE
            assert client.call(ChangeState, b.service("change_state"), request).success
            status, result = goal.result()
            assert status == GoalStatus.STATUS_ABORTED
            assert result.outcome.code == MotionOutcome.HALTED, result.outcome.message
            assert "deactivated" in result.outcome.message, result.outcome.message
            assert "pause (20001)" in result.outcome.message, result.outcome.message
        else:
            proc.send_signal(signal.SIGINT)
            assert proc.wait(EXIT_TIMEOUT_S) == 0
        assert commands(device, mark) == ["pause"]
        assert not device.running
        goal.close()
