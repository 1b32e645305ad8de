#!/usr/bin/env python3
"""Lifeguard feed gaps on a MOTEC bus with one drive dead: the margin the bridge keeps.

Measured before feeds had their own thread and went first on the line: three
drives, drive 3 unplugged, ``lifeguard_ms`` 500 and ``timeout_s`` 0.5: drives 1 and 2
faulted within 1.8 s; at 100 ms / 0.1 s the lifeguard tripped in 2 of 3 runs with every
drive alive. The bridge now refuses a lifeguard time below
``motec_bridge.lifeguard.lifeguard_min_ms`` (docs/bridges/motec.md, "Lifeguard"); this bench
runs it at exactly that floor, the hardest setting it accepts.

Setup: the MOTEC simulator (three drives at 115200 baud) in this process on a socat pty
pair, ``motec_bridge`` in a process of its own (10 Hz polls, ``lifeguard_ms`` = the
floor for the ``timeout_s`` under test). Drives 1 and 2 are put in network mode,
velocity control, enabled, straight in the simulator (the lifeguard only watches network
mode). Phases of ``--seconds`` each: every drive alive, then drive 3 unplugged (first a
read and its retry time out, then every reconnect probe holds the line a whole timeout).
For drives 1 and 2: the gaps between consecutive writes the simulator accepted (any
write feeds the lifeguard), as median / 99th percentile / max and max as a share of
``lifeguard_ms``, and lifeguard trips. ``--burners N`` runs N CPU-bound processes beside
it. Prints a table; asserts nothing. Only ptys; ROS discovery on localhost.

    .venv/bin/python bench/lifeguard_gaps.py [--seconds 10] [--timeouts 0.1,0.5] [--burners 2]
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing
import os
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

UNITS = (1, 2, 3)
WATCHED = (1, 2)
DEAD = 3
BAUD = 115200
POLL_RATE_HZ = 10.0


def burn() -> None:
    while True:
        pass


def percentile(values: list[float], share: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(share * (len(ordered) - 1)))]


def armed(drive: Any) -> bool:
    return bool(drive.value("lifeguard_mode") == 9999)


def run(timeout_s: float, seconds: float) -> list[tuple[str, int, list[str]]]:
    """Both phases at one timeout; rows of (phase, lifeguard_ms, one cell per drive)."""
    from bridge_core.wire.transport import SerialSettings
    from motec_bridge.lifeguard import lifeguard_min_ms
    from motec_bridge.registers import CONTROL_MODE_VELOCITY, OPERATION_MODE_NETWORK
    from motec_bridge.sim import make_simulator
    from tests.support.ros import node_process, wait_for
    from tests.support.serial_pair import served_on_pty

    hold_s = SerialSettings("", BAUD, timeout_s=timeout_s).longest_hold_s()
    lifeguard_ms = lifeguard_min_ms(len(UNITS), hold_s)
    simulator = make_simulator(UNITS)
    rows: list[tuple[str, int, list[str]]] = []
    with tempfile.TemporaryDirectory() as logs, served_on_pty(simulator, BAUD) as port:
        params = {
            "serial_port": port,
            "baudrate": BAUD,
            "unit_ids": list(UNITS),
            "timeout_s": timeout_s,
            "poll_rate_hz": POLL_RATE_HZ,
            "lifeguard_ms": lifeguard_ms,
        }
        with node_process("motec_bridge.node", params, Path(logs)):
            drives = [simulator.drive(unit) for unit in UNITS]
            wait_for(lambda: all(map(armed, drives)), 60, "the bridge to arm every lifeguard")
            for unit in WATCHED:
                drive = simulator.drive(unit)
                with drive.lock:
                    drive.set("operation_mode", OPERATION_MODE_NETWORK)
                    drive.set("control_mode", CONTROL_MODE_VELOCITY)
                    drive.set("enable", 1)
            for phase in ("all alive", f"drive {DEAD} dead"):
                if phase != "all alive":
                    simulator.unplug(DEAD)
                start = time.time()  # the simulator stamps its write log with time.time()
                trips = {u: simulator.drive(u).lifeguard_trips for u in WATCHED}
                time.sleep(seconds)
                cells = []
                for unit in WATCHED:
                    drive = simulator.drive(unit)
                    times = [r.time for r in drive.write_log if r.time >= start]
                    gaps = [b - a for a, b in itertools.pairwise(times)] or [seconds]
                    worst, p99 = max(gaps), percentile(gaps, 0.99)
                    if worst > lifeguard_ms / 1000.0:
                        at = times[gaps.index(worst)] - start
                        print(
                            f"{phase}, drive {unit}: {worst:.3f} s without a write from +{at:.3f} s"
                        )
                    cells.append(
                        f"{statistics.median(gaps) * 1000:6.0f} {p99 * 1000:6.0f}"
                        f" {worst * 1000:6.0f} {worst * 100000 / lifeguard_ms:4.0f}%"
                        f" {drive.lifeguard_trips - trips[unit]:3d}"
                    )
                rows.append((phase, lifeguard_ms, cells))
        log = (Path(logs) / "motec_bridge_node.log").read_text()
        losses = [
            line for line in log.splitlines() if " lost" in line and f"unit {DEAD}" not in line
        ]
        for line in losses:  # a live drive that looked dead: its feeds stop until it is back
            print(f"timeout_s {timeout_s}: {line}")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each phase")
    parser.add_argument("--timeouts", default="0.1,0.5", help="timeout_s values to run")
    parser.add_argument("--burners", type=int, default=0, help="CPU-bound processes beside")
    args = parser.parse_args()
    burners = [multiprocessing.Process(target=burn, daemon=True) for _ in range(args.burners)]
    for burner in burners:
        burner.start()
    try:
        results = [(float(t), run(float(t), args.seconds)) for t in args.timeouts.split(",")]
    finally:
        for burner in burners:
            burner.terminate()
    print(
        f"motec_bridge, 3 drives at {BAUD} baud, {POLL_RATE_HZ:g} Hz polls, lifeguard_ms at the "
        f"floor, {args.seconds:g} s per phase, {args.burners} CPU burner(s)"
    )
    print("gaps between writes to a drive (ms): median p99 max, max / lifeguard_ms, trips")
    header = "".join(f"  {f'drive {u}':>31s}" for u in WATCHED)
    print(f"{'timeout_s':>9s} {'lifeguard':>9s} {'phase':14s}{header}")
    for timeout_s, rows in results:
        for phase, lifeguard_ms, cells in rows:
            line = "".join(f"  {cell:>31s}" for cell in cells)
            print(f"{timeout_s:9.1f} {lifeguard_ms:7d}ms {phase:14s}{line}")


if __name__ == "__main__":
    main()
