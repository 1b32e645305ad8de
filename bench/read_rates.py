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
import contextlib
import datetime
import io
import json
import multiprocessing
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import bridge_core  # noqa: E402
from bench import bridge_bench  # noqa: E402
from bench.change_probe import ChangeProbe  # noqa: E402
from bench.pipelining import (  # noqa: E402
    bare_rate,
    controlled_simulator,
    device_groups,
    device_rate,
)
from bench.rtu_pollers import (  # noqa: E402
    MOTEC_BAUD,
    MOTEC_TIMEOUT_S,
    STEPPER_TIMEOUT_S,
    NodePoller,
    whole_map_plan,
)
from bench.rtu_saturated import saturated_run  # noqa: E402
from bench.rtu_wire import transaction_wire_s  # noqa: E402
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S  # noqa: E402
from bridge_core.runtime.reads import as_request  # noqa: E402
from bridge_core.wire.planner import ReadRequest  # noqa: E402
from bridge_core.wire.registers import RegisterMap  # noqa: E402
from bridge_core.wire.requests import RTU_ADU_OVERHEAD, pdu_bytes  # noqa: E402
from bridge_core.wire.serial_timing import silence_s  # noqa: E402
from bridge_core.wire.transport import SerialSettings  # noqa: E402
from motec_bridge import snapshots as motec_snapshots  # noqa: E402
from motec_bridge.registers import MOTEC_MAP  # noqa: E402
from stepper_bridge import snapshots as stepper_snapshots  # noqa: E402
from stepper_bridge.registers import REPLY_DELAY_S as STEPPER_REPLY_DELAY_S  # noqa: E402
from stepper_bridge.registers import STEPPER_MAP  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "read_rates.json"
STEPPER_BAUD = 9600  # the manual's
SLOW_PERIOD_S = SLOW_POLL_PERIOD_DEFAULT_S  # the devices are built with the node default
NODE_RATE_HZ = bridge_bench.MAX_RATE_HZ  # the node's poll_rate_hz upper bound
# Not bridge_bench.py's 101 (nor the tests' 1 + pid % 100): a bridge_bench run beside
# this one would mix its nodes' diagnostics into ours. One of the ids bridge_bench accepts.
DEFAULT_DOMAIN_ID = 216
WIRE_CHECK_S = 1e-9  # the two wire arithmetics must agree (rtu_wire vs bridge_core)

# Joint 1 of each device's snapshot, and the values the probe sets it to (integers: the
# stepper's user units, MOTEC counts, R6 and xArm degrees), inside what the simulators
# allow without tripping a limit switch.
JOINT_READERS: dict[str, Callable[[Any], float]] = {
    "stepper": lambda s: float(s.coordinates[0]),
    "motec": lambda s: float(s.position_actual),
    "r6": lambda s: float(s.axis_positions_deg[0]),
    "xarm": lambda s: float(s.joint_angles_deg[0]),
}
JOINT_RANGES: dict[str, tuple[int, int]] = {
    "stepper": (1, 400),
    "motec": (-1_000_000, 1_000_000),
    "r6": (-170, 170),
    "xarm": (-180, 180),
}


@dataclass(frozen=True)
class RtuCase:
    label: str
    kind: str  # "stepper" | "motec" (rtu_devices)
    baudrate: int
    drives: int
    reply_delay_s: float  # nominal: the simulator's
    timeout_s: float  # the node's default
    register_map: RegisterMap
    fast: tuple[ReadRequest, ...]
    slow: tuple[ReadRequest, ...]


def rtu_cases(drives: Sequence[int]) -> list[RtuCase]:
    stepper = RtuCase(
        f"stepper {STEPPER_BAUD} {STEPPER_REPLY_DELAY_S * 1e3:g}ms",
        "stepper",
        STEPPER_BAUD,
        1,
        STEPPER_REPLY_DELAY_S,
        STEPPER_TIMEOUT_S,
        STEPPER_MAP,
        tuple(stepper_snapshots.FAST_PLAN),
        tuple(stepper_snapshots.SLOW_PLAN),
    )
    motec = [
        RtuCase(
            f"MOTEC x{n} {MOTEC_BAUD}",
            "motec",
            MOTEC_BAUD,
            n,
            0.0,
            MOTEC_TIMEOUT_S,
            MOTEC_MAP,
            tuple(motec_snapshots.FAST_PLAN),
            tuple(motec_snapshots.SLOW_PLAN),
        )
        for n in drives
    ]
    return [stepper, *motec]


def fast_wire_s(case: RtuCase) -> float:
    """Ideal wire time of one poll of the fast blocks alone (see the module's docstring)."""
    total = 0.0
    for request in case.fast:
        pdu_request, pdu_reply = pdu_bytes(as_request(request))
        total += transaction_wire_s(
            case.baudrate,
            pdu_request + RTU_ADU_OVERHEAD,
            pdu_reply + RTU_ADU_OVERHEAD,
            case.reply_delay_s,
        )
    return total


