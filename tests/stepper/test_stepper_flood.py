"""Jog floods on the stepper: the bridge in its own process, the simulator
in another (on a socat pty pair, its writes and reads logged to files), an rclpy client in
this process publishing the flood. The simulator has a process of its own so that the flood
this process publishes cannot slow the device down: what is measured is the bridge.

A jog stream keeps only its newest value, writes at most ``command_rate_hz`` speeds a
second, costs the polls no link, and its deadman stop counts from the last message's
arrival. Bounds here are on counts and on the simulator's clock, never an upper
wall-clock bound (bench/stop_after_outage.py and bench/stream_flood.py measure those).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

import pytest
from std_msgs.msg import Float64

from bridge_core.sim.logs import WriteRecord
from bridge_core.wire.registers import Table
from msg_defs.msg import StepperState
from stepper_bridge.interface import JOG_WRITE_RATE_HZ
from stepper_bridge.registers import STEPPER_MAP, motor_coil, motor_register
from stepper_bridge.sim import StepperSimDevice

from ..support.bridges import BRIDGES, SimProcess
from ..support.fixtures import client_fixture
from ..support.ros import (
    WAIT_S,
    Bridge,
    Client,
    start_bridge,
    wait_for,
    wait_subscribed,
)

pytestmark = pytest.mark.ros

# Reply timeout far above any scheduling delay, so that a live device never looks dead: with
# two CPU burners beside a flood, the simulator handled no request for 1-2 s in some runs,
# and at 1.0 s (the other stepper tests' value) the bridge lost its link to it.
TIMEOUT_S = 5.0
COMMAND_TIMEOUT_S = 1.5  # jog deadman, far above a flood's gaps between messages
POLL_RATE_HZ = 20.0
# Longer than the deadman: one counted from the flood's first message stops it mid-flood.
FLOOD_S = 2.0
FLOOD_PERIOD_S = 0.001  # ~1000 msg/s
# What counts as a flood: 20 times the write rate at least. Paced at ~1000 msg/s, but the
# sending thread's speed is the machine's: beside two CPU burners it sent 197 in a second.
FLOOD_MIN_HZ = 20 * JOG_WRITE_RATE_HZ
SLACK_S = 1.0  # the newest value waits up to 1 / rate after the flood, plus scheduling
# Each motor's speed register before a jog (the simulator's default): never a flood value.
CONFIGURED_RPM = int(StepperSimDevice().get(motor_register(1, "speed")))
FLOOD_FIRST_RPM = 100  # varying flood: 100, 101, 102, ... rpm (never 0, never repeated)
CONSTANT_RPM = 600
# Far beyond any jog here: the motor never reaches its limit switch, so "not running"
# after the stop is the stop's doing.
TRAVEL = 1_000_000.0
RATE_HZ = JOG_WRITE_RATE_HZ  # the node's default command_rate_hz, not overridden below
# Polls stamped between the flood's first message and the stop (3.5 s, 70 at 20 Hz). Not
# counted over the flood alone: with two CPU burners beside the test, polls inside the
# 2 s flood fell to 1-5 in some runs (one transaction waited out the 1 s reply timeout),
# while a poller starved or stopped by the flood has none until after the stop.
MIN_POLLS_FLOOD_AND_DEADMAN = 5
POLLS_AFTER_STOP = 5
QUIET_AFTER_STOP_S = 0.5  # five deadman periods (0.1 s) during which nothing may follow
H, C = Table.HOLDING, Table.COIL

Write = tuple[int, Table, int, tuple[int, ...]]


client = client_fixture("stepper_flood_client", diagnostics=True, log=True, scope="module")


@pytest.fixture
def sim(tmp_path: Path) -> Iterator[SimProcess]:
    """The stepper simulator in its own process: no reply delay, TRAVEL to the limits."""
    info = next(entry for entry in BRIDGES if entry.key == "stepper")
    process = SimProcess(info, tmp_path / "sim")
    process.extra_args = ("--reply-delay-ms", "0", "--travel", str(TRAVEL))
    process.start()
    try:
        yield process
    finally:
        process.stop()


def bridge(
    client: Client, tmp_path: Path, sim: SimProcess
) -> AbstractContextManager[tuple[Bridge, Any]]:
    """The node with the stepper tests' settings and its default command_rate_hz."""
    return start_bridge(
        client,
        tmp_path,
        "stepper_bridge.node",
        "stepper_bridge",
        StepperState,
        {
            **sim.address_params(),
            "poll_rate_hz": POLL_RATE_HZ,
            "timeout_s": TIMEOUT_S,
            "reconnect_max_s": 1.0,
            "command_timeout_s": COMMAND_TIMEOUT_S,
        },
    )


