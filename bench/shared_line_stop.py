#!/usr/bin/env python3
"""Stop latency on a shared stepper line with one controller absent (stepper decision 18).

Setup: ``stepper_bus`` (``python -m stepper_bridge.bus``) in a process of its own with
``unit_ids [1, 2]`` and the node's defaults (``timeout_s`` 0.5, 3 Hz polls) unless
overridden; on the far end of the emulated byte-timed line (``bench/line_relay.py``, 9600
baud) the stepper simulator serves unit 1 only (the manual's 35 ms reply delay): unit 2 is
absent, so its node probes it every ``--reconnect-max-s`` (the backoff's cap; short by
default, so that stops often meet a probe on the line). Per repetition: start motor 1 of
``stepper_1`` (``~/motor_1/forward``), wait a random 0-``--jitter-s``, call
``~/stepper_1/motor_1/stop`` and measure from the call to the stop coil's arrival at the
controller (the simulator's write log: the request's last byte has crossed the line).
The transaction on the line at the call is named from the relay's frame record (a request
with no reply after it: a probe of unit 2). Prints a table and the worst figure; asserts
nothing. Only loopback and ptys; discovery on localhost.

    .venv/bin/python bench/shared_line_stop.py [--repeat 40] [--baudrate 9600]
        [--timeout-s 0.5] [--reconnect-max-s 0.25] [--jitter-s 0.6]
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
os.environ.setdefault("ROS_DOMAIN_ID", "106")

from bench.line_relay import REPLY, REQUEST, Frame, LineRelay  # noqa: E402

MOTOR = 1
PRESENT, ABSENT = 1, 2
WAIT_S = 30.0  # generous bound on every wait for the bridge (a loaded machine)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=40)
    parser.add_argument("--baudrate", type=int, default=9600)
    parser.add_argument("--timeout-s", type=float, default=0.5, help="the bus's timeout_s")
    parser.add_argument(
        "--reconnect-max-s", type=float, default=0.25, help="backoff cap of the absent unit"
    )
    parser.add_argument("--reply-delay-ms", type=float, default=35.0)
    parser.add_argument("--jitter-s", type=float, default=0.6, help="random wait before a stop")
    args = parser.parse_args()

    from tests.support.ros import Client

    client = Client("shared_line_stop_bench")
    try:
        rows = run(args, client)
    finally:
        client.close()

    latencies = [latency for latency, _ in rows]
    print(
        f"stepper_bus units {PRESENT} (present) and {ABSENT} (absent), stop of unit {PRESENT} "
        f"motor {MOTOR}: {len(rows)} stops, {args.baudrate} baud byte-timed line, reply delay "
        f"{args.reply_delay_ms:.0f} ms, timeout_s {args.timeout_s}, unit {ABSENT} probed "
        f"every <= {args.reconnect_max_s} s + its probe timeout"
    )
    print(f"{'on the line at the call':34s} {'stops':>5s} {'median s':>9s} {'max s':>7s}")
    by_kind: dict[str, list[float]] = {}
    for latency, kind in rows:
        by_kind.setdefault(kind, []).append(latency)
    for kind, values in sorted(by_kind.items()):
        print(f"{kind:34s} {len(values):5d} {statistics.median(values):9.3f} {max(values):7.3f}")
    print(
        f"{'all':34s} {len(latencies):5d} {statistics.median(latencies):9.3f} {max(latencies):7.3f}"
    )
    print(f"worst stop latency: {max(latencies):.3f} s (call to the coil at the controller)")


def run(args: argparse.Namespace, client: Any) -> list[tuple[float, str]]:
    from std_srvs.srv import Trigger

    from bridge_core.wire.registers import Table
    from bridge_core.wire.transport import SerialSettings
    from msg_defs.msg import StepperState
    from stepper_bridge.registers import motor_coil, reply_timeout_floor_s
    from stepper_bridge.sim import StepperSimDevice, make_bus_simulator
    from tests.support.ros import Bridge, node_process, wait_for

    # A probe of the absent unit holds the line this long after its request at most.
    probe_s = min(args.timeout_s, reply_timeout_floor_s(SerialSettings("", args.baudrate)))
    simulator = make_bus_simulator([PRESENT], reply_delay_s=args.reply_delay_ms / 1000.0)
    device = simulator.devices[PRESENT]
    assert isinstance(device, StepperSimDevice)
    stop_coil = (Table.COIL, motor_coil(MOTOR, "stop"))
    ns = f"/shared_stop_{os.getpid()}"
    b = Bridge(client, ns, f"stepper_{PRESENT}", StepperState)
    rows: list[tuple[float, str]] = []
    with tempfile.TemporaryDirectory() as logs, LineRelay(args.baudrate) as relay:
        simulator.start_serial(relay.device_path, args.baudrate)
        params = Path(logs) / "bus.yaml"
        params.write_text(
            f"""/**:
  ros__parameters:
    serial_port: "{relay.client_path}"
    baudrate: {args.baudrate}
    unit_ids: [{PRESENT}, {ABSENT}]
    timeout_s: {args.timeout_s}
/**/stepper_{PRESENT}:
  ros__parameters:
    joint_prefix: "a_"
