"""Confirmation of a stepper command by the controller's own state (stepper decision 23).

The controller acknowledges every write whether or not it obeys, so a command that starts,
stops or changes motion is done only when the controller's own state, read back, shows
it. A stop: the running flags (40168+) of its motors read 0 within STOP_CONFIRM_S (the
stop coil is the manual's "急停", an immediate stop); a start: a running flag reads 1, or a
coordinate (40108+) moved, within START_CONFIRM_S (a register write: the register reads the
value written, ``StepperDevice``). Read at command priority every CONFIRM_READ_PERIOD_S
(polls get the line between two reads); not shown in time: ``NotConfirmed`` saying what
was written and read. No ROS here.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Protocol

from bridge_core.wire.codec import Value
from bridge_core.wire.errors import NotConfirmed

from .registers import motor_register
from .replies import coordinates_text, flags_text, register_label, units_differ


class ConfirmingDevice(Protocol):
    """What a confirmation reads from the device (``StepperDevice``), named here so the
    device imports this module and never the other way round."""

    def read_named(self, *names: str) -> dict[str, Value]: ...

    def coordinates(self, motors: Sequence[int]) -> dict[int, float]: ...


STOP_CONFIRM_S = 0.5
START_CONFIRM_S = 0.5
CONFIRM_READ_PERIOD_S = 0.05


def running_flags(device: ConfirmingDevice, motors: Sequence[int]) -> dict[int, bool]:
    """The running flags (40168+) of ``motors``, read now at command priority."""
    names = {m: motor_register(m, "running") for m in motors}
    values = device.read_named(*names.values())
    return {m: bool(values[name]) for m, name in names.items()}


def confirm_stopped(device: ConfirmingDevice, motors: Sequence[int], wrote: str) -> str:
    """The running flags of ``motors`` read until every one is 0, for STOP_CONFIRM_S:
    what was written and read, or ``NotConfirmed`` saying so."""
    deadline = time.monotonic() + STOP_CONFIRM_S
    while True:
        flags = running_flags(device, motors)
        still = [m for m in motors if flags[m]]
        if not still:
            return f"wrote {wrote}; read {flags_text(motors, 0)}"
        if time.monotonic() >= deadline:
            raise NotConfirmed(
                f"wrote {wrote}; read {flags_text(still, 1)} {STOP_CONFIRM_S:g} s after"
            )
        time.sleep(CONFIRM_READ_PERIOD_S)


def confirm_started(
    device: ConfirmingDevice, motors: Sequence[int], wrote: str, before: dict[int, float]
) -> str:
    """A start shown: a running flag of ``motors`` reads 1, or a coordinate left its
    value ``before`` the start by a step (a short single run may end before the first
    read), within START_CONFIRM_S; else ``NotConfirmed`` with what was read."""
    deadline = time.monotonic() + START_CONFIRM_S
    while True:
        flags = running_flags(device, motors)
        on = [m for m in motors if flags[m]]
        if on:
            return f"wrote {wrote}; read {flags_text(on, 1)}"
        now = device.coordinates(motors)
        moved = [m for m in motors if units_differ(now[m], before[m])]
        if moved:
            return f"wrote {wrote}; read {coordinates_text(moved, before, now)}"
        if time.monotonic() >= deadline:
            unchanged = ", ".join(
                f"motor {m} coordinate ({register_label(motor_register(m, 'coordinate'))}) "
                f"{now[m]:g}"
                for m in motors
            )
            raise NotConfirmed(
                f"wrote {wrote}; read {flags_text(motors, 0)} and {unchanged} unchanged "
                f"{START_CONFIRM_S:g} s after"
            )
        time.sleep(CONFIRM_READ_PERIOD_S)
