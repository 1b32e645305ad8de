"""The MOTEC bridge in its own process (one node per drive, one shared bus) against the
simulator's drives on a real socat pty pair, driven by an rclpy client in this process."""

from __future__ import annotations

import itertools
import math
import re
import signal
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool, Trigger

from bench.line_relay import LineRelay
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import SerialSettings
from motec_bridge.lifeguard import lifeguard_min_ms
from motec_bridge.sim import LIFEGUARD_FAULT_CODE, MotecSimDrive, MotecSimulator, make_simulator
from motec_bridge.snapshots import STANDSTILL_SPEED_RPM
from msg_defs.msg import MotecState
from msg_defs.srv import (
    PositionMove,
    ReadParameter,
    SetControlMode,
    SetOutput,
    SetValue,
    WriteParameter,
)

from ..support.fixtures import client_fixture
from ..support.ros import (
    LATCHED,
    ROOT,
    WAIT_S,
    Client,
    node_process,
    refused_at_start,
    ros_args,
    unique_namespace,
    values_of,
    wait_for,
    wait_stream_refusals,
    wait_subscribed,
    wall_minus_monotonic,
)
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty
from ..support.sims import motec_on_pty

pytestmark = pytest.mark.ros

BAUD = 115200
UNITS = [1, 2, 3]
# A pty can hold every byte ~2 s beside CPU burners (tests/support/serial_pair.py), so a
# test whose subject is not a silent line takes PTY_REPLY_TIMEOUT_S: a live drive never
# looks dead, a write never fails for a stall. A test that silences a drive, or arms a
# lifeguard (its floor grows with the timeout), takes SHORT_TIMEOUT_S. The deadman
# silence is far above what a loaded machine delays a message by.
SHORT_TIMEOUT_S = 1.0
COMMAND_TIMEOUT_S = 1.5
SET_UP_TRIES = 3  # Bridge.set_up


def lifeguard_floor_ms(drives: int, timeout_s: float = SHORT_TIMEOUT_S) -> int:
    """The shortest lifeguard time the bridge accepts on the tests' bus (docs/bridges/motec.md)."""
    return lifeguard_min_ms(drives, SerialSettings("", BAUD, timeout_s=timeout_s).longest_hold_s())


# The drive faults after this long without a write: two drives, 1 s timeouts.
LIFEGUARD_MS = lifeguard_floor_ms(2) + 100
H, C = Table.HOLDING, Table.COIL


class MotecBridge:
    """Topic and service names of one running motec_bridge process (all its drives)."""

    def __init__(
        self, client: Client, namespace: str, port: str, units: Sequence[int], prefix: str = ""
    ) -> None:
        self.client, self.ns, self.port, self.prefix = client, namespace, port, prefix
        self.joint_states = f"{namespace}/joint_states"
        client.subscribe(JointState, self.joint_states)
        for unit in units:
            client.subscribe(MotecState, self.state(unit))
            client.subscribe(Bool, self.connected(unit), LATCHED)

    def state(self, unit: int) -> str:
        return f"{self.ns}/motec_{unit}/state"

    def connected(self, unit: int) -> str:
        return f"{self.ns}/motec_{unit}/connected"

    def call(self, unit: int | None, srv: Any, name: str, **fields: Any) -> Any:
        node = "motec_bridge" if unit is None else f"motec_{unit}"
        request = srv.Request()
        for key, value in fields.items():
            setattr(request, key, value)
        return self.client.call(srv, f"{self.ns}/{node}/{name}", request)

    def ok(self, unit: int | None, srv: Any, name: str, **fields: Any) -> Any:
        reply = self.call(unit, srv, name, **fields)
        assert reply.success, f"{name}: {reply.message}"
        return reply

    def set_up(self, unit: int, srv: Any, name: str, **fields: Any) -> Any:
        """``ok`` for a test's set-up, not its subject: an idempotent write tried again
        when the simulator, a thread of this busy test process, answered past the
        bridge's timeout (seen beside two CPU burners with a 0.5 s ``timeout_s``)."""
        for _ in range(SET_UP_TRIES):
            reply = self.call(unit, srv, name, **fields)
            if reply.success or "no reply within" not in reply.message:
                break
        assert reply.success, f"{name}: {reply.message}"
        return reply

    def joints(self, unit: int, since: float = 0.0) -> list[Any]:
        name = [f"{self.prefix}drive_{unit}"]
        return [m for m in self.client.received(self.joint_states, since) if list(m.name) == name]

    def wait_joint(
        self, unit: int, predicate: Callable[[Any], bool] = lambda m: True, since: float = 0.0
    ) -> Any:
        def find() -> Any:
            return next((m for m in reversed(self.joints(unit, since)) if predicate(m)), None)

        return wait_for(find, WAIT_S, f"joint_states of drive {unit}")

    def wait_joints(self, unit: int, count: int, since: float) -> None:
        """``count`` joint_states of drive ``unit`` published since ``since``."""
        wait_for(lambda: len(self.joints(unit, since)) >= count, WAIT_S, f"drive {unit} polls")

    def wait_state(
        self, unit: int, predicate: Callable[[Any], bool] = lambda m: True, since: float = 0.0
    ) -> Any:
        return self.client.wait_message(self.state(unit), predicate, WAIT_S, since)

    def wait_connected(self, unit: int, value: bool, since: float = 0.0) -> None:
        self.client.wait_message(self.connected(unit), lambda m: m.data == value, WAIT_S, since)

    def wait_diagnostic(
        self, unit: int, predicate: Callable[[Any], bool], since: float = 0.0
    ) -> Any:
        """The newest status of drive ``unit`` on this bus (hardware id names the port)."""

        def find() -> Any:
            for array in reversed(self.client.received("/diagnostics", since)):
                for status in array.status:
                    if (
                        status.name.startswith(f"{self.ns}/motec_{unit}: ")
                        and f"{self.port}@" in status.hardware_id
                        and predicate(status)
                    ):
                        return status
            return None

        return wait_for(find, WAIT_S, f"a matching diagnostic status of motec_{unit}")

    def set_param(self, unit: int, name: str, value: Any) -> Any:
        """SetParameters on drive ``unit``'s node: its one result."""
        request = SetParameters.Request()
        request.parameters = [Parameter(name, value=value).to_parameter_msg()]
        reply = self.client.call(SetParameters, f"{self.ns}/motec_{unit}/set_parameters", request)
        (result,) = reply.results
        return result

    def set_bus_param(self, name: str, value: Any) -> Any:
        """SetParameters on the bus node: its one result."""
        request = SetParameters.Request()
        request.parameters = [Parameter(name, value=value).to_parameter_msg()]
        reply = self.client.call(SetParameters, f"{self.ns}/motec_bridge/set_parameters", request)
        (result,) = reply.results
        return result

    def acknowledged(self, unit: int) -> None:
        """A round trip through drive ``unit``'s command callbacks (a refused request that
        writes nothing): its cmd_velocity messages that arrived before have been handled."""
        reply = self.call(unit, SetOutput, "set_output", board=1, index=1, state=True)
        assert not reply.success and "refused" in reply.message, reply.message


