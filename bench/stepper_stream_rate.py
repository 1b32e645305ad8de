#!/usr/bin/env python3
"""The stepper's ``joint_states`` rate while ``~/joint_commands`` streams position targets.

The test suite's stepper set-up (tests/support/joint_rigs.py, as
tests/core/ros/test_joint_commands.py uses it): the simulator at 9600 baud with 35 ms replies
in a process of its own, the bridge with its default ``poll_rate_hz`` (3) in another. A client
publishes position targets for ``motor_1`` and ``motor_2`` at 100 Hz, every joint every cycle
(ros2_control's topic-based interface with ``trigger_joint_command_threshold`` -1), each a
triangle of ``--amplitude-mm`` at ``--speed-mm-s`` (1.5 mm/s, as the test's ramps), then holds
the last target. Counted by the messages' header stamps (one per poll), per phase: idle before,
streaming, holding; the rate over the phase and the fewest / most stamps in any whole second of
it, and the longest gap between two stamps; and the writes on the wire per second while
streaming (the simulator's log). Prints figures; asserts nothing. Loopback and ptys only;
discovery on localhost.

    .venv/bin/python bench/stepper_stream_rate.py [--stream-s 30] [--idle-s 10] [--hold-s 6]
        [--command-rate-hz 5]
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "109")

COMMAND_RATE_HZ = 100.0  # the controller manager's usual update rate
JOINTS = ("motor_1", "motor_2")


def stamps(client: Any, topic: str, begin: float, end: float) -> list[float]:
    """Header stamps (wall clock, s) of the joint_states messages stamped in [begin, end)."""
    seen = []
    for msg in client.received(topic):
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if begin <= t < end:
            seen.append(t)
    return sorted(set(seen))


def per_second(times: Sequence[float], begin: float, end: float) -> tuple[int, int]:
    """The fewest and most of ``times`` in any whole second from ``begin`` up to ``end``."""
    counts = [
        sum(1 for t in times if begin + k <= t < begin + k + 1)
        for k in range(math.floor(end - begin))
    ]
    return (min(counts), max(counts)) if counts else (0, 0)


def triangle(t: float, amplitude: float, speed: float) -> float:
    """0 -> amplitude -> 0 ..., at ``speed``."""
    leg = amplitude / speed
    phase = t % (2 * leg)
    return speed * phase if phase < leg else amplitude - speed * (phase - leg)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--idle-s", type=float, default=10.0)
    parser.add_argument("--stream-s", type=float, default=30.0)
    parser.add_argument("--hold-s", type=float, default=6.0)
    parser.add_argument("--amplitude-mm", type=float, default=6.0)
    parser.add_argument("--speed-mm-s", type=float, default=1.5)
    parser.add_argument(
        "--command-rate-hz", type=float, help="set the node's command_rate_hz first (default 5)"
    )
    args = parser.parse_args()

    from sensor_msgs.msg import JointState

    from tests.support.joint_rigs import STEPPER_BAUD, STEPPER_REPLY_DELAY_MS, stepper_rig
    from tests.support.ros import ros_client, wait_subscribed

    with (
        ros_client("stepper_stream_rate") as client,
        tempfile.TemporaryDirectory() as tmp,
        stepper_rig(client, Path(tmp)) as rig,
    ):
        topic = rig.bridge.joint_states
        last = client.last(topic)
        start = {n: p for n, p in zip(last.name, last.position, strict=True) if n in JOINTS}
        if args.command_rate_hz is not None:
            from rcl_interfaces.srv import SetParameters
            from rclpy.parameter import Parameter

            request = SetParameters.Request()
            request.parameters = [
                Parameter("command_rate_hz", value=args.command_rate_hz).to_parameter_msg()
            ]
            node = f"{rig.bridge.ns}/{rig.owner}"
            (result,) = client.call(SetParameters, f"{node}/set_parameters", request).results
            assert result.successful, result.reason
        publisher = client.node.create_publisher(JointState, rig.commands, 10)
        wait_subscribed(publisher)

        idle0 = time.time()
        time.sleep(args.idle_s)
        idle1 = time.time()

        amplitude, speed = args.amplitude_mm / 1000.0, args.speed_mm_s / 1000.0
        writes_before = len(rig.writes())
        period = 1.0 / COMMAND_RATE_HZ
        began = time.monotonic()
        stream0 = time.time()
        sent = 0
        targets = dict(start)
        while True:
            elapsed = time.monotonic() - began
            if elapsed >= args.stream_s + args.hold_s:
                break
            if elapsed < args.stream_s:
                sign = {"motor_1": 1.0, "motor_2": -1.0}
                targets = {
                    j: start[j] + sign[j] * triangle(elapsed, amplitude, speed) for j in JOINTS
                }
            msg = JointState()
            msg.header.stamp = client.node.get_clock().now().to_msg()
            msg.name = list(JOINTS)
            msg.position = [targets[j] for j in JOINTS]
            publisher.publish(msg)
            sent += 1
            time.sleep(max(0.0, began + sent * period - time.monotonic()))
        stream1 = stream0 + args.stream_s
        hold1 = time.time()
        stream_writes = [r for r in rig.writes(writes_before) if stream0 <= r.time < stream1]
        client.node.destroy_publisher(publisher)

        print(
            f"stepper {STEPPER_BAUD} baud, {STEPPER_REPLY_DELAY_MS} ms replies, "
            f"poll_rate_hz 3 asked, command_rate_hz {args.command_rate_hz or 5:g}; "
            f"{', '.join(JOINTS)} streamed at "
            f"{COMMAND_RATE_HZ:.0f} Hz ({args.amplitude_mm} mm triangles at "
            f"{args.speed_mm_s} mm/s)"
        )
        print(
            f"{'phase':10s} {'s':>5s} {'stamps':>6s} {'Hz':>5s} {'min/s':>5s} {'max/s':>5s} "
            f"{'gap s':>5s}"
        )
        for name, begin, end in (
            ("idle", idle0, idle1),
            ("streaming", stream0, stream1),
            ("holding", stream1, hold1),
        ):
            seen = stamps(client, topic, begin, end)
            low, high = per_second(seen, begin, end)
            gap = max((b - a for a, b in itertools.pairwise(seen)), default=0.0)
            print(
                f"{name:10s} {end - begin:5.1f} {len(seen):6d} "
                f"{len(seen) / (end - begin):5.2f} {low:5d} {high:5d} {gap:5.2f}"
            )
        runs = sum(1 for r in stream_writes if r.table.value == "coil" and r.values == (1,))
        print(
            f"while streaming: {len(stream_writes) / args.stream_s:.1f} writes/s on the "
            f"wire, {runs / args.stream_s:.1f} coil starts/s"
        )


if __name__ == "__main__":
    main()
