"""The R6 bridge against a controller that does not obey or answers late.

The simulator plays such a controller (docs/tools.md "Device personalities",
docs/bridges/r6.md "Simulator"): ``--ignore NAME,...`` acknowledges the named motion
writes and changes nothing, ``--reply-delay-ms MIN:MAX`` answers each request after a
round trip drawn in that range, ``--cycle-time-at start`` writes the last cycle time
(2401) when a cycle begins. The rows:

- the device layer (no ROS): stops, pauses and starts are done only when read back (R6
  decision 29), and ``run_cycle``'s REACHED holds under either reading of 2401 (decision
  23); the simulator refuses the writes the map refuses (decisions 3, 5);
- the node in its own process (rclpy clients here): every way motion starts, stops or
  changes against a controller that ignores it is never success or REACHED, says what
  was written and read back, and a halt (deactivate, read_only, exit) still tries its
  stop and logs "not confirmed"; against round trips up to 50 ms the node connects,
  polls, reconnects after the simulator is killed and restarted, and a stop goes out at
  once.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from action_msgs.msg import GoalStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from bridge_core.runtime.goals import Outcome
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import DeviceException, NotConfirmed
from bridge_core.wire.transport import ModbusLink, TcpSettings
from msg_defs.action import RunCycle
from msg_defs.msg import MotionOutcome, R6State
from msg_defs.srv import ClearAlarmAndNext, SetValue
from r6_bridge.device import R6Device
from r6_bridge.motions import RunCycleMotion
from r6_bridge.registers import COMMANDS, R6_MAP, parameter_address
from r6_bridge.sim import IGNORABLE, R6SimDevice, make_simulator

from ..support.bridges import BRIDGES, SimProcess
from ..support.fixtures import client_fixture
from ..support.ros import (
    Bridge,
    Client,
    node_process,
    start_bridge,
    unique_namespace,
    wait_for,
)
from .test_r6_sim import judge_until, judge_until_after_start, timed_program, wait_for_poll

TIMEOUT_S = 1.0
EXIT_TIMEOUT_S = 20.0  # Ctrl-C to exit on a loaded machine (a bound, not a measure)
WAIT_S = 30.0
STOPS = ("stop", "pause", "stop_button")
STARTS = ("start", "single_cycle")
# Two steps of 15 degrees: a cycle of about a second at 100 % global speed.
PROGRAM = timed_program(0.5, 0.0)
R6_INFO = next(info for info in BRIDGES if info.key == "r6")


# ---------------------------------------------------------------- the simulator
@pytest.fixture
def simulator() -> Iterator[tuple[Simulator, R6SimDevice, int]]:
    simulator = make_simulator(axis_count=6, io_board_count=1)
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    device.program = PROGRAM
    device.set("global_speed", 100.0)
    port = simulator.start_tcp()
    yield simulator, device, port
    simulator.stop()


@pytest.fixture
def r6(
    simulator: tuple[Simulator, R6SimDevice, int],
) -> Iterator[tuple[R6Device, R6SimDevice, DeviceChannel, Simulator]]:
    sim, device, port = simulator
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    channel = DeviceChannel(link, 1, retries=0)
    yield R6Device(channel), device, channel, sim
    link.close()


def commands(device: R6SimDevice, since: int = 0) -> list[tuple[str, bool]]:
    """The commands (20000-20006) the simulator saw, each with its ``ignored`` flag."""
    names = {address: name for name, address in COMMANDS.items()}
    return [(names[r.address], r.ignored) for r in device.write_log[since:] if r.address in names]


def test_every_motion_write_has_a_name_and_is_ignored_by_it(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """``--ignore``: each name covers the writes the bridge sends for it; such a write is
    acknowledged, logged ``ignored``, and changes nothing."""
    _, device, channel, sim = r6
    assert set(IGNORABLE) == {*STOPS, *STARTS, "clear_alarm", "speed"}
    assert R6SimDevice.IGNORABLE == IGNORABLE
    sim.ignore(IGNORABLE)
    device.running = True
    for name in (*STOPS, *STARTS, "clear_alarm_and_next", "clear_alarm_and_continue"):
        channel.write_register(COMMANDS[name], 1)
    channel.write_register(R6_MAP["global_speed"].address, 100)
    assert all(record.ignored for record in device.write_log)
    assert len(device.write_log) == 8
    assert device.running and device.get("global_speed") == 100.0


def test_ignore_names_on_the_command_line() -> None:
    """A name the simulator does not have: one line naming the ones it has, exit 2."""
    proc = subprocess.run(
        [sys.executable, "-m", "r6_bridge.sim", "--ignore", "jump"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "unknown motion write jump" in proc.stderr
    assert "stop_button" in proc.stderr and "Traceback" not in proc.stderr


def run_one_cycle(device: R6SimDevice) -> None:
    """Let the simulator run one whole cycle as a single cycle (its own clock; waits on a
    condition): it stands at the end."""
    target = device.cycles_completed + 1
    with device.lock:
        device.single_cycle = True
        device.running = True
    wait_for(lambda: device.cycles_completed >= target and not device.running, WAIT_S, "a cycle")


def test_cycle_time_written_at_a_cycles_start(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """``--cycle-time-at start``: 2401 takes the last completed cycle's time when the next
    cycle begins, not when that cycle ends."""
    _, device, _, _ = r6
    device.program = timed_program(0.1, 0.0)
    device.set_cycle_time_at("start")
    run_one_cycle(device)
    assert device.get("last_cycle_time") == 0  # the cycle ended: nothing written yet
    device.running = True
    wait_for(lambda: device.get("last_cycle_time") != 0, WAIT_S, "2401 at the next start")
    assert device.cycles_completed == 1  # written while the second cycle runs
    with pytest.raises(ValueError, match="one of end, start"):
        device.set_cycle_time_at("middle")


def test_the_simulator_refuses_the_writes_the_map_refuses(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """Decision 5: parameters 965-999 (22230-22299) are read only; decision 3: 20056
    takes boards 0-3 only (4-7 mean different boards in §3.3.3 and the table)."""
    _, device, channel, _ = r6
    with pytest.raises(DeviceException, match="exception 0x02"):
        channel.write_registers(parameter_address(965), [0, 1])
    with pytest.raises(DeviceException, match="exception 0x02"):
        channel.write_registers(parameter_address(999), [0, 1])
    with pytest.raises(DeviceException, match="exception 0x02"):
        channel.write_registers(parameter_address(964), [0, 1, 0, 2])  # runs into 965
    for board in (4, 7):
        with pytest.raises(DeviceException, match="exception 0x03"):
            channel.write_registers(R6_MAP["output_board"].address, [board, 0, 1])
    assert device.write_log == []
    channel.write_registers(parameter_address(964), [0, 1])
    channel.write_registers(R6_MAP["output_board"].address, [3, 0, 1])
    assert len(device.write_log) == 2


# ---------------------------------------------------------------- stops and starts read back
@pytest.mark.parametrize("name", STOPS)
def test_a_stop_the_controller_ignores_is_not_confirmed(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator], name: str
) -> None:
    """Decision 29: done only when 2470 reads 0 and 2397 stops counting; otherwise what
    was written and read."""
    bridge, device, _, sim = r6
    device.running = True
    sim.ignore({name})
    with pytest.raises(NotConfirmed) as err:
        bridge.halt(name)
    said = str(err.value)
    assert f"wrote {COMMANDS[name]} = 1 ({name})" in said and "read moving (2470) 1" in said
    assert commands(device) == [(name, True)] and device.running
    sim.ignore(())
    said = bridge.halt(name)
    assert "moving (2470) 0" in said and "the program stands" in said
    assert not device.running


@pytest.mark.parametrize("name", STARTS)
def test_a_start_the_controller_ignores_is_not_confirmed(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator], name: str
) -> None:
    bridge, device, _, sim = r6
    sim.ignore({name})
    with pytest.raises(NotConfirmed) as err:
        bridge.run_program(name)
    said = str(err.value)
    assert f"wrote {COMMANDS[name]} = 1 ({name})" in said and "read moving (2470) 0" in said
    assert "did not start" in said
    sim.ignore(())
    assert "the program runs" in bridge.run_program(name)
    assert device.running


# ---------------------------------------------------------------- run_cycle's REACHED
def test_a_cycle_stopped_half_way_is_not_reached_when_2401_is_written_at_a_start(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """Decision 23 under the other reading: 2401 changes when the cycle begins, so its
    change proves nothing; a cycle another client stops half-way is not REACHED."""
    bridge, device, channel, _ = r6
    device.set_cycle_time_at("start")
    device.program = timed_program(0.1, 0.0)
    run_one_cycle(device)  # a completed cycle for the next start to write
    device.program = PROGRAM
    motion = RunCycleMotion(bridge, bridge.poll(), single_cycle=True)
    motion.start()
    # Under way with the 2401 its start wrote: a poll can read 2401 just before the start
    # and ``moving`` just after (that case is the test below).
    wait_for_poll(
        bridge,
        lambda s: motion.judge(s) is None and s.moving and s.last_cycle_time_ms != 0,
        "the cycle under way, 2401 written",
    )
    R6Device(channel).command("stop")  # another client's stop
    verdict = judge_until_after_start(bridge, motion)
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "could not prove the cycle finished" in verdict.message
    assert "changed while the cycle ran" in verdict.message
    assert bridge.cycle_time_written_at == "start"


class StartBeforeMoving(DeviceChannel):
    """Once ``armed``, the next read of 2470 first runs one tick of the (held) simulator:
    its cycle begins, 2401 written, between a poll's read of 2401 and its read of
    ``moving``, as it may on a real controller."""

    sim: R6SimDevice
    armed = False

    def read_registers(self, address: int, *args: Any, **kwargs: Any) -> list[int]:
        if self.armed and address == R6_MAP["moving"].address:
            self.armed = False
            R6SimDevice.tick(self.sim, 0.02)
        return super().read_registers(address, *args, **kwargs)


def test_a_cycle_stopped_before_any_poll_read_2401_while_it_counted_is_not_reached(
    simulator: tuple[Simulator, R6SimDevice, int],
) -> None:
    """Decision 23: a poll that read 2401 (unchanged) just before the cycle began and
    ``moving`` (1) just after, then a stop from another client: every later poll stands
    with the 2401 the start wrote. No poll read 2401 while 2397 counted, so its change
    proves no end: STOPPED, and the bridge learns neither reading (REACHED before)."""
    _, device, port = simulator
    device.set_cycle_time_at("start")
    device.program = timed_program(0.1, 0.0)
    run_one_cycle(device)  # a completed cycle for the next start to write
    device.program = PROGRAM
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    channel = StartBeforeMoving(link, 1, retries=0)
    channel.sim = device
    try:
        bridge = R6Device(channel)
        device.tick = lambda dt: None  # type: ignore[method-assign]  # held: the hook ticks
        motion = RunCycleMotion(bridge, bridge.poll(), single_cycle=True)
        motion.start()
        channel.armed = True
        torn = bridge.poll()
        assert torn.moving and torn.last_cycle_time_ms == 0, torn
        assert motion.judge(torn) is None
        R6Device(channel).command("stop")  # another client's stop
        R6SimDevice.tick(device, 0.02)  # stood: ``moving`` 0 before the next poll
        del device.tick  # the simulator's own clock again
        verdict = judge_until_after_start(bridge, motion)
    finally:
        link.close()
    assert device.get("last_cycle_time") != 0  # the start wrote it
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "no poll read it while the cycle counted" in verdict.message
    assert bridge.cycle_time_written_at is None


def test_a_whole_cycle_is_not_claimed_when_2401_is_written_at_a_start(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """Under that reading no read shows a cycle's end: "could not prove", never REACHED."""
    bridge, device, _, _ = r6
    device.set_cycle_time_at("start")
    device.program = timed_program(0.1, 0.0)
    run_one_cycle(device)
    device.program = timed_program(0.3, 0.0)
    verdict = judge_until(bridge, RunCycleMotion(bridge, bridge.poll(), single_cycle=True))
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "could not prove the cycle finished" in verdict.message


