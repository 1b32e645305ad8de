"""bench/bridge_bench.py's rate phase: the bare pymodbus loop and the device layer
issuing the node's read plan as fast as they can, and the bridge node at its maximum
poll rate (without and with the bench subscribed to joint_states); ratio node / bare.
"""

from __future__ import annotations

import argparse
from typing import Any

from bench.bare_loops import ReadPlan, run_loop
from bench.bench_processes import Processes, log, node_argv
from bench.node_measure import BenchClient, measure_node

GOAL_RATE_RATIO = 0.8
MAX_RATE_HZ = 1000.0  # the node's poll_rate_hz maximum


def phase_rate(
    opts: argparse.Namespace,
    procs: Processes,
    client: BenchClient,
    sim_port: int,
    sim_pid: int,
    plan: ReadPlan,
) -> dict[str, Any]:
    d, w, s, p = opts.duration, opts.warmup, opts.slices, opts.profile
    log(f"rate: bare pymodbus loop, max rate, {plan.describe()} ({d} s)")
    bare = run_loop(
        procs,
        p,
        "bare",
        sim_port,
        duration=d,
        warmup=w,
        rate=0,
        slices=s,
        plan=plan,
        sim_pid=sim_pid,
    )
    log(f"rate: device layer {p.device_class}.poll(), max rate ({d} s)")
    device = run_loop(
        procs,
        p,
        "device",
        sim_port,
        duration=d,
        warmup=w,
        rate=0,
        slices=s,
        plan=plan,
        sim_pid=sim_pid,
    )
    nodes: dict[str, Any] = {}
    for subscribed in (False, True):
        what = "bench subscribed" if subscribed else "no subscriber"
        log(f"rate: {p.package} node at poll_rate_hz {MAX_RATE_HZ:g}, {what} ({d} s)")
        name = f"{p.package}_1000{'_sub' if subscribed else ''}"
        with procs.running(name, node_argv(p, sim_port, MAX_RATE_HZ)) as proc:
            nodes[what] = measure_node(
                client,
                proc.pid,
                package=p.package,
                duration=d,
                warmup=w,
                plan=plan,
                sim_pid=sim_pid,
                subscribe_joint_states=subscribed,
            )
    node, node_sub = nodes["no subscriber"], nodes["bench subscribed"]
    return {
        "bare_pymodbus": bare,
        "device_loop": device,
        "node_1000": node,
        "node_1000_subscribed": node_sub,
        "ratio_node_to_bare": node["rate_hz"] / bare["rate_hz"],
        # The same ratio from the node's own "achieved poll rate (Hz)" (5 s window).
        "ratio_node_diagnostics_to_bare": node["diagnostics_achieved_hz"] / bare["rate_hz"],
        "ratio_node_subscribed_to_bare": node_sub["rate_hz"] / bare["rate_hz"],
        "ratio_device_to_bare": device["rate_hz"] / bare["rate_hz"],
        "goal_ratio_min": GOAL_RATE_RATIO,
    }
