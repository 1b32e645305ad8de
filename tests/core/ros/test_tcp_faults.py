"""Faults every TCP bridge survives: its simulator killed mid-poll and restarted.

Runs the simulator as its own process (killed with SIGKILL, restarted on the same port,
writes logged to a file) and the bridge node as another; the rclpy client is this process.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from std_srvs.srv import Trigger

from bridge_core.ros.node_base import LINK_DOWN_LOG_PERIOD_S
from bridge_core.sim.logs import read_write_log
from bridge_core.wire.ports import free_port
from msg_defs.msg import R6State, XArmState

from ...support.fixtures import client_fixture
from ...support.ros import (
    ROOT,
    Client,
    node_process,
    start_bridge,
    unique_namespace,
    values_of,
    wait_for,
)

WARN, INFO = 30, 20  # rcl_interfaces/msg/Log levels

pytestmark = pytest.mark.ros

DEVICES = [
    pytest.param("r6_bridge", R6State, "start", ["--running"], id="r6"),
    pytest.param("xarm_bridge", XArmState, "resume", [], id="xarm"),
]


client = client_fixture("fault_client", diagnostics=True, log=True, scope="module")


@pytest.mark.parametrize(("package", "state_type", "command", "sim_args"), DEVICES)
def test_simulator_killed_and_restarted(
    client: Client, tmp_path: Path, package: str, state_type: Any, command: str, sim_args: list[str]
) -> None:
    port = free_port()
    write_log = tmp_path / "writes.jsonl"

    def start_sim() -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                f"{package}.sim",
                "--port",
                str(port),
                "--write-log",
                str(write_log),
                *sim_args,
            ],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        assert proc.stdout is not None
        line = proc.stdout.readline().decode()
        assert "listening" in line, line
        return proc

    params = {
        "port": port,
        "poll_rate_hz": 50.0,
        "timeout_s": 1.0,  # far above a loaded machine's scheduling delays
        "reconnect_max_s": 1.0,
    }
    sim_proc = start_sim()
    try:
        with start_bridge(client, tmp_path, f"{package}.node", package, state_type, params) as (
            bridge,
            node,
        ):
            client.wait_message(bridge.joint_states)
            bridge.wait_connected(True)
            killed = time.monotonic()  # before the kill: the node may notice at once
            sim_proc.send_signal(signal.SIGKILL)  # mid-poll: the node polls at 50 Hz
            sim_proc.wait(5)
            bridge.wait_connected(False, since=killed)
            status = bridge.wait_diagnostic(2, killed, port)
            assert values_of(status)["link state"] == "disconnected"
            down = time.monotonic()
            reply = client.call(Trigger, bridge.service(command), Trigger.Request())
            assert not reply.success and "not connected" in reply.message
            # Stay down a while (two reconnect attempts fail): no joint_states or state
            # with fresh stamps may appear meanwhile.
            failed = int(values_of(status)["failed connects"])
            bridge.wait_diagnostic(
                2, down, port, where=lambda v: int(v["failed connects"]) >= failed + 2
            )
            assert client.received(bridge.joint_states, since=down) == []
            assert client.received(bridge.state, since=down) == []
            assert node.poll() is None
            restarted = time.monotonic()
            sim_proc = start_sim()
            client.wait_message(bridge.joint_states, since=restarted)
            bridge.wait_connected(True, since=restarted)
            status = bridge.wait_diagnostic(0, restarted, port)
            assert int(values_of(status)["reconnects"]) >= 1
            # The refused command was not executed after the reconnect.
            assert read_write_log(write_log) == []
    finally:
        sim_proc.kill()
        sim_proc.wait(5)


def test_a_device_never_reached_is_said_on_the_console(client: Client, tmp_path: Path) -> None:
    """A bridge that cannot reach its device says so at once (WARN, with the OS
    reason), again at most every 10 s while it lasts, and INFO once it is up."""
    port = free_port()  # nothing listens there yet
    where = f"tcp://127.0.0.1:{port} unit 1"
    params = {"port": port, "timeout_s": 1.0, "reconnect_max_s": 0.5}
    started = time.monotonic()
    namespace = unique_namespace("unreachable")
    with node_process("r6_bridge.node", params, tmp_path, ["-r", f"__ns:={namespace}"]) as node:
        line = client.wait_log("r6_bridge", f"cannot reach {where}", since=started)
        assert line.level == WARN and "connection refused" in line.msg, line.msg
        still = client.wait_log("r6_bridge", f"{where} still down", since=started, timeout=60)
        assert still.level == WARN and "connection refused" in still.msg, still.msg

        def stamp(log: Any) -> float:
            return float(log.stamp.sec + log.stamp.nanosec * 1e-9)

        # Not on the first retry: a period after the line that said it went down.
        assert stamp(still) - stamp(line) >= LINK_DOWN_LOG_PERIOD_S - 0.05

        def failed_connects() -> int:
            for array in reversed(client.received("/diagnostics", started)):
                for status in array.status:
                    if status.hardware_id.endswith(where):
                        return int(values_of(status)["failed connects"])
            return 0

        wait_for(lambda: failed_connects() >= 6, 60, "six failed connects")
        elapsed = time.monotonic() - started
        repeats = [m for m in client.received("/rosout", started) if f"{where} still down" in m.msg]
        assert len(repeats) <= elapsed // LINK_DOWN_LOG_PERIOD_S, [m.msg for m in repeats]
        up = time.monotonic()
        sim = subprocess.Popen(
            [sys.executable, "-m", "r6_bridge.sim", "--port", str(port)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        try:
            line = client.wait_log("r6_bridge", f"connected to {where}", since=up)
            assert line.level == INFO
            assert node.poll() is None
        finally:
            sim.kill()
            sim.wait(5)
