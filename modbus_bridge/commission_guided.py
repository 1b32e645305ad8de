"""modbus_bridge's guided commissioning steps (``bridge_commission modbus``, after the
operator's ``yes``): the file's start trigger and its stop, and its watchdog, each judged
by what the device reads back.

They use the bridge's own ``DescribedDevice``: a trigger is checked as the bridge checks
it (``CommandRejected``: nothing written, the step is not run), written and read back
(decision 19: ``NotConfirmed`` is what the device showed), and a ``require_keepalive``
file's keepalive is armed and fed by the bridge's ``KeepaliveFeeder`` while a step runs
(the bridge refuses motion without it). The stop every step sends on its way out is the
start's group's stop trigger (the bridge's exit stop, decision 12). Motion is judged from
the joints' velocity registers (SI, as joint_states). No ROS here.
"""

from __future__ import annotations

import time

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.wire.errors import CommandRejected, NotConfirmed

from .commission_file import Target, target
from .description_joints import RUNNING_MIN_SI

# How long the steps may take, and how often they read.
RUN_LIMIT_S = 3.0  # a start must show motion within this, else "could not tell"
READ_PERIOD_S = 0.05  # the joints' velocities read this often while a step runs
FED_PERIODS = 1.0  # the watchdog step feeds the running device this many watchdog times
STOP_GRACE_S = 2.0  # after the watchdog time, the device has this long to slow down
SLOWED_SHARE = 0.8  # a device stops (it slows on its ramp) once its speed reads this share
HELD_SHARE = 0.95  # of its top speed or less; it runs on when it still reads this share
SILENCE_OVER = 1.2  # mode any_frame: no frame for this many watchdog times, then reads


def start_and_stop(found: Target) -> tuple[str, str] | None:
    """The file's first ``starts_motion`` trigger and the stop trigger of its group."""
    triggers = found.device.commands.triggers
    stops = found.device.exit_stops()
    for trigger in triggers:
        if trigger.starts_motion and trigger.group in stops:
            return trigger.name, stops[trigger.group]
    return None


def _feed(found: Target) -> None:
    """The bridge's keepalive, armed and fed when due (as the node's thread does)."""
    feeder = found.described.keepalive
    if feeder is None:
        return
    due = feeder.next_feed()
    if due is not None and due <= time.monotonic():
        feeder.due()


def speed(found: Target) -> float | None:
    """The largest joint speed read now (SI), or None when no joint has a velocity."""
    sources = [j.velocity for j in found.device.joints if j.velocity is not None]
    if not sources:
        return None
    values = found.described.read([s.register for s in sources])
    return max(abs(float(values[s.register]) * s.to_si) for s in sources)


def _start(probe: Probe, found: Target, name: str) -> Finding | str:
    """Arm the keepalive, then the start trigger, read back; a Finding if it failed."""
    try:
        _feed(found)
        return found.described.trigger(name)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused, nothing written: {err}")
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"~/{name}: not confirmed: {err}: the device does not hold the start it was "
            "sent (it clears its command word, or ignored it); every command on it reads "
            "not confirmed",
        )


def _until_moving(probe: Probe, found: Target) -> tuple[float | None, bool]:
    """Reads (feeding the keepalive) until a joint moves or ``RUN_LIMIT_S``: the speed
    read last, and whether the operator stopped it."""
    deadline = time.monotonic() + RUN_LIMIT_S
    seen = speed(found)
    while seen is not None and seen <= RUNNING_MIN_SI and time.monotonic() < deadline:
        if probe.wait(READ_PERIOD_S):
            return seen, True
        _feed(found)
        seen = speed(found)
    return seen, False


def _no_start(found: Target) -> Finding | None:
    if start_and_stop(found) is None:
        return Finding(Verdict.NOT_RUN, "the file has no starts_motion trigger with a stop trigger")
    return None


def run_forward(probe: Probe) -> Finding:
    """VFD decision 16: the start trigger, read back, then the joints read until they
    move (the stop follows: ``stop``)."""
    found = target(probe)
    if (missing := _no_start(found)) is not None:
        return missing
    name, stop_name = start_and_stop(found) or ("", "")
    started = _start(probe, found, name)
    if isinstance(started, Finding):
        return started
    seen, stopped = _until_moving(probe, found)
    if stopped:
        return Finding(Verdict.UNCLEAR, f"stopped by the operator ({started})")
    if seen is None:
        return Finding(
            Verdict.UNCLEAR,
            f"{started}: read back; the file has no joint velocity to see the motion: watch "
            "the device",
        )
    if seen <= RUNNING_MIN_SI:
        return Finding(
            Verdict.UNCLEAR,
            f"{started}: read back, but no joint moved within {RUN_LIMIT_S:g} s: the "
            "setpoint may be 0 (set one first), the run source is not communication, or "
            "the start value is not your manual's",
        )
    return Finding(
        Verdict.CONFIRMED,
        f"{started}: read back, and the joints turn ({seen:.3g} SI/s); ~/{stop_name} follows",
    )


def read_back(probe: Probe) -> Finding:
    """Decision 19: the start trigger and at once its stop, each read back."""
    found = target(probe)
    if (missing := _no_start(found)) is not None:
        return missing
    name, stop_name = start_and_stop(found) or ("", "")
    started = _start(probe, found, name)
    if isinstance(started, Finding):
        return started
    try:
        stopped = found.described.trigger(stop_name)
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"{started}: read back; ~/{stop_name}: not confirmed: {err}: the device clears "
            "its command word (or ignored the stop): stop it at the panel",
        )
    return Finding(Verdict.CONFIRMED, f"{started}: read back; {stopped}: read back")


