"""What ``record_wire`` costs: the R6 node's CPU per second at a 100 Hz poll rate against
its simulator over TCP, with the parameter off and on, A/B on one machine.

Three arms, run in turns (off, on, on with a subscriber; ``--rounds`` times) so that a
drift of the machine's load falls on all of them: ``off`` (the default: nothing
installed), ``on`` (frames published on ``~/wire``, nobody subscribed), ``on+sub`` (this
process subscribes to ``~/wire`` raw, as a recorder would: the frames are serialized and
sent). Each run: a fresh node, ``--warmup`` s, then the node process's utime+stime over
``--seconds`` s (/proc), and its own diagnostics (achieved poll rate, transactions, wire
frames published / dropped). Prints a table and writes JSON next to the logs.

    .venv/bin/python bench/wire_record.py            # ~2 min
    .venv/bin/python bench/wire_record.py --rounds 1 --seconds 5 --warmup 2   # quick
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_processes import (
    Processes,
    loadavg,
    log,
    node_argv,
    proc_cpu_s,
    start_sim_process,
    wait_until,
)
from bench.bridge_profiles import PROFILES
from bench.node_measure import BenchClient

RATE_HZ = 100.0
ARMS = ("off", "on", "on+sub")
WIRE_KEY = "wire frames published / dropped"


def run_arm(
    procs: Processes, client: BenchClient, port: int, arm: str, args: argparse.Namespace
) -> dict[str, Any]:
    from diagnostic_msgs.msg import DiagnosticArray

    from msg_defs.msg import ModbusFrame

    profile = PROFILES["r6"]
    argv = [*node_argv(profile, port, RATE_HZ), "-p", f"record_wire:={arm != 'off'}".lower()]
    latest: dict[str, str] = {}
    frames = [0]
    lock = threading.Lock()

    def on_diag(msg: Any) -> None:
        for status in msg.status:
            if status.name.lstrip("/").startswith(f"{profile.package}:"):
                with lock:
                    latest.clear()
                    latest.update({kv.key: kv.value for kv in status.values})

    def on_frame(_raw: Any) -> None:
        frames[0] += 1

    sub_d = client.node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    sub_w = (
        client.node.create_subscription(
            ModbusFrame, f"/{profile.package}/wire", on_frame, 100, raw=True
        )
        if arm == "on+sub"
        else None
    )
    try:
        with procs.running(f"{profile.package}_{arm.replace('+', '_')}", argv) as proc:
            wait_until(lambda: "transactions" in latest, 60, "the node's diagnostics")
            time.sleep(args.warmup)  # the window starts after start-up's reads settle
            with lock:
                t0 = float(latest["transactions"])
            cpu0, wall0, frames0 = proc_cpu_s(proc.pid), time.monotonic(), frames[0]
            time.sleep(args.seconds)  # the measuring window
            cpu1, wall1, frames1 = proc_cpu_s(proc.pid), time.monotonic(), frames[0]
            wait_until(lambda: float(latest.get("transactions", 0)) > t0, 10, "a later status")
            with lock:
                status = dict(latest)
    finally:
        client.node.destroy_subscription(sub_d)
        if sub_w is not None:
            client.node.destroy_subscription(sub_w)
    window = wall1 - wall0
    return {
        "arm": arm,
        "cpu_percent": 100.0 * (cpu1 - cpu0) / window,
        "achieved_hz": float(status.get("achieved poll rate (Hz)", "nan")),
        "wire": status.get(WIRE_KEY, "-"),
        "frames_received_per_s": (frames1 - frames0) / window,
        "window_s": window,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--warmup", type=float, default=3.0)
    args = parser.parse_args()
    log_dir = Path(tempfile.mkdtemp(prefix="wire_record_"))
    procs = Processes(log_dir)
    client = BenchClient("wire_record_bench")
    results: list[dict[str, Any]] = []
    try:
        sim, port = start_sim_process(procs, PROFILES["r6"])
        log(f"r6 simulator on port {port}; logs in {log_dir}; load {loadavg()}")
        for round_no in range(args.rounds):
            for arm in ARMS:
                result = run_arm(procs, client, port, arm, args)
                result["round"] = round_no + 1
                results.append(result)
                log(
                    f"round {round_no + 1} {arm:7s} CPU {result['cpu_percent']:5.1f} %  "
                    f"poll {result['achieved_hz']:6.1f} Hz  wire {result['wire']}  "
                    f"frames received {result['frames_received_per_s']:.0f}/s"
                )
        procs.stop(sim)
    finally:
        procs.stop_all()
        client.close()
    print(f"\nR6 node at {RATE_HZ:g} Hz over TCP, CPU per second of the node process")
    print(f"(median of {args.rounds} runs of {args.seconds:g} s each; load {loadavg()})")
    print(f"{'record_wire':12s} {'CPU %':>7s} {'poll Hz':>8s}")
    off = statistics.median(r["cpu_percent"] for r in results if r["arm"] == "off")
    for arm in ARMS:
        cpu = statistics.median(r["cpu_percent"] for r in results if r["arm"] == arm)
        hz = statistics.median(r["achieved_hz"] for r in results if r["arm"] == arm)
        extra = "" if arm == "off" else f"  (+{cpu - off:.1f} points)"
        print(f"{arm:12s} {cpu:7.1f} {hz:8.1f}{extra}")
    out = log_dir / "wire_record.json"
    out.write_text(json.dumps(results, indent=1))
    print(f"JSON: {out}")


if __name__ == "__main__":
    main()