def test_a_goal_sent_while_the_program_runs_is_not_reached_on_that_cycle(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """The cycle that ends began before the goal: it proves nothing of the goal's."""
    bridge, device, _, _ = r6
    device.running = True  # a continuous run, started by someone else
    wait_for_poll(bridge, lambda s: s.moving and s.current_cycle_time_ms > 0, "the run")
    cycles = device.cycles_completed
    verdict = judge_until(bridge, RunCycleMotion(bridge, bridge.poll(), single_cycle=True))
    assert device.cycles_completed == cycles + 1  # 20002 ended the run with its cycle
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "already running when the goal came" in verdict.message


def test_a_cycle_as_long_as_the_last_one_could_not_be_proved(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """A finished cycle whose time ties the last one's to the millisecond reads as 2401
    unchanged: "could not prove it finished", not "stopped by another client"."""
    bridge, device, _, _ = r6
    device.program = timed_program(0.3, 0.0)
    before = bridge.poll()
    motion = RunCycleMotion(bridge, before, single_cycle=True)
    motion.start()
    started = time.monotonic()
    deadline = started + WAIT_S
    while True:
        with device.lock:  # the controller's tie: 2401 written with the same time
            if device.cycles_completed:
                device.set("last_cycle_time", before.last_cycle_time_ms)
        verdict = motion.judge(bridge.poll(), time.monotonic() - started)
        if verdict is not None:
            break
        assert time.monotonic() < deadline, "no verdict"
    assert device.cycles_completed == 1
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "could not prove the cycle finished" in verdict.message
    assert "a cycle exactly as long as the last one" in verdict.message


def test_a_cycle_between_two_polls_is_not_claimed_before_2401_was_seen(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel, Simulator],
) -> None:
    """No goal yet saw when this controller writes 2401: a cycle no poll saw running is
    not proved (a start stopped before any poll reads the same under the other reading)."""
    bridge, device, _, _ = r6
    device.program = timed_program(0.05)
    motion = RunCycleMotion(bridge, bridge.poll(), single_cycle=True)
    motion.start()
    started = time.monotonic()
    wait_for(lambda: device.cycles_completed >= 1, WAIT_S, "the whole cycle before a poll")
    deadline = started + WAIT_S
    while (verdict := motion.judge(bridge.poll(), time.monotonic() - started)) is None:
        assert time.monotonic() < deadline, "no verdict"
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "no poll saw it running" in verdict.message


# ---------------------------------------------------------------- the node
client = client_fixture("r6_personality_client", log=True, scope="module")


def node_params(port: int, **more: Any) -> dict[str, Any]:
    return {
        "port": port,
        "poll_rate_hz": 50.0,
        "timeout_s": TIMEOUT_S,
        "reconnect_max_s": 1.0,
        **more,
    }


def said_what_it_wrote_and_read(message: str, name: str) -> None:
    assert "not confirmed" in message, message
    assert f"wrote {COMMANDS[name]} = 1 ({name})" in message, message
    assert "read moving (2470)" in message, message


def test_services_against_a_controller_that_ignores_them(
    simulator: tuple[Simulator, R6SimDevice, int], client: Client, tmp_path: Path
) -> None:
    """~/start, ~/single_cycle, ~/stop, ~/pause, ~/stop_button: never success when the
    controller does not obey; the reply says what was written and read back. Obeyed:
    success, with what was read."""
    sim, device, port = simulator
    with start_bridge(
        client, tmp_path, "r6_bridge.node", "r6_bridge", R6State, node_params(port)
    ) as (
        b,
        _proc,
    ):
        client.wait_message(b.state, lambda s: s.global_speed_percent == 100.0)
        sim.ignore(STARTS)
        for name in STARTS:
            reply = b.call(Trigger, name)
            assert not reply.success, reply.message
            said_what_it_wrote_and_read(reply.message, name)
        assert commands(device) == [(name, True) for name in STARTS] and not device.running
        sim.ignore(STOPS)
        device.running = True
        mark = len(device.write_log)
        for name in STOPS:
            reply = b.call(Trigger, name)
            assert not reply.success, reply.message
            said_what_it_wrote_and_read(reply.message, name)
        assert commands(device, mark) == [(name, True) for name in STOPS] and device.running
        sim.ignore(())
        reply = b.call(Trigger, "pause")
        assert reply.success and "the program stands" in reply.message, reply.message
        reply = b.call(Trigger, "start")
        assert reply.success and "the program runs" in reply.message, reply.message
        assert b.call(Trigger, "stop").success


def test_speed_and_alarm_clears_against_a_controller_that_ignores_them(
    simulator: tuple[Simulator, R6SimDevice, int], client: Client, tmp_path: Path
) -> None:
    """~/set_global_speed (the running program's speed) and the alarm clears that set it
    running again: not success when the controller keeps its value, with what was
    written and read back; success, with the read, when it takes it."""
    sim, device, port = simulator
    params = node_params(port)
    with start_bridge(client, tmp_path, "r6_bridge.node", "r6_bridge", R6State, params) as (
        b,
        _proc,
    ):
        client.wait_message(b.state, lambda s: s.global_speed_percent == 100.0)
        sim.ignore({"speed", "clear_alarm"})
        reply = b.call(SetValue, "set_global_speed", value=25.0)
        assert not reply.success and "not confirmed" in reply.message, reply.message
        assert "wrote 20200 = 250" in reply.message and "read 20200 = 1000" in reply.message
        device.set_alarm(0x325)
        client.wait_message(b.state, lambda s: s.alarm_code == 0x325)
        reply = b.call(Trigger, "clear_alarm_and_continue")
        assert not reply.success and "not confirmed" in reply.message, reply.message
        assert "wrote 20006 = 1" in reply.message and "alarm code (2396) 805" in reply.message
        reply = b.call(ClearAlarmAndNext, "clear_alarm_and_next", skip_failed_step=True)
        assert not reply.success and "wrote 20005 = 1" in reply.message, reply.message
        assert [r.ignored for r in device.write_log] == [True, True, True]
        sim.ignore(())
        reply = b.call(SetValue, "set_global_speed", value=25.0)
        assert reply.success and "read 250 (25 %)" in reply.message, reply.message
        reply = b.call(Trigger, "clear_alarm_and_continue")
        assert reply.success and "alarm code (2396) 0" in reply.message, reply.message


def test_run_cycle_against_a_controller_that_ignores_it(
    simulator: tuple[Simulator, R6SimDevice, int], client: Client, tmp_path: Path
) -> None:
    """A single cycle the controller ignores: never REACHED, the result says what was
    written and read; a cancel whose pause is ignored: the result says "not confirmed"."""
    sim, device, port = simulator
    with start_bridge(
        client, tmp_path, "r6_bridge.node", "r6_bridge", R6State, node_params(port)
    ) as (
        b,
        _proc,
    ):
        client.wait_message(b.state, lambda s: s.global_speed_percent == 100.0)
        sim.ignore({"single_cycle"})
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=True)
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.outcome.code == MotionOutcome.STOPPED, result.outcome.message
        assert "wrote 20002 = 1 (single_cycle)" in result.outcome.message
        assert "read moving (2470) 0" in result.outcome.message
        assert commands(device) == [("single_cycle", True)]

        sim.ignore({"pause"})
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=False)
        goal.wait_feedback(lambda f: f.moving)
        mark = len(device.write_log)
        goal.cancel()
        status, result = goal.result()
        assert status == GoalStatus.STATUS_CANCELED
        assert result.outcome.code == MotionOutcome.CANCELLED
        said_what_it_wrote_and_read(result.outcome.message, "pause")
        assert commands(device, mark) == [("pause", True)] and device.running
        sim.ignore(())
        assert b.call(Trigger, "stop").success


