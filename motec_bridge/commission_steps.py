"""``bridge_commission motec``: the drive's facts and the read-only checks of
``motec_bridge/commission.py`` (the guided steps are commission_guided.py's). No ROS here.

The tool commissions one drive of the bus (its ``--unit-id``, by default the first of
``unit_ids``) through the bridge's own ``MotecDevice``. Everything here only reads; every
limit is a named constant. "Decision N" is MOTEC decision N of docs/decisions/motec.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import words_to_int
from bridge_core.wire.errors import DeviceException
from bridge_core.wire.registers import Register, Table, ValueType, WordOrder
from bridge_core.wire.serial_timing import longest_hold_s

from .device import MotecDevice
from .lifeguard import lifeguard_min_ms
from .registers import (
    LAST_PARAMETER,
    LIFEGUARD_ACTIVE,
    LIFEGUARD_OFF_MS,
    MOTEC_MAP,
    control_mode_name,
    fault_text,
    operation_mode_name,
)
from .snapshots import FAST_PLAN, SLOW_PLAN

# Decision 2: a count is plausible within this many motor turns of 0 (0x26, 0xAA, 0xAC);
# a word swap of a count of a few turns reads hundreds of millions.
PLAUSIBLE_TURNS = 10_000
WORD_ORDER_ROWS = ("target_distance", "position_setpoint", "position_actual")
# Decision 3: the unnamed parameters the poll reads through (0x2A-0x2C, 0xC7).
UNNAMED_IN_POLL = ((0x2A, 3), (0xC7, 1))
# Decision 13: where the parameter table's end is looked for (bisection from the last
# parameter the manual names; a holding address is 16 bits).
TABLE_SCAN_LIMIT = 0xFFFF
# Decision 9: what the report recommends for lifeguard_ms on a drive whose own setting
# is off (the example params file's value), never below the bus's floor.
LIFEGUARD_RECOMMENDED_MS = 1000
FACT_NAMES = (
    "operation_mode",
    "control_mode",
    "enable",
    "fault_code",
    "speed_setpoint",
    "analog_max_speed",
    "lifeguard_time",
    "lifeguard_mode",
    "position_actual",
)


@dataclass
class Drive:
    """``probe.device`` of the MOTEC checks: the bridge's device for the drive, its unit,
    and what the guided steps found it as (so their stops put it back)."""

    device: MotecDevice
    unit: int
    counts_per_rev: float
    enabled_at_start: bool


def drive_of(probe: Probe) -> Drive:
    found = probe.device
    assert isinstance(found, Drive), "setup() runs first"
    return found


def device_of(values: dict[str, Any] | Any, io: RegisterIO) -> MotecDevice:
    """The bridge's device, made from the drive node's parameters as node.py makes it."""
    return MotecDevice(
        io,
        max_speed_rpm=int(values.get("max_speed_rpm", 3000)),
        output1_coil=int(values.get("output1_coil", 0)),
        read_io_tables=bool(values.get("read_io_tables", False)),
        allow_unlisted_parameters=bool(values.get("allow_unlisted_parameters", False)),
    )


def ping(io: RegisterIO) -> object:
    """One short read, timed for the reply times: the actual speed (0xAF)."""
    return io.read_registers(MOTEC_MAP["speed_actual"].address, 1, priority=Priority.COMMAND)


def setup(probe: Probe) -> None:
    """The drive's facts for the report (reads only). The manual names no firmware or
    model register: the facts are the modes, the fault code and the settings."""
    device = device_of(probe.values, probe.io)
    v = device.read_named(*FACT_NAMES)
    unit = int(getattr(probe.io, "unit_id", 0))  # the channel's (the tool's --unit-id)
    probe.device = Drive(
        device, unit, float(probe.values.get("counts_per_rev", 10000.0)), bool(v["enable"])
    )
    fault = int(v["fault_code"])
    probe.facts.update(
        {
            "unit id": str(unit),
            "firmware": "not readable (the manual names no such register)",
            "operation mode (0x24)": f"{operation_mode_name(int(v['operation_mode']))}",
            "control mode (0x25)": control_mode_name(int(v["control_mode"])),
            "enabled (0x28)": str(int(v["enable"])),
            "fault code (0xC8-0xC9)": f"0x{fault:08X}: {fault_text(fault)}",
            "speed limit (0xAE)": f"{int(v['speed_setpoint'])} rpm",
            "analog max speed (0x6D)": f"{int(v['analog_max_speed'])}",
            "lifeguard (0x112, 0x114)": f"{int(v['lifeguard_time'])} ms, mode "
            f"{int(v['lifeguard_mode'])}",
            "position (0xAC)": f"{int(v['position_actual'])} counts",
        }
    )


def requests_per_poll(probe: Probe) -> int:
    """A poll of the fast group (decision 20), with the IO tables' 3 reads if set."""
    return len(FAST_PLAN) + (3 if bool(probe.values.get("read_io_tables", False)) else 0)


