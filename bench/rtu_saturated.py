"""Every unit polled back to back on the emulated RTU line (bench/rtu_devices.py's stepper
and bus parts, bench/read_rates.py's RTU part): polls/s against the wire limit of the
same transactions, where the time beyond it went, and the line's t3.5 checks.
"""

from __future__ import annotations

import contextlib
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from multiprocessing.connection import Connection
from typing import Any

from bench.line_relay import REQUEST, Frame, request_gaps, silence_violations, transactions
from bench.rtu_pollers import (
    NODE_MAX_POLL_RATE_HZ,
    SIM_TICK_S,
    START_TIMEOUT_S,
    NodePoller,
    line,
    polling,
    wait_until,
)
from bench.rtu_wire import transaction_wire_s
from bridge_core.wire.serial_timing import silence_s

# A request this far inside t3.5 is no timestamp error of the relay (its calibrated
# latencies are ~10-30 us; line_relay.py tolerates 20 us); pymodbus's stock client sends
# ~0.5-1.7 ms early.
GROSS_VIOLATION_S = 100e-6


def wire_figures(
    frames: Sequence[Frame], baudrate: int, nominal_delay_s: float, start: float, end: float
) -> dict[str, Any]:
    """Transactions wholly inside [start, end] vs their ideal wire time; line checks."""
    t35 = silence_s(baudrate)
    pairs = [(q, r) for q, r in transactions(frames) if q.start >= start and r.end <= end]
    turnaround = statistics.median(r.start - q.end for q, r in pairs) if pairs else 0.0
    window = end - start
    nominal = sum(transaction_wire_s(baudrate, q.size, r.size, nominal_delay_s) for q, r in pairs)
    observed = sum(transaction_wire_s(baudrate, q.size, r.size, turnaround) for q, r in pairs)
    gaps = [g.silence_s for g in request_gaps(frames)]
    # Where the window's time beyond the ideal went, per transaction (ms): the client's
    # silence before a request beyond t3.5, the device's turnaround beyond the nominal
    # one, frames stretched on the wire (relay late).
    in_window = [g for g in request_gaps(frames) if g.before.end >= start and g.request.end <= end]
    char_s = 10 / baudrate
    n = max(1, len(pairs))
    lost = {
        "client": sum(max(0.0, g.silence_s - t35) for g in in_window) / n,
        "device": sum(r.start - q.end - max(t35, nominal_delay_s) for q, r in pairs) / n,
        "frames": sum(f.end - f.start - f.size * char_s for qr in pairs for f in qr) / n,
    }
    return {
        "window_s": window,
        "transactions": len(pairs),
        "ratio": nominal / window,
        "ratio_dev": observed / window,
        "lost_ms_per_transaction": {k: v * 1e3 for k, v in lost.items()},
        "device_turnaround_ms": turnaround * 1e3,
        "mean_gap_ms": statistics.fmean(gaps) * 1e3 if gaps else None,
        "median_gap_ms": statistics.median(gaps) * 1e3 if gaps else None,
        "min_gap_ms": min(gaps) * 1e3 if gaps else None,
        "requests_on_wire": sum(f.direction == REQUEST for f in frames),
        "violations": len(violations := silence_violations(frames, t35)),
        "gross_violations": len(silence_violations(frames, t35, GROSS_VIOLATION_S)),
        "violation_examples": [
            {
                "silence_ms": g.silence_s * 1e3,
                "before": asdict(g.before),
                "request": asdict(g.request),
            }
            for g in violations[:5]
        ],
        "t35_ms": t35 * 1e3,
    }