def as_write(record: WriteRecord) -> Write:
    return (record.function_code, record.table, record.address, record.values)


def speed_write(motor: int, rpm: int) -> Write:
    return (6, H, STEPPER_MAP[motor_register(motor, "speed")].address, (rpm,))


def coil_write(motor: int, action: str) -> Write:
    return (5, C, motor_coil(motor, action), (1,))


def is_speed_write(write: Write, motor: int) -> bool:
    return write[:3] == speed_write(motor, 0)[:3]


def stamp_s(msg: Any) -> float:
    """A message's header stamp (the poll's wall-clock read time) in seconds."""
    return float(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)


def flood(
    publisher: Any, value: Callable[[int], float], seconds: float
) -> tuple[int, float, float]:
    """Publish ``value(n)`` every FLOOD_PERIOD_S for ``seconds`` (the sleep only paces the
    flood); returns the count and the wall-clock times of the first and last send (each
    taken just before its publish: the bridge may have the message before this thread
    runs again, so only that stamp bounds the arrival from below)."""
    sent, first, last = 0, time.time(), 0.0
    started = time.monotonic()
    while time.monotonic() < started + seconds:
        last = time.time()
        publisher.publish(Float64(data=value(sent)))
        sent += 1
        time.sleep(max(0.0, started + sent * FLOOD_PERIOD_S - time.monotonic()))
    return sent, first, last


def stop_index(sim: SimProcess, before: int, motor: int) -> int:
    """Waits for the motor's stop coil among the writes from ``before`` on; its index."""
    stop = coil_write(motor, "stop")
    return int(
        wait_for(
            lambda: next(
                (i for i, r in enumerate(sim.writes()) if i >= before and as_write(r) == stop),
                None,
            ),
            WAIT_S,
            f"motor {motor}'s stop coil",
        )
    )


def wait_quiet_after(client: Client, b: Bridge, stop_time: float) -> list[Any]:
    """Until POLLS_AFTER_STOP polls began after the stop and one came QUIET_AFTER_STOP_S
    after it (a write that follows a stop comes within a deadman period or two); returns
    the states polled after the stop."""

    def after() -> list[Any]:
        return [m for m in client.received(b.state) if stamp_s(m) > stop_time]

    wait_for(
        lambda: (
            len(after()) >= POLLS_AFTER_STOP
            and stamp_s(after()[-1]) > stop_time + QUIET_AFTER_STOP_S
        ),
        WAIT_S,
        "polls after the stop",
    )
    return after()


def check_nothing_after_stop(after: list[Write], motor: int) -> None:
    """Nothing may follow the stop coil but, once, the motor's configured speed written
    back to its speed register (not motion: the speed only applies to the next run)."""
    assert after in ([], [speed_write(motor, CONFIGURED_RPM)]), after