def fast_wire_s_bridge_core(case: RtuCase) -> float:
    """The same from bridge_core's budget arithmetic: frames and one silence
    (``SerialSettings.frame_time_s``) plus the turnaround, as ``WireBudget`` adds it."""
    settings = SerialSettings("", case.baudrate)
    turnaround = max(silence_s(case.baudrate), case.reply_delay_s)
    return sum(settings.frame_time_s(as_request(r)) + turnaround for r in case.fast)


# ---------------------------------------------------------------- RTU


def rtu_run(
    case: RtuCase, whole_map: bool, duration_s: float, warmup_s: float, seed: int
) -> dict[str, Any]:
    """One case on the emulated line, a probe changing drive 1's joint in the window."""
    mine, theirs = multiprocessing.get_context("spawn").Pipe()
    low, high = JOINT_RANGES[case.kind]
    probe = ChangeProbe(mine, JOINT_READERS[case.kind], low, high, seed=seed)

    def during(pollers: list[NodePoller]) -> contextlib.AbstractContextManager[object]:
        pollers[0].observer = probe.observe
        return probe.running()

    run = saturated_run(
        case.baudrate,
        case.kind,
        range(1, case.drives + 1),
        duration_s,
        warmup_s,
        case.reply_delay_s,
        case.timeout_s,
        whole_map=whole_map,
        control=theirs,
        during=during,
    )
    per_drive = run["polls_per_s"] / case.drives
    limit = 1.0 / (case.drives * fast_wire_s(case))
    return {
        "plan": "today" if whole_map else "groups",
        "polls_per_s_per_drive": per_drive,
        "polls_per_s_slowest_drive": run["per_unit_min"],
        "fast_wire_limit_per_drive": limit,
        "of_fast_wire_limit": per_drive / limit,
        "latency": latency(probe),
        "run": run,
    }


def latency(probe: ChangeProbe) -> dict[str, Any]:
    return {
        **bridge_bench.latency_stats(probe.samples_s),
        "missed": probe.missed,
        "error": probe.error,
        "what": "register change -> snapshot (device layer)",
    }


def rtu_part(
    cases: Sequence[RtuCase], duration_s: float, warmup_s: float, seed: int
) -> list[dict[str, Any]]:
    print_rtu_header()
    rows = []
    for case in cases:
        today_plan = whole_map_plan(case.register_map, case.fast, case.slow)
        plans = {
            "today": str(len(today_plan)),
            "groups": f"{len(case.fast)}+{len(case.slow)}/{SLOW_PERIOD_S:g}s",
        }
        row: dict[str, Any] = {
            "case": case.label,
            "kind": case.kind,
            "baudrate": case.baudrate,
            "drives": case.drives,
            "reply_delay_ms": case.reply_delay_s * 1e3,
            "fast_wire_ms": fast_wire_s(case) * 1e3,
            "fast_wire_ms_bridge_core": fast_wire_s_bridge_core(case) * 1e3,
            "requests_per_poll": plans,
        }
        if abs(fast_wire_s(case) - fast_wire_s_bridge_core(case)) > WIRE_CHECK_S:
            print(
                f"  note: wire arithmetic differs: rtu_wire {row['fast_wire_ms']:.3f} ms, "
                f"bridge_core {row['fast_wire_ms_bridge_core']:.3f} ms per fast poll"
            )
        for plan, whole in (("today", True), ("groups", False)):
            row[plan] = rtu_run(case, whole, duration_s, warmup_s, seed)
            print_rtu_row(case.label, plan, plans[plan], row[plan], row.get("today"))
        rows.append(row)
    print()
    return rows


RTU_HEAD = (
    f"{'case':<20} {'plan':<6} {'req/poll':>9} {'polls/s/dev':>11} {'min':>6} "
    f"{'fast wire/s':>11} {'of wire':>7} {'x today':>7} {'line':>5} {'cpu ms/poll':>11} "
    f"{'p50/p99 ms (n, miss)':>22} {'err':>3} {'viol':>4}"
)


def print_rtu_header() -> None:
    print(
        "RTU, emulated byte-timed line, device layer (NodePoller, polls back to back; no "
        f"ROS node): today = whole map every poll, groups = fast every poll + slow every "
        f"{SLOW_PERIOD_S:g} s; latency = register change -> snapshot (device layer)"
    )
    print(RTU_HEAD)
    print("-" * len(RTU_HEAD))