# One per test: the last test of the module, under heavy load, twice missed messages
# a long-lived client had subscribed to (cause not found; a fresh one carries none of
# the earlier tests' subscriptions and /rosout history).
client = client_fixture("motec_client", diagnostics=True, log=True)
# Statuses every 0.25 s: the tests wait for a level or a count in them one after another.
DIAGNOSTIC_PERIOD_S = 0.25


@pytest.fixture
def bus() -> Iterator[tuple[MotecSimulator, str]]:
    """Three drives on one simulated bus at the device end of a socat pty pair."""
    with motec_on_pty(UNITS, BAUD) as served:
        yield served


def bridge_params(port: str, **params: Any) -> dict[str, Any]:
    defaults: dict[str, Any] = {
        "serial_port": port,
        "baudrate": BAUD,
        "unit_ids": UNITS,
        "poll_rate_hz": 20.0,
        "timeout_s": PTY_REPLY_TIMEOUT_S,
        "reconnect_max_s": 0.5,
        "command_timeout_s": COMMAND_TIMEOUT_S,
        "diagnostic_period_s": DIAGNOSTIC_PERIOD_S,
    }
    defaults.update(params)
    return defaults


@contextmanager
def motec(
    client: Client,
    log_dir: Path,
    params: dict[str, Any],
    *,
    port: str = "",
    units: Sequence[int] = UNITS,
    extra: Sequence[str] = (),
    namespace: str | None = None,
) -> Iterator[tuple[MotecBridge, Any]]:
    namespace = namespace or unique_namespace("motec_test")
    port = port or str(params["serial_port"])
    bridge = MotecBridge(client, namespace, port, units, str(params.get("joint_prefix", "")))
    log_dir.mkdir(parents=True, exist_ok=True)
    with node_process(
        "motec_bridge.node", params, log_dir, ["-r", f"__ns:={namespace}", *extra]
    ) as proc:
        yield bridge, proc


def writes(drive: MotecSimDrive) -> list[tuple[int, Table, int, tuple[int, ...]]]:
    return [(r.function_code, r.table, r.address, r.values) for r in drive.write_log]


def level(value: int, *keys: str) -> Callable[[Any], bool]:
    """Status at ``value`` that has ``keys`` (a drive's own keys come with its first poll)."""
    return lambda status: (
        status.level == bytes([value]) and all(key in values_of(status) for key in keys)
    )


def test_three_drives_topics_services_and_deadman(bus, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sim, port = bus
    sim.drive(2).set_position(2500)  # a quarter turn at 10000 counts/rev
    sim.drive(3).set_input(8, True)
    sim.drive(3).set_analog(1234)
    params = bridge_params(port, joint_prefix="m_")
    with motec(client, tmp_path, params) as (b, proc):
        for unit in UNITS:
            b.wait_connected(unit, True)
            b.wait_joint(unit)
        js = b.wait_joint(2)
        assert list(js.position) == pytest.approx([math.pi / 2])
        assert list(js.velocity) == [0.0]
        st = b.wait_state(3)
        assert st.unit_id == 3 and st.inputs[7] and sum(st.inputs) == 1
        assert st.input_word == 0x80 and st.analog_input == 1234
        assert (st.operation_mode_name, st.control_mode_name) == ("other(1)", "position")
        assert not st.enabled and st.fault_code == 0 and st.fault_text == "no fault (无故障)"
        for unit in UNITS:
            status = b.wait_diagnostic(unit, level(0, "unit id"))
            assert values_of(status)["unit id"] == str(unit)
            assert f"unit {unit}" in status.hardware_id

        # Drive 1: the manual's position-mode sequence, then more services.
        b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.POSITION)
        b.ok(1, SetBool, "enable", data=True)
        # Two turns out, so that the way back at 95 rpm cruises ~1.2 s: polls and the
        # simulator's ticks see its speed through a stall of the loaded machine.
        assert b.ok(1, PositionMove, "move", position=4 * math.pi, relative=True).counts == 20000
        t = time.monotonic()
        b.wait_joint(1, lambda m: m.position[0] == pytest.approx(4 * math.pi), since=t)
        b.wait_state(1, lambda m: m.position_actual == 20000 and not m.moving, since=t)
        b.ok(1, PositionMove, "move", position=0.0, relative=False, max_velocity=10.0)
        t = time.monotonic()
        b.wait_state(1, lambda m: m.speed_actual_rpm == -95, since=t)  # 10 rad/s = 95 rpm
        b.wait_state(1, lambda m: m.position_actual == 0 and not m.moving, since=t)
        assert "0x29 = 0" in b.ok(1, Trigger, "stop").message
        b.ok(1, Trigger, "save_to_flash")
        b.ok(1, SetOutput, "set_output", board=0, index=2, state=True)
        b.ok(1, SetValue, "set_analog_max_speed", value=1500.0)
        t = time.monotonic()
        st = b.wait_state(1, lambda m: m.outputs[1] and m.analog_max_speed_rpm == 1500, since=t)
        assert st.motion_mode == MotecState.MOTION_MODE_ABSOLUTE and st.enabled
        assert sim.drive(1).saves == 1

        # Drive 3: an output.
        b.ok(3, SetOutput, "set_output", board=0, index=1, state=True)
        b.wait_state(3, lambda m: m.outputs[0] and m.output_word == 1, since=time.monotonic())

        # Drive 2: velocity stream, then silence: the deadman sets 0 rpm.
        b.ok(2, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY)
        b.ok(2, SetBool, "enable", data=True)
        pub = client.node.create_publisher(Float64, f"{b.ns}/motec_2/cmd_velocity", 10)
        wait_subscribed(pub)
        t = time.monotonic()
        deadline = t + 1.0
        while time.monotonic() < deadline:
            last_sent = time.time()  # before: the bridge may have it before this thread runs
            pub.publish(Float64(data=2 * math.pi))  # 60 rpm
            time.sleep(0.05)
        js = b.wait_joint(2, lambda m: m.velocity[0] != 0.0, since=t)
        assert js.velocity[0] == pytest.approx(2 * math.pi)
        b.wait_state(2, lambda m: m.speed_actual_rpm == 0, since=time.monotonic())
        client.node.destroy_publisher(pub)
        stop = sim.drive(2).write_log[-1]
        assert (stop.address, stop.values) == (0xAE, (0,))
        assert stop.time - last_sent >= COMMAND_TIMEOUT_S * 0.9
        assert proc.poll() is None

    assert writes(sim.drive(1)) == [
        (6, H, 0x24, (0,)),  # network mode
        (6, H, 0x25, (2,)),  # position control
        (6, H, 0x28, (1,)),  # enable
        (6, H, 0x2D, (0,)),  # relative
        (16, H, 0x26, (0, 20000)),  # 4 pi rad = two turns
        (6, H, 0x29, (1,)),  # start
        (6, H, 0xAE, (95,)),  # max_velocity 10 rad/s
        (6, H, 0x2D, (1,)),  # absolute
        (16, H, 0x26, (0, 0)),
        (6, H, 0x29, (1,)),
        (6, H, 0x29, (0,)),  # stop
        (6, H, 0x35, (1,)),  # save to flash
        (5, C, 1, (1,)),  # OUTPUT2 on
        (6, H, 0x6D, (1500,)),
    ]
    assert writes(sim.drive(2)) == [
        (6, H, 0x24, (0,)),
        (6, H, 0xAE, (0,)),  # zeroed before velocity control
        (6, H, 0x25, (1,)),
        (6, H, 0xAE, (0,)),  # and before enabling
        (6, H, 0x28, (1,)),
        (6, H, 0xAE, (60,)),  # once, for 20 equal messages
        (6, H, 0xAE, (0,)),  # the deadman
    ]
    assert writes(sim.drive(3)) == [(5, C, 0, (1,))]  # OUTPUT1 on


