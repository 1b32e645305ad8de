"""The stepper bridge node in its own process, against the simulator over a real socat pty
pair, driven by an rclpy client in this process."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from bridge_core.wire.registers import Table
from msg_defs.action import LineMotion
from msg_defs.msg import StepperState
from msg_defs.srv import (
    ArcMove,
    ConfigureMotor,
    ConfirmedCommand,
    LineMove,
    MoveBy,
    SetHomingOrder,
    SetInteger,
    SetLimitInputs,
    SetOutput,
    SetValue,
)
from stepper_bridge.sim import START_POSITION, StepperSimDevice, make_simulator

from ..support.fixtures import client_fixture
from ..support.ros import (
    WAIT_S,
    Bridge,
    Client,
    refused_at_start,
    start_bridge,
    unique_namespace,
    values_of,
    wait_for,
    wait_stream_refusals,
    wait_subscribed,
)
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty
from ..support.sims import stepper_on_pty

pytestmark = pytest.mark.ros

BAUD = 115200
# A pty can hold every byte ~2 s beside CPU burners (tests/support/serial_pair.py), so a
# test whose subject is not a silent line takes PTY_REPLY_TIMEOUT_S: a live device never
# looks dead, a write never fails for a stall. The tests that silence the line themselves
# take OUTAGE_TIMEOUT_S, so the outage is seen in a second. The jog deadman is far above
# what a loaded machine delays a jog message by.
OUTAGE_TIMEOUT_S = 1.0
COMMAND_TIMEOUT_S = 1.5


# One per test, as the MOTEC tests: beside two CPU burners a long-lived client once
# heard nothing from the third bridge of this module on (cause not found; a fresh
# client carries no other test's subscriptions, discovery or /rosout history).
client = client_fixture("stepper_client", diagnostics=True, log=True)
# Statuses every 0.25 s: the tests wait for a level or a count in them one after another.
DIAGNOSTIC_PERIOD_S = 0.25


@pytest.fixture
def sim() -> Iterator[tuple[StepperSimDevice, str]]:
    """The simulator on one end of a socat pty pair; yields it and the bridge's end."""
    with stepper_on_pty(BAUD) as served:
        yield served


def bridge(
    client: Client, tmp_path: Path, port: str, **params: Any
) -> AbstractContextManager[tuple[Bridge, Any]]:
    defaults: dict[str, Any] = {
        "serial_port": port,
        "baudrate": BAUD,
        "poll_rate_hz": 20.0,
        "timeout_s": PTY_REPLY_TIMEOUT_S,
        "reconnect_max_s": 1.0,
        "command_timeout_s": COMMAND_TIMEOUT_S,
        "diagnostic_period_s": DIAGNOSTIC_PERIOD_S,
    }
    defaults.update(params)
    return start_bridge(
        client, tmp_path, "stepper_bridge.node", "stepper_bridge", StepperState, defaults
    )


def diagnostic(b: Bridge, predicate: Callable[[Any], bool], since: float) -> Any:
    def find() -> Any:
        for status in reversed(b.diagnostics(since)):
            if predicate(status):
                return status
        return None

    return wait_for(find, WAIT_S, "a matching diagnostic status")


def stamp_s(msg: Any) -> float:
    """A message's header stamp (the poll's wall-clock read time) in seconds."""
    return float(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)


def writes(device: StepperSimDevice) -> list[tuple[int, Table, int, tuple[int, ...]]]:
    return [(r.function_code, r.table, r.address, r.values) for r in device.write_log]


