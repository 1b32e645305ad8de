"""Stepper controller device model: polls into snapshots, commands into checked writes.

No ROS here. Every command validates all of its inputs before its first write, so a
refused command writes nothing. Values are in the manual's units: the user's length unit
for lead, run distance and coordinates (the device stores them x100), rpm, Hz, degrees.

"Stepper decision N" is reading N of docs/decisions/stepper.md.

Confirmation (issue 39, stepper decision 23): the controller acknowledges every write
whether or not it obeys, so a stop is done when the running flags (40168+) read 0, a start
when one reads 1 or a coordinate moved, a register write when it reads back; otherwise
``NotConfirmed`` says what was written and what was read.

Polling. A poll reads three status blocks (running flags 40168-40172 first, then
coordinates 40108-40117 and inputs 40124-40136: three requests, the undefined rows
between them cannot be read through); the outputs 40148-40159 are the slow group, read
every ``slow_poll_period_s`` (stepper decision 21). The configuration (motor parameters,
limit inputs, homing order, system mode) changes rarely; it is read whole when the link comes
up, then refreshed one request per poll every ``config_refresh_s``, and the cache is
updated from every write the bridge makes.

Jog (``jog``): rpm with sign = direction. A change of speed writes the speed register
(40006+, "运行中可以调节": adjustable while running); a change of direction writes the
forward / reverse coil (a reversal sends the stop coil first); 0 sends the stop coil.
A command equal to the last one writes nothing. After a stop (the motor's stop service
or the emergency stop) jogging is locked until a 0 command (or the node's deadman) so a
joystick still held cannot restart a motor that was just stopped.

The speed register is also the configured speed of single runs, forward / reverse,
homing and the interpolation approach, so a jog gives it back: the value before the jog's
first speed write (from the configuration cache) is written back (FC 06, which starts no
motion) after the jog's stop (its 0, the deadman, the motor's stop service, the
e-stop, shutdown), and before a command that runs the motor from its configuration
(single run, forward, reverse, home, home all, return to zero, line / arc) or saves the
parameters. A failed restore after a stop is recorded (``speed_restore_failures``),
never raised, and retried at the next stop or such command.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from bridge_core.runtime.checks import (
    check_choice,
    check_finite,
    check_index,
    check_range,
    check_whole_number,
)
from bridge_core.runtime.config_cache import ConfiguredDevice
from bridge_core.runtime.goals import Motion, Outcome, Verdict, within
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, PollGroups
from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value, decode, encode
from bridge_core.wire.errors import CommandRejected, DeviceException, LinkError, NotConfirmed
from bridge_core.wire.planner import ReadRequest, plan_reads
from bridge_core.wire.registers import Register, Table
from bridge_core.wire.requests import Span

from .registers import (
    ARC_MODE_CENTER,
    ARC_MODE_THREE_POINTS,
    DISTANCE_SCALE,
    INPUTS,
    INTERPOLATION_PAIRS,
    INTERPOLATION_PAIRS_POINT_ROWS,
    INTERPOLATION_REGISTERS,
    LINK_REGISTERS,
    MOTOR_ACTIONS,
    MOTOR_FIELD_NAMES,
    MOTORS,
    OUTPUTS,
    STEPPER_MAP,
    SYSTEM_COILS,
    SYSTEM_MODES,
    U16_MAX,
    U32_MAX,
    coil,
    motor_coil,
    motor_register,
    output_coil,
)

SYSTEM_COMMANDS = (
    "emergency_stop",
    "zero_coordinates",
    "return_to_zero",
    "home_all",
    "save_parameters",
)
DESTRUCTIVE_COMMANDS = ("factory_reset", "clear_all_parameters")
LIMIT_FIELDS = ("positive_limit_input", "negative_limit_input", "home_input")
DEFAULT_CONFIG_REFRESH_S = 5.0
DEFAULT_JOG_TIMEOUT_S = 0.5
SPEED_MAX_RPM = U16_MAX
# A prismatic motor's controller units per metre unless configured: the user's unit is mm.
DEFAULT_UNITS_PER_METER = 1000.0
# Coils that stop motion: sent at Priority.STOP (with each motor's stop coil).
_STOP_COILS = frozenset({"emergency_stop", "arc_stop", "line_stop"})
# Confirmation (issue 39, stepper decision 23): a command that starts, stops or changes
# motion is done only when the controller's own state, read back, shows it. A stop: the
# running flags (40168+) of its motors read 0 within STOP_CONFIRM_S (the stop coil is the
# manual's "急停", an immediate stop); a start: a running flag reads 1, or a coordinate
# (40108+) moved, within START_CONFIRM_S; a register write: the register reads the value
# written. Read at command priority every CONFIRM_READ_PERIOD_S (polls get the line
# between two reads); not shown in time: ``NotConfirmed`` saying what was written and read.
STOP_CONFIRM_S = 0.5
START_CONFIRM_S = 0.5
CONFIRM_READ_PERIOD_S = 0.05
JOINT_TYPES = ("prismatic", "revolute")
# interpolation_pair_reading: which of the manual's two readings of pair types 2 and 3 the
# controller follows (stepper decision 19). Unset until the hardware check in
# docs/decisions/stepper.md settles it: pairs 2 and 3 are refused meanwhile.
PAIR_READING_UNSET = "unset"
PAIR_READINGS: dict[str, dict[int, tuple[int, int]]] = {
    "type_rows": INTERPOLATION_PAIRS,
    "point_rows": INTERPOLATION_PAIRS_POINT_ROWS,
}
PAIR_READING_CHOICES = (PAIR_READING_UNSET, *PAIR_READINGS)
# Every motor an interpolation pair can name, under either reading: what
# stop_interpolation stops when the bridge started no line / arc itself.
INTERPOLATION_MOTORS = tuple(
    sorted({m for pairs in PAIR_READINGS.values() for pair in pairs.values() for m in pair})
)


# ---------------------------------------------------------------- snapshots


@dataclass(frozen=True)
class MotorConfig:
    """One motor's parameters as last read (or written) by the bridge."""

    step_angle_deg: float
    microstep: int
    start_frequency_hz: int
    accel_frequency_hz: int
    direction: int  # 0 positive, 1 negative: the single run's direction
    speed_rpm: int
    lead: float  # user units per revolution
    run_distance: float  # user units
    positive_limit_input: int  # input 1-13, 0 none
    negative_limit_input: int
    home_input: int
    reciprocations: int  # system mode 1 round trips, 0 endless


