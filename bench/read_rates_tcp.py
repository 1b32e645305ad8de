"""bench/read_rates.py's TCP part: the R6 and xArm device layers by ``max_in_flight`` and
a bare pymodbus loop of the same plan, at simulated round trips (bench/pipelining.py's
loops), with a change probe on joint 1.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

from bench.change_probe import ChangeProbe
from bench.pipelining import bare_rate, controlled_simulator, device_groups, device_rate
from bench.read_rates_common import (
    JOINT_RANGES,
    JOINT_READERS,
    SLOW_PERIOD_S,
    latency,
    latency_cell,
)


def tcp_point(
    name: str,
    round_trip_ms: float,
    windows: Sequence[int],
    duration_s: float,
    repeats: int,
    seed: int,
) -> dict[str, Any]:
    """Bare loop and device layer per window at one round trip, medians over ``repeats``
    rounds (each window once per round, in turn, as pipelining.py measures)."""
    low, high = JOINT_RANGES[name]
    with controlled_simulator(name, round_trip_ms) as (port, control):
        fast, slow = device_groups(name, port)
        probes = {
            w: ChangeProbe(control, JOINT_READERS[name], low, high, seed=seed + w) for w in windows
        }
        runs: dict[str, list[tuple[float, ...]]] = {"bare": [], **{str(w): [] for w in windows}}
        for _ in range(repeats):
            runs["bare"].append(bare_rate(name, port, duration_s, fast, slow, SLOW_PERIOD_S))
            for w in windows:
                with probes[w].running():
                    runs[str(w)].append(device_rate(name, port, w, duration_s, probes[w].observe))
    row: dict[str, Any] = {
        "device": name,
        "round_trip_ms": round_trip_ms,
        "requests_per_poll": f"{len(fast)}+{len(slow)}/{SLOW_PERIOD_S:g}s",
    }
    for key, samples in runs.items():
        row[key] = {
            "polls_per_s": statistics.median(s[0] for s in samples),
            "cpu_us_per_poll": statistics.median(s[1] for s in samples) * 1e6,
        }
        if key != "bare":
            row[key]["transaction_ms"] = statistics.median(s[2] for s in samples) * 1e3
            row[key]["fallbacks"] = max(int(s[3]) for s in samples)
            row[key]["latency"] = latency(probes[int(key)])
    return row


TCP_HEAD = (
    f"{'device':<6} {'rtt ms':>6} {'tx ms':>6} {'loop':<6} {'req/poll':>9} {'polls/s':>8} "
    f"{'x N=1':>6} {'x bare':>6} {'cpu us/poll':>11} {'p50/p99 ms (n, miss)':>22} {'fb':>3}"
)


def tcp_part(
    devices: Sequence[str],
    round_trips: Sequence[float],
    windows: Sequence[int],
    duration_s: float,
    repeats: int,
    seed: int,
) -> list[dict[str, Any]]:
    print(
        "TCP, device layer (R6Device / XArmDevice.poll back to back, the slow group once a "
        f"second) by max_in_flight N, and a bare pymodbus loop of the same plan; "
        f"latency = register change -> snapshot (device layer); medians of {repeats} "
        f"round(s) of {duration_s:g} s"
    )
    print(TCP_HEAD)
    print("-" * len(TCP_HEAD))
    rows = []
    for name in devices:
        for rtt in round_trips:
            row = tcp_point(name, rtt, windows, duration_s, repeats, seed)
            print_tcp_row(row, windows)
            rows.append(row)
    print()
    return rows


def print_tcp_row(row: dict[str, Any], windows: Sequence[int]) -> None:
    one = row[str(windows[0])]["polls_per_s"] if windows else float("nan")
    bare = row["bare"]["polls_per_s"]
    tx = row[str(windows[0])]["transaction_ms"] if windows else float("nan")
    for key in ("bare", *(str(w) for w in windows)):
        r = row[key]
        loop = "bare" if key == "bare" else f"N={key}"
        lat = latency_cell(r["latency"]) if "latency" in r else "-"
        fallbacks = str(r["fallbacks"]) if "fallbacks" in r else "-"
        print(
            f"{row['device']:<6} {row['round_trip_ms']:>6g} {tx:>6.2f} {loop:<6} "
            f"{row['requests_per_poll']:>9} {r['polls_per_s']:>8.1f} "
            f"{r['polls_per_s'] / one:>6.2f} {r['polls_per_s'] / bare:>6.2f} "
            f"{r['cpu_us_per_poll']:>11.0f} {lat:>22} {fallbacks:>3}",
            flush=True,
        )