def test_a_varying_jog_flood_is_rate_limited_and_stopped_after_its_last_message(
    sim: SimProcess, client: Client, tmp_path: Path
) -> None:
    """~1000 msg/s of never-repeating jog values on motor 1 write at most
    ``command_rate_hz`` speeds a second, the newest value last; the deadman's stop comes
    command_timeout_s after the last message's arrival and nothing moves the motor after
    it; the bridge keeps its link and keeps polling meanwhile."""
    motor = 1
    with bridge(client, tmp_path, sim) as (b, proc):
        b.wait_connected(True)
        client.wait_message(b.state)
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_{motor}/jog", 10)
        wait_subscribed(jog)
        start = time.monotonic()
        before = len(sim.writes())
        sent, first, last = flood(jog, lambda n: float(FLOOD_FIRST_RPM + n), FLOOD_S)
        assert sent > FLOOD_S * FLOOD_MIN_HZ, f"not a flood: {sent} messages in {FLOOD_S} s"
        last_rpm = FLOOD_FIRST_RPM + sent - 1

        index = stop_index(sim, before, motor)
        records = sim.writes()
        stop = records[index]
        # (b) The deadman counted from the last message's arrival (no upper bound here).
        assert stop.time - last >= COMMAND_TIMEOUT_S * 0.9, stop.time - last
        during = [as_write(r) for r in records[before:index]]
        speed_records = [r for r in records[before:index] if is_speed_write(as_write(r), motor)]
        speeds = [r.values[0] for r in speed_records]
        # One forward coil (the jog's start); every other write is a speed.
        assert [w for w in during if not is_speed_write(w, motor)] == [
            coil_write(motor, "forward")
        ], during
        # (a) At most command_rate_hz speeds a second: over the flood and the newest
        # value's wait (behaviour.md's bound), and by the guard's own spacing: the n writes
        # need (n - 1) / rate s between the first message and the last write.
        assert 1 <= len(speeds) <= RATE_HZ * (last - first + SLACK_S) + 1, speeds
        assert len(speeds) - 1 <= RATE_HZ * (speed_records[-1].time - first) + 0.05, [
            round(r.time - first, 3) for r in speed_records
        ]
        # Newest wins: the values only grow, and the last one written is the last sent.
        assert speeds == sorted(set(speeds)) and speeds[-1] == last_rpm, (speeds, last_rpm)

        # (c) Nothing moves the motor after its stop.
        states = wait_quiet_after(client, b, stop.time)
        check_nothing_after_stop([as_write(r) for r in sim.writes()[index + 1 :]], motor)
        assert not any(m.running[motor - 1] for m in states)

        # (d) The link held and the polls went on: joint_states stamped (read) during the
        # flood, and over the flood and the deadman's wait (see MIN_POLLS_...); the polls
        # the simulator handled during the flood are in the message.
        assert all(m.data for m in client.received(b.connected, since=start))
        assert client.last(b.connected).data
        stamps = [stamp_s(m) for m in client.received(b.joint_states)]
        position = STEPPER_MAP[motor_register(1, "coordinate")]  # read once per poll
        handled = [
            round(r.time - first, 2)
            for r in sim.reads()
            if first <= r.time <= last and r.covers(position.table, position.address)
        ]
        assert any(first <= t <= last for t in stamps), handled
        polled = [t for t in stamps if first <= t <= stop.time]
        assert len(polled) >= MIN_POLLS_FLOOD_AND_DEADMAN, (len(polled), handled)
        client.node.destroy_publisher(jog)
        # (e) The bridge process is alive (start_bridge checks it again on the way out).
        assert proc.poll() is None


def test_a_constant_jog_flood_writes_one_speed_and_one_direction(
    sim: SimProcess, client: Client, tmp_path: Path
) -> None:
    """A repeated jog value is written once: however many messages, motor 2 gets its
    speed and its forward coil once, then the deadman's stop."""
    motor = 2
    with bridge(client, tmp_path, sim) as (b, proc):
        b.wait_connected(True)
        client.wait_message(b.state)
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_{motor}/jog", 10)
        wait_subscribed(jog)
        before = len(sim.writes())
        sent, _, _ = flood(jog, lambda _n: float(CONSTANT_RPM), 1.0)
        assert sent > FLOOD_MIN_HZ, f"not a flood: {sent} messages in 1 s"
        index = stop_index(sim, before, motor)
        states = wait_quiet_after(client, b, sim.writes()[index].time)
        writes = [as_write(r) for r in sim.writes()[before:]]
        assert writes[: index - before + 1] == [
            speed_write(motor, CONSTANT_RPM),
            coil_write(motor, "forward"),
            coil_write(motor, "stop"),
        ], writes
        check_nothing_after_stop(writes[index - before + 1 :], motor)
        assert not any(m.running[motor - 1] for m in states)
        client.node.destroy_publisher(jog)
        assert proc.poll() is None