@dataclass(frozen=True)
class InterpolationConfig:
    """40182-40211 as last read (or written): the last line / arc set up, user units.

    Points are (first motor, second motor) of the pair, by the type rows' reading
    (registers.INTERPOLATION_PAIRS)."""

    arc_pair: int
    arc_mode: int
    arc_start: tuple[float, float]
    arc_end: tuple[float, float]
    arc_center: tuple[float, float]
    arc_via: tuple[float, float]
    arc_counterclockwise: bool
    arc_speed_rpm: int
    line_pair: int
    line_start: tuple[float, float]
    line_end: tuple[float, float]
    line_speed_rpm: int


@dataclass(frozen=True)
class StepperConfig:
    motors: tuple[MotorConfig, ...]
    homing_order: tuple[int, ...]
    system_mode: int
    interpolation: InterpolationConfig
    device_id: int  # 40212: read only (stepper decision 13: never written)
    baud_rate: int  # 40213-40214


@dataclass(frozen=True)
class InterpolationRun:
    """A line / arc the bridge started: its motors (under both readings of the pair), the
    first poll sequence number that began after its start coil was sent, the pair's motors
    by the configured reading and every motor's coordinate read before the start."""

    kind: str
    motors: tuple[int, ...]
    first_poll: int
    pair: int = 0
    expected: tuple[int, ...] = ()
    start_coordinates: dict[int, float] = field(default_factory=dict)

    def moved(self, coordinates: Sequence[float]) -> list[int]:
        """Motors of either reading whose coordinate is off its value at the start by a
        step or more (the registers count hundredths of a unit)."""
        return [
            m
            for m, at_start in self.start_coordinates.items()
            if round(coordinates[m - 1] * DISTANCE_SCALE) != round(at_start * DISTANCE_SCALE)
        ]

    def wrong_motors(self, coordinates: Sequence[float]) -> list[int]:
        """Moved motors outside the configured pair (the controller reads it otherwise)."""
        return [m for m in self.moved(coordinates) if m not in self.expected]


@dataclass(frozen=True)
class StepperSnapshot:
    """One poll: status as read now, configuration as last read."""

    read_time: float  # wall clock when the coordinates were read (joint_states)
    # When the running flags, read first, were read (~/state): a state stamped after a
    # stop shows flags read after it (the stop may go between the two reads).
    state_read_time: float
    slow_read_time: float  # wall clock when the slow group (the outputs) was read
    coordinates: tuple[float, ...]  # user units (register / 100)
    running: tuple[bool, ...]
    inputs: tuple[bool, ...]  # input 1 first
    outputs: tuple[bool, ...]  # output 1 first; the slow group, read at slow_read_time
    config: StepperConfig


def _fast_names() -> list[str]:
    """Every poll (stepper decision 21): what moves by itself and what the motions
    judge: the running flags (a motion ends, a limit or the home switch stops a motor),
    the coordinates (joint_states), the inputs (the limit and home switches)."""
    names = [motor_register(m, "coordinate") for m in range(1, MOTORS + 1)]
    names += [f"input_{n}" for n in range(1, INPUTS + 1)]
    names += [motor_register(m, "running") for m in range(1, MOTORS + 1)]
    return names


def _slow_names() -> list[str]:
    """Every ``slow_poll_period_s``: the outputs change only by coils (00049-00072, all
    outputs on / off, the e-stop: ``OUTPUTS_TOUCHED_BY``), which refresh them at the next
    poll; nothing the bridge decides reads them."""
    return [f"output_{n}" for n in range(1, OUTPUTS + 1)]


def _config_names() -> list[str]:
    names = [motor_register(m, f) for m in range(1, MOTORS + 1) for f in MOTOR_FIELD_NAMES]
    names += [motor_register(m, f) for m in range(1, MOTORS + 1) for f in LIMIT_FIELDS]
    names += [f"homing_order_{k}" for k in range(1, MOTORS + 1)]
    names += ["system_mode"]
    names += [motor_register(m, "reciprocations") for m in range(1, MOTORS + 1)]
    names += list(INTERPOLATION_REGISTERS) + list(LINK_REGISTERS)
    return names


# Speed register name -> its motor (a speed written by a command is the configured one).
_SPEED_REGISTERS = {motor_register(m, "speed"): m for m in range(1, MOTORS + 1)}
_RUNNING_REGISTERS = frozenset(motor_register(m, "running") for m in range(1, MOTORS + 1))
# The running flags are read first: a coordinate read after a flag that says "stands" is
# where the motor stopped. In address order (coordinates first) a motor that stops between
# the two reads would be reported standing at a coordinate from before its last step.
FAST_PLAN: list[ReadRequest] = sorted(
    plan_reads(STEPPER_MAP, STEPPER_MAP.select(_fast_names())),
    key=lambda request: not any(r.name in _RUNNING_REGISTERS for r in request.registers),
)
SLOW_PLAN: list[ReadRequest] = plan_reads(STEPPER_MAP, STEPPER_MAP.select(_slow_names()))
# The writes that change an output besides the outputs' own rows (which are read only).
_OUTPUT_COILS = range(output_coil(1, True), output_coil(OUTPUTS, False) + 1)
OUTPUTS_TOUCHED_BY: tuple[Span, ...] = (
    Span(Table.COIL, _OUTPUT_COILS.start, len(_OUTPUT_COILS)),
    *(
        Span(Table.COIL, coil(SYSTEM_COILS[name]))
        for name in (
            "emergency_stop",
            "all_outputs_on",
            "all_outputs_off",
            "factory_reset",
            "clear_all_parameters",
        )
    ),
)
# joint_states is stamped with the read time of the block holding the coordinates.
STAMP_REGISTER = motor_register(1, "coordinate")
CONFIG_PLAN: list[ReadRequest] = plan_reads(STEPPER_MAP, STEPPER_MAP.select(_config_names()))


# ---------------------------------------------------------------- joint units


