"""The stepper's commissioning steps: the read-only checks and guided steps that the rows
of ``stepper_bridge/commission.py`` name (``bridge_commission stepper``,
docs/commissioning.md).

They use the bridge's own device logic (``StepperDevice``, the goals of ``motions``), so
a step succeeds by the bridge's rule: what the controller reads back (stepper decision
23). No ROS here. "Stepper decision N" is reading N of docs/decisions/stepper.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

from bridge_core.runtime.commission import (
    Finding,
    Probe,
    Verdict,
    recommend_timeout_s,
    reply_times,
)
from bridge_core.runtime.goals import Motion, Outcome
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.errors import (
    CommandRejected,
    DeviceException,
    LinkError,
    NotConfirmed,
)
from bridge_core.wire.transport import SerialSettings

from .device import StepperDevice
from .motions import HomeMotion, InterpolationMotion, MoveByMotion
from .registers import (
    MAX_REGISTERS_PER_REQUEST,
    MOTORS,
    REPLY_DELAY_S,
    STEPPER_MAP,
    UNDEFINED_HOLDING,
    holding,
    motor_register,
    reply_timeout_floor_s,
)
from .snapshots import FAST_PLAN, StepperSnapshot
from .units import JointScale, joint_scales

# Decision 7: the reply times the check takes itself (the runner's are not given to it).
REPLY_PINGS = 10
# Decisions 7 and 21: the undefined rows between the poll's blocks (PLC numbers, inclusive)
# whose answer would let the coordinates, inputs, outputs and running flags be read in
# fewer requests.
POLL_GAPS = ((40118, 40123), (40137, 40147), (40160, 40167))
# Guided steps: how far, how fast, how long.
PAIR_TRIED = 2  # decision 19: the pair whose two readings differ (3 differs the same way)
PAIR_READING_TRIED = "type_rows"  # the hypothesis the line runs under (the page's check)
LINE_END_UNITS = (2.0, 4.0)  # the line from (0, 0): 2 x 4 units (mm with a lead in mm)
LINE_RPM = 30  # the line's speed (40211)
HOME_MOTOR = 1
HOME_OFF_UNITS = 5.0  # decision 20: motor 1 first runs this far off home (a single run)
RUN_BEFORE_STOP_S = 0.5  # decision 23: motor 1 runs forward this long before its stop
MOTION_LIMIT_S = 120.0  # a motion not ended by then: stopped, could not tell
SETTLE_LIMIT_S = 10.0  # the motors must stand this long before a step starts
STAND_READ_PERIOD_S = 0.2


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


# ---------------------------------------------------------------- guided steps
def _scales(probe: Probe) -> list[JointScale]:
    values = probe.values
    default = ["prismatic"] * MOTORS
    return joint_scales(
        values.get("joint_types", default),
        values.get("units_per_meter", [1000.0] * MOTORS),
        values.get("units_per_revolution", [0.0] * MOTORS),
    )


def _tolerance(probe: Probe) -> float:
    return float(probe.values.get("goal_tolerance", 0.01))


def _stands(probe: Probe, device: StepperDevice, motors: list[int]) -> str | None:
    """None once ``motors`` stand (running flags 0), else why the step does not start."""
    deadline = time.monotonic() + SETTLE_LIMIT_S
    names = [motor_register(m, "running") for m in motors]
    while any(device.read_named(*names).values()):
        if time.monotonic() > deadline or probe.wait(STAND_READ_PERIOD_S):
            return f"motors {'+'.join(map(str, motors))} run: stop them first"
    return None


def follow(
    probe: Probe, device: StepperDevice, motion: Motion[StepperSnapshot]
) -> tuple[Outcome, str] | Finding:
    """A goal's motion started and followed through the polls, as the bridge's action
    server follows it: its verdict, or a Finding when the operator stopped it or it took
    longer than ``MOTION_LIMIT_S``."""
    motion.start()
    started = time.monotonic()
    period = 1.0 / float(probe.values.get("poll_rate_hz", 3.0))
    while True:
        if probe.wait(period):
            return Finding(Verdict.UNCLEAR, "stopped by the operator before the motion ended")
        if time.monotonic() - started > MOTION_LIMIT_S:
            return Finding(Verdict.UNCLEAR, f"the motion did not end within {MOTION_LIMIT_S:g} s")
        verdict = motion.judge(device.poll(), time.monotonic() - started)
        if verdict is not None:
            return verdict.outcome, verdict.message


def _stop(probe: Probe, stop: Callable[[], str]) -> str:
    try:
        return stop()
    except NotConfirmed as err:
        return f"not confirmed: {err}: stop the motors at the controller (its e-stop)"


def stop_interpolation(probe: Probe) -> str:
    """The line step's stop: the arc and line stops, then the stop coil of every motor a
    pair may move, read back (stepper decision 23)."""
    return _stop(probe, the_device(probe).stop_interpolation)


def stop_motor_1(probe: Probe) -> str:
    """The homing and stop steps' stop: motor 1's stop coil, its running flag read back."""
    return _stop(probe, lambda: the_device(probe).stop_motors([HOME_MOTOR]))


def pair_reading(probe: Probe) -> Finding:
    """Decision 19: coordinates zeroed (coil 00044, read back), then a pair-2 line from
    (0, 0) run as the bridge's ``line_move`` goal under the type rows' reading: a motor
    outside motors 1+3 that moves stops it (HALTED: the point rows' reading)."""
    device = the_device(probe)
    if (busy := _stands(probe, device, list(range(1, MOTORS + 1)))) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    try:
        zeroed = device.zero_coordinates(list(range(1, 4)))
        if any(abs(v) > _tolerance(probe) for v in zeroed.values()):
            return Finding(
                Verdict.UNCLEAR,
                f"the zero coordinates coil (00044) left {zeroed}: nothing run",
            )

        def begin() -> object:
            return device.line_move(PAIR_TRIED, (0.0, 0.0), LINE_END_UNITS, LINE_RPM, confirm=False)

        motion = InterpolationMotion(
            device,
            _scales(probe),
            PAIR_TRIED,
            LINE_END_UNITS,
            f"line of pair {PAIR_TRIED}",
            begin,
            tolerance=_tolerance(probe),
        )
        ran = follow(probe, device, motion)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused, nothing written: {err}")
    if isinstance(ran, Finding):
        return ran
    outcome, message = ran
    if outcome is Outcome.REACHED:
        return Finding(
            Verdict.CONFIRMED,
            f"{message}: the controller follows the type rows (pair 2 = motors 1+3)",
            {"interpolation_pair_reading": "type_rows"},
        )
    if outcome is Outcome.HALTED:
        return Finding(
            Verdict.CONTRADICTED,
            f"{message}: the controller follows the point rows (pair 2 = motors 2+3); run "
            "the step again with the recommended reading to see it end",
            {"interpolation_pair_reading": "point_rows"},
        )
    return Finding(Verdict.UNCLEAR, f"{outcome.name}: {message}")


def zero_at_home(probe: Probe) -> Finding:
    """Decision 20: motor 1 runs ``HOME_OFF_UNITS`` off home (a single run, as
    ``move_by``), then homes (its home coil, as the ``home`` goal, judged by the home
    input); the coordinate read there says whether the controller zeroes at home."""
    device = the_device(probe)
    if (busy := _stands(probe, device, [HOME_MOTOR])) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    scales, tolerance = _scales(probe), _tolerance(probe)
    try:
        off = MoveByMotion(
            device, scales, HOME_MOTOR, HOME_OFF_UNITS, HOME_OFF_UNITS, tolerance=tolerance
        )
        moved = follow(probe, device, off)
        if isinstance(moved, Finding):
            return moved
        if moved[0] is not Outcome.REACHED:
            return Finding(Verdict.UNCLEAR, f"the run off home ended {moved[0].name}: {moved[1]}")
        home = HomeMotion(device, scales, "home", [HOME_MOTOR], tolerance=tolerance)
        ran = follow(probe, device, home)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused, nothing written: {err}")
    if isinstance(ran, Finding):
        return ran
    outcome, message = ran
    config = device.config.motors[HOME_MOTOR - 1]
    wiring = (
        "home is the negative limit input, as the manual wires it"
        if config.home_input == config.negative_limit_input
        else f"home IN{config.home_input} is not the negative limit IN{config.negative_limit_input}"
    )
    if outcome is not Outcome.REACHED:
        return Finding(
            Verdict.UNCLEAR,
            f"{outcome.name}: {message}; {wiring}: check the input assignment "
            f"(~/motor_{HOME_MOTOR}/set_limit_inputs)",
        )
    at = device.coordinates([HOME_MOTOR])[HOME_MOTOR]
    if abs(at) <= tolerance:
        return Finding(
            Verdict.CONFIRMED,
            f"{message}; {wiring}; the controller zeroes the coordinate at home: leave "
            "zero_after_home false",
            {"zero_after_home": False},
        )
    return Finding(
        Verdict.CONTRADICTED,
        f"{message}; {wiring}; the controller leaves the coordinate at {at:g} at home: "
        "zero_after_home true zeroes it after each homing (every motor's coordinate, coil "
        "00044); leave it false if your sequences do not need 0 at home",
        {"zero_after_home": True},
    )


def stop_and_start(probe: Probe) -> Finding:
    """Decision 23: motor 1 forward (its coil, the start read back as ``~/motor_1/forward``
    reads it), ``RUN_BEFORE_STOP_S`` running, then its stop coil read back as
    ``~/motor_1/stop`` reads it: both within the bridge's 0.5 s."""
    device = the_device(probe)
    if (busy := _stands(probe, device, [HOME_MOTOR])) is not None:
        return Finding(Verdict.NOT_RUN, busy)
    try:
        started = device.motor_action(HOME_MOTOR, "forward")
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused, nothing written: {err}")
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"the start: {err}: the flag comes later than START_CONFIRM_S (or the motor did "
            "not run: speed 0?); tell us the time you see",
        )
    if probe.wait(RUN_BEFORE_STOP_S):
        return Finding(Verdict.UNCLEAR, f"stopped by the operator before the stop ({started})")
    try:
        stopped = device.stop_motors([HOME_MOTOR])
    except NotConfirmed as err:
        return Finding(
            Verdict.CONTRADICTED,
            f"the stop: {err}: the controller decelerates (or clears the flag) slower than "
            "STOP_CONFIRM_S, or ignores its stop coil: stop it at the controller if it runs, "
            "and tell us the time it takes to stand",
        )
    return Finding(Verdict.CONFIRMED, f"start: {started}; stop: {stopped}")