def print_rtu_row(
    label: str, plan: str, requests: str, r: dict[str, Any], today: dict[str, Any] | None
) -> None:
    lat, run = r["latency"], r["run"]
    gain = (
        f"{r['polls_per_s_per_drive'] / today['polls_per_s_per_drive']:.2f}"
        if today is not None and plan != "today" and today["polls_per_s_per_drive"]
        else ""
    )
    print(
        f"{label:<20} {plan:<6} {requests:>9} {r['polls_per_s_per_drive']:>11.2f} "
        f"{r['polls_per_s_slowest_drive']:>6.2f} {r['fast_wire_limit_per_drive']:>11.2f} "
        f"{r['of_fast_wire_limit']:>7.3f} {gain:>7} {run['ratio']:>5.2f} "
        f"{run['client_cpu_ms_per_poll']:>11.3f} {latency_cell(lat):>22} "
        f"{run['errors']:>3} {run['violations']:>4}",
        flush=True,
    )


def latency_cell(lat: dict[str, Any]) -> str:
    if not lat["n"]:
        return f"- (0, {lat['missed']})"
    return f"{lat['p50_ms']:.1f}/{lat['p99_ms']:.1f} ({lat['n']}, {lat['missed']})"


# ---------------------------------------------------------------- TCP


def tcp_point(
    name: str,
    round_trip_ms: float,
    windows: Sequence[int],
    duration_s: float,
    repeats: int,
    seed: int,
) -> dict[str, Any]:
    """Bare loop and device layer per window at one round trip, medians over ``repeats``
    rounds (each window once per round, in turn, as pipelining.py measures)."""
    low, high = JOINT_RANGES[name]
    with controlled_simulator(name, round_trip_ms) as (port, control):
        fast, slow = device_groups(name, port)
        probes = {
            w: ChangeProbe(control, JOINT_READERS[name], low, high, seed=seed + w) for w in windows
        }
        runs: dict[str, list[tuple[float, ...]]] = {"bare": [], **{str(w): [] for w in windows}}
        for _ in range(repeats):
            runs["bare"].append(bare_rate(name, port, duration_s, fast, slow, SLOW_PERIOD_S))
            for w in windows:
                with probes[w].running():
                    runs[str(w)].append(device_rate(name, port, w, duration_s, probes[w].observe))
    row: dict[str, Any] = {
        "device": name,
        "round_trip_ms": round_trip_ms,
        "requests_per_poll": f"{len(fast)}+{len(slow)}/{SLOW_PERIOD_S:g}s",
    }
    for key, samples in runs.items():
        row[key] = {
            "polls_per_s": statistics.median(s[0] for s in samples),
            "cpu_us_per_poll": statistics.median(s[1] for s in samples) * 1e6,
        }
        if key != "bare":
            row[key]["transaction_ms"] = statistics.median(s[2] for s in samples) * 1e3
            row[key]["fallbacks"] = max(int(s[3]) for s in samples)
            row[key]["latency"] = latency(probes[int(key)])
    return row


TCP_HEAD = (
    f"{'device':<6} {'rtt ms':>6} {'tx ms':>6} {'loop':<6} {'req/poll':>9} {'polls/s':>8} "
    f"{'x N=1':>6} {'x bare':>6} {'cpu us/poll':>11} {'p50/p99 ms (n, miss)':>22} {'fb':>3}"
)


def tcp_part(
    devices: Sequence[str],
    round_trips: Sequence[float],
    windows: Sequence[int],
    duration_s: float,
    repeats: int,
    seed: int,
) -> list[dict[str, Any]]:
    print(
        "TCP, device layer (R6Device / XArmDevice.poll back to back, the slow group once a "
        f"second) by max_in_flight N, and a bare pymodbus loop of the same plan; "
        f"latency = register change -> snapshot (device layer); medians of {repeats} "
        f"round(s) of {duration_s:g} s"
    )
    print(TCP_HEAD)
    print("-" * len(TCP_HEAD))
    rows = []
    for name in devices:
        for rtt in round_trips:
            row = tcp_point(name, rtt, windows, duration_s, repeats, seed)
            print_tcp_row(row, windows)
            rows.append(row)
    print()
    return rows


def print_tcp_row(row: dict[str, Any], windows: Sequence[int]) -> None:
    one = row[str(windows[0])]["polls_per_s"] if windows else float("nan")
    bare = row["bare"]["polls_per_s"]
    tx = row[str(windows[0])]["transaction_ms"] if windows else float("nan")
    for key in ("bare", *(str(w) for w in windows)):
        r = row[key]
        loop = "bare" if key == "bare" else f"N={key}"
        lat = latency_cell(r["latency"]) if "latency" in r else "-"
        fallbacks = str(r["fallbacks"]) if "fallbacks" in r else "-"
        print(
            f"{row['device']:<6} {row['round_trip_ms']:>6g} {tx:>6.2f} {loop:<6} "
            f"{row['requests_per_poll']:>9} {r['polls_per_s']:>8.1f} "
            f"{r['polls_per_s'] / one:>6.2f} {r['polls_per_s'] / bare:>6.2f} "
            f"{r['cpu_us_per_poll']:>11.0f} {lat:>22} {fallbacks:>3}",
            flush=True,
        )


