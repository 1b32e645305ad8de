"""Faults on the RS-485 line: the stepper node survives, reports and recovers.

The line is bridge <-> socat pty pair A <-> a relay in this process <-> socat pty pair B
<-> the simulator. The relay passes requests through and, on demand, corrupts the CRC of
replies or rewrites their unit id (with a valid CRC); pair A can be unplugged (socat
killed, the bridge's tty vanishes) and plugged back at the same path; the simulator can
withhold its replies.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from pymodbus.framer import FramerRTU
from std_srvs.srv import Trigger

from bridge_core.sim.pty_pair import end_socat
from msg_defs.msg import StepperState
from stepper_bridge.sim import StepperSimDevice, make_simulator

from ..support.fixtures import client_fixture
from ..support.ros import WAIT_S, Bridge, Client, start_bridge, values_of, wait_for
from ..support.serial_pair import socat_pair

pytestmark = pytest.mark.ros

BAUD = 115200
FRAME_GAP_S = 0.003  # end of a reply on the relay's side (ptys deliver a frame at once)
WRONG_UNIT = 7
# Far above what scheduling on a loaded machine can delay a reply by: only the faults this
# test makes may look like a dead device.
TIMEOUT_S = 1.0


def start_socat(a: Path, b: Path) -> subprocess.Popen[bytes]:
    socat = shutil.which("socat")
    assert socat is not None, "socat is missing"
    for path in (a, b):
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
    proc = subprocess.Popen(
        [socat, f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for(lambda: a.exists() and b.exists(), 10, "socat's pty links")
    return proc


class Relay:
    """Copies bytes between two ptys; replies (device -> bridge) may be altered."""

    def __init__(self, bridge_side: Path, device_side: str) -> None:
        self.bridge_side = bridge_side
        self.device_side = device_side
        self.mode = "pass"  # "pass", "corrupt" (flip the CRC), "unit" (reply as unit 7)
        self.replies = 0
        self._stop = threading.Event()
        self._a: int | None = None
        self._b = os.open(device_side, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _open_a(self) -> None:
        try:
            self._a = os.open(self.bridge_side, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            self._a = None

    def _drop_a(self) -> None:
        if self._a is not None:
            with contextlib.suppress(OSError):
                os.close(self._a)
        self._a = None

    def _alter(self, frame: bytes) -> bytes:
        if self.mode == "corrupt":
            return frame[:-1] + bytes([frame[-1] ^ 0xFF])
        if self.mode == "unit":
            body = bytes([WRONG_UNIT]) + frame[1:-2]
            return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")
        return frame

    def _run(self) -> None:
        reply = b""
        while not self._stop.is_set():
            if self._a is None:
                self._open_a()
                if self._a is None:
                    time.sleep(0.02)
                    continue
            fds = [self._a, self._b]
            ready, _, _ = select.select(fds, [], [], FRAME_GAP_S)
            if self._a in ready:
                try:
                    data = os.read(self._a, 512)
                except OSError:
                    data = b""
                if not data:  # pair A unplugged
                    self._drop_a()
                    continue
                os.write(self._b, data)
            if self._b in ready:
                reply += os.read(self._b, 512)
            elif reply:  # silence after a reply: pass the whole frame on
                self.replies += 1
                with contextlib.suppress(OSError):
                    os.write(self._a, self._alter(reply))
                reply = b""

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self._drop_a()
        os.close(self._b)


client = client_fixture("stepper_fault_client", diagnostics=True, scope="module")


def status_after(b: Bridge, since: float, level: int, **expect: Any) -> Any:
    """The first diagnostic status at ``level`` since ``since`` matching ``expect``."""

    def find() -> Any:
        for status in b.diagnostics(since):
            values = values_of(status)
            if status.level == bytes([level]) and all(check(values) for check in expect.values()):
                return status
        return None

    return wait_for(find, WAIT_S, f"diagnostics level {level}")


def test_line_faults(client: Client, tmp_path: Path) -> None:
    simulator = make_simulator(reply_delay_s=0.0)
    device = simulator.device
    assert isinstance(device, StepperSimDevice)
    bridge_link, relay_link = tmp_path / "bridge", tmp_path / "relay"
    pair_a = start_socat(bridge_link, relay_link)
    params = {
        "serial_port": str(bridge_link),
        "baudrate": BAUD,
        "poll_rate_hz": 20.0,
        "timeout_s": TIMEOUT_S,
        "reconnect_max_s": 1.0,
    }
    with socat_pair() as (relay_end, device_end, _):
        simulator.start_serial(device_end, BAUD)
        relay = Relay(relay_link, relay_end)
        try:
            with start_bridge(
                client, tmp_path, "stepper_bridge.node", "stepper_bridge", StepperState, params
            ) as (b, node):

                def down_then_up(fault: str, since: float, **expect: Any) -> Any:
                    b.wait_connected(False, since=since)
                    status = status_after(b, since, 2, **expect)
                    assert values_of(status)["link state"] == "disconnected", fault
                    # A command while down is refused and never executed later.
                    reply = b.call(Trigger, "motor_1/forward")
                    assert not reply.success and "not connected" in reply.message, fault
                    return status

                def restored(since: float) -> None:
                    client.wait_message(b.joint_states, since=since)
                    b.wait_connected(True, since=since)
                    status_after(b, since, 0)

                client.wait_message(b.joint_states)
                b.wait_connected(True)

                # 1. The device stops answering.
                t = time.monotonic()
                device_sim = simulator
                device_sim.withhold_replies = True
                down_then_up("withheld", t, timeouts=lambda v: int(v["timeouts"]) > 0)
                t = time.monotonic()
                device_sim.withhold_replies = False
                restored(t)

                # 2. CRC-corrupted replies.
                t = time.monotonic()
                relay.mode = "corrupt"
                status = down_then_up(
                    "corrupt", t, frames=lambda v: int(v["CRC / frame errors"]) > 0
                )
                assert "CRC" in values_of(status)["last error"]
                t = time.monotonic()
                relay.mode = "pass"
                restored(t)

                # 3. Replies from the wrong unit id (valid CRC).
                frames_before = int(values_of(b.diagnostics()[-1])["CRC / frame errors"])
                t = time.monotonic()
                relay.mode = "unit"
                # While down, the bridge probes with the short stop timeout: on a loaded
                # host a probe may time out before the relayed reply comes, and that
                # timeout becomes the last error; a status naming the wrong unit must come.
                down_then_up(
                    "unit",
                    t,
                    frames=lambda v: int(v["CRC / frame errors"]) > frames_before,
                )
                status_after(
                    b,
                    t,
                    2,
                    unit=lambda v: f"device id {WRONG_UNIT}" in v["last error"],
                )
                t = time.monotonic()
                relay.mode = "pass"
                restored(t)

                # 4. The bridge's serial port vanishes (pty closed) and comes back.
                failed = int(values_of(b.diagnostics()[-1])["failed connects"])
                t = time.monotonic()
                end_socat(pair_a)
                down_then_up("unplugged", t)
                # It stays down a while: two reconnect attempts fail.
                status_after(b, t, 2, connects=lambda v: int(v["failed connects"]) >= failed + 2)
                assert node.poll() is None
                t = time.monotonic()
                pair_a = start_socat(bridge_link, relay_link)
                restored(t)
                status = status_after(b, t, 0, reconnects=lambda v: int(v["reconnects"]) >= 4)
                assert device.write_log == []  # no refused command ran after a reconnect
                # And the link works for commands again.
                assert b.call(Trigger, "motor_1/stop").success
                assert len(device.write_log) == 1
        finally:
            relay.close()
            simulator.stop()
            end_socat(pair_a)