def set_read_only(client: Client, b: Bridge, value: bool) -> None:
    request = SetParameters.Request()
    request.parameters = [Parameter("read_only", value=value).to_parameter_msg()]
    reply = client.call(SetParameters, b.service("set_parameters"), request)
    assert reply.results[0].successful, reply.results[0].reason


@pytest.mark.parametrize("end", ["deactivate", "read_only", "exit"])
def test_a_halt_still_tries_its_pause_and_logs_not_confirmed(
    simulator: tuple[Simulator, R6SimDevice, int], client: Client, tmp_path: Path, end: str
) -> None:
    """A program set running by ~/start and a run_cycle goal: each halt writes pause
    (20001) for both (the write log: ``ignored``), and the node logs "not confirmed"."""
    sim, device, port = simulator
    b = Bridge(client, unique_namespace(f"r6_deaf_{end}"), "r6_bridge", R6State)
    log = tmp_path / "r6_bridge_node.log"
    with node_process(
        "r6_bridge.node", node_params(port), tmp_path, ["-r", f"__ns:={b.ns}"]
    ) as proc:
        client.wait_message(b.state, lambda s: s.global_speed_percent == 100.0)
        assert b.call(Trigger, "start").success
        goal = b.send_goal(RunCycle, "run_cycle", single_cycle=False)
        goal.wait_feedback(lambda f: f.moving)
        sim.ignore({"pause"})
        mark = len(device.write_log)
        since = time.monotonic()
        if end == "deactivate":
            request = ChangeState.Request()
            request.transition.id = Transition.TRANSITION_DEACTIVATE
            assert client.call(ChangeState, b.service("change_state"), request).success
        elif end == "read_only":
            set_read_only(client, b, True)
        else:
            proc.send_signal(signal.SIGINT)
            assert proc.wait(EXIT_TIMEOUT_S) == 0
        if end != "exit":
            _status, result = goal.result()
            assert result.outcome.code == MotionOutcome.HALTED, result.outcome.message
            said_what_it_wrote_and_read(result.outcome.message, "pause")
            client.wait_log("r6_bridge", "its stop went out, not confirmed", since)
        text = log.read_text()
        assert text.count("not confirmed") >= 2, text[-3000:]
        assert "its stop went out, not confirmed" in text, text[-3000:]
        assert commands(device, mark) == [("pause", True), ("pause", True)]
        assert device.running
        goal.close()
        sim.ignore(())


