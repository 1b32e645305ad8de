"""Stepper jog: one command stream per motor, and the configured speed each jog borrows.

Jog (``StepperDevice.jog``): rpm with sign = direction. A change of speed writes the speed
register (40006+, "运行中可以调节": adjustable while running); a change of direction writes
the forward / reverse coil (a reversal sends the stop coil first); 0 sends the stop coil.
A command equal to the last one writes nothing. After a stop (the motor's stop service
or the emergency stop) jogging is locked until a 0 command (or the node's deadman) so a
joystick still held cannot restart a motor that was just stopped.

Speed restore: the speed register is also the configured speed of single runs, forward /
reverse, homing and the interpolation approach, so a jog gives it back: the value before
the jog's first speed write (from the configuration cache) is written back (FC 06, which
starts no motion) after the jog's stop (its 0, the deadman, the motor's stop service, the
e-stop, shutdown), and before a command that runs the motor from its configuration
(single run, forward, reverse, home, home all, return to zero, line / arc) or saves the
parameters. A failed restore after a stop is recorded (``failures``), never raised, and
retried at the next stop or such command. No ROS here.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Protocol

from bridge_core.runtime.checks import check_range
from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.wire.channel import RegisterIO
from bridge_core.wire.codec import Value
from bridge_core.wire.errors import DeviceException, LinkError

from .registers import MOTORS, U16_MAX, motor_coil, motor_register
from .replies import check_motor


class JogDevice(Protocol):
    """What the jog streams use of the device (``StepperDevice``), named here so the
    device imports this module and never the other way round."""

    @property
    def io(self) -> RegisterIO: ...

    @property
    def on_speed_restore_failure(self) -> Callable[[int, int, LinkError], None]: ...

    def read_named(self, *names: str) -> dict[str, Value]: ...

    def cached_value(self, name: str) -> Value | None: ...

    def write_values(self, values: Sequence[tuple[str, Value]], *, jog: bool = False) -> None: ...

    def stream_stop(self, motor: int) -> str: ...


DEFAULT_JOG_TIMEOUT_S = 0.5
SPEED_MAX_RPM = U16_MAX


class JogControl:
    """The jog streams of one controller (``guard``, one per motor), the direction coil
    each motor was last sent by a jog and the configured speed a jog's speed replaced."""

    def __init__(
        self,
        device: JogDevice,
        *,
        timeout_s: float = DEFAULT_JOG_TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.device = device
        self.guard: StreamGuard[int] = StreamGuard(
            range(1, MOTORS + 1),
            self._send,
            self._stop_coil,
            timeout_s=timeout_s,
            stop_when_idle=True,
            clock=clock,
            after_stop=self.restore_after_stop,
        )
        # +1 forward, -1 reverse, 0 stopped, None unknown (a write was lost).
        self.direction: dict[int, int | None] = dict.fromkeys(range(1, MOTORS + 1), 0)
        # The speed register (40006+) is the motor's configured speed for single runs,
        # forward / reverse, homing and the interpolation approach; a jog writes its own
        # speed there. The configured value, kept from before a jog's first speed write
        # until it is written back (None: the register holds the configured speed).
        self.configured_speed: dict[int, int | None] = dict.fromkeys(range(1, MOTORS + 1))
        # Motors whose speed restore failed, with the reason (diagnostics; retried).
        self.failures: dict[int, str] = {}

    # ------------------------------------------------------------------ the stream
    def check(self, motor: int, rpm: float) -> float:
        """A jog command's motor and speed; the speed rounded to the register's whole rpm."""
        check_motor(motor)
        check_range("jog speed", rpm, -SPEED_MAX_RPM, SPEED_MAX_RPM, "rpm")
        return float(round(rpm))

    def command(self, motor: int, rpm: float) -> bool:
        """Run at ``rpm`` (sign = direction) until told otherwise; True if anything was sent."""
        return self.guard.command(
            motor,
            self.check(motor, rpm),
            refuse_reason=f"motor {motor} was stopped: send a 0 jog before jogging it again",
        )

    def _send(self, motor: int, rpm: float, _previous: float | None) -> None:
        """Speed (40006+, adjustable while running) and direction coil, as needed.

        A reversal, or a motor whose direction is unknown, gets the stop coil first.
        """
        device = self.device
        speed, sign = round(abs(rpm)), (1 if rpm > 0 else -1)
        direction = self.direction[motor]
        try:
            if direction is None or direction == -sign:
                device.io.write_coil(motor_coil(motor, "stop"), True)
                self.direction[motor] = direction = 0
            # The speed register keeps its value across stops: write it only when the
            # value the cache holds (read from the device, or our own last write) differs.
            speed_register = motor_register(motor, "speed")
            if device.cached_value(speed_register) != speed:
                if self.configured_speed[motor] is None:
                    self.configured_speed[motor] = self._speed_before_jog(motor)
                device.write_values([(speed_register, speed)], jog=True)
            if direction != sign:
                device.io.write_coil(motor_coil(motor, "forward" if sign > 0 else "reverse"), True)
                self.direction[motor] = sign
        except LinkError:
            self.direction[motor] = None
            raise

    def _stop_coil(self, motor: int) -> None:
        self.device.stream_stop(motor)

    def taken_over(self, motor: int, *, locked: bool) -> None:
        """A command took the motor over (a stop, a service's motion, the e-stop): the next
        jog command is sent whole; ``locked``: it must be a 0 first."""
        self.guard.taken_over(motor, locked=locked)
        self.direction[motor] = 0

    def jogging(self, motor: int) -> bool:
        """Running under a jog, or possibly so after a failed write (the deadman's cue)."""
        return self.guard[motor].may_move

    def locked(self, motor: int) -> bool:
        return self.guard[motor].locked

    def stop(self, motor: int) -> bool:
        """Send the motor's stop coil now and end its jog."""
        check_motor(motor)
        return self.guard.stop(motor)

    # ------------------------------------------------------------------ speed restore
    def _speed_before_jog(self, motor: int) -> int:
        """The configured speed, from the cache (or the device when the cache lacks it)."""
        name = motor_register(motor, "speed")
        value = self.device.cached_value(name)
        if value is None:
            value = self.device.read_named(name)[name]
        return int(value)

    def configured(self, motor: int, rpm: int) -> None:
        """A speed written by anything but a jog is the motor's new configured speed: the
        jog's restore writes it."""
        if self.configured_speed[motor] is not None:
            self.configured_speed[motor] = rpm

    def forget(self) -> None:
        """Every parameter was replaced: no configured speed is left to restore."""
        for motor in range(1, MOTORS + 1):
            self.configured_speed[motor] = None
        self.failures.clear()

    def restore_pending(self) -> dict[int, int]:
        """Motors whose speed register may hold a jog's speed: motor -> configured rpm."""
        return {m: rpm for m, rpm in self.configured_speed.items() if rpm is not None}

    def restore_speeds(self, motors: Sequence[int], *, include_jogging: bool = False) -> None:
        """Write the configured speed back to each of ``motors`` whose jog changed it.

        A plain FC 06 of the speed register: it starts no motion ("运行中可以调节": it
        only sets the speed of a motion that runs). A motor still jogging is skipped
        unless ``include_jogging`` (a command is taking it over). Raises LinkError.
        """
        with self.guard.lock:
            for motor in motors:
                rpm = self.configured_speed[motor]
                if rpm is None or (self.jogging(motor) and not include_jogging):
                    continue
                # Written even when the cache holds it: a jog's write that failed on the
                # link may still have landed (the cache follows acknowledged writes only).
                self.device.write_values([(motor_register(motor, "speed"), rpm)], jog=True)
                self.configured_speed[motor] = None
                self.failures.pop(motor, None)

    def restore_after_stop(self, _stopped: Sequence[int]) -> None:
        """After stops (a jog's 0, the deadman, a stop service, the e-stop, shutdown):
        every motor no longer jogging gets its configured speed back, including retries of
        restores that failed before. A failure is recorded and reported, never raised: the
        stop itself was acknowledged."""
        for motor in sorted(self.restore_pending()):
            try:
                self.restore_speeds([motor])
            except LinkError as err:
                rpm = self.configured_speed[motor] or 0
                self.failures[motor] = f"{rpm} rpm not restored: {err}"
                self.device.on_speed_restore_failure(motor, rpm, err)
                if not isinstance(err, DeviceException):
                    break  # the link is failing: the rest stay pending, no more timeouts