def refusal_reason(_reg: Register, _probe: Probe) -> None:
    """Every row of the map is a parameter of the contiguous table: none is expected to
    be refused."""
    return None


# ---------------------------------------------------------------- read-only checks
def word_order(probe: Probe) -> Finding:
    """Decision 2: every nonzero count (0x26, 0xAA, 0xAC), decoded both ways."""
    assert probe.rows is not None
    limit = PLAUSIBLE_TURNS * drive_of(probe).counts_per_rev
    seen: list[str] = []
    high_ok = low_ok = 0
    for name in WORD_ORDER_ROWS:
        words = probe.rows.answered.get(name)
        if not words or not any(words):
            continue
        signed = MOTEC_MAP[name].value_type is ValueType.I32
        high = words_to_int(words, signed, WordOrder.HIGH_FIRST)
        low = words_to_int(words, signed, WordOrder.LOW_FIRST)
        high_ok += abs(high) <= limit
        low_ok += abs(low) <= limit
        seen.append(f"{name} {high} (low word first: {low})")
    read = f"plausible: within {PLAUSIBLE_TURNS} turns; read {'; '.join(seen)}"
    if not seen:
        return Finding(
            Verdict.UNCLEAR,
            "every count read 0: turn the shaft a few turns by hand while the drive is "
            "released (or run a move), then run this again",
        )
    if high_ok == len(seen) and low_ok < len(seen):
        return Finding(Verdict.CONFIRMED, f"high word first is plausible, low is not ({read})")
    if low_ok == len(seen) and high_ok < len(seen):
        return Finding(
            Verdict.CONTRADICTED,
            "only low word first gives plausible counts: every position, target and "
            f"fault code the bridge reads or writes would be wrong; do not run it, tell us "
            f"({read})",
        )
    return Finding(Verdict.UNCLEAR, f"the counts settle neither order ({read})")


def unnamed_rows(probe: Probe) -> Finding:
    """Decision 3: the unnamed parameters alone, then every request of the poll as the
    bridge sends it (each reads through them)."""
    refused: list[str] = []
    for address, count in UNNAMED_IN_POLL:
        try:
            probe.io.read_registers(address, count, Table.HOLDING, Priority.COMMAND)
        except DeviceException as err:
            refused.append(f"0x{address:X}-0x{address + count - 1:X} ({err.name})")
    for request in (*FAST_PLAN, *SLOW_PLAN):
        try:
            probe.io.read_registers(request.address, request.count, request.table, Priority.COMMAND)
        except DeviceException as err:
            end = request.address + request.count - 1
            refused.append(f"the poll's 0x{request.address:X}-0x{end:X} ({err.name})")
    if refused:
        return Finding(
            Verdict.CONTRADICTED,
            f"refused: {'; '.join(refused)}: the table is not contiguous on this drive. "
            "The bridge reads without the unnamed rows from the first refusal on (logged "
            "once), so it works, with more requests per poll; tell us",
        )
    plans = len(FAST_PLAN) + len(SLOW_PLAN)
    return Finding(
        Verdict.CONFIRMED,
        f"0x2A-0x2C and 0xC7 answered alone, and the poll's {plans} requests that read "
        "through them answered",
    )


