"""The R6 program's commands checked and read back (R6 decisions 23 and 29).

A command that sets the program running (start, single cycle, the two alarm clears) is
checked first against rows read just before it: auto mode, homed, the alarm. A start,
stop or clear is done only when the controller, read back, shows it. The device writes
the commands (``R6Device.command``); this module reads and judges. No ROS here. "R6
decision N" is reading N of docs/decisions/r6.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from bridge_core.runtime.reads import read_named
from bridge_core.wire.channel import RegisterIO
from bridge_core.wire.errors import CommandRejected, LinkError, NotConfirmed

from .registers import COMMANDS, R6_MAP, mode_name

PROGRAM = "program"  # the axis of what runs the controller's program (run_cycle, ~/start)
MODE_AUTO = 2  # 2185: "2 自动" (decision 2)
# The commands that set the program running (R6 decision 23): checked first.
PROGRAM_COMMANDS = ("start", "single_cycle", "clear_alarm_and_continue", "clear_alarm_and_next")
CLEAR_COMMANDS = ("clear_alarm_and_continue", "clear_alarm_and_next")
# The rows those checks read fresh, at command priority (moving and the current cycle time:
# what a start is confirmed against, and whether a program already runs).
READINESS_ROWS = (
    "mode",
    "alarm_code",
    "homed",
    "global_speed",
    "last_cycle_time",
    "moving",
    "current_cycle_time",
)
# The commands that set the program running from standstill, confirmed after the write.
START_COMMANDS = ("start", "single_cycle")
# R6 decision 29: a stop, pause or stop button is done when the controller, read back,
# shows the program standing (2470 moving 0 and the current cycle time 2397 not counting
# over PROGRAM_STILL_S) within HALT_CONFIRM_S of the write's acknowledgement; a start or
# single cycle when it shows it running (moving 1, 2397 or 2401 changed) within
# START_CONFIRM_S. Otherwise: "not confirmed", with what was written and read.
HALT_CONFIRM_S = 1.0
START_CONFIRM_S = 1.0
PROGRAM_STILL_S = 0.1  # 2397 unchanged this long (moving 0): the cycle is not counting
CONFIRM_READ_PERIOD_S = 0.02  # between two read backs while waiting


@dataclass(frozen=True)
class Readiness:
    """The rows a program start is checked against, read just before it is written."""

    mode: int
    alarm_code: int
    homed: bool
    global_speed_percent: float
    last_cycle_time_ms: int
    moving: bool = False
    current_cycle_time_ms: int = 0


@dataclass(frozen=True)
class ProgramState:
    """What a stop or start is confirmed from (R6 decision 29): 2470, 2397 and (for a
    start) 2401, read at ``at`` (time.monotonic(), after the reply)."""

    moving: bool
    cycle_ms: int
    last_cycle_ms: int | None
    at: float

    @property
    def text(self) -> str:
        last = (
            ""
            if self.last_cycle_ms is None
            else f", last cycle time (2401) {self.last_cycle_ms} ms"
        )
        return (
            f"moving (2470) {int(self.moving)}, current cycle time (2397) {self.cycle_ms} ms{last}"
        )


def read_readiness(io: RegisterIO) -> Readiness:
    values = read_named(io, R6_MAP, READINESS_ROWS)
    return Readiness(
        mode=int(values["mode"]),
        alarm_code=int(values["alarm_code"]),
        homed=bool(values["homed"]),
        global_speed_percent=float(values["global_speed"]),
        last_cycle_time_ms=int(values["last_cycle_time"]),
        moving=bool(values["moving"]),
        current_cycle_time_ms=int(values["current_cycle_time"]),
    )


def read_program_state(io: RegisterIO, *, last_cycle: bool = False) -> ProgramState:
    """2470 and 2397 (and 2401 with ``last_cycle``), at command priority."""
    names = ("moving", "current_cycle_time", *(("last_cycle_time",) if last_cycle else ()))
    values = read_named(io, R6_MAP, names)
    return ProgramState(
        moving=bool(values["moving"]),
        cycle_ms=int(values["current_cycle_time"]),
        last_cycle_ms=int(values["last_cycle_time"]) if last_cycle else None,
        at=time.monotonic(),
    )


def check_program_command(
    io: RegisterIO, name: str, *, skip_failed_step: bool = False
) -> Readiness:
    """Refuse a command that sets the program running unless the controller, read just
    now, is in auto mode and homed, and (start, single cycle) has no alarm or (the
    clear-alarm commands) has one to clear (R6 decision 23). 20005 skips the
    instruction that raised the alarm: only with ``skip_failed_step``."""
    if name not in PROGRAM_COMMANDS:
        raise CommandRejected(f"{name} does not start the program")
    if name == "clear_alarm_and_next" and not skip_failed_step:
        raise CommandRejected(
            "clear_alarm_and_next (20005) skips the instruction that raised the alarm "
            "(e.g. a failed vacuum check): send skip_failed_step: true to mean it, or "
            "clear_alarm_and_continue to retry that instruction"
        )
    ready = read_readiness(io)
    if ready.mode != MODE_AUTO:
        raise CommandRejected(
            f"the controller is in {mode_name(ready.mode)} mode (2185 = {ready.mode}), "
            "not auto: switch to auto on the pendant first"
        )
    if not ready.homed:
        raise CommandRejected(
            "the controller is not homed (2471 = 0): set every axis's origin first"
        )
    if name in CLEAR_COMMANDS:
        if not ready.alarm_code:
            raise CommandRejected("no alarm is active (2396 = 0): nothing to clear")
    elif ready.alarm_code:
        raise CommandRejected(
            f"alarm {ready.alarm_code} is active and blocks the program: clear it first"
        )
    return ready


def confirm_halted(io: RegisterIO, name: str) -> str:
    """A stop (20000), pause (20001) or stop button (20004) just acknowledged: done only
    when the controller shows the program standing within HALT_CONFIRM_S (R6 decision
    29): moving (2470) 0 and the current cycle time (2397) not counting over
    PROGRAM_STILL_S (a step that waits for an input shows moving 0 while its cycle
    counts). Not shown: ``NotConfirmed`` with what was written and read."""
    wrote = f"wrote {COMMANDS[name]} = 1 ({name}), acknowledged"
    deadline = time.monotonic() + HALT_CONFIRM_S
    still: ProgramState | None = None  # the first read of the current standstill
    while True:
        try:
            seen = read_program_state(io)
        except LinkError as err:
            raise NotConfirmed(f"sent ({wrote}); the read back failed: {err}") from err
        if seen.moving:
            still = None
        elif still is None or seen.cycle_ms != still.cycle_ms:
            still = seen
        elif seen.at - still.at >= PROGRAM_STILL_S:
            return f"{wrote}; read {seen.text}, not counting: the program stands"
        if time.monotonic() >= deadline:
            raise NotConfirmed(
                f"sent ({wrote}); read {seen.text} {HALT_CONFIRM_S:g} s after "
                "(HALT_CONFIRM_S): the program may still run"
            )
        time.sleep(CONFIRM_READ_PERIOD_S)


def confirm_start(io: RegisterIO, name: str, before: Readiness) -> str:
    """A start or single cycle just acknowledged: done only when the controller shows
    the program running within START_CONFIRM_S (R6 decision 29): moving (2470) 1, or
    the current (2397) or last (2401) cycle time changed from ``before`` (read just
    before the write: a step that waits counts 2397 with moving 0; a cycle shorter
    than a read back changes 2401). Not shown: ``NotConfirmed``."""
    wrote = f"wrote {COMMANDS[name]} = 1 ({name}), acknowledged"
    was = (
        f"moving (2470) {int(before.moving)}, current cycle time (2397) "
        f"{before.current_cycle_time_ms} ms, last cycle time (2401) "
        f"{before.last_cycle_time_ms} ms"
    )
    deadline = time.monotonic() + START_CONFIRM_S
    while True:
        try:
            seen = read_program_state(io, last_cycle=True)
        except LinkError as err:
            raise NotConfirmed(f"sent ({wrote}); the read back failed: {err}") from err
        if (
            seen.moving
            or seen.cycle_ms != before.current_cycle_time_ms
            or seen.last_cycle_ms != before.last_cycle_time_ms
        ):
            already = " (it was moving before the write)" if before.moving else ""
            return f"{wrote}; read {seen.text}: the program runs{already}"
        if time.monotonic() >= deadline:
            raise NotConfirmed(
                f"sent ({wrote}); read {seen.text} {START_CONFIRM_S:g} s after "
                f"(START_CONFIRM_S); before the write: {was}: the program did not start"
            )
        time.sleep(CONFIRM_READ_PERIOD_S)


def confirm_cleared(io: RegisterIO, name: str, before: Readiness) -> str:
    """20005 / 20006 just acknowledged: done only when the alarm code (2396) reads 0
    within START_CONFIRM_S (R6 decision 29); otherwise ``NotConfirmed``."""
    wrote = f"wrote {COMMANDS[name]} = 1 ({name}), acknowledged"
    deadline = time.monotonic() + START_CONFIRM_S
    while True:
        try:
            code = int(read_named(io, R6_MAP, ("alarm_code",))["alarm_code"])
        except LinkError as err:
            raise NotConfirmed(f"sent ({wrote}); the read back failed: {err}") from err
        if code == 0:
            return f"{wrote}; read alarm code (2396) 0 (was {before.alarm_code})"
        if time.monotonic() >= deadline:
            raise NotConfirmed(
                f"sent ({wrote}); read alarm code (2396) {code} {START_CONFIRM_S:g} s "
                "after (START_CONFIRM_S): the alarm was not cleared"
            )
        time.sleep(CONFIRM_READ_PERIOD_S)