def test_cmd_velocity_floods_are_coalesced_and_rate_limited(
    bus: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """A command stream keeps only its newest value and writes at most
    ``command_rate_hz`` speeds a second; a flood costs no drive its link, and the deadman
    stop after it is the last write (counted from the last message's arrival)."""
    sim, port = bus
    rate_hz = 10.0
    drive = sim.drive(2)
    with motec(client, tmp_path, bridge_params(port, command_rate_hz=rate_hz)) as (b, proc):
        for unit in UNITS:
            b.wait_connected(unit, True)
        b.ok(2, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY)
        b.ok(2, SetBool, "enable", data=True)
        pub = client.node.create_publisher(Float64, f"{b.ns}/motec_2/cmd_velocity", 10)
        wait_subscribed(pub)

        def flood(value: Callable[[int], float], count: int) -> tuple[float, float]:
            """``count`` messages about 1 ms apart; a flood by count, not by time, so a
            loaded machine makes it slower, not smaller (asserted still many times the
            rate limit)."""
            first = last = time.time()
            for sent in range(count):
                last = time.time()  # the last publish's start: a lower bound of its arrival
                pub.publish(Float64(data=value(sent)))
                time.sleep(0.001)
            assert count / (last - first) > 4 * rate_hz, "not a flood"
            return first, last

        # A constant value: one write, however many messages.
        start = time.monotonic()
        before = len(drive.write_log)
        flood(lambda _n: 2 * math.pi, 250)
        b.wait_state(2, lambda m: m.speed_actual_rpm == 60, since=time.monotonic())
        assert writes(drive)[before:] == [(6, H, 0xAE, (60,))]
        # A varying one (1.0-5.9 rad/s, never 0): speeds at most rate_hz a second.
        before = len(drive.write_log)
        first, last = flood(lambda n: 1.0 + (n % 50) / 10, 400)
        wait_for(lambda: (6, H, 0xAE, (0,)) in writes(drive)[before:], WAIT_S, "the deadman's stop")
        during = writes(drive)[before:]
        stop_index = during.index((6, H, 0xAE, (0,)))
        speeds = during[:stop_index]
        assert speeds and all(w[2] == 0xAE for w in speeds)
        # One write per 1/rate_hz at most: over the flood and the last value's wait.
        assert len(speeds) <= rate_hz * (last - first + 1.0) + 1, len(speeds)
        stop = drive.write_log[before + stop_index]
        assert stop.time - last >= COMMAND_TIMEOUT_S * 0.9
        assert during[stop_index + 1 :] == []  # nothing after the stop (so far)
        for unit in UNITS:  # no drive lost its link to the flood
            assert all(m.data for m in client.received(b.connected(unit), since=start))
        client.node.destroy_publisher(pub)
        assert proc.poll() is None


def test_a_drive_removed_and_back(bus, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sim, port = bus
    with motec(client, tmp_path, bridge_params(port, timeout_s=SHORT_TIMEOUT_S)) as (b, proc):
        for unit in UNITS:
            b.wait_joint(unit)
            b.wait_connected(unit, True)

        t = time.monotonic()
        sim.unplug(2)
        b.wait_connected(2, False, since=t)
        status = b.wait_diagnostic(2, level(2), since=t)
        values = values_of(status)
        assert values["link state"] == "disconnected" and int(values["timeouts"]) > 0
        reply = b.call(2, SetBool, "enable", data=True)
        assert not reply.success and "not connected" in reply.message
        # The live drives keep polling and stay connected while drive 2 times out, and
        # nothing stale is published for the dead drive meanwhile.
        t1 = time.monotonic()
        for unit in (1, 3):
            b.wait_joints(unit, 10, since=t1)
            b.wait_diagnostic(unit, level(0), since=t1)
        assert b.joints(2, t1) == []
        for unit in (1, 3):
            assert [m.data for m in client.received(b.connected(unit), t)] == [], unit

        t = time.monotonic()
        sim.plug(2)
        b.wait_connected(2, True, since=t)
        b.wait_joint(2, since=t)
        status = b.wait_diagnostic(2, level(0), since=t)
        assert int(values_of(status)["reconnects"]) >= 1
        b.acknowledged(2)  # a refused command would have run by now
        assert proc.poll() is None
    for unit in UNITS:
        assert sim.drive(unit).write_log == []  # the refused command never ran


def test_lifeguard_fault_after_the_bridge_dies(bus, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sim, port = bus
    params = bridge_params(
        port, unit_ids=[1, 2], lifeguard_ms=LIFEGUARD_MS, timeout_s=SHORT_TIMEOUT_S
    )
    namespace = unique_namespace("motec_lifeguard")  # the same for both bridges
    drive = sim.drive(1)
    with motec(client, tmp_path / "first", params, units=[1, 2], namespace=namespace) as (b, proc):
        b.wait_connected(1, True)
        b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY)
        b.ok(1, SetBool, "enable", data=True)
        assert writes(drive)[:2] == [(6, H, 0x112, (LIFEGUARD_MS,)), (6, H, 0x114, (9999,))]
        st = b.wait_state(1, lambda m: m.enabled and m.lifeguard_armed)
        assert st.lifeguard_time_ms == LIFEGUARD_MS and st.lifeguard_mode == 9999
        status = b.wait_diagnostic(1, level(0, "lifeguard"))
        assert values_of(status)["lifeguard"] == f"armed, {LIFEGUARD_MS} ms, fed by the bridge"

        def feeds() -> int:
            return sum(1 for r in drive.write_log if r.address == 0x112)

        # Five more feeds (over more than one lifeguard time): the drive stays happy.
        fed = feeds()
        wait_for(lambda: feeds() >= fed + 5, WAIT_S, "five lifeguard feeds")
        assert drive.fault == 0 and drive.enabled and drive.lifeguard_trips == 0
        proc.send_signal(signal.SIGKILL)
        proc.wait(5)
        wait_for(lambda: drive.fault == LIFEGUARD_FAULT_CODE, WAIT_S, "the lifeguard to fire")
        assert not drive.enabled and drive.lifeguard_trips == 1
        assert sim.drive(2).fault == 0  # not in network mode: no lifeguard

    t = time.monotonic()
    with motec(client, tmp_path / "second", params, units=[1, 2], namespace=namespace) as (b, _):
        st = b.wait_state(1, lambda m: m.fault_code == LIFEGUARD_FAULT_CODE, since=t)
        assert st.fault_text == "fault (有故障)" and not st.enabled
        assert (st.fault_flag, st.fault_detail) == (1, 0)  # §4.3: 0xC8 reads 1 (item 12)
        # The drive's ERROR, not the one of a status published before the first poll
        # ("disconnected", also level 2).
        status = b.wait_diagnostic(
            1, lambda s: level(2)(s) and s.message.startswith("drive fault"), since=t
        )
        assert status.message == f"drive fault {LIFEGUARD_FAULT_CODE}: fault (有故障)"
        assert values_of(status)["link state"] == "connected"
        b.ok(1, SetBool, "enable", data=False)  # releasing does not clear it (§3.4)
        assert sim.drive(1).fault == LIFEGUARD_FAULT_CODE
        sim.power_cycle(1)  # a restart does (docs/bridges/motec.md, "Lifeguard")
        t = time.monotonic()
        b.wait_state(1, lambda m: m.fault_code == 0, since=t)
        b.wait_diagnostic(1, level(0), since=t)


def test_lifeguard_armed_changed_and_disarmed_at_run_time(
    bus: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """lifeguard_ms is live: a set arms, re-arms or (0) disarms the drive at
    once, and is refused with the reason, writing nothing, when it is too small for the
    bus, under read_only, or while the drive does not answer."""
    sim, port = bus
    drive = sim.drive(1)
    floor = lifeguard_floor_ms(len(UNITS))
    armed, changed = floor + 100, floor + 900
    with motec(client, tmp_path, bridge_params(port, timeout_s=SHORT_TIMEOUT_S)) as (b, _):
        b.wait_connected(1, True)
        b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY)
        before = len(drive.write_log)
        result = b.set_param(1, "lifeguard_ms", armed)
        assert result.successful, result.reason
        assert writes(drive)[before:] == [(6, H, 0x112, (armed,)), (6, H, 0x114, (9999,))]
        t = time.monotonic()
        st = b.wait_state(1, lambda m: m.lifeguard_armed, since=t)
        assert st.lifeguard_time_ms == armed
        wait_for(lambda: (6, H, 0x112, (armed,)) in writes(drive)[before + 2 :], WAIT_S, "a feed")

        before = len(drive.write_log)
        result = b.set_param(1, "lifeguard_ms", changed)
        assert result.successful, result.reason
        assert writes(drive)[before : before + 2] == [
            (6, H, 0x112, (changed,)),
            (6, H, 0x114, (9999,)),
        ]
        wait_for(lambda: (6, H, 0x112, (changed,)) in writes(drive)[before + 2 :], WAIT_S, "feed")

        # Too small for three drives at 1 s timeouts: refused with the formula, nothing sent.
        before = len(drive.write_log)
        result = b.set_param(1, "lifeguard_ms", floor - 1)
        assert not result.successful
        assert f"below {floor} ms" in result.reason and "3 drive(s)" in result.reason
        # read_only would end the feeds of the armed drive: refused.
        result = b.set_param(1, "read_only", True)
        assert not result.successful, "read_only set on an armed drive"
        assert f"lifeguard is armed ({changed} ms)" in result.reason, result.reason
        assert "set lifeguard_ms to 0 first" in result.reason, result.reason
        assert all(w[2] != 0x114 for w in writes(drive)[before:])

        # 0 disarms: 0x112 = 0 (§3.4's own frame), then 0x114 = 0; the feeds stop.
        result = b.set_param(1, "lifeguard_ms", 0)
        assert result.successful, result.reason
        assert writes(drive)[-2:] == [(6, H, 0x112, (0,)), (6, H, 0x114, (0,))]
        t = time.monotonic()
        b.wait_state(1, lambda m: not m.lifeguard_armed and m.lifeguard_mode == 0, since=t)
        disarmed = len(drive.write_log)
        # More than a feed period of the old time later (by poll stamps), no feed went out.
        b.wait_joints(1, 2, time.monotonic() + changed / 1000.0 / 3 + 0.2)
        assert writes(drive)[disarmed:] == []
        # Disarmed, read_only may be set; and then arming is refused.
        result = b.set_param(1, "read_only", True)
        assert result.successful, result.reason
        result = b.set_param(1, "lifeguard_ms", armed)
        assert not result.successful and "read_only" in result.reason, result.reason
        assert b.set_param(1, "read_only", False).successful
        assert writes(drive)[disarmed:] == []

        # A drive that does not answer: refused, nothing sent (and nothing to send to).
        drive_3 = sim.drive(3)
        t = time.monotonic()
        sim.unplug(3)
        b.wait_connected(3, False, since=t)
        result = b.set_param(3, "lifeguard_ms", armed)
        assert not result.successful and "not connected" in result.reason, result.reason
        sim.plug(3)
        assert all(w[2] not in (0x112, 0x114) for w in writes(drive_3))


def test_a_lifeguard_too_short_for_the_bus_is_refused_at_start() -> None:
    """One line with the formula, exit code 2, before anything is sent."""
    floor = lifeguard_floor_ms(3)
    params = {"unit_ids": UNITS, "baudrate": BAUD, "timeout_s": SHORT_TIMEOUT_S}
    params["lifeguard_ms"] = floor - 1
    line = refused_at_start("motec_bridge.node", ros_args(params), WAIT_S * 2)
    assert f"lifeguard_ms {floor - 1} is below {floor} ms" in line, line
    assert "3 drive(s) x 1.024 s" in line, line


def test_a_dead_drive_never_starves_the_lifeguard_of_the_others(
    client: Client, tmp_path: Path
) -> None:
    """Three drives, lifeguard_ms at the shortest the bridge accepts; drive 3
    dies (first while still marked connected: a read and its retry; then every reconnect
    probe holds the line for a whole timeout): drives 1 and 2 never go a lifeguard time
    without a write, and never trip."""
    timeout_s = 0.5  # the dead drive's probes hold the line this long each
    lifeguard_ms = lifeguard_floor_ms(3, timeout_s)
    simulator = make_simulator(UNITS)
    params = bridge_params("", timeout_s=timeout_s, lifeguard_ms=lifeguard_ms)
    with served_on_pty(simulator, BAUD) as port:
        params["serial_port"] = port
        with motec(client, tmp_path, params) as (b, proc):
            for unit in UNITS:
                b.wait_connected(unit, True)
            for unit in (1, 2):  # the lifeguard watches drives in network mode
                b.set_up(
                    unit, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY
                )
                b.set_up(unit, SetBool, "enable", data=True)
            t, unplugged = time.monotonic(), time.time()  # the write log has time.time()
            simulator.unplug(3)
            b.wait_connected(3, False, since=t)
            # Three lifeguard times of probes of the dead drive, counted by polls of drive 1.
            b.wait_joints(1, 3, time.monotonic() + 3 * lifeguard_ms / 1000.0)
            assert proc.poll() is None
            # Judged while the bridge still feeds: once it exits, an armed drive faults
            # after lifeguard_ms by design (docs/bridges/motec.md), and beside two CPU
            # burners the exit took that long before the simulator stopped (a trip, no gap).
            fed_until = time.time()
            after = {
                u: (d.lifeguard_trips, d.fault, d.enabled) for u, d in simulator.drives.items()
            }
    for unit in (1, 2):
        drive = simulator.drive(unit)
        times = [r.time for r in drive.write_log if unplugged <= r.time <= fed_until]
        gaps = [later - earlier for earlier, later in itertools.pairwise(times)]
        assert len(times) >= 6, times  # fed all along
        assert max(gaps) < lifeguard_ms / 1000.0, (unit, max(gaps), lifeguard_ms)
        assert after[unit] == (0, 0, True), (unit, "lifeguard trips, fault, enabled")


BLACKOUTS_MS = (300, 600, 900)


def armed_by_bridge(drive: MotecSimDrive) -> bool:
    return drive.value("lifeguard_mode") == 9999


def written_after(drive: MotecSimDrive, t: float) -> bool:
    """A write reached ``drive`` after ``t`` (its own clock: ``time.monotonic()``)."""
    return drive.last_command > t


def last_write_before(drive: MotecSimDrive, t: float) -> float:
    """When ``drive`` last accepted a write before ``t`` (``time.monotonic()``; its write
    records are on ``time.time()``)."""
    wall_to_mono = -wall_minus_monotonic()
    return max(r.time + wall_to_mono for r in list(drive.write_log) if r.time + wall_to_mono < t)


def around_the_blackout(
    drive: MotecSimDrive, line: LineRelay, dark_from: float, dark_until: float
) -> str:
    """What a failure needs to tell the bridge from the rig: the drive's accepted writes
    (from 1 s before the blackout to 1.5 s after) and every frame on the line (from 0.1 s
    before to 1 s after), in seconds from the line's return (a request on the wire that
    the drive did not take is the rig's; no request at all is the bridge's)."""
    wall_to_mono = -wall_minus_monotonic()  # write records are on time.time()
    writes = [
        f"{r.time + wall_to_mono - dark_until:+.3f}"
        for r in drive.write_log
        if dark_from - 1.0 <= r.time + wall_to_mono <= dark_until + 1.5
    ]
    frames = [
        f"{f.direction[:3]}{f.size}@{f.start - dark_until:+.3f}"
        for f in line.frames()
        if dark_from - 0.1 <= f.start <= dark_until + 1.0
    ]
    return (
        f"dark {dark_from - dark_until:+.3f}..0; drive writes at {' '.join(writes)}; "
        f"frames {' '.join(frames)}"
    )


def config_motec_yaml(tmp_path: Path, port: str) -> list[str]:
    """config/motec.yaml as shipped (1000 ms lifeguard, timeout_s 0.1, three drives), on
    ``port``: the ``--params-file`` arguments."""
    config = (ROOT / "config" / "motec.yaml").read_text()
    assert '"/dev/ttyUSB0"' in config and "lifeguard_ms: 1000" in config
    params_file = tmp_path / "motec.yaml"
    params_file.write_text(config.replace('"/dev/ttyUSB0"', f'"{port}"'))
    return ["--params-file", str(params_file)]


def test_line_blackouts_never_trip_a_drive_that_answers_again_in_time(
    client: Client, tmp_path: Path
) -> None:
    """With config/motec.yaml (lifeguard 1000 ms, fed every 333 ms), the
    emulated line goes dark for 300, 600 and 900 ms, each time just after a write reached
    drive 1. The feeds go on while the drives are marked down (one try with the short stop
    timeout each feed period), so a drive whose line comes back within lifeguard - feed
    period of its last write is fed before it trips (before: a 600 ms blackout left it
    1.29 s without a write). Drives 2 and 3 are at other phases; a 900 ms blackout is
    beyond the claim (the figures: bench/motec_blackout.py)."""
    lifeguard_s, feed_period_s = 1.0, 1.0 / 3
    simulator = make_simulator(UNITS)
    with LineRelay(BAUD) as line:
        simulator.start_serial(line.device_path, BAUD)
        try:
            extra = config_motec_yaml(tmp_path, line.client_path)
            with motec(client, tmp_path, {}, port=line.client_path, extra=extra) as (b, proc):
                for unit in UNITS:
                    b.wait_connected(unit, True)
                for unit in UNITS:  # the lifeguard watches drives in network mode
                    drive = simulator.drive(unit)
                    assert drive.write(6, 0x24, [0]) is None
                    wait_for(partial(armed_by_bridge, drive), WAIT_S, "the drive armed")
                drive_1 = simulator.drive(1)
                for blackout_ms in BLACKOUTS_MS:
                    last = drive_1.last_command
                    wait_for(partial(written_after, drive_1, last), WAIT_S, "a write")
                    trips = {u: simulator.drive(u).lifeguard_trips for u in UNITS}
                    dark_from, dark_until = line.blackout(blackout_ms / 1000.0)
                    for unit in UNITS:  # each drive written again after the line is back
                        drive = simulator.drive(unit)
                        wait_for(partial(written_after, drive, dark_until), WAIT_S, "a write")
                    # Each drive's last write before the line came back, from its log: a frame
                    # the relay let through just before the dark may be taken by the drive just
                    # after dark_from, and this thread may run late, so neither "at most
                    # dark_from" nor "last_command right after the blackout call" holds.
                    before = {u: last_write_before(simulator.drive(u), dark_until) for u in UNITS}
                    for unit in UNITS:
                        drive = simulator.drive(unit)
                        silent_s = dark_until - before[unit]
                        if silent_s <= lifeguard_s - feed_period_s:
                            assert drive.lifeguard_trips == trips[unit], (
                                f"drive {unit} tripped after a {blackout_ms} ms blackout, "
                                f"its line back {silent_s:.3f} s after its last write; "
                                + around_the_blackout(drive, line, dark_from, dark_until)
                            )
                        if drive.lifeguard_trips != trips[unit]:  # beyond the claim
                            simulator.power_cycle(unit)
                            for address, value in ((0x24, 0), (0x112, 1000), (0x114, 9999)):
                                assert drive.write(6, address, [value]) is None
                assert proc.poll() is None
        finally:
            simulator.stop()


def test_refusals_read_only_and_params_file(bus, client: Client, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sim, port = bus
    sim.drive(2).set_position(25000)  # 2.5 motor turns = a quarter joint turn at gear 10
    sim.drive(1).inject_fault(7)
    config = (ROOT / "config" / "motec.yaml").read_text()
    for old, new in (
        ('"/dev/ttyUSB0"', f'"{port}"'),
        ("lifeguard_ms: 1000", "lifeguard_ms: 0"),
        ("poll_rate_hz: 10.0", "poll_rate_hz: 20.0"),
        ("timeout_s: 0.1 ", f"timeout_s: {PTY_REPLY_TIMEOUT_S} "),
    ):
        assert old in config, old
        config = config.replace(old, new)
    config += "/**/motec_3:\n  ros__parameters:\n    read_only: true\n"
    params_file = tmp_path / "motec.yaml"
    params_file.write_text(config)
    extra = ["--params-file", str(params_file)]
    with motec(client, tmp_path, {}, port=port, extra=extra) as (b, _):
        for unit in UNITS:
            b.wait_connected(unit, True)
        assert b.wait_joint(2).position[0] == pytest.approx(math.pi / 2)  # gear_ratio 10
        status = b.wait_diagnostic(1, level(2))
        assert status.message == "drive fault 7: fault 0x00000007 (code not listed in the manual)"

        refusals: list[tuple[int, Any, str, dict[str, Any], str]] = [
            (1, PositionMove, "move", {"position": 1.0, "relative": True}, "network mode"),
            (1, PositionMove, "move", {"position": math.nan}, "not a finite"),
            (1, PositionMove, "move", {"position": 1e12}, "outside"),
            (1, PositionMove, "move", {"position": 1.0, "max_velocity": 1e3}, "max_speed_rpm"),
            (1, PositionMove, "move", {"position": 1.0, "max_velocity": -1.0}, "negative"),
            (1, SetControlMode, "set_control_mode", {"mode": 3}, "control mode 3"),
            (1, SetOutput, "set_output", {"board": 0, "index": 4, "state": True}, "output 4"),
            (1, SetOutput, "set_output", {"board": 1, "index": 1, "state": True}, "board 1"),
            (1, SetValue, "set_analog_max_speed", {"value": 70000.0}, "outside"),
            (1, SetValue, "set_analog_max_speed", {"value": 1.5}, "whole number"),
            (3, SetBool, "enable", {"data": False}, "read_only"),
            (3, Trigger, "save_to_flash", {}, "read_only"),
        ]
        for unit, srv, name, fields, reason in refusals:
            reply = b.call(unit, srv, name, **fields)
            assert not reply.success, (name, reply.message)
            assert "refused" in reply.message and reason in reply.message, reply.message
        # The drive itself refuses to enable with a latched fault.
        reply = b.call(1, SetBool, "enable", data=True)
        assert not reply.success and "ILLEGAL DATA VALUE" in reply.message
        # Velocity commands outside velocity control, or read_only: nothing written. Each
        # refused value is waited for by the drive node's refusal count before the next
        # (a command stream keeps only its newest value).
        for unit in (1, 3):
            t = time.monotonic()
            pub = client.node.create_publisher(Float64, f"{b.ns}/motec_{unit}/cmd_velocity", 10)
            wait_subscribed(pub)
            for refused, value in enumerate((1.0, math.nan, 1e6), start=1):
                pub.publish(Float64(data=value))
                wait_stream_refusals(client, f"motec_{unit}", refused, time.monotonic())
            client.wait_log(f"{b.ns[1:]}.motec_{unit}", "cmd_velocity 1.0 rad/s refused", t)
            client.node.destroy_publisher(pub)
        # A disconnected drive.
        t = time.monotonic()
        sim.unplug(2)
        b.wait_connected(2, False, since=t)
        reply = b.call(2, SetBool, "enable", data=True)
        assert not reply.success and "not connected" in reply.message
        # A stop is tried on the wire even so, and says it failed.
        reply = b.call(2, Trigger, "stop")
        assert not reply.success and reply.message.startswith("stop failed:"), reply.message
        sim.plug(2)
        b.wait_connected(2, True, since=time.monotonic())
        b.acknowledged(2)  # the refused enable would have run by now
        for unit in UNITS:
            assert sim.drive(unit).write_log == [], unit

        # The bus node's broadcast reaches every drive (drive 1's fault stays latched).
        assert "broadcast" in b.ok(None, Trigger, "disable_all").message
        wait_for(lambda: all(sim.drive(u).write_log for u in UNITS), 5, "the broadcast")
        for unit in UNITS:
            assert writes(sim.drive(unit)) == [(6, H, 0x28, (0,))]
        b.wait_state(1, lambda m: m.fault_code == 7, since=time.monotonic())


def test_parameters_start_all_io_tables_and_output_numbering(
    bus: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """~/read_parameter and ~/write_parameter (guarded), the bus node's broadcast
    start of a synchronised move, the IO tables and 0x29 in ~/state, output1_coil."""
    sim, port = bus
    units = [1, 2]
    sim.drive(2).set_input(5, True)
    params = bridge_params(port, unit_ids=units, read_io_tables=True, output1_coil=1)
    with motec(client, tmp_path, params, units=units) as (b, _):
        for unit in units:
            b.wait_connected(unit, True)
        st = b.wait_state(2, lambda m: m.io_tables_read)
        assert list(st.discrete_inputs) == [False] * 4 + [True] + [False] * 3
        assert st.start == 0 and (st.fault_flag, st.fault_detail) == (0, 0)
        assert st.output1_coil == 1
        # Parameters by number.
        assert b.ok(1, ReadParameter, "read_parameter", index=0x6D).value == 0
        b.ok(1, WriteParameter, "write_parameter", index=0x6D, value=1500)
        assert b.ok(1, ReadParameter, "read_parameter", index=0x6D).value == 1500
        for index, value, reason in (
            (0x2A, 1, "not a parameter the manual names"),
            (0x28, 1, "~/enable"),
            (0x6D, 70000, "outside"),
            (39, 1, "low word"),
        ):
            reply = b.call(1, WriteParameter, "write_parameter", index=index, value=value)
            assert not reply.success and "refused" in reply.message, reply.message
            assert reason in reply.message, reply.message
        # Any Pr.N reads (an unnamed one reads 0 in the simulator).
        assert b.ok(1, ReadParameter, "read_parameter", index=0x2A).value == 0
        reply = b.call(1, ReadParameter, "read_parameter", index=0x115)
        assert not reply.success and "ILLEGAL DATA ADDRESS" in reply.message, reply.message
        # A synchronised start: refused while a drive is not ready, nothing sent.
        reply = b.call(None, Trigger, "start_all")
        assert not reply.success and "drive 1 is in operation mode" in reply.message
        for unit in units:
            b.ok(unit, SetControlMode, "set_control_mode", mode=SetControlMode.Request.POSITION)
            b.ok(unit, SetBool, "enable", data=True)
            b.ok(unit, WriteParameter, "write_parameter", index=38, value=2000 * unit)
        for address, value in ((0x24, 0), (0x25, 2), (0x28, 1)):  # drive 3, not the bridge's
            assert sim.drive(3).write(6, address, [value]) is None
        result = b.set_bus_param("read_only", True)
        assert result.successful, result.reason
        reply = b.call(None, Trigger, "start_all")
        assert not reply.success and "read_only" in reply.message, reply.message
        assert b.set_bus_param("read_only", False).successful
        assert bus_transition(client, b.ns, Transition.TRANSITION_DEACTIVATE)
        reply = b.call(None, Trigger, "start_all")
        assert not reply.success and "not active" in reply.message, reply.message
        assert bus_transition(client, b.ns, Transition.TRANSITION_ACTIVATE)
        # A drive node's read_only holds for the broadcast too.
        assert b.set_param(2, "read_only", True).successful
        reply = b.call(None, Trigger, "start_all")
        assert not reply.success and "drive 2's node is read_only" in reply.message, reply.message
        assert b.set_param(2, "read_only", False).successful
        message = b.ok(None, Trigger, "start_all").message
        assert "broadcast 0x29 = 1 sent, read back: drive 1: 0x28 = 1, 0x29 = 1" in message
        t = time.monotonic()
        for unit in units:
            target = 2000 * unit
            b.wait_state(unit, lambda m: bool(m.position_actual == target), since=t)  # noqa: B023
        # OUTPUT2 at coil 2 (the §3.3.3 example's numbering).
        b.ok(1, SetOutput, "set_output", board=0, index=2, state=True)
        t = time.monotonic()
        b.wait_state(1, lambda m: m.outputs[1] and m.coil_outputs[1], since=t)
    assert writes(sim.drive(1))[-2:] == [(6, H, 0x29, (1,)), (5, C, 2, (1,))]
    assert writes(sim.drive(2))[-1] == (6, H, 0x29, (1,))
    assert writes(sim.drive(3))[-1] == (6, H, 0x29, (1,))  # a broadcast reaches every drive


def bus_transition(client: Client, namespace: str, transition: int) -> bool:
    """A lifecycle transition of the bus node (lifecycle_msgs, as a manager sends it)."""
    request = ChangeState.Request()
    request.transition.id = transition
    reply = client.call(ChangeState, f"{namespace}/motec_bridge/change_state", request)
    return bool(reply.success)


def test_more_than_eight_drives_on_rs232_are_refused_at_start() -> None:
    """§1.1.1: "RS232通讯口最多可以支持连接8台驱动器联网": one line, exit code 2."""
    params = {"unit_ids": list(range(1, 10)), "interface": "rs232"}
    line = refused_at_start("motec_bridge.node", ros_args(params), WAIT_S * 2)
    assert "unit_ids has 9 drives, but an rs232 line takes at most 8" in line, line


def reads_speed(rpm: int) -> Callable[[Any], bool]:
    """A MotecState whose 0xAF reads ``rpm``."""
    return lambda m: bool(m.speed_actual_rpm == rpm)


def test_set_control_mode_refuses_a_turning_motor_not_speed_noise(
    client: Client, tmp_path: Path
) -> None:
    """Decision 17: a servo at rest dithers a few rpm on 0xAF; the
    mode change is refused only above the standstill band, with nothing written."""
    with motec_on_pty([1], BAUD) as (sim, port):
        drive = sim.drive(1)
        drive.tick = lambda dt: None  # type: ignore[method-assign]  # 0xAF stays as set here
        params = bridge_params(port, unit_ids=[1])
        with motec(client, tmp_path, params, units=[1]) as (b, _):
            b.wait_connected(1, True)
            velocity, position = SetControlMode.Request.VELOCITY, SetControlMode.Request.POSITION
            # Standing, with noise inside the band: the manual's sequence goes out.
            for rpm, mode in ((-2, velocity), (STANDSTILL_SPEED_RPM, position)):
                drive.set("speed_actual", rpm)
                b.wait_state(1, reads_speed(rpm), time.monotonic())
                mark = len(drive.write_log)
                b.ok(1, SetControlMode, "set_control_mode", mode=mode)
                written = [(r.address, r.values) for r in drive.write_log[mark:]]
                assert written[0] == (0x24, (0,)) and written[-1] == (0x25, (mode,)), written
            # Turning faster than the band, either way: refused, nothing written.
            for rpm in (STANDSTILL_SPEED_RPM + 1, -120):
                drive.set("speed_actual", rpm)
                b.wait_state(1, reads_speed(rpm), time.monotonic())
                mark = len(drive.write_log)
                reply = b.call(1, SetControlMode, "set_control_mode", mode=velocity)
                assert not reply.success and f"turns at {rpm} rpm" in reply.message, reply.message
                assert drive.write_log[mark:] == []


def test_an_armed_drive_whose_replies_are_lost_is_still_fed(client: Client, tmp_path: Path) -> None:
    """The node's half: the drive's replies are lost for four lifeguard
    times while it still hears the line (a broken transmit pair). The bridge marks it
    down, and its lifeguard feeds go on, one try each feed period with the short stop
    timeout, so the drive never trips. The reconnect backoff is the default 5 s cap: the
    probes' own re-arming (link-up work before each probe) comes 0.25, 0.5, 1, 2, 4 s
    apart and alone would let a 1.9 s lifeguard trip. (Before the fix the feeds stopped
    while the drive was down: it tripped and released its motor.)"""
    armed = lifeguard_floor_ms(1) + 100
    simulator = make_simulator([1])
    drive = simulator.drive(1)
    with LineRelay(BAUD) as line:
        simulator.start_serial(line.device_path, BAUD)
        try:
            params = bridge_params(
                line.client_path, unit_ids=[1], reconnect_max_s=5.0, timeout_s=SHORT_TIMEOUT_S
            )
            with motec(client, tmp_path, params, port=line.client_path, units=[1]) as (b, proc):
                b.wait_connected(1, True)
                b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY)
                result = b.set_param(1, "lifeguard_ms", armed)
                assert result.successful, result.reason
                b.wait_state(1, lambda m: m.lifeguard_armed)
                trips = drive.lifeguard_trips
                since = time.monotonic()
                _, muted_until = line.mute_replies(4 * armed / 1000.0)
                b.wait_connected(1, False, since)
                b.wait_connected(1, True, muted_until)  # the replies are back
                assert drive.lifeguard_trips == trips, "the drive tripped while it was down"
                assert proc.poll() is None
        finally:
            simulator.stop()


def test_drives_that_together_exceed_their_line_are_said_once_by_the_bus_owner(
    client: Client, tmp_path: Path
) -> None:
    """The wire budget: three drives at 9600 baud, each asking 6 polls a second. A
    poll is ~60 ms of frames at 9600 (the budget counts a real line's bytes; the pty moves
    them faster), so each drive alone needs ~40 % of the line and the three ~120 %: the
    bus owner says so once, with the rates the line carries, and each drive's diagnostics
    show the line's sum."""
    baud = 9600
    with motec_on_pty(UNITS, baud) as (_sim, port):
        # 1 s statuses: "three more statuses" below is a window of ~3 s for a second line.
        params = bridge_params(port, baudrate=baud, poll_rate_hz=6.0, diagnostic_period_s=1.0)
        with motec(client, tmp_path, params) as (b, proc):
            owner = f"{b.ns}/motec_bridge".strip("/").replace("/", ".")
            line = client.wait_log(owner, "the polls of its 3 devices need")
            match = re.search(r"need (\d+)% of the line; .* carries about (.*) Hz", line.msg)
            assert match is not None, line.msg
            assert int(match.group(1)) > 100
            carried = [float(rate) for rate in match.group(2).split(", ")]
            assert len(carried) == 3 and all(0 < rate < 6.0 for rate in carried)
            status = b.wait_diagnostic(
                1, lambda s: values_of(s).get("line load, all devices (%)", "n/a") != "n/a"
            )
            values = values_of(status)
            assert float(values["line load, all devices (%)"]) > 100
            assert float(values["wire load (%)"]) < float(values["line load, all devices (%)"])
            # Once: three more statuses of drive 1 (the owner judged meanwhile) and one line.
            since = time.monotonic()
            wait_for(
                lambda: (
                    sum(
                        s.name.startswith(f"{b.ns}/motec_1: ")
                        for a in client.received("/diagnostics", since)
                        for s in a.status
                    )
                    >= 3
                ),
                WAIT_S,
                "3 statuses of drive 1",
            )
            said = [m for m in client.received("/rosout") if "devices need" in m.msg]
            assert len(said) == 1, [m.msg for m in said]
            assert proc.poll() is None
