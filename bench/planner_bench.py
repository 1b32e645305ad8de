#!/usr/bin/env python3
"""Read planner figures: requests per plan and planning time for every bridge's map.

Prints a table; asserts nothing (tests/core/wire/test_planner_optimal.py checks the optimum).

    .venv/bin/python bench/planner_bench.py [--repeat 20]

Each map is planned for all its readable registers (the largest plan a bridge can ask
for; the R6 map is the largest, 2384 registers), and the xArm description's poll plan
with and without a ``max_gap`` cap, to show what the cap costs in requests.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bridge_core.wire.planner import plan_reads  # noqa: E402
from bridge_core.wire.registers import RegisterMap  # noqa: E402
from modbus_bridge.description import load  # noqa: E402
from motec_bridge.registers import MOTEC_MAP  # noqa: E402
from r6_bridge.registers import R6_MAP  # noqa: E402
from stepper_bridge.registers import STEPPER_MAP  # noqa: E402
from xarm_bridge.registers import XARM_MAP  # noqa: E402


def figures(register_map: RegisterMap, repeat: int) -> tuple[int, int, int, float]:
    """(registers, requests, values read, median ms per plan)."""
    wanted = [reg for reg in register_map if reg.access.readable]
    times = []
    plan = plan_reads(register_map, wanted)
    for _ in range(repeat):
        start = time.perf_counter()
        plan_reads(register_map, wanted)
        times.append(time.perf_counter() - start)
    values = sum(request.count for request in plan)
    return len(wanted), len(plan), values, statistics.median(times) * 1e3


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    xarm_file = load(ROOT / "config" / "devices" / "xarm.yaml").device.register_map
    maps = [R6_MAP, XARM_MAP, STEPPER_MAP, MOTEC_MAP, xarm_file]
    for cap in (None, 0):
        limits = dataclasses.replace(xarm_file.limits, read_undefined_ok=True, max_gap=cap)
        maps.append(
            RegisterMap(f"xarm.yaml, read_undefined, max_gap {cap}", xarm_file.registers, limits)
        )
    print(f"{'map':44} {'registers':>9} {'requests':>8} {'values':>7} {'ms/plan':>8}")
    for register_map in maps:
        registers, requests, values, ms = figures(register_map, args.repeat)
        print(f"{register_map.device:44} {registers:9} {requests:8} {values:7} {ms:8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