/**/stepper_{ABSENT}:
  ros__parameters:
    joint_prefix: "b_"
    reconnect_max_s: {args.reconnect_max_s}
"""
        )
        try:
            with node_process(
                "stepper_bridge.bus",
                {},
                Path(logs),
                ["--params-file", str(params), "-r", f"__ns:={ns}"],
            ):
                b.wait_connected(True, timeout=WAIT_S)
                forward = client.node.create_client(Trigger, b.service(f"motor_{MOTOR}/forward"))
                stop = client.node.create_client(Trigger, b.service(f"motor_{MOTOR}/stop"))
                for service in (forward, stop):
                    wait_for(service.service_is_ready, WAIT_S, "the motor services")
                for _ in range(args.repeat):
                    reply = wait_for(
                        _done(forward.call_async(Trigger.Request())), WAIT_S, "forward"
                    )
                    assert reply.success, reply.message
                    wait_for(lambda: device.motion[MOTOR] is not None, WAIT_S, "motor 1 running")
                    time.sleep(random.uniform(0.0, args.jitter_s))
                    before = len(device.write_log)
                    called_wall, called = time.time(), time.monotonic()
                    future = stop.call_async(Trigger.Request())

                    def stop_record(before: int = before) -> Any:
                        return next(
                            (
                                r
                                for r in device.write_log[before:]
                                if (r.table, r.address) == stop_coil
                            ),
                            None,
                        )

                    record = wait_for(stop_record, WAIT_S, "the stop coil")
                    reply = wait_for(_done(future), WAIT_S, "the stop's reply")
                    assert reply.success, reply.message
                    on_line = _on_the_line(relay.frames(), called, probe_s)
                    rows.append((record.time - called_wall, on_line))
                    relay.clear()
        finally:
            simulator.stop()
    return rows


def _done(future: Any) -> Any:
    """A wait_for predicate: the future's result once it is done."""
    return lambda: future.result() if future.done() else None


def _on_the_line(frames: list[Frame], at: float, probe_s: float) -> str:
    """What occupied the line at ``at``: the last request begun before it, and whether a
    reply followed it (none: a probe of the absent unit, waiting out its ``probe_s``)."""
    last = None
    for k, frame in enumerate(frames):
        if frame.direction == REQUEST and frame.start <= at:
            last = k
    if last is None:
        return "nothing recorded"
    request = frames[last]
    replied = last + 1 < len(frames) and frames[last + 1].direction == REPLY
    if not replied:
        if at > request.end + probe_s:
            return "idle (last transaction done)"
        return "a probe of the absent unit"
    reply = frames[last + 1]
    if reply.end < at:
        return "idle (last transaction done)"
    return "a transaction of the present unit"


if __name__ == "__main__":
    main()
