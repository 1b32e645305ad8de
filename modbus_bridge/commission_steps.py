"""modbus_bridge's read-only commissioning checks (``bridge_commission modbus``): what
the rows of ``modbus_bridge/commission.py`` name, for any device a description file makes
(the file, its node and the bridge's device: commission_file.py).

Every check reads the device through the bridge's own ``DescribedDevice`` and plan
(``device.poll_plan``), and judges from the file alone (its rows' types, ranges, word
orders, keepalive), never from a model of a product. A description key is no parameter:
where one decides, the finding's ``seen`` names the key to change in the file. The
guided steps are in commission_guided.py. No ROS here.
"""

from __future__ import annotations

import dataclasses
import math
import statistics

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.wire.codec import decode
from bridge_core.wire.errors import DeviceException
from bridge_core.wire.planner import ReadRequest
from bridge_core.wire.registers import Register, RegisterMap, ValueType, WordOrder

from .commission_file import listed, poll_time, read_rows, span, target
from .description import Device
from .description_commands import ANY_FRAME_POLLS_PER_PERIOD
from .device import KEEPALIVE_FEEDS_PER_PERIOD, poll_plan

# Decision 10's check: the plan with gaps capped at this many registers, timed against
# the file's own plan over this many polls each; the capped plan "is faster" only when its
# median poll is shorter by more than this share (noise on a busy line is not a verdict).
CAPPED_GAP = 4
PLAN_POLLS = 5
PLAN_MARGIN = 0.1
# Word order (inverter decision 16): a 32/64-bit row decoded in its file's order and in
# the other one. With no ``range`` in the file, a float is plausible when 0 or its
# magnitude lies in FLOAT_PLAUSIBLE (a swapped float's exponent comes from its mantissa's
# low bits: tiny, huge or not a number); an integer when its magnitude is at most
# INT_PLAUSIBLE_MAX raw and it is no nonzero multiple of 65536 (a small value read with
# its words swapped has a low word of 0).
FLOAT_PLAUSIBLE = (1e-6, 1e9)
INT_PLAUSIBLE_MAX = 1_000_000_000
WORD_VALUES = 1 << 16
RATE_STEP_HZ = 0.1  # a poll rate recommended for a watchdog any frame resets: rounded up
ADDRESS_SHIFTS = (-1, 1)  # decision 8: a refused row read again this far off


# ---------------------------------------------------------------- read-only checks
def _through(request: ReadRequest) -> bool:
    """Whether ``request`` reads registers (or bits) no wanted row of it holds."""
    return request.count > sum(r.count for r in request.registers)


def gaps_served(probe: Probe) -> Finding:
    """Decisions 10 and 11: each request of the file's plan that reads through rows it
    does not want, read as the bridge plans it."""
    assert probe.rows is not None
    found = target(probe)
    fast, slow, _ = poll_plan(found.device)
    refused_alone = probe.rows.refused_names()
    through = [r for r in (*fast, *slow) if _through(r)]
    judged = [r for r in through if not {reg.name for reg in r.registers} & refused_alone]
    if not through:
        return Finding(
            Verdict.CONFIRMED,
            f"the plan's {len(fast) + len(slow)} requests read through no gap: nothing the "
            "device could refuse there",
        )
    if not judged:
        return Finding(
            Verdict.UNCLEAR,
            "every request that reads through a gap holds a row refused alone: see the "
            "addresses check first",
        )
    refused: list[str] = []
    undefined = False
    for request in judged:
        try:
            read_rows(probe.io, request.table, request.address, request.count)
        except DeviceException as err:
            refused.append(f"{span(request)} ({err.name})")
            undefined = undefined or any(
                found.device.register_map.owner_at(request.table, a) is None
                for a in range(request.address, request.end)
            )
    if not refused:
        return Finding(
            Verdict.CONFIRMED,
            f"the {len(judged)} requests that read through gaps were served",
        )
    key = "`read_undefined: false`" if undefined else "a `max_gap`"
    return Finding(
        Verdict.CONTRADICTED,
        f"the device refused {len(refused)} of the {len(judged)} merged reads: "
        f"{listed(refused)}; the bridge reads them in parts after the first refusal, but "
        f"set {key} under `device` in {found.file} so the plan does not try them at every "
        "start",
    )


def _capped(device: Device, gap: int) -> Device:
    register_map = device.register_map
    limits = dataclasses.replace(register_map.limits, max_gap=gap)
    capped = RegisterMap(register_map.device, register_map.registers, limits)
    return dataclasses.replace(device, register_map=capped)