def _answers(probe: Probe, address: int) -> bool:
    try:
        probe.io.read_registers(address, 1, Table.HOLDING, Priority.COMMAND)
    except DeviceException:
        return False
    return True


def table_end(probe: Probe) -> Finding:
    """Decision 13: a number past the table's end answers exception 02. The end is found
    by bisection between Pr.276 (named, read by the scan) and ``TABLE_SCAN_LIMIT``."""
    low, high = LAST_PARAMETER, TABLE_SCAN_LIMIT
    if not _answers(probe, low):
        return Finding(Verdict.UNCLEAR, f"Pr.{low} (0x{low:X}, the lifeguard mode) refused")
    if _answers(probe, high):
        return Finding(
            Verdict.CONTRADICTED,
            f"Pr.{high} (0x{high:X}) answered: this drive answers numbers past its table, so "
            "~/read_parameter of a number the vendor tool does not show gives a value, not "
            "ILLEGAL DATA ADDRESS; trust only the numbers the vendor tool shows",
        )
    while high - low > 1:
        middle = (low + high) // 2
        if _answers(probe, middle):
            low = middle
        else:
            high = middle
    return Finding(
        Verdict.CONFIRMED,
        f"the table ends after Pr.{low} (0x{low:X}): Pr.{high} and Pr.{TABLE_SCAN_LIMIT} "
        "answer exception 02",
    )


def lifeguard_floor_ms(values: dict[str, Any] | Any) -> int:
    """The shortest lifeguard time the bridge keeps fed on this bus (lifeguard.py)."""
    drives = max(1, len(list(values.get("unit_ids", [1]))))
    hold = longest_hold_s(
        int(values.get("baudrate", 115200)),
        float(values.get("timeout_s", 0.1)),
        frame_gap_s=float(values.get("frame_gap_s", 0.0)),
    )
    return lifeguard_min_ms(drives, hold)


def lifeguard_settings(probe: Probe) -> Finding:
    """Decision 9: the drive's own lifeguard (0x112, 0x114, read by the scan), taken as
    armed unless 0x112 reads 0; ``lifeguard_ms`` recommended from it and the bus."""
    assert probe.rows is not None
    time_words = probe.rows.answered.get("lifeguard_time")
    mode_words = probe.rows.answered.get("lifeguard_mode")
    if not time_words or not mode_words:
        return Finding(Verdict.UNCLEAR, "0x112 or 0x114 refused: see the rows refused")
    time_ms, mode = time_words[0], mode_words[0]
    floor = lifeguard_floor_ms(probe.values)
    given = int(probe.values.get("lifeguard_ms", 0))
    drives = len(list(probe.values.get("unit_ids", [1])))
    said = (
        f"0x112 = {time_ms} ms, 0x114 = {mode}; this bus keeps at least {floor} ms fed "
        f"({drives} drive(s), timeout_s {float(probe.values.get('timeout_s', 0.1)):g}: "
        "lower it to the recommended one and this floor falls)"
    )
    if time_ms == LIFEGUARD_OFF_MS:
        wanted = max(given or LIFEGUARD_RECOMMENDED_MS, floor)
        return Finding(
            Verdict.CONFIRMED,
            f"off by the drive's own setting ({said}): the bridge arms it with lifeguard_ms",
            {"lifeguard_ms": wanted},
        )
    armed = "armed (0x114 = 9999)" if mode == LIFEGUARD_ACTIVE else "taken as armed"
    if time_ms < floor:
        return Finding(
            Verdict.CONTRADICTED,
            f"{armed} by the drive's own setting ({said}): too short to keep fed on this "
            f"bus, so the drive would trip under a running bridge; lifeguard_ms {floor} "
            "rewrites it at start",
            {"lifeguard_ms": max(given, floor)},
        )
    return Finding(
        Verdict.CONFIRMED,
        f"{armed} by the drive's own setting ({said}): the bridge feeds it even with "
        "lifeguard_ms 0; the recommendation keeps the drive's time. Note: a drive armed "
        "in network mode trips while this tool only reads",
        {"lifeguard_ms": max(given, time_ms)},
    )
