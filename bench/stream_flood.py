#!/usr/bin/env python3
"""A command-stream flood: poll rates kept, writes/s, stop delay (MOTEC or stepper).

Measured before command streams kept only their newest value: 1000 msg/s of a
constant ``cmd_velocity`` on one MOTEC drive dropped every drive's poll rate from 10 Hz to
2.0-3.8 Hz and cost links; a varying stepper jog flood kept writing for 0.84 s after the
last message and stopped 1.34 s after it against a 0.5 s ``command_timeout_s``.

Setup (``--device``):

- ``motec``: ``motec_bridge`` with three drives at 115200 baud (the node's defaults:
  10 Hz, 0.1 s timeout, ``command_rate_hz`` 20), the flood on drive 2's ``cmd_velocity``
  (rad/s), its stop = 0xAE = 0;
- ``stepper``: ``stepper_bridge`` at 9600 baud (the node's defaults: 3 Hz, 0.5 s timeout,
  ``command_rate_hz`` 5) against a simulator with the manual's 35 ms reply delay, the
  flood on motor 1's ``jog`` (rpm), its stop = motor 1's stop coil (00005);

``command_timeout_s`` 0.5 for both; the bridge and the simulator (write log in a file)
each in a process of its own on a socat pty pair; this process publishes the flood (one
rclpy publisher, paced at ``--rate``) and counts ``joint_states`` per joint (one per
poll). Phases: ``idle`` (no commands), ``constant`` (one value), ``varying`` (a new value
every message), then silence: the stop delay is the simulator's time of the deadman's stop
minus the last message's send time. Prints a table; asserts nothing. Only loopback and
ptys; discovery on localhost.

``--topic joint_commands`` floods ``~/joint_commands`` instead (``JointState``
with the joint's name and a velocity in SI units; the MOTEC bus owner's topic for drive 2,
the stepper's for motor 1): the same phases, the same stop.

    .venv/bin/python bench/stream_flood.py [--device motec|stepper] [--seconds 5] [--rate 1000]
        [--topic stream|joint_commands]
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "104")

COMMAND_TIMEOUT_S = 0.5


@dataclass(frozen=True)
class Target:
    """One bridge under a flood: how to start it and what its stream and stop look like."""

    module: str
    sim_module: str
    sim_args: tuple[str, ...]
    baudrate: int
    params: dict[str, Any]
    node: str  # the node whose services set up the stream
    topic: str  # the flooded topic, under the node
    joints: tuple[str, ...]  # joint_states names counted (one per poll)
    unit_id: int  # the simulator's unit whose writes count
    setup: tuple[tuple[str, str, dict[str, Any]], ...]  # (service, type, fields) first
    constant: float
    varying: Callable[[int], float]  # never 0
    is_stop: Callable[[Any], bool]  # a write-log record that is the stream's stop
    # --topic joint_commands: the node that owns the topic, the joint, the values (SI).
    jc_node: str = ""
    jc_joint: str = ""
    jc_constant: float = 0.0
    jc_varying: Callable[[int], float] = lambda _n: 0.0


TARGETS = {
    "motec": Target(
        module="motec_bridge.node",
        sim_module="motec_bridge.sim_cli",
        sim_args=("--unit-ids", "1,2,3"),
        baudrate=115200,
        params={"unit_ids": [1, 2, 3]},
        node="motec_2",
        topic="cmd_velocity",
        joints=("drive_1", "drive_2", "drive_3"),
        unit_id=2,
        setup=(
            ("set_control_mode", "msg_defs.srv.SetControlMode", {"mode": 1}),
            ("enable", "std_srvs.srv.SetBool", {"data": True}),
        ),
        constant=2 * math.pi,
        varying=lambda n: 1.0 + (n % 50) / 10,
        is_stop=lambda r: r.address == 0xAE and r.values == (0,),
        jc_node="motec_bridge",
        jc_joint="drive_2",
        jc_constant=2 * math.pi,
        jc_varying=lambda n: 1.0 + (n % 50) / 10,
    ),
    "stepper": Target(
        module="stepper_bridge.node",
        sim_module="stepper_bridge.sim",
        sim_args=(),
        baudrate=9600,
        params={},
        node="stepper_bridge",
        topic="motor_1/jog",
        joints=("motor_1",),
        unit_id=1,
        setup=(),
        constant=60.0,
        varying=lambda n: 100.0 + n % 50,
        is_stop=lambda r: r.table.value == "coil" and r.address == 4,  # 00005: motor 1 stop
        jc_node="stepper_bridge",
        jc_joint="motor_1",
        jc_constant=0.003,  # m/s (tests/core/ros/test_joint_commands.py's speeds)
        jc_varying=lambda n: 0.001 + (n % 50) * 1e-5,
    ),
}


def stream_writes(write_log: Path, unit_id: int) -> list[Any]:
    """The simulator's accepted writes to the flooded device, from its JSON-lines log."""
    from bridge_core.sim.logs import read_write_log

    if not write_log.exists():
        return []
    return [r for r in read_write_log(write_log) if r.unit_id == unit_id]