def plan_speed(probe: Probe) -> Finding:
    """Decision 10: the fewest-requests plan against one with gaps capped at
    ``CAPPED_GAP``, each polled ``PLAN_POLLS`` times, alternately."""
    found = target(probe)
    own = poll_plan(found.device)[0]
    limit = found.device.register_map.limits.max_gap
    if limit is not None and limit <= CAPPED_GAP:
        return Finding(Verdict.CONFIRMED, f"the file caps gaps at {limit} already")
    capped = poll_plan(_capped(found.device, CAPPED_GAP))[0]
    if [span(r) for r in capped] == [span(r) for r in own]:
        return Finding(
            Verdict.CONFIRMED,
            f"`max_gap: {CAPPED_GAP}` makes the same {len(own)} requests: nothing to compare",
        )
    times: dict[str, list[float]] = {"own": [], "capped": []}
    for _ in range(PLAN_POLLS):
        times["own"].append(poll_time(probe.io, own))
        times["capped"].append(poll_time(probe.io, capped))
    mine, theirs = (statistics.median(times[k]) for k in ("own", "capped"))
    said = (
        f"the file's plan: {len(own)} requests, median poll {mine * 1000:.1f} ms; with "
        f"`max_gap: {CAPPED_GAP}`: {len(capped)} requests, {theirs * 1000:.1f} ms"
    )
    if theirs < mine * (1 - PLAN_MARGIN):
        return Finding(
            Verdict.CONTRADICTED,
            f"{said}: set `max_gap: {CAPPED_GAP}` under `device` in {found.file}",
        )
    return Finding(Verdict.CONFIRMED, said)


def addresses(probe: Probe) -> Finding:
    """Decision 8: every readable row answered alone at its address; a refused row is read
    again ``ADDRESS_SHIFTS`` off (a manual that counts from 1)."""
    assert probe.rows is not None
    found = target(probe)
    answered = len(probe.rows.answered)
    if not probe.rows.refused:
        return Finding(
            Verdict.CONFIRMED,
            f"all {answered} readable rows answered at their addresses; compare `modbus_doc "
            f"{found.file}` with the manual row by row (the names are yours to check)",
        )
    shifted: dict[int, list[str]] = {shift: [] for shift in ADDRESS_SHIFTS}
    for refusal in probe.rows.refused:
        reg = found.device.register_map[refusal.name]
        for shift in ADDRESS_SHIFTS:
            try:
                read_rows(probe.io, reg.table, reg.address + shift, reg.count)
            except DeviceException:
                continue
            shifted[shift].append(reg.name)
            break
    names = [r.name for r in probe.rows.refused]
    said = f"{len(names)} of {answered + len(names)} rows refused at their address: {listed(names)}"
    for shift, moved in shifted.items():
        if len(moved) == len(names):
            how = "subtract 1 from" if shift < 0 else "add 1 to"
            return Finding(
                Verdict.CONTRADICTED,
                f"{said}; each answers at its address {shift:+d}: the manual counts from "
                f"{1 if shift < 0 else -1} (PLC numbering 40001): {how} every address in "
                f"{found.file}",
            )
    return Finding(
        Verdict.CONTRADICTED,
        f"{said}: check their addresses and tables against the manual (every poll that "
        "reads them fails)",
    )


def parity(probe: Probe) -> Finding:
    """Decision 24: a device that answered at all answered at this framing."""
    values = probe.values
    if "serial_port" not in values:
        return Finding(Verdict.NOT_RUN, "a TCP link: no serial framing to check")
    framing = f"{values['baudrate']} 8{str(values['parity']).upper()}{values['stopbits']}"
    return Finding(
        Verdict.CONFIRMED, f"the device answered on {values['serial_port']} at {framing}"
    )


def _other(order: WordOrder) -> WordOrder:
    return WordOrder.LOW_FIRST if order is WordOrder.HIGH_FIRST else WordOrder.HIGH_FIRST


def plausible(reg: Register, value: float) -> bool:
    """Whether ``value`` (engineering units) is one ``reg`` may read: within its ``range``
    if the file gives one, and (a float always, an integer without a range) by the type's
    rule (``FLOAT_PLAUSIBLE``, ``INT_PLAUSIBLE_MAX``)."""
    if not math.isfinite(value):
        return False
    low = -math.inf if reg.minimum is None else reg.minimum
    high = math.inf if reg.maximum is None else reg.maximum
    if reg.value_type.is_float:  # a float within its range and of a plausible size
        size_ok = value == 0 or FLOAT_PLAUSIBLE[0] <= abs(value) <= FLOAT_PLAUSIBLE[1]
        return size_ok and low <= value <= high
    if reg.minimum is not None or reg.maximum is not None:
        return low <= value <= high
    raw = round((value - reg.offset) * reg.scale)
    return abs(raw) <= INT_PLAUSIBLE_MAX and (raw == 0 or raw % WORD_VALUES != 0)