# ---------------------------------------------------------------- round trips up to 50 ms
def test_round_trips_up_to_50_ms(client: Client, tmp_path: Path) -> None:
    """``--reply-delay-ms 0:50``: the node connects at start, polls, reconnects after the
    simulator is killed and restarted on the same port, and a stop is the first write
    to reach the device after the call, with at most the reads already in flight
    before it."""
    sim = SimProcess(R6_INFO, tmp_path / "sim")
    sim.extra_args = ("--reply-delay-ms", "0:50")
    sim.start()
    try:
        params = node_params(sim.port, max_in_flight=2)
        with start_bridge(client, tmp_path, "r6_bridge.node", "r6_bridge", R6State, params) as (
            b,
            proc,
        ):
            b.wait_connected(True, timeout=WAIT_S)
            started = time.monotonic()
            wait_for(lambda: len(client.received(b.joint_states, started)) >= 5, WAIT_S, "polls")

            killed = time.monotonic()
            sim.kill()
            b.wait_connected(False, since=killed, timeout=WAIT_S)
            restarted = time.monotonic()
            sim.start()
            b.wait_connected(True, since=restarted, timeout=WAIT_S)
            wait_for(
                lambda: len(client.received(b.joint_states, restarted)) >= 5, WAIT_S, "polls again"
            )

            with client.service_client(Trigger, b.service("stop"), WAIT_S) as stop_client:
                before = len(sim.reads())
                wait_for(lambda: len(sim.reads()) > before + 2, WAIT_S, "a poll under way")
                called = time.time()
                reply = stop_client.call_async(Trigger.Request())
                wait_for(reply.done, WAIT_S, "the stop's reply")
            assert reply.result().success, reply.result().message
            stops = [w for w in sim.writes() if w.time >= called]
            assert stops and stops[0].address == COMMANDS["stop"], stops
            ahead = [x for x in sim.reads() if called <= x.time <= stops[0].time]
            assert len(ahead) <= 2 * 2, [(x.address, x.count) for x in ahead]
            assert proc.poll() is None
    finally:
        sim.stop()