@dataclass(frozen=True)
class JointScale:
    """Device units <-> SI for one motor (docs/bridges/stepper.md, ``joint_states``).

    prismatic: metres = units / ``units_per_meter`` (1000 when the user's unit is mm);
    revolute: radians = units / ``units_per_revolution`` x 2 pi, the user units per JOINT
    revolution (a reduction makes it lead x ratio); 0 takes the lead read from the device
    (units per MOTOR revolution: no reduction).
    """

    joint_type: str = "prismatic"
    units_per_meter: float = DEFAULT_UNITS_PER_METER
    units_per_revolution: float = 0.0

    def __post_init__(self) -> None:
        if self.joint_type not in JOINT_TYPES:
            raise ValueError(f"joint type {self.joint_type!r} is not one of {JOINT_TYPES}")
        if not math.isfinite(self.units_per_meter) or self.units_per_meter <= 0:
            raise ValueError(f"units_per_meter must be positive, got {self.units_per_meter}")
        if not math.isfinite(self.units_per_revolution) or self.units_per_revolution < 0:
            raise ValueError(
                f"units_per_revolution must be 0 (the lead) or positive, "
                f"got {self.units_per_revolution}"
            )

    def needs_lead(self) -> bool:
        """Whether the conversion depends on the lead read from the device."""
        return self.joint_type == "revolute" and self.units_per_revolution == 0

    def units_per_si(self, lead: float) -> float | None:
        """Controller units per metre (prismatic) or per radian (revolute); None when a
        revolute joint takes the lead and the device's lead is unset (0)."""
        if self.joint_type == "prismatic":
            return self.units_per_meter
        per_revolution = self.units_per_revolution or lead
        if per_revolution <= 0:
            return None
        return per_revolution / (2.0 * math.pi)

    def to_si(self, units: float, lead: float) -> float:
        factor = self.units_per_si(lead)
        if factor is None:
            return math.nan  # the device's lead is unset: no angle
        return units / factor

    def to_units(self, si: float, lead: float) -> float:
        if not math.isfinite(si):
            raise CommandRejected(f"{si} is not a finite distance")
        factor = self.units_per_si(lead)
        if factor is None:
            raise CommandRejected("the motor's lead is 0: a revolute angle cannot be converted")
        return si * factor


def pair_axes(pair: int, reading: str) -> tuple[int, int]:
    """The (first, second) motor of an interpolation pair under the configured reading.

    Pair 1 is motors 1+2 under both readings of the manual. Pairs 2 and 3 are motors 1+3
    and 2+3 by the type rows (40182 / 40202) but 2+3 and 1+3 by the point rows under them:
    refused (one line) until ``interpolation_pair_reading`` names the reading the hardware
    check showed (registers.INTERPOLATION_PAIRS).
    """
    _check_pair(pair)
    by_type, by_points = INTERPOLATION_PAIRS[pair], INTERPOLATION_PAIRS_POINT_ROWS[pair]
    if by_type == by_points:
        return by_type
    if reading not in PAIR_READINGS:
        raise CommandRejected(
            f"interpolation pair {pair} refused: the manual names motors "
            f"{by_type[0]}+{by_type[1]} for it in its type rows (40182/40202) and "
            f"{by_points[0]}+{by_points[1]} in its point rows; run the hardware check in "
            "docs/decisions/stepper.md, then set interpolation_pair_reading to type_rows or "
            "point_rows (pair 1 needs neither)"
        )
    return PAIR_READINGS[reading][pair]


# ---------------------------------------------------------------- what a reply names


def coil_label(address: int) -> str:
    """The manual's number of a coil ("00005" for motor 1's stop, address 4)."""
    return f"{address + 1:05d}"


def register_label(name: str) -> str:
    """The manual's number of a holding register ("40168" for motor 1's running flag)."""
    return str(40001 + STEPPER_MAP[name].address)