Row = tuple[str, dict[str, float], float, int, float]  # phase, polls/s, writes/s, msg/s, CPU %


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", choices=sorted(TARGETS), default="motec")
    parser.add_argument("--seconds", type=float, default=5.0, help="length of each phase")
    parser.add_argument("--rate", type=float, default=1000.0, help="flood messages/s")
    parser.add_argument("--topic", choices=("stream", "joint_commands"), default="stream")
    args = parser.parse_args()
    target = TARGETS[args.device]

    from sensor_msgs.msg import JointState

    from tests.support.ros import Client, wait_for

    ns = f"/flood_{os.getpid()}"
    polls: Counter[str] = Counter()

    def count(msg: Any) -> None:
        for name in msg.name:
            polls[name] += 1

    client = Client("flood_bench")
    client.node.create_subscription(JointState, f"{ns}/joint_states", count, 100)
    try:
        with tempfile.TemporaryDirectory() as logs:
            port, write_log = Path(logs) / "sim.pty", Path(logs) / "writes.jsonl"
            sim = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    target.sim_module,
                    "--pty",
                    str(port),
                    "--baudrate",
                    str(target.baudrate),
                    *target.sim_args,
                    "--write-log",
                    str(write_log),
                ],
                cwd=ROOT,
            )
            try:
                wait_for(port.exists, 30, "the simulator's pty")
                rows, delay, after_last = run(args, target, client, ns, port, write_log, polls)
            finally:
                sim.send_signal(signal.SIGINT)
                sim.wait(30)
    finally:
        client.close()

    flooded = (
        f"{target.jc_node}/joint_commands ({target.jc_joint})"
        if args.topic == "joint_commands"
        else f"{target.node}/{target.topic}"
    )
    print(
        f"{target.module}, {target.baudrate} baud, flood on {flooded} "
        f"({args.seconds:.0f} s per phase, target {args.rate:.0f} msg/s)"
    )
    print(f"{'phase':10s} {'msg/s':>6s} " + " ".join(f"{f'{j} Hz':>12s}" for j in target.joints))
    for name, rates, writes_per_s, sent_per_s, cpu in rows:
        line = " ".join(f"{rates[j]:12.2f}" for j in target.joints)
        print(
            f"{name:10s} {sent_per_s:6d} {line}   stream writes/s: {writes_per_s:.1f}"
            f"   bridge CPU: {cpu:.0f} % of a core"
        )
    print(
        f"stop after the last message: {delay:.3f} s (command_timeout_s {COMMAND_TIMEOUT_S}); "
        f"writes after the last message: {after_last} (the stop included)"
    )


def run(
    args: argparse.Namespace,
    target: Target,
    client: Any,
    ns: str,
    port: Path,
    write_log: Path,
    polls: Counter[str],
) -> tuple[list[Row], float, int]:
    """The three phases and the stop; returns the rows, the stop delay, writes after."""
    import importlib

    from std_msgs.msg import Float64

    from tests.support.ros import node_process, wait_for, wait_subscribed

    rows: list[Row] = []
    params = {
        "serial_port": str(port),
        "baudrate": target.baudrate,
        "command_timeout_s": COMMAND_TIMEOUT_S,
        **target.params,
    }

    def writes() -> list[Any]:
        return stream_writes(write_log, target.unit_id)

    with node_process(target.module, params, write_log.parent, ["-r", f"__ns:={ns}"]) as bridge:
        wait_for(lambda: all(polls[j] for j in target.joints), 60, "every device polled")
        for service, type_name, fields in target.setup:
            module_name, class_name = type_name.rsplit(".", 1)
            srv = getattr(importlib.import_module(module_name), class_name)
            request = srv.Request()
            for key, value in fields.items():
                setattr(request, key, value)
            reply = client.call(srv, f"{ns}/{target.node}/{service}", request)
            assert reply.success, reply.message
        if args.topic == "joint_commands":
            from sensor_msgs.msg import JointState

            publisher = client.node.create_publisher(
                JointState, f"{ns}/{target.jc_node}/joint_commands", 10
            )

            def message(value: float) -> Any:
                return JointState(name=[target.jc_joint], velocity=[value])

            constant, varying = target.jc_constant, target.jc_varying
        else:
            publisher = client.node.create_publisher(
                Float64, f"{ns}/{target.node}/{target.topic}", 10
            )

            def message(value: float) -> Any:
                return Float64(data=value)

            constant, varying = target.constant, target.varying
        wait_subscribed(publisher)

        def phase(name: str, value: Callable[[int], float] | None) -> float:
            """Publish for --seconds (value None: nothing); returns the last send time."""
            start_polls, start_writes = dict(polls), len(writes())
            start_cpu = cpu_seconds(bridge.pid)
            started = time.monotonic()
            sent, last = 0, 0.0
            while time.monotonic() < started + args.seconds:
                if value is None:
                    time.sleep(0.05)
                    continue
                publisher.publish(message(value(sent)))
                last = time.time()
                sent += 1
                time.sleep(max(0.0, started + sent / args.rate - time.monotonic()))
            span = time.monotonic() - started
            rates = {j: (polls[j] - start_polls[j]) / span for j in target.joints}
            cpu = 100 * (cpu_seconds(bridge.pid) - start_cpu) / span
            written = (len(writes()) - start_writes) / span
            rows.append((name, rates, written, int(sent / span), cpu))
            return last

        phase("idle", None)
        phase("constant", lambda _n: constant)
        before = len(writes())
        last_sent = phase("varying", varying)

        def stop_record() -> Any:
            return next((r for r in writes()[before:] if target.is_stop(r)), None)

        stop = wait_for(stop_record, 30, "the deadman's stop")
        after_last = sum(1 for r in writes()[before:] if r.time > last_sent)
    return rows, stop.time - last_sent, after_last


if __name__ == "__main__":
    main()
