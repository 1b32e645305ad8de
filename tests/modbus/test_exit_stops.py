"""What modbus_bridge starts with a ``starts_motion`` trigger, it stops on every
way out, and a keepalive stops the device when the bridge is gone.

The VFD example (config/devices/vfd_rtu.yaml, RTU 8E1 on a pty: parity end to end) runs
forward from ``~/run_forward``; then SIGINT, SIGTERM, deactivate or a fatal error must put
exactly its stop trigger's write on the wire (the simulator's write log, the keepalive's
counter writes aside). A silent line still gets the stop on the wire (the silent simulator
hears it; the node says it failed for want of a reply); ``kill -9`` leaves the drive to
its watchdog, which the simulator models and times (it trips within its period).
A signal's exit prints no ERROR, traceback or uncollected callback error.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from std_srvs.srv import Trigger

from bridge_core.sim.serving import Simulator
from bridge_core.wire.registers import Table
from modbus_bridge.description import load
from modbus_bridge.sim import DescribedSimDevice, make_simulator
from msg_defs.msg import DeviceValues
from msg_defs.srv import SetValue, WriteRegister

from ..support.fixtures import client_fixture
from ..support.ros import (
    Bridge,
    Client,
    exit_complaints,
    node_log,
    node_process,
    refused_at_start,
    unique_namespace,
    wait_for,
)
from ..support.serial_pair import socat_pair

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[2]
VFD = ROOT / "config" / "devices" / "vfd_rtu.yaml"
SIM_IN_TEST_TIMEOUT_S = 1.0
VFD_MAP = load(VFD).device.register_map
BAUD = 19200  # the file's, with its parity E
WAIT_S = 30.0
EXIT_TIMEOUT_S = 20.0
CONTROL_WORD = VFD_MAP["control_word"].address
WATCHDOG = VFD_MAP["comm_watchdog"].address
STOP_WRITE = (6, Table.HOLDING, CONTROL_WORD, (5,))
KEEPALIVE = load(VFD).device.keepalive
assert KEEPALIVE is not None
KEEPALIVE_PERIOD_S = KEEPALIVE.period_s


client = client_fixture("modbus_exit_client", scope="module")


@contextmanager
def vfd_on_pty() -> Iterator[tuple[Simulator, DescribedSimDevice, str]]:
    """The VFD example served at 8E1 on the device end of a fresh pty pair."""
    simulator = make_simulator(load(VFD))
    device = simulator.device
    assert isinstance(device, DescribedSimDevice)
    with socat_pair() as (bridge_end, device_end, _):
        simulator.start_serial(device_end, BAUD, "E", 1)
        try:
            yield simulator, device, bridge_end
        finally:
            simulator.stop()


def commands(device: DescribedSimDevice, since: int = 0) -> list[tuple[Any, ...]]:
    """The writes after ``since`` that are not the keepalive's feeds."""
    return [
        (r.function_code, r.table, r.address, r.values)
        for r in device.write_log[since:]
        if r.address != WATCHDOG
    ]


@contextmanager
def running_forward(
    client: Client, tmp_path: Path, module: str = "modbus_bridge.node"
) -> Iterator[tuple[Bridge, Any, Simulator, DescribedSimDevice]]:
    """The bridge in its own process, connected, its keepalive armed, the drive running
    forward at 10 Hz (started by ``~/run_forward``)."""
    with vfd_on_pty() as (simulator, device, port):
        params = {
            "device_file": str(VFD),
            "serial_port": port,
            "poll_rate_hz": 20.0,
            "reconnect_max_s": 1.0,
            # The simulator answers from this test process, beside the client's spin thread
            # and other busy processes: at the example's 0.2 s its late replies cost the
            # link on loaded runs of the suite ("no reply within 0.2 s" at set_frequency).
            "timeout_s": SIM_IN_TEST_TIMEOUT_S,
        }
        b = Bridge(client, unique_namespace("vfd_exit"), "modbus_bridge", DeviceValues)
        with node_process(module, params, tmp_path, ["-r", f"__ns:={b.ns}"]) as proc:
            b.wait_connected(True, timeout=WAIT_S)
            wait_for(lambda: device.writes_to(WATCHDOG), WAIT_S, "the keepalive armed")
            # Preconditions: asked again if a stalled pty cost the link just before.
            reply = b.call_sent(SetValue, "set_frequency", value=10.0)
            assert reply.success, reply.message
            reply = b.call_sent(Trigger, "run_forward")
            assert reply.success, reply.message
            assert device.get("control_word") == 1
            yield b, proc, simulator, device


@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM], ids=["int", "term"])
def test_a_signal_sends_the_stop_of_a_started_motion(
    client: Client, tmp_path: Path, signal_number: int
) -> None:
    with running_forward(client, tmp_path) as (_, proc, _, device):
        before = len(device.write_log)
        log = node_log(tmp_path, "modbus_bridge.node")
        since = log.stat().st_size
        proc.send_signal(signal_number)
        assert proc.wait(EXIT_TIMEOUT_S) == 0
        assert commands(device, before) == [STOP_WRITE]
        assert device.get("control_word") == 5
        assert exit_complaints(log, since) == []


