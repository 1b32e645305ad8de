#!/usr/bin/env python3
"""Command -> register write latency of ``~/joint_commands`` at 100 Hz commands.

A client publishes ``sensor_msgs/JointState`` commands for one joint at 100 Hz, as
ros2_control's topic-based interface does with ``trigger_joint_command_threshold`` -1
(docs/ros2_control.md). The value changes every ``--step-s`` (cycling through four values,
so each step differs from the one before) and stays constant in between, so the stream
writes nothing between steps (a repeat writes nothing). One sample = the simulator's time of
the first write to the joint's command register after a step minus the wall-clock time the
client published the step's first message. The simulator logs its writes with
``time.time()`` in its own process on this machine, so both clocks are the same.

Cases (each bridge and its simulator in processes of their own, the test suite's set-ups:
tests/support/joint_rigs.py, as tests/core/ros/test_joint_commands.py uses them):

- ``stepper`` motor_1 velocity (m/s -> jog rpm), 9600 baud, 35 ms replies, the node's
  ``command_rate_hz`` (5);
- ``motec`` drive_2 velocity (rad/s -> 0xAE rpm), three drives at 115200 baud, the drive
  in network mode, velocity control, enabled; ``command_rate_hz`` 20;
- ``modbus`` the axes description's spindle (velocity -> ``spindle_setpoint``) and lift
  (position -> ``lift_target``), Modbus TCP on loopback, ``command_rate_hz`` 10.

Not measured: a stepper or MOTEC position target (the stepper sends one only when the
motor stands, the MOTEC needs position control: the latency is the motion's, not the
bridge's). Prints p50/p99/max per case; asserts nothing. Only loopback and ptys;
discovery on localhost.

    .venv/bin/python bench/joint_command_latency.py [--case all|stepper|motec|modbus]
        [--steps 60] [--step-s 0.4]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "107")

COMMAND_RATE_HZ = 100.0  # the controller manager's usual update rate


@dataclass(frozen=True)
class Joint:
    """One commanded joint: its field, the values a step cycles through, and which
    write-log records are its command register's."""

    name: str
    field: str  # "velocity" or "position"
    values: tuple[float, ...]
    is_write: Callable[[Any], bool]
    stop: float | None  # published after the run (velocity: 0); None: nothing


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))
    return ordered[index]


LABELS = {
    "stepper": "stepper 9600/35 ms",
    "motec": "MOTEC x3 115200",
    "modbus": "modbus_bridge TCP",
}


@contextmanager
def motec_velocity_rig(client: Any, work: Path) -> Iterator[Any]:
    """The MOTEC rig with drive 2 in network mode, velocity control, enabled."""
    from std_srvs.srv import SetBool

    from msg_defs.srv import SetControlMode
    from tests.support.joint_rigs import motec_rig

    with motec_rig(client, work) as rig:
        mode = SetControlMode.Request()
        mode.mode = 1
        reply = client.call(SetControlMode, f"{rig.bridge.ns}/motec_2/set_control_mode", mode)
        assert reply.success, reply.message
        enable = SetBool.Request()
        enable.data = True
        reply = client.call(SetBool, f"{rig.bridge.ns}/motec_2/enable", enable)
        assert reply.success, reply.message
        yield rig


def rigs() -> dict[str, Callable[[Any, Path], Any]]:
    from tests.support.joint_rigs import axes_rig, stepper_rig

    return {"stepper": stepper_rig, "motec": motec_velocity_rig, "modbus": axes_rig}


def holding(unit: int, address: int) -> Callable[[Any], bool]:
    return lambda r: r.unit_id == unit and r.table.value == "holding" and r.address == address


def stepper_write(r: Any) -> bool:
    """Any write to the stepper (only the jog of motor 1 writes during the run)."""
    return bool(r.unit_id == 1)


CASES: dict[str, tuple[Joint, ...]] = {
    "stepper": (Joint("motor_1", "velocity", (0.001, 0.002, 0.003, 0.004), stepper_write, 0.0),),
    "motec": (Joint("drive_2", "velocity", (1.0, 2.0, 3.0, 4.0), holding(2, 0xAE), 0.0),),
    "modbus": (
        Joint("spindle", "velocity", (1.0, 2.0, 3.0, 4.0), holding(1, 102), 0.0),
        Joint("lift", "position", (0.001, 0.002, 0.003, 0.004), holding(1, 100), None),
    ),
}


def measure(client: Any, rig: Any, joint: Joint, steps: int, step_s: float) -> list[float]:
    """Publish ``steps`` steps at 100 Hz; the latency of each step's first write (s)."""
    from sensor_msgs.msg import JointState

    from tests.support.ros import wait_subscribed

    publisher = client.node.create_publisher(JointState, rig.commands, 1)
    wait_subscribed(publisher)

    def publish(value: float) -> None:
        msg = JointState()
        msg.header.stamp = client.node.get_clock().now().to_msg()
        msg.name = [joint.name]
        setattr(msg, joint.field, [float(value)])
        publisher.publish(msg)

    step_times: list[float] = []
    period = 1.0 / COMMAND_RATE_HZ
    started = time.monotonic()
    sent = 0
    for k in range(steps):
        value = joint.values[k % len(joint.values)]
        step_times.append(time.time())
        step_end = started + (k + 1) * step_s
        while time.monotonic() < step_end:
            publish(value)
            sent += 1
            time.sleep(max(0.0, started + sent * period - time.monotonic()))
    if joint.stop is not None:
        for _ in range(10):
            publish(joint.stop)
            time.sleep(period)
    time.sleep(0.5)  # the last step's write, if it is late, is in the log by then
    writes = [r for r in rig.sim.writes() if joint.is_write(r)]
    samples = []
    for k, t in enumerate(step_times):
        end = step_times[k + 1] if k + 1 < len(step_times) else t + step_s
        first = next((r.time for r in writes if t <= r.time < end), None)
        if first is not None:
            samples.append(first - t)
    client.node.destroy_publisher(publisher)
    return samples


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--case", choices=["all", *CASES], default="all")
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--step-s", type=float, default=0.4)
    args = parser.parse_args()

    from tests.support.ros import ros_client

    cases = list(CASES) if args.case == "all" else [args.case]
    rows = []
    with ros_client("joint_command_latency") as client, tempfile.TemporaryDirectory() as tmp:
        for key in cases:
            with rigs()[key](client, Path(tmp) / key) as rig:
                for joint in CASES[key]:
                    samples = measure(client, rig, joint, args.steps, args.step_s)
                    rows.append((LABELS[key], joint, samples))
    print(
        f"~/joint_commands -> register write, {COMMAND_RATE_HZ:.0f} Hz commands, "
        f"{args.steps} steps of {args.step_s} s"
    )
    print(
        f"{'case':22s} {'joint':10s} {'field':9s} {'n':>3s} "
        f"{'p50 ms':>7s} {'p99 ms':>7s} {'max ms':>7s}"
    )
    for label, joint, samples in rows:
        if not samples:
            print(f"{label:22s} {joint.name:10s} {joint.field:9s}   0 (no write seen)")
            continue
        print(
            f"{label:22s} {joint.name:10s} {joint.field:9s} {len(samples):3d} "
            f"{statistics.median(samples) * 1e3:7.1f} {percentile(samples, 0.99) * 1e3:7.1f} "
            f"{max(samples) * 1e3:7.1f}"
        )


if __name__ == "__main__":
    main()
