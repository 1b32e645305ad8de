#!/usr/bin/env python3
"""How far apart the R6 world block (``~/tcp_pose``) and the axis positions
(``joint_states``) are read in one poll (R6 decision 26, docs/decisions/r6.md).

Polls the R6 device layer against its simulator over real TCP; the simulator logs the
wall time it handled each read request. Per poll it prints the time between the world
block's request (2332+) and the position block's (2268+), and how far the pose's stamp
lies from the world block's read: for the poll as the bridge reads it now (the world
block just before the positions, the pose stamped with its own read time) and as it read
it in the old order (the world block 8 requests before the positions, the pose stamped
with the positions' time). Asserts nothing; prints medians and maxima in ms.

    .venv/bin/python bench/r6_pose_offset.py [--polls 300]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bridge_core.runtime.reads import read_blocks
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.transport import ModbusLink, TcpSettings
from r6_bridge.device import STAMP_REGISTER, R6Device
from r6_bridge.registers import R6_MAP
from r6_bridge.sim import R6SimDevice, make_simulator

WORLD = R6_MAP["world_x"].address
POSITIONS = R6_MAP["axis_position_1"].address


def measure(polls: int, old_order: bool) -> tuple[list[float], list[float]]:
    """Per poll: (positions - world block) as the simulator handled them, and the pose's
    stamp minus the time the simulator read the world block, in ms."""
    simulator = make_simulator(6, 1)
    sim = simulator.device
    assert isinstance(sim, R6SimDevice)
    port = simulator.start_tcp()
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    channel = DeviceChannel(link, 1, retries=0)
    device = R6Device(channel)
    # The old order: one read of the blocks by address, only the positions last, and
    # ~/tcp_pose stamped with the positions' read time.
    plan = device.poll_plan(6, 1)
    old_plan = [*sorted(plan[:-1], key=lambda r: r.address), plan[-1]]
    gaps: list[float] = []
    errors: list[float] = []
    try:
        device.poll()
        sim.log_reads = True
        for _ in range(polls):
            sim.read_log.clear()
            if old_order:
                _, pose_stamp = read_blocks(channel, old_plan, stamp_register=STAMP_REGISTER)
            else:
                pose_stamp = device.poll().world_read_time
            times = {r.address: r.time for r in sim.read_log}
            gaps.append((times[POSITIONS] - times[WORLD]) * 1000.0)
            errors.append((pose_stamp - times[WORLD]) * 1000.0)
    finally:
        link.close()
        simulator.stop()
    return gaps, errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--polls", type=int, default=300)
    args = parser.parse_args()
    print(
        "| order | polls | world -> positions p50 / max ms | pose stamp - world read p50 / max ms |"
    )
    print("|---|---|---|---|")
    for name, old in (("old order", True), ("now", False)):
        gaps, errors = measure(args.polls, old)
        print(
            f"| {name} | {args.polls} | {statistics.median(gaps):.2f} / {max(gaps):.2f} | "
            f"{statistics.median(errors):.2f} / {max(errors):.2f} |"
        )


if __name__ == "__main__":
    main()
