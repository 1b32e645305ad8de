"""bench/bridge_bench.py's latency phase: the node at 100 Hz against a simulator in the
bench's own process; a register change -> the first joint_states carrying it, and a
command service call -> its write in the simulator's write log.
"""

from __future__ import annotations

import argparse
import importlib
import math
import random
import statistics
import threading
import time
from typing import Any

from bench.bench_processes import Processes, log, node_argv, wait_until
from bench.bridge_profiles import Profile
from bench.node_measure import BenchClient

DEG = math.pi / 180.0
GOAL_LATENCY_MARGIN_MS = 2.0
LATENCY_RATE_HZ = 100.0


def percentile(samples: list[float], fraction: float) -> float:
    """Nearest-rank percentile (p99 of 200 samples is the 198th smallest)."""
    if not samples:
        return float("nan")
    data = sorted(samples)
    rank = max(1, math.ceil(fraction * len(data)))
    return data[rank - 1]


def median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def latency_stats(samples_s: list[float]) -> dict[str, Any]:
    ms = [1e3 * x for x in samples_s]
    return {
        "n": len(ms),
        "p50_ms": median(ms),
        "p99_ms": percentile(ms, 0.99),
        "max_ms": max(ms) if ms else float("nan"),
        "min_ms": min(ms) if ms else float("nan"),
    }


def phase_latency(
    opts: argparse.Namespace, procs: Processes, client: BenchClient
) -> dict[str, Any]:
    from sensor_msgs.msg import JointState

    p: Profile = opts.profile
    # The simulator's tick() keeps running: both simulators leave the joints alone while
    # idle (R6 not running, xArm sleeping), which is how they start.
    sim = importlib.import_module(f"{p.simulator}.sim").make_simulator(*p.sim_args)
    sim.round_trip_s = opts.reply_delay_ms / 1000.0  # --reply-delay-ms, as in the other phases
    sim.nagle = opts.nagle
    port = sim.start_tcp("127.0.0.1", 0)
    device = sim.device
    rng = random.Random(opts.seed)
    scale = device.map[p.joint_register].scale
    state: dict[str, Any] = {"expected": None, "t1": 0.0, "t1_wall": 0.0, "stamp": 0.0}
    arrived = threading.Event()
    first = threading.Event()

    def on_joints(msg: Any) -> None:
        now, now_wall = time.monotonic(), time.time()
        first.set()
        expected = state["expected"]
        if expected is not None and msg.position and abs(msg.position[0] - expected) < 1e-9:
            state["expected"] = None
            state["t1"], state["t1_wall"] = now, now_wall
            state["stamp"] = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            arrived.set()

    service = f"/{p.package}/{p.service}"
    srv_type = getattr(importlib.import_module("msg_defs.srv"), p.service_type)
    sub = client.node.create_subscription(JointState, "/joint_states", on_joints, 10)
    srv = client.node.create_client(srv_type, service)
    register_s: list[float] = []
    in_flight_s: list[float] = []  # poll start (header stamp) -> arrival
    write_s: list[float] = []
    response_s: list[float] = []
    missed = failed = 0
    try:
        log(
            f"latency: {p.package} at {LATENCY_RATE_HZ:g} Hz, simulator in this process, "
            f"{opts.changes} register changes"
        )
        with procs.running(f"{p.package}_latency", node_argv(p, port, LATENCY_RATE_HZ)):
            if not first.wait(60):
                raise RuntimeError(f"no joint_states from {p.package}")
            time.sleep(opts.warmup)
            last_raw = None
            for _ in range(opts.changes):
                raw = last_raw
                while raw == last_raw:
                    raw = rng.randint(-p.joint_raw_max, p.joint_raw_max)
                last_raw = raw
                value = raw / scale
                arrived.clear()
                state["expected"] = value * DEG  # what the node computes: deg * DEG
                t0 = time.monotonic()
                device.set(p.joint_register, value)
                if arrived.wait(1.0):
                    register_s.append(state["t1"] - t0)
                    in_flight_s.append(state["t1_wall"] - state["stamp"])
                else:
                    state["expected"] = None
                    missed += 1
                time.sleep(rng.uniform(0.020, 0.050))

            log(f"latency: {opts.service_calls} ~/{p.service} calls")
            wait_until(srv.service_is_ready, 30, f"service {service}")
            for k in range(opts.service_calls):
                request, table, address = p.service_request(k, rng)
                done = threading.Event()
                with device.lock:
                    seen = len(device.write_log)
                t0_wall = time.time()
                t0 = time.monotonic()
                future = srv.call_async(request)
                future.add_done_callback(lambda _f, e=done: e.set())
                if not done.wait(5.0) or not future.result().success:
                    failed += 1
                    continue
                response_s.append(time.monotonic() - t0)
                with device.lock:
                    new = [
                        r
                        for r in device.write_log[seen:]
                        if r.table.value == table and r.address == address
                    ]
                if new:
                    write_s.append(new[0].time - t0_wall)
                else:
                    failed += 1
                time.sleep(rng.uniform(0.020, 0.050))
    finally:
        client.node.destroy_subscription(sub)
        client.node.destroy_client(srv)
        sim.stop()
    period_ms = 1e3 / LATENCY_RATE_HZ
    reg = latency_stats(register_s)
    reg["missed"] = missed
    return {
        "poll_rate_hz": LATENCY_RATE_HZ,
        "joint_register": p.joint_register,
        "service": service,
        "register_to_joint_states": reg,
        # The part after the poll started (JointState stamp = wall time of a read in the
        # poll: R6 the last block's, xArm the first's): the rest of the poll, decode,
        # publish, delivery to this process.
        "poll_start_to_joint_states": latency_stats(in_flight_s),
        "goal_p99_max_ms": period_ms + GOAL_LATENCY_MARGIN_MS,
        "service_call_to_register_write": {**latency_stats(write_s), "failed": failed},
        "service_call_to_response": latency_stats(response_s),
    }
