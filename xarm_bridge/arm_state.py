"""The xArm's state machine as a command reads it back (xArm decisions 19 and 20).

A stop, pause, start or offline task is done only when H33 (and the error code I32) read
back show it within CONFIRM_S; the pause / stop coils are shown, never taken as proof.
The device writes the commands (``XArmDevice``); this module reads and judges. No ROS
here. "xArm decision N" is reading N of docs/decisions/xarm.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.errors import NotConfirmed
from bridge_core.wire.registers import Table

from .registers import (
    COIL_PAUSED,
    SET_STATE_PAUSE,
    SET_STATE_STOP,
    XARM_MAP,
    error_text,
    mode_name,
    state_name,
)

MODE_ADDRESS = XARM_MAP["arm_mode"].address
STATE_ADDRESS = XARM_MAP["arm_state"].address
# A stop, pause or start is given this long to show in the state read back (the SDK's
# own set_state answers at once; a stop that ramps down shows its state when it begins).
CONFIRM_S = 0.5
CONFIRM_READ_PERIOD_S = 0.02  # between two read backs of the state while waiting
STATE_IN_MOTION = 1  # H33 read (the xArm SDK's get_state)
STATE_READY = 2  # "sleeping": ready, nothing to do (what a start leaves when no task waits)
ERROR_ADDRESS = XARM_MAP["error_code"].address

# What the state read back must show (xArm decisions 19 and 20), per command kind.
SHOWN_BY = {
    "stop": "state 4 (stopped)",
    "pause": "state 3 (paused) or 4 (stopped)",
    "start": "state 1 (in motion) or 2 (ready) with no error",
    "task": "state 1 (in motion) with no error",
}


@dataclass(frozen=True)
class ArmReading:
    """What a motion command reads back: H32, H33, the error code I32 and the pause /
    stop coils C144 / C145 (shown, never taken as proof: xArm decision 19)."""

    mode: int
    state: int
    error_code: int
    paused: bool
    stopped: bool

    def shows(self, kind: str) -> bool:
        """Whether H33 (and I32) show ``kind`` done (``SHOWN_BY``). A pause is not shown
        by state 2: a task waiting on an input stands in state 2 and moves again."""
        if kind == "stop":
            return self.state == SET_STATE_STOP
        if kind == "pause":
            return self.state in (SET_STATE_PAUSE, SET_STATE_STOP)
        if kind == "start":
            return self.error_code == 0 and self.state in (STATE_IN_MOTION, STATE_READY)
        return self.error_code == 0 and self.state == STATE_IN_MOTION

    def __str__(self) -> str:
        error = f"error {self.error_code}"
        if self.error_code:
            error += f" ({error_text(self.error_code)})"
        return (
            f"mode {self.mode} ({mode_name(self.mode)}), state {self.state} "
            f"({state_name(self.state)}), {error}, C144 paused {int(self.paused)}, C145 "
            f"stopped {int(self.stopped)}"
        )


def read_arm(io: RegisterIO) -> ArmReading:
    """H32-33, the error code I32 and the coils C144-145, at command priority."""
    mode, state = io.read_registers(MODE_ADDRESS, 2, priority=Priority.COMMAND)
    (error,) = io.read_registers(ERROR_ADDRESS, 1, table=Table.INPUT, priority=Priority.COMMAND)
    paused, stopped = io.read_bits(COIL_PAUSED, 2, priority=Priority.COMMAND)
    return ArmReading(signed(mode), signed(state), error, bool(paused), bool(stopped))


def confirm(io: RegisterIO, kind: str, wrote: str) -> str:
    """The state read back until it shows ``kind`` or CONFIRM_S passed: what was
    written and read when it shows; ``NotConfirmed`` saying both when it does not."""
    deadline = time.monotonic() + CONFIRM_S
    while True:
        seen = read_arm(io)
        if seen.shows(kind):
            return f"wrote {wrote}; reads {seen}"
        if time.monotonic() >= deadline:
            raise NotConfirmed(
                f"wrote {wrote}; reads {seen} after {CONFIRM_S:g} s, not {SHOWN_BY[kind]}"
            )
        time.sleep(CONFIRM_READ_PERIOD_S)


def signed(word: int) -> int:
    return word - 0x10000 if word >= 0x8000 else word
