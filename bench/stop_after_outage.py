#!/usr/bin/env python3
"""A stop while the stepper's line is down: how soon it reaches the device once it is back.

The goal: "a stop while the link is down reaches the device within 0.3 s of the line
coming back". Setup: ``stepper_bridge`` in a process of its own with the node's
defaults (9600 baud, ``timeout_s`` 0.5, ``command_timeout_s`` 0.5, ``reconnect_max_s`` 5,
3 Hz polls) unless overridden, against the stepper simulator in this process on a socat pty
pair (the manual's 35 ms reply delay). Per repetition: jog motor 1 until it runs, cut the
line (the simulator withholds every reply: the controller hears nothing), then

- ``deadman``: stop publishing the jog; once the bridge logged that its deadman stop failed
  (the stop is pending), wait a random 0-``--jitter-s`` (so the line comes back at any
  phase of the bridge's retries), restore the line;
- ``service``: once the link is marked down, call ``~/motor_1/stop`` (attempted at once;
  the reply says whether it went out), wait for its reply up to ``--service-wait-s``, then
  restore the line.

Measured on the simulator's clock: from the moment replies are restored to the arrival of
motor 1's stop coil in its write log (or "never" within ``--wait-s``). Prints a table;
asserts nothing. Only loopback and ptys; discovery on localhost.

    .venv/bin/python bench/stop_after_outage.py [--repeat 10] [--cases deadman,service]
        [--timeout-s 0.5] [--baudrate 9600] [--reply-delay-ms 35]
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "105")

FIGURE_S = 0.3  # the goal: the stop reaches the device within this of the line coming back
JOG_RPM = 100.0
MOTOR = 1
WAIT_S = 30.0  # generous bound on every wait for the bridge (a loaded machine)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=10, help="repetitions per case")
    parser.add_argument("--cases", default="deadman,service", help="deadman, service or both")
    parser.add_argument("--timeout-s", type=float, help="the node's timeout_s (default: its own)")
    parser.add_argument("--baudrate", type=int, default=9600)
    parser.add_argument("--reply-delay-ms", type=float, default=35.0)
    parser.add_argument("--jitter-s", type=float, default=1.0, help="random wait before restoring")
    parser.add_argument("--wait-s", type=float, default=5.0, help="how long to wait for the stop")
    parser.add_argument(
        "--service-wait-s", type=float, default=3.0, help="service case: line down this long"
    )
    args = parser.parse_args()

    from tests.support.ros import Client

    client = Client("stop_after_outage_bench")
    client.subscribe_log()
    results: dict[str, list[tuple[float | None, str]]] = {}
    try:
        for case in args.cases.split(","):
            results[case] = run_case(args, client, case)
    finally:
        client.close()

    timeout = "node default" if args.timeout_s is None else f"{args.timeout_s} s"
    print(
        f"stepper_bridge, stop coil after the line comes back ({args.repeat} runs per case, "
        f"{args.baudrate} baud, reply delay {args.reply_delay_ms:.0f} ms, timeout_s {timeout})"
    )
    print(
        f"{'case':8s} {'reached':>8s} {'min s':>7s} {'median s':>9s} {'max s':>7s} {'< 0.3 s':>8s}"
    )
    for case, rows in results.items():
        delays = [d for d, _ in rows if d is not None]
        under = sum(1 for d in delays if d < FIGURE_S)
        if delays:
            span = f"{min(delays):7.3f} {statistics.median(delays):9.3f} {max(delays):7.3f}"
        else:
            span = f"{'-':>7s} {'-':>9s} {'-':>7s}"
        print(f"{case:8s} {len(delays):4d}/{len(rows):<3d} {span} {under:4d}/{len(rows):<3d}")
        for delay, note in rows:
            if note:
                print(f"  {case}: {'never' if delay is None else f'{delay:.3f} s'}: {note}")


def run_case(args: argparse.Namespace, client: Any, case: str) -> list[tuple[float | None, str]]:
    """One bridge process and simulator for ``args.repeat`` repetitions of ``case``."""
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger

    from bridge_core.wire.registers import Table
    from msg_defs.msg import StepperState
    from stepper_bridge.registers import motor_coil
    from stepper_bridge.sim import StepperSimDevice, make_simulator
    from tests.support.ros import Bridge, node_process, wait_for, wait_subscribed
    from tests.support.serial_pair import served_on_pty

    simulator = make_simulator(reply_delay_s=args.reply_delay_ms / 1000.0)
    device = simulator.device
    assert isinstance(device, StepperSimDevice)
    stop_coil = (Table.COIL, motor_coil(MOTOR, "stop"))
    ns = f"/outage_{os.getpid()}_{case}"
    b = Bridge(client, ns, "stepper_bridge", StepperState)
    rows: list[tuple[float | None, str]] = []
    with tempfile.TemporaryDirectory() as logs, served_on_pty(simulator, args.baudrate) as port:
        params: dict[str, Any] = {"serial_port": port, "baudrate": args.baudrate}
        if args.timeout_s is not None:
            params["timeout_s"] = args.timeout_s
        with node_process("stepper_bridge.node", params, Path(logs), ["-r", f"__ns:={ns}"]):
            b.wait_connected(True, timeout=WAIT_S)
            jog = client.node.create_publisher(
                Float64, f"{ns}/stepper_bridge/motor_{MOTOR}/jog", 10
            )
            wait_subscribed(jog)

            def jogging() -> bool:
                jog.publish(Float64(data=JOG_RPM))
                time.sleep(0.05)  # paces the jog messages while waiting
                return device.motion[MOTOR] is not None

            for _ in range(args.repeat):
                # The line is up and the link marked so (a poll after the last restore).
                t = time.monotonic()
                client.wait_message(b.state, since=t, timeout=WAIT_S)
                b.wait_connected(True, timeout=WAIT_S)
                jog.publish(Float64(data=0.0))  # unlocks the stream after a service stop
                wait_for(jogging, WAIT_S, "motor 1 jogging")
                simulator.withhold_replies = True
                cut = time.monotonic()
                note = ""
                if case == "deadman":
                    client.wait_log("stepper_bridge", "(deadman) failed", since=cut, timeout=WAIT_S)
                    time.sleep(random.uniform(0.0, args.jitter_s))  # the phase of the retries
                else:
                    b.wait_connected(False, since=cut, timeout=WAIT_S)
                    stopper = client.node.create_client(Trigger, b.service(f"motor_{MOTOR}/stop"))
                    wait_for(stopper.service_is_ready, WAIT_S, "the stop service")
                    called = time.monotonic()
                    future = stopper.call_async(Trigger.Request())
                    try:  # attempted at once: it answers within the reply timeout, or not
                        wait_for(future.done, args.service_wait_s, "the stop service's reply")
                        reply = future.result()
                        note = f"replied while down after {time.monotonic() - called:.2f} s, "
                        note += "done" if reply.success else "failed"
                    except AssertionError:
                        note = f"no reply while down ({args.service_wait_s} s)"
                before = len(device.write_log)
                restored = time.time()
                simulator.withhold_replies = False

                def stop_record(before: int = before) -> Any:
                    return next(
                        (r for r in device.write_log[before:] if (r.table, r.address) == stop_coil),
                        None,
                    )

                try:
                    record = wait_for(stop_record, args.wait_s, "the stop coil")
                    rows.append((record.time - restored, note))
                except AssertionError:
                    rows.append((None, note or f"no stop coil within {args.wait_s} s"))
                    b.wait_connected(True, since=cut, timeout=WAIT_S)
                    reply = client.call(
                        Trigger, b.service(f"motor_{MOTOR}/stop"), Trigger.Request()
                    )
                    assert reply.success, reply.message  # clean-up before the next run
                if case == "service":
                    wait_for(future.done, WAIT_S, "the stop service's reply after the outage")
                    if not note.startswith("replied"):
                        note += f", then {'done' if future.result().success else 'failed'}"
                    client.node.destroy_client(stopper)
                wait_for(lambda: device.motion[MOTOR] is None, WAIT_S, "motor 1 stopped")
            client.node.destroy_publisher(jog)
    return rows


if __name__ == "__main__":
    main()
