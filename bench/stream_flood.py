#!/usr/bin/env python3
"""A cmd_velocity flood against motec_bridge: poll rates kept, writes/s, stop delay.

Issue 9 measured, before command streams kept only their newest value: 1000 msg/s of a
constant ``cmd_velocity`` on one drive dropped every drive's poll rate from 10 Hz to
2.0-3.8 Hz and cost links; a varying flood kept writing for 0.84 s after the last message
and stopped 1.34 s after it against a 0.5 s ``command_timeout_s``.

Setup: ``motec_bridge`` (three drives, the node's defaults: 10 Hz, 0.1 s timeout,
``command_rate_hz`` 20, ``command_timeout_s`` 0.5) and the MOTEC simulator (three
drives at 115200 baud on a socat pty pair, its write log in a file) each in a process of
its own; this process publishes the flood (one rclpy publisher, paced at ``--rate``) and
counts every drive's ``joint_states`` (one per poll). Phases: ``idle`` (no commands),
``constant`` (drive 2, one value), ``varying`` (drive 2, a new value every message),
then silence: the stop delay is the simulator's time of the deadman's 0xAE = 0 minus the
last message's send time. Prints a table; asserts nothing. Only loopback and ptys;
discovery on localhost.

    .venv/bin/python bench/stream_flood.py [--seconds 5] [--rate 1000]
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
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "104")

UNITS = (1, 2, 3)
FLOODED = 2
BAUD = 115200
COMMAND_TIMEOUT_S = 0.5
SPEED_REGISTER = 0xAE


def drive_writes(write_log: Path) -> list[Any]:
    """The simulator's accepted writes to the flooded drive, from its JSON-lines log."""
    from bridge_core.sim_base import read_write_log

    if not write_log.exists():
        return []
    return [r for r in read_write_log(write_log) if r.unit_id == FLOODED]


Row = tuple[str, dict[str, float], float, int]  # phase, polls/s per drive, writes/s, msg/s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="length of each phase")
    parser.add_argument("--rate", type=float, default=1000.0, help="flood messages/s")
    args = parser.parse_args()

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
            port, write_log = Path(logs) / "motec.pty", Path(logs) / "writes.jsonl"
            sim = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "motec_bridge.sim",
                    "--pty",
                    str(port),
                    "--baudrate",
                    str(BAUD),
                    "--unit-ids",
                    ",".join(str(u) for u in UNITS),
                    "--write-log",
                    str(write_log),
                ],
                cwd=ROOT,
            )
            try:
                wait_for(port.exists, 30, "the simulator's pty")
                rows, delay, after_last = run(args, client, ns, port, write_log, polls)
            finally:
                sim.send_signal(signal.SIGINT)
                sim.wait(30)
    finally:
        client.close()

    print(
        f"motec_bridge, 3 drives at {BAUD} baud, flood on drive {FLOODED} "
        f"({args.seconds:.0f} s per phase, target {args.rate:.0f} msg/s)"
    )
    print(f"{'phase':10s} {'msg/s':>6s} " + " ".join(f"{f'drive_{u} Hz':>11s}" for u in UNITS))
    for name, rates, writes_per_s, sent_per_s in rows:
        line = " ".join(f"{rates[f'drive_{u}']:11.2f}" for u in UNITS)
        print(
            f"{name:10s} {sent_per_s:6d} {line}   writes/s on drive {FLOODED}: {writes_per_s:.1f}"
        )
    print(
        f"stop after the last message: {delay:.3f} s (command_timeout_s {COMMAND_TIMEOUT_S}); "
        f"writes after the last message: {after_last} (the stop included)"
    )


def run(
    args: argparse.Namespace,
    client: Any,
    ns: str,
    port: Path,
    write_log: Path,
    polls: Counter[str],
) -> tuple[list[Row], float, int]:
    """The three phases and the stop; returns the rows, the stop delay, writes after."""
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool

    from msg_defs.srv import SetControlMode
    from tests.support.ros import node_process, wait_for, wait_subscribed

    rows: list[Row] = []
    params = {
        "serial_port": str(port),
        "baudrate": BAUD,
        "unit_ids": list(UNITS),
        "command_timeout_s": COMMAND_TIMEOUT_S,
    }
    with node_process("motec_bridge.node", params, write_log.parent, ["-r", f"__ns:={ns}"]):
        wait_for(lambda: all(polls[f"drive_{u}"] for u in UNITS), 60, "every drive polled")

        def call(service: str, srv: Any, **fields: Any) -> None:
            request = srv.Request()
            for key, value in fields.items():
                setattr(request, key, value)
            reply = client.call(srv, f"{ns}/motec_{FLOODED}/{service}", request)
            assert reply.success, reply.message

        call("set_control_mode", SetControlMode, mode=SetControlMode.Request.VELOCITY)
        call("enable", SetBool, data=True)
        topic = f"{ns}/motec_{FLOODED}/cmd_velocity"
        publisher = client.node.create_publisher(Float64, topic, 10)
        wait_subscribed(publisher)

        def phase(name: str, value: Any) -> float:
            """Publish for --seconds (value None: nothing); returns the last send time."""
            start_polls, start_writes = dict(polls), len(drive_writes(write_log))
            started = time.monotonic()
            sent, last = 0, 0.0
            while time.monotonic() < started + args.seconds:
                if value is None:
                    time.sleep(0.05)
                    continue
                publisher.publish(Float64(data=value(sent)))
                last = time.time()
                sent += 1
                time.sleep(max(0.0, started + sent / args.rate - time.monotonic()))
            span = time.monotonic() - started
            rates = {
                f"drive_{u}": (polls[f"drive_{u}"] - start_polls[f"drive_{u}"]) / span
                for u in UNITS
            }
            writes = len(drive_writes(write_log)) - start_writes
            rows.append((name, rates, writes / span, int(sent / span)))
            return last

        phase("idle", None)
        phase("constant", lambda _n: 2 * math.pi)
        before = len(drive_writes(write_log))
        last_sent = phase("varying", lambda n: 1.0 + (n % 50) / 10)

        def stop_record() -> Any:
            return next(
                (
                    r
                    for r in drive_writes(write_log)[before:]
                    if r.address == SPEED_REGISTER and r.values == (0,)
                ),
                None,
            )

        stop = wait_for(stop_record, 30, "the deadman's stop")
        after_last = sum(1 for r in drive_writes(write_log)[before:] if r.time > last_sent)
    return rows, stop.time - last_sent, after_last


if __name__ == "__main__":
    main()
