"""MOTEC β drive model: polls into snapshots, commands into checked writes. No ROS here.

Every command checks all of its inputs (and, where the drive's mode matters, the mode
read fresh from the drive) before its first write, so a refused command writes nothing.
Units are the drive's: encoder counts and rpm; ``DriveScale`` converts to SI. "MOTEC
decision N" is reading N of docs/decisions/motec.md.

Polling: 2 reads per drive every poll (0xAA-0xAF, 0xC5-0xC9), and the slow group's 2
(0x24-0x2D, 0x109) every ``slow_poll_period_s`` (MOTEC decision 20; see registers.py on
reading through unnamed parameters). The configuration (analog max speed 0x6D, lifeguard
0x112 / 0x114) is read whole when the link comes up, then one request per poll every
``config_refresh_s``, and the cache follows the bridge's own writes.

Commands that depend on the mode (``move``, ``enable``, ``stop``, the first velocity
command of a stream) read 0x24-0x29 first at command priority (one FC 03, ~3 ms at
115200 baud): the last poll may be older than a mode change the caller just made.

Velocity stream (``velocity``): rpm, sign = direction, written to 0xAE when it changes; a
command equal to the last one writes nothing. The first non-zero command of a stream
checks network mode, velocity control and enable. After ``stop`` the stream is locked
until a 0 command (or the node's deadman), so a joystick still held cannot restart the
motor. ``velocity_stop`` (the deadman) writes 0 rpm; the drive ramps down by its own
acceleration (§4.2).

Lifeguard (§3.4): ``arm_lifeguard(ms)`` writes 0x112 = ms then 0x114 = 9999 (the
manual's two FC 06 frames), ``disarm_lifeguard`` 0x112 = 0 then 0x114 = 0;
``feed_lifeguard`` rewrites 0x112 (at ``Priority.KEEPALIVE``, before commands and polls)
when no other write went to the drive for a feed period (also while the drive is marked
down), so the drive's watchdog only fires when the bridge is gone (or the bus is, for
longer than the lifeguard time less a feed period). ``lifeguard_min_ms`` is the shortest
lifeguard time a bus can keep fed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Hashable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from bridge_core.runtime.checks import (
    check_choice,
    check_converted,
    check_finite,
    check_index,
    check_range,
    check_whole_number,
)
from bridge_core.runtime.config_cache import ConfiguredDevice
from bridge_core.runtime.goals import Motion, Outcome, Verdict
from bridge_core.runtime.keepalive import FEED_WAKE_S
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, PollGroups
from bridge_core.runtime.reads import read_blocks
from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value, encode
from bridge_core.wire.errors import CommandRejected, LinkError, NotConfirmed, NotSent
from bridge_core.wire.planner import ReadRequest, plan_reads
from bridge_core.wire.registers import Register, Table

from .registers import (
    CONTROL_MODE_POSITION,
    CONTROL_MODE_VELOCITY,
    ENABLE_OFF,
    ENABLE_ON,
    INPUTS,
    LIFEGUARD_ACTIVE,
    LIFEGUARD_MODE_OFF,
    LIFEGUARD_OFF_MS,
    MOTEC_MAP,
    MOTION_ABSOLUTE,
    MOTION_RELATIVE,
    OPERATION_MODE_NETWORK,
    OUTPUT1_COIL_CHOICES,
    OUTPUT1_COIL_DEFAULT,
    OUTPUTS,
    PARAMETER_OWN_SERVICE,
    SAVE_TO_FLASH,
    START_MOVE,
    STOP_MOVE,
    control_mode_name,
    fault_text,
    operation_mode_name,
    output_coil,
    parameter_numbers,
    parameter_register,
)

DEFAULT_CONFIG_REFRESH_S = 5.0
# ~/read_parameter / ~/write_parameter: Pr.N is holding address N, one of 65536 (FC 03 /
# FC 06 carry a 16-bit address); an unlisted parameter is one 16-bit word.
PARAMETER_NUMBER_LIMIT = 0x10000
U16_LIMIT = 0xFFFF
I16_LIMIT = 0x8000
DEFAULT_MAX_SPEED_RPM = 3000
DEFAULT_VELOCITY_TIMEOUT_S = 0.5
VELOCITY_STREAM = 0  # the key of the drive's one cmd_velocity stream
SPEED_LIMIT_RPM = 32767  # 0xAE is a signed 16-bit register
LIFEGUARD_MIN_MS = 50  # below this a feed every third of it would crowd the bus
FEEDS_PER_PERIOD = 3  # the bridge writes at least 3 times per lifeguard time
# While a drive is marked down, within the lifeguard time since its last write, a feed is
# tried this often (each try holds the line for the short stop timeout): a line that
# answers again is found, and the drive fed, within about this (issue 39 hole 11).
DOWN_FEED_RETRY_S = 0.1
# A servo at rest dithers by a count or two and shows an rpm or two in 0xAF (MOTEC
# decision 17): |0xAF| within this band counts as standing still.
STANDSTILL_SPEED_RPM = 3
# ~/move_to's default time limit: the move's time at its speed limit times this margin,
# plus an allowance for the ramps (the manual gives no acceleration; decision 17).
MOVE_TIME_MARGIN = 2.0
MOVE_TIME_ALLOWANCE_S = 2.0
# A position stop (0x29 = 0) is verified on this many reads of 0xAA-0xAF, one poll period
# of the default 10 Hz apart (decision 18); unverified, the drive is released.
STOP_CHECK_READS = 2
STOP_CHECK_PERIOD_S = 0.1
# A move's start is confirmed when the motor is seen moving within this (read every
# START_CHECK_PERIOD_S), or 0x26 / 0x29 do not read what was written: "not confirmed".
# A target within MOVE_SEEN_COUNTS of where the motor is needs no motion to be seen.
START_CHECK_S = 0.5
START_CHECK_PERIOD_S = 0.02
START_CHECK_READS = round(START_CHECK_S / START_CHECK_PERIOD_S)
MOVE_SEEN_COUNTS = 10
# A stop that took (|0xAF| falling) must bring the drive into the standstill band within
# this (the manual gives no deceleration; decision 22); otherwise the drive is released.
STOP_SETTLE_S = 2.0
STOP_SETTLE_READS = round(STOP_SETTLE_S / STOP_CHECK_PERIOD_S)

CONFIG_NAMES = ("analog_max_speed", "lifeguard_time", "lifeguard_mode")
MODE_NAMES = ("operation_mode", "control_mode", "target_distance", "enable", "start")

# Rate groups (MOTEC decision 20). Fast, every poll: 0xAA-0xAF (joint_states, the
# moves' verdicts) and 0xC5-0xC9 (the fault code: a move ends FAULT at once; the inputs
# share the request). Slow: 0x24-0x2D (the modes, enable, start: host-written; a drive
# that drops enable on a lifeguard trip also raises its fault code, which is fast; every
# command that depends on a mode reads it at command priority) and 0x109 (the analog
# input: nothing the bridge decides reads it).
FAST_NAMES = (
    "position_setpoint",
    "position_actual",
    "speed_setpoint",
    "speed_actual",
    "input_word",
    "output_state",
    "fault_code",
)
SLOW_NAMES = (*MODE_NAMES, "motion_mode", "analog_input")
STATUS_NAMES = (*FAST_NAMES, *SLOW_NAMES)
STATUS_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(STATUS_NAMES))
FAST_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(FAST_NAMES))
SLOW_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(SLOW_NAMES))
CONFIG_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(CONFIG_NAMES))
MODE_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(MODE_NAMES))
OUTPUT_WORD_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(("output_word",)))
# A stop's check: 0xAA-0xAF in one read (the actual position and speed; decision 22).
MOTION_PLAN: list[ReadRequest] = plan_reads(
    MOTEC_MAP, MOTEC_MAP.select(("position_setpoint", "position_actual", "speed_actual"))
)
# After a broadcast: what each drive shows (0x28, 0x29, 0xAA, 0xAF).
BROADCAST_CHECK_NAMES = ("enable", "start", "position_setpoint", "speed_actual")
BROADCAST_CHECK_PLAN: list[ReadRequest] = plan_reads(
    MOTEC_MAP, MOTEC_MAP.select(BROADCAST_CHECK_NAMES)
)
# Before start_all: what ~/move checks (modes, the speed limit 0xAE) and the fault code.
START_CHECK_NAMES = (*MODE_NAMES, "position_setpoint", "speed_setpoint", "fault_code")
START_CHECK_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(START_CHECK_NAMES))
# joint_states is stamped with the read time of the block holding the actual position.
STAMP_REGISTER = "position_actual"


# ---------------------------------------------------------------- snapshots


@dataclass(frozen=True)
class Modes:
    """What decides whether the drive may move over Modbus (0x24, 0x25, 0x28)."""

    operation_mode: int
    control_mode: int
    enabled: bool

    @property
    def network(self) -> bool:
        return self.operation_mode == OPERATION_MODE_NETWORK

    def describe(self) -> str:
        return (
            f"operation mode {operation_mode_name(self.operation_mode)}, control mode "
            f"{control_mode_name(self.control_mode)}, {'enabled' if self.enabled else 'disabled'}"
        )


@dataclass(frozen=True)
class MotecConfig:
    analog_max_speed_rpm: int
    lifeguard_time_ms: int
    lifeguard_mode: int

    @property
    def lifeguard_armed(self) -> bool:
        """Taken as armed unless 0x112 reads 0: §3.4 arms it with a non-zero time and mode
        9999, and gives no other mode's meaning, so a drive with a time and any mode may
        be watching (MOTEC decision 9)."""
        return self.lifeguard_time_ms != LIFEGUARD_OFF_MS


@dataclass(frozen=True)
class MotecSnapshot:
    """One poll of one drive (drive units)."""

    read_time: float  # wall clock when 0xAA-0xAF were read
    slow_read_time: float  # wall clock when the slow group was read (modes, analog input)
    modes: Modes
    motion_mode: int
    target_distance: int  # counts, as last written
    start: int
    position_setpoint: int  # counts
    position_actual: int  # counts
    speed_setpoint_rpm: int
    speed_actual_rpm: int
    input_word: int
    output_word: int
    fault_code: int
    analog_input: int
    config: MotecConfig
    output1_coil: int = OUTPUT1_COIL_DEFAULT  # bit of OUTPUT1 in 0xC6 / 0x79 / FC 01
    # The IO tables (``read_io_tables``): 0x79, FC 01 and FC 02; None when not read.
    output_word_79: int | None = None
    coil_outputs: tuple[bool, ...] | None = None
    discrete_inputs: tuple[bool, ...] | None = None

    @property
    def fault_flag(self) -> int:
        """0xC8, the high word: §4.3 writes "0—无故障" / "1—有故障" beside it (decision 7)."""
        return self.fault_code >> 16

    @property
    def fault_detail(self) -> int:
        """0xC9, the low word: the manual gives none of its values."""
        return self.fault_code & 0xFFFF

    @property
    def inputs(self) -> tuple[bool, ...]:
        return tuple(bool(self.input_word >> k & 1) for k in range(INPUTS))

    @property
    def outputs(self) -> tuple[bool, ...]:
        return output_bits(self.output_word, self.output1_coil)

    @property
    def moving(self) -> bool:
        """Derived (the manual gives no motion flag's address): turning, or not yet at
        the setpoint (with no band: ``stands`` is the verdict a goal waits for)."""
        return self.speed_actual_rpm != 0 or self.position_setpoint != self.position_actual

    @property
    def turning(self) -> bool:
        """|0xAF| above the standstill band (a resting servo's dither is not motion)."""
        return abs(self.speed_actual_rpm) > STANDSTILL_SPEED_RPM

    def stands(self, tolerance_counts: int) -> bool:
        """At rest: |0xAF| within the standstill band and the actual position within
        ``tolerance_counts`` of the setpoint (decision 17)."""
        return (
            not self.turning
            and abs(self.position_setpoint - self.position_actual) <= tolerance_counts
        )


def output_bits(word: int, output1_coil: int) -> tuple[bool, ...]:
    """OUTPUT1-3 from an output word whose bit ``output1_coil`` is OUTPUT1 (decision 6)."""
    return tuple(bool(word >> (k + output1_coil) & 1) for k in range(OUTPUTS))


def read_modes(io: RegisterIO) -> Modes:
    """0x24-0x29 now, at command priority (one FC 03)."""
    v: dict[str, Value] = {}
    for request in MODE_PLAN:
        v.update(read_blocks(io, (request,), Priority.COMMAND)[0])
    return Modes(int(v["operation_mode"]), int(v["control_mode"]), bool(v["enable"]))


# ---------------------------------------------------------------- units


@dataclass(frozen=True)
class DriveScale:
    """Drive units <-> SI for one joint (docs/bridges/motec.md, ``joint_states``).

    ``counts_per_rev``: encoder counts per motor revolution; ``gear_ratio``: motor
    revolutions per joint revolution. rad = counts / (counts_per_rev x gear) x 2 pi;
    rad/s = rpm x 2 pi / 60 / gear.
    """

    counts_per_rev: float = 10000.0
    gear_ratio: float = 1.0

    def __post_init__(self) -> None:
        for what, value in (
            ("counts_per_rev", self.counts_per_rev),
            ("gear_ratio", self.gear_ratio),
        ):
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{what} must be positive and finite, got {value}")

    def position(self, counts: int) -> float:
        return counts / (self.counts_per_rev * self.gear_ratio) * 2.0 * math.pi

    def velocity(self, rpm: float) -> float:
        return rpm * 2.0 * math.pi / 60.0 / self.gear_ratio

    def to_counts(self, rad: float) -> int:
        check_finite("position", rad)
        kind = MOTEC_MAP["target_distance"].value_type
        counts = check_converted(
            f"position {rad:g} rad in counts",
            rad / (2.0 * math.pi) * self.counts_per_rev * self.gear_ratio,
            kind.raw_min,
            kind.raw_max,
        )
        return round(counts)

    def to_rpm(self, rad_s: float) -> float:
        check_finite("velocity", rad_s)
        return check_converted(
            f"velocity {rad_s:g} rad/s in rpm",
            rad_s * 60.0 / (2.0 * math.pi) * self.gear_ratio,
            -SPEED_LIMIT_RPM,
            SPEED_LIMIT_RPM,
        )


# ---------------------------------------------------------------- the device


class MotecDevice(ConfiguredDevice[MotecConfig]):
    """One MOTEC β drive behind one Modbus channel (one unit id on the shared bus)."""

    def __init__(
        self,
        io: RegisterIO,
        *,
        max_speed_rpm: int = DEFAULT_MAX_SPEED_RPM,
        config_refresh_s: float = DEFAULT_CONFIG_REFRESH_S,
        slow_period_s: float = SLOW_POLL_PERIOD_DEFAULT_S,
        velocity_timeout_s: float = DEFAULT_VELOCITY_TIMEOUT_S,
        output1_coil: int = OUTPUT1_COIL_DEFAULT,
        read_io_tables: bool = False,
        allow_unlisted_parameters: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if not 1 <= max_speed_rpm <= SPEED_LIMIT_RPM:
            raise ValueError(f"max_speed_rpm {max_speed_rpm} outside 1..{SPEED_LIMIT_RPM}")
        if output1_coil not in OUTPUT1_COIL_CHOICES:
            raise ValueError(f"output1_coil {output1_coil} not one of {OUTPUT1_COIL_CHOICES}")
        self.max_speed_rpm = max_speed_rpm
        self.output1_coil = output1_coil
        self.read_io_tables = read_io_tables
        self.allow_unlisted_parameters = allow_unlisted_parameters
        self._clock = clock
        self._sleep = sleep
        groups = PollGroups(FAST_PLAN, SLOW_PLAN, period_s=slow_period_s, clock=clock)
        super().__init__(io, MOTEC_MAP, CONFIG_PLAN, config_refresh_s, clock, groups=groups)
        self._io_tables: dict[str, Any] = {}  # read with the slow group (read_io_tables)
        # cmd_velocity: one stream (this drive). A 0 ends only the stream's own motion:
        # 0xAE is also a position move's speed limit (MOTEC decision 5).
        self.stream: StreamGuard[int] = StreamGuard(
            (VELOCITY_STREAM,),
            self._velocity_send,
            self._velocity_zero,
            timeout_s=velocity_timeout_s,
            stop_when_idle=False,
            clock=clock,
        )
        self.streams.append(self.stream)
        # clock() just before the request of the last successful write: the drive's
        # watchdog restarts when the request arrives, never before it was sent.
        self.last_write = -math.inf
        self.last_feed_try = -math.inf  # clock() before the last feed's request

    # ------------------------------------------------------------------ reads
    @property
    def config(self) -> MotecConfig:
        v = self.cached("drive")
        return MotecConfig(
            analog_max_speed_rpm=int(v["analog_max_speed"]),
            lifeguard_time_ms=int(v["lifeguard_time"]),
            lifeguard_mode=int(v["lifeguard_mode"]),
        )

    def read_modes(self) -> Modes:
        """0x24-0x29 now, at command priority (one FC 03)."""
        return read_modes(self.io)

    def read_outputs(self, priority: Priority = Priority.COMMAND) -> tuple[bool, ...]:
        """OUTPUT1-3 with FC 01 (§3.3.1), from coil ``output1_coil`` on."""
        bits = self.io.read_bits(self.output1_coil, OUTPUTS, Table.COIL, priority)
        return tuple(bool(b) for b in bits)

    def read_inputs(self, priority: Priority = Priority.COMMAND) -> tuple[bool, ...]:
        """INPUT1-8 with FC 02 (§3.3.2)."""
        bits = self.io.read_bits(0, INPUTS, Table.DISCRETE_INPUT, priority)
        return tuple(bool(b) for b in bits)

    def read_output_word_79(self, priority: Priority = Priority.COMMAND) -> int:
        """0x79, the second output word of §3.3.3 (FC 03)."""
        return int(read_blocks(self.io, OUTPUT_WORD_PLAN, priority)[0]["output_word"])

    def poll(self) -> MotecSnapshot:
        read = self.poll_status(STAMP_REGISTER)
        v = read.values
        if self.read_io_tables and (read.slow_refreshed or not self._io_tables):
            # 3 more reads (MOTEC decision 12), with the slow group: copies of
            # 0xC5 / 0xC6, which every poll reads. Empty until all three got through.
            self._io_tables = {}
            self._io_tables = {
                "output_word_79": self.read_output_word_79(Priority.POLL),
                "coil_outputs": self.read_outputs(Priority.POLL),
                "discrete_inputs": self.read_inputs(Priority.POLL),
            }
        return MotecSnapshot(
            read_time=read.read_time,
            slow_read_time=read.slow_read_time,
            modes=Modes(int(v["operation_mode"]), int(v["control_mode"]), bool(v["enable"])),
            motion_mode=int(v["motion_mode"]),
            target_distance=int(v["target_distance"]),
            start=int(v["start"]),
            position_setpoint=int(v["position_setpoint"]),
            position_actual=int(v["position_actual"]),
            speed_setpoint_rpm=int(v["speed_setpoint"]),
            speed_actual_rpm=int(v["speed_actual"]),
            input_word=int(v["input_word"]),
            output_word=int(v["output_state"]),
            fault_code=int(v["fault_code"]),
            analog_input=int(v["analog_input"]),
            config=self.config,
            output1_coil=self.output1_coil,
            **self._io_tables,
        )

    # ------------------------------------------------------------------ writes
    def _write(self, name: str, value: Value, priority: Priority = Priority.COMMAND) -> None:
        """One value: FC 06 for a 16-bit register, FC 16 for a 32-bit one (§3.1)."""
        reg = MOTEC_MAP[name]
        words = encode(reg, value)
        sent = self._clock()
        if len(words) == 1:
            self.io.write_register(reg.address, words[0], priority)
        else:
            self.io.write_registers(reg.address, words)
        self.last_write = max(self.last_write, sent)
        self._cache.note_written(name, value)

    def _check_speed(self, rpm: float, what: str) -> int:
        check_range(f"{what} (max_speed_rpm)", rpm, -self.max_speed_rpm, self.max_speed_rpm, "rpm")
        return round(rpm)

    def check_velocity(self, rpm: float) -> float:
        """A cmd_velocity value in rpm, rounded to the register's whole rpm."""
        return float(self._check_speed(rpm, "velocity"))

    def set_control_mode(self, mode: int) -> None:
        """Network mode (0x24 = 0), then the control mode (0x25), as §4.1 / §4.2 do.

        Refused while the motor turns (|0xAF| above the standstill band), read fresh at
        command priority: the last poll may be older than a move started since. Velocity:
        the speed setpoint is zeroed between the two, so that switching an enabled drive
        to velocity control never starts the motor with a stale speed. Read back after:
        ``NotConfirmed`` (what was written and read) unless 0x24 / 0x25 (and 0xAE) show it.
        """
        check_choice("control mode", mode, (CONTROL_MODE_VELOCITY, CONTROL_MODE_POSITION))
        speed = int(read_blocks(self.io, MOTION_PLAN, Priority.COMMAND)[0]["speed_actual"])
        if abs(speed) > STANDSTILL_SPEED_RPM:
            raise CommandRejected(f"the motor turns at {speed} rpm: ~/stop it before changing mode")
        self.stream.taken_over(VELOCITY_STREAM, locked=False)
        self._write("operation_mode", OPERATION_MODE_NETWORK)
        if mode == CONTROL_MODE_VELOCITY:
            self._write("speed_setpoint", 0)
        self._write("control_mode", mode)
        modes = self.read_modes()
        wrote = f"0x24 = {OPERATION_MODE_NETWORK}, 0x25 = {mode}"
        read = f"0x24 = {modes.operation_mode}, 0x25 = {modes.control_mode}"
        ok = modes.network and modes.control_mode == mode
        if mode == CONTROL_MODE_VELOCITY:
            held = int(self.read_named("speed_setpoint")["speed_setpoint"])
            wrote += ", 0xAE = 0"
            read += f", 0xAE = {held}"
            ok = ok and held == 0
        if not ok:
            raise NotConfirmed(f"sent, not confirmed: wrote {wrote}, read {read}")

    def enable(self, on: bool) -> None:
        """0x28 = 1 / 0 (§4.1 step 4), read back: ``NotConfirmed`` unless 0x28 shows it.
        Enabling in velocity control first zeroes 0xAE: §4.2 step 4 says enabling starts
        the motor at the set speed, and a bridge's enable must not start motion by
        itself."""
        if not on:
            with self.stream.lock:
                try:
                    self._write("enable", ENABLE_OFF)
                    self._enable_reads(ENABLE_OFF)
                except (LinkError, NotConfirmed):
                    self.stream.stop_failed(VELOCITY_STREAM)  # its own stop stays pending
                    raise
                self.stream.taken_over(VELOCITY_STREAM, locked=False)
            return
        modes = self.read_modes()
        if modes.control_mode == CONTROL_MODE_VELOCITY:
            self._write("speed_setpoint", 0)
            self.stream.taken_over(VELOCITY_STREAM, locked=False)
        self._write("enable", ENABLE_ON)
        self._enable_reads(ENABLE_ON)

    def _enable_reads(self, value: int) -> None:
        read = int(self.read_modes().enabled)
        if read != value:
            raise NotConfirmed(f"sent, not confirmed: wrote 0x28 = {value}, read 0x28 = {read}")

    def check_move(self, counts: int, speed_rpm: float) -> int:
        """A move's distance / target and speed limit checked (no I/O); the limit in rpm."""
        if isinstance(counts, bool) or not isinstance(counts, int):
            raise CommandRejected(f"distance {counts!r} is not a whole number of counts")
        encode(MOTEC_MAP["target_distance"], counts)  # range check before any write
        limit = self._check_speed(speed_rpm, "max velocity")
        if limit < 0:
            raise CommandRejected(f"max velocity {speed_rpm:g} rpm must not be negative")
        return limit

    def move(self, counts: int, *, relative: bool, speed_rpm: float = 0.0) -> None:
        """Point-to-point move (§4.1): [speed limit 0xAE], motion mode 0x2D, distance or
        target 0x26-0x27 (FC 16), start 0x29 = 1. Needs network mode, position control
        and an enabled drive (read fresh). Read back after (``_confirm_start``): a start
        not seen is ``NotConfirmed`` (what was written and read), and the move stopped."""
        limit = self.check_move(counts, speed_rpm)
        modes = self.read_modes()
        if not modes.network or modes.control_mode != CONTROL_MODE_POSITION or not modes.enabled:
            raise CommandRejected(
                f"a move needs network mode, position control and an enabled drive; the drive "
                f"is in {modes.describe()} (use ~/set_control_mode and ~/enable)"
            )
        if limit:
            self._write("speed_setpoint", limit)
        else:
            # 0: the drive's own speed limit. After a velocity session 0xAE holds that
            # session's last speed, often 0, and a move limited to 0 rpm never happens.
            held = int(self.read_named("speed_setpoint")["speed_setpoint"])
            if held <= 0:
                raise CommandRejected(
                    f"max velocity 0 keeps the drive's speed limit 0xAE, which is {held} rpm: "
                    f"the move could not run; give a max velocity > 0"
                )
        position = int(read_blocks(self.io, MOTION_PLAN, Priority.COMMAND)[0]["position_actual"])
        self._write("motion_mode", MOTION_RELATIVE if relative else MOTION_ABSOLUTE)
        self._write("target_distance", counts)
        self._write("start", START_MOVE)
        try:
            self._confirm_start(counts, (position + counts) if relative else counts, position)
        except NotConfirmed as err:
            # It may run to a target it had before, or start late: stopped, and said.
            try:
                stopped = self.stop_move()
            except (LinkError, NotConfirmed) as stop_err:
                stopped = f"its stop failed: {stop_err}"
            raise NotConfirmed(f"{err}; stopped: {stopped}") from None

    def _confirm_start(self, counts: int, target: int, position: int) -> None:
        """After 0x29 = 1: 0x26-0x27 and 0x29 must read what was written, and the motor
        must be seen moving (|0xAF| above the standstill band, or 0xAC more than
        ``MOVE_SEEN_COUNTS`` from where it was) within ``START_CHECK_S``, unless the
        target is within ``MOVE_SEEN_COUNTS`` of it (nothing to see). 0x29 may read 1
        from an earlier move, so it alone proves nothing (decision 15)."""
        v = read_blocks(self.io, MODE_PLAN, Priority.COMMAND)[0]
        wrote = f"0x26 = {counts}, 0x29 = 1"
        read = f"0x26 = {int(v['target_distance'])}, 0x29 = {int(v['start'])}"
        if int(v["target_distance"]) != counts or int(v["start"]) != START_MOVE:
            raise NotConfirmed(f"sent, not confirmed: wrote {wrote}, read {read}")
        if abs(target - position) <= MOVE_SEEN_COUNTS:
            return
        speed, now = 0, position
        for n in range(START_CHECK_READS):
            if n:
                self._sleep(START_CHECK_PERIOD_S)
            m = read_blocks(self.io, MOTION_PLAN, Priority.COMMAND)[0]
            speed, now = int(m["speed_actual"]), int(m["position_actual"])
            if abs(speed) > STANDSTILL_SPEED_RPM or abs(now - position) > MOVE_SEEN_COUNTS:
                return
        raise NotConfirmed(
            f"sent, not confirmed: wrote {wrote}, read {read} but the motor did not move "
            f"within {START_CHECK_S:g} s (0xAC {position} -> {now}, 0xAF {speed} rpm)"
        )

    def retarget(self, counts: int) -> None:
        """A newer absolute target for the move this bridge's position stream started
        (``joint_commands``): motion mode absolute, the target (0x26-0x27), 0x29 = 1 again;
        the drive turns towards it from where it is (MOTEC decision 21). 0x26-0x27 and
        0x29 are read back (one read): a drive that did not take the target would run on
        to the older one, so it is stopped and ``NotConfirmed`` says what was written and
        read (issue 39)."""
        encode(MOTEC_MAP["target_distance"], counts)  # range check before any write
        self._write("motion_mode", MOTION_ABSOLUTE)
        self._write("target_distance", counts)
        self._write("start", START_MOVE)
        v = read_blocks(self.io, MODE_PLAN, Priority.COMMAND)[0]
        if int(v["target_distance"]) == counts and int(v["start"]) == START_MOVE:
            return
        said = (
            f"sent, not confirmed: wrote 0x26 = {counts}, 0x29 = 1, read 0x26 = "
            f"{int(v['target_distance'])}, 0x29 = {int(v['start'])}"
        )
        try:
            stopped = self.stop_move()
        except (LinkError, NotConfirmed) as stop_err:
            stopped = f"its stop failed: {stop_err}"
        raise NotConfirmed(f"{said}; stopped: {stopped}")

    def stop(self) -> str:
        """Stop in the present mode, each verified until the drive stands (|0xAF| within
        the standstill band, decision 22): velocity -> 0xAE = 0 (ramps down, §4.2);
        position -> 0x29 = 0 (the move / stop register, ``stop_move``); any other mode ->
        release (0x28 = 0), the only stop the manual gives for every mode. A stop that
        does not take is followed by a release (``release_checked``). Returns what was
        done and seen; ``NotConfirmed`` when the drive is not seen standing."""
        with self.stream.lock:  # no cmd_velocity write between the stop and the lock
            try:
                modes = self.read_modes()
                if modes.network and modes.control_mode == CONTROL_MODE_VELOCITY:
                    done = self.velocity_stop_checked()
                elif modes.network and modes.control_mode == CONTROL_MODE_POSITION:
                    done = self.stop_move()
                else:
                    done = release_checked(
                        self.io,
                        self._write,
                        self._sleep,
                        f"{modes.describe()}: no Modbus stop for that mode",
                    )
            except (LinkError, NotConfirmed):
                self.stream.stop_failed(VELOCITY_STREAM)  # cmd_velocity's stop stays pending
                raise
            self.stream.taken_over(VELOCITY_STREAM, locked=True)
            return done

    def velocity_stop_checked(self) -> str:
        """0xAE = 0, then ``watch_stop`` (0xAE read back in the same reads): the motor
        ramps down by the drive's own acceleration (§4.2); released if it does not."""
        self._write("speed_setpoint", 0)
        try:
            held = int(self.read_named("speed_setpoint")["speed_setpoint"])
            watch = watch_stop(self.io, self._sleep)
            if watch.stands and held == 0:
                return f"speed setpoint 0 (0xAE reads 0; {watch.text()})"
            seen = f"0xAE reads {held}, {watch.text()}"
        except LinkError as err:
            seen = f"its effect could not be read: {err}"
        return release_checked(
            self.io, self._write, self._sleep, f"0xAE = 0 did not stop the motor ({seen})"
        )

    def stop_move(self) -> str:
        """0x29 = 0 at once (a goal's stop: it started a position move, so no mode read
        first; on a bad line that read could fail and keep the stop off the wire), then
        verified: "运动/停止寄存器" 0 = stop is our reading (decision 5), and a drive that
        takes 0x29 as a start trigger only would run on. The drive must stand (|0xAF|
        within the band, decision 22) or show its speed falling within
        ``STOP_CHECK_READS`` reads and stand within ``STOP_SETTLE_S``; otherwise it is
        released (0x28 = 0), and the text says so (decision 18). ``NotConfirmed`` when it
        is still not seen standing."""
        return verified_position_stop(self.io, self._write, self._sleep)

    def save_to_flash(self) -> None:
        self._write("save_to_flash", SAVE_TO_FLASH)

    def set_output(self, output: int, on: bool) -> None:
        """OUTPUT1-3 with FC 05 (§3.3.3): 0xFF00 on, 0x0000 off."""
        check_index("output", output, range(1, OUTPUTS + 1))
        sent = self._clock()
        self.io.write_coil(output_coil(output, self.output1_coil), bool(on))
        self.last_write = max(self.last_write, sent)

    def set_analog_max_speed(self, rpm: float) -> None:
        reg = MOTEC_MAP["analog_max_speed"]
        value = check_whole_number(
            "analog max speed (rpm)", rpm, reg.value_type.raw_min, reg.value_type.raw_max
        )
        self._write("analog_max_speed", value)

    # ------------------------------------------------------------------ parameters
    def read_parameter(self, number: int) -> int:
        """Pr.``number`` (address ``number``, §5.2) with FC 03; a named 32-bit one whole
        (§3.2), any other number as one unsigned 16-bit word (a read needs no range: a
        number past the drive's table answers exception 02, §2.7; decision 13)."""
        check_index("parameter number", number, range(PARAMETER_NUMBER_LIMIT))
        reg = parameter_register(number)
        if reg is None:
            second_word_of(number)  # the low word of a named 32-bit value: refused
            return int(self.io.read_registers(number, 1, Table.HOLDING, Priority.COMMAND)[0])
        return int(self.read_named(reg.name)[reg.name])

    def write_parameter(self, number: int, value: int) -> None:
        """Pr.``number`` = ``value`` (FC 06, or FC 16 high word first for a 32-bit one,
        §3.1), within the manual's range; refused before any write otherwise. A number the
        manual does not name only with ``allow_unlisted_parameters`` (FC 06, one word,
        0..65535 or -32768..-1 as its two's complement): its range is the drive's to
        check, which answers exception 03 for a value it does not take (§2.7, §3.1)."""
        check_index("parameter number", number, range(PARAMETER_NUMBER_LIMIT))
        reg = parameter_register(number)
        if reg is None:
            second_word_of(number)
            if not self.allow_unlisted_parameters:
                known_parameter(number)  # refused, with the list of known ones
            word = check_whole_number(f"Pr.{number} (unlisted)", value, -I16_LIMIT, U16_LIMIT)
            sent = self._clock()
            self.io.write_register(number, word & U16_LIMIT, Priority.COMMAND)
            self.last_write = max(self.last_write, sent)
            return
        what = f"Pr.{number} (0x{number:X}, {reg.name})"
        if not reg.access.writable:
            raise CommandRejected(f"{what} is read only (§3.2)")
        if reg.name in PARAMETER_OWN_SERVICE:
            raise CommandRejected(f"{what} is written by {PARAMETER_OWN_SERVICE[reg.name]}")
        low, high = int(reg.minimum or 0), int(reg.maximum or 0)
        self._write(reg.name, check_whole_number(what, value, low, high))

    # ------------------------------------------------------------------ velocity stream
    def velocity(self, rpm: float) -> bool:
        """Command ``rpm`` (0xAE) until told otherwise; True if anything was written."""
        return self.stream.command(
            VELOCITY_STREAM,
            self.check_velocity(rpm),
            refuse_reason="the drive was stopped: send 0 before commanding a velocity again",
        )

    def _velocity_send(self, _key: int, rpm: float, previous: float | None) -> None:
        if previous is None:
            # Starting (or the speed the drive holds is unknown): the drive must be able
            # to turn under 0xAE at all.
            modes = self.read_modes()
            if (
                not modes.network
                or modes.control_mode != CONTROL_MODE_VELOCITY
                or not modes.enabled
            ):
                raise CommandRejected(
                    f"velocity commands need network mode, velocity control and an enabled "
                    f"drive; the drive is in {modes.describe()}"
                )
        self._write("speed_setpoint", round(rpm))

    def _velocity_zero(self, _key: int) -> None:
        """The stream's stop (a 0 command, the deadman, a halt): 0xAE = 0, read back
        (``NotConfirmed`` unless it reads 0: the stop stays pending, the deadman tries
        again). The drive ramps down by its own acceleration (§4.2); ``~/stop`` also
        waits for it to stand."""
        self._write("speed_setpoint", 0)
        held = int(self.read_named("speed_setpoint")["speed_setpoint"])
        if held != 0:
            raise NotConfirmed(f"sent, not confirmed: wrote 0xAE = 0, read 0xAE = {held}")

    @property
    def streaming(self) -> bool:
        return self.stream[VELOCITY_STREAM].may_move

    @property
    def stream_locked(self) -> bool:
        return self.stream[VELOCITY_STREAM].locked

    @property
    def stream_rpm(self) -> int | None:
        value = self.stream[VELOCITY_STREAM].value
        return None if value is None else round(value)

    def velocity_stop(self) -> bool:
        """0 rpm now if the stream may be turning the motor (the deadman, shutdown)."""
        if not self.streaming:
            self.stream[VELOCITY_STREAM].locked = False
            return False
        return self.stream.stop(VELOCITY_STREAM)

    # ------------------------------------------------------------------ lifeguard
    def arm_lifeguard(self, time_ms: int) -> None:
        """§3.4: detection time 0x112 (ms), then mode 0x114 = 9999."""
        _check_lifeguard_ms(time_ms)
        self._write("lifeguard_time", int(time_ms))
        self._write("lifeguard_mode", LIFEGUARD_ACTIVE)

    def disarm_lifeguard(self) -> None:
        """0x112 = 0, then 0x114 = 0: §3.4 arms the drive "当Pr.274为非零值" and its own
        frame turns the watchdog off with 0x112 = 0; 0x114 = 0 is a value the manual never
        gives, written second only so that a re-arm needs both again (decision 9)."""
        self._write("lifeguard_time", LIFEGUARD_OFF_MS)
        self._write("lifeguard_mode", LIFEGUARD_MODE_OFF)

    def next_feed(self, time_ms: int, down: bool = False) -> float:
        """When the lifeguard needs its next write (``clock()`` time).

        Up: a feed period after the request of the last write of any kind (a feed that
        failed while the line was down does not delay it: once the line answers again the
        overdue feed goes at once, issue 39 hole 11). Down (``down``): the first try a
        feed period after the last write, then one every ``DOWN_FEED_RETRY_S`` until the
        lifeguard time since the last write is over (after it a real drive has tripped
        unless a try got through), then one per feed period."""
        period = lifeguard_feed_period_s(time_ms)
        first = self.last_write + period
        if not down or self.last_feed_try < first - period:
            return first
        trip = self.last_write + time_ms / 1000.0
        retry = DOWN_FEED_RETRY_S if self.last_feed_try + DOWN_FEED_RETRY_S < trip else period
        return max(first, self.last_feed_try + min(retry, period))

    def feed_lifeguard(self, time_ms: int, down: bool = False) -> bool:
        """Rewrite 0x112 if nothing was written to the drive for a feed period. Also while
        the drive is marked down (``down``: the caller sends it like a stop: one try, the
        short stop timeout), on ``next_feed``'s schedule, so a line that comes back within
        the lifeguard time finds the drive fed before it trips (docs/bridges/motec.md,
        "Lifeguard")."""
        if time_ms <= 0:
            return False
        if self._clock() < self.next_feed(time_ms, down):
            return False
        tried, self.last_feed_try = self.last_feed_try, self._clock()
        try:
            self._write("lifeguard_time", int(time_ms), Priority.KEEPALIVE)
        except NotSent:
            self.last_feed_try = tried  # nothing went out: due again at once
            raise
        return True


def move_time_limit_s(
    distance_counts: int, speed_rpm: float, counts_per_rev: float, margin: float
) -> float:
    """A move's default time limit: ``distance`` at ``speed_rpm`` (motor counts per
    revolution ``counts_per_rev``) times ``margin``, plus ``MOVE_TIME_ALLOWANCE_S`` for
    the ramps. A 0 rpm limit gives no limit (the move is refused anyway)."""
    if speed_rpm <= 0:
        return math.inf
    travel_s = distance_counts / counts_per_rev / (speed_rpm / 60.0)
    return travel_s * margin + MOVE_TIME_ALLOWANCE_S


def lifeguard_feed_period_s(time_ms: int) -> float:
    return time_ms / 1000.0 / FEEDS_PER_PERIOD


def lifeguard_min_ms(drives: int, hold_s: float) -> int:
    """The shortest lifeguard time the bridge can keep fed on a bus (docs/bridges/motec.md).

    A feed falls due ``time / FEEDS_PER_PERIOD`` after the request of the drive's last
    write (counted from the request, not the reply: the drive's watchdog may restart as
    early as the request reaches it), starts up to ``FEED_WAKE_S`` late, then waits for
    the line: for the transaction in progress and for the feeds of the other drives
    queued before it (feeds go first), each at most ``hold_s``
    (``SerialSettings.longest_hold_s``: silence, the longest frame, the reply timeout).
    The gap between two writes to a live drive stays within the time if
        time / 3 + FEED_WAKE_S + drives x hold_s <= time,
    i.e. time >= 1.5 x (FEED_WAKE_S + drives x hold_s) with 3 feeds per period. While
    the line is down the feeds go on with the short stop timeout (``next_feed``: every
    ``DOWN_FEED_RETRY_S`` within the lifeguard time), so a drive whose line answers x
    after its last write is fed before it trips when x + DOWN_FEED_RETRY_S +
    FEED_WAKE_S + hold_s < time (docs/bridges/motec.md, "Across line outages";
    bench/motec_blackout.py)."""
    gap_s = FEED_WAKE_S + drives * hold_s
    bound_ms = gap_s * FEEDS_PER_PERIOD / (FEEDS_PER_PERIOD - 1) * 1000.0
    return max(LIFEGUARD_MIN_MS, math.ceil(round(bound_ms, 6)))  # 90.00000000000001 is 90


def lifeguard_bound_text(drives: int, hold_s: float) -> str:
    """The formula of ``lifeguard_min_ms`` with this bus's numbers, for messages."""
    return (
        f"{FEEDS_PER_PERIOD / (FEEDS_PER_PERIOD - 1):g} x ({FEED_WAKE_S:g} s wake-up + "
        f"{drives} drive(s) x {hold_s:.3f} s, the longest transaction on this line: "
        f"silence, the longest frame, timeout_s)"
    )


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


def _drive_line(unit: int, v: Mapping[str, Value]) -> str:
    return (
        f"drive {unit}: 0x28 = {v['enable']}, 0x29 = {v['start']}, "
        f"0xAA = {v['position_setpoint']}, 0xAF = {v['speed_actual']} rpm"
    )


def disable_all(broadcast: RegisterIO, drives: Mapping[int, RegisterIO]) -> tuple[bool, str]:
    """Release every drive on the bus with one broadcast write (unit 0, §2.5): 0x28 = 0.

    No drive answers a broadcast, so each drive's 0x28 / 0x29 / 0xAA / 0xAF is read back
    after it; a drive still enabled (it missed the frame) gets its own 0x28 = 0 and is read
    again. True only when every drive reads 0x28 = 0 (decision 15); the text says, drive
    by drive, what was seen.
    """
    reg = MOTEC_MAP["enable"]
    broadcast.write_register(reg.address, encode(reg, ENABLE_OFF)[0])
    ok = True
    lines: list[str] = []
    for unit, io in drives.items():
        try:
            v = read_blocks(io, BROADCAST_CHECK_PLAN, Priority.COMMAND)[0]
            if int(v["enable"]) != ENABLE_OFF:
                io.write_register(reg.address, encode(reg, ENABLE_OFF)[0])
                v = read_blocks(io, BROADCAST_CHECK_PLAN, Priority.COMMAND)[0]
                note = " (missed the broadcast: released by a write of its own)"
            else:
                note = ""
        except LinkError as err:
            ok = False
            lines.append(f"drive {unit}: did not answer ({err}): its state is unknown")
            continue
        if int(v["enable"]) != ENABLE_OFF:
            ok = False
            note = " STILL ENABLED"
        lines.append(_drive_line(unit, v) + note)
    return ok, "; ".join(lines)


def _start_checked(drives: Mapping[int, RegisterIO], read_only: Iterable[int]) -> dict[int, int]:
    """``start_all``'s checks before it sends anything (refused: ``CommandRejected``,
    naming every drive that fails one); the setpoint 0xAA each drive had, by unit."""
    refused = [f"drive {u}'s node is read_only" for u in sorted(set(read_only) & set(drives))]
    before: dict[int, int] = {}
    for unit, io in drives.items():
        try:
            v = read_blocks(io, START_CHECK_PLAN, Priority.COMMAND)[0]
            before[unit] = int(v["position_setpoint"])
        except LinkError as err:
            raise CommandRejected(f"drive {unit} did not answer ({err}); nothing sent") from None
        modes = Modes(int(v["operation_mode"]), int(v["control_mode"]), bool(v["enable"]))
        if not (modes.network and modes.control_mode == CONTROL_MODE_POSITION and modes.enabled):
            refused.append(f"drive {unit} is in {modes.describe()}")
        if int(v["fault_code"]):
            refused.append(f"drive {unit} has fault {int(v['fault_code'])}")
        if int(v["speed_setpoint"]) <= 0:
            refused.append(
                f"drive {unit}'s speed limit 0xAE is {int(v['speed_setpoint'])} rpm (the move "
                "could not run)"
            )
    if refused:
        raise CommandRejected(
            "a synchronised start needs every drive in network mode, position control, "
            f"enabled, without a fault, with a speed limit 0xAE > 0 and writable; "
            f"{'; '.join(refused)}; nothing was sent"
        )
    return before


def _stop_the_started(
    drives: Mapping[int, RegisterIO], to_stop: Iterable[int], sleep: Callable[[float], None]
) -> list[str]:
    """A start not every drive took: the drives that took it, and those whose state is
    unknown (they may be running), stopped (``verified_position_stop``), a line each."""
    stops: list[str] = []
    for unit in to_stop:
        io = drives[unit]

        def write(name: str, value: Value, io: RegisterIO = io) -> None:
            r = MOTEC_MAP[name]
            io.write_register(r.address, encode(r, value)[0])

        try:
            stops.append(f"drive {unit}: {verified_position_stop(io, write, sleep)}")
        except NotConfirmed as err:
            stops.append(f"drive {unit}: stop not confirmed: {err}")
        except LinkError as err:
            stops.append(f"drive {unit}: stop failed: {err}")
    return stops


def start_all(
    broadcast: RegisterIO,
    drives: Mapping[int, RegisterIO],
    read_only: Iterable[int] = (),
    sleep: Callable[[float], None] = time.sleep,
) -> tuple[bool, str]:
    """A synchronised start (§4.1 step 6 "0x29 写 1" sent to unit 0, §2.5: "支持广播通信方式
    ... 不回应广播"): every drive starts the move it was given (0x26, 0x2D, 0xAE).

    Before: ``~/move``'s checks for every drive (network mode, position control, enabled,
    a speed limit 0xAE > 0), no fault code, and no drive whose node is ``read_only``;
    refused, nothing sent, otherwise. After (nothing answers a broadcast): every drive's
    0x28 / 0x29 / 0xAA / 0xAF read back. A drive took the start if its setpoint 0xAA moved
    since the check or |0xAF| is above the standstill band (0x29 may read 1 from an
    earlier move: it proves nothing). One that did not leaves a start that is not
    synchronised, so the drives that did are stopped (``verified_position_stop``) and the
    answer is False (decision 15); a zero-length move counts as not started. A drive whose
    read-back is lost is neither: its state is unknown, it may be running, so it is
    stopped too and the answer is False.
    """
    before = _start_checked(drives, read_only)
    reg = MOTEC_MAP["start"]
    broadcast.write_register(reg.address, encode(reg, START_MOVE)[0])
    seen: dict[int, Mapping[str, Value]] = {}
    unknown: dict[int, str] = {}
    for unit, io in drives.items():
        try:
            seen[unit] = read_blocks(io, BROADCAST_CHECK_PLAN, Priority.COMMAND)[0]
        except LinkError as err:
            unknown[unit] = str(err)
    missed = [
        u
        for u, v in seen.items()
        if int(v["position_setpoint"]) == before[u]
        and abs(int(v["speed_actual"])) <= STANDSTILL_SPEED_RPM
    ]
    lines = [
        f"drive {u}: not read back ({unknown[u]}): its state is unknown"
        if u in unknown
        else _drive_line(u, seen[u])
        for u in drives
    ]
    if not missed and not unknown:
        return True, "; ".join(lines)
    to_stop = [u for u in drives if u not in missed]
    stops = _stop_the_started(drives, to_stop, sleep)
    what = []
    if missed:
        what.append(f"drives {missed} did not take the start")
    if unknown:
        what.append(f"drives {sorted(unknown)} were not read back (they may be running)")
    return False, (
        f"{' and '.join(what)} ({'; '.join(lines)}); stopped the others: "
        f"{'; '.join(stops) or 'none had started'}"
    )


# ---------------------------------------------------------------- checks


def second_word_of(number: int) -> None:
    """Refuse Pr.``number`` if it is the low word of a named 32-bit parameter."""
    for other in MOTEC_MAP.in_table(Table.HOLDING):
        if number in other.addresses() and number != other.address:
            raise CommandRejected(
                f"Pr.{number} is the low word of the 32-bit Pr.{other.address} ({other.name}, "
                f"high word first, §3.1.2): give {other.address}"
            )


def known_parameter(number: int) -> Register:
    """The register of Pr.``number`` (a parameter the manual names), else refused."""
    reg = parameter_register(number)
    if reg is not None:
        return reg
    second_word_of(number)
    known = ", ".join(str(n) for n in parameter_numbers())
    raise CommandRejected(
        f"Pr.{number} is not a parameter the manual names, so its range is unknown (known: "
        f"{known}); the drive node's allow_unlisted_parameters lets ~/write_parameter send it "
        "anyway (the drive checks the value: exception 03)"
    )


def _check_lifeguard_ms(time_ms: int) -> None:
    reg = MOTEC_MAP["lifeguard_time"]
    if (
        isinstance(time_ms, bool)
        or not isinstance(time_ms, int)
        or not LIFEGUARD_MIN_MS <= time_ms <= (reg.maximum or 0)
    ):
        raise CommandRejected(
            f"lifeguard time {time_ms!r} ms outside {LIFEGUARD_MIN_MS}..{int(reg.maximum or 0)}"
        )


class MoveToMotion(Motion[MotecSnapshot]):
    """``~/move_to``: one point-to-point move followed through the polls (docs/actions.md). Over
    when the drive stands (``MotecSnapshot.stands``: |0xAF| within the standstill band, 0xAC
    within ``tolerance_counts`` of 0xAA) on two polls in a row: at the target within
    ``tolerance_counts`` it is REACHED, elsewhere STOPPED (a stop service, a disable, the
    drive); a fault code ends it at once. Its stop is ``~/stop``'s, verified.
    ``time_limit_margin`` > 0 (and no goal ``timeout_s``): the goal is stopped and TIMED_OUT
    after the move's time at its speed limit times the margin plus ``MOVE_TIME_ALLOWANCE_S``
    (decision 17)."""

    axes: frozenset[Hashable] = frozenset({"drive"})
    confirm_reached = True  # "stands" on two polls, REACHED too

    def __init__(
        self,
        device: MotecDevice,
        scale: DriveScale,
        position_rad: float,
        *,
        relative: bool,
        max_velocity_rad_s: float,
        tolerance_counts: int,
        time_limit_margin: float = 0.0,
    ) -> None:
        super().__init__()
        self.device = device
        self.scale = scale
        self.counts = scale.to_counts(position_rad)
        self.speed_rpm = scale.to_rpm(max_velocity_rad_s)
        device.check_move(self.counts, self.speed_rpm)
        self.relative = relative
        self.tolerance_counts = tolerance_counts
        self.time_limit_margin = time_limit_margin
        self.time_limit_s = math.inf  # set at the start (distance and speed known then)
        self.target = self.counts  # absolute; a relative move's is known at its start
        self.what = f"move_to {'by' if relative else 'to'} {position_rad:g} rad"

    def start(self) -> None:
        # Where the drive is now: a relative move's target, an absolute one's distance.
        position = int(self.device.read_named("position_actual")["position_actual"])
        if self.relative:
            self.target = position + self.counts
        if self.time_limit_margin > 0:
            rpm = self.speed_rpm or abs(
                int(self.device.read_named("speed_setpoint")["speed_setpoint"])
            )
            self.time_limit_s = move_time_limit_s(
                abs(self.target - position),
                rpm,
                self.scale.counts_per_rev,
                self.time_limit_margin,
            )
        # A relative goal is sent as the absolute target it computed: the drive counts a
        # relative move from its setpoint when 0x29 is written, which a move still under
        # way shifts after this read, and the goal would judge a target the drive never
        # had (MOTEC decision 19).
        self.device.move(self.target, relative=False, speed_rpm=self.speed_rpm)

    def stop(self) -> str:
        return self.device.stop_move()

    def running(self, snapshot: MotecSnapshot) -> bool:
        return not snapshot.stands(self.tolerance_counts)

    def default_timeout_s(self, node_default_s: float) -> float:
        """Its own limit from the distance and the speed (decision 17) is judged on the
        polls; the node's ``goal_timeout_s`` stays a backstop for when no poll comes (a
        device that refuses every poll but the link is up)."""
        return node_default_s

    def judge(self, snapshot: MotecSnapshot, since_start_s: float = math.inf) -> Verdict | None:
        if since_start_s != math.inf and since_start_s > self.time_limit_s:
            if (verdict := self.fault(snapshot)) is not None:
                return verdict
            return Verdict(
                Outcome.TIMED_OUT,
                f"{self.what}: not done within {self.time_limit_s:.3g} s, the default limit "
                f"(the move's time at {self.speed_rpm or 'the drive'}'s speed limit x "
                f"{self.time_limit_margin:g} + {MOVE_TIME_ALLOWANCE_S:g} s; goal timeout_s "
                "sets another, the node's move_time_margin 0 none)",
            )
        return super().judge(snapshot, since_start_s)

    def fault(self, snapshot: MotecSnapshot) -> Verdict | None:
        code = snapshot.fault_code
        if not code:
            return None
        text = fault_text(code)
        return Verdict(Outcome.FAULT, f"{self.what}: drive fault {code}: {text}", code, text)

    def ended(self, snapshot: MotecSnapshot) -> Verdict:
        short = self.target - snapshot.position_actual
        if abs(short) <= self.tolerance_counts:
            return Verdict(Outcome.REACHED, f"{self.what}: reached ({short} counts from target)")
        return Verdict(
            Outcome.STOPPED,
            f"{self.what}: the drive stopped {self.scale.position(short):.6g} rad "
            f"({short} counts) short of the target",
        )

    def feedback(self, snapshot: MotecSnapshot) -> dict[str, Any]:
        return {
            "position": self.scale.position(snapshot.position_actual),
            "velocity": self.scale.velocity(snapshot.speed_actual_rpm),
            "distance_to_go": self.scale.position(self.target - snapshot.position_actual),
        }

    def result(self, snapshot: MotecSnapshot | None) -> dict[str, Any]:
        position = math.nan if snapshot is None else self.scale.position(snapshot.position_actual)
        return {"position": position, "target_counts": self.target}


__all__ = [
    "CONFIG_PLAN",
    "MODE_PLAN",
    "STATUS_PLAN",
    "DriveScale",
    "Modes",
    "MotecConfig",
    "MotecDevice",
    "MotecSnapshot",
    "MoveToMotion",
    "disable_all",
    "lifeguard_bound_text",
    "lifeguard_feed_period_s",
    "lifeguard_min_ms",
    "move_time_limit_s",
    "start_all",
    "verified_position_stop",
]