def test_a_pending_halt_stop_not_confirmed_on_reconnect_is_said_and_polls_go_on(
    client: Client, tmp_path: Path
) -> None:
    """read_only while the controller is gone: the pause fails and waits; the controller
    back, deaf to pause: the pause goes out, "not confirmed" is logged, and the node
    polls on (the pending stop's NotConfirmed does not fail the link-up)."""
    first = make_simulator(axis_count=6)
    port = first.start_tcp()
    b = Bridge(client, unique_namespace("r6_deaf_pending"), "r6_bridge", R6State)
    with node_process("r6_bridge.node", node_params(port), tmp_path, ["-r", f"__ns:={b.ns}"]):
        b.wait_connected(True, timeout=WAIT_S)
        assert b.call(Trigger, "start").success
        gone = time.monotonic()
        first.stop()
        b.wait_connected(False, since=gone, timeout=WAIT_S)
        set_read_only(client, b, True)
        client.wait_log("r6_bridge", "its stop failed", gone)
        second = make_simulator(axis_count=6)
        device = second.device
        assert isinstance(device, R6SimDevice)
        device.running = True
        second.ignore({"pause"})
        back = time.monotonic()
        second.start_tcp(port=port)
        try:
            client.wait_log("r6_bridge", "its pending stop went out, not confirmed", back)
            b.wait_connected(True, since=back, timeout=WAIT_S)
            wait_for(lambda: len(client.received(b.state, back)) >= 5, WAIT_S, "polls")
            assert ("pause", True) in commands(device)
        finally:
            second.stop()