def test_deactivate_sends_the_stop_once(client: Client, tmp_path: Path) -> None:
    with running_forward(client, tmp_path) as (b, proc, _, device):
        before = len(device.write_log)
        request = ChangeState.Request()
        request.transition.id = Transition.TRANSITION_DEACTIVATE
        reply = client.call(ChangeState, f"{b.ns}/modbus_bridge/change_state", request)
        assert reply.success
        assert commands(device, before) == [STOP_WRITE]  # done before the reply
        log = node_log(tmp_path, "modbus_bridge.node")
        since = log.stat().st_size
        proc.send_signal(signal.SIGINT)
        assert proc.wait(EXIT_TIMEOUT_S) == 0
        assert commands(device, before) == [STOP_WRITE]  # stopped since: not sent again
        assert exit_complaints(log, since) == []


def test_a_fatal_error_sends_the_stop(client: Client, tmp_path: Path) -> None:
    with running_forward(client, tmp_path, "tests.modbus.fatal_modbus") as (_, proc, _, device):
        # From the start's write on (keepalive feeds may have come after it).
        before = max(
            i
            for i, r in enumerate(device.write_log)
            if r.address == CONTROL_WORD and r.values == (1,)
        )
        assert proc.wait(EXIT_TIMEOUT_S) == 1  # EXIT_FATAL_ERROR
        assert commands(device, before) == [(6, Table.HOLDING, CONTROL_WORD, (1,)), STOP_WRITE]


def test_a_silent_line_still_gets_the_stop_tried(client: Client, tmp_path: Path) -> None:
    """The link is marked down (the device hears but never answers): the exit's stop still
    goes out on the wire (the silent simulator received its frame) and fails for want of
    a reply, not for not being sent."""
    with running_forward(client, tmp_path) as (b, proc, simulator, _):
        cut = time.monotonic()
        simulator.withhold_replies = True
        b.wait_connected(False, since=cut, timeout=WAIT_S)
        before = len(simulator.withheld_writes)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(EXIT_TIMEOUT_S) == 0

        def heard() -> list[tuple[int, Table, int, tuple[int, ...]]]:
            return [
                (r.function_code, r.table, r.address, r.values)
                for r in simulator.withheld_writes[before:]
                if r.address != WATCHDOG
            ]

        # The bridge may exit (its reply timeout over) before the simulator's thread has
        # taken the frame off a stalled pty: wait for it, then nothing else may be there.
        wait_for(lambda: heard() != [], WAIT_S, "the exit's stop on the silent line")
        assert heard() == [STOP_WRITE]
        log = (tmp_path / "modbus_bridge_node.log").read_text()
        failed = "run_forward: its stop failed (the node is exiting): unit 1: no reply within"
        assert failed in log, log


def test_kill_9_leaves_the_drive_to_its_keepalive_watchdog(client: Client, tmp_path: Path) -> None:
    """The drive stops itself within its keepalive period of the bridge's last feed, by
    the simulator's own records (its last feed and its trip; the margin is the one tick
    that found the trip, as the simulator timed it), not by the test's clock."""
    with running_forward(client, tmp_path) as (_, proc, _, device):
        wait_for(lambda: device.velocities_si["motor"] > 1.0, WAIT_S, "the motor turning")
        before = len(device.write_log)
        assert device.keepalive_trips == 0
        proc.kill()
        proc.wait(EXIT_TIMEOUT_S)
        wait_for(lambda: device.keepalive_trips == 1, WAIT_S, "the watchdog (period_s 2 s)")
        (trip,) = device.keepalive_trip_log
        assert trip.period_s == KEEPALIVE_PERIOD_S
        silent_s = trip.tripped_at - trip.fed_at  # from the last feed to the stop
        assert trip.period_s < silent_s <= trip.period_s + trip.tick_s, trip
        assert commands(device, before) == []  # nothing came from the killed bridge
        assert device.get("control_word") == 5  # the drive stopped itself
        wait_for(lambda: device.velocities_si["motor"] < 0.01, WAIT_S, "the ramp down")


def test_a_rounded_write_answers_what_was_written(client: Client, tmp_path: Path) -> None:
    """``~/write accel_time 12.34`` on a 0.1 s register."""
    with running_forward(client, tmp_path) as (b, _, _, device):
        request = WriteRegister.Request(name="accel_time", value=12.34)
        reply = client.call(WriteRegister, b.service("write"), request)
        rounded = "accel_time = 12.3 s written (12.34 rounded to the register's 0.1 s)"
        assert reply.success and reply.message == f"{rounded}: done", reply.message
        reply = b.call(SetValue, "set_accel_time", value=12.34)
        assert reply.success and reply.message == f"{rounded}: done", reply.message
        assert device.get("accel_time") == pytest.approx(12.3)


def test_a_keepalive_period_below_the_links_floor_refuses_to_start() -> None:
    """2 s with a 2 s reply timeout: a feed may wait out a whole transaction, so the floor
    (1.5 x (0.1 s + the longest transaction)) is above the watchdog time."""
    args = ["--ros-args", "-p", f"device_file:={VFD}", "-p", "timeout_s:=2.0"]
    line = refused_at_start("modbus_bridge.node", args)
    assert "keepalive period_s 2.0 s is below" in line, line
