"""The stepper's action goals (docs/actions.md): each motion a goal starts, followed
through the polls and judged from the controller's running flags, coordinates and inputs.

``MoveByMotion`` (``~/motor_<n>/move_by``), ``HomeMotion`` (``~/motor_<n>/home``,
``~/home_all``), ``CoilMotion`` (``~/return_to_zero``), ``InterpolationMotion``
(``~/line_move``, ``~/arc_move``). No ROS here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from bridge_core.runtime.goals import Motion, Outcome, Verdict, within
from bridge_core.wire.errors import CommandRejected

from .device import StepperDevice
from .interpolation import InterpolationRun, wrong_pair_text
from .registers import INPUTS, motor_register
from .replies import check_motor, flags_text
from .snapshots import StepperSnapshot
from .units import JointScale


class StepperMotion(Motion[StepperSnapshot]):
    """A stepper motion followed through the polls (docs/actions.md).

    Over when the running flags of its motors (40168+) are off for ``idle_polls_to_end``
    polls in a row; then REACHED if every motor of one of ``targets`` (controller units;
    several: the manual's two readings of an interpolation pair) is within ``tolerance``,
    LIMIT if an e-stop this bridge sent or a limit input of a stopped motor explains the
    shortfall, STOPPED otherwise. ``stop`` sends each motor's stop coil (``stop_coils``)
    or the interpolation stops.
    """

    def __init__(
        self,
        device: StepperDevice,
        scales: Sequence[JointScale],
        motors: Sequence[int],
        what: str,
        *,
        tolerance: float,
        targets: Sequence[dict[int, float]] = (),
        interpolation: bool = False,
        idle_polls_to_end: int = 1,
    ) -> None:
        super().__init__()
        for motor in motors:
            check_motor(motor)
        self.device = device
        self.scales = tuple(scales)
        self.motors = tuple(motors)
        self.axes = frozenset(self.motors)
        self.what = what
        self.tolerance = tolerance
        self.targets = [dict(t) for t in targets]
        self.interpolation = interpolation
        self.idle_polls_to_end = idle_polls_to_end
        self.estops_at_start = device.estops
        # What ``begin`` wrote (and read back), for a verdict that saw no motion.
        self.wrote = ""

    def start(self) -> None:
        self.estops_at_start = self.device.estops
        self.begin()

    def begin(self) -> None:
        """The motion's writes (each kind's own)."""
        raise NotImplementedError

    def stop(self) -> str:
        """The stop, confirmed by the running flags read back (``NotConfirmed`` when they
        do not show it): what was written and read."""
        if self.interpolation:
            return self.device.stop_interpolation()
        return self.device.stop_motors(self.motors)

    def running(self, snapshot: StepperSnapshot) -> bool:
        return any(snapshot.running[m - 1] for m in self.motors)

    def judge(self, snapshot: StepperSnapshot, since_start_s: float = math.inf) -> Verdict | None:
        if (fault := self.fault(snapshot)) is not None:
            return fault  # at once, running or not: never held back for the idle polls
        verdict = super().judge(snapshot, since_start_s)
        if verdict is not None and self.seen_running and self.idle_polls < self.idle_polls_to_end:
            return None  # home_all: the next motor of the order may not have begun yet
        if verdict is not None and not self.seen_running and verdict.outcome is not Outcome.REACHED:
            # The device never showed the motion: say what was sent and what was read.
            return Verdict(
                verdict.outcome,
                f"{verdict.message}; not confirmed: {self.wrote or 'its start was sent'}; "
                f"read {flags_text(self.motors, 0)} at every poll since",
                verdict.fault_code,
                verdict.fault_text,
            )
        return verdict

    def ended(self, snapshot: StepperSnapshot) -> Verdict:
        coordinates = snapshot.coordinates
        for target in self.targets:
            if all(within(coordinates[m - 1], to, self.tolerance) for m, to in target.items()):
                return Verdict(Outcome.REACHED, f"{self.what}: done")
        if not self.targets:
            return Verdict(Outcome.REACHED, f"{self.what}: done")
        if self.device.estops > self.estops_at_start:
            return Verdict(Outcome.LIMIT, f"{self.what}: ended by the e-stop (~/emergency_stop)")
        for motor in self.motors:
            if (switch := _limit_on(snapshot, motor)) is not None:
                return Verdict(Outcome.LIMIT, f"{self.what}: motor {motor} stopped at its {switch}")
        where = ", ".join(f"motor {m} at {coordinates[m - 1]:g}" for m in self.motors)
        return Verdict(Outcome.STOPPED, f"{self.what}: stopped short of the target ({where} units)")

    def positions(self, snapshot: StepperSnapshot) -> list[float]:
        leads = [motor.lead for motor in snapshot.config.motors]
        return [
            scale.to_si(units, lead)
            for scale, units, lead in zip(self.scales, snapshot.coordinates, leads, strict=True)
        ]

    def feedback(self, snapshot: StepperSnapshot) -> dict[str, object]:
        return {"positions": self.positions(snapshot), "running": list(snapshot.running)}

    def result(self, snapshot: StepperSnapshot | None) -> dict[str, object]:
        return {"positions": [] if snapshot is None else self.positions(snapshot)}


class MoveByMotion(StepperMotion):
    """``~/motor_<n>/move_by``: target = the coordinate read at the start + distance."""

    def __init__(
        self,
        device: StepperDevice,
        scales: Sequence[JointScale],
        motor: int,
        distance_units: float,
        distance_si: float,
        *,
        tolerance: float,
    ) -> None:
        super().__init__(
            device, scales, (motor,), f"motor {motor} move_by {distance_si:g}", tolerance=tolerance
        )
        device.check_move_by(motor, distance_units)
        self.motor = motor
        self.distance = distance_units

    def begin(self) -> None:
        name = motor_register(self.motor, "coordinate")
        here = float(self.device.read_named(name)[name])
        self.targets = [{self.motor: here + self.distance}]
        self.wrote = self.device.move_by(self.motor, self.distance, confirm=False)

    def feedback(self, snapshot: StepperSnapshot) -> dict[str, object]:
        fields = super().feedback(snapshot)
        positions = self.positions(snapshot)
        lead = snapshot.config.motors[self.motor - 1].lead
        target = self.scales[self.motor - 1].to_si(self.targets[0][self.motor], lead)
        fields["distance_to_go"] = target - positions[self.motor - 1]
        return fields


class CoilMotion(StepperMotion):
    """Homing (one motor, or all in the homing order) and return to zero: one coil, and
    the coordinates of its motors end at 0."""

    def __init__(
        self,
        device: StepperDevice,
        scales: Sequence[JointScale],
        command: str,
        motors: Sequence[int],
        *,
        tolerance: float,
        homed: Sequence[int] | None = None,
    ) -> None:
        homed = motors if homed is None else homed
        what = f"motor {motors[0]} home" if command == "home" else command
        super().__init__(
            device,
            scales,
            motors,
            what,
            tolerance=tolerance,
            targets=[dict.fromkeys(homed, 0.0)],
            idle_polls_to_end=2 if command == "home_all" else 1,
        )
        self.command = command

    def begin(self) -> None:
        if self.command == "home":
            self.wrote = self.device.motor_action(self.motors[0], "home", confirm=False)
        else:
            self.wrote = self.device.system_command(self.command, confirm=False)


class HomeMotion(CoilMotion):
    """Homing one motor (its home coil) or all in the homing order (00046), judged by the
    home input (stepper decision 20).

    Over when its motors stand (running flags off, two idle polls for home_all); REACHED
    when each homed motor's home input (40083+) is on, the message giving the coordinate
    there. The manual stops homing at the home switch ("直到碰到机械零点信号才停止") and
    wires home to the reverse limit input ("一般情况下反限位与原点设定同一个触发信号输入口"),
    but never says that the controller zeroes the coordinate there (it has a separate
    "坐标清零" coil, 00044): the coordinate is reported as read. ``zero`` (the node's
    ``zero_after_home``) sends that coil after a REACHED homing and returns the homed
    motors' coordinates read back (or raises, or says why it failed); any of them off 0
    ends the goal FAULT.
    """

    # The result reports the coordinates: a poll may have read them before the motor
    # reached the switch and its running flag after (a second idle poll confirms).
    confirm_reached = True

    def __init__(
        self,
        device: StepperDevice,
        scales: Sequence[JointScale],
        command: str,
        motors: Sequence[int],
        *,
        tolerance: float,
        homed: Sequence[int] | None = None,
        zero: Callable[[Sequence[int]], tuple[bool, str, dict[int, float] | None]] | None = None,
    ) -> None:
        super().__init__(device, scales, command, motors, tolerance=tolerance, homed=homed)
        self.homed = tuple(motors if homed is None else homed)
        config = device.config  # refused until the configuration was read
        for motor in self.homed:
            number = config.motors[motor - 1].home_input
            if not 1 <= number <= INPUTS:
                raise CommandRejected(
                    f"motor {motor} has no home input (40083+ reads {number}): homing would "
                    "run in reverse until a stop (直到碰到机械零点信号才停止); set one with "
                    f"~/motor_{motor}/set_limit_inputs"
                )
        self.zero = zero

    def ended(self, snapshot: StepperSnapshot) -> Verdict:
        coordinates = snapshot.coordinates
        if self.device.estops > self.estops_at_start:
            return Verdict(Outcome.LIMIT, f"{self.what}: ended by the e-stop (~/emergency_stop)")
        at_home: list[str] = []
        for motor in self.homed:
            number = snapshot.config.motors[motor - 1].home_input
            if not (1 <= number <= len(snapshot.inputs) and snapshot.inputs[number - 1]):
                here = f"coordinate {coordinates[motor - 1]:g}"
                if (switch := _limit_on(snapshot, motor)) is not None:
                    return Verdict(
                        Outcome.LIMIT,
                        f"{self.what}: motor {motor} stopped at its {switch}, its home input "
                        f"IN{number} off ({here})",
                    )
                return Verdict(
                    Outcome.STOPPED,
                    f"{self.what}: motor {motor} stopped with its home input IN{number} off "
                    f"({here})",
                )
            at_home.append(f"motor {motor} IN{number} on at coordinate {coordinates[motor - 1]:g}")
        return Verdict(Outcome.REACHED, f"{self.what}: done, home input on ({', '.join(at_home)})")

    def judge(self, snapshot: StepperSnapshot, since_start_s: float = math.inf) -> Verdict | None:
        verdict = super().judge(snapshot, since_start_s)
        if verdict is None or verdict.outcome is not Outcome.REACHED:
            return verdict
        if self.zero is None:
            return Verdict(
                verdict.outcome, f"{verdict.message}; coordinates not zeroed (zero_after_home)"
            )
        ok, message, read_back = self.zero(self.homed)
        if not ok or read_back is None:
            return Verdict(Outcome.FAULT, f"{verdict.message}; zeroing failed: {message}")
        off = [
            f"motor {m} reads {v:g}"
            for m, v in read_back.items()
            if not within(v, 0.0, self.tolerance)
        ]
        if off:
            return Verdict(
                Outcome.FAULT,
                f"{verdict.message}; after the zero coordinates coil (00044) {', '.join(off)}",
            )
        return Verdict(
            verdict.outcome,
            f"{verdict.message}; coordinates zeroed (coil 00044: every motor's coordinate)",
        )


class InterpolationMotion(StepperMotion):
    """Line / arc interpolation: ``begin`` is the device's line_move / arc_move.

    The target is the end point on the pair's motors by the configured reading. The
    coordinates of every motor either reading names (1-3 for pairs 2 and 3) are read
    before the start: a motor outside the configured pair that moves away from its
    coordinate (the controller follows the other reading) ends the goal at once, HALTED
    (the interpolation stops are sent), naming the motors that moved; every other ending
    says which motors moved (stepper decision 19).
    """

    def __init__(
        self,
        device: StepperDevice,
        scales: Sequence[JointScale],
        pair: int,
        end: tuple[float, float],
        what: str,
        begin: Callable[[], object],
        *,
        tolerance: float,
    ) -> None:
        a, b = device.pair_axes(pair)
        motors = device.pair_motors(pair)
        super().__init__(
            device,
            scales,
            motors,
            what,
            tolerance=tolerance,
            targets=[{a: end[0], b: end[1]}],
            interpolation=True,
            idle_polls_to_end=2,  # the approach to the start, then the line / arc
        )
        self.run = InterpolationRun("", (), 0)  # the device's, once started
        self._begin = begin

    def begin(self) -> None:
        self.wrote = str(self._begin() or "")
        # The device read every motor's coordinate just before the start coil.
        run = self.device.interpolation_run
        self.run = run if run is not None else InterpolationRun("", (), 0)

    def fault(self, snapshot: StepperSnapshot) -> Verdict | None:
        wrong = self.run.wrong_motors(snapshot.coordinates)
        if not wrong:
            return None
        why = wrong_pair_text(self.run, wrong, snapshot.coordinates, self.device.pair_reading)
        return Verdict(Outcome.HALTED, f"{self.what}: stopped, {why}")

    def ended(self, snapshot: StepperSnapshot) -> Verdict:
        verdict = super().ended(snapshot)
        moved = "+".join(map(str, self.run.moved(snapshot.coordinates))) or "none"
        return Verdict(
            verdict.outcome, f"{verdict.message}; motors moved: {moved} (coordinates read back)"
        )


def _limit_on(snapshot: StepperSnapshot, motor: int) -> str | None:
    """The motor's limit switch whose input is on, if any ("positive limit switch (IN3)")."""
    config = snapshot.config.motors[motor - 1]
    for name, number in (
        ("positive limit switch", config.positive_limit_input),
        ("negative limit switch", config.negative_limit_input),
    ):
        if 1 <= number <= len(snapshot.inputs) and snapshot.inputs[number - 1]:
            return f"{name} (IN{number})"
    return None
