"""bench/read_rates.py's RTU part: the stepper and MOTEC device layers polled back to back
on the emulated byte-timed line (``rtu_saturated.saturated_run``), today's plan and the
rate groups, against the wire limit of the fast blocks alone.
"""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from bench.change_probe import ChangeProbe
from bench.read_rates_common import (
    JOINT_RANGES,
    JOINT_READERS,
    SLOW_PERIOD_S,
    latency,
    latency_cell,
)
from bench.rtu_pollers import (
    MOTEC_BAUD,
    MOTEC_TIMEOUT_S,
    STEPPER_TIMEOUT_S,
    NodePoller,
    whole_map_plan,
)
from bench.rtu_saturated import saturated_run
from bench.rtu_wire import transaction_wire_s
from bridge_core.runtime.reads import as_request
from bridge_core.wire.planner import ReadRequest
from bridge_core.wire.registers import RegisterMap
from bridge_core.wire.requests import RTU_ADU_OVERHEAD, pdu_bytes
from bridge_core.wire.serial_timing import silence_s
from bridge_core.wire.transport import SerialSettings
from motec_bridge import snapshots as motec_snapshots
from motec_bridge.registers import MOTEC_MAP
from stepper_bridge import snapshots as stepper_snapshots
from stepper_bridge.registers import REPLY_DELAY_S as STEPPER_REPLY_DELAY_S
from stepper_bridge.registers import STEPPER_MAP

STEPPER_BAUD = 9600  # the manual's
WIRE_CHECK_S = 1e-9  # the two wire arithmetics must agree (rtu_wire vs bridge_core)


@dataclass(frozen=True)
class RtuCase:
    label: str
    kind: str  # "stepper" | "motec" (rtu_devices)
    baudrate: int
    drives: int
    reply_delay_s: float  # nominal: the simulator's
    timeout_s: float  # the node's default
    register_map: RegisterMap
    fast: tuple[ReadRequest, ...]
    slow: tuple[ReadRequest, ...]


def rtu_cases(drives: Sequence[int]) -> list[RtuCase]:
    stepper = RtuCase(
        f"stepper {STEPPER_BAUD} {STEPPER_REPLY_DELAY_S * 1e3:g}ms",
        "stepper",
        STEPPER_BAUD,
        1,
        STEPPER_REPLY_DELAY_S,
        STEPPER_TIMEOUT_S,
        STEPPER_MAP,
        tuple(stepper_snapshots.FAST_PLAN),
        tuple(stepper_snapshots.SLOW_PLAN),
    )
    motec = [
        RtuCase(
            f"MOTEC x{n} {MOTEC_BAUD}",
            "motec",
            MOTEC_BAUD,
            n,
            0.0,
            MOTEC_TIMEOUT_S,
            MOTEC_MAP,
            tuple(motec_snapshots.FAST_PLAN),
            tuple(motec_snapshots.SLOW_PLAN),
        )
        for n in drives
    ]
    return [stepper, *motec]


def fast_wire_s(case: RtuCase) -> float:
    """Ideal wire time of one poll of the fast blocks alone (see the module's docstring)."""
    total = 0.0
    for request in case.fast:
        pdu_request, pdu_reply = pdu_bytes(as_request(request))
        total += transaction_wire_s(
            case.baudrate,
            pdu_request + RTU_ADU_OVERHEAD,
            pdu_reply + RTU_ADU_OVERHEAD,
            case.reply_delay_s,
        )
    return total


def fast_wire_s_bridge_core(case: RtuCase) -> float:
    """The same from bridge_core's budget arithmetic: frames and one silence
    (``SerialSettings.frame_time_s``) plus the turnaround, as ``WireBudget`` adds it."""
    settings = SerialSettings("", case.baudrate)
    turnaround = max(silence_s(case.baudrate), case.reply_delay_s)
    return sum(settings.frame_time_s(as_request(r)) + turnaround for r in case.fast)


# ---------------------------------------------------------------- RTU