# ---------------------------------------------------------------- node (bridge_bench)


def node_cases(
    choice: str, devices: Sequence[str], round_trips: Sequence[float], windows: Sequence[int]
) -> list[tuple[str, float, int]]:
    if choice == "none" or not round_trips or not windows:
        return []
    if choice == "some":
        name = "r6" if "r6" in devices else devices[0]
        return [(name, max(round_trips), w) for w in sorted({min(windows), max(windows)})]
    return [(d, rtt, w) for d in devices for rtt in round_trips for w in windows]


def node_point(
    client: bridge_bench.BenchClient,
    procs: bridge_bench.Processes,
    name: str,
    round_trip_ms: float,
    window: int,
    duration_s: float,
    warmup_s: float,
    changes: int,
    domain_id: int,
    seed: int,
) -> dict[str, Any]:
    """The bridge node at one round trip and ``max_in_flight``: bridge_bench's rate
    measure (no subscriber) and its latency phase (the service part cut to one call)."""
    opts = bridge_bench.parse_args(
        [
            "--device",
            name,
            "--duration",
            str(duration_s),
            "--warmup",
            str(warmup_s),
            "--changes",
            str(changes),
            "--service-calls",
            "1",
            "--domain-id",
            str(domain_id),
            "--seed",
            str(seed),
            "--reply-delay-ms",
            str(round_trip_ms),
            "--max-in-flight",
            str(window),
        ]
    )
    profile = opts.profile
    sim_proc, port = bridge_bench.start_sim_process(procs, profile, opts.sim_extra)
    try:
        # The node's read plan: its device's rate groups (the node's polls are its
        # transactions less the slow group's, over the fast group's requests).
        plan = bridge_bench.device_plan(profile, port)
        argv = bridge_bench.node_argv(profile, port, NODE_RATE_HZ)
        with procs.running(f"read_rates_{name}_{round_trip_ms:g}ms_n{window}", argv) as proc:
            node = bridge_bench.measure_node(
                client,
                proc.pid,
                package=profile.package,
                duration=opts.duration,
                warmup=opts.warmup,
                plan=plan,
                sim_pid=sim_proc.pid,
                subscribe_joint_states=False,
            )
    finally:
        procs.stop(sim_proc)
    with contextlib.redirect_stdout(io.StringIO()):  # its progress lines, not our table's
        lat = bridge_bench.phase_latency(opts, procs, client)
    return {
        "device": name,
        "round_trip_ms": round_trip_ms,
        "max_in_flight": window,
        "node": node,
        "latency": {
            **lat["register_to_joint_states"],
            "what": "register change -> joint_states (node at 100 Hz)",
        },
    }


NODE_HEAD = (
    f"{'device':<6} {'rtt ms':>6} {'N':>3} {'polls/s':>8} {'diag Hz':>8} {'cpu us/poll':>11} "
    f"{'joint_states p50/p99 ms (n, miss)':>34}"
)


def node_part(
    cases: Sequence[tuple[str, float, int]],
    duration_s: float,
    warmup_s: float,
    changes: int,
    domain_id: int,
    seed: int,
) -> list[dict[str, Any]]:
    print(
        f"node (bridge_bench.py): poll rate at poll_rate_hz {NODE_RATE_HZ:g}, no subscriber "
        "(the node's transactions less its slow group's / its fast requests per poll), "
        "CPU from /proc; latency = "
        "register change -> joint_states, node at 100 Hz"
    )
    bridge_bench.isolate_ros(domain_id)  # before rclpy is imported
    log_dir = bridge_bench.RESULTS / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    try:
        client = bridge_bench.BenchClient("read_rates_bench")
    except ImportError as err:
        print(f"  skipped: rclpy not importable ({err})\n")
        return []
    procs = bridge_bench.Processes(log_dir)
    rows = []
    try:
        print(NODE_HEAD)
        print("-" * len(NODE_HEAD))
        for name, rtt, window in cases:
            row = node_point(
                client, procs, name, rtt, window, duration_s, warmup_s, changes, domain_id, seed
            )
            node, lat = row["node"], row["latency"]
            print(
                f"{name:<6} {rtt:>6g} {window:>3} {node['rate_hz']:>8.1f} "
                f"{node['diagnostics_achieved_hz']:>8.1f} {node['cpu_us_per_cycle']:>11.0f} "
                f"{latency_cell(lat):>34}",
                flush=True,
            )
            rows.append(row)
    finally:
        procs.stop_all()
        with contextlib.suppress(Exception):
            client.close()
    print()
    return rows


# ---------------------------------------------------------------- main

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