def saturated_run(
    baudrate: int,
    kind: str,
    units: Sequence[int],
    duration_s: float,
    warmup_s: float,
    nominal_delay_s: float,
    timeout_s: float,
    sim_tick_s: float = SIM_TICK_S,
    *,
    whole_map: bool = False,
    control: Connection[Any, Any] | None = None,
    during: Callable[[list[NodePoller]], contextlib.AbstractContextManager[object]] | None = None,
) -> dict[str, Any]:
    """Every unit polled back to back; the window runs from the first poll completed
    after the warm-up to the last one before its end, so whole polls are counted.

    ``whole_map``: every unit reads its whole map every poll (``read_whole_map``);
    ``control``: the simulator's (``serve``); ``during(pollers)``: a context entered for
    the measured window (e.g. a ``change_probe.ChangeProbe`` changing registers)."""
    with (
        line(baudrate, kind, units, sim_tick_s, control) as relay,
        polling(relay, kind, units, NODE_MAX_POLL_RATE_HZ, timeout_s, whole_map) as pollers,
    ):
        if not wait_until(lambda: all(p.completed for p in pollers), START_TIMEOUT_S):
            raise RuntimeError(f"{kind}: not every unit answered")
        time.sleep(warmup_s)
        with during(pollers) if during is not None else contextlib.nullcontext():
            relay.clear()
            t0, cpu0 = time.monotonic(), time.process_time()
            time.sleep(duration_s)
            t1, cpu1 = time.monotonic(), time.process_time()
        frames = relay.frames()
    ends = sorted(t for p in pollers for t in p.completed if t0 <= t <= t1)
    start, end = ends[0], ends[-1]
    polls = [sum(start < t <= end for t in p.completed) for p in pollers]
    wire = wire_figures(frames, baudrate, nominal_delay_s, start, end)
    rate = sum(polls) / (end - start)
    return {
        "kind": kind,
        "baudrate": baudrate,
        "units": len(units),
        "reply_delay_ms": nominal_delay_s * 1e3,
        "polls": sum(polls),
        "polls_per_s": rate,
        "per_unit_min": min(polls) / (end - start),
        "per_unit_max": max(polls) / (end - start),
        "wire_polls_per_s": rate / wire["ratio"],
        "wire_polls_per_s_dev": rate / wire["ratio_dev"],
        "errors": sum(p.failures for p in pollers),
        **wire,
        # The bench process (poll threads, link) only: simulator and relay run elsewhere.
        "client_cpu_ms_per_transaction": (cpu1 - cpu0) * 1e3 / max(1, wire["transactions"]),
        "client_cpu_ms_per_poll": (cpu1 - cpu0) * 1e3 / max(1, len(ends)),
        "whole_map": whole_map,
        "relay_latency_us": {k: v * 1e6 for k, v in relay.latency_s.items()},
    }


def print_saturated(rows: Sequence[dict[str, Any]], header: bool = True) -> None:
    head = (
        f"{'device':<7} {'baud':>6} {'units':>5} {'polls':>5} {'polls/s':>8} {'unit min':>8} "
        f"{'wire/s':>7} {'ratio':>6} {'wire/s d':>8} {'r_dev':>6} {'turn':>6} {'gap':>5} "
        f"{'min':>5} "
        f"{'viol/req':>10} {'err':>3} {'lost ms/tx: client dev frames':>30} {'cpu ms/tx':>9}"
    )
    if header:
        print(head)
        print("-" * len(head))
    for r in rows:
        lost = r["lost_ms_per_transaction"]
        print(
            f"{r['kind']:<7} {r['baudrate']:>6} {r['units']:>5} {r['polls']:>5} "
            f"{r['polls_per_s']:>8.2f} {r['per_unit_min']:>8.2f} {r['wire_polls_per_s']:>7.2f} "
            f"{r['ratio']:>6.3f} {r['wire_polls_per_s_dev']:>8.2f} {r['ratio_dev']:>6.3f} "
            f"{r['device_turnaround_ms']:>6.2f} {r['median_gap_ms']:>5.2f} {r['min_gap_ms']:>5.3f} "
            f"{r['violations']:>4}/{r['requests_on_wire']:<5} {r['errors']:>3} "
            f"{lost['client']:>17.3f} {lost['device']:>6.3f} {lost['frames']:>6.3f} "
            f"{r['client_cpu_ms_per_transaction']:>9.3f}",
            flush=True,
        )