def test_topics_jog_and_deadman(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    device.position[2] = START_POSITION + 2.5  # coordinate 2.50 = half a turn at lead 5.00
    device.position[5] = START_POSITION - 12.5
    device.set_input(9, True)
    device.set("output_4", 1)
    started = time.monotonic()
    with bridge(
        client,
        tmp_path,
        port,
        joint_types=["prismatic", "revolute", "prismatic", "prismatic", "prismatic"],
        units_per_meter=[1000.0, 1.0, 1.0, 1000.0, 1000.0],
        joint_prefix="x_",
    ) as (b, _):
        js = client.wait_message(b.joint_states)
        assert js.name == [f"x_motor_{m}" for m in range(1, 6)]
        assert list(js.position) == pytest.approx([0.0, math.pi, 0.0, 0.0, -0.0125])
        st = client.wait_message(b.state)
        assert st.inputs[8] and sum(st.inputs) == 1 and st.outputs[3]
        assert list(st.coordinates) == pytest.approx([0.0, 2.5, 0.0, 0.0, -12.5])
        assert st.lead[1] == pytest.approx(5.0) and st.microstep[0] == 8
        assert list(st.home_input) == [2, 4, 6, 8, 10] and st.system_mode == 0
        # The device's own keys come with the first snapshot.
        status = diagnostic(
            b, lambda s: s.level == b"\x00" and "system mode" in values_of(s), started
        )
        assert values_of(status)["system mode"] == "0"

        # Jog motor 1 at 600 rpm (50 mm/s) for a while: the position moves.
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_1/jog", 10)
        wait_subscribed(jog)
        jogging = time.monotonic()
        first = client.wait_message(b.joint_states, since=jogging).position[0]
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            last_sent = time.time()  # before: the bridge may have it before this thread runs
            jog.publish(Float64(data=600.0))
            time.sleep(0.05)
        # > 20 mm at 50 mm/s
        client.wait_message(b.joint_states, lambda m: m.position[0] > first + 0.02, since=jogging)
        # Silence: the deadman stops the motor after command_timeout_s, then writes the
        # configured speed (60 rpm, the simulator's) back.
        wait_for(lambda: len(device.write_log) >= 4, WAIT_S, "the deadman's stop and restore")
        stop = device.write_log[2]
        assert (stop.table, stop.address) == (Table.COIL, 4)
        assert stop.time - last_sent >= COMMAND_TIMEOUT_S * 0.9
        # Speed once, forward once (20 identical messages), the deadman's stop coil, the
        # configured speed back.
        assert writes(device) == [
            (6, Table.HOLDING, 5, (600,)),
            (5, Table.COIL, 1, (1,)),
            (5, Table.COIL, 4, (1,)),
            (6, Table.HOLDING, 5, (60,)),
        ]

        # The motor rests: five polls that began after the stop (by their stamps; states
        # polled before it may still be on their way) show it still, at one coordinate.
        def rest() -> list[Any]:
            return [m for m in client.received(b.state) if stamp_s(m) > stop.time]

        wait_for(lambda: len(rest()) >= 5, WAIT_S, "five polls after the stop")
        assert {m.coordinates[0] for m in rest()} == {rest()[0].coordinates[0]}
        assert not any(m.running[0] for m in rest())
        # Jog 0 after the stop writes nothing (already stopped; it may also be coalesced
        # with the 600 right after it): the next jog writes its speed and forward coil,
        # and a 0 then stops it and writes the configured speed back.
        for rpm in (0.0, 600.0):
            jog.publish(Float64(data=rpm))
        wait_for(lambda: len(device.write_log) >= 6, WAIT_S, "the jog after the 0")
        jog.publish(Float64(data=0.0))
        wait_for(lambda: len(device.write_log) >= 8, WAIT_S, "the stop by the 0 and restore")
        assert writes(device)[4:] == [
            (6, Table.HOLDING, 5, (600,)),
            (5, Table.COIL, 1, (1,)),
            (5, Table.COIL, 4, (1,)),
            (6, Table.HOLDING, 5, (60,)),
        ]
        assert device.get("motor1_speed") == 60
        client.node.destroy_publisher(jog)


def test_a_jog_gives_the_configured_speed_back(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The jog's speed is not left in the speed register. After the stop
    service the configured speed is written back, a move_by then runs at it; a refused
    restore is logged and in diagnostics, never fails the stop, and is retried before the
    next move_by's single run."""
    device, port = sim
    H, C = Table.HOLDING, Table.COIL  # noqa: N806
    device.set("motor1_speed", 1200)  # configured: 100 mm/s
    single_run_speeds: list[int] = []  # motor's speed register when its single run starts

    def at_single_run(record: Any) -> None:
        if (record.table, record.address) in ((C, 0), (C, 5)):
            motor = 1 + record.address // 5
            single_run_speeds.append(int(device.get(f"motor{motor}_speed")))

    device.write_hooks.append(at_single_run)
    with bridge(client, tmp_path, port) as (b, _):
        b.wait_connected(True)
        client.wait_message(b.state)
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_1/jog", 10)
        wait_subscribed(jog)
        jog.publish(Float64(data=300.0))
        wait_for(lambda: len(device.write_log) >= 2, WAIT_S, "the jog's speed and coil")
        assert b.call(Trigger, "motor_1/stop").success
        assert writes(device) == [
            (6, H, 5, (300,)),
            (5, C, 1, (1,)),
            (5, C, 4, (1,)),  # the stop first
            (6, H, 5, (1200,)),  # then the configured speed, a plain FC 06
        ]
        reply = b.call(MoveBy, "motor_1/move_by", distance=0.001)
        assert reply.success, reply.message
        assert single_run_speeds == [1200]
        client.node.destroy_publisher(jog)

        # Motor 2 (configured 60 rpm): the restore is refused by the device.
        refused = (6, H, 15, (60,))
        device.write_guards.append(
            lambda r: 0x04 if (r.function_code, r.table, r.address, r.values) == refused else None
        )
        jog2 = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_2/jog", 10)
        wait_subscribed(jog2)
        before = len(device.write_log)
        jog2.publish(Float64(data=240.0))
        wait_for(lambda: len(device.write_log) >= before + 2, WAIT_S, "motor 2 jogging")
        failed = time.monotonic()
        jog2.publish(Float64(data=0.0))
        client.wait_log("stepper_bridge", "motor 2: writing back its configured speed 60 rpm")
        assert writes(device)[before:] == [(6, H, 15, (240,)), (5, C, 6, (1,)), (5, C, 9, (1,))]
        assert device.motion[2] is None  # stopped all the same
        status = diagnostic(b, lambda s: "written back" in s.message, failed)
        assert status.level == b"\x01"
        assert "60 rpm not restored" in values_of(status)["jog speed restore failed"]
        # The device takes it again: the next move_by writes it before its single run.
        device.write_guards.clear()
        before = len(device.write_log)
        reply = b.call(MoveBy, "motor_2/move_by", distance=0.001)
        assert reply.success, reply.message
        assert writes(device)[before:] == [
            (6, H, 14, (0,)),
            (16, H, 18, (100, 0)),
            (6, H, 15, (60,)),
            (5, C, 5, (1,)),
        ]
        assert single_run_speeds == [1200, 60]
        healed = time.monotonic()
        diagnostic(b, lambda s: values_of(s).get("jog speed restore failed") == "none", healed)
        client.node.destroy_publisher(jog2)


def jog_motor_1(client: Client, b: Bridge, device: StepperSimDevice) -> Any:
    """Connected, motor 1 jogging at 100 rpm; the jog publisher."""
    b.wait_connected(True)
    jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_1/jog", 10)
    wait_subscribed(jog)
    jog.publish(Float64(data=100.0))
    wait_for(lambda: device.motion[1] is not None, WAIT_S, "motor 1 jogging")
    return jog


def test_a_deadman_stop_lost_in_an_outage_is_the_first_request_when_the_line_is_back(
    client: Client, tmp_path: Path
) -> None:
    """The deadman's stop, lost while the line is silent, stays pending and is the
    first request the controller handles when the line comes back (before any poll)."""
    simulator = make_simulator(reply_delay_s=0.0)
    device = simulator.device
    assert isinstance(device, StepperSimDevice)
    device.log_reads = True
    stop_coil = (Table.COIL, 4)  # motor 1 stop: coil 00005
    with (
        served_on_pty(simulator, BAUD) as port,
        bridge(client, tmp_path, port, timeout_s=OUTAGE_TIMEOUT_S) as (b, proc),
    ):
        jog = jog_motor_1(client, b, device)
        # The line goes silent (the controller hears nothing); the jog falls silent too.
        simulator.withhold_replies = True
        cut = time.monotonic()
        client.wait_log("stepper_bridge", "(deadman) failed", since=cut)
        assert device.motion[1] is not None  # the stop did not get through: still running
        writes_before, reads_before = len(device.write_log), len(device.read_log)
        simulator.withhold_replies = False
        wait_for(
            lambda: stop_coil in [(r.table, r.address) for r in device.write_log[writes_before:]],
            WAIT_S,
            "the pending stop after the line came back",
        )
        stop = next(
            r for r in device.write_log[writes_before:] if (r.table, r.address) == stop_coil
        )
        assert device.write_log[writes_before] is stop  # no other write before it
        assert all(r.time >= stop.time for r in device.read_log[reads_before:])  # nor a poll
        assert device.motion[1] is None
        b.wait_connected(True, since=cut)
        assert proc.poll() is None
        client.node.destroy_publisher(jog)


def test_a_halts_stop_lost_in_an_outage_is_retried_while_the_node_is_inactive(
    client: Client, tmp_path: Path
) -> None:
    """A motor a service set running, a deactivate while the line is silent: its stop
    fails and stays pending. The inactive node polls nothing, so no reconnect sends it:
    its retry timer does, once the line is back ("the pending stop got through")."""
    simulator = make_simulator(reply_delay_s=0.0)
    device = simulator.device
    assert isinstance(device, StepperSimDevice)
    stop_coil = (Table.COIL, 4)  # motor 1 stop: coil 00005
    with (
        served_on_pty(simulator, BAUD) as port,
        bridge(client, tmp_path, port, timeout_s=OUTAGE_TIMEOUT_S) as (b, _proc),
    ):
        b.wait_connected(True)
        reply = b.call(Trigger, "motor_1/forward")
        assert reply.success, reply.message
        wait_for(lambda: device.motion[1] is not None, WAIT_S, "motor 1 running")
        simulator.withhold_replies = True
        since = time.monotonic()
        deactivate = Transition(id=Transition.TRANSITION_DEACTIVATE)
        assert b.call(ChangeState, "change_state", transition=deactivate).success
        client.wait_log("stepper_bridge", "tried again until it gets through", since)
        assert device.motion[1] is not None  # the stop did not get through: still running
        writes_before = len(device.write_log)
        simulator.withhold_replies = False
        wait_for(
            lambda: stop_coil in [(r.table, r.address) for r in device.write_log[writes_before:]],
            WAIT_S,
            "the pending stop, retried while inactive",
        )
        client.wait_log("stepper_bridge", "the pending stop got through", since)
        assert device.motion[1] is None


def test_a_stop_service_that_fails_in_an_outage_leaves_the_jogs_stop_pending(
    client: Client, tmp_path: Path
) -> None:
    """~/motor_1/stop while the line is silent is tried at once and fails; the jog
    it meant to end keeps its stop pending (the first request when the line is back) and
    stays locked (a jog command is refused until a 0)."""
    simulator = make_simulator(reply_delay_s=0.0)
    device = simulator.device
    assert isinstance(device, StepperSimDevice)
    device.log_reads = True
    stop_coil = (Table.COIL, 4)  # motor 1 stop: coil 00005
    with (
        served_on_pty(simulator, BAUD) as port,
        bridge(client, tmp_path, port, timeout_s=OUTAGE_TIMEOUT_S, command_timeout_s=60.0) as (
            b,
            proc,
        ),
    ):
        jog = jog_motor_1(client, b, device)
        simulator.withhold_replies = True
        reply = b.call(Trigger, "motor_1/stop")
        assert not reply.success and "no reply" in reply.message, reply.message
        assert device.motion[1] is not None  # it did not get through
        writes_before, reads_before = len(device.write_log), len(device.read_log)
        since = time.monotonic()
        simulator.withhold_replies = False
        wait_for(
            lambda: stop_coil in [(r.table, r.address) for r in device.write_log[writes_before:]],
            WAIT_S,
            "the pending stop after the line came back",
        )
        stop = device.write_log[writes_before]
        assert (stop.table, stop.address) == stop_coil  # no other write before it
        assert all(r.time >= stop.time for r in device.read_log[reads_before:])  # nor a poll
        assert device.motion[1] is None
        # Locked: a jog command is refused (counted by the node), nothing written.
        b.wait_connected(True, since=since)
        after_stop = len(device.write_log)
        jog.publish(Float64(data=100.0))
        wait_stream_refusals(client, "stepper_bridge", 1, since)
        assert all(r.table != Table.COIL for r in device.write_log[after_stop:])
        assert device.motion[1] is None and proc.poll() is None
        client.node.destroy_publisher(jog)


def test_services_write_what_they_should(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    device.set("motor1_speed", 1200)  # 100 mm/s: move_by finishes quickly
    with bridge(client, tmp_path, port, joint_types=["prismatic", "revolute"]) as (b, _):
        b.wait_connected(True)
        client.wait_message(b.state)

        def ok(srv: Any, name: str, **fields: Any) -> None:
            reply = b.call(srv, name, **fields)
            assert reply.success, f"{name}: {reply.message}"

        ok(MoveBy, "motor_1/move_by", distance=0.005)  # 5 mm -> 5.00 -> 500
        client.wait_message(
            b.state, lambda m: m.coordinates[0] == pytest.approx(5.0) and not m.running[0]
        )
        js = client.wait_message(b.joint_states, lambda m: m.position[0] > 0.004)
        assert js.position[0] == pytest.approx(0.005)
        ok(MoveBy, "motor_2/move_by", distance=-math.pi / 2)  # quarter turn at lead 5 -> 1.25
        ok(
            SetLimitInputs,
            "motor_3/set_limit_inputs",
            positive_limit=11,
            negative_limit=12,
            home=12,
        )
        ok(
            ConfigureMotor,
            "motor_3/configure",
            step_angle_deg=0.9,
            microstep=16,
            start_frequency_hz=500,
            accel_frequency_hz=4000,
            speed_rpm=300,
            lead=12.0,
        )
        for action in ("run_once", "forward", "reverse", "home", "stop"):
            ok(Trigger, f"motor_4/{action}")
        for name in ("zero_coordinates", "return_to_zero"):
            ok(Trigger, name)
        # No homing order yet (40177-40181 all 0): the coil goes out and homes nothing.
        # The reply says what was written and read: "not confirmed" when every
        # running flag reads 0, "done" when one still reads 1 from a motion above.
        reply = b.call(Trigger, "home_all")
        assert "wrote home all (coil 00046 = ON); read motor " in reply.message, reply.message
        ok(Trigger, "save_parameters")
        ok(Trigger, "emergency_stop")
        ok(SetOutput, "set_output", board=0, index=4, state=True)
        ok(SetOutput, "set_output", board=0, index=4, state=False)
        ok(SetBool, "set_all_outputs", data=True)
        ok(SetHomingOrder, "set_homing_order", motors=[2, 1])
        ok(SetInteger, "set_system_mode", value=0)
        ok(
            LineMove,
            "line_move",
            pair=LineMove.Request.PAIR_MOTORS_1_2,
            start=[0.001, math.pi / 2],
            end=[0.003, -math.pi],
            speed_rpm=100,
        )
        ok(Trigger, "stop_interpolation")  # a second move while one runs is refused
        ok(
            ArcMove,
            "arc_move",
            pair=ArcMove.Request.PAIR_MOTORS_1_2,
            mode=ArcMove.Request.MODE_CENTER,
            start=[0.01, 0.0],
            end=[0.0, math.pi],
            center=[0.0, 0.0],
            via=[0.0, 0.0],
            counterclockwise=True,
            speed_rpm=60,
        )
        ok(Trigger, "stop_interpolation")
        ok(ConfirmedCommand, "factory_reset", confirm="factory_reset")
        ok(ConfirmedCommand, "clear_all_parameters", confirm="clear_all_parameters")
        assert device.saves == 1
        H, C = Table.HOLDING, Table.COIL  # noqa: N806
        assert writes(device) == [
            (6, H, 4, (0,)),  # motor 1 direction +
            (16, H, 8, (500, 0)),  # run distance 5.00
            (5, C, 0, (1,)),  # single run
            (6, H, 14, (1,)),  # motor 2 direction -
            (16, H, 18, (125, 0)),  # 1.25 = a quarter of lead 5.00
            (5, C, 5, (1,)),
            (16, H, 86, (11, 12, 12)),  # 40087-40089
            (16, H, 20, (90, 16, 500, 4000)),
            (16, H, 25, (300, 1200, 0)),
            (5, C, 15, (1,)),
            (5, C, 16, (1,)),
            (5, C, 17, (1,)),
            (5, C, 18, (1,)),
            (5, C, 19, (1,)),
            (5, C, 43, (1,)),
            (5, C, 44, (1,)),
            (5, C, 45, (1,)),
            (5, C, 95, (1,)),
            (5, C, 41, (1,)),
            (5, C, 54, (1,)),  # output 4 on: coil 00055
            (5, C, 55, (1,)),  # output 4 off: coil 00056
            (5, C, 97, (1,)),
            (16, H, 176, (2, 1, 0, 0, 0)),
            (6, H, 299, (0,)),
            # 40202-40211: motor 1 in mm x100, motor 2 revolute at lead 5 (-2.50: 0xFF06)
            (16, H, 201, (1, 100, 0, 125, 0, 300, 0, 0xFF06, 0xFFFF, 100)),
            (5, C, 101, (1,)),
            (5, C, 100, (1,)),
            (5, C, 102, (1,)),
            (5, C, 4, (1,)),  # the pair's own stops
            (5, C, 9, (1,)),
            (
                16,
                H,
                181,
                (1, 0, 1000, 0, 0, 0, 0, 0, 250, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 60),
            ),  # 40182-40201: motor 1 in mm x100, motor 2 revolute: pi rad = 2.50 at lead 5
            (5, C, 99, (1,)),
            (5, C, 100, (1,)),
            (5, C, 102, (1,)),
            (5, C, 4, (1,)),
            (5, C, 9, (1,)),
            (5, C, 72, (1,)),
            (5, C, 96, (1,)),
        ]


def test_setters_read_back_and_interpolation(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Device id and baud rate in diagnostics; round trips and the interpolation
    set-up in the state; speed / direction / run distance (SI) / round trips setters;
    a second line / arc while one runs refused, nothing written; clear-all warns."""
    device, port = sim
    H = Table.HOLDING  # noqa: N806
    device.set("baud_rate", 19200)
    device.set("motor2_reciprocations", 4)
    started = time.monotonic()
    with bridge(client, tmp_path, port, joint_types=["prismatic", "revolute"]) as (b, _):
        b.wait_connected(True)
        status = diagnostic(b, lambda s: "device id" in values_of(s), started)
        assert (values_of(status)["device id"], values_of(status)["baud rate"]) == ("1", "19200")
        st = client.wait_message(b.state)
        assert list(st.round_trips) == [0, 4, 0, 0, 0] and st.line_pair == 0

        def ok(srv: Any, name: str, **fields: Any) -> Any:
            reply = b.call(srv, name, **fields)
            assert reply.success, f"{name}: {reply.message}"
            return reply

        refusals: list[tuple[Any, str, dict[str, Any], str]] = [
            (SetInteger, "motor_3/set_speed", {"value": 70000}, "speed"),
            (SetInteger, "motor_3/set_direction", {"value": 2}, "direction"),
            (SetValue, "motor_3/set_run_distance", {"value": -0.01}, "negative"),
            (SetValue, "motor_3/set_run_distance", {"value": math.inf}, "finite"),
            (SetInteger, "motor_5/set_round_trips", {"value": -1}, "round trips"),
        ]
        for srv, name, fields, reason in refusals:
            reply = b.call(srv, name, **fields)
            assert not reply.success, name
            assert "refused" in reply.message and reason in reply.message, reply.message
        assert device.write_log == []
        ok(SetInteger, "motor_3/set_speed", value=300)
        ok(SetInteger, "motor_3/set_direction", value=1)
        ok(SetValue, "motor_3/set_run_distance", value=0.0125)  # m -> 12.50 mm
        ok(SetValue, "motor_2/set_run_distance", value=math.pi)  # half a turn at lead 5
        ok(SetInteger, "motor_5/set_round_trips", value=2)
        assert writes(device) == [
            (6, H, 25, (300,)),
            (6, H, 24, (1,)),
            (16, H, 28, (1250, 0)),
            (16, H, 18, (250, 0)),
            (6, H, 304, (2,)),
        ]
        st = client.wait_message(b.state, lambda m: m.round_trips[4] == 2)
        assert st.speed_rpm[2] == 300 and st.direction[2] == 1 and st.run_distance[1] == 2.5

        # A slow line (1 rpm): the state shows it; a second line or an arc is refused.
        ok(LineMove, "line_move", pair=1, start=[0.0, 0.0], end=[0.04, math.pi], speed_rpm=1)
        st = client.wait_message(b.state, lambda m: m.line_pair == 1 and m.running[0])
        assert st.interpolation_running and st.line_speed_rpm == 1
        assert list(st.line_end) == pytest.approx([40.0, 2.5])
        before = len(device.write_log)
        for srv, name, fields in (
            (LineMove, "line_move", {"pair": 1, "end": [0.01, 0.0], "speed_rpm": 10}),
            (
                ArcMove,
                "arc_move",
                {"pair": 1, "end": [0.01, 0.0], "center": [0.005, 0.0], "speed_rpm": 10},
            ),
        ):
            reply = b.call(srv, name, **fields)
            assert not reply.success and "插补过程运行中不可调节" in reply.message, reply.message
        assert len(device.write_log) == before and device.interpolation is not None
        ok(Trigger, "stop_interpolation")
        st = client.wait_message(b.state, lambda m: not m.interpolation_running)
        ok(
            ArcMove,
            "arc_move",
            pair=1,
            mode=ArcMove.Request.MODE_THREE_POINTS,
            end=[0.02, 0.0],
            via=[0.01, 1.0],
            counterclockwise=True,
            speed_rpm=7,
        )
        st = client.wait_message(b.state, lambda m: m.arc_pair == 1 and m.arc_speed_rpm == 7)
        assert st.arc_mode == 1 and st.arc_counterclockwise
        assert list(st.arc_via) == pytest.approx([10.0, 0.8])  # 1 rad at lead 5: 0.7958 -> 0.80

        since = time.monotonic()
        reply = ok(ConfirmedCommand, "clear_all_parameters", confirm="clear_all_parameters")
        assert "the link may be lost" in reply.message, reply.message
        log = client.wait_log("stepper_bridge", "the link may be lost", since)
        assert log.level == 30  # WARN


def test_refusals_write_nothing(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    device.set("motor5_lead", 0.0)  # a revolute motor without a lead: no angle
    started = time.monotonic()
    with bridge(client, tmp_path, port, joint_types=["prismatic"] * 4 + ["revolute"]) as (b, _):
        b.wait_connected(True)
        js = client.wait_message(b.joint_states)
        assert math.isnan(js.position[4])
        status = diagnostic(b, lambda s: s.level == b"\x01", started)
        assert "lead 0 on revolute motor(s) 5" in status.message
        refusals: list[tuple[Any, str, dict[str, Any], str]] = [
            (MoveBy, "motor_1/move_by", {"distance": math.nan}, "not a finite"),
            (MoveBy, "motor_1/move_by", {"distance": 1e6}, "outside"),
            (MoveBy, "motor_1/move_by", {"distance": 0.0}, "below"),
            (MoveBy, "motor_5/move_by", {"distance": 1.0}, "lead is 0"),
            (
                ConfigureMotor,
                "motor_2/configure",
                {"step_angle_deg": 0.0, "microstep": 8, "speed_rpm": 10, "lead": 1.0},
                "step_angle",
            ),
            (
                ConfigureMotor,
                "motor_2/configure",
                {"step_angle_deg": 1.8, "microstep": 8, "speed_rpm": 10, "lead": math.inf},
                "lead",
            ),
            (SetLimitInputs, "motor_1/set_limit_inputs", {"home": 14}, "home_input"),
            (SetOutput, "set_output", {"board": 0, "index": 13, "state": True}, "output 13"),
            (SetOutput, "set_output", {"board": 0, "index": 0, "state": True}, "output 0"),
            (SetOutput, "set_output", {"board": 1, "index": 1, "state": True}, "board 1"),
            (SetHomingOrder, "set_homing_order", {"motors": [1, 2, 3, 4, 5, 1]}, "at most"),
            (SetHomingOrder, "set_homing_order", {"motors": [3, 3]}, "twice"),
            (SetInteger, "set_system_mode", {"value": 9}, "system mode 9"),
            (LineMove, "line_move", {"pair": 4, "speed_rpm": 10}, "pair 4"),
            (LineMove, "line_move", {"pair": 1, "end": [0.01, 0.0], "speed_rpm": 0}, "speed"),
            (ArcMove, "arc_move", {"pair": 1, "end": [0.01, 0.0], "speed_rpm": 10}, "three"),
            (ConfirmedCommand, "factory_reset", {"confirm": ""}, "confirm"),
            (ConfirmedCommand, "factory_reset", {"confirm": "yes"}, "confirm"),
            (ConfirmedCommand, "clear_all_parameters", {"confirm": "factory_reset"}, "confirm"),
        ]
        for srv, name, fields, reason in refusals:
            reply = b.call(srv, name, **fields)
            assert not reply.success, name
            assert "refused" in reply.message and reason in reply.message, reply.message
        assert device.write_log == []
        # Refused jogs write nothing (each one waited for by the node's refusal count): the
        # first write is that of the valid jog after them.
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_1/jog", 10)
        wait_subscribed(jog)
        for refused, value in enumerate((math.nan, math.inf, 1e6), start=1):
            jog.publish(Float64(data=value))
            wait_stream_refusals(client, "stepper_bridge", refused, time.monotonic())
        assert device.write_log == []
        jog.publish(Float64(data=100.0))
        wait_for(lambda: len(device.write_log) >= 2, WAIT_S, "the valid jog")
        jog.publish(Float64(data=0.0))
        wait_for(lambda: len(device.write_log) >= 4, WAIT_S, "its stop and speed restore")
        client.node.destroy_publisher(jog)
        assert writes(device) == [
            (6, Table.HOLDING, 5, (100,)),
            (5, Table.COIL, 1, (1,)),
            (5, Table.COIL, 4, (1,)),
            (6, Table.HOLDING, 5, (60,)),
        ]


def test_revolute_joints_with_a_reduction(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """units_per_revolution: lead 5 per motor turn, 50 per joint turn (1:10). A coordinate
    of 25 is pi rad; move_by and interpolation points convert the same way (pairs 2 and 3
    by the type rows, as configured)."""
    device, port = sim
    H = Table.HOLDING  # noqa: N806
    device.position[1] = START_POSITION + 25.0
    device.position[2] = START_POSITION + 50.0
    with bridge(
        client,
        tmp_path,
        port,
        joint_types=["revolute", "revolute", "prismatic", "prismatic", "revolute"],
        units_per_revolution=[50.0, 50.0, 0.0, 0.0, 0.0],
        interpolation_pair_reading="type_rows",
    ) as (b, _):
        js = client.wait_message(b.joint_states)
        assert list(js.position[:2]) == pytest.approx([math.pi, 2 * math.pi])
        device.position[5] = START_POSITION + 2.5  # motor 5: 0 = the lead, no reduction
        client.wait_message(b.joint_states, lambda m: m.position[4] == pytest.approx(math.pi))
        reply = b.call(MoveBy, "motor_1/move_by", distance=-math.pi / 2)  # 12.50 units
        assert reply.success, reply.message
        for pair in (LineMove.Request.PAIR_MOTORS_1_3, LineMove.Request.PAIR_MOTORS_2_3):
            reply = b.call(
                LineMove, "line_move", pair=pair, start=[math.pi, 0.001], end=[0.0, 0.002]
            )
            assert not reply.success and "speed" in reply.message  # speed 0: pair passed
        reply = b.call(
            LineMove,
            "line_move",
            pair=LineMove.Request.PAIR_MOTORS_1_3,
            start=[math.pi, 0.001],  # 25.00 units; motor 3 in mm: 1.00
            end=[-math.pi / 2, 0.002],  # -12.50: 0xFB1E 0xFFFF
            speed_rpm=30,
        )
        assert reply.success, reply.message
        assert writes(device) == [
            (6, H, 4, (1,)),
            (16, H, 8, (1250, 0)),
            (5, Table.COIL, 0, (1,)),
            (16, H, 201, (2, 2500, 0, 100, 0, 0xFB1E, 0xFFFF, 200, 0, 30)),
            (5, Table.COIL, 101, (1,)),  # coil 00102: line start
        ]


def test_pairs_2_and_3_are_refused_until_the_reading_is_set(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path
) -> None:
    """Pairs 2 and 3 (motors 1+3 / 2+3 or 2+3 / 1+3 by the manual's two
    readings) are refused, services and actions, in one line saying what to do, while
    interpolation_pair_reading is unset (the default); nothing is written, pair 1 goes."""
    device, port = sim
    units_per_meter = [1000.0, 500.0, 1000.0, 1000.0, 1000.0]
    with bridge(client, tmp_path, port, units_per_meter=units_per_meter) as (b, _):
        b.wait_connected(True)
        client.wait_message(b.state)
        arc = {"end": [0.01, 0.0], "center": [0.005, 0.0], "speed_rpm": 10}
        for srv, name, pair, fields in (
            (LineMove, "line_move", LineMove.Request.PAIR_MOTORS_1_3, {"end": [0.01, 0.0]}),
            (LineMove, "line_move", LineMove.Request.PAIR_MOTORS_2_3, {"end": [0.01, 0.0]}),
            (ArcMove, "arc_move", ArcMove.Request.PAIR_MOTORS_1_3, arc),
            (ArcMove, "arc_move", ArcMove.Request.PAIR_MOTORS_2_3, arc),
        ):
            reply = b.call(srv, name, pair=pair, **fields)
            assert not reply.success, name
            message = reply.message
            assert "refused" in message and "interpolation_pair_reading" in message, message
            assert "\n" not in message, message
        for pair in (LineMotion.Goal.PAIR_MOTORS_1_3, LineMotion.Goal.PAIR_MOTORS_2_3):
            goal = b.send_goal(LineMotion, "line_move", pair=pair, end=[0.01, 0.0], speed_rpm=10)
            assert not goal.accepted
            client.wait_log("stepper_bridge", f"interpolation pair {pair} refused")
        assert writes(device) == []
        reply = b.call(
            LineMove,
            "line_move",
            pair=LineMove.Request.PAIR_MOTORS_1_2,
            start=[0.001, 0.001],
            end=[0.002, 0.004],
            speed_rpm=10,
        )
        assert reply.success, reply.message
        # The first write is pair 1's: motor 1 in mm, motor 2 at 500 units per metre.
        assert writes(device) == [
            (16, Table.HOLDING, 201, (1, 100, 0, 50, 0, 200, 0, 200, 0, 10)),
            (5, Table.COIL, 101, (1,)),  # coil 00102: line start
        ]


def test_a_negative_units_per_revolution_is_refused_at_start() -> None:
    line = refused_at_start(
        "stepper_bridge.node", ["--ros-args", "-p", "units_per_revolution:=[0.0, -50.0]"]
    )
    assert "units_per_revolution" in line and "-50.0" in line, line


def test_read_only_refuses_every_write(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge(client, tmp_path, port, read_only=True) as (b, _):
        b.wait_connected(True)
        replies = [b.call(Trigger, name) for name in ("motor_1/forward", "emergency_stop")]
        replies += [
            b.call(MoveBy, "motor_2/move_by", distance=0.01),
            b.call(SetOutput, "set_output", board=0, index=1, state=True),
            b.call(ConfirmedCommand, "factory_reset", confirm="factory_reset"),
            b.call(SetBool, "set_all_outputs", data=False),
            b.call(SetInteger, "motor_1/set_speed", value=10),
            b.call(SetInteger, "motor_1/set_direction", value=1),
            b.call(SetValue, "motor_1/set_run_distance", value=0.01),
            b.call(SetInteger, "motor_1/set_round_trips", value=1),
        ]
        for reply in replies:
            assert not reply.success and "read_only" in reply.message, reply.message
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_1/jog", 10)
        wait_subscribed(jog)
        t = time.monotonic()
        jog.publish(Float64(data=100.0))
        client.wait_log(f"{b.ns[1:]}.{b.node_name}", "motor 1 jog 100.0 rpm refused: read_only", t)
        client.node.destroy_publisher(jog)
        assert device.write_log == []


def test_example_yaml_configures_the_node(sim, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from sensor_msgs.msg import JointState

    from ..support.ros import ROOT, node_process

    device, port = sim
    device.position[5] = START_POSITION + 1.25  # a quarter turn at lead 5.00
    config = (ROOT / "config" / "stepper.yaml").read_text()
    config = config.replace('"/dev/ttyUSB0"', f'"{port}"').replace(
        "baudrate: 9600", "baudrate: 115200"
    )
    params = tmp_path / "stepper.yaml"
    params.write_text(config)
    ns = unique_namespace("yaml_stepper")
    client.subscribe(JointState, f"{ns}/joint_states")
    with node_process(
        "stepper_bridge.node",
        {},
        tmp_path,
        ["--params-file", str(params), "-r", f"__ns:={ns}"],
    ) as proc:
        msg = client.wait_message(f"{ns}/joint_states")
        assert msg.name == [f"motor_{m}" for m in range(1, 6)]
        assert msg.position[4] == pytest.approx(math.pi / 2)  # joint_types: motor 5 revolute
        assert proc.poll() is None