def _motor_coils_text(motors: Sequence[int], action: str) -> str:
    return ", ".join(
        f"motor {m} {action.replace('_', ' ')} (coil {coil_label(motor_coil(m, action))} = ON)"
        for m in motors
    )


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
        # The jog streams (one per motor) and the direction coil each motor was last sent
        # by a jog: +1 forward, -1 reverse, 0 stopped, None unknown (a write was lost).
        self.jogs: StreamGuard[int] = StreamGuard(
            range(1, MOTORS + 1),
            self._jog_send,
            self._jog_stop_coil,
            timeout_s=jog_timeout_s,
            stop_when_idle=True,
            clock=clock,
            after_stop=self._restore_after_stop,
        )
        self.streams.append(self.jogs)
        self._direction: dict[int, int | None] = dict.fromkeys(range(1, MOTORS + 1), 0)
        # The speed register (40006+) is the motor's configured speed for single runs,
        # forward / reverse, homing and the interpolation approach; a jog writes its own
        # speed there. The configured value, kept from before a jog's first speed write
        # until it is written back (None: the register holds the configured speed).
        self._configured_speed: dict[int, int | None] = dict.fromkeys(range(1, MOTORS + 1))
        # Motors whose speed restore failed, with the reason (diagnostics; retried).
        self.speed_restore_failures: dict[int, str] = {}
        # Told of each failed restore (the node logs it); must not raise.
        self.on_speed_restore_failure: Callable[[int, int, LinkError], None] = (
            lambda _motor, _rpm, _err: None
        )
        # Polls are numbered as they begin.
        # The controller has no "interpolation running" register: a line / arc the bridge
        # started counts as running until a poll begun after its start coil shows its
        # motors stopped (or a stop / e-stop is acknowledged). §5(1) 40201 / 40211:
        # "插补过程运行中不可调节"; a second line / arc is refused meanwhile.
        self._next_poll = 0
        self.interpolation_run: InterpolationRun | None = None
        # A line / arc that moved a motor outside its configured pair, once per run: the
        # node stops it (stepper decision 19). Set by a poll, taken by the node.
        self._wrong_pair: str | None = None
        self._wrong_pair_run: InterpolationRun | None = None
        self.estops = 0  # e-stops this bridge sent (acknowledged)

    # ------------------------------------------------------------------ reads
    @property
    def config(self) -> StepperConfig:
        v = self.cached("controller")

        def i(name: str) -> int:
            return int(v[name])

        motors = tuple(
            MotorConfig(
                step_angle_deg=float(v[motor_register(m, "step_angle")]),
                microstep=i(motor_register(m, "microstep")),
                start_frequency_hz=i(motor_register(m, "start_frequency")),
                accel_frequency_hz=i(motor_register(m, "accel_frequency")),
                direction=i(motor_register(m, "direction")),
                speed_rpm=i(motor_register(m, "speed")),
                lead=float(v[motor_register(m, "lead")]),
                run_distance=float(v[motor_register(m, "run_distance")]),
                positive_limit_input=i(motor_register(m, "positive_limit_input")),
                negative_limit_input=i(motor_register(m, "negative_limit_input")),
                home_input=i(motor_register(m, "home_input")),
                reciprocations=i(motor_register(m, "reciprocations")),
            )
            for m in range(1, MOTORS + 1)
        )

        def point(name: str) -> tuple[float, float]:
            return (float(v[f"{name}_a"]), float(v[f"{name}_b"]))

        interpolation = InterpolationConfig(
            arc_pair=i("arc_pair"),
            arc_mode=i("arc_mode"),
            arc_start=point("arc_start"),
            arc_end=point("arc_end"),
            arc_center=point("arc_center"),
            arc_via=point("arc_via"),
            arc_counterclockwise=bool(i("arc_direction")),
            arc_speed_rpm=i("arc_speed"),
            line_pair=i("line_pair"),
            line_start=point("line_start"),
            line_end=point("line_end"),
            line_speed_rpm=i("line_speed"),
        )
        return StepperConfig(
            motors=motors,
            homing_order=tuple(i(f"homing_order_{k}") for k in range(1, MOTORS + 1)),
            system_mode=i("system_mode"),
            interpolation=interpolation,
            device_id=i("device_id"),
            baud_rate=i("baud_rate"),
        )

    def lead(self, motor: int) -> float:
        _check_motor(motor)
        return self.config.motors[motor - 1].lead

    def poll(self) -> StepperSnapshot:
        sequence = self._next_poll
        self._next_poll += 1
        read = self.poll_status(STAMP_REGISTER)
        v = read.values
        running = tuple(bool(v[motor_register(m, "running")]) for m in range(1, MOTORS + 1))
        coordinates = tuple(float(v[motor_register(m, "coordinate")]) for m in range(1, MOTORS + 1))
        self._note_wrong_pair(coordinates)
        self._note_running(sequence, running)
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
    def _write_values(self, values: Sequence[tuple[str, Value]], *, jog: bool = False) -> None:
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
            if motor is not None and not jog and self._configured_speed[motor] is not None:
                self._configured_speed[motor] = int(value)

    def _coil(self, name: str) -> None:
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
        _check_motor(motor)
        if action not in MOTOR_ACTIONS:
            raise CommandRejected(f"unknown motor action {action!r}; known: {MOTOR_ACTIONS}")
        if action == "stop":
            return self.stop_motors([motor])
        before = self._coordinates([motor]) if confirm else {}
        with self.jogs.lock:
            # The motion runs at the speed register: a jog's speed is undone first (the
            # service takes the motor over from any jog).
            self.restore_speeds([motor], include_jogging=True)
            try:
                self.io.write_coil(motor_coil(motor, action), True, Priority.COMMAND)
            finally:
                # A service overrides any jog: the next jog command is sent whole, and a 0
                # jog then stops the motor once (it may be running the service's motion).
                self.jogs.taken_over(motor, locked=False)
                self._direction[motor] = 0
        wrote = _motor_coils_text([motor], action)
        if not confirm:
            return f"wrote {wrote}"
        return self.confirm_started([motor], wrote, before)

    def _send_motor_stops(self, motors: Sequence[int]) -> LinkError | None:
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
                self.jogs.taken_over(motor, locked=True)
                self._direction[motor] = 0
            if error is None:
                self._restore_after_stop(list(motors))
        return error

    def stop_motors(self, motors: Sequence[int]) -> str:
        """Each motor's stop coil (all sent first), then their running flags read back
        until 0 (``confirm_stopped``). Raises the first LinkError, or NotConfirmed."""
        motors = list(dict.fromkeys(motors))
        for motor in motors:
            _check_motor(motor)
        error = self._send_motor_stops(motors)
        if error is not None:
            raise error
        return self.confirm_stopped(motors, _motor_coils_text(motors, "stop"))

    # ------------------------------------------------------------------ read-back
    def _running_flags(self, motors: Sequence[int]) -> dict[int, bool]:
        """The running flags (40168+) of ``motors``, read now at command priority."""
        names = {m: motor_register(m, "running") for m in motors}
        values = self.read_named(*names.values())
        return {m: bool(values[name]) for m, name in names.items()}

    def confirm_stopped(self, motors: Sequence[int], wrote: str) -> str:
        """The running flags of ``motors`` read until every one is 0, for STOP_CONFIRM_S:
        what was written and read, or ``NotConfirmed`` saying so."""
        deadline = time.monotonic() + STOP_CONFIRM_S
        while True:
            flags = self._running_flags(motors)
            still = [m for m in motors if flags[m]]
            if not still:
                return f"wrote {wrote}; read {_flags_text(motors, 0)}"
            if time.monotonic() >= deadline:
                raise NotConfirmed(
                    f"wrote {wrote}; read {_flags_text(still, 1)} {STOP_CONFIRM_S:g} s after"
                )
            time.sleep(CONFIRM_READ_PERIOD_S)

    def confirm_started(self, motors: Sequence[int], wrote: str, before: dict[int, float]) -> str:
        """A start shown: a running flag of ``motors`` reads 1, or a coordinate left its
        value ``before`` the start by a step (a short single run may end before the first
        read), within START_CONFIRM_S; else ``NotConfirmed`` with what was read."""
        deadline = time.monotonic() + START_CONFIRM_S
        while True:
            flags = self._running_flags(motors)
            on = [m for m in motors if flags[m]]
            if on:
                return f"wrote {wrote}; read {_flags_text(on, 1)}"
            now = self._coordinates(motors)
            moved = [m for m in motors if _units_differ(now[m], before[m])]
            if moved:
                return f"wrote {wrote}; read {_coordinates_text(moved, before, now)}"
            if time.monotonic() >= deadline:
                unchanged = ", ".join(
                    f"motor {m} coordinate ({register_label(motor_register(m, 'coordinate'))}) "
                    f"{now[m]:g}"
                    for m in motors
                )
                raise NotConfirmed(
                    f"wrote {wrote}; read {_flags_text(motors, 0)} and {unchanged} unchanged "
                    f"{START_CONFIRM_S:g} s after"
                )
            time.sleep(CONFIRM_READ_PERIOD_S)

    def _read_back(self, values: Sequence[tuple[str, Value]]) -> str:
        """The registers just written read back: "wrote X = 1, Y = 2 (read back)", or
        ``NotConfirmed`` with every value written and read (the cache takes what was
        read)."""
        read = self.read_named(*(name for name, _ in values))
        expected = {name: _as_read(STEPPER_MAP[name], value) for name, value in values}
        wrote = ", ".join(f"{_register_text(name)} = {v:g}" for name, v in expected.items())
        if all(read[name] == v for name, v in expected.items()):
            return f"wrote {wrote} (read back)"
        for name in expected:
            self._cache.note_written(name, read[name])
        seen = ", ".join(f"{_register_text(name)} = {read[name]:g}" for name in expected)
        raise NotConfirmed(f"wrote {wrote}; read {seen}")

    def set_motor_parameter(self, motor: int, field: str, value: float) -> None:
        """One basic parameter: FC 06 for a 16-bit one, FC 10 for lead / run distance.

        ``field`` is one of MOTOR_FIELD_NAMES, in the manual's units (degrees, Hz, rpm,
        user units; the device stores step angle, lead and distance x100).
        """
        _check_motor(motor)
        if field not in MOTOR_FIELD_NAMES:
            raise CommandRejected(f"unknown motor parameter {field!r}; known: {MOTOR_FIELD_NAMES}")
        _check_finite(field, value)
        reg = STEPPER_MAP[motor_register(motor, field)]
        if reg.scale == 1.0:
            _check_integer(field, value, low=0, high=U32_MAX)
            self._write_values([(reg.name, int(value))])
        else:
            self._write_values([(reg.name, float(value))])

    def set_run_distance(self, motor: int, distance: float) -> None:
        """Run distance (user units, x100, 32-bit low word first) with FC 10."""
        self.set_motor_parameter(motor, "run_distance", distance)

    def check_move_by(self, motor: int, distance: float) -> None:
        """A single run's motor and distance checked (no I/O)."""
        _check_motor(motor)
        _check_finite("distance", distance)
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
        self._write_values(values[:1])
        self._write_values(values[1:])
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
        _check_motor(motor)
        _check_finite("step angle", step_angle_deg)
        _check_finite("lead", lead)
        for what, value in (
            ("microstep", microstep),
            ("start frequency", start_frequency_hz),
            ("accel frequency", accel_frequency_hz),
            ("speed", speed_rpm),
        ):
            _check_integer(what, value)
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
        self._write_values(first)
        self._write_values(second)

    def set_speed(self, motor: int, rpm: int) -> str:
        """Speed register (40006+, rpm, "运行中可以调节": a running motion takes it at once).

        During a jog it becomes the configured speed the jog's end writes back."""
        _check_motor(motor)
        _check_integer("speed", rpm)
        values: list[tuple[str, Value]] = [(motor_register(motor, "speed"), int(rpm))]
        self._write_values(values)
        return self._read_back(values)

    def set_direction(self, motor: int, direction: int) -> None:
        """Single-run direction (40005+): 0 positive, 1 negative ("0 对应正方向,1 对应反方向")."""
        _check_motor(motor)
        _check_choice("direction", direction, (0, 1))
        self._write_values([(motor_register(motor, "direction"), int(direction))])

    def set_round_trips(self, motor: int, count: int) -> None:
        """Mode-1 round trips of ``motor`` (40301-40305), 0 = endless ("0表示无限次")."""
        _check_motor(motor)
        _check_integer("round trips", count)
        self._write_values([(motor_register(motor, "reciprocations"), int(count))])

    def set_limit_inputs(self, motor: int, positive: int, negative: int, home: int) -> None:
        """Which input (1-13, 0 none) is the motor's positive / negative limit and home."""
        _check_motor(motor)
        for what, value in (("positive limit", positive), ("negative limit", negative)):
            _check_integer(f"{what} input", value)
        _check_integer("home input", home)
        self._write_values(
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
            _check_motor(motor)
        if len(set(motors)) != len(motors):
            raise CommandRejected(f"motor listed twice in the homing order {list(motors)}")
        order = [int(m) for m in motors] + [0] * (MOTORS - len(motors))
        self._write_values([(f"homing_order_{k + 1}", m) for k, m in enumerate(order)])

    def set_system_mode(self, mode: int) -> None:
        _check_choice("system mode", mode, tuple(SYSTEM_MODES))
        self._write_values([("system_mode", int(mode))])

    # ------------------------------------------------------------------ jog
    def check_jog(self, motor: int, rpm: float) -> float:
        """A jog command's motor and speed; the speed rounded to the register's whole rpm."""
        _check_motor(motor)
        check_range("jog speed", rpm, -SPEED_MAX_RPM, SPEED_MAX_RPM, "rpm")
        return float(round(rpm))

    def jog(self, motor: int, rpm: float) -> bool:
        """Run at ``rpm`` (sign = direction) until told otherwise; True if anything was sent."""
        return self.jogs.command(
            motor,
            self.check_jog(motor, rpm),
            refuse_reason=f"motor {motor} was stopped: send a 0 jog before jogging it again",
        )

    def _jog_send(self, motor: int, rpm: float, _previous: float | None) -> None:
        """Speed (40006+, adjustable while running) and direction coil, as needed.

        A reversal, or a motor whose direction is unknown, gets the stop coil first.
        """
        speed, sign = round(abs(rpm)), (1 if rpm > 0 else -1)
        direction = self._direction[motor]
        try:
            if direction is None or direction == -sign:
                self.io.write_coil(motor_coil(motor, "stop"), True)
                self._direction[motor] = direction = 0
            # The speed register keeps its value across stops: write it only when the
            # value the cache holds (read from the device, or our own last write) differs.
            speed_register = motor_register(motor, "speed")
            if self._cache.values.get(speed_register) != speed:
                if self._configured_speed[motor] is None:
                    self._configured_speed[motor] = self._speed_before_jog(motor)
                self._write_values([(speed_register, speed)], jog=True)
            if direction != sign:
                self.io.write_coil(motor_coil(motor, "forward" if sign > 0 else "reverse"), True)
                self._direction[motor] = sign
        except LinkError:
            self._direction[motor] = None
            raise

    def _jog_stop_coil(self, motor: int) -> None:
        self.stream_stop(motor)

    def stream_stop(self, motor: int) -> str:
        """A stream's stop (a jog's 0, the deadman, a halt; the position stream's too):
        the motor's stop coil at stop priority, its running flag read back until 0
        (``NotConfirmed`` otherwise: the stream's stop stays pending and is sent again)."""
        self.io.write_coil(motor_coil(motor, "stop"), True, Priority.STOP)
        self._direction[motor] = 0
        return self.confirm_stopped([motor], _motor_coils_text([motor], "stop"))

    # ------------------------------------------------------------------ jog speed restore
    def _speed_before_jog(self, motor: int) -> int:
        """The configured speed, from the cache (or the device when the cache lacks it)."""
        name = motor_register(motor, "speed")
        value = self._cache.values.get(name)
        if value is None:
            value = self.read_named(name)[name]
        return int(value)

    def restore_pending(self) -> dict[int, int]:
        """Motors whose speed register may hold a jog's speed: motor -> configured rpm."""
        return {m: rpm for m, rpm in self._configured_speed.items() if rpm is not None}

    def restore_speeds(self, motors: Sequence[int], *, include_jogging: bool = False) -> None:
        """Write the configured speed back to each of ``motors`` whose jog changed it.

        A plain FC 06 of the speed register: it starts no motion ("运行中可以调节": it
        only sets the speed of a motion that runs). A motor still jogging is skipped
        unless ``include_jogging`` (a command is taking it over). Raises LinkError.
        """
        with self.jogs.lock:
            for motor in motors:
                rpm = self._configured_speed[motor]
                if rpm is None or (self.jogging(motor) and not include_jogging):
                    continue
                # Written even when the cache holds it: a jog's write that failed on the
                # link may still have landed (the cache follows acknowledged writes only).
                self._write_values([(motor_register(motor, "speed"), rpm)], jog=True)
                self._configured_speed[motor] = None
                self.speed_restore_failures.pop(motor, None)

    def _restore_after_stop(self, _stopped: Sequence[int]) -> None:
        """After stops (a jog's 0, the deadman, a stop service, the e-stop, shutdown):
        every motor no longer jogging gets its configured speed back, including retries of
        restores that failed before. A failure is recorded and reported, never raised: the
        stop itself was acknowledged."""
        for motor in sorted(self.restore_pending()):
            try:
                self.restore_speeds([motor])
            except LinkError as err:
                rpm = self._configured_speed[motor] or 0
                self.speed_restore_failures[motor] = f"{rpm} rpm not restored: {err}"
                self.on_speed_restore_failure(motor, rpm, err)
                if not isinstance(err, DeviceException):
                    break  # the link is failing: the rest stay pending, no more timeouts

    def jogging(self, motor: int) -> bool:
        """Running under a jog, or possibly so after a failed write (the deadman's cue)."""
        return self.jogs[motor].may_move

    def jog_locked(self, motor: int) -> bool:
        return self.jogs[motor].locked

    def jog_stop(self, motor: int) -> bool:
        """Send the motor's stop coil now and end its jog."""
        _check_motor(motor)
        return self.jogs.stop(motor)

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
        before = self._coordinates(every) if starts else {}
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
                self._coil(name)
            except LinkError:
                for motor in range(1, MOTORS + 1):
                    if name == "emergency_stop":
                        self.jogs.stop_failed(motor)  # each jog's own stop stays pending
                    elif takes_over:
                        self.jogs.taken_over(motor, locked=False)
                        self._direction[motor] = 0
                raise
            # The e-stop halts every jog and locks it; homing and return to zero take the
            # motors over, so the next jog command is sent whole.
            if takes_over:
                for motor in range(1, MOTORS + 1):
                    self.jogs.taken_over(motor, locked=name == "emergency_stop")
                    self._direction[motor] = 0
            if name == "emergency_stop":
                self.estops += 1  # a goal it ended says so (StepperMotion)
                self.interpolation_run = None  # "完成所有电机急停": the move ended
                self._restore_after_stop(list(range(1, MOTORS + 1)))
        wrote = f"{name.replace('_', ' ')} (coil {coil_label(coil(SYSTEM_COILS[name]))} = ON)"
        if name == "emergency_stop":
            return self.confirm_stopped(every, wrote)
        if starts:
            return self.confirm_started(every, wrote, before)
        if name == "return_to_zero" and confirm:
            return f"wrote {wrote}; every coordinate read 0 before it"
        return f"wrote {wrote}"

    def zero_coordinates(self, motors: Sequence[int]) -> dict[int, float]:
        """The "坐标清零" coil (00044; it names no motor: every coordinate), then the
        coordinates of ``motors`` read back (user units)."""
        self.system_command("zero_coordinates")
        return self._coordinates(motors)

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
            self._coil(name)
        finally:
            self._cache.refresh_soon()
        # Every parameter was replaced: no configured speed is left to restore.
        for motor in range(1, MOTORS + 1):
            self._configured_speed[motor] = None
        self.speed_restore_failures.clear()

    def set_output(self, output: int, on: bool) -> None:
        """Output 1-12: 0xFF00 to its ON coil, or to its OFF coil (00049-00072 in pairs)."""
        check_index("output", output, range(1, OUTPUTS + 1))
        self.io.write_coil(output_coil(output, bool(on)), True)

    def set_all_outputs(self, on: bool) -> None:
        self._coil("all_outputs_on" if on else "all_outputs_off")

    # ------------------------------------------------------------------ interpolation
    def check_line_move(
        self, pair: int, start: tuple[float, float], end: tuple[float, float], speed_rpm: int
    ) -> None:
        """A line's pair, points and speed checked (no I/O)."""
        self.pair_axes(pair)
        _check_integer("speed", speed_rpm, low=1)
        _check_points([("start", start), ("end", end)])
        if _same(start, end):
            raise CommandRejected("line start and end are the same point")
        self._check_no_interpolation_running()

    def check_arc_move(
        self,
        pair: int,
        mode: int,
        start: tuple[float, float],
        end: tuple[float, float],
        center: tuple[float, float],
        via: tuple[float, float],
        speed_rpm: int,
    ) -> None:
        """An arc's pair, mode, points and speed checked (no I/O)."""
        self.pair_axes(pair)
        _check_choice("arc mode", mode, (ARC_MODE_CENTER, ARC_MODE_THREE_POINTS))
        _check_integer("speed", speed_rpm, low=1)
        _check_points([("start", start), ("end", end), ("center", center), ("via", via)])
        third = center if mode == ARC_MODE_CENTER else via
        if _same(start, end) or _same(start, third) or _same(end, third):
            raise CommandRejected("an arc needs three different points (manual: 三点确定圆弧)")
        if mode == ARC_MODE_THREE_POINTS and _collinear(start, via, end):
            raise CommandRejected("start, via and end are on one line: no arc passes them")
        self._check_no_interpolation_running()

    def line_move(
        self,
        pair: int,
        start: tuple[float, float],
        end: tuple[float, float],
        speed_rpm: int,
        *,
        confirm: bool = True,
    ) -> str:
        """Line interpolation: 40202-40211 in one FC 10, then the start coil (00102)."""
        self.check_line_move(pair, start, end, speed_rpm)
        at_start = self._coordinates(self.pair_motors(pair))
        # The motors first run to the start each at its own speed (40202 note 2).
        self._restore_for_interpolation(pair)
        self._write_values(
            [
                ("line_pair", pair),
                ("line_start_a", float(start[0])),
                ("line_start_b", float(start[1])),
                ("line_end_a", float(end[0])),
                ("line_end_b", float(end[1])),
                ("line_speed", int(speed_rpm)),
            ]
        )
        return self._start_interpolation("line", pair, at_start, confirm)

    def arc_move(
        self,
        pair: int,
        mode: int,
        start: tuple[float, float],
        end: tuple[float, float],
        center: tuple[float, float],
        via: tuple[float, float],
        counterclockwise: bool,
        speed_rpm: int,
        *,
        confirm: bool = True,
    ) -> str:
        """Arc interpolation: 40182-40201 in one FC 10, then the start coil (00100).

        Mode 0 uses start, end and centre; mode 1 start, end and the middle point ``via``.
        The point the mode does not use is written as given (the device ignores it).
        """
        self.check_arc_move(pair, mode, start, end, center, via, speed_rpm)
        at_start = self._coordinates(self.pair_motors(pair))
        self._restore_for_interpolation(pair)
        self._write_values(
            [
                ("arc_pair", pair),
                ("arc_mode", mode),
                ("arc_start_a", float(start[0])),
                ("arc_start_b", float(start[1])),
                ("arc_end_a", float(end[0])),
                ("arc_end_b", float(end[1])),
                ("arc_center_a", float(center[0])),
                ("arc_center_b", float(center[1])),
                ("arc_via_a", float(via[0])),
                ("arc_via_b", float(via[1])),
                ("arc_direction", 1 if counterclockwise else 0),
                ("arc_speed", int(speed_rpm)),
            ]
        )
        return self._start_interpolation("arc", pair, at_start, confirm)

    def _restore_for_interpolation(self, pair: int) -> None:
        """The pair's motors (under either reading) that a jog left at its speed, unless
        still jogging, get their configured speed back before the approach runs."""
        motors = set(INTERPOLATION_PAIRS[pair]) | set(INTERPOLATION_PAIRS_POINT_ROWS[pair])
        self.restore_speeds(sorted(motors))

    def stop_interpolation(self) -> str:
        """Arc stop (00101) and line stop (00103), then the stop coil of each motor the
        line / arc may move (the bridge's run's, under either reading of its pair; every
        motor a pair can name when the bridge started none), every one tried even if
        one fails; then their running flags read back until 0 (issue 39 hole 7: a
        controller that kept running after the interpolation stops was reported
        stopped; stepper decision 23). Raises the first LinkError, or NotConfirmed."""
        run = self.interpolation_run
        motors = list(run.motors) if run is not None else list(INTERPOLATION_MOTORS)
        error: LinkError | None = None
        for name in ("arc_stop", "line_stop"):
            try:
                self._coil(name)
            except LinkError as err:
                error = error or err
        error = self._send_motor_stops(motors) or error
        if error is not None:
            raise error
        wrote = ", ".join(
            f"{name.replace('_', ' ')} (coil {coil_label(coil(SYSTEM_COILS[name]))} = ON)"
            for name in ("arc_stop", "line_stop")
        )
        said = self.confirm_stopped(motors, f"{wrote}, {_motor_coils_text(motors, 'stop')}")
        if self.interpolation_run is run:
            self.interpolation_run = None
        return said

    # ------------------------------------------------------------------ interpolation state
    def pair_axes(self, pair: int) -> tuple[int, int]:
        """The pair's (first, second) motor by the configured reading (``pair_axes``)."""
        return pair_axes(pair, self.pair_reading)

    def pair_motors(self, pair: int) -> tuple[int, ...]:
        """The pair's motors under either reading of the type (decision 11)."""
        return tuple(
            sorted(set(INTERPOLATION_PAIRS[pair]) | set(INTERPOLATION_PAIRS_POINT_ROWS[pair]))
        )

    def _coordinates(self, motors: Sequence[int]) -> dict[int, float]:
        """The coordinates of ``motors`` read now (user units)."""
        names = {m: motor_register(m, "coordinate") for m in motors}
        values = self.read_named(*names.values())
        return {m: float(values[name]) for m, name in names.items()}

    def _start_interpolation(
        self, kind: str, pair: int, at_start: dict[int, float], confirm: bool
    ) -> str:
        """The start coil; from then on (even when its reply is lost: it may have started)
        the move counts as running until a later poll shows its motors stopped. With
        ``confirm`` the start is read back (a motor of the pair runs or moved)."""
        name = f"{kind}_start"
        try:
            self._coil(name)
        finally:
            self.interpolation_run = InterpolationRun(
                kind,
                self.pair_motors(pair),
                self._next_poll,
                pair,
                self.pair_axes(pair),
                dict(at_start),
            )
        wrote = f"{kind} start (coil {coil_label(coil(SYSTEM_COILS[name]))} = ON)"
        if not confirm:
            return f"wrote {wrote}"
        return self.confirm_started(sorted(at_start), wrote, at_start)

    def _note_wrong_pair(self, coordinates: Sequence[float]) -> None:
        run = self.interpolation_run
        if run is None or run is self._wrong_pair_run:
            return
        wrong = run.wrong_motors(coordinates)
        if wrong:
            self._wrong_pair_run = run
            self._wrong_pair = _wrong_pair_text(run, wrong, coordinates, self.pair_reading)

    def take_wrong_pair(self) -> str | None:
        """Why the running line / arc must be stopped (a motor outside its configured pair
        moved), once; None when nothing is wrong."""
        why, self._wrong_pair = self._wrong_pair, None
        return why

    def wrong_pair_not_stopped(self) -> None:
        """The stop after ``take_wrong_pair`` failed: the next poll says so again."""
        self._wrong_pair_run = None

    def _note_running(self, sequence: int, running: tuple[bool, ...]) -> None:
        run = self.interpolation_run
        if (
            run is not None
            and sequence >= run.first_poll
            and not any(running[m - 1] for m in run.motors)
        ):
            self.interpolation_run = None

    def _check_no_interpolation_running(self) -> None:
        run = self.interpolation_run
        if run is not None:
            raise CommandRejected(
                f"a {run.kind} interpolation of motors "
                f"{'+'.join(map(str, run.motors))} is running (manual: 插补过程运行中不可调节): "
                "wait for it to end or call stop_interpolation"
            )


# ---------------------------------------------------------------- read-back texts


def _register_text(name: str) -> str:
    """ "motor 1 speed (40006)" for a motor's register, "line_pair (40202)" otherwise."""
    reg = STEPPER_MAP[name]
    what = reg.description if reg.name.startswith("motor") and reg.description else name
    return f"{what} ({register_label(name)})"


def _flags_text(motors: Sequence[int], value: int) -> str:
    return ", ".join(
        f"motor {m} running ({register_label(motor_register(m, 'running'))}) = {value}"
        for m in motors
    )


def _coordinates_text(
    motors: Sequence[int], before: dict[int, float], now: dict[int, float]
) -> str:
    return ", ".join(
        f"motor {m} coordinate ({register_label(motor_register(m, 'coordinate'))}) "
        f"{before[m]:g} -> {now[m]:g}"
        for m in motors
    )


def _units_differ(a: float, b: float) -> bool:
    """Two coordinates a step (0.01 unit) or more apart."""
    return round(a * DISTANCE_SCALE) != round(b * DISTANCE_SCALE)


# ---------------------------------------------------------------- checks


def _as_read(reg: Register, value: Value) -> Value:
    """The value a read of ``reg`` would decode to after writing ``value``."""
    return decode(reg, encode(reg, value))


def _check_contiguous(regs: Sequence[Register]) -> None:
    for before, after in itertools.pairwise(regs):
        if after.address != before.end:
            raise ValueError(f"{after.name} does not follow {before.name}")


def _check_motor(motor: int) -> None:
    check_index("motor", motor, range(1, MOTORS + 1))


def _check_pair(pair: int) -> None:
    if pair not in INTERPOLATION_PAIRS:
        raise CommandRejected(
            f"interpolation pair {pair!r} refused: 1 (motors 1+2), 2 (1+3) or 3 (2+3)"
        )


_check_choice = check_choice
_check_finite = check_finite


def _check_integer(what: str, value: float, low: int = 0, high: int = U16_MAX) -> None:
    check_whole_number(what, value, low, high)


def _check_points(points: Sequence[tuple[str, tuple[float, float]]]) -> None:
    for what, point in points:
        if len(point) != 2:
            raise CommandRejected(f"{what} needs 2 coordinates, got {len(point)}")
        for value in point:
            _check_finite(what, value)
            encode(STEPPER_MAP["line_start_a"], float(value))  # int32 x100 range


def _same(p: tuple[float, float], q: tuple[float, float]) -> bool:
    return all(
        round(a * DISTANCE_SCALE) == round(b * DISTANCE_SCALE) for a, b in zip(p, q, strict=True)
    )


def _collinear(p: tuple[float, float], q: tuple[float, float], r: tuple[float, float]) -> bool:
    cross = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
    scale = max(1.0, *(abs(v) for v in (*p, *q, *r)))
    return abs(cross) <= 1e-9 * scale * scale


# ---------------------------------------------------------------- action goals
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
            _check_motor(motor)
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
                f"read {_flags_text(self.motors, 0)} at every poll since",
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
        why = _wrong_pair_text(self.run, wrong, snapshot.coordinates, self.device.pair_reading)
        return Verdict(Outcome.HALTED, f"{self.what}: stopped, {why}")

    def ended(self, snapshot: StepperSnapshot) -> Verdict:
        verdict = super().ended(snapshot)
        moved = "+".join(map(str, self.run.moved(snapshot.coordinates))) or "none"
        return Verdict(
            verdict.outcome, f"{verdict.message}; motors moved: {moved} (coordinates read back)"
        )


def _wrong_pair_text(
    run: InterpolationRun, wrong: Sequence[int], coordinates: Sequence[float], reading: str
) -> str:
    """One line: which motor outside the configured pair moved, and what to do."""
    where = ", ".join(
        f"motor {m} {run.start_coordinates[m]:g} -> {coordinates[m - 1]:g}" for m in wrong
    )
    expected = "+".join(map(str, run.expected))
    return (
        f"a motor outside the pair moved ({where} units): interpolation_pair_reading "
        f"{reading} names motors {expected} for pair {run.pair}, the controller follows the "
        "other reading (docs/decisions/stepper.md hardware check)"
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


__all__ = [
    "DESTRUCTIVE_COMMANDS",
    "PAIR_READING_CHOICES",
    "PAIR_READING_UNSET",
    "SYSTEM_COILS",
    "SYSTEM_COMMANDS",
    "CoilMotion",
    "HomeMotion",
    "InterpolationConfig",
    "InterpolationMotion",
    "JointScale",
    "MotorConfig",
    "MoveByMotion",
    "StepperConfig",
    "StepperDevice",
    "StepperMotion",
    "StepperSnapshot",
]
