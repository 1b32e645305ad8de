"""bench/read_rates.py's node part: the bridge node itself (R6, xArm) at a simulated
round trip and ``max_in_flight``, measured by bench/bridge_bench.py's parts: its poll
rate without a subscriber (``node_measure.measure_node``) and register ->
``joint_states`` (``latency_phase.phase_latency``).
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Sequence
from typing import Any

from bench import bridge_bench
from bench.read_rates_common import latency_cell

NODE_RATE_HZ = bridge_bench.MAX_RATE_HZ  # the node's poll_rate_hz upper bound


def node_cases(
    choice: str, devices: Sequence[str], round_trips: Sequence[float], windows: Sequence[int]
) -> list[tuple[str, float, int]]:
    if choice == "none" or not round_trips or not windows:
        return []
    if choice == "some":
        name = "r6" if "r6" in devices else devices[0]
        return [(name, max(round_trips), w) for w in sorted({min(windows), max(windows)})]
    return [(d, rtt, w) for d in devices for rtt in round_trips for w in windows]


def node_point(
    client: bridge_bench.BenchClient,
    procs: bridge_bench.Processes,
    name: str,
    round_trip_ms: float,
    window: int,
    duration_s: float,
    warmup_s: float,
    changes: int,
    domain_id: int,
    seed: int,
) -> dict[str, Any]:
    """The bridge node at one round trip and ``max_in_flight``: bridge_bench's rate
    measure (no subscriber) and its latency phase (the service part cut to one call)."""
    opts = bridge_bench.parse_args(
        [
            "--device",
            name,
            "--duration",
            str(duration_s),
            "--warmup",
            str(warmup_s),
            "--changes",
            str(changes),
            "--service-calls",
            "1",
            "--domain-id",
            str(domain_id),
            "--seed",
            str(seed),
            "--reply-delay-ms",
            str(round_trip_ms),
            "--max-in-flight",
            str(window),
        ]
    )
    profile = opts.profile
    sim_proc, port = bridge_bench.start_sim_process(procs, profile, opts.sim_extra)
    try:
        # The node's read plan: its device's rate groups (the node's polls are its
        # transactions less the slow group's, over the fast group's requests).
        plan = bridge_bench.device_plan(profile, port)
        argv = bridge_bench.node_argv(profile, port, NODE_RATE_HZ)
        with procs.running(f"read_rates_{name}_{round_trip_ms:g}ms_n{window}", argv) as proc:
            node = bridge_bench.measure_node(
                client,
                proc.pid,
                package=profile.package,
                duration=opts.duration,
                warmup=opts.warmup,
                plan=plan,
                sim_pid=sim_proc.pid,
                subscribe_joint_states=False,
            )
    finally:
        procs.stop(sim_proc)
    with contextlib.redirect_stdout(io.StringIO()):  # its progress lines, not our table's
        lat = bridge_bench.phase_latency(opts, procs, client)
    return {
        "device": name,
        "round_trip_ms": round_trip_ms,
        "max_in_flight": window,
        "node": node,
        "latency": {
            **lat["register_to_joint_states"],
            "what": "register change -> joint_states (node at 100 Hz)",
        },
    }


NODE_HEAD = (
    f"{'device':<6} {'rtt ms':>6} {'N':>3} {'polls/s':>8} {'diag Hz':>8} {'cpu us/poll':>11} "
    f"{'joint_states p50/p99 ms (n, miss)':>34}"
)


def node_part(
    cases: Sequence[tuple[str, float, int]],
    duration_s: float,
    warmup_s: float,
    changes: int,
    domain_id: int,
    seed: int,
) -> list[dict[str, Any]]:
    print(
        f"node (bridge_bench.py): poll rate at poll_rate_hz {NODE_RATE_HZ:g}, no subscriber "
        "(the node's transactions less its slow group's / its fast requests per poll), "
        "CPU from /proc; latency = "
        "register change -> joint_states, node at 100 Hz"
    )
    bridge_bench.isolate_ros(domain_id)  # before rclpy is imported
    log_dir = bridge_bench.RESULTS / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    try:
        client = bridge_bench.BenchClient("read_rates_bench")
    except ImportError as err:
        print(f"  skipped: rclpy not importable ({err})\n")
        return []
    procs = bridge_bench.Processes(log_dir)
    rows = []
    try:
        print(NODE_HEAD)
        print("-" * len(NODE_HEAD))
        for name, rtt, window in cases:
            row = node_point(
                client, procs, name, rtt, window, duration_s, warmup_s, changes, domain_id, seed
            )
            node, lat = row["node"], row["latency"]
            print(
                f"{name:<6} {rtt:>6g} {window:>3} {node['rate_hz']:>8.1f} "
                f"{node['diagnostics_achieved_hz']:>8.1f} {node['cpu_us_per_cycle']:>11.0f} "
                f"{latency_cell(lat):>34}",
                flush=True,
            )
            rows.append(row)
    finally:
        procs.stop_all()
        with contextlib.suppress(Exception):
            client.close()
    print()
    return rows
