"""Bus-wide commands: one write to unit 0 (§2.5: "支持广播通信方式 ... 不回应广播") that
every drive on the line takes, then read back drive by drive, since no drive answers a
broadcast (MOTEC decision 15). ``disable_all`` releases every drive (0x28 = 0);
``start_all`` starts every drive's prepared move at once (0x29 = 1), after ``~/move``'s
checks on each. The bus node (bus.py) offers them as ``~/disable_all`` / ``~/start_all``.
No ROS here.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping

from bridge_core.runtime.reads import read_blocks
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value, encode
from bridge_core.wire.errors import CommandRejected, LinkError, NotConfirmed
from bridge_core.wire.planner import ReadRequest, plan_reads

from .registers import CONTROL_MODE_POSITION, ENABLE_OFF, MOTEC_MAP, START_MOVE
from .snapshots import MODE_NAMES, STANDSTILL_SPEED_RPM, Modes
from .stops import verified_position_stop

# After a broadcast: what each drive shows (0x28, 0x29, 0xAA, 0xAF).
BROADCAST_CHECK_NAMES = ("enable", "start", "position_setpoint", "speed_actual")
BROADCAST_CHECK_PLAN: list[ReadRequest] = plan_reads(
    MOTEC_MAP, MOTEC_MAP.select(BROADCAST_CHECK_NAMES)
)
# Before start_all: what ~/move checks (modes, the speed limit 0xAE) and the fault code.
START_CHECK_NAMES = (*MODE_NAMES, "position_setpoint", "speed_setpoint", "fault_code")
START_CHECK_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(START_CHECK_NAMES))


def _drive_line(unit: int, v: Mapping[str, Value]) -> str:
    return (
        f"drive {unit}: 0x28 = {v['enable']}, 0x29 = {v['start']}, "
        f"0xAA = {v['position_setpoint']}, 0xAF = {v['speed_actual']} rpm"
    )


def disable_all(broadcast: RegisterIO, drives: Mapping[int, RegisterIO]) -> tuple[bool, str]:
    """Release every drive on the bus with one broadcast write (unit 0, §2.5): 0x28 = 0.

    No drive answers a broadcast, so each drive's 0x28 / 0x29 / 0xAA / 0xAF is read back
    after it; a drive still enabled (it missed the frame) gets its own 0x28 = 0 and is read
    again. True only when every drive reads 0x28 = 0 (decision 15); the text says, drive
    by drive, what was seen.
    """
    reg = MOTEC_MAP["enable"]
    broadcast.write_register(reg.address, encode(reg, ENABLE_OFF)[0])
    ok = True
    lines: list[str] = []
    for unit, io in drives.items():
        try:
            v = read_blocks(io, BROADCAST_CHECK_PLAN, Priority.COMMAND)[0]
            if int(v["enable"]) != ENABLE_OFF:
                io.write_register(reg.address, encode(reg, ENABLE_OFF)[0])
                v = read_blocks(io, BROADCAST_CHECK_PLAN, Priority.COMMAND)[0]
                note = " (missed the broadcast: released by a write of its own)"
            else:
                note = ""
        except LinkError as err:
            ok = False
            lines.append(f"drive {unit}: did not answer ({err}): its state is unknown")
            continue
        if int(v["enable"]) != ENABLE_OFF:
            ok = False
            note = " STILL ENABLED"
        lines.append(_drive_line(unit, v) + note)
    return ok, "; ".join(lines)


def _start_checked(drives: Mapping[int, RegisterIO], read_only: Iterable[int]) -> dict[int, int]:
    """``start_all``'s checks before it sends anything (refused: ``CommandRejected``,
    naming every drive that fails one); the setpoint 0xAA each drive had, by unit."""
    refused = [f"drive {u}'s node is read_only" for u in sorted(set(read_only) & set(drives))]
    before: dict[int, int] = {}
    for unit, io in drives.items():
        try:
            v = read_blocks(io, START_CHECK_PLAN, Priority.COMMAND)[0]
            before[unit] = int(v["position_setpoint"])
        except LinkError as err:
            raise CommandRejected(f"drive {unit} did not answer ({err}); nothing sent") from None
        modes = Modes(int(v["operation_mode"]), int(v["control_mode"]), bool(v["enable"]))
        if not (modes.network and modes.control_mode == CONTROL_MODE_POSITION and modes.enabled):
            refused.append(f"drive {unit} is in {modes.describe()}")
        if int(v["fault_code"]):
            refused.append(f"drive {unit} has fault {int(v['fault_code'])}")
        if int(v["speed_setpoint"]) <= 0:
            refused.append(
                f"drive {unit}'s speed limit 0xAE is {int(v['speed_setpoint'])} rpm (the move "
                "could not run)"
            )
    if refused:
        raise CommandRejected(
            "a synchronised start needs every drive in network mode, position control, "
            f"enabled, without a fault, with a speed limit 0xAE > 0 and writable; "
            f"{'; '.join(refused)}; nothing was sent"
        )
    return before


def _stop_the_started(
    drives: Mapping[int, RegisterIO], to_stop: Iterable[int], sleep: Callable[[float], None]
) -> list[str]:
    """A start not every drive took: the drives that took it, and those whose state is
    unknown (they may be running), stopped (``verified_position_stop``), a line each."""
    stops: list[str] = []
    for unit in to_stop:
        io = drives[unit]

        def write(name: str, value: Value, io: RegisterIO = io) -> None:
            r = MOTEC_MAP[name]
            io.write_register(r.address, encode(r, value)[0])

        try:
            stops.append(f"drive {unit}: {verified_position_stop(io, write, sleep)}")
        except NotConfirmed as err:
            stops.append(f"drive {unit}: stop not confirmed: {err}")
        except LinkError as err:
            stops.append(f"drive {unit}: stop failed: {err}")
    return stops


def start_all(
    broadcast: RegisterIO,
    drives: Mapping[int, RegisterIO],
    read_only: Iterable[int] = (),
    sleep: Callable[[float], None] = time.sleep,
) -> tuple[bool, str]:
    """A synchronised start (§4.1 step 6 "0x29 写 1" sent to unit 0, §2.5: "支持广播通信方式
    ... 不回应广播"): every drive starts the move it was given (0x26, 0x2D, 0xAE).

    Before: ``~/move``'s checks for every drive (network mode, position control, enabled,
    a speed limit 0xAE > 0), no fault code, and no drive whose node is ``read_only``;
    refused, nothing sent, otherwise. After (nothing answers a broadcast): every drive's
    0x28 / 0x29 / 0xAA / 0xAF read back. A drive took the start if its setpoint 0xAA moved
    since the check or |0xAF| is above the standstill band (0x29 may read 1 from an
    earlier move: it proves nothing). One that did not leaves a start that is not
    synchronised, so the drives that did are stopped (``verified_position_stop``) and the
    answer is False (decision 15); a zero-length move counts as not started. A drive whose
    read-back is lost is neither: its state is unknown, it may be running, so it is
    stopped too and the answer is False.
    """
    before = _start_checked(drives, read_only)
    reg = MOTEC_MAP["start"]
    broadcast.write_register(reg.address, encode(reg, START_MOVE)[0])
    seen: dict[int, Mapping[str, Value]] = {}
    unknown: dict[int, str] = {}
    for unit, io in drives.items():
        try:
            seen[unit] = read_blocks(io, BROADCAST_CHECK_PLAN, Priority.COMMAND)[0]
        except LinkError as err:
            unknown[unit] = str(err)
    missed = [
        u
        for u, v in seen.items()
        if int(v["position_setpoint"]) == before[u]
        and abs(int(v["speed_actual"])) <= STANDSTILL_SPEED_RPM
    ]
    lines = [
        f"drive {u}: not read back ({unknown[u]}): its state is unknown"
        if u in unknown
        else _drive_line(u, seen[u])
        for u in drives
    ]
    if not missed and not unknown:
        return True, "; ".join(lines)
    to_stop = [u for u in drives if u not in missed]
    stops = _stop_the_started(drives, to_stop, sleep)
    what = []
    if missed:
        what.append(f"drives {missed} did not take the start")
    if unknown:
        what.append(f"drives {sorted(unknown)} were not read back (they may be running)")
    return False, (
        f"{' and '.join(what)} ({'; '.join(lines)}); stopped the others: "
        f"{'; '.join(stops) or 'none had started'}"
    )
