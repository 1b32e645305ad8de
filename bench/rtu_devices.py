#!/usr/bin/env python3
"""Device-level RTU figures on the emulated byte-timed line (docs/architecture.md,
"Performance: how it is measured").

Prints tables and writes bench/results/rtu_devices.json; asserts nothing.

    .venv/bin/python bench/rtu_devices.py [--duration 10] [--quick]
        [--parts stepper,bus,dead] [--drives 1,4,8] [--fixed-rate-hz 10]
        [--sim-tick-s 0.1] [--whole-map] [--json PATH]

Everything runs the bridges' own device layers (``StepperDevice.poll()``,
``MotecDevice.poll()``: exactly the requests a node sends per poll cycle, configuration
refresh included) through ``DeviceChannel`` on one shared ``ModbusLink``
(``TimedSerialClient``, ``PriorityLock``), against the bridges' own simulators
(``stepper_bridge.sim`` with its 35 ms reply delay, ``motec_bridge.sim`` with several
drives on one serial server), each in a process of its own on the far end of
``bench/line_relay.py`` (bytes paced at 10 bits / baud on one half-duplex timeline; the
relay holds a reply until t3.5 after the request, as a real RTU device must wait).
The simulators tick their devices' motion every 0.1 s instead of 10 ms
(``--sim-tick-s``): nothing moves here, and 100 Hz ticks of 8 drives take CPU from the
client on a 2-vCPU machine that a real drive would not (see ``rtu_pollers.SIM_TICK_S``).
Each drive gets the nodes' own poller (``bridge_core.runtime.poller.Poller``):
pacing, backoff guard and re-plan (``rtu_pollers.NodePoller``; no ROS, nothing
published), with the nodes' default channel settings. ``--whole-map``: each device reads
its whole map every poll, as before the rate groups (``rtu_pollers.read_whole_map``), for
an A/B in one tree (``bench/read_rates.py`` prints both side by side).

This script is the command line; the parts, one job each: bench/rtu_pollers.py (the
simulators on the emulated line, the nodes' poll threads), bench/rtu_saturated.py
(units polled back to back: the stepper and bus parts, the wire accounting),
bench/rtu_dead_drive.py (the dead part).

Parts:

- ``stepper``: one controller at 9600 and 115200 baud, polled back to back (the node's
  maximum poll rate);
- ``bus``: MOTEC drives 1, 4 and 8 on one bus at 115200, every drive polled as fast as
  possible (the node's maximum poll rate), round-robin through the PriorityLock;
- ``dead``: 4 MOTEC units at 115200, one of them (unit 4) dead (no simulator answers
  it), the others alive, at ``--fixed-rate-hz`` each and saturated; compared with the
  same units all alive (and, saturated, with the 3 live drives alone). The dead drive's
  channel uses the MOTEC node's defaults: timeout 0.1 s, 1 retry (``DeviceChannel``
  probes a device that is down once, without it), reconnect backoff 0.25 s doubling to
  5 s.

Figures:

- ``ratio``: sum of the ideal wire time of every transaction completed in the window,
  over the window (= achieved rate / wire-limit rate for the same transactions). Ideal
  transaction (8N1): (request + reply bytes) x 10 / baud, plus the device turnaround
  max(t3.5, nominal reply delay), plus t3.5 after the reply (``rtu_wire.transaction_wire_s``;
  t3.5 = 3.5 chars, fixed 1.75 ms above 19200 baud);
- ``r_dev``: the same with the turnaround the relay observed (median reply start - request
  end) instead of the nominal delay: the simulator's asyncio sleep overshoots 35 ms by
  ~1.5 ms, which is the device's doing, not the link's;
- ``gap`` / ``min``: median / shortest silence before a request (ms; t3.5 is the floor);
  ``viol/req``: requests that started inside t3.5 after the previous frame (relay
  timestamps, 20 us tolerance) / requests on the wire; the JSON also counts those more
  than 0.1 ms inside (``gross_violations``) and shows the first few; ``err``: failed
  polls of live devices;
- ``lost ms/tx``: where the window's time beyond the ideal went, per transaction: the
  client (silence before a request beyond t3.5), the device (turnaround beyond the
  nominal one), frames stretched on the wire (the relay released bytes late: the
  emulation's own); ``cpu ms/tx``: the bench process's CPU (poll threads and link);
- dead-drive tables: each live drive's polls/s over a window, and the share it keeps of
  its rate with all alive. ``steady``: between two attempts on the dead drive once its
  backoff reached the 5 s cap (whole backoff periods, so the window is unbiased);
  ``first``: the first ``--duration`` seconds after the drive went dead (backoff ramp:
  attempts after 0.25, 0.5, 1, 2, 4 s).
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.rtu_dead_drive import DEAD_UNITS, dead_cases, print_dead  # noqa: E402
from bench.rtu_pollers import (  # noqa: E402
    MOTEC_BAUD,
    MOTEC_TIMEOUT_S,
    NODE_RECONNECT_MAX_S,
    SIM_TICK_S,
    STEPPER_TIMEOUT_S,
)
from bench.rtu_saturated import print_saturated, saturated_run  # noqa: E402
from stepper_bridge.registers import REPLY_DELAY_S as STEPPER_REPLY_DELAY_S  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "rtu_devices.json"
MOTEC_DEFAULT_POLL_HZ = 10.0  # motec_bridge.interface.MOTEC_DEFAULTS.poll_rate_hz


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=10.0, help="measured s per case")
    parser.add_argument("--quick", action="store_true", help="2 s windows, 1 backoff period")
    parser.add_argument("--parts", default="stepper,bus,dead")
    parser.add_argument(
        "--fixed-rate-hz",
        type=float,
        default=MOTEC_DEFAULT_POLL_HZ,
        help="per-drive poll rate of the fixed-rate dead-drive case (node default 10)",
    )
    parser.add_argument("--drives", default="1,4,8", help="bus part: drive counts")
    parser.add_argument(
        "--sim-tick-s",
        type=float,
        default=SIM_TICK_S,
        help="simulators' motion tick (their default: 0.01)",
    )
    parser.add_argument(
        "--whole-map",
        action="store_true",
        help="stepper and bus parts: read the whole map every poll (the plan before rate "
        "groups; read_whole_map)",
    )
    parser.add_argument("--json", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    duration = 2.0 if args.quick else args.duration
    warmup = 0.5 if args.quick else 1.0
    periods = 1 if args.quick else 2
    parts = set(args.parts.split(","))
    tick = args.sim_tick_s
    started = time.monotonic()
    result: dict[str, Any] = {
        "when": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": platform.platform(),
        "duration_s": duration,
        "sim_tick_s": args.sim_tick_s,
        "whole_map": args.whole_map,
    }
    plan = "the whole map every poll" if args.whole_map else "rate groups"
    if "stepper" in parts:
        print(f"stepper: StepperDevice.poll() back to back, 35 ms reply delay, {plan}")
        rows = []
        for baud in (9600, 115200):
            rows.append(
                saturated_run(
                    baud,
                    "stepper",
                    [1],
                    duration,
                    warmup,
                    STEPPER_REPLY_DELAY_S,
                    STEPPER_TIMEOUT_S,
                    tick,
                    whole_map=args.whole_map,
                )
            )
            print_saturated(rows[-1:], header=len(rows) == 1)
        result["stepper"] = rows
        print()
    if "bus" in parts:
        print(
            f"MOTEC bus at {MOTEC_BAUD}: every drive's MotecDevice.poll() as fast as "
            f"possible, {plan}"
        )
        rows = []
        for n in (int(x) for x in args.drives.split(",") if x):
            rows.append(
                saturated_run(
                    MOTEC_BAUD,
                    "motec",
                    range(1, n + 1),
                    duration,
                    warmup,
                    0.0,
                    MOTEC_TIMEOUT_S,
                    tick,
                    whole_map=args.whole_map,
                )
            )
            print_saturated(rows[-1:], header=len(rows) == 1)
        result["bus"] = rows
        print()
    if "dead" in parts:
        print(
            f"MOTEC, {DEAD_UNITS} units at {MOTEC_BAUD}, unit {DEAD_UNITS} dead "
            f"(timeout {MOTEC_TIMEOUT_S} s, probed once, backoff to "
            f"{NODE_RECONNECT_MAX_S:g} s): live drives' polls/s"
        )
        dead = dead_cases(args.fixed_rate_hz, duration, periods, tick)
        print_dead(dead["rows"])
        result["dead"] = dead
        print()
    result["run_s"] = time.monotonic() - started
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))
    print(f"wrote {args.json} ({result['run_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
