"""``bridge_commission motec``: the guided steps (they write or move; each runs only after
the operator's ``yes``, and its stop goes out on every way out of it). No ROS here.

Each step checks first with the bridge's own checks (a refused command writes nothing),
writes with the bridge's ``MotecDevice`` and judges by what the drive reads back: the
verified stop of stops.py (decisions 18, 22), the fault code and 0x28 after a lifeguard
trip (decisions 7, 9). "Decision N" is MOTEC decision N of docs/decisions/motec.md.
"""

from __future__ import annotations

import time

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.runtime.reads import read_blocks
from bridge_core.wire.channel import Priority
from bridge_core.wire.errors import CommandRejected, NotConfirmed

from .commission_steps import Drive, drive_of
from .device import MotecDevice
from .registers import (
    CONTROL_MODE_POSITION,
    FAULT_NONE,
    FAULT_PRESENT,
    LIFEGUARD_ACTIVE,
)
from .snapshots import MOTION_PLAN, STANDSTILL_SPEED_RPM
from .stops import STOP_SETTLE_S

# The test moves (decisions 5, 18, 22): relative, this many motor turns at this speed,
# stopped with 0x29 = 0 after RUN_BEFORE_STOP_S (long before their end).
MOVE_TURNS = 2
MOVE_SPEED_RPM = 60  # one motor turn a second: the move lasts about 2 s
RUN_BEFORE_STOP_S = 0.4
SETPOINT_SAMPLES = 4  # 0xAA-0xAF read this many times while the move runs,
SETPOINT_PERIOD_S = 0.05  # this far apart
# The lifeguard step (decisions 7, 9): armed with this time, then nothing is written;
# the fault code is read every TRIP_READ_S until TRIP_LIMIT_FACTOR x the time + TRIP_SLACK_S.
LIFEGUARD_TEST_MS = 300
TRIP_READ_S = 0.05
TRIP_LIMIT_FACTOR = 3
TRIP_SLACK_S = 1.0
TRIP_EARLY_SHARE = 0.8  # a trip before this share of the time is too early
# Disarming (decision 9): armed with LIFEGUARD_TEST_MS, disarmed, then nothing written or
# read for OFF_WATCH_FACTOR x that time before the fault code is read.
OFF_WATCH_FACTOR = 3
# A resting servo (decision 17): enabled, no move, 0xAA-0xAF read every REST_READ_S for
# REST_WATCH_S; a larger dither than goal_tolerance_counts gets REST_TOLERANCE_FACTOR x it.
# A new target while a move runs (decision 21): an absolute move NEW_TARGET_FAR_TURNS
# ahead, after RUN_BEFORE_STOP_S a target NEW_TARGET_NEAR_TURNS ahead of where it started
# (the bridge's retarget), then read every REST_READ_S until it stands (up to
# NEW_TARGET_LIMIT_S) or runs NEW_TARGET_OVERSHOOT_TURNS past the new target.
NEW_TARGET_FAR_TURNS = 4
NEW_TARGET_NEAR_TURNS = 1
NEW_TARGET_LIMIT_S = 10.0
NEW_TARGET_OVERSHOOT_TURNS = 0.25  # this far past the new target: running on to the first
REST_WATCH_S = 1.0
REST_READ_S = 0.1
REST_TOLERANCE_FACTOR = 2


def _ready(drive: Drive) -> str | None:
    """None when the drive may start a step: no fault latched, the motor standing."""
    v = drive.device.read_named("fault_code", "speed_actual")
    if int(v["fault_code"]) != FAULT_NONE:
        return (
            f"the drive shows fault 0x{int(v['fault_code']):08X}: power-cycle it first "
            "(decision 16)"
        )
    if abs(int(v["speed_actual"])) > STANDSTILL_SPEED_RPM:
        return f"the motor turns at {int(v['speed_actual'])} rpm: stop it first"
    return None


def _start_move(probe: Probe) -> Finding | None:
    """Position control, enabled, the test move under way (None), or why not."""
    drive = drive_of(probe)
    if (busy := _ready(drive)) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    return _move(drive.device, round(MOVE_TURNS * drive.counts_per_rev), relative=True)


def _move(device: MotecDevice, counts: int, *, relative: bool) -> Finding | None:
    """Checked as the bridge checks it, position control, enabled, the move sent (each
    read back by the device's methods): None, or why it did not start."""
    try:
        device.check_move(counts, MOVE_SPEED_RPM)
        device.set_control_mode(CONTROL_MODE_POSITION)
        device.enable(True)
        device.move(counts, relative=relative, speed_rpm=MOVE_SPEED_RPM)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused: {err}")
    except NotConfirmed as err:
        return Finding(Verdict.UNCLEAR, f"the move did not start: {err}")
    return None


