"""The stepper's ``~/joint_commands`` (docs/ros2_control.md). No ROS here.

Joints ``motor_1 .. motor_5`` (the names of ``joint_states``, with ``joint_prefix``):

- **velocity** (rad/s or m/s): converted to motor rpm with the motor's own ``JointScale``
  (controller units per SI unit, as ``joint_states``) and its lead (controller units per
  motor revolution): rpm = v x units per SI / lead x 60, then offered to the motor's **jog
  guard** (``StepperDevice.jogs``): the same stream as ``~/motor_<n>/jog``, with its rate,
  deadman, 0 = stop coil and lock after a stop service or the e-stop;
- **position** (rad or m): a target coordinate in controller units (``JointScale.to_units``,
  the conversion ``joint_states`` uses backwards), rounded to the coordinate's step
  (0.01 unit). The controller has only relative single runs (40009+, coil "single run"), so
  a target is sent when the motor stands: its running flag (40168+) and coordinate
  (40108+) are read at command priority (``observe``, before the jogs' lock is taken:
  a stop service waits only for the writes), then the difference is written as the
  direction and the run distance (both every time, as ``move_by``) and the single-run
  coil starts it, at the motor's configured speed (40006+). While the motor still runs the stream's
  previous target, a newer one waits (``Deferred``: nothing written, the newest tried at
  the next pass); a motor running anything else (a jog, a service, a goal) refuses it. A
  target within one step of the coordinate writes nothing.

Limits: a target must be a coordinate the controller can hold (int32 x 0.01 unit), a
velocity a speed the speed register holds (0-65535 rpm, whole rpm). A position stream has
the jog stream's deadman (``command_timeout_s``: the motor's stop coil) and rate
(``command_rate_hz``); it follows the jog guard, so a stop service, the e-stop, homing or
a goal that takes the motor over takes the position stream over too.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from bridge_core.runtime.checks import check_converted
from bridge_core.runtime.joint_commands import CommandJoint, CommandStream, Gate, Offer
from bridge_core.runtime.stream_guard import Deferred, StreamGuard
from bridge_core.wire.errors import CommandRejected

from .device import StepperDevice
from .jog import SPEED_MAX_RPM
from .registers import (
    DISTANCE_SCALE,
    I32_SCALED_MAX,
    I32_SCALED_MIN,
    MOTORS,
    motor_register,
)
from .units import JointScale

SECONDS_PER_MINUTE = 60.0
# The smallest run the controller takes: one step of its distance registers (0.01 unit).
STEP_UNITS = 1.0 / DISTANCE_SCALE


class MotorTargets:
    """The position streams of the five motors (controller units), behind one guard that
    follows the jog guard (one lock, the jogs' takeovers)."""

    def __init__(
        self, device: StepperDevice, *, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.device = device
        self.guard: StreamGuard[int] = StreamGuard(
            range(1, MOTORS + 1),
            self._send,
            self._stop,
            timeout_s=device.jogs.timeout_s,
            stop_when_idle=False,
            zero_stops=False,
            clock=clock,
        )
        self.guard.follow(device.jogs)
        device.streams.append(self.guard)  # a reconnect forgets what it sent
        # motor -> (running, coordinate or None): read by ``observe`` for the next send.
        self._seen: dict[int, tuple[bool, float | None]] = {}

    def observe(self, motor: int, target: float) -> float:
        """The writer's ``convert``: read the motor's running flag, and its coordinate when
        it stands, before the guard's lock is taken (the lock is the jogs' too, which a
        stop service takes: it waits for the writes of a target, not for these reads).
        Only a stop can come between these reads and the writes, and a stop locks the
        stream, so a stale reading is never acted on. A repeat of the target in force
        reads nothing (the guard writes nothing for it; should it send after all, it
        reads then), nor does a target the guard's lock refuses."""
        self._seen.pop(motor, None)
        stream = self.guard[motor]
        if stream.active and not stream.stop_pending and stream.value == target:
            return target
        if stream.locked and not stream.settled:
            # Refused by the guard's lock: no reads on the line for it (a
            # controller holding a target the stop cut short starved the polls).
            return target
        running = self._read(motor, "running")
        coordinate = None if running else self._read(motor, "coordinate")
        self._seen[motor] = (bool(running), coordinate)
        return target

    def _read(self, motor: int, field: str) -> float:
        name = motor_register(motor, field)
        return float(self.device.read_named(name)[name])

    def _send(self, motor: int, target: float, previous: float | None) -> None:
        """Run the motor from where it stands to ``target`` (controller units)."""
        seen = self._seen.pop(motor) if motor in self._seen else self._observed(motor)
        running, coordinate = seen
        if running:
            if previous is None:
                raise CommandRejected(
                    f"motor {motor} is running, not from joint_commands: stop it (or let it "
                    "end) before position commands"
                )
            raise Deferred  # still on the way to the stream's previous target
        assert coordinate is not None
        distance = on_step(target - coordinate)
        if abs(distance) < STEP_UNITS:
            return  # there already
        # Direction and run distance are written every time, as move_by does: the values
        # the bridge read may have been changed at the controller (its touch panel) since,
        # and a cached direction would send the motor the wrong way (stepper decision 22).
        self.device.move_by(motor, distance, confirm=False)

    def _observed(self, motor: int) -> tuple[bool, float | None]:
        """Read now (a send without ``observe`` first: tests, or a caller of the guard)."""
        self.observe(motor, 0.0)
        return self._seen.pop(motor)

    def _stop(self, motor: int) -> None:
        """The motor's stop coil, at stop priority, its running flag read back (as a jog's
        stop: ``StepperDevice.stream_stop``)."""
        self.device.stream_stop(motor)


def on_step(units: float) -> float:
    """``units`` on the step of the controller's distance registers (0.01 unit)."""
    return round(units * DISTANCE_SCALE) / DISTANCE_SCALE


def to_target(scale: JointScale, lead: float, si: float) -> float:
    """A position target (m or rad) in controller units, on the coordinate's step; refused
    outside the coordinate register's range."""
    units = check_converted(
        f"target {si:g} in controller units",
        scale.to_units(si, lead),
        I32_SCALED_MIN,
        I32_SCALED_MAX,
    )
    return on_step(units)


def to_rpm(device: StepperDevice, motor: int, scale: JointScale, lead: float, si: float) -> float:
    """A joint velocity (m/s or rad/s) as the motor's jog rpm (checked and rounded by the
    jog's own check)."""
    per_si = scale.units_per_si(lead)
    if per_si is None or lead <= 0:
        raise CommandRejected(f"motor {motor}'s lead is 0: a velocity cannot be converted to rpm")
    rpm = check_converted(
        f"velocity {si:g} in rpm",
        si * per_si / lead * SECONDS_PER_MINUTE,
        -SPEED_MAX_RPM,
        SPEED_MAX_RPM,
    )
    return device.check_jog(motor, rpm)


def command_joints(
    names: Sequence[str],
    device: StepperDevice,
    targets: MotorTargets,
    scales: Sequence[JointScale],
    gate: Gate,
    offer: Offer,
    here: Callable[[int], float | None],
    max_jump: Callable[[], float],
) -> list[CommandJoint]:
    """The ``CommandJoint`` of each motor, named as in ``joint_states``; ``here(motor)``:
    its newest published position (SI)."""
    joints: list[CommandJoint] = []
    for motor, name in enumerate(names, start=1):
        scale = scales[motor - 1]

        def position(si: float, motor: int = motor, scale: JointScale = scale) -> float:
            return to_target(scale, device.lead(motor), si)

        def velocity(si: float, motor: int = motor, scale: JointScale = scale) -> float:
            return to_rpm(device, motor, scale, device.lead(motor), si)

        joints.append(
            CommandJoint(
                name,
                CommandStream(targets.guard, motor, position),
                CommandStream(device.jogs, motor, velocity),
                gate,
                offer,
                lambda motor=motor: here(motor),  # type: ignore[misc]
                max_jump,
            )
        )
    return joints


__all__ = ["STEP_UNITS", "MotorTargets", "command_joints", "on_step", "to_rpm", "to_target"]
