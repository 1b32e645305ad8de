"""The xArm description (config/devices/xarm.yaml) against the xArm's own simulator: the
generic bridge gives the same joint_states positions and velocities as xarm_bridge."""

from __future__ import annotations

import random
from collections.abc import Iterator
from pathlib import Path

import pytest
from sensor_msgs.msg import JointState

from bridge_core.runtime.units import DEG
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, TcpSettings
from modbus_bridge.description import load
from modbus_bridge.device import DescribedDevice
from msg_defs.msg import DeviceValues, XArmState
from xarm_bridge.device import XArmDevice
from xarm_bridge.sim import XArmSimDevice, make_simulator

from ..support.ros import ros_client, start_bridge

ROOT = Path(__file__).resolve().parents[2]
XARM_FILE = ROOT / "config" / "devices" / "xarm.yaml"
TOLERANCE = 1e-9


@pytest.fixture
def xarm_sim() -> Iterator[tuple[XArmSimDevice, int]]:
    simulator = make_simulator()
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, XArmSimDevice)
    device.tick = lambda dt: None  # type: ignore[method-assign]  # frozen: both read alike
    yield device, port
    simulator.stop()


def test_device_layers_agree_on_random_joints(xarm_sim: tuple[XArmSimDevice, int]) -> None:
    sim, port = xarm_sim
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=2.0))
    try:
        channel = DeviceChannel(link, 1, retries=0)
        theirs = XArmDevice(channel)
        ours = DescribedDevice(channel, load(XARM_FILE).device)
        rng = random.Random(13)
        for _ in range(20):
            for j in range(1, 8):
                sim.set(f"joint_angle_{j}", rng.randint(-32768, 32767) / 10)
                sim.set(f"joint_speed_{j}", rng.randint(-32768, 32767) / 10)
            expected = theirs.poll()
            got = ours.poll()
            positions = [a * DEG for a in expected.joint_angles_deg]
            velocities = [v * DEG for v in expected.joint_speeds_deg_s]
            assert got.positions == pytest.approx(positions, abs=TOLERANCE, rel=0)
            assert got.velocities == pytest.approx(velocities, abs=TOLERANCE, rel=0)
        # The poll reads what xarm_bridge reads, and writes nothing.
        assert sim.write_log == []
    finally:
        link.close()


@pytest.mark.ros
def test_joint_states_equal_xarm_bridges(
    xarm_sim: tuple[XArmSimDevice, int], tmp_path: Path
) -> None:
    sim, port = xarm_sim
    for j in range(1, 8):
        sim.set(f"joint_angle_{j}", -170.0 + 45.3 * j)
        sim.set(f"joint_speed_{j}", 12.7 * j - 50.0)
    common = {"port": port, "poll_rate_hz": 20.0, "timeout_s": 1.0}
    with (
        ros_client("xarm_compare_client") as client,
        start_bridge(client, tmp_path, "xarm_bridge.node", "xarm_bridge", XArmState, common) as (
            theirs,
            _,
        ),
        start_bridge(
            client,
            tmp_path,
            "modbus_bridge.node",
            "modbus_bridge",
            DeviceValues,
            {**common, "device_file": str(XARM_FILE)},
        ) as (ours, _),
    ):
        expected: JointState = client.wait_message(theirs.joint_states)
        got: JointState = client.wait_message(ours.joint_states)
        assert list(got.name) == list(expected.name)
        assert list(got.position) == pytest.approx(list(expected.position), abs=TOLERANCE, rel=0)
        assert list(got.velocity) == pytest.approx(list(expected.velocity), abs=TOLERANCE, rel=0)
        state = client.wait_message(ours.state)
        values = dict(zip(state.names, state.values, strict=True))
        assert values["joint_angle_3"] == pytest.approx(-170.0 + 45.3 * 3)
    assert not [r for r in sim.write_log if r.table is Table.HOLDING]
