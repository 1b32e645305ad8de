"""The three set-ups of ``~/joint_commands``, shared by
tests/core/ros/test_joint_commands.py and bench/joint_command_latency.py: a simulator process with
its writes logged, and its bridge in another process under a fresh namespace.

- the stepper as the issue asks: 9600 baud, replies no sooner than 35 ms;
- three MOTEC drives on one bus at 115200;
- a ``modbus_bridge`` description with a position joint and a velocity joint
  (tests/support/joint_axes.yaml) over loopback TCP.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from bridge_core.sim.logs import WriteRecord
from msg_defs.msg import DeviceValues, MotecState, StepperState

from .bridges import BRIDGES, BridgeInfo, SimProcess
from .ros import Bridge, Client, start_bridge

AXES = Path(__file__).resolve().parent / "joint_axes.yaml"
COMMAND_TIMEOUT_S = 0.5  # every bridge's default deadman
# The rigs' status period: a refusal count is seen in a quarter of the default 1 s (the
# refusal tests wait for one count after another).
DIAGNOSTIC_PERIOD_S = 0.25
STEPPER_BAUD = 9600
STEPPER_REPLY_DELAY_MS = 35
STEPPER_TIMEOUT_S = 1.0  # far above the 0.15 s floor: a loaded machine never looks dead
MOTEC_UNITS = (1, 2, 3)
# Far above a transaction's few ms at 115200: with 0.2 s, beside two CPU burners, the
# simulator's late replies cost the link (reconnects, refused commands, the deadman) in
# the middle of a trajectory. The lifeguard stays off (its floor grows with the timeout).
MOTEC_TIMEOUT_S = 1.0
# The ramps run drives at up to 1.5 rad/s, and beside two burners the test client's first
# cycle can come 0.3 s late: its first target is judged from where the drive stands
# (docs/ros2_control.md, decision 3), so the default 0.1 rad would refuse the trajectory.
MOTEC_MAX_JUMP = 0.5


@dataclass
class Rig:
    """A simulator process, a bridge process, and the names of its command topic."""

    sim: SimProcess
    bridge: Bridge
    proc: Any
    commands: str  # the ~/joint_commands topic
    owner: str  # the node that owns it (its diagnostics count the refusals)

    def writes(self, since: int = 0) -> list[WriteRecord]:
        return self.sim.writes()[since:]


def info(key: str) -> BridgeInfo:
    return next(entry for entry in BRIDGES if entry.key == key)


def names(joint: str) -> Callable[[Any], bool]:
    """A joint_states message that names ``joint``."""
    return lambda msg: joint in msg.name


@contextmanager
def _rig(
    client: Client,
    sim: SimProcess,
    work: Path,
    module: str,
    node_name: str,
    state_type: Any,
    params: dict[str, Any],
    owner_node: str,
    ready: Callable[[Bridge], None],
) -> Iterator[Rig]:
    """Start ``sim``, then the bridge with ``params`` (the simulator's address and the
    shared deadman added), wait until connected and ``ready``, yield, stop both."""
    sim.start()
    params = {
        **sim.address_params(),
        "reconnect_max_s": 1.0,
        "command_timeout_s": COMMAND_TIMEOUT_S,
        "diagnostic_period_s": DIAGNOSTIC_PERIOD_S,
        **params,
    }
    try:
        with start_bridge(client, work, module, node_name, state_type, params) as (bridge, proc):
            bridge.wait_connected(True)
            ready(bridge)
            commands = f"{bridge.ns}/{owner_node}/joint_commands"
            yield Rig(sim, bridge, proc, commands, node_name)
    finally:
        sim.stop()


@contextmanager
def stepper_rig(client: Client, work: Path) -> Iterator[Rig]:
    sim = SimProcess(info("stepper"), work / "sim")
    sim.baudrate = STEPPER_BAUD
    sim.extra_args = ("--reply-delay-ms", str(STEPPER_REPLY_DELAY_MS), "--travel", "1000")
    with _rig(
        client,
        sim,
        work,
        "stepper_bridge.node",
        "stepper_bridge",
        StepperState,
        {"timeout_s": STEPPER_TIMEOUT_S},
        "stepper_bridge",
        lambda bridge: client.wait_message(bridge.joint_states),
    ) as rig:
        yield rig


@contextmanager
def motec_rig(client: Client, work: Path) -> Iterator[Rig]:
    units = ",".join(str(u) for u in MOTEC_UNITS)
    sim = SimProcess(replace(info("motec"), sim_args=("--unit-ids", units)), work / "sim")

    def every_drive_polled(bridge: Bridge) -> None:
        for unit in MOTEC_UNITS:
            client.wait_message(bridge.joint_states, names(f"drive_{unit}"))

    with _rig(
        client,
        sim,
        work,
        "motec_bridge.node",
        "motec_1",
        MotecState,
        {
            "unit_ids": list(MOTEC_UNITS),
            "timeout_s": MOTEC_TIMEOUT_S,
            "joint_command_max_jump": MOTEC_MAX_JUMP,
        },
        "motec_bridge",
        every_drive_polled,
    ) as rig:
        yield rig


@contextmanager
def axes_rig(client: Client, work: Path) -> Iterator[Rig]:
    sim = SimProcess(replace(info("modbus"), sim_args=("--device-file", str(AXES))), work / "sim")
    with _rig(
        client,
        sim,
        work,
        "modbus_bridge.node",
        "modbus_bridge",
        DeviceValues,
        {"device_file": str(AXES), "timeout_s": 0.5},
        "modbus_bridge",
        lambda bridge: client.wait_message(bridge.joint_states),
    ) as rig:
        yield rig


__all__ = [
    "AXES",
    "COMMAND_TIMEOUT_S",
    "STEPPER_BAUD",
    "STEPPER_REPLY_DELAY_MS",
    "STEPPER_TIMEOUT_S",
    "Rig",
    "axes_rig",
    "info",
    "motec_rig",
    "names",
    "stepper_rig",
]
