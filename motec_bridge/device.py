"""MOTEC β drive model: polls into snapshots, commands into checked writes. No ROS here.

Every command checks all of its inputs (and, where the drive's mode matters, the mode
read fresh from the drive) before its first write, so a refused command writes nothing.
Units are the drive's: encoder counts and rpm; ``DriveScale`` (units.py) converts to SI.
"MOTEC decision N" is reading N of docs/decisions/motec.md.

Around ``MotecDevice``: snapshots.py (what a poll reads: the plans, the snapshot),
stops.py (how a stop is verified), lifeguard.py (the watchdog's arithmetic),
parameters.py (which Pr.N may be read or written), broadcast.py (``disable_all`` /
``start_all``, every drive at once) and motions.py (``~/move_to``'s goal).

Commands that depend on the mode (``move``, ``enable``, ``stop``, the first velocity
command of a stream) read 0x24-0x29 first at command priority (one FC 03, ~3 ms at
115200 baud): the last poll may be older than a mode change the caller just made.

Velocity stream (``velocity``): rpm, sign = direction, written to 0xAE when it changes; a
command equal to the last one writes nothing. The first non-zero command of a stream
checks network mode, velocity control and enable. After ``stop`` the stream is locked
until a 0 command (or the node's deadman), so a joystick still held cannot restart the
motor. ``velocity_stop`` (the deadman) writes 0 rpm; the drive ramps down by its own
acceleration (§4.2).

Lifeguard (§3.4, lifeguard.py): ``arm_lifeguard`` / ``disarm_lifeguard`` write 0x112 and
0x114; ``feed_lifeguard`` rewrites 0x112 on ``next_feed``'s schedule.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from bridge_core.runtime.checks import (
    check_choice,
    check_index,
    check_range,
    check_whole_number,
)
from bridge_core.runtime.config_cache import ConfiguredDevice
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, PollGroups
from bridge_core.runtime.reads import read_blocks
from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value, encode
from bridge_core.wire.errors import CommandRejected, LinkError, NotConfirmed, NotSent
from bridge_core.wire.registers import Table

from .lifeguard import check_lifeguard_ms, next_feed_time
from .parameters import parameter_to_read, parameter_to_write
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
    SAVE_TO_FLASH,
    START_MOVE,
    output_coil,
)
from .snapshots import (
    CONFIG_PLAN,
    FAST_PLAN,
    MODE_PLAN,
    MOTION_PLAN,
    OUTPUT_WORD_PLAN,
    SLOW_PLAN,
    STAMP_REGISTER,
    STANDSTILL_SPEED_RPM,
    Modes,
    MotecConfig,
    MotecSnapshot,
    read_modes,
)
from .stops import release_checked, verified_position_stop, watch_stop
from .units import SPEED_LIMIT_RPM

DEFAULT_CONFIG_REFRESH_S = 5.0
DEFAULT_MAX_SPEED_RPM = 3000
DEFAULT_VELOCITY_TIMEOUT_S = 0.5
VELOCITY_STREAM = 0  # the key of the drive's one cmd_velocity stream
# A move's start is confirmed when the motor is seen moving within this (read every
# START_CHECK_PERIOD_S), or 0x26 / 0x29 do not read what was written: "not confirmed".
# A target within MOVE_SEEN_COUNTS of where the motor is needs no motion to be seen.
START_CHECK_S = 0.5
START_CHECK_PERIOD_S = 0.02
START_CHECK_READS = round(START_CHECK_S / START_CHECK_PERIOD_S)
MOVE_SEEN_COUNTS = 10


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
        read (MOTEC decision 21)."""
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
        (§3.2), any other number as one unsigned 16-bit word (``parameter_to_read``;
        decision 13)."""
        reg = parameter_to_read(number)
        if reg is None:
            return int(self.io.read_registers(number, 1, Table.HOLDING, Priority.COMMAND)[0])
        return int(self.read_named(reg.name)[reg.name])

    def write_parameter(self, number: int, value: int) -> None:
        """Pr.``number`` = ``value`` (FC 06, or FC 16 high word first for a 32-bit one,
        §3.1), checked by ``parameter_to_write`` before any write. A number the manual
        does not name only with ``allow_unlisted_parameters`` (FC 06, one word)."""
        reg, word = parameter_to_write(number, value, self.allow_unlisted_parameters)
        if reg is None:
            sent = self._clock()
            self.io.write_register(number, word, Priority.COMMAND)
            self.last_write = max(self.last_write, sent)
            return
        self._write(reg.name, word)

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
        check_lifeguard_ms(time_ms)
        self._write("lifeguard_time", int(time_ms))
        self._write("lifeguard_mode", LIFEGUARD_ACTIVE)

    def disarm_lifeguard(self) -> None:
        """0x112 = 0, then 0x114 = 0: §3.4 arms the drive "当Pr.274为非零值" and its own
        frame turns the watchdog off with 0x112 = 0; 0x114 = 0 is a value the manual never
        gives, written second only so that a re-arm needs both again (decision 9)."""
        self._write("lifeguard_time", LIFEGUARD_OFF_MS)
        self._write("lifeguard_mode", LIFEGUARD_MODE_OFF)

    def next_feed(self, time_ms: int, down: bool = False) -> float:
        """When the lifeguard needs its next write (``clock()`` time; ``next_feed_time``
        from this drive's last write and last feed try)."""
        return next_feed_time(time_ms, self.last_write, self.last_feed_try, down)

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
