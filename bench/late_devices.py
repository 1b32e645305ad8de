#!/usr/bin/env python3
"""Connect success and poll rate against a device's reply delay.

A real RTU device answers later than its manual's minimum. Per bridge and reply delay
(the simulator's ``set_reply_delay``, the ``--reply-delay-ms MIN[:MAX]`` personality,
drawn per reply), on the emulated byte-timed line (``bench/line_relay.py``, the device's
baud rate): start the simulator, then the bridge node in a process of its own with its
defaults (stepper: 9600 baud, ``timeout_s`` 0.5; MOTEC: 115200 baud, ``timeout_s`` 0.1,
one drive), and measure

- ``connect s``: from the node process's start to its first ``~/connected`` true
  ("never" within ``--connect-wait-s``);
- ``polls/s``: ``joint_states`` messages per second over ``--window-s`` once connected;
- ``after outage s``: the simulator withholds every reply for 2 s, then answers again:
  from the restore to ``~/connected`` true again.

Prints one table; asserts nothing. Only loopback and ptys; discovery on localhost.

    .venv/bin/python bench/late_devices.py [--bridges stepper,motec]
        [--stepper-delays 35,100,200,300,35:300] [--motec-delays 0,20,40,60,80,0:80]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "107")

OUTAGE_S = 2.0


@dataclass(frozen=True)
class Rig:
    """One bridge as this bench runs it."""

    module: str
    node: str
    baudrate: int
    params: dict[str, Any]


RIGS = {
    "stepper": Rig("stepper_bridge.node", "stepper_bridge", 9600, {}),
    "motec": Rig("motec_bridge.node", "motec_1", 115200, {"unit_ids": [1]}),
}


def main() -> None:
    from bridge_core.sim.personality import delay_range_ms

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bridges", default="stepper,motec")
    parser.add_argument("--stepper-delays", default="35,100,200,300,35:300")
    parser.add_argument("--motec-delays", default="0,20,40,60,80,0:80")
    parser.add_argument("--connect-wait-s", type=float, default=10.0)
    parser.add_argument("--window-s", type=float, default=4.0)
    args = parser.parse_args()

    from tests.support.ros import Client

    client = Client("late_devices_bench")
    rows = []
    try:
        for bridge in args.bridges.split(","):
            for text in getattr(args, f"{bridge}_delays").split(","):
                delay = delay_range_ms(text)
                rows.append((bridge, text, *run(args, client, RIGS[bridge], delay)))
    finally:
        client.close()
    print(f"reply delay vs connect and poll rate (byte-timed line; node defaults; {ROOT.name})")
    print(
        f"{'bridge':8s} {'delay ms':>9s} {'connect s':>10s} {'polls/s':>8s} {'after outage s':>15s}"
    )
    for bridge, text, connect, rate, again in rows:
        print(f"{bridge:8s} {text:>9s} {_s(connect):>10s} {_rate(rate):>8s} {_s(again):>15s}")


def _s(value: float | None) -> str:
    return "never" if value is None else f"{value:.2f}"


def _rate(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def run(
    args: argparse.Namespace, client: Any, rig: Rig, delay: Any
) -> tuple[float | None, float | None, float | None]:
    """(connect time, polls per second, reconnect time after the outage) of one case."""
    from bench.line_relay import LineRelay
    from tests.support.ros import node_process

    if rig.module.startswith("stepper"):
        from stepper_bridge.sim import make_simulator

        simulator: Any = make_simulator()
    else:
        from motec_bridge.sim import make_simulator as make_motec

        simulator = make_motec([1])
    simulator.set_reply_delay(delay.low_s, delay.high_s)
    ns = f"/late_{os.getpid()}_{time.monotonic_ns()}"
    connected = f"{ns}/{rig.node}/connected"
    joint_states = f"{ns}/joint_states"
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Bool

    from tests.support.ros import LATCHED

    client.subscribe(Bool, connected, LATCHED)
    client.subscribe(JointState, joint_states)

    def up_since(t: float, wait_s: float) -> float | None:
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            with client._lock:
                got = [s for s, m in client.messages[connected] if s >= t and m.data]
            if got:
                return float(got[0]) - t
            time.sleep(0.02)
        return None

    with LineRelay(rig.baudrate) as line, tempfile.TemporaryDirectory() as logs:
        simulator.start_serial(line.device_path, rig.baudrate)
        try:
            params = {"serial_port": line.client_path, "baudrate": rig.baudrate, **rig.params}
            started = time.monotonic()
            with node_process(rig.module, params, Path(logs), ["-r", f"__ns:={ns}"]):
                connect = up_since(started, args.connect_wait_s)
                if connect is None:
                    return None, None, None
                t0 = time.monotonic()
                time.sleep(args.window_s)
                rate = len(client.received(joint_states, t0)) / args.window_s
                simulator.withhold_replies = True
                time.sleep(OUTAGE_S)
                simulator.withhold_replies = False
                restored = time.monotonic()
                again = up_since(restored, args.connect_wait_s)
                return connect, rate, again
        finally:
            simulator.stop()


if __name__ == "__main__":
    main()