def _watched(probe: Probe, found: Target, limit_s: float, top: float, since: float) -> Finding:
    """After the feeds (or frames) stopped at ``since``: reads until the speed is at most
    ``SLOWED_SHARE`` of ``top`` (stopping: confirmed) or ``limit_s`` passed: still at
    ``HELD_SHARE`` of ``top`` or more, contradicted; in between, a drive on a long ramp
    could not tell."""
    while True:  # at least one read, however late
        seen = speed(found) or 0.0
        waited = time.monotonic() - since
        if seen <= top * SLOWED_SHARE:
            return Finding(
                Verdict.CONFIRMED,
                f"the device slowed to {seen:.3g} SI/s (from {top:.3g}) {waited:.2f} s "
                "after its last feed: its watchdog stops it",
            )
        if waited >= limit_s:
            break
        if probe.wait(READ_PERIOD_S):
            return Finding(Verdict.UNCLEAR, "stopped by the operator while the feeds paused")
    if seen < top * HELD_SHARE:
        return Finding(
            Verdict.UNCLEAR,
            f"the device slows ({seen:.3g} SI/s, was {top:.3g}) {limit_s:g} s after its last "
            "feed, but not by a fifth: a long ramp, or it slows for another reason; watch it",
        )
    return Finding(
        Verdict.CONTRADICTED,
        f"the device still turns ({seen:.3g} SI/s, was {top:.3g}) {limit_s:g} s after its "
        "last feed: its watchdog is off, or watches another register (or, mode any_frame, "
        "only writes reset it); set it on the device and point the file's `keepalive` at "
        "what your manual names",
    )


def _running(probe: Probe, found: Target, fed_s: float) -> tuple[Finding | None, float]:
    """Start, see it move, then read it (feeding the keepalive) for ``fed_s``: (a Finding
    if that failed, the top speed read)."""
    name, _ = start_and_stop(found) or ("", "")
    started = _start(probe, found, name)
    if isinstance(started, Finding):  # the start's own verdict is the read-back step's
        if started.verdict is Verdict.CONTRADICTED:
            started = Finding(Verdict.UNCLEAR, f"could not start: {started.seen}")
        return started, 0.0
    seen, stopped = _until_moving(probe, found)
    if stopped:
        return Finding(Verdict.UNCLEAR, f"stopped by the operator ({started})"), 0.0
    if seen is None or seen <= RUNNING_MIN_SI:
        return Finding(
            Verdict.UNCLEAR, f"{started}, but no joint velocity showed motion: nothing to stop"
        ), 0.0
    top = seen
    fed_until = time.monotonic() + fed_s
    while time.monotonic() < fed_until:
        if probe.wait(READ_PERIOD_S):
            return Finding(Verdict.UNCLEAR, "stopped by the operator while fed"), top
        _feed(found)
        top = max(top, speed(found) or 0.0)
    return None, top


def watchdog(probe: Probe) -> Finding:
    """Decisions 13, 16: a register keepalive fed while the device runs (``FED_PERIODS``
    watchdog times), then not fed: the device must slow within its watchdog time and
    ``STOP_GRACE_S``."""
    found = target(probe)
    spec, feeder = found.device.keepalive, found.described.keepalive
    if spec is None or feeder is None:
        return Finding(Verdict.NOT_RUN, "the file names no keepalive register")
    if (missing := _no_start(found)) is not None:
        return missing
    _feed(found)  # armed: its watchdog time (a period_from register read) is known
    period = feeder.period_s
    if period is None:
        return Finding(Verdict.UNCLEAR, f"{spec.period_register} reads 0: the watchdog is off")
    failed, top = _running(probe, found, FED_PERIODS * period)
    if failed is not None:
        return failed
    probe.say(f"  fed while it ran; feeds paused now (watchdog time {period:g} s)")
    last_feed = feeder.last_feed
    return _watched(probe, found, period + STOP_GRACE_S, top, last_feed)


def frame_watchdog(probe: Probe) -> Finding:
    """Decision 22: a watchdog any frame resets: the device runs while read
    (``FED_PERIODS`` watchdog times), then gets no frame for ``SILENCE_OVER`` times its
    watchdog time; then it must read slowing within the watchdog time and
    ``STOP_GRACE_S``."""
    found = target(probe)
    period = found.device.frame_watchdog_s
    if period is None:
        return Finding(Verdict.NOT_RUN, "the file's keepalive is not mode any_frame")
    if (missing := _no_start(found)) is not None:
        return missing
    failed, top = _running(probe, found, FED_PERIODS * period)
    if failed is not None:
        return failed
    silent_from = time.monotonic()
    probe.say(f"  no frame for {SILENCE_OVER * period:g} s now (watchdog time {period:g} s)")
    if probe.wait(SILENCE_OVER * period):  # silence: no frame at all
        return Finding(Verdict.UNCLEAR, "stopped by the operator during the silence")
    return _watched(probe, found, SILENCE_OVER * period + STOP_GRACE_S, top, silent_from)


def stop(probe: Probe) -> str:
    """The stop of every step: the start's group's stop trigger (the bridge's exit stop),
    read back; sent however the step ended."""
    found = target(probe)
    pair = start_and_stop(found)
    if pair is None:
        return "the file has no stop trigger: nothing to send"
    try:
        return found.described.trigger(pair[1])
    except NotConfirmed as err:
        return f"~/{pair[1]}: not confirmed: {err}: stop it at the panel"
    except CommandRejected as err:  # not expected: a stop takes no check that refuses
        return f"~/{pair[1]} refused: {err}: stop it at the panel"


__all__ = [
    "frame_watchdog",
    "read_back",
    "run_forward",
    "speed",
    "stop",
    "watchdog",
]
