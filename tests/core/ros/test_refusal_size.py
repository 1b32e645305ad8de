"""A refusal of an oversized request names what it is and its size and never echoes its
values (a fault soak sent 30,000 indexes and got 300 KB reply messages back)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge_core.runtime.checks import MESSAGE_MAX_CHARS
from msg_defs.msg import XArmState
from msg_defs.srv import SetOutputs
from xarm_bridge.sim import XArmSimDevice, make_simulator

from ...support.ros import ros_client, start_bridge

pytestmark = pytest.mark.ros

VALUES = 30_000


def test_an_oversized_request_is_refused_by_its_size(tmp_path: Path) -> None:
    simulator = make_simulator(7)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, XArmSimDevice)
    try:
        with (
            ros_client("refusal_size_client") as client,
            start_bridge(
                client,
                tmp_path,
                "xarm_bridge.node",
                "xarm_bridge",
                XArmState,
                {"port": port, "timeout_s": 1.0},
            ) as (bridge, _proc),
        ):
            bridge.wait_connected(True, timeout=30)
            reply = bridge.call(
                SetOutputs,
                "set_digital_outputs",
                indexes=list(range(VALUES)),
                states=[True] * VALUES,
            )
    finally:
        simulator.stop()
    assert not reply.success
    assert len(reply.message) < MESSAGE_MAX_CHARS, len(reply.message)
    # What it is and its size, no value of it: not even the first index.
    assert reply.message == (
        f"set_digital_outputs ({VALUES} outputs) refused: {VALUES} indexes, at most 16"
    ), reply.message
    assert device.write_log == []
