"""The stepper's read-only commissioning checks and what the tool needs to reach the
device (``ping``, ``setup``, ``requests_per_poll``), named by the rows of
``stepper_bridge/commission.py`` (``bridge_commission stepper``, docs/commissioning.md);
the guided steps are commission_guided.py's.

They read only, with the bridge's own device logic (``StepperDevice``) and its reply
floor (``registers.reply_timeout_floor_s``). No ROS here. "Stepper decision N" is reading
N of docs/decisions/stepper.md.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from bridge_core.runtime.commission import (
    Finding,
    Probe,
    Verdict,
    recommend_timeout_s,
    reply_times,
)
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import words_to_int
from bridge_core.wire.errors import (
    DeviceException,
    LinkError,
)
from bridge_core.wire.registers import WordOrder
from bridge_core.wire.transport import SerialSettings

from .device import StepperDevice
from .registers import (
    BAUD_RATES,
    DISTANCE_SCALE,
    MAX_REGISTERS_PER_REQUEST,
    MOTORS,
    REPLY_DELAY_S,
    STEPPER_MAP,
    UNDEFINED_HOLDING,
    holding,
    motor_register,
    reply_timeout_floor_s,
)
from .snapshots import FAST_PLAN

# Decision 7: the reply times the check takes itself (the runner's are not given to it).
REPLY_PINGS = 10
# Decision 1: the manual's order first (low word first), then the other.
WORD_ORDERS = (WordOrder.LOW_FIRST, WordOrder.HIGH_FIRST)
# Decisions 7 and 21: the undefined rows between the poll's blocks (PLC numbers, inclusive)
# whose answer would let the coordinates, inputs, outputs and running flags be read in
# fewer requests.
POLL_GAPS = ((40118, 40123), (40137, 40147), (40160, 40167))
PAIR_READING_TRIED = "type_rows"  # the guided line's hypothesis (commission_guided)


def the_device(probe: Probe) -> StepperDevice:
    found = probe.device
    assert isinstance(found, StepperDevice), "setup() runs first"
    return found


def ping(io: RegisterIO) -> object:
    """One short read, timed for the reply times: motor 1's running flag (40168)."""
    return io.read_registers(STEPPER_MAP["motor1_running"].address, 1, priority=Priority.COMMAND)


def setup(probe: Probe) -> None:
    """The controller's facts for the report (reads only): the link settings it holds, its
    mode, and per motor what the guided steps use (speed, lead, limit and home inputs)."""
    device = StepperDevice(probe.io, pair_reading=PAIR_READING_TRIED)
    config = device.read_config(Priority.COMMAND)
    probe.device = device
    baud = str(config.baud_rate)
    line_baud = int(probe.values.get("baudrate", config.baud_rate))
    if config.baud_rate != line_baud:
        # Decision 13 reads "一旦设定成功控制器立即生效" (at once): a rate that differs from
        # the line's may be the one the controller comes up with after a power cycle.
        baud += (
            f" (the line runs at {line_baud}: after a power cycle the controller may answer "
            f"at {config.baud_rate} only; tell us)"
        )
    probe.facts.update(
        {
            "firmware": "no register for it in the manual",
            "watchdog": "none in the manual: a motion runs on when the bridge dies (README)",
            "device id (40212)": str(config.device_id),
            "baud rate (40213)": baud,
            "system mode (40300)": str(config.system_mode),
            "homing order (40177-40181)": ", ".join(map(str, config.homing_order)),
            "line / arc pair (40202 / 40182)": (
                f"{config.interpolation.line_pair} / {config.interpolation.arc_pair}"
            ),
        }
    )
    for m, motor in enumerate(config.motors, start=1):
        probe.facts[f"motor {m}"] = (
            f"speed {motor.speed_rpm} rpm, lead {motor.lead:g}, inputs: positive limit "
            f"IN{motor.positive_limit_input}, negative limit IN{motor.negative_limit_input}, "
            f"home IN{motor.home_input}"
        )


def requests_per_poll(_probe: Probe) -> int:
    """The requests of one poll that reads no slow group (stepper decision 21)."""
    return len(FAST_PLAN)


# ---------------------------------------------------------------- read-only checks
def serial_settings(values: Mapping[str, Any]) -> SerialSettings:
    """The line as the bridge would open it, from the tool's parameters."""
    return SerialSettings(
        str(values.get("serial_port", "")),
        int(values.get("baudrate", 9600)),
        str(values.get("parity", "N")).upper(),
        int(values.get("stopbits", 1)),
        timeout_s=float(values.get("timeout_s", 0.5)),
    )