def _motion(device: MotecDevice) -> tuple[int, int, int]:
    """0xAA, 0xAC, 0xAF in one read."""
    v = read_blocks(device.io, MOTION_PLAN, Priority.COMMAND)[0]
    return int(v["position_setpoint"]), int(v["position_actual"]), int(v["speed_actual"])


def stop_and_restore(probe: Probe) -> str:
    """The stop of the motion steps: the bridge's verified stop for the drive's mode
    (position control: 0x29 = 0, watched until it stands, released if it does not), then
    the drive released again if it was released before the tool ran (0x28 read back)."""
    drive = drive_of(probe)
    try:
        said = drive.device.stop()
    except NotConfirmed as err:
        return f"not confirmed: {err}: stop the motor at the drive (its enable input or power)"
    if not drive.enabled_at_start:
        try:
            drive.device.enable(False)
            said += "; released again (0x28 = 0, reads 0)"
        except NotConfirmed as err:
            said += f"; the release was not confirmed: {err}"
    return said


def position_stop(probe: Probe) -> Finding:
    """Decisions 5, 18: a move stopped with 0x29 = 0 (the bridge's verified stop) must
    stand by 0x29 = 0 alone, not by the release that follows a stop that did not take."""
    if (refused := _start_move(probe)) is not None:
        return refused
    device = drive_of(probe).device
    if probe.wait(RUN_BEFORE_STOP_S):
        return Finding(Verdict.UNCLEAR, "stopped by the operator before the test's stop")
    _, _, speed = _motion(device)
    if abs(speed) <= STANDSTILL_SPEED_RPM:
        return Finding(Verdict.UNCLEAR, f"the move had ended before the stop (0xAF {speed} rpm)")
    try:
        said = device.stop_move()
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"{err}: neither 0x29 = 0 nor the release stopped the motor; stop using the "
            "bridge on this drive and tell us",
        )
    if said.startswith("move stopped"):
        return Finding(Verdict.CONFIRMED, f"at {speed} rpm: {said}")
    return Finding(
        Verdict.CONTRADICTED,
        f"at {speed} rpm: {said}. The drive takes 0x29 as a start trigger only: every "
        "position stop of the bridge releases the motor (it coasts); do not use ~/move on "
        "a load that must be held, and tell us",
    )


def setpoint_in_a_move(probe: Probe) -> Finding:
    """Decision 22: 0xAA next to 0xAC while the test move runs, then the verified stop
    (it must stand, |0xAF| within the band, within ``STOP_SETTLE_S``)."""
    if (refused := _start_move(probe)) is not None:
        return refused
    device = drive_of(probe).device
    reads = [_motion(device)]
    for _ in range(SETPOINT_SAMPLES - 1):
        if probe.wait(SETPOINT_PERIOD_S):
            return Finding(Verdict.UNCLEAR, "stopped by the operator during the reads")
        reads.append(_motion(device))
    try:
        stop = device.stop_move()
    except NotConfirmed as err:
        stop = f"not confirmed: {err}"
    setpoints = [r[0] for r in reads]
    positions = [r[1] for r in reads]
    seen = (
        f"0xAA {setpoints[0]} -> {setpoints[-1]}, 0xAC {positions[0]} -> {positions[-1]} over "
        f"{len(reads)} reads; stop: {stop}"
    )
    if not stop.startswith("move stopped"):
        return Finding(
            Verdict.CONTRADICTED,
            f"the stop did not stand the motor within {STOP_SETTLE_S:g} s by 0x29 = 0 "
            f"({seen}); see the check of 0x29 = 0 above",
        )
    if positions[-1] == positions[0]:
        return Finding(Verdict.UNCLEAR, f"0xAC did not move during the reads ({seen})")
    if setpoints[-1] != setpoints[0]:
        return Finding(Verdict.CONFIRMED, f"0xAA advances with 0xAC ({seen})")
    return Finding(
        Verdict.CONTRADICTED,
        f"0xAA holds the move's target while 0xAC advances: the other reading of decision "
        f"22; the bridge relies on neither (its stops watch 0xAF), so report it ({seen})",
    )


