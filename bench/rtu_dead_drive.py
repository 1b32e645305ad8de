"""bench/rtu_devices.py's dead part: MOTEC units on one bus at 115200, the last of them
dead (no simulator answers it), the live drives' polls/s against the same units all
alive (and, saturated, the live drives alone): in the first seconds after the drive went
dead (its backoff ramp) and once its backoff reached the cap.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence
from typing import Any

from bench.line_relay import REQUEST, silence_violations
from bench.rtu_pollers import (
    MOTEC_BAUD,
    MOTEC_TIMEOUT_S,
    NODE_MAX_POLL_RATE_HZ,
    NODE_RECONNECT_MAX_S,
    SIM_TICK_S,
    line,
    polling,
    wait_until,
)
from bench.rtu_saturated import wire_figures
from bridge_core.wire.serial_timing import silence_s

DEAD_UNITS = 4  # units on the bus in the dead-drive cases, the last one dead
BACKOFF_CAP_ATTEMPT = 7  # the 7th attempt on a dead channel follows a capped (5 s) delay


def dead_run(
    rate_hz: float,
    duration_s: float,
    periods: int,
    dead: bool,
    live_only: bool = False,
    sim_tick_s: float = SIM_TICK_S,
) -> dict[str, Any]:
    """Units 1..DEAD_UNITS polled at ``rate_hz`` each; the last unit dead if ``dead``.

    ``live_only``: only the live units exist (no dead unit polled either).
    """
    all_units = list(range(1, DEAD_UNITS + 1))
    live = all_units[:-1] if dead or live_only else all_units
    polled = live if live_only else all_units
    with (
        line(MOTEC_BAUD, "motec", live, sim_tick_s) as relay,
        polling(relay, "motec", polled, rate_hz, MOTEC_TIMEOUT_S) as pollers,
    ):
        t_start = time.monotonic()
        live_pollers = [p for p in pollers if p.channel.unit_id in live]
        dead_poller = next((p for p in pollers if p.channel.unit_id not in live), None)
        if dead_poller is not None:
            # Until the backoff is capped and `periods` whole 5 s periods have followed.
            last = BACKOFF_CAP_ATTEMPT + periods
            done = wait_until(
                lambda: (
                    len(dead_poller.attempts) >= last and time.monotonic() - t_start >= duration_s
                ),
                60 + periods * (NODE_RECONNECT_MAX_S + 1) + duration_s,
            )
            if not done:
                raise RuntimeError("the dead drive's attempts did not come as expected")
            attempts = dead_poller.attempts
            windows = {
                "first": (attempts[0], attempts[0] + duration_s),
                "steady": (attempts[BACKOFF_CAP_ATTEMPT - 1], attempts[last - 1]),
            }
        else:
            time.sleep(1.0 + duration_s)  # 1 s warm-up
            t1 = time.monotonic()
            windows = {"steady": (t1 - duration_s, t1), "first": (t1 - duration_s, t1)}
        frames = relay.frames()
    rates = {name: [p.rate_in(a, b) for p in live_pollers] for name, (a, b) in windows.items()}
    a, b = windows["steady"]
    return {
        "rate_hz": rate_hz,
        "units_polled": len(polled),
        "live": len(live),
        "dead": dead,
        "windows_s": {k: w[1] - w[0] for k, w in windows.items()},
        "live_rates": rates,
        "dead_attempts": len(dead_poller.attempts) if dead_poller else 0,
        "dead_timeouts": dead_poller.channel.stats.timeouts if dead_poller else 0,
        "errors": sum(p.failures for p in live_pollers),
        "bus_ratio_steady": wire_figures(frames, MOTEC_BAUD, 0.0, a, b)["ratio"],
        "violations": len(silence_violations(frames, silence_s(MOTEC_BAUD))),
        "requests_on_wire": sum(f.direction == REQUEST for f in frames),
    }


def dead_cases(
    rate_hz: float, duration_s: float, periods: int, sim_tick_s: float = SIM_TICK_S
) -> dict[str, Any]:
    def measure(rate: float, **kwargs: bool) -> dict[str, Any]:
        return dead_run(rate, duration_s, periods, sim_tick_s=sim_tick_s, **kwargs)

    fixed_alive = measure(rate_hz, dead=False)
    fixed_dead = measure(rate_hz, dead=True)
    sat_alive = measure(NODE_MAX_POLL_RATE_HZ, dead=False)
    sat_live_only = measure(NODE_MAX_POLL_RATE_HZ, dead=False, live_only=True)
    sat_dead = measure(NODE_MAX_POLL_RATE_HZ, dead=True)
    out: dict[str, Any] = {"runs": [fixed_alive, fixed_dead, sat_alive, sat_live_only, sat_dead]}
    rows = []
    for label, ref, run in (
        (f"{rate_hz:g} Hz, 1 dead vs 4 alive", fixed_alive, fixed_dead),
        ("max, 1 dead vs 4 alive", sat_alive, sat_dead),
        ("max, 1 dead vs 3 alone", sat_live_only, sat_dead),
    ):
        # Per live unit: its rate with the dead unit / the same unit's rate in ``ref``.
        ref_rates = ref["live_rates"]["steady"][: len(run["live_rates"]["steady"])]
        row: dict[str, Any] = {"case": label, "ref_rate": statistics.median(ref_rates)}
        for window in ("steady", "first"):
            rates = run["live_rates"][window]
            kept = [r / q for r, q in zip(rates, ref_rates, strict=True)]
            row[window] = {
                "rate": statistics.median(rates),
                "kept_median": statistics.median(kept),
                "kept_min": min(kept),
            }
        row["violations"] = run["violations"] + ref["violations"]
        row["requests_on_wire"] = run["requests_on_wire"] + ref["requests_on_wire"]
        row["errors"] = run["errors"] + ref["errors"]
        row["dead_attempts"] = run["dead_attempts"]
        row["steady_window_s"] = run["windows_s"]["steady"]
        rows.append(row)
    out["rows"] = rows
    return out


def print_dead(rows: Sequence[dict[str, Any]]) -> None:
    head = (
        f"{'case':<24} {'ref/s':>6} {'steady/s':>8} {'kept':>6} {'min':>6} "
        f"{'first/s':>7} {'kept':>6} {'min':>6} {'window':>6} {'viol/req':>11} {'err':>3}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        s, f = r["steady"], r["first"]
        print(
            f"{r['case']:<24} {r['ref_rate']:>6.2f} {s['rate']:>8.2f} {s['kept_median']:>6.3f} "
            f"{s['kept_min']:>6.3f} {f['rate']:>7.2f} {f['kept_median']:>6.3f} "
            f"{f['kept_min']:>6.3f} {r['steady_window_s']:>6.1f} "
            f"{r['violations']:>4}/{r['requests_on_wire']:<6} {r['errors']:>3}",
            flush=True,
        )
