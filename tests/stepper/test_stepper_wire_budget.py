"""The wire budget on the emulated byte-timed line ("a rate that the wire cannot
carry gives one WARN with the achievable rate"): the stepper node at the manual's 9600
baud with its 35 ms replies (bench/line_relay.py paces every byte at 10 bits / baud),
asked for more polls than the line carries."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter

from bench.line_relay import LineRelay
from msg_defs.msg import StepperState
from stepper_bridge.registers import REPLY_DELAY_S
from stepper_bridge.sim import make_simulator

from ..support.fixtures import client_fixture
from ..support.ros import WAIT_S, Client, start_bridge, values_of, wait_for

pytestmark = pytest.mark.ros

BAUD = 9600
ASKED_HZ = 20.0  # a fast poll is ~4 reads of ~45 ms each at 9600 with 35 ms replies
WITHIN_HZ = 0.5
# The line is slow by design (a poll of ~0.3 s, the configuration read whole first): the
# waits are longer than the suite's usual one.
SLOW_WAIT_S = 3 * WAIT_S
WARN = re.compile(r"poll_rate_hz (\S+) needs (\d+)% of the wire .* carries about ([\d.]+) Hz")


client = client_fixture("wire_budget_client", diagnostics=True, log=True)


def warnings(client: Client, node: str) -> list[re.Match[str]]:
    lines = [m.msg for m in client.received("/rosout") if node in m.name]
    return [match for line in lines if (match := WARN.search(line))]


def set_rate(client: Client, node: str, rate_hz: float) -> None:
    request = SetParameters.Request()
    request.parameters = [Parameter("poll_rate_hz", value=rate_hz).to_parameter_msg()]
    reply = client.call(SetParameters, f"{node}/set_parameters", request)
    assert reply.results[0].successful, reply.results[0].reason


def test_a_rate_the_line_cannot_carry_is_said_once_with_the_rate_it_carries(
    client: Client, tmp_path: Path
) -> None:
    simulator = make_simulator(1, reply_delay_s=REPLY_DELAY_S)
    with LineRelay(BAUD) as line:
        simulator.start_serial(line.device_path, BAUD)
        try:
            params: dict[str, Any] = {
                "serial_port": line.client_path,
                "baudrate": BAUD,
                "poll_rate_hz": ASKED_HZ,
                "timeout_s": 1.0,
                # 1 s statuses: "three more statuses" below is a window of ~3 s for a
                # second WARN to show.
                "diagnostic_period_s": 1.0,
            }
            with start_bridge(
                client, tmp_path, "stepper_bridge.node", "stepper_bridge", StepperState, params
            ) as (bridge, _proc):
                node = f"{bridge.ns}/stepper_bridge"
                logger = node.strip("/").replace("/", ".")
                first = wait_for(lambda: warnings(client, logger), SLOW_WAIT_S, "the budget WARN")[
                    0
                ]
                assert float(first.group(1)) == ASKED_HZ and int(first.group(2)) > 100
                carried = float(first.group(3))
                assert 0.0 < carried < ASKED_HZ
                # The diagnostics agree, and show the measured reply delay (35 ms, the
                # simulator's, at least).
                since = time.monotonic()

                def budget_status() -> Any:
                    for status in reversed(bridge.diagnostics(since)):
                        values = values_of(status)
                        if values.get("wire load (%)", "n/a") != "n/a":
                            return values
                    return None

                values = wait_for(budget_status, SLOW_WAIT_S, "diagnostics with the budget")
                assert float(values["wire load (%)"]) > 100
                assert float(values["reply delay (ms)"]) >= REPLY_DELAY_S * 1e3
                assert 0.0 < float(values["achievable poll rate (Hz)"]) < ASKED_HZ
                # Once: three more statuses (polls went on meanwhile) and still one line.
                wait_for(lambda: len(bridge.diagnostics(since)) >= 3, WAIT_S, "3 statuses")
                assert len(warnings(client, logger)) == 1
                # A change of the rate judges the budget again (a rate within it is not
                # said: tests/core/runtime/test_wire_budget.py).
                set_rate(client, node, WITHIN_HZ)
                set_rate(client, node, ASKED_HZ * 2)
                second = wait_for(
                    lambda: warnings(client, logger)[1:], SLOW_WAIT_S, "a WARN after the change"
                )[0]
                assert float(second.group(1)) == ASKED_HZ * 2
        finally:
            simulator.stop()
