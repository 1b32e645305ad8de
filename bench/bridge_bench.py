#!/usr/bin/env python3
"""Bridge benchmark: poll rate, latency and CPU per cycle, as ratios
(docs/architecture.md, "Performance: how it is measured").

One bench for the TCP bridges, ``--device r6`` (default), ``--device xarm``, or
``--device modbus`` (modbus_bridge with config/devices/xarm.yaml, against the xArm's own
simulator: the bare loop then reads the generic bridge's poll plan), against that
bridge's simulator. Prints figures and writes them to
bench/results/<device>_bench.json; asserts nothing.

    .venv/bin/python bench/bridge_bench.py [--device r6|xarm|modbus] [--duration 5] [--quick]
        [--domain-id 101] [--phases rate,latency,cpu] [--json PATH]

(bench/r6_bench.py is the same bench under its old name.) Figures (see bench/README.md):
1. rate: a bare pymodbus loop issuing the node's read plan as fast as it can, the
   device layer (<Device>.poll) likewise, and the bridge node at poll_rate_hz 1000; ratio
   node rate / bare rate (goal >= 0.8), CPU per cycle of each. The read plan is the
   device's own rate groups (``<device>.groups`` after a first poll against the
   simulator, as the node sets them): the fast group every poll, the slow group first in
   a poll once ``slow_poll_period_s`` (the node's default) has passed, as ``PollGroups``
   does. The node's polls are counted from its own diagnostics: its transactions less the
   slow group's (``slow group``: requests, period, when last read), over the fast group's
   requests; its "achieved poll rate (Hz)" is printed beside them.
2. latency: register change in the simulator -> first joint_states carrying it (node at
   100 Hz; goal p99 <= poll period + 2 ms), and a command service call (R6
   ~/set_global_speed, xArm ~/set_digital_output) -> write in the simulator's write log.
3. cpu: at 100 Hz, node CPU per poll cycle vs floor A (bare rclpy publisher of the same
   three messages, bench/floor_rclpy_publisher.py) + floor B (bare pymodbus loop paced
   at 100 Hz); ratio node / (A + B) (goal <= 1.2).

Every measured loop runs in a process of its own (CPU from time.process_time inside it,
or from /proc/<pid>/stat utime+stime from outside); the simulator runs in a separate
process except in the latency phase, which changes its registers directly. Every ROS
process gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and ROS_DOMAIN_ID=--domain-id
(default 101: the tests use 1 + pid % 100; 0-101 or 215-232, see ``DOMAIN_ID_RULE``).
Only 127.0.0.1 is used.

This script is the command line and the report; the parts live beside it, one job each:
bench/bridge_profiles.py (what differs per bridge), bench/bare_loops.py (the read plan
and the loops without ROS, in worker processes this script runs with ``--worker``),
bench/node_measure.py (the node's rate and CPU from its diagnostics), bench/rate_phase.py,
bench/latency_phase.py and bench/cpu_phase.py (the phases), bench/bench_processes.py (the
child processes).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
import platform
import sys
import time
from contextlib import suppress
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# Nothing ROS-related is imported at module level, here or in the parts: the worker
# processes (bare pymodbus loop, device loop) must not pay for rclpy, and the
# environment must be set first.
from bench.bare_loops import ReadPlan, device_plan, run_worker  # noqa: E402
from bench.bench_processes import (  # noqa: E402
    Processes,
    loadavg,
    log,
    node_argv,
    start_sim_process,
)
from bench.bridge_profiles import PROFILES  # noqa: E402
from bench.cpu_phase import phase_cpu  # noqa: E402
from bench.latency_phase import latency_stats, phase_latency  # noqa: E402
from bench.node_measure import BenchClient, measure_node, slow_group_status  # noqa: E402
from bench.rate_phase import MAX_RATE_HZ, phase_rate  # noqa: E402

# What other bench scripts and tests/bench/test_bridge_bench.py import from here.
__all__ = [
    "MAX_RATE_HZ",
    "PROFILES",
    "RESULTS",
    "BenchClient",
    "Processes",
    "ReadPlan",
    "device_plan",
    "isolate_ros",
    "latency_stats",
    "loadavg",
    "main",
    "measure_node",
    "node_argv",
    "parse_args",
    "phase_latency",
    "slow_group_status",
    "start_sim_process",
]

DEFAULT_DOMAIN_ID = 101
# ROS 2's "About Domain ID" page: with the default RTPS ports (7400 + 250 x domain id + a
# few per participant) ids 102-214 fall inside Linux's ephemeral ports (32768-60999), which
# the kernel hands to any socket, so a participant may fail to bind; above 232 the port
# passes 65535. 215-232 are safe but leave room for fewer participants per machine.
DOMAIN_IDS = (range(0, 102), range(215, 233))
DOMAIN_ID_RULE = (
    "0-101 or 215-232: with ROS 2's default ports ids 102-214 land in Linux's ephemeral "
    "ports 32768-60999 and may fail to bind (ROS 2 docs, 'About Domain ID')"
)
RESULTS = ROOT / "bench" / "results"


# ====================================================================== report


def fmt(value: Any, digits: int = 1) -> str:
    if isinstance(value, float):
        return "n/a" if math.isnan(value) else f"{value:.{digits}f}"
    return str(value)


def print_table(results: dict[str, Any]) -> None:
    meta = results["meta"]
    p = PROFILES[meta["device"]]
    print()
    print(
        f"{p.title} bench {meta['date']}  {meta['machine']}  duration {meta['duration_s']} s/phase"
        f"  load {meta['loadavg_before']} -> {meta['loadavg_after']}"
    )
    if "read_plan" in meta:
        plan = ReadPlan.from_json(meta["read_plan"])
        print(
            f"read plan of the node and the bare loops (the device's rate groups): "
            f"{plan.describe()}"
        )
    rows: list[tuple[str, str, str, str, str]] = []
    if "rate" in results:
        r = results["rate"]
        for key, label in (
            ("bare_pymodbus", "1a bare pymodbus loop, max"),
            ("device_loop", f"1  {p.device_class}.poll() loop, max (context)"),
            ("node_1000", f"1b {p.package}, poll_rate_hz 1000, no subscriber"),
            ("node_1000_subscribed", f"   {p.package}, 1000 Hz, bench subscribed (context)"),
        ):
            m = r[key]
            rows.append(
                (
                    label,
                    fmt(m["rate_hz"]),
                    fmt(m["cpu_us_per_cycle"], 0),
                    fmt(m["cpu_percent"]),
                    fmt(m["sim_cpu_percent"], 0),
                )
            )
        m = r["node_1000"]
        rows.append(
            (
                f"   1b counted, last {fmt(m['diagnostics_window_s'])} s / node's diagnostics "
                f"({m['diagnostics_rate_window_s']:g} s)",
                f"{fmt(m['rate_over_diagnostics_window_hz'])} / "
                f"{fmt(m['diagnostics_achieved_hz'])}",
                "",
                "",
                "",
            )
        )
        n = r["node_1000_subscribed"]
        rows.append(
            (
                "   subscribed: joint_states received / diag achieved",
                f"{fmt(n['joint_states_received_hz'])} / {fmt(n['diagnostics_achieved_hz'])}",
                "",
                "",
                "",
            )
        )
    if "cpu" in results:
        c = results["cpu"]
        rows.append(
            (
                f"3  {p.package} at 100 Hz",
                fmt(c["node"]["rate_hz"]),
                fmt(c["node"]["cpu_us_per_cycle"], 0),
                fmt(c["node"]["cpu_percent"]),
                fmt(c["node"]["sim_cpu_percent"], 0),
            )
        )
        rows.append(
            (
                "3  floor A: rclpy publisher, 100 Hz",
                fmt(c["floor_a_rclpy"]["rate_hz"]),
                fmt(c["floor_a_rclpy"]["cpu_us_per_cycle"], 0),
                fmt(c["floor_a_rclpy"]["cpu_percent"]),
                "",
            )
        )
        for key, m in c.items():
            if key.startswith("floor_a_rclpy_") and isinstance(m, dict):
                name = key.removeprefix("floor_a_rclpy_").removesuffix("_executor")
                rows.append(
                    (
                        f"   floor A with {name} executor (context)",
                        fmt(m["rate_hz"]),
                        fmt(m["cpu_us_per_cycle"], 0),
                        fmt(m["cpu_percent"]),
                        "",
                    )
                )
        rows.append(
            (
                "3  floor B: pymodbus loop paced 100 Hz",
                fmt(c["floor_b_pymodbus"]["rate_hz"]),
                fmt(c["floor_b_pymodbus"]["cpu_us_per_cycle"], 0),
                fmt(c["floor_b_pymodbus"]["cpu_percent"]),
                fmt(c["floor_b_pymodbus"]["sim_cpu_percent"], 0),
            )
        )
    if rows:
        width = max(len(r[0]) for r in rows)
        head = ("cycles/s", "CPU us/cycle", "CPU %core", "sim %core")
        print(f"{'loop':<{width}}  {head[0]:>14}  {head[1]:>12}  {head[2]:>9}  {head[3]:>9}")
        for label, rate, cpu, pct, sim in rows:
            print(f"{label:<{width}}  {rate:>14}  {cpu:>12}  {pct:>9}  {sim:>9}")
        print()
    figures: list[tuple[str, str, str, str]] = []  # figure, value, goal, note

    def verdict(ok: bool) -> str:
        return "met" if ok else "MISSED"

    if "rate" in results:
        r = results["rate"]
        ratio, goal = r["ratio_node_to_bare"], r["goal_ratio_min"]
        figures.append(
            (
                "1  rate node(1000 Hz) / bare pymodbus",
                f"{ratio:.2f}",
                f">= {goal} {verdict(ratio >= goal)}",
                f"from the node's diagnostics (achieved poll rate) "
                f"{r['ratio_node_diagnostics_to_bare']:.2f}; device loop / bare "
                f"{r['ratio_device_to_bare']:.2f}; with the bench subscribed to "
                f"joint_states {r['ratio_node_subscribed_to_bare']:.2f}",
            )
        )
    if "latency" in results:
        lat = results["latency"]
        reg, fl = lat["register_to_joint_states"], lat["poll_start_to_joint_states"]
        goal = lat["goal_p99_max_ms"]
        figures.append(
            (
                "2  register -> joint_states p50/p99/max ms",
                f"{fmt(reg['p50_ms'])}/{fmt(reg['p99_ms'])}/{fmt(reg['max_ms'])}",
                f"p99 <= {goal:g} {verdict(reg['p99_ms'] <= goal)}",
                f"n {reg['n']}, missed {reg['missed']}; poll start -> msg "
                f"p50/p99 {fmt(fl['p50_ms'])}/{fmt(fl['p99_ms'])}",
            )
        )
        sw, sr = lat["service_call_to_register_write"], lat["service_call_to_response"]
        figures.append(
            (
                "2  service call -> register write p50/p99 ms",
                f"{fmt(sw['p50_ms'], 2)}/{fmt(sw['p99_ms'], 2)}",
                "",
                f"n {sw['n']}, failed {sw['failed']}; call -> response "
                f"p50/p99 {fmt(sr['p50_ms'], 2)}/{fmt(sr['p99_ms'], 2)}",
            )
        )
    if "cpu" in results:
        c = results["cpu"]
        ratio, goal = c["ratio_node_to_floors"], c["goal_ratio_max"]
        figures.append(
            (
                "3  CPU/cycle node / (floor A + floor B)",
                f"{ratio:.2f}",
                f"<= {goal} {verdict(ratio <= goal)}",
                f"{fmt(c['node']['cpu_us_per_cycle'], 0)} / "
                f"({fmt(c['floor_a_rclpy']['cpu_us_per_cycle'], 0)} + "
                f"{fmt(c['floor_b_pymodbus']['cpu_us_per_cycle'], 0)}) us",
            )
        )
    if figures:
        fw = max(len(f[0]) for f in figures)
        vw = max(len(f[1]) for f in figures)
        gw = max(len(f[2]) for f in figures)
        print(f"{'figure':<{fw}}  {'value':>{vw}}  {'goal':<{gw}}  note")
        for name, value, goal_text, note in figures:
            print(f"{name:<{fw}}  {value:>{vw}}  {goal_text:<{gw}}  {note}")
    print()


# ====================================================================== main


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description="Bridge benchmark (prints figures)")
    parser.add_argument(
        "--device", choices=sorted(PROFILES), default="r6", help="bridge to measure (default r6)"
    )
    parser.add_argument("--duration", type=float, default=5.0, help="measured seconds per phase")
    parser.add_argument(
        "--warmup",
        type=float,
        default=None,
        help="discarded seconds before each measurement (default 1, quick 0.3)",
    )
    parser.add_argument("--quick", action="store_true", help="~1 s phases, fewer latency samples")
    parser.add_argument(
        "--domain-id",
        type=int,
        default=DEFAULT_DOMAIN_ID,
        help=f"ROS_DOMAIN_ID for the bench and its nodes (default {DEFAULT_DOMAIN_ID})",
    )
    parser.add_argument(
        "--phases", default="rate,latency,cpu", help="comma-separated subset of rate,latency,cpu"
    )
    parser.add_argument("--changes", type=int, default=None, help="register changes (default 200)")
    parser.add_argument(
        "--service-calls", type=int, default=None, help="service calls (default 100)"
    )
    parser.add_argument(
        "--extra-executors",
        default="multi,events",
        help="also measure floor A with these executors (comma list of multi,events; '' for none)",
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--reply-delay-ms",
        type=float,
        default=0.0,
        help="the simulator's simulated round trip (bench/pipelining.py)",
    )
    parser.add_argument(
        "--max-in-flight", type=int, default=1, help="the node's max_in_flight (default 1)"
    )
    parser.add_argument(
        "--nagle",
        action="store_true",
        help="the simulator leaves Nagle on for its replies (its --nagle personality)",
    )
    parser.add_argument(
        "--json", type=Path, default=None, help="default bench/results/<device>_bench.json"
    )
    # worker mode (internal)
    parser.add_argument("--worker", choices=("bare", "device"), help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--rate", type=float, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument("--slices", type=int, default=5, help=argparse.SUPPRESS)
    parser.add_argument("--sim-pid", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--plan", default="", help=argparse.SUPPRESS)  # ReadPlan as JSON
    opts = parser.parse_args(argv)
    opts.profile = PROFILES[opts.device]
    opts.sim_extra = ("--reply-delay-ms", str(opts.reply_delay_ms)) if opts.reply_delay_ms else ()
    if opts.nagle:
        opts.sim_extra = (*opts.sim_extra, "--nagle")
    if opts.max_in_flight != 1:
        opts.profile = dataclasses.replace(
            opts.profile,
            node_params=(*opts.profile.node_params, f"max_in_flight:={opts.max_in_flight}"),
        )
    opts.json = opts.json or RESULTS / f"{opts.device}_bench.json"
    if opts.quick:
        if "--duration" not in (argv if argv is not None else sys.argv):
            opts.duration = 1.0
        opts.changes = opts.changes or 40
        opts.service_calls = opts.service_calls or 20
        opts.warmup = 0.3 if opts.warmup is None else opts.warmup
    opts.changes = opts.changes or 200
    opts.service_calls = opts.service_calls or 100
    opts.warmup = 1.0 if opts.warmup is None else opts.warmup
    opts.extra_executors = [e for e in opts.extra_executors.split(",") if e]
    if not any(opts.domain_id in ids for ids in DOMAIN_IDS):
        parser.error(f"--domain-id {opts.domain_id}: use {DOMAIN_ID_RULE}")
    return opts


def isolate_ros(domain_id: int) -> None:
    """ROS discovery on this machine, in ``domain_id``: before rclpy is imported anywhere;
    inherited by every child process (bench/read_rates.py calls it too)."""
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.setdefault("PYTHONUNBUFFERED", "1")


def main(argv: list[str] | None = None) -> None:
    opts = parse_args(argv)
    if opts.worker:
        run_worker(opts)
        return
    isolate_ros(opts.domain_id)
    phases = [p.strip() for p in opts.phases.split(",") if p.strip()]
    unknown = set(phases) - {"rate", "latency", "cpu"}
    if unknown:
        raise SystemExit(f"unknown phases {sorted(unknown)}")

    import pymodbus

    RESULTS.mkdir(parents=True, exist_ok=True)
    log_dir = RESULTS / "logs"
    log_dir.mkdir(exist_ok=True)
    results: dict[str, Any] = {
        "meta": {
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "machine": f"{platform.node()} {os.cpu_count()} CPU {platform.machine()}",
            "python": platform.python_version(),
            "pymodbus": pymodbus.__version__,
            "duration_s": opts.duration,
            "warmup_s": opts.warmup,
            "quick": opts.quick,
            "ros_domain_id": opts.domain_id,
            "device": opts.device,
            "loadavg_before": loadavg(),
        }
    }
    log(
        f"{opts.device} bench: domain {opts.domain_id}, {opts.duration} s per phase, "
        f"phases {','.join(phases)}; logs in {log_dir}"
    )
    procs = Processes(log_dir)
    client = BenchClient(f"{opts.device}_bench")
    started = time.monotonic()
    try:
        if "rate" in phases or "cpu" in phases:
            sim_proc, sim_port = start_sim_process(procs, opts.profile, opts.sim_extra)
            try:
                plan = device_plan(opts.profile, sim_port)
                results["meta"]["read_plan"] = plan.to_json()
                log(f"read plan (the device's rate groups): {plan.describe()}")
                args = (opts, procs, client, sim_port, sim_proc.pid, plan)
                if "rate" in phases:
                    results["rate"] = phase_rate(*args)
                if "cpu" in phases:
                    results["cpu"] = phase_cpu(*args)
            finally:
                procs.stop(sim_proc)
        if "latency" in phases:
            results["latency"] = phase_latency(opts, procs, client)
    finally:
        procs.stop_all()
        with suppress(Exception):
            client.close()
    results["meta"]["loadavg_after"] = loadavg()
    results["meta"]["elapsed_s"] = round(time.monotonic() - started, 1)
    print_table(results)
    opts.json.parent.mkdir(parents=True, exist_ok=True)
    opts.json.write_text(json.dumps(results, indent=2) + "\n")
    log(f"wrote {opts.json}")


if __name__ == "__main__":
    main()