def standstill(probe: Probe) -> Finding:
    """Decision 17: enabled in position control, no move: |0xAF| within the standstill
    band and |0xAA - 0xAC| within ``goal_tolerance_counts`` on every read."""
    drive = drive_of(probe)
    if (busy := _ready(drive)) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    try:
        drive.device.set_control_mode(CONTROL_MODE_POSITION)
        drive.device.enable(True)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused: {err}")
    except NotConfirmed as err:
        return Finding(Verdict.UNCLEAR, f"the drive was not enabled: {err}")
    reads = [_motion(drive.device)]
    while len(reads) * REST_READ_S < REST_WATCH_S:
        if probe.wait(REST_READ_S):
            return Finding(Verdict.UNCLEAR, "stopped by the operator during the reads")
        reads.append(_motion(drive.device))
    speed = max(abs(r[2]) for r in reads)
    offset = max(abs(r[0] - r[1]) for r in reads)
    tolerance = int(probe.values.get("goal_tolerance_counts", 10))
    seen = (
        f"{len(reads)} reads over {REST_WATCH_S:g} s: |0xAF| up to {speed} rpm (band "
        f"{STANDSTILL_SPEED_RPM}), |0xAA - 0xAC| up to {offset} counts (goal_tolerance_counts "
        f"{tolerance})"
    )
    if speed > STANDSTILL_SPEED_RPM:
        return Finding(
            Verdict.CONTRADICTED,
            f"the resting servo reads more speed than the standstill band: {seen}; moves "
            "may never end REACHED and stops may release it: report the figure (the band is "
            "a constant)",
        )
    if offset > tolerance:
        wanted = max(tolerance, REST_TOLERANCE_FACTOR * offset)
        return Finding(
            Verdict.CONTRADICTED,
            f"the resting servo dithers more than goal_tolerance_counts: {seen}; raise it",
            {"goal_tolerance_counts": wanted},
        )
    return Finding(Verdict.CONFIRMED, seen)


def lifeguard_off(probe: Probe) -> Finding:
    """Decision 9: armed by the bridge's arm, disarmed by its disarm (0x112 = 0, then
    0x114 = 0), then nothing written: the drive must not trip."""
    drive = drive_of(probe)
    if (busy := _ready(drive)) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    device = drive.device
    try:
        device.set_control_mode(CONTROL_MODE_POSITION)
        device.arm_lifeguard(LIFEGUARD_TEST_MS)
        device.disarm_lifeguard()
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused: {err}")
    except NotConfirmed as err:
        return Finding(Verdict.UNCLEAR, f"network mode was not taken: {err}")
    watch_s = OFF_WATCH_FACTOR * LIFEGUARD_TEST_MS / 1000.0
    if probe.wait(watch_s):
        return Finding(Verdict.UNCLEAR, "stopped by the operator before the fault code was read")
    v = device.read_named("fault_code", "lifeguard_time", "lifeguard_mode")
    seen = (
        f"armed with {LIFEGUARD_TEST_MS} ms, disarmed (0x112 = 0, 0x114 = 0; read "
        f"{int(v['lifeguard_time'])}, {int(v['lifeguard_mode'])}), nothing written for "
        f"{watch_s:g} s: fault code 0x{int(v['fault_code']):08X}"
    )
    if int(v["fault_code"]) != FAULT_NONE:
        return Finding(
            Verdict.CONTRADICTED,
            f"the drive still watched after the disarm: {seen}. lifeguard_ms 0 does not "
            "disarm it: stop the bridge only with the drive released; power-cycle it now, "
            "and tell us",
        )
    return Finding(Verdict.CONFIRMED, seen)


def new_target(probe: Probe) -> Finding:
    """Decision 21: a newer absolute target and 0x29 = 1 while a move runs (the bridge's
    ``retarget``, read back): the drive must turn to it and stand there, not run on to
    the first target."""
    drive = drive_of(probe)
    if (busy := _ready(drive)) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    device = drive.device
    start = _motion(device)[1]
    far = start + round(NEW_TARGET_FAR_TURNS * drive.counts_per_rev)
    near = start + round(NEW_TARGET_NEAR_TURNS * drive.counts_per_rev)
    if (failed := _move(device, far, relative=False)) is not None:
        return failed
    if probe.wait(RUN_BEFORE_STOP_S):
        return Finding(Verdict.UNCLEAR, "stopped by the operator before the new target")
    try:
        device.retarget(near)
    except NotConfirmed as err:
        return Finding(Verdict.CONTRADICTED, f"the drive did not take the new target: {err}")
    started = time.monotonic()
    position, speed = _motion(device)[1:]
    overshoot = round(NEW_TARGET_OVERSHOOT_TURNS * drive.counts_per_rev)
    while abs(speed) > STANDSTILL_SPEED_RPM:
        if abs(position - start) > abs(near - start) + overshoot:
            break  # well past the new target: running on to the first one
        if time.monotonic() - started > NEW_TARGET_LIMIT_S:
            break
        if probe.wait(REST_READ_S):
            return Finding(Verdict.UNCLEAR, "stopped by the operator before it stood")
        position, speed = _motion(device)[1:]
    tolerance = int(probe.values.get("goal_tolerance_counts", 10))
    seen = (
        f"from 0xAC {start}: target {far}, then {near} while it ran; 0xAC {position}, 0xAF "
        f"{speed} rpm after {time.monotonic() - started:.1f} s"
    )
    if abs(speed) <= STANDSTILL_SPEED_RPM and abs(position - near) <= tolerance:
        return Finding(Verdict.CONFIRMED, f"it stood at the new target: {seen}")
    return Finding(
        Verdict.CONTRADICTED,
        f"it did not stand at the new target (it runs on to the first one): {seen}; do not "
        "use ~/joint_commands position streams on this drive (velocity streams are "
        "unaffected), and tell us",
    )


