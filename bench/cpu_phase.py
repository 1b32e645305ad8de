"""bench/bridge_bench.py's cpu phase: at 100 Hz, the node's CPU per poll cycle against
floor A (bench/floor_rclpy_publisher.py, a bare rclpy process publishing the same
messages; context rows with other executors) plus floor B (the bare pymodbus loop
paced at 100 Hz); ratio node / (A + B).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from bench.bare_loops import ReadPlan, run_loop
from bench.bench_processes import ROOT, Processes, log, node_argv
from bench.node_measure import BenchClient, measure_node, measure_publisher

GOAL_CPU_RATIO = 1.2
CPU_RATE_HZ = 100.0


def phase_cpu(
    opts: argparse.Namespace,
    procs: Processes,
    client: BenchClient,
    sim_port: int,
    sim_pid: int,
    plan: ReadPlan,
) -> dict[str, Any]:
    d, w, s, p = opts.duration, opts.warmup, opts.slices, opts.profile
    rate = CPU_RATE_HZ
    log(f"cpu: {p.package} node at {rate:g} Hz ({d} s)")
    with procs.running(f"{p.package}_100", node_argv(p, sim_port, rate)) as proc:
        node = measure_node(
            client,
            proc.pid,
            package=p.package,
            duration=d,
            warmup=w,
            plan=plan,
            sim_pid=sim_pid,
        )
    floors: dict[str, Any] = {}
    for executor in ("single", *opts.extra_executors):
        log(f"cpu: floor A, bare rclpy publisher at {rate:g} Hz, {executor} executor ({d} s)")
        argv = [
            sys.executable,
            str(ROOT / "bench" / "floor_rclpy_publisher.py"),
            "--device",
            p.name,
            "--rate",
            str(rate),
            "--executor",
            executor,
            "--ros-args",
            "-r",
            "__ns:=/floor",
        ]
        with procs.running(f"floor_rclpy_{p.name}_{executor}", argv) as proc:
            floors[executor] = measure_publisher(
                client, proc.pid, "/floor/joint_states", duration=d, warmup=w
            )
    log(f"cpu: floor B, bare pymodbus loop paced at {rate:g} Hz ({d} s)")
    floor_b = run_loop(
        procs,
        p,
        "bare",
        sim_port,
        duration=d,
        warmup=w,
        rate=rate,
        slices=s,
        plan=plan,
        sim_pid=sim_pid,
    )
    floor_a = floors["single"]
    floor_sum = floor_a["cpu_us_per_cycle"] + floor_b["cpu_us_per_cycle"]
    result = {
        "rate_hz": rate,
        "node": node,
        "floor_a_rclpy": floor_a,
        "floor_b_pymodbus": floor_b,
        "floor_sum_us_per_cycle": floor_sum,
        "ratio_node_to_floors": node["cpu_us_per_cycle"] / floor_sum,
        "goal_ratio_max": GOAL_CPU_RATIO,
    }
    for executor in opts.extra_executors:
        result[f"floor_a_rclpy_{executor}_executor"] = floors[executor]
    return result