def word_order(probe: Probe) -> Finding:
    """Inverter decision 16 (and decision 1): every nonzero 32/64-bit row decoded in its
    file's word order and in the other."""
    assert probe.rows is not None
    found = target(probe)
    agree: list[str] = []
    other: list[str] = []
    neither: list[str] = []
    for reg in found.device.register_map:
        words = probe.rows.answered.get(reg.name)
        if not _multi_word(reg) or not words or not any(words):
            continue
        swapped = dataclasses.replace(reg, word_order=_other(reg.word_order))
        mine, theirs = (float(decode(r, words)) for r in (reg, swapped))
        shown = f"{reg.name} {mine:g} ({swapped.word_order.value}: {theirs:g})"
        ok_mine, ok_theirs = plausible(reg, mine), plausible(reg, theirs)
        if ok_mine and not ok_theirs:
            agree.append(shown)
        elif ok_theirs and not ok_mine:
            other.append(f"{shown}: set `word_order: {swapped.word_order.value}`")
        else:
            neither.append(shown)
    if other:
        return Finding(
            Verdict.CONTRADICTED,
            f"plausible only in the other word order ({len(other)} rows): "
            f"{listed(other)} on each in {found.file} (or the device's `word_order`); "
            f"as the file says: {listed(agree) or 'none'}",
        )
    if agree:
        unsettled = f"; unsettled: {listed(neither)}" if neither else ""
        return Finding(
            Verdict.CONFIRMED,
            f"plausible in the file's word order only ({len(agree)} rows): {listed(agree)}"
            + unsettled,
        )
    if neither:
        return Finding(Verdict.UNCLEAR, f"the values settle neither order: {listed(neither)}")
    if not any(_multi_word(reg) for reg in found.device.register_map):
        return Finding(Verdict.NOT_RUN, "the file has no 32/64-bit row")
    return Finding(
        Verdict.UNCLEAR,
        "no 32/64-bit row read nonzero: run the device (a speed, a voltage) and run this again",
    )


def _multi_word(reg: Register) -> bool:
    return reg.count > 1 and not reg.table.is_bit and reg.value_type is not ValueType.STRING


def _refused(probe: Probe, *names: str | None) -> list[str]:
    assert probe.rows is not None
    refused = probe.rows.refused_names()
    return [name for name in names if name is not None and name in refused]


def keepalive_settings(probe: Probe) -> Finding:
    """Decisions 13, 21, 22: the watchdog the file names can be fed: its registers answer
    and a time read from the device is not 0; a watchdog any frame resets gets
    ``ANY_FRAME_POLLS_PER_PERIOD`` polls per watchdog time at ``poll_rate_hz``, on this
    line."""
    found = target(probe)
    device, spec = found.device, found.device.keepalive
    if spec is not None:
        if bad := _refused(probe, spec.register, spec.period_register):
            return Finding(
                Verdict.CONTRADICTED,
                f"{listed(bad)} refused alone: every feed (or arming) fails; check the "
                f"address against the manual and the keepalive in {found.file}",
            )
        period = spec.period_s
        if spec.period_register is not None:
            assert probe.rows is not None
            reg = device.register_map[spec.period_register]
            period = float(decode(reg, probe.rows.answered[reg.name])) * spec.period_to_s
            if period <= 0:
                return Finding(
                    Verdict.CONTRADICTED,
                    f"{reg.name} reads 0: the device's watchdog is off (decision 22), so "
                    "nothing stops it when the bridge dies; write its watchdog time there "
                    f"first (~/write name: {reg.name})",
                )
        assert period is not None
        return Finding(
            Verdict.CONFIRMED,
            f"{spec.register} answers; a watchdog time of {period:g} s, fed every "
            f"{period / KEEPALIVE_FEEDS_PER_PERIOD:.3g} s ({spec.mode})",
        )
    watchdog_s = device.frame_watchdog_s
    if watchdog_s is None:
        return Finding(Verdict.NOT_RUN, "the file names no keepalive")
    rate = float(probe.values["poll_rate_hz"])
    needed = ANY_FRAME_POLLS_PER_PERIOD / watchdog_s
    poll_s = poll_time(probe.io, poll_plan(device)[0])
    said = (
        f"poll_rate_hz {rate:g} sends {rate * watchdog_s:.3g} polls per {watchdog_s:g} s "
        f"watchdog time; one poll takes {poll_s * 1000:.1f} ms on this line"
    )
    if poll_s * needed >= 1:
        return Finding(
            Verdict.CONTRADICTED,
            f"{said}: the line cannot carry {ANY_FRAME_POLLS_PER_PERIOD} polls a watchdog "
            f"time; set a longer time-out on the drive and as `period_s` in {found.file}",
        )
    if rate < needed:
        wanted = math.ceil(round(needed / RATE_STEP_HZ, 6)) * RATE_STEP_HZ
        return Finding(
            Verdict.CONTRADICTED,
            f"{said}: fewer than {ANY_FRAME_POLLS_PER_PERIOD}, the drive may trip while the "
            "bridge runs",
            {"poll_rate_hz": round(wanted, 6)},
        )
    return Finding(Verdict.CONFIRMED, said)
