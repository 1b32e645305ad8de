"""How a MOTEC stop is verified (MOTEC decisions 18 and 22): the drive must be seen
standing (|0xAF| within the standstill band), or its speed falling and then standing;
a stop that does not take is followed by a release (0x28 = 0), read back. Used by the
drive's own stops (``MotecDevice``) and by ``start_all``'s stop of a start not every
drive took (broadcast.py). No ROS here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from bridge_core.runtime.reads import read_blocks
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value
from bridge_core.wire.errors import LinkError, NotConfirmed

from .registers import ENABLE_OFF, STOP_MOVE
from .snapshots import MODE_PLAN, MOTION_PLAN, STANDSTILL_SPEED_RPM

# A position stop (0x29 = 0) is verified on this many reads of 0xAA-0xAF, one poll period
# of the default 10 Hz apart (decision 18); unverified, the drive is released.
STOP_CHECK_READS = 2
STOP_CHECK_PERIOD_S = 0.1
# A stop that took (|0xAF| falling) must bring the drive into the standstill band within
# this (the manual gives no deceleration; decision 22); otherwise the drive is released.
STOP_SETTLE_S = 2.0
STOP_SETTLE_READS = round(STOP_SETTLE_S / STOP_CHECK_PERIOD_S)


@dataclass
class StopWatch:
    """What a stop's check read: 0xAC and 0xAF, in order (decision 22)."""

    positions: list[int]
    speeds: list[int]

    @property
    def stands(self) -> bool:
        return bool(self.speeds) and abs(self.speeds[-1]) <= STANDSTILL_SPEED_RPM

    def text(self) -> str:
        if not self.speeds:
            return "nothing read"
        reads = f" over {len(self.speeds)} reads" if len(self.speeds) > 2 else ""
        return (
            f"0xAC {self.positions[0]} -> {self.positions[-1]}, 0xAF {self.speeds[0]} -> "
            f"{self.speeds[-1]} rpm{reads}"
        )


def watch_stop(io: RegisterIO, sleep: Callable[[float], None] = time.sleep) -> StopWatch:
    """0xAA-0xAF now and every ``STOP_CHECK_PERIOD_S`` until the drive stands (|0xAF|
    within the standstill band, decision 22: an unchanged 0xAA proves nothing). Gives up
    when ``STOP_CHECK_READS`` reads in a row did not show |0xAF| falling by more than the
    band (the stop did not take), or after ``STOP_SETTLE_S`` (a ramp too long)."""
    watch = StopWatch([], [])
    since_fall = 0
    for n in range(STOP_SETTLE_READS + 1):
        if n:
            sleep(STOP_CHECK_PERIOD_S)
        v = read_blocks(io, MOTION_PLAN, Priority.COMMAND)[0]
        speed = int(v["speed_actual"])
        if watch.speeds:
            falls = abs(speed) < abs(watch.speeds[-1]) - STANDSTILL_SPEED_RPM
            since_fall = 0 if falls else since_fall + 1
        watch.positions.append(int(v["position_actual"]))
        watch.speeds.append(speed)
        if watch.stands or since_fall >= STOP_CHECK_READS:
            break
    return watch


def verified_position_stop(
    io: RegisterIO,
    write: Callable[[str, Value], None],
    sleep: Callable[[float], None] = time.sleep,
) -> str:
    """0x29 = 0, then ``watch_stop``: stopped only when |0xAF| is within the standstill
    band (decision 22; a falling speed keeps the check reading, up to ``STOP_SETTLE_S``).
    Otherwise 0x28 = 0 (release, the stop the manual gives for every mode), 0x28 read back
    and the drive watched again (``release_checked``). Returns what was done and seen when
    the drive stands; ``NotConfirmed`` (what was written and read) when it does not
    (decision 18)."""
    write("start", STOP_MOVE)
    try:
        watch = watch_stop(io, sleep)
        if watch.stands:
            return f"move stopped (0x29 = 0; {watch.text()})"
        seen = watch.text()
    except LinkError as err:
        seen = f"its effect could not be read: {err}"
    return release_checked(io, write, sleep, f"0x29 = 0 did not stop the move ({seen})")


def release_checked(
    io: RegisterIO,
    write: Callable[[str, Value], None],
    sleep: Callable[[float], None],
    why: str,
) -> str:
    """0x28 = 0 after a stop that did not take (``why``), then 0x28 read back and the
    drive watched until it stands (``watch_stop``); ``NotConfirmed`` unless it reads 0x28
    = 0 and stands."""
    write("enable", ENABLE_OFF)
    try:
        enable = int(read_blocks(io, MODE_PLAN, Priority.COMMAND)[0]["enable"])
        watch = watch_stop(io, sleep)
    except LinkError as err:
        raise NotConfirmed(
            f"{why}: sent, not confirmed: wrote 0x28 = 0 (release), not read back: {err}"
        ) from None
    if enable != ENABLE_OFF:
        raise NotConfirmed(
            f"{why}: sent, not confirmed: wrote 0x28 = 0 (release), read 0x28 = {enable} "
            f"({watch.text()})"
        )
    if not watch.stands:
        raise NotConfirmed(
            f"{why}: drive released (0x28 = 0, reads 0), not confirmed standing: {watch.text()}"
        )
    return f"{why}: drive released (0x28 = 0, reads 0; {watch.text()})"