def rtu_run(
    case: RtuCase, whole_map: bool, duration_s: float, warmup_s: float, seed: int
) -> dict[str, Any]:
    """One case on the emulated line, a probe changing drive 1's joint in the window."""
    mine, theirs = multiprocessing.get_context("spawn").Pipe()
    low, high = JOINT_RANGES[case.kind]
    probe = ChangeProbe(mine, JOINT_READERS[case.kind], low, high, seed=seed)

    def during(pollers: list[NodePoller]) -> contextlib.AbstractContextManager[object]:
        pollers[0].observer = probe.observe
        return probe.running()

    run = saturated_run(
        case.baudrate,
        case.kind,
        range(1, case.drives + 1),
        duration_s,
        warmup_s,
        case.reply_delay_s,
        case.timeout_s,
        whole_map=whole_map,
        control=theirs,
        during=during,
    )
    per_drive = run["polls_per_s"] / case.drives
    limit = 1.0 / (case.drives * fast_wire_s(case))
    return {
        "plan": "today" if whole_map else "groups",
        "polls_per_s_per_drive": per_drive,
        "polls_per_s_slowest_drive": run["per_unit_min"],
        "fast_wire_limit_per_drive": limit,
        "of_fast_wire_limit": per_drive / limit,
        "latency": latency(probe),
        "run": run,
    }


def rtu_part(
    cases: Sequence[RtuCase], duration_s: float, warmup_s: float, seed: int
) -> list[dict[str, Any]]:
    print_rtu_header()
    rows = []
    for case in cases:
        today_plan = whole_map_plan(case.register_map, case.fast, case.slow)
        plans = {
            "today": str(len(today_plan)),
            "groups": f"{len(case.fast)}+{len(case.slow)}/{SLOW_PERIOD_S:g}s",
        }
        row: dict[str, Any] = {
            "case": case.label,
            "kind": case.kind,
            "baudrate": case.baudrate,
            "drives": case.drives,
            "reply_delay_ms": case.reply_delay_s * 1e3,
            "fast_wire_ms": fast_wire_s(case) * 1e3,
            "fast_wire_ms_bridge_core": fast_wire_s_bridge_core(case) * 1e3,
            "requests_per_poll": plans,
        }
        if abs(fast_wire_s(case) - fast_wire_s_bridge_core(case)) > WIRE_CHECK_S:
            print(
                f"  note: wire arithmetic differs: rtu_wire {row['fast_wire_ms']:.3f} ms, "
                f"bridge_core {row['fast_wire_ms_bridge_core']:.3f} ms per fast poll"
            )
        for plan, whole in (("today", True), ("groups", False)):
            row[plan] = rtu_run(case, whole, duration_s, warmup_s, seed)
            print_rtu_row(case.label, plan, plans[plan], row[plan], row.get("today"))
        rows.append(row)
    print()
    return rows


RTU_HEAD = (
    f"{'case':<20} {'plan':<6} {'req/poll':>9} {'polls/s/dev':>11} {'min':>6} "
    f"{'fast wire/s':>11} {'of wire':>7} {'x today':>7} {'line':>5} {'cpu ms/poll':>11} "
    f"{'p50/p99 ms (n, miss)':>22} {'err':>3} {'viol':>4}"
)


def print_rtu_header() -> None:
    print(
        "RTU, emulated byte-timed line, device layer (NodePoller, polls back to back; no "
        f"ROS node): today = whole map every poll, groups = fast every poll + slow every "
        f"{SLOW_PERIOD_S:g} s; latency = register change -> snapshot (device layer)"
    )
    print(RTU_HEAD)
    print("-" * len(RTU_HEAD))


def print_rtu_row(
    label: str, plan: str, requests: str, r: dict[str, Any], today: dict[str, Any] | None
) -> None:
    lat, run = r["latency"], r["run"]
    gain = (
        f"{r['polls_per_s_per_drive'] / today['polls_per_s_per_drive']:.2f}"
        if today is not None and plan != "today" and today["polls_per_s_per_drive"]
        else ""
    )
    print(
        f"{label:<20} {plan:<6} {requests:>9} {r['polls_per_s_per_drive']:>11.2f} "
        f"{r['polls_per_s_slowest_drive']:>6.2f} {r['fast_wire_limit_per_drive']:>11.2f} "
        f"{r['of_fast_wire_limit']:>7.3f} {gain:>7} {run['ratio']:>5.2f} "
        f"{run['client_cpu_ms_per_poll']:>11.3f} {latency_cell(lat):>22} "
        f"{run['errors']:>3} {run['violations']:>4}",
        flush=True,
    )