def reply_rule(probe: Probe) -> Finding:
    """Decision 7: ``REPLY_PINGS`` timed reads; the median reply within the floor at the
    line's baud rate confirms the bridge's reading (the controller's own delay is its
    typical reply; a slow one now and then is the host or the line, and the timeout
    covers it), and ``timeout_s`` is recommended from the slowest (never below the floor:
    the bridge refuses less)."""
    settings = serial_settings(probe.values)
    floor = reply_timeout_floor_s(settings)
    samples: list[float] = []
    lost = 0
    for _ in range(REPLY_PINGS):
        started = time.perf_counter()
        try:
            ping(probe.io)
        except LinkError:
            lost += 1
            continue
        samples.append(time.perf_counter() - started)
    times = reply_times(samples, lost)
    timeout = recommend_timeout_s(times, floor)
    line = f"{settings.baudrate} baud: floor {floor:.2f} s"
    if settings.timeout_s < floor - 1e-9:
        line += f" (the timeout_s {settings.timeout_s:g} given is below it: the bridge refuses it)"
    if not samples:
        return Finding(Verdict.UNCLEAR, f"no reply to {lost} requests at {line}")
    least = min(samples)
    shortest = (
        f"shortest {least * 1000:.1f} ms ("
        f"{'not sooner than' if least >= REPLY_DELAY_S else 'sooner than'} the manual's "
        f"{REPLY_DELAY_S * 1000:.0f} ms: a minimum, sooner is harmless)"
    )
    seen = f"{times.text}; {shortest}; {line}"
    if lost:
        return Finding(
            Verdict.UNCLEAR,
            f"{seen}: replies lost. Either the controller wants silence before each "
            "request (decision 7's other reading: run again with -p frame_gap_s:=0.035) or "
            "it answers later than timeout_s (run again with a larger timeout_s)",
        )
    if times.p50_s > floor:
        return Finding(
            Verdict.CONTRADICTED,
            f"{seen}: the controller answers later than the floor the bridge assumes; "
            f"timeout_s {timeout:g} covers it (3 x the slowest reply)",
            {"timeout_s": timeout},
        )
    late = "" if times.max_s <= floor else " (the slowest above it: the host or the line)"
    return Finding(
        Verdict.CONFIRMED,
        f"{seen}: the median reply within the floor{late}; timeout_s {timeout:g}",
        {"timeout_s": timeout},
    )


def word_order(probe: Probe) -> Finding:
    """Decision 1: the baud rate (40213-40214), a 32-bit value the manual lists every
    possible value of, decoded both ways from the row scan's words: exactly one order
    gives one of them. The leads read (nonzero) are listed both ways beside it."""
    assert probe.rows is not None
    words = probe.rows.answered.get("baud_rate")
    if not words:
        return Finding(Verdict.UNCLEAR, "the baud rate (40213-40214) was not read")
    low, high = (words_to_int(words, False, order) for order in WORD_ORDERS)
    leads = []
    for m in range(1, MOTORS + 1):
        lead = probe.rows.answered.get(motor_register(m, "lead"))
        if lead and any(lead):
            a, b = (words_to_int(lead, False, order) / DISTANCE_SCALE for order in WORD_ORDERS)
            leads.append(f"motor {m} lead {a:g} (high word first: {b:g})")
    seen = "; ".join([f"baud rate {low} (high word first: {high})", *leads])
    if low in BAUD_RATES and high not in BAUD_RATES:
        return Finding(
            Verdict.CONFIRMED, f"low word first gives a baud rate the manual lists; {seen}"
        )
    if high in BAUD_RATES and low not in BAUD_RATES:
        return Finding(
            Verdict.CONTRADICTED,
            "only high word first gives a baud rate the manual lists: every lead, run "
            "distance, coordinate and interpolation point the bridge reads and writes would "
            f"be wrong; do not run it, tell us; {seen}",
        )
    return Finding(Verdict.UNCLEAR, f"neither order settles it; {seen}")


def _gap_ranges() -> list[tuple[int, int]]:
    """Every undefined range of the map as (first PLC number, count), at most
    ``MAX_REGISTERS_PER_REQUEST`` a read."""
    ranges: list[tuple[int, int]] = []
    for first, last in UNDEFINED_HOLDING:
        at = first
        while at <= last:
            count = min(last - at + 1, MAX_REGISTERS_PER_REQUEST)
            ranges.append((at, count))
            at += count
    return ranges


def undefined_rows(probe: Probe) -> Finding:
    """Decisions 7 and 21: every undefined range read whole, alone; the controller refuses
    each. Ranges that answer between the poll's blocks would allow fewer requests a poll."""
    answered: list[str] = []
    ranges = _gap_ranges()
    for first, count in ranges:
        try:
            probe.io.read_registers(holding(first), count, priority=Priority.COMMAND)
        except DeviceException:
            continue
        answered.append(f"{first}-{first + count - 1}")
    if not answered:
        return Finding(
            Verdict.CONFIRMED,
            f"the {len(ranges)} undefined ranges ({_plc_ranges()}) each refused: the bridge's "
            "poll of three requests stands",
        )
    between = [f"{a}-{b}" for a, b in POLL_GAPS if f"{a}-{b}" in answered]
    faster = (
        f"; {', '.join(between)} lie between the poll's blocks: with them readable the "
        "coordinates and inputs (40108-40136) could be one request, or inputs, outputs and "
        "running flags (40124-40172, 49 registers) one, saving a request (~55 ms at 9600 "
        "baud) a poll; the bridge does not plan so (tell us)"
        if between
        else ""
    )
    return Finding(
        Verdict.CONTRADICTED,
        f"{len(answered)} of {len(ranges)} undefined ranges answered: {', '.join(answered)} "
        f"(harmless: the bridge never reads them){faster}",
    )


def _plc_ranges() -> str:
    return ", ".join(f"{a}-{b}" for a, b in UNDEFINED_HOLDING)