def disarm(probe: Probe) -> str:
    """The lifeguard step's stop: the bridge's disarm (0x112 = 0, then 0x114 = 0), read
    back; the drive is not moving (the step starts none)."""
    device = drive_of(probe).device
    device.disarm_lifeguard()
    v = device.read_named("lifeguard_time", "lifeguard_mode", "fault_code")
    said = (
        f"lifeguard disarmed (0x112 = 0, 0x114 = 0; read {int(v['lifeguard_time'])}, "
        f"{int(v['lifeguard_mode'])})"
    )
    if int(v["fault_code"]) != FAULT_NONE:
        said += (
            f"; fault 0x{int(v['fault_code']):08X} stays latched: power-cycle the drive "
            "(decision 16)"
        )
    return said


def _trip(probe: Probe, device: MotecDevice, armed_at: float) -> tuple[float, int, int] | str:
    """Read 0xC8-0xC9 and 0x28 until the fault shows: (seconds after the last write,
    fault, 0x28), or why not."""
    limit = TRIP_LIMIT_FACTOR * LIFEGUARD_TEST_MS / 1000.0 + TRIP_SLACK_S
    while time.monotonic() - armed_at < limit:
        v = device.read_named("fault_code", "enable")
        if int(v["fault_code"]) != FAULT_NONE:
            return time.monotonic() - armed_at, int(v["fault_code"]), int(v["enable"])
        if probe.wait(TRIP_READ_S):
            return "stopped by the operator before the trip"
    return f"no fault within {limit:g} s"


def lifeguard_trip(probe: Probe) -> Finding:
    """Decisions 7, 9: network mode, the lifeguard armed with ``LIFEGUARD_TEST_MS`` by the
    bridge's own arm, then nothing written: the drive must trip (fault code, 0x28 = 0)
    about that long after the last write; which half of 0xC8-0xC9 it fills is read."""
    drive = drive_of(probe)
    if (busy := _ready(drive)) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    device = drive.device
    try:
        device.set_control_mode(CONTROL_MODE_POSITION)
        device.arm_lifeguard(LIFEGUARD_TEST_MS)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused: {err}")
    except NotConfirmed as err:
        return Finding(Verdict.UNCLEAR, f"network mode was not taken: {err}")
    armed_at = device.last_write
    tripped = _trip(probe, device, armed_at)
    if isinstance(tripped, str):
        if tripped.startswith("stopped"):
            return Finding(Verdict.UNCLEAR, tripped)
        return Finding(
            Verdict.CONTRADICTED,
            f"armed with 0x112 = {LIFEGUARD_TEST_MS} ms, 0x114 = {LIFEGUARD_ACTIVE} in network "
            f"mode and nothing written: {tripped} (reads every {TRIP_READ_S:g} s; they may "
            "feed it). The bridge's lifeguard_ms does not protect on this drive: tell us",
        )
    after_s, fault, enabled = tripped
    seen = (
        f"fault 0x{fault:08X} (0xC8 = {fault >> 16}, 0xC9 = {fault & 0xFFFF}) read "
        f"{after_s * 1000:.0f} ms after the last write (0x112 = {LIFEGUARD_TEST_MS} ms, "
        f"reads every {TRIP_READ_S * 1000:.0f} ms), 0x28 = {enabled}"
    )
    if after_s < TRIP_EARLY_SHARE * LIFEGUARD_TEST_MS / 1000.0:
        return Finding(
            Verdict.CONTRADICTED,
            f"tripped early: {seen}; 0x112 may not be in ms on this drive: tell us",
        )
    if enabled:
        return Finding(Verdict.CONTRADICTED, f"{seen}: the drive did not release the motor (§3.4)")
    if fault == FAULT_PRESENT << 16:
        return Finding(Verdict.CONFIRMED, f"the flag is in 0xC8, as §4.3 prints it: {seen}")
    if fault == FAULT_PRESENT:
        return Finding(
            Verdict.CONTRADICTED,
            f"the drive keeps the flag in 0xC9 (decision 7's other reading; diagnostics are "
            f"ERROR either way: report it): {seen}",
        )
    return Finding(
        Verdict.CONTRADICTED,
        f"a code the manual does not list: {seen}; report it (diagnostics are ERROR)",
    )


__all__ = [
    "disarm",
    "lifeguard_off",
    "lifeguard_trip",
    "new_target",
    "position_stop",
    "setpoint_in_a_move",
    "standstill",
    "stop_and_restore",
]
