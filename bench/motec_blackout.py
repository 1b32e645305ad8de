#!/usr/bin/env python3
"""MOTEC lifeguard across line blackouts: does a drive trip when its line goes dark?

Measured before the feeds went on while a drive is marked down: with
``config/motec.yaml`` (three drives, ``lifeguard_ms`` 1000, ``timeout_s`` 0.1) a 600 ms
blackout left a drive 1.29 s without a write: it faulted and released its motor. Now a
drive marked down is fed like a stop is sent (one try, the short stop timeout) every
feed period (333 ms), so a drive whose line comes back within lifeguard - feed period
(667 ms) of its last write is fed before it trips.

Setup: the MOTEC simulator (drives 1-3, in network mode so their lifeguard watches) in
this process, behind ``bench/line_relay.py`` (115200 baud, byte-timed), and
``motec_bridge`` in a process of its own with ``config/motec.yaml`` as shipped (only
``serial_port`` replaced). Per run the relay cuts the line both ways for the blackout,
``aligned`` (just after a write reached drive 1) or at a ``random`` phase. Per drive:
"silent before" = from its last write to the line's return, "gap" = from its last write
before to its first write after (the simulator's write log), and whether it tripped.
A tripped drive is power-cycled and set up again in the simulator. Prints a table;
asserts nothing. Only ptys; ROS discovery on localhost.

    .venv/bin/python bench/motec_blackout.py [--repeat 5] [--blackouts 300,600,900]
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "106")

UNITS = (1, 2, 3)
BAUD = 115200
LIFEGUARD_S = 1.0  # config/motec.yaml
FEED_PERIOD_S = LIFEGUARD_S / 3
WAIT_S = 30.0


@dataclass(frozen=True)
class Run:
    blackout_ms: int
    phase: str
    unit: int
    silent_before_s: float  # last write -> line back
    gap_s: float  # last write before -> first write after
    tripped: bool

    @property
    def claimed(self) -> bool:
        """Within the claim: the line back within lifeguard - feed period."""
        return self.silent_before_s <= LIFEGUARD_S - FEED_PERIOD_S


def armed(drive: Any) -> bool:
    return bool(drive.value("lifeguard_mode") == 9999)


def written_after(drive: Any, t: float) -> bool:
    return bool(drive.last_command > t)


def wait(predicate: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {what}")
        time.sleep(0.005)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per blackout and phase")
    parser.add_argument("--blackouts", default="300,600,900", help="blackout lengths, ms")
    parser.add_argument("--phases", default="aligned,random")
    parser.add_argument("--verbose", action="store_true", help="print every drive-run")
    args = parser.parse_args()
    blackouts = [int(b) for b in args.blackouts.split(",")]
    phases = args.phases.split(",")

    from bench.line_relay import LineRelay
    from motec_bridge.sim import MotecSimDrive, make_simulator
    from tests.support.ros import node_process

    def setup(drive: MotecSimDrive) -> None:
        for address, value in ((0x24, 0), (0x112, 1000), (0x114, 9999)):
            assert drive.write(6, address, [value]) is None

    runs: list[Run] = []
    simulator = make_simulator(UNITS)
    wall_offset = time.time() - time.monotonic()
    with LineRelay(BAUD) as line, tempfile.TemporaryDirectory() as tmp:
        simulator.start_serial(line.device_path, BAUD)
        config = (ROOT / "config" / "motec.yaml").read_text()
        params_file = Path(tmp) / "motec.yaml"
        params_file.write_text(config.replace('"/dev/ttyUSB0"', f'"{line.client_path}"'))
        try:
            with node_process(
                "motec_bridge.node", {}, Path(tmp), ["--params-file", str(params_file)]
            ):
                for unit in UNITS:
                    drive = simulator.drive(unit)
                    wait(partial(armed, drive), "the bridge to arm")
                    assert drive.write(6, 0x24, [0]) is None  # network mode
                drive_1 = simulator.drive(1)
                for blackout_ms in blackouts:
                    for phase in phases:
                        for _ in range(args.repeat):
                            time.sleep(0.5)  # every drive fed again since the last run
                            if phase == "aligned":
                                last = drive_1.last_command
                                wait(partial(written_after, drive_1, last), "a write")
                            else:
                                time.sleep(random.uniform(0.0, FEED_PERIOD_S))
                            trips = {u: simulator.drive(u).lifeguard_trips for u in UNITS}
                            dark_from, dark_until = line.blackout(blackout_ms / 1000.0)
                            for unit in UNITS:
                                drive = simulator.drive(unit)
                                wait(partial(written_after, drive, dark_until), "a write")
                            for unit in UNITS:
                                drive = simulator.drive(unit)
                                times = [r.time - wall_offset for r in drive.write_log]
                                last_before = max(t for t in times if t <= dark_from)
                                first_after = min(t for t in times if t > dark_until)
                                tripped = drive.lifeguard_trips != trips[unit]
                                runs.append(
                                    Run(
                                        blackout_ms,
                                        phase,
                                        unit,
                                        dark_until - last_before,
                                        first_after - last_before,
                                        tripped,
                                    )
                                )
                                if tripped:
                                    drive.power_cycle()
                                    setup(drive)
        finally:
            simulator.stop()

    if args.verbose:
        for r in runs:
            print(r)
    print(
        f"motec_bridge, config/motec.yaml (lifeguard 1000 ms, feed period 333 ms, timeout_s "
        f"0.1, 3 drives, {BAUD} baud on the emulated line), {args.repeat} runs per row, "
        "3 drives each"
    )
    print(
        f"{'blackout':>8s} {'phase':>8s} {'drive-runs':>10s} {'claimed':>8s} "
        f"{'trips (claimed)':>16s} {'max silent s':>12s} {'max gap s':>10s}"
    )
    for blackout_ms in blackouts:
        for phase in phases:
            rows = [r for r in runs if r.blackout_ms == blackout_ms and r.phase == phase]
            claimed = [r for r in rows if r.claimed]
            trip_count = sum(r.tripped for r in rows)
            claimed_trips = sum(r.tripped for r in claimed)
            print(
                f"{blackout_ms:>6d}ms {phase:>8s} {len(rows):>10d} {len(claimed):>8d} "
                f"{trip_count:>7d} ({claimed_trips:>d}){'':>6s} "
                f"{max(r.silent_before_s for r in rows):>12.3f} "
                f"{max(r.gap_s for r in rows):>10.3f}"
            )


if __name__ == "__main__":
    main()
