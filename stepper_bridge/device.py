"""Stepper controller device model: polls into snapshots, commands into checked writes.

No ROS here. Every command validates all of its inputs before its first write, so a
refused command writes nothing. Values are in the manual's units: the user's length unit
for lead, run distance and coordinates (the device stores them x100), rpm, Hz, degrees.

"Stepper decision N" is reading N of docs/decisions/stepper.md.

Confirmation (stepper decision 23; ``confirm``): the controller acknowledges every
write whether or not it obeys, so a stop is done when the running flags (40168+) read 0, a
start when one reads 1 or a coordinate moved, a register write when it reads back;
otherwise ``NotConfirmed`` says what was written and what was read.

Polling (``snapshots``: the plans and types): status every poll, the outputs every
``slow_poll_period_s``; the configuration is read whole when the link comes up, then
refreshed one request per poll every ``config_refresh_s``, and the cache is updated from
every write the bridge makes.

Rooms: the jog streams and their speed restore are ``jog.JogControl`` (``jog_control``),
line / arc interpolation ``interpolation.InterpolationControl`` (``interpolation``); the
device names their commands. The action goals are ``motions``, the SI units ``units``, the
reply texts and shared checks ``replies``.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence

from bridge_core.runtime.checks import check_choice, check_finite, check_index
from bridge_core.runtime.config_cache import ConfiguredDevice
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, PollGroups
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value, decode, encode
from bridge_core.wire.errors import CommandRejected, LinkError, NotConfirmed
from bridge_core.wire.registers import Register

from .confirm import confirm_started, confirm_stopped
from .interpolation import PAIR_READING_UNSET, InterpolationControl, InterpolationRun
from .jog import DEFAULT_JOG_TIMEOUT_S, JogControl
from .registers import (
    DISTANCE_SCALE,
    INPUTS,
    MOTOR_ACTIONS,
    MOTOR_FIELD_NAMES,
    MOTORS,
    OUTPUTS,
    STEPPER_MAP,
    SYSTEM_COILS,
    SYSTEM_MODES,
    U32_MAX,
    coil,
    motor_coil,
    motor_register,
    output_coil,
)
from .replies import (
    check_integer,
    check_motor,
    coil_label,
    motor_coils_text,
    register_text,
)
from .snapshots import (
    CONFIG_PLAN,
    FAST_PLAN,
    OUTPUTS_TOUCHED_BY,
    SLOW_PLAN,
    STAMP_REGISTER,
    StepperConfig,
    StepperSnapshot,
    decode_config,
)

SYSTEM_COMMANDS = (
    "emergency_stop",
    "zero_coordinates",
    "return_to_zero",
    "home_all",
    "save_parameters",
)
DESTRUCTIVE_COMMANDS = ("factory_reset", "clear_all_parameters")
DEFAULT_CONFIG_REFRESH_S = 5.0
# Coils that stop motion: sent at Priority.STOP (with each motor's stop coil).
_STOP_COILS = frozenset({"emergency_stop", "arc_stop", "line_stop"})


# Speed register name -> its motor (a speed written by a command is the configured one).
_SPEED_REGISTERS = {motor_register(m, "speed"): m for m in range(1, MOTORS + 1)}


# ---------------------------------------------------------------- the device


class StepperDevice(ConfiguredDevice[StepperConfig]):
    """The stepper controller behind one Modbus channel."""

    def __init__(
        self,
        io: RegisterIO,
        *,
        config_refresh_s: float = DEFAULT_CONFIG_REFRESH_S,
        slow_period_s: float = SLOW_POLL_PERIOD_DEFAULT_S,
        jog_timeout_s: float = DEFAULT_JOG_TIMEOUT_S,
        pair_reading: str = PAIR_READING_UNSET,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        groups = PollGroups(
            FAST_PLAN,
            SLOW_PLAN,
            period_s=slow_period_s,
            touched_by=OUTPUTS_TOUCHED_BY,
            clock=clock,
        )
        super().__init__(io, STEPPER_MAP, CONFIG_PLAN, config_refresh_s, clock, groups=groups)
        # Which reading of pair types 2 and 3 the controller follows (PAIR_READING_CHOICES).
        self.pair_reading = pair_reading
        # The jog streams (one per motor, ``jogs``) and the speed each jog borrows.
        self.jog_control = JogControl(self, timeout_s=jog_timeout_s, clock=clock)
        self.jogs = self.jog_control.guard
        self.streams.append(self.jogs)
        # Told of each failed restore (the node logs it); must not raise.
        self.on_speed_restore_failure: Callable[[int, int, LinkError], None] = (
            lambda _motor, _rpm, _err: None
        )
        # Polls are numbered as they begin (a line / arc runs until a later poll says not).
        self.next_poll = 0
        self.interpolation = InterpolationControl(self)
        # The rooms' commands, under the device's name (the node and the tests call these).
        self.check_jog = self.jog_control.check
        self.jog = self.jog_control.command
        self.jogging = self.jog_control.jogging
        self.jog_locked = self.jog_control.locked
        self.jog_stop = self.jog_control.stop
        self.restore_pending = self.jog_control.restore_pending
        self.restore_speeds = self.jog_control.restore_speeds
        self.speed_restore_failures = self.jog_control.failures
        self.check_line_move = self.interpolation.check_line_move
        self.check_arc_move = self.interpolation.check_arc_move
        self.line_move = self.interpolation.line_move
        self.arc_move = self.interpolation.arc_move
        self.stop_interpolation = self.interpolation.stop_interpolation
        self.pair_axes = self.interpolation.pair_axes
        self.pair_motors = self.interpolation.pair_motors
        self.take_wrong_pair = self.interpolation.take_wrong_pair
        self.wrong_pair_not_stopped = self.interpolation.wrong_pair_not_stopped
        self.estops = 0  # e-stops this bridge sent (acknowledged)

    @property
    def interpolation_run(self) -> InterpolationRun | None:
        """The line / arc this bridge started, while it runs (``interpolation.run``)."""
        return self.interpolation.run

    def cached_value(self, name: str) -> Value | None:
        """A configuration value as last read or written, None if not read yet."""
        return self._cache.values.get(name)

    # ------------------------------------------------------------------ reads
    @property
    def config(self) -> StepperConfig:
        return decode_config(self.cached("controller"))

    def lead(self, motor: int) -> float:
        check_motor(motor)
        return self.config.motors[motor - 1].lead

    def poll(self) -> StepperSnapshot:
        sequence = self.next_poll
        self.next_poll += 1
        read = self.poll_status(STAMP_REGISTER)
        v = read.values
        running = tuple(bool(v[motor_register(m, "running")]) for m in range(1, MOTORS + 1))
        coordinates = tuple(float(v[motor_register(m, "coordinate")]) for m in range(1, MOTORS + 1))
        self.interpolation.note_wrong_pair(coordinates)
        self.interpolation.note_running(sequence, running)
        return StepperSnapshot(
            read_time=read.read_time,
            state_read_time=read.first_read_time,
            slow_read_time=read.slow_read_time,
            coordinates=coordinates,
            running=running,
            inputs=tuple(bool(v[f"input_{n}"]) for n in range(1, INPUTS + 1)),
            outputs=tuple(bool(v[f"output_{n}"]) for n in range(1, OUTPUTS + 1)),
            config=self.config,
        )

    # ------------------------------------------------------------------ write helpers
    def write_values(self, values: Sequence[tuple[str, Value]], *, jog: bool = False) -> None:
        """Consecutive registers in one write (FC 06 for one register, else FC 10).

        ``values`` must be contiguous and in address order; each is range-checked by the
        map before anything is sent. The cache follows a successful write; after a
        failed one a configuration refresh is started. A speed written by anything but a
        jog (``jog``) is the motor's new configured speed: a jog's restore writes it.
        """
        regs = [STEPPER_MAP[name] for name, _ in values]
        words: list[int] = []
        for reg, (_, value) in zip(regs, values, strict=True):
            words += encode(reg, value)
        _check_contiguous(regs)
        try:
            if len(words) == 1:
                self.io.write_register(regs[0].address, words[0])
            else:
                self.io.write_registers(regs[0].address, words)
        except LinkError:
            self._cache.refresh_soon()
            raise
        for reg, (_, value) in zip(regs, values, strict=True):
            self._cache.note_written(reg.name, _as_read(reg, value))
            motor = _SPEED_REGISTERS.get(reg.name)
            if motor is not None and not jog:
                self.jog_control.configured(motor, int(value))

    def send_coil(self, name: str) -> None:
        # Stops go in the line's next free slot, before other controllers' commands and
        # polls (stepper decision 18).
        priority = Priority.STOP if name in _STOP_COILS else Priority.COMMAND
        self.io.write_coil(STEPPER_MAP[name].address, True, priority)

    # ------------------------------------------------------------------ motor commands
    def motor_action(self, motor: int, action: str, *, confirm: bool = True) -> str:
        """run_once / forward / reverse / home / stop: 0xFF00 to the motor's coil (FC 05),
        then the controller's state read back (stepper decision 23): a stop is done when
        the motor's running flag reads 0, a start when it reads 1 or the coordinate moved
        (``NotConfirmed`` otherwise). ``confirm`` False: a start is not read back (an
        action goal judges it from the polls); a stop always is. Returns what was written
        and read back."""
        check_motor(motor)
        if action not in MOTOR_ACTIONS:
            raise CommandRejected(f"unknown motor action {action!r}; known: {MOTOR_ACTIONS}")
        if action == "stop":
            return self.stop_motors([motor])
        before = self.coordinates([motor]) if confirm else {}
        with self.jogs.lock:
            # The motion runs at the speed register: a jog's speed is undone first (the
            # service takes the motor over from any jog).
            self.restore_speeds([motor], include_jogging=True)
            try:
                self.io.write_coil(motor_coil(motor, action), True, Priority.COMMAND)
            finally:
                # A service overrides any jog: the next jog command is sent whole, and a 0
                # jog then stops the motor once (it may be running the service's motion).
                self.jog_control.taken_over(motor, locked=False)
        wrote = motor_coils_text([motor], action)
        if not confirm:
            return f"wrote {wrote}"
        return confirm_started(self, [motor], wrote, before)

    def send_motor_stops(self, motors: Sequence[int]) -> LinkError | None:
        """Each motor's stop coil at stop priority, every one tried; the first failure is
        returned. A motor whose stop went out is taken over from its jog (locked); one
        whose stop failed keeps its jog's stop pending."""
        error: LinkError | None = None
        with self.jogs.lock:
            for motor in motors:
                try:
                    self.io.write_coil(motor_coil(motor, "stop"), True, Priority.STOP)
                except LinkError as err:
                    self.jogs.stop_failed(motor)  # a jog it meant to end: its stop pending
                    error = error or err
                    continue
                self.jog_control.taken_over(motor, locked=True)
            if error is None:
                self.jog_control.restore_after_stop(list(motors))
        return error

    def stop_motors(self, motors: Sequence[int]) -> str:
        """Each motor's stop coil (all sent first), then their running flags read back
        until 0 (``confirm_stopped``). Raises the first LinkError, or NotConfirmed."""
        motors = list(dict.fromkeys(motors))
        for motor in motors:
            check_motor(motor)
        error = self.send_motor_stops(motors)
        if error is not None:
            raise error
        return confirm_stopped(self, motors, motor_coils_text(motors, "stop"))

    def stream_stop(self, motor: int) -> str:
        """A stream's stop (a jog's 0, the deadman, a halt; the position stream's too):
        the motor's stop coil at stop priority, its running flag read back until 0
        (``NotConfirmed`` otherwise: the stream's stop stays pending and is sent again)."""
        self.io.write_coil(motor_coil(motor, "stop"), True, Priority.STOP)
        self.jog_control.direction[motor] = 0
        return confirm_stopped(self, [motor], motor_coils_text([motor], "stop"))

    # ------------------------------------------------------------------ read-back
    def coordinates(self, motors: Sequence[int]) -> dict[int, float]:
        """The coordinates of ``motors`` read now (user units)."""
        names = {m: motor_register(m, "coordinate") for m in motors}
        values = self.read_named(*names.values())
        return {m: float(values[name]) for m, name in names.items()}

    def _read_back(self, values: Sequence[tuple[str, Value]]) -> str:
        """The registers just written read back: "wrote X = 1, Y = 2 (read back)", or
        ``NotConfirmed`` with every value written and read (the cache takes what was
        read)."""
        read = self.read_named(*(name for name, _ in values))
        expected = {name: _as_read(STEPPER_MAP[name], value) for name, value in values}
        wrote = ", ".join(f"{register_text(name)} = {v:g}" for name, v in expected.items())
        if all(read[name] == v for name, v in expected.items()):
            return f"wrote {wrote} (read back)"
        for name in expected:
            self._cache.note_written(name, read[name])
        seen = ", ".join(f"{register_text(name)} = {read[name]:g}" for name in expected)
        raise NotConfirmed(f"wrote {wrote}; read {seen}")

    def set_motor_parameter(self, motor: int, field: str, value: float) -> None:
        """One basic parameter: FC 06 for a 16-bit one, FC 10 for lead / run distance.

        ``field`` is one of MOTOR_FIELD_NAMES, in the manual's units (degrees, Hz, rpm,
        user units; the device stores step angle, lead and distance x100).
        """
        check_motor(motor)
        if field not in MOTOR_FIELD_NAMES:
            raise CommandRejected(f"unknown motor parameter {field!r}; known: {MOTOR_FIELD_NAMES}")
        check_finite(field, value)
        reg = STEPPER_MAP[motor_register(motor, field)]
        if reg.scale == 1.0:
            check_integer(field, value, low=0, high=U32_MAX)
            self.write_values([(reg.name, int(value))])
        else:
            self.write_values([(reg.name, float(value))])

    def set_run_distance(self, motor: int, distance: float) -> None:
        """Run distance (user units, x100, 32-bit low word first) with FC 10."""
        self.set_motor_parameter(motor, "run_distance", distance)

    def check_move_by(self, motor: int, distance: float) -> None:
        """A single run's motor and distance checked (no I/O)."""
        check_motor(motor)
        check_finite("distance", distance)
        reg = STEPPER_MAP[motor_register(motor, "run_distance")]
        encode(reg, abs(float(distance)))  # range check before the first write
        if round(abs(float(distance)) * DISTANCE_SCALE) == 0:
            raise CommandRejected(
                f"distance {distance} is below the controller's step of {1 / DISTANCE_SCALE}"
            )

    def move_by(self, motor: int, distance: float, *, confirm: bool = True) -> str:
        """Signed single run: direction (FC 06), distance (FC 10), both read back (one
        read: a controller that kept other values would run elsewhere), then the
        single-run coil (FC 05), its start read back unless ``confirm`` is False."""
        self.check_move_by(motor, distance)
        values: list[tuple[str, Value]] = [
            (motor_register(motor, "direction"), 0 if distance >= 0 else 1),
            (motor_register(motor, "run_distance"), abs(float(distance))),
        ]
        self.write_values(values[:1])
        self.write_values(values[1:])
        held = self._read_back(values)
        return f"{held}; {self.motor_action(motor, 'run_once', confirm=confirm)}"

    def configure(
        self,
        motor: int,
        *,
        step_angle_deg: float,
        microstep: int,
        start_frequency_hz: int,
        accel_frequency_hz: int,
        speed_rpm: int,
        lead: float,
    ) -> None:
        """Basic parameters: 40001-40004 then 40006-40008 (two FC 10; direction untouched)."""
        check_motor(motor)
        check_finite("step angle", step_angle_deg)
        check_finite("lead", lead)
        for what, value in (
            ("microstep", microstep),
            ("start frequency", start_frequency_hz),
            ("accel frequency", accel_frequency_hz),
            ("speed", speed_rpm),
        ):
            check_integer(what, value)
        first: list[tuple[str, Value]] = [
            (motor_register(motor, "step_angle"), float(step_angle_deg)),
            (motor_register(motor, "microstep"), int(microstep)),
            (motor_register(motor, "start_frequency"), int(start_frequency_hz)),
            (motor_register(motor, "accel_frequency"), int(accel_frequency_hz)),
        ]
        second: list[tuple[str, Value]] = [
            (motor_register(motor, "speed"), int(speed_rpm)),
            (motor_register(motor, "lead"), float(lead)),
        ]
        for name, new in first + second:
            encode(STEPPER_MAP[name], new)  # every range checked before the first write
        self.write_values(first)
        self.write_values(second)

    def set_speed(self, motor: int, rpm: int) -> str:
        """Speed register (40006+, rpm, "运行中可以调节": a running motion takes it at once).

        During a jog it becomes the configured speed the jog's end writes back."""
        check_motor(motor)
        check_integer("speed", rpm)
        values: list[tuple[str, Value]] = [(motor_register(motor, "speed"), int(rpm))]
        self.write_values(values)
        return self._read_back(values)

    def set_direction(self, motor: int, direction: int) -> None:
        """Single-run direction (40005+): 0 positive, 1 negative ("0 对应正方向,1 对应反方向")."""
        check_motor(motor)
        check_choice("direction", direction, (0, 1))
        self.write_values([(motor_register(motor, "direction"), int(direction))])

    def set_round_trips(self, motor: int, count: int) -> None:
        """Mode-1 round trips of ``motor`` (40301-40305), 0 = endless ("0表示无限次")."""
        check_motor(motor)
        check_integer("round trips", count)
        self.write_values([(motor_register(motor, "reciprocations"), int(count))])

    def set_limit_inputs(self, motor: int, positive: int, negative: int, home: int) -> None:
        """Which input (1-13, 0 none) is the motor's positive / negative limit and home."""
        check_motor(motor)
        for what, value in (("positive limit", positive), ("negative limit", negative)):
            check_integer(f"{what} input", value)
        check_integer("home input", home)
        self.write_values(
            [
                (motor_register(motor, "positive_limit_input"), int(positive)),
                (motor_register(motor, "negative_limit_input"), int(negative)),
                (motor_register(motor, "home_input"), int(home)),
            ]
        )

    def set_homing_order(self, motors: Sequence[int]) -> None:
        """40177-40181: the motors home_all homes, in order; the rest is set to 0 (none)."""
        if len(motors) > MOTORS:
            raise CommandRejected(f"at most {MOTORS} motors, got {len(motors)}")
        for motor in motors:
            check_motor(motor)
        if len(set(motors)) != len(motors):
            raise CommandRejected(f"motor listed twice in the homing order {list(motors)}")
        order = [int(m) for m in motors] + [0] * (MOTORS - len(motors))
        self.write_values([(f"homing_order_{k + 1}", m) for k, m in enumerate(order)])

    def set_system_mode(self, mode: int) -> None:
        check_choice("system mode", mode, tuple(SYSTEM_MODES))
        self.write_values([("system_mode", int(mode))])

    # ------------------------------------------------------------------ all-motor commands
    def system_command(self, name: str, *, confirm: bool = True) -> str:
        """An all-motor or system coil. The e-stop is done when every running flag reads
        0; home_all and return_to_zero when a motor runs or moved (unless ``confirm`` is
        False: an action goal judges them from the polls); ``NotConfirmed`` otherwise.
        Returns what was written (and read back)."""
        if name not in SYSTEM_COMMANDS:
            raise CommandRejected(f"unknown command {name!r}; known: {SYSTEM_COMMANDS}")
        takes_over = name in ("emergency_stop", "home_all", "return_to_zero")
        every = list(range(1, MOTORS + 1))
        starts = confirm and name in ("home_all", "return_to_zero")
        before = self.coordinates(every) if starts else {}
        if starts and name == "return_to_zero" and not any(before.values()):
            starts = False  # every coordinate reads 0 already: nothing to run
        with self.jogs.lock:
            if name == "save_parameters":
                # Saving a jog's speed would make it the configured one for good.
                jogging = [m for m in self.restore_pending() if self.jogging(m)]
                if jogging:
                    raise CommandRejected(
                        f"motor(s) {', '.join(map(str, jogging))} jogging with a jog speed "
                        "in the speed register: stop the jog before save_parameters"
                    )
            if name in ("home_all", "return_to_zero", "save_parameters"):
                self.restore_speeds(list(range(1, MOTORS + 1)), include_jogging=True)
            try:
                self.send_coil(name)
            except LinkError:
                for motor in range(1, MOTORS + 1):
                    if name == "emergency_stop":
                        self.jogs.stop_failed(motor)  # each jog's own stop stays pending
                    elif takes_over:
                        self.jog_control.taken_over(motor, locked=False)
                raise
            # The e-stop halts every jog and locks it; homing and return to zero take the
            # motors over, so the next jog command is sent whole.
            if takes_over:
                for motor in range(1, MOTORS + 1):
                    self.jog_control.taken_over(motor, locked=name == "emergency_stop")
            if name == "emergency_stop":
                self.estops += 1  # a goal it ended says so (StepperMotion)
                self.interpolation.run = None  # "完成所有电机急停": the move ended
                self.jog_control.restore_after_stop(list(range(1, MOTORS + 1)))
        wrote = f"{name.replace('_', ' ')} (coil {coil_label(coil(SYSTEM_COILS[name]))} = ON)"
        if name == "emergency_stop":
            return confirm_stopped(self, every, wrote)
        if starts:
            return confirm_started(self, every, wrote, before)
        if name == "return_to_zero" and confirm:
            return f"wrote {wrote}; every coordinate read 0 before it"
        return f"wrote {wrote}"

    def zero_coordinates(self, motors: Sequence[int]) -> dict[int, float]:
        """The "坐标清零" coil (00044; it names no motor: every coordinate), then the
        coordinates of ``motors`` read back (user units)."""
        self.system_command("zero_coordinates")
        return self.coordinates(motors)

    def destructive_command(self, name: str, confirmation: str) -> None:
        """Factory reset (00073) or clear all parameters (00097): ``confirmation`` must
        repeat the command's name."""
        if name not in DESTRUCTIVE_COMMANDS:
            raise CommandRejected(f"unknown command {name!r}; known: {DESTRUCTIVE_COMMANDS}")
        if confirmation != name:
            raise CommandRejected(
                f"{name} erases the controller's parameters: set confirm to {name!r} to do it"
            )
        try:
            self.send_coil(name)
        finally:
            self._cache.refresh_soon()
        self.jog_control.forget()  # every parameter was replaced

    def set_output(self, output: int, on: bool) -> None:
        """Output 1-12: 0xFF00 to its ON coil, or to its OFF coil (00049-00072 in pairs)."""
        check_index("output", output, range(1, OUTPUTS + 1))
        self.io.write_coil(output_coil(output, bool(on)), True)

    def set_all_outputs(self, on: bool) -> None:
        self.send_coil("all_outputs_on" if on else "all_outputs_off")


# ---------------------------------------------------------------- checks


def _as_read(reg: Register, value: Value) -> Value:
    """The value a read of ``reg`` would decode to after writing ``value``."""
    return decode(reg, encode(reg, value))


def _check_contiguous(regs: Sequence[Register]) -> None:
    for before, after in itertools.pairwise(regs):
        if after.address != before.end:
            raise ValueError(f"{after.name} does not follow {before.name}")


__all__ = [
    "DESTRUCTIVE_COMMANDS",
    "SYSTEM_COILS",
    "SYSTEM_COMMANDS",
    "StepperDevice",
]
