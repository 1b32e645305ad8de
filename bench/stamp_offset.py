#!/usr/bin/env python3
"""How far a snapshot's stamp lies from the read of its joint positions
(docs/architecture.md, "The read path").

For the TCP bridges' device layers (R6, xArm) against their simulators over real TCP,
polled through ``bridge_core.runtime.poller.Poller`` exactly as the nodes do (the node copies the
snapshot's ``read_time`` into ``joint_states`` unchanged). The simulator logs the wall
time it handled each read request; per poll the bench prints

    offset = stamp - (time the simulator handled the position block's request)

next to the transaction time (client round trip). Two cases: ``plain`` and ``retried``,
where another block of every poll is answered only after the reply timeout once (the
channel times out, reconnects and retries it), the case in which the old R6 stamp moved
by +0.70 s. Asserts nothing; prints medians and maxima in ms.

    .venv/bin/python bench/stamp_offset.py [--polls 200]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bridge_core.runtime.poller import Poller, PollOutcome
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.registers import RegisterMap
from bridge_core.wire.transport import ModbusLink, TcpSettings

TIMEOUT_S = 0.2
SLOW_S = 0.3  # longer than TIMEOUT_S: the first attempt of the slow block times out


def devices() -> list[tuple[str, Simulator, Any, RegisterMap, str]]:
    from r6_bridge.device import STAMP_REGISTER, R6Device
    from r6_bridge.registers import R6_MAP
    from r6_bridge.sim import make_simulator as r6_sim
    from xarm_bridge.device import XArmDevice
    from xarm_bridge.registers import XARM_MAP
    from xarm_bridge.sim import make_simulator as xarm_sim

    return [
        ("r6", r6_sim(6, 1), R6Device, R6_MAP, STAMP_REGISTER),
        ("xarm", xarm_sim(), XArmDevice, XARM_MAP, "joint_angle_1"),
    ]


def slow_first_attempt(device: SimulatedDevice, address: int) -> None:
    """Answer the read at ``address`` late every second time (one retry per poll)."""
    original = device.read
    late = {"next": True}

    def read(function_code: int, start: int, count: int) -> list[int] | int:
        if start == address:
            if late["next"]:
                time.sleep(SLOW_S)
            late["next"] = not late["next"]
        return original(function_code, start, count)

    device.read = read  # type: ignore[method-assign, assignment]


def run(name: str, case: str, polls: int) -> dict[str, float]:
    (entry,) = [d for d in devices() if d[0] == name]
    _, sim, device_class, register_map, stamp_register = entry
    sim_device = sim.device
    sim_device.log_reads = True
    sim_device.tick = lambda dt: None  # type: ignore[method-assign]
    port = sim.start_tcp()
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=TIMEOUT_S))
    channel = DeviceChannel(link, 1, retries=1)
    device = device_class(channel)
    position = register_map[stamp_register]
    snapshots: list[Any] = []
    poller: Poller[Any] = Poller(
        channel,
        device.poll,
        snapshots.append,
        rate_hz=1000.0,
        link_up=getattr(device, "invalidate_plan", lambda: None),
    )
    try:
        poller.tick()  # connect, plan
        if case == "retried":
            other = next(
                r.address
                for r in sim_device.read_log
                if not r.covers(position.table, position.address)
            )
            slow_first_attempt(sim_device, other)
        start = len(sim_device.read_log)
        done = 0
        while done < polls:
            if poller.tick() is PollOutcome.PUBLISHED:
                done += 1
            poller.publish_pending()  # keep every snapshot (the queue keeps only 8)
    finally:
        sim.stop()
        link.close()
    reads = sim_device.read_log[start:]
    handled = [r.time for r in reads if r.covers(position.table, position.address)]
    offsets: list[float] = []
    for snapshot in snapshots[-polls:]:
        before = [t for t in handled if t <= snapshot.read_time]
        if before:
            offsets.append(snapshot.read_time - before[-1])
    latencies = list(channel.stats.latencies_s)
    return {
        "offset_p50_ms": 1000 * statistics.median(offsets),
        "offset_max_ms": 1000 * max(offsets),
        "transaction_p50_ms": 1000 * statistics.median(latencies),
        "transaction_max_ms": 1000 * max(latencies),
        "retries": float(channel.stats.timeouts),
        "polls": float(len(offsets)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--polls", type=int, default=200)
    args = parser.parse_args(argv)
    print(
        f"{'device':6} {'case':8} {'polls':>5} {'offset p50':>10} {'offset max':>10} "
        f"{'tx p50':>7} {'tx max':>7} {'timeouts':>8}  (ms)"
    )
    for name in ("r6", "xarm"):
        for case in ("plain", "retried"):
            polls = args.polls if case == "plain" else max(10, args.polls // 10)
            r = run(name, case, polls)
            print(
                f"{name:6} {case:8} {int(r['polls']):5d} {r['offset_p50_ms']:10.3f} "
                f"{r['offset_max_ms']:10.3f} {r['transaction_p50_ms']:7.3f} "
                f"{r['transaction_max_ms']:7.3f} "
                f"{int(r['retries']):8d}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
