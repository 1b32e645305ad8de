#!/usr/bin/env python3
"""Read rates side by side: rate groups against the wire limit, and
pipelined Modbus TCP against one request at a time and a bare pymodbus loop.

    .venv/bin/python bench/read_rates.py [--quick] [--parts rtu,tcp,node]
        [--duration S] [--drives 1,3,8] [--devices r6,xarm] [--round-trips-ms 0,1,5]
        [--windows 1,4,13] [--tcp-duration S] [--repeats N] [--node all|some|none]
        [--node-duration S] [--changes N] [--domain-id 216] [--seed 1] [--json PATH]

Prints three tables and writes bench/results/read_rates.json; asserts nothing. It
measures nothing of its own: it composes the benches that do (bench/README.md).

1. RTU (``rtu_saturated.saturated_run``): the stepper at 9600 baud with 35 ms replies and
   MOTEC with 1 / 3 / 8 drives on one bus at 115200, the bridges' device layers polled
   back to back by the nodes' own poller (``NodePoller``) through one ``ModbusLink`` on
   the emulated byte-timed line (``line_relay.py``), against the bridges' simulators.
   Each case twice: ``today`` (the whole map every poll) and ``groups`` (the rate groups
   as the bridges ship them: fast every poll, slow every ``slow_poll_period_s`` = 1 s,
   the node default; the configuration refresh, one request per poll every 5 s, in both).
2. TCP (``pipelining.bare_rate`` / ``device_rate``): R6 and xArm at simulated round
   trips (the simulator's ``round_trip_s``, ``--reply-delay-ms`` on its command line):
   a bare sync pymodbus loop issuing the device layer's own plan (its fast group every
   poll, its slow group once a second: ``pipelining.device_groups``), and the device
   layer with ``max_in_flight`` 1, 4 and 13.
3. node (``node_measure.measure_node`` / ``latency_phase.phase_latency``): the node for
   TCP cases (R6, xArm; ``--node all`` every TCP case, ``some`` R6 at the largest round
   trip with N = 1 and the largest): its poll rate at ``poll_rate_hz`` 1000 without a
   subscriber, its CPU per poll, and register -> ``joint_states`` at 100 Hz.

This script is the command line; a module per part: bench/read_rates_rtu.py,
bench/read_rates_tcp.py, bench/read_rates_node.py, and bench/read_rates_common.py for
what they share (joint 1 of each device, the probe's latency figures).

How "today's plan" is emulated (``rtu_pollers.read_whole_map``, bench only): the
device is built as the bridge builds it, then its ``PollGroups`` get, through their
public ``set_plans``, one fast plan covering every register of both groups (planned as
one by the bridges' planner, ``rtu_pollers.whole_map_plan``) and no slow group. Every
poll then makes the requests a poll made before the rate groups (the tree before
dc8e5b1: stepper 4 requests, MOTEC 4; with the groups 3 and 2 a poll, plus the slow
group's 1 and 2 once a second). No bridge code changes: the bridges keep their groups.

Columns:

- ``req/poll``: requests per poll: the whole map's, or fast + slow (slow once per period);
- ``polls/s/dev``: device-layer polls per second per device (= ``joint_states`` per
  second of a node, which publishes once per poll), mean over the drives; ``min``: the
  slowest drive's;
- ``fast wire/s``: the wire limit of the fast blocks alone, per device: 1 / (drives x
  the ideal wire time of one fast poll), each fast request's frames at the baud
  (``bridge_core.wire.requests.pdu_bytes``), the device's turnaround max(t3.5, nominal
  reply delay) and t3.5 after the reply (``rtu_wire.transaction_wire_s``; the same
  arithmetic as the node's wire budget, ``SerialSettings.frame_time_s``); ``of wire``:
  polls/s/dev over it (1.0: as fast as the joints alone could be read);
- ``line``: the share of the line's time the run kept busy with ideal transactions
  (``rtu_devices``' ``ratio``: ~1.0 = the line is saturated, the rest is overhead);
- ``x today``: groups over today, same case;
- ``cpu ms/poll`` / ``cpu us/poll``: this process's CPU (all threads, user + system) over
  the window / polls in it (RTU: the poll threads of every drive, the link and the probe;
  the simulators and the relay run in processes of their own); node: the node process's
  CPU from /proc (10 ms ticks) / its polls;
- ``p50/p99 ms (n)``: device layer (RTU, TCP): register change in the simulator -> the
  first snapshot carrying it, at the poll's return (``change_probe.py``; polls back to
  back, the simulator in a process of its own); node: register change -> the first
  ``joint_states`` carrying it (bridge_bench's latency phase: node at 100 Hz, the
  simulator in the bench's process). ``n`` samples; ``miss``: changes never seen;
- TCP ``tx ms``: median transaction time one request at a time (the round trip the
  simulator really gives); ``x N=1``: polls/s over those of N = 1; ``x bare``: over the
  bare loop's; ``fb``: pipelining fallbacks (should be 0).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import bridge_core  # noqa: E402
from bench import bridge_bench  # noqa: E402
from bench.read_rates_common import SLOW_PERIOD_S  # noqa: E402
from bench.read_rates_node import node_cases, node_part  # noqa: E402
from bench.read_rates_rtu import rtu_cases, rtu_part  # noqa: E402
from bench.read_rates_tcp import tcp_part  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "read_rates.json"
# Not bridge_bench.py's 101 (nor the tests' 1 + pid % 100): a bridge_bench run beside
# this one would mix its nodes' diagnostics into ours. One of the ids bridge_bench accepts.
DEFAULT_DOMAIN_ID = 216


QUICK = {
    "duration": 3.0,
    "warmup": 0.5,
    "drives": "3",
    "round_trips_ms": "0,5",
    "tcp_duration": 1.0,
    "repeats": 1,
    "node": "some",
    "node_duration": 2.0,
    "node_warmup": 0.5,
    "changes": 40,
}
FULL = {
    "duration": 10.0,
    "warmup": 1.0,
    "drives": "1,3,8",
    "round_trips_ms": "0,1,5",
    "tcp_duration": 2.0,
    "repeats": 3,
    "node": "all",
    "node_duration": 5.0,
    "node_warmup": 1.0,
    "changes": 200,
}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="short windows and a subset (stepper, MOTEC x3, R6/xArm at 0 and 5 ms, the "
        "node for R6 at 5 ms with N 1 and 13): about 2 minutes",
    )
    parser.add_argument("--parts", default="rtu,tcp,node", help="comma list of rtu,tcp,node")
    parser.add_argument("--duration", type=float, help="RTU window, s (10; quick 3)")
    parser.add_argument("--warmup", type=float, help="RTU warm-up, s (1; quick 0.5)")
    parser.add_argument("--drives", help="MOTEC drive counts (1,3,8; quick 3)")
    parser.add_argument("--devices", default="r6,xarm", help="TCP devices")
    parser.add_argument("--round-trips-ms", help="simulated round trips (0,1,5; quick 0,5)")
    parser.add_argument("--windows", default="1,4,13", help="max_in_flight values")
    parser.add_argument("--tcp-duration", type=float, help="TCP window, s (2; quick 1)")
    parser.add_argument("--repeats", type=int, help="TCP rounds, medians (3; quick 1)")
    parser.add_argument(
        "--node", choices=("all", "some", "none"), help="node cases (all; quick some)"
    )
    parser.add_argument("--node-duration", type=float, help="node rate window, s (5; quick 2)")
    parser.add_argument("--node-warmup", type=float, help="node warm-up, s (1; quick 0.5)")
    parser.add_argument("--changes", type=int, help="node latency samples (200; quick 40)")
    parser.add_argument(
        "--domain-id",
        type=int,
        default=DEFAULT_DOMAIN_ID,
        help=f"ROS_DOMAIN_ID of the node part (default {DEFAULT_DOMAIN_ID})",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    defaults = QUICK if args.quick else FULL
    for key, value in defaults.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    unknown = set(args.parts.split(",")) - {"rtu", "tcp", "node", ""}
    if unknown:
        parser.error(f"unknown parts {sorted(unknown)}")
    return args


def numbers(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    parts = set(args.parts.split(","))
    devices = [d for d in args.devices.split(",") if d]
    round_trips = numbers(args.round_trips_ms)
    windows = [int(w) for w in numbers(args.windows)]
    started = time.monotonic()
    meta: dict[str, Any] = {
        "when": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": f"{platform.node()} {os.cpu_count()} CPU {platform.machine()}",
        "python": platform.python_version(),
        "bridge_core": str(Path(bridge_core.__file__).resolve().parent),
        "quick": args.quick,
        "slow_poll_period_s": SLOW_PERIOD_S,
        "loadavg_before": bridge_bench.loadavg(),
        "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
    }
    print(
        f"read_rates {meta['when']}  {meta['machine']}  load {meta['loadavg_before']}  "
        f"{'quick' if args.quick else 'full'}\nbridge_core from {meta['bridge_core']}\n"
        "CPU = this process's CPU / polls (node: the node process's); latency = register "
        "change -> device-layer snapshot in the RTU and TCP tables (no node run there), "
        "register change -> joint_states in the node table\n",
        flush=True,
    )
    result: dict[str, Any] = {"meta": meta}
    if "rtu" in parts:
        cases = rtu_cases([int(n) for n in numbers(args.drives)])
        result["rtu"] = rtu_part(cases, args.duration, args.warmup, args.seed)
    if "tcp" in parts:
        result["tcp"] = tcp_part(
            devices, round_trips, windows, args.tcp_duration, args.repeats, args.seed
        )
    if "node" in parts:
        cases_node = node_cases(args.node, devices, round_trips, windows)
        if cases_node:
            result["node"] = node_part(
                cases_node,
                args.node_duration,
                args.node_warmup,
                args.changes,
                args.domain_id,
                args.seed,
            )
    meta["loadavg_after"] = bridge_bench.loadavg()
    meta["run_s"] = round(time.monotonic() - started, 1)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1, default=str) + "\n")
    print(f"wrote {args.json} ({meta['run_s']:.0f} s, load {meta['loadavg_after']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
