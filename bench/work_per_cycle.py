#!/usr/bin/env python3
"""Work per poll cycle of the TCP bridge nodes, counted rather than timed.

Why: on the shared 2-vCPU machines CPU-per-cycle figures of the same code spread by 2x
between runs (bench/README.md), so a change of a few percent cannot be seen in them. The
number of Python function calls one poll + publish cycle makes is deterministic: it
tells whether a change added work to the hot path, and where (``--top``).

For each node (R6 with 6 axes and 1 IO board, xArm) against its simulator over real TCP
on 127.0.0.1 (the simulator runs in this process, in its own threads, which cProfile does
not count): the node's poller runs ``--cycles`` cycles in this thread (poll, then publish
the snapshot), under cProfile. Prints calls per cycle and, for information only, the
profiled CPU time per cycle (noisy, and inflated by the profiler). Asserts nothing.

    .venv/bin/python bench/work_per_cycle.py [--cycles 300] [--top 15]

For an A/B against a tree before the shared runtime (no ``node.poller``), run it with
``PYTHONPATH=<that tree>``: it then drives that tree's ``_poll_tick`` and publisher.
"""

from __future__ import annotations

import argparse
import cProfile
import importlib
import os
import pstats
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

if not os.environ.get("PYTHONPATH"):
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

WARMUP_CYCLES = 30
NODES = {
    # name: (package, node class, simulator arguments)
    "r6": ("r6_bridge", "R6BridgeNode", (6, 1)),
    "xarm": ("xarm_bridge", "XArmBridgeNode", ()),
}


def one_cycle(node: Any) -> Callable[[], None]:
    poller = getattr(node, "poller", None)
    if poller is not None:

        def cycle() -> None:
            poller.tick()
            poller.publish_pending()

        return cycle

    def old_cycle() -> None:  # trees before bridge_core.runtime.poller
        node._poll_tick()
        node.publish_snapshot(node._snapshots.get_nowait())

    return old_cycle


def measure(name: str, cycles: int, top: int) -> None:
    from rclpy.parameter import Parameter

    package, class_name, sim_args = NODES[name]
    sim = importlib.import_module(f"{package}.sim").make_simulator(*sim_args)
    port = sim.start_tcp("127.0.0.1", 0)
    node_class = getattr(importlib.import_module(f"{package}.node"), class_name)
    node = node_class(parameter_overrides=[Parameter("port", value=port)])
    try:
        cycle = one_cycle(node)
        for _ in range(WARMUP_CYCLES):
            cycle()
        profile = cProfile.Profile()
        cpu_start = time.process_time()
        profile.enable()
        for _ in range(cycles):
            cycle()
        profile.disable()
        cpu = time.process_time() - cpu_start
        stats = pstats.Stats(profile)
        calls: int = stats.total_calls  # type: ignore[attr-defined]
        print(
            f"{name}: {calls / cycles:.0f} Python calls per cycle "
            f"(poll + publish, {cycles} cycles); profiled CPU {cpu / cycles * 1e6:.0f} us/cycle"
        )
        if top:
            rows = sorted(stats.stats.items(), key=lambda item: -item[1][1])  # type: ignore[attr-defined]
            for (path, line, function), (_, ncalls, *_rest) in rows[:top]:
                where = path.split("site-packages/")[-1]
                print(f"  {ncalls / cycles:7.1f}  {function}  ({where}:{line})")
    finally:
        node.close()  # stops the (never started) poller, closes the link
        node.destroy_node()
        sim.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles", type=int, default=300)
    parser.add_argument("--top", type=int, default=0, help="list the most called functions")
    parser.add_argument("--nodes", default="r6,xarm")
    args = parser.parse_args()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_DOMAIN_ID", "102")
    import rclpy
    from rclpy.utilities import try_shutdown

    rclpy.init()
    try:
        for name in args.nodes.split(","):
            measure(name, args.cycles, args.top)
    finally:
        try_shutdown()


if __name__ == "__main__":
    main()
