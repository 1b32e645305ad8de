"""The stepper's guided commissioning steps: each writes or moves, and runs only after the
operator's ``yes`` (``bridge_commission stepper``, the rows of
``stepper_bridge/commission.py``); the read-only checks are in commission_steps.py.

Each step checks first with the bridge's own checks (a ``CommandRejected``: nothing
written), moves with the device's methods and the bridge's goals (``motions``), follows
them through the polls as the action server does, and is judged by what the controller
reads back (stepper decision 23). Its stop goes out on every way out (the runner's
``finally``). No ROS here. "Stepper decision N" is reading N of docs/decisions/stepper.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from bridge_core.runtime.commission import Finding, Probe, Verdict
from bridge_core.runtime.goals import Motion, Outcome
from bridge_core.wire.errors import CommandRejected, NotConfirmed

from .commission_steps import the_device
from .device import StepperDevice
from .motions import HomeMotion, InterpolationMotion, MoveByMotion
from .registers import MOTORS, motor_register
from .snapshots import StepperSnapshot
from .units import JointScale, joint_scales

# Guided steps: how far, how fast, how long.
PAIR_TRIED = 2  # decision 19: the pair whose two readings differ (3 differs the same way)
LINE_END_UNITS = (2.0, 4.0)  # the line from (0, 0): 2 x 4 units (mm with a lead in mm)
LINE_RPM = 30  # the line's speed (40211)
HOME_MOTOR = 1
HOME_OFF_UNITS = 5.0  # decision 20: motor 1 first runs this far off home (a single run)
RUN_BEFORE_STOP_S = 0.5  # decision 23: motor 1 runs forward this long before its stop
MOTION_LIMIT_S = 120.0  # a motion not ended by then: stopped, could not tell
SETTLE_LIMIT_S = 10.0  # the motors must stand this long before a step starts
STAND_READ_PERIOD_S = 0.2


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
    try:  # both goals checked before the first write (a motor without a home input)
        lead = device.config.motors[HOME_MOTOR - 1].lead
        off_si = scales[HOME_MOTOR - 1].to_si(HOME_OFF_UNITS, lead)
        off = MoveByMotion(device, scales, HOME_MOTOR, HOME_OFF_UNITS, off_si, tolerance=tolerance)
        home = HomeMotion(device, scales, "home", [HOME_MOTOR], tolerance=tolerance)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused, nothing written: {err}")
    try:
        moved = follow(probe, device, off)
        if isinstance(moved, Finding):
            return moved
        if moved[0] is not Outcome.REACHED:
            return Finding(Verdict.UNCLEAR, f"the run off home ended {moved[0].name}: {moved[1]}")
        ran = follow(probe, device, home)
    except CommandRejected as err:
        return Finding(Verdict.NOT_RUN, f"refused: {err}")
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
