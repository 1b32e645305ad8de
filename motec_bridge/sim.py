"""Simulator of MOTEC β drives on one RS-485 bus, on the shared simulator base.

Behaviour (the manual where it says something, the simulator's own choice where it is
silent; the choices are MOTEC decisions of docs/decisions/motec.md, and the simulator's
summary is in docs/bridges/motec.md):

- one serial server, several drives (unit ids 1-31); a unit id nobody owns gets no
  reply, a broadcast write (unit 0) is applied by every drive that is plugged in and
  answered by none (§2.4-2.6); ``unplug(unit)`` takes one drive off the bus (silent, not
  ticking: powered off or cable pulled) and ``plug(unit)`` puts it back;
- the parameter table is contiguous: every holding address 0x00-0x114 reads (unnamed
  ones as 0), anything beyond answers 0x02; writes are accepted only at the registers the
  map names writable (else 0x02), within their ranges (else 0x03); a request that cuts
  a 32-bit value in two answers 0x02; FC 04 / 15 answer 0x01 (§2.7). Coils and inputs are
  16 bits wide (OUTPUT1-3, INPUT1-8, the rest 0); FC 05 beyond OUTPUT3 answers 0x02;
- powers up in operation mode 1 (not network), position control, released, at position
  0, no fault; motion over Modbus needs network mode (§4): elsewhere the motor stays;
- position control: 0x29 = 1 starts a trapezoidal move (ramps at ``accel_rpm_s`` up to
  |0xAE| rpm) to setpoint + distance (0x2D = 0) or to the distance as a target (0x2D = 1);
  0x29 = 0 decelerates to a stop. With 0xAE = 0 the move is started and never gets
  anywhere (0x29 reads 1, the motor stands): the manual gives no other meaning for a 0
  speed limit. 0xAE holds ``move_speed_rpm`` at power-up (the manual gives no power-up
  value). Starting without network mode, position control and enable answers 0x03;
- velocity control: the speed ramps to 0xAE at ``accel_rpm_s`` (§4.2) while enabled;
- releasing (0x28 = 0) stops the motor at once (it coasts in reality); a fault stays
  latched until the drive is restarted (``power_cycle``): the manual gives no Modbus
  fault reset (§3.4 only "驱动器会报警并disable电机"), and a restart brings back "上电状态
  的参数" (§3.5): the values last saved to flash (0x35 = 1), the rest at power-up values,
  released, outputs off, position 0. Enabling while a fault is latched answers 0x03;
- lifeguard (§3.4): with 0x112 != 0 and 0x114 = 9999 in network mode, a drive that gets
  no write (any FC 05/06/16 to its unit id or to the broadcast id) for 0x112 ms latches
  fault ``lifeguard_fault_code`` (0xC8 = 1, the manual's "有故障", 0xC9 = 0) and
  releases the motor.
  Reads do not feed it (the strictest reading of "没有指令信号");
- ``inject_fault(code)`` latches any fault (and releases), ``set_input`` drives an
  input (0xC5 and FC 02 agree), ``set_analog`` the analog input 0x109; outputs switched
  by FC 05, or FC 06 at 0x79 / 0xC6 (low 3 bits), show in 0x79, 0xC6 and FC 01 alike;
- 0x35 = 1 counts a save to flash, is echoed ``00 01`` and reads 0 from the next tick
  (§3.5: the drive clears it when done); ``start_is_trigger`` makes 0x29 = 0 leave a
  move running (the other reading of 0x29); ``deaf_to_broadcast`` units miss broadcasts;
- ``setpoint_holds_target`` makes 0xAA read a move's target while it runs (the other
  reading of "位置设定值", MOTEC decision 22), not the position it tracks;
- replies after ``reply_delay_s`` (0 by default: the manual states none); the whole bus
  can withhold its replies (``withhold_replies``);
- personalities (docs/tools.md): ``--reply-delay-ms MIN[:MAX]`` and ``--ignore NAME,...``
  with the names of ``MotecSimDrive.IGNORABLE`` (a drive that acknowledges those writes
  and does nothing), and the other readings ``bridge_commission motec`` settles
  (``low_word_first``, ``unnamed_refused``, ``answer_past_table``,
  ``lifeguard_fault_code``, ``lifeguard_keeps_watching``, ``ignores_new_target``,
  ``rest_dither_counts``, ``power_up_armed``). The command line, ``motec_sim``, is
sim_cli.py's (``python -m motec_bridge.sim_cli``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.serving import TICK_S, Simulator
from bridge_core.sim.sim_base import (
    FUNCTION_TABLES,
    ILLEGAL_ADDRESS,
    ILLEGAL_VALUE,
    SimulatedDevice,
)
from bridge_core.wire.codec import decode
from bridge_core.wire.registers import Table

from .registers import (
    BIT_TABLE_WIDTH,
    CONTROL_MODE_POSITION,
    CONTROL_MODE_VELOCITY,
    DEFAULT_BAUDRATE,
    FAULT_NONE,
    FAULT_PRESENT,
    I16_MAX,
    INPUTS,
    LAST_PARAMETER,
    LIFEGUARD_ACTIVE,
    MOTEC_MAP,
    MOTION_ABSOLUTE,
    OPERATION_MODE_NETWORK,
    OUTPUTS,
    UNIT_IDS,
)

DEFAULT_COUNTS_PER_REV = 10000
DEFAULT_ACCEL_RPM_S = 6000.0
DEFAULT_MOVE_SPEED_RPM = 600.0
POWER_UP_OPERATION_MODE = 1  # anything but network: the user must select network mode
# §4.3 writes "0—无故障" and "1—有故障" beside "故障代码 0x00C8高位": during a fault 0xC8 reads 1
# (decision 7); the detail 0xC9 has no listed value and stays 0.
LIFEGUARD_FAULT_CODE = FAULT_PRESENT << 16
# A tick this late means the simulator's process was not scheduled (a loaded test
# machine): a write that reached the line meanwhile may still wait, unread, in the port's
# buffer, where a real drive would have taken it as it came. The lifeguard is judged at
# the next tick, after what arrived was read (a drive that was really not fed trips then).
STALLED_TICK_S = 0.1
OUTPUT_MASK = (1 << OUTPUTS) - 1
HOLDING_END = 0x10000  # one past the last holding address (``answer_past_table``)
I32_MIN, I32_MAX = -(1 << 31), (1 << 31) - 1
_WRITABLE_HOLDING = {
    address
    for reg in MOTEC_MAP.in_table(Table.HOLDING)
    if reg.access.writable
    for address in reg.addresses()
}
_OUTPUT_WORDS = ("output_word", "output_state")
# Parameters a save to flash keeps over a restart (§3.5): the writable ones that are
# settings, not commands (enable, start and the output words come back 0).
_SAVED = tuple(
    reg.name
    for reg in MOTEC_MAP.in_table(Table.HOLDING)
    if reg.access.writable and reg.name not in {"enable", "start", "save_to_flash", *_OUTPUT_WORDS}
)


@dataclass
class Move:
    """A position move in progress (counts); ``target`` None = decelerate to a stop."""

    target: float | None
    max_rpm: float


class MotecSimDrive(SimulatedDevice):
    """One MOTEC β drive: registers, motion, IO, lifeguard and faults."""

    # ``--ignore`` (docs/tools.md "Device personalities"): the motion writes a drive can be
    # told to acknowledge and not obey; ``write_names`` says which a write is.
    IGNORABLE: ClassVar[Mapping[str, str]] = {
        "enable": "0x28 = 1 (~/enable true)",
        "disable": "0x28 = 0 (~/enable false, a release, disable_all's broadcast)",
        "start": "0x29 = 1 (a position move's start: ~/move, ~/move_to, joint_commands "
        "targets, start_all's broadcast)",
        "stop": "0x29 = 0 (a position move's stop: ~/stop, a goal's end, the position "
        "stream's stop)",
        "speed": "0xAE != 0 (velocity setpoint, a move's speed limit)",
        "speed_zero": "0xAE = 0 (the velocity stop: ~/stop in velocity control, a 0 "
        "command, the deadman)",
        "target": "0x26-0x27 and 0x2D (a move's distance or target, relative or absolute)",
        "control_mode": "0x24 and 0x25 (network mode, velocity or position control)",
    }

    def __init__(
        self,
        unit_id: int = 1,
        *,
        counts_per_rev: int = DEFAULT_COUNTS_PER_REV,
        accel_rpm_s: float = DEFAULT_ACCEL_RPM_S,
        move_speed_rpm: float = DEFAULT_MOVE_SPEED_RPM,
        lifeguard_fault_code: int = LIFEGUARD_FAULT_CODE,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if unit_id not in UNIT_IDS:
            raise ValueError(f"unit id {unit_id} outside 1-31 (§1.1.2)")
        super().__init__(
            MOTEC_MAP,
            unit_id,
            extra_addresses={
                Table.HOLDING: range(0, LAST_PARAMETER + 1),
                Table.COIL: range(BIT_TABLE_WIDTH),
                Table.DISCRETE_INPUT: range(BIT_TABLE_WIDTH),
            },
        )
        self.counts_per_rev = counts_per_rev
        self.accel_rpm_s = accel_rpm_s
        self.move_speed_rpm = move_speed_rpm
        self.lifeguard_fault_code = lifeguard_fault_code
        self._clock = clock
        self.position = 0.0  # counts
        self.speed = 0.0  # rpm
        self.move: Move | None = None
        self.fault = FAULT_NONE
        self.outputs = 0
        self.forced_inputs = 0
        self.analog = 0
        self.saves = 0
        self.save_pending = False  # 0x35 = 1 written, cleared at the next tick (§3.5)
        # True: 0x29 = 0 does not stop a move (a drive that takes 0x29 as a start trigger
        # only, the other reading of "运动/停止寄存器", decision 18)
        self.start_is_trigger = False
        # True: 0xAA reads a running move's target, not the position it tracks (the other
        # reading of "当前电机的位置设定值", decision 22)
        self.setpoint_holds_target = False
        # Personalities of ``bridge_commission motec`` (main's options): the other readings
        # of decisions 2 (32-bit values low word first in every read), 3 (the unnamed
        # parameters answer 0x02) and 13 (addresses past the table read 0, no 0x02).
        self.low_word_first = False
        self.unnamed_refused = False
        self.answer_past_table = False
        # ... and of decisions 9 (once armed, the watchdog keeps its time until a restart,
        # whatever 0x112 / 0x114 are set to) and 17 (at rest, enabled, 0xAC reads this
        # many counts off the setpoint, alternately either side: a servo that dithers).
        self.lifeguard_keeps_watching = False
        # ... and of decision 21: 0x29 = 1 while a move runs is taken and ignored (the drive
        # runs on to the target it had).
        self.ignores_new_target = False
        self.rest_dither_counts = 0
        self._armed_ms = 0  # the time the watchdog was last armed with (0: never)
        self._dither_sign = 1
        self.lifeguard_trips = 0
        self.last_command = clock()
        self.write_guards.append(self._guard)
        self.write_hooks.append(self._on_write)
        with self.lock:
            self._power_up_values()
            # What 0x35 = 1 saved (§3.5): the writable parameters at power-up to begin with.
            self.flash = {name: self.value(name) for name in _SAVED}
            self._update_registers()

    def _power_up_values(self) -> None:
        for name in _SAVED:
            self.set(name, 0)
        self.set("operation_mode", POWER_UP_OPERATION_MODE)
        self.set("control_mode", CONTROL_MODE_POSITION)
        self.set("speed_setpoint", round(self.move_speed_rpm))

    def power_cycle(self) -> None:
        """Switch the drive off and on: the only recovery from a fault the manual allows
        (no reset register); parameters come back as last saved to flash (§3.5)."""
        with self.lock:
            self._power_up_values()
            for name, value in self.flash.items():
                self.set(name, value)
            self.set("enable", 0)
            self.set("start", 0)
            self.fault = FAULT_NONE
            self.position, self.speed, self.move = 0.0, 0.0, None
            self.outputs = 0
            self.last_command = self._clock()
            self._armed_ms = 0
            self._update_registers()

    # ------------------------------------------------------------ for tests / the CLI
    def power_up_armed(self, time_ms: int) -> None:
        """The lifeguard saved to flash armed (0x112 = ``time_ms``, 0x114 = 9999): it is
        so from now and after every restart."""
        with self.lock:
            for name, value in (("lifeguard_time", time_ms), ("lifeguard_mode", LIFEGUARD_ACTIVE)):
                self.flash[name] = value
                self.set(name, value)

    def inject_fault(self, code: int) -> None:
        """Latch fault ``code`` and release the motor, as a drive alarm does."""
        with self.lock:
            self._trip(code)
            self._update_registers()

    def set_input(self, number: int, on: bool) -> None:
        """Drive INPUT ``number`` (1-8) high or low."""
        if not 1 <= number <= INPUTS:
            raise ValueError(f"input {number} outside 1-{INPUTS}")
        with self.lock:
            bit = 1 << (number - 1)
            self.forced_inputs = self.forced_inputs | bit if on else self.forced_inputs & ~bit
            self._update_registers()

    def set_position(self, counts: float) -> None:
        """Put the motor at ``counts`` (as if turned by hand while released)."""
        with self.lock:
            self.position = float(counts)
            self._update_registers()

    def set_analog(self, raw: int) -> None:
        with self.lock:
            self.analog = raw
            self._update_registers()

    @property
    def enabled(self) -> bool:
        return bool(self.get("enable"))

    def value(self, name: str) -> int:
        value = self.get(name)
        assert isinstance(value, int)
        return value

    # ------------------------------------------------------------ Modbus behaviour
    def write_names(self, record: WriteRecord) -> frozenset[str]:
        """Which of ``IGNORABLE`` a write is (a register it covers whole, by its value)."""
        if record.table is not Table.HOLDING:
            return frozenset()
        end = record.address + len(record.values)
        names: set[str] = set()
        for reg in MOTEC_MAP.in_table(Table.HOLDING):
            if not (reg.address >= record.address and reg.end <= end):
                continue
            offset = reg.address - record.address
            value = decode(reg, list(record.values[offset : offset + reg.end - reg.address]))
            if reg.name == "enable":
                names.add("enable" if value else "disable")
            elif reg.name == "start":
                names.add("start" if value else "stop")
            elif reg.name == "speed_setpoint":
                names.add("speed" if value else "speed_zero")
            elif reg.name in ("target_distance", "motion_mode"):
                names.add("target")
            elif reg.name in ("operation_mode", "control_mode"):
                names.add("control_mode")
        return frozenset(names)

    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        """The base's read, played by the commissioning personalities (``__init__``)."""
        if FUNCTION_TABLES[function_code] is not Table.HOLDING:
            return super().read(function_code, address, count)
        addresses = range(address, address + count)
        if self.answer_past_table and address > LAST_PARAMETER and addresses.stop <= HOLDING_END:
            return [0] * count
        if self.unnamed_refused and any(
            self.map.owner_at(Table.HOLDING, a) is None for a in addresses
        ):
            return ILLEGAL_ADDRESS
        words = super().read(function_code, address, count)
        if not self.low_word_first or isinstance(words, int):
            return words
        for reg in MOTEC_MAP.in_table(Table.HOLDING):
            if reg.count == 2 and reg.address in addresses and reg.end <= addresses.stop:
                at = reg.address - address
                words[at], words[at + 1] = words[at + 1], words[at]
        return words

    def _guard(self, record: WriteRecord) -> int | None:
        end = record.address + len(record.values)
        if record.table is Table.COIL:
            return None if end <= OUTPUTS else ILLEGAL_ADDRESS
        if any(a not in _WRITABLE_HOLDING for a in range(record.address, end)):
            return ILLEGAL_ADDRESS  # an unnamed parameter: never written
        new: dict[str, int] = {}
        for reg in MOTEC_MAP.in_table(Table.HOLDING):
            if reg.address >= record.address and reg.end <= end:
                words = record.values[reg.address - record.address : reg.end - record.address]
                value = decode(reg, list(words))
                assert isinstance(value, int)
                if (reg.minimum is not None and value < reg.minimum) or (
                    reg.maximum is not None and value > reg.maximum
                ):
                    return ILLEGAL_VALUE
                new[reg.name] = value
        if new.get("enable") == 1 and self.fault != FAULT_NONE:
            return ILLEGAL_VALUE  # a latched fault: release (0x28 = 0) first
        if new.get("start") == 1 and not self._may_move(CONTROL_MODE_POSITION):
            return ILLEGAL_VALUE
        return None

    def _may_move(self, control_mode: int) -> bool:
        return (
            self.value("operation_mode") == OPERATION_MODE_NETWORK
            and self.value("control_mode") == control_mode
            and self.enabled
            and self.fault == FAULT_NONE
        )

    def _on_write(self, record: WriteRecord) -> None:
        self.last_command = self._clock()  # any accepted write feeds the lifeguard
        if record.table is Table.COIL:
            bit = 1 << record.address
            self.outputs = self.outputs | bit if record.values[0] else self.outputs & ~bit
            self._update_registers()
            return
        end = record.address + len(record.values)
        written = {
            reg.name
            for reg in MOTEC_MAP.in_table(Table.HOLDING)
            if reg.address >= record.address and reg.end <= end
        }
        if "enable" in written and not self.enabled:
            self.speed, self.move = 0.0, None  # a latched fault stays (power_cycle)
        if written & {"operation_mode", "control_mode"}:
            # A mode change ends any move: decelerate to a stop first.
            self.move = Move(None, 0.0) if self.speed else None
        if "start" in written:
            if self.value("start") == 1:
                if not (self.ignores_new_target and self.move is not None):
                    self._start_move()
            elif self.move is not None and not self.start_is_trigger:
                self.move = Move(None, 0.0) if self.speed else None
        if "save_to_flash" in written and self.value("save_to_flash") == 1:
            self.saves += 1
            self.flash = {name: self.value(name) for name in _SAVED}
            # Cleared "when done" (§3.5), not before the reply: the FC 06 reply echoes
            # the 00 01 written, as §3.5's frame prints it.
            self.save_pending = True
        for name in _OUTPUT_WORDS:
            if name in written:
                self.outputs = self.value(name) & OUTPUT_MASK
        if self.value("lifeguard_time") > 0 and self.value("lifeguard_mode") == LIFEGUARD_ACTIVE:
            self._armed_ms = self.value("lifeguard_time")
        self._update_registers()

    def _start_move(self) -> None:
        distance = float(self.value("target_distance"))
        if self.value("motion_mode") == MOTION_ABSOLUTE:
            target = distance
        else:
            target = self.position + distance
        self.move = Move(target, float(abs(self.value("speed_setpoint"))))

    def _trip(self, code: int) -> None:
        self.fault = code
        self.set("enable", 0)
        self.speed, self.move = 0.0, None

    # ------------------------------------------------------------ time
    def tick(self, dt: float) -> None:
        with self.lock:
            if self.save_pending:
                self.save_pending = False
                self.set("save_to_flash", 0)
            if dt <= STALLED_TICK_S:
                self._check_lifeguard()
            self._advance(dt)
            self._update_registers()

    def _check_lifeguard(self) -> None:
        time_ms = self.value("lifeguard_time")
        armed = time_ms > 0 and self.value("lifeguard_mode") == LIFEGUARD_ACTIVE
        if armed:
            self._armed_ms = time_ms
        elif self.lifeguard_keeps_watching and self._armed_ms:
            time_ms, armed = self._armed_ms, True
        if (
            armed
            and self.value("operation_mode") == OPERATION_MODE_NETWORK
            and self.fault == FAULT_NONE
            and self._clock() - self.last_command > time_ms / 1000.0
        ):
            self.lifeguard_trips += 1
            self._trip(self.lifeguard_fault_code)

    def _advance(self, dt: float) -> None:
        network = self.value("operation_mode") == OPERATION_MODE_NETWORK
        if not self.enabled or self.fault != FAULT_NONE or not network or dt <= 0:
            self.speed = 0.0
            return
        if self.move is not None:  # a move, or the deceleration after a stop / mode change
            self._advance_move(self.move, dt)
        elif self.value("control_mode") == CONTROL_MODE_VELOCITY:
            target = float(self.value("speed_setpoint"))
            accel = self.accel_rpm_s * dt
            self.speed += max(-accel, min(accel, target - self.speed))
            self.position += self.speed / 60.0 * self.counts_per_rev * dt
        else:
            self.speed = 0.0  # position control, no move: hold

    def _advance_move(self, move: Move, dt: float) -> None:
        """Trapezoid, computed online: never faster than the distance left allows."""
        counts_per_rpm_s = self.counts_per_rev / 60.0  # counts/s per rpm
        accel = self.accel_rpm_s * dt
        if move.target is None:
            desired = 0.0
        else:
            remaining = move.target - self.position
            a = self.accel_rpm_s * counts_per_rpm_s  # counts/s^2
            reachable = math.sqrt(2.0 * a * abs(remaining)) / counts_per_rpm_s  # rpm
            desired = math.copysign(min(move.max_rpm, reachable), remaining)
        self.speed += max(-accel, min(accel, desired - self.speed))
        before = self.position
        self.position += self.speed * counts_per_rpm_s * dt
        if move.target is None:
            if self.speed == 0.0:
                self.move = None
            return
        crossed = (before - move.target) * (self.position - move.target) <= 0
        if crossed or abs(move.target - self.position) < 0.5:
            self.position, self.speed, self.move = move.target, 0.0, None

    def _update_registers(self) -> None:
        position = max(I32_MIN, min(I32_MAX, round(self.position)))
        setpoint = position  # perfect tracking
        resting = self.move is None and self.value("control_mode") == CONTROL_MODE_POSITION
        if self.rest_dither_counts and self.enabled and resting:
            self._dither_sign = -self._dither_sign
            position = max(
                I32_MIN, min(I32_MAX, position + self._dither_sign * self.rest_dither_counts)
            )
        self.set("position_actual", position)
        if self.setpoint_holds_target and self.move is not None and self.move.target is not None:
            setpoint = max(I32_MIN, min(I32_MAX, round(self.move.target)))
        self.set("position_setpoint", setpoint)
        self.set("speed_actual", max(-I16_MAX, min(I16_MAX, round(self.speed))))
        self.set("fault_code", self.fault)
        self.set("input_word", self.forced_inputs)
        self.set("analog_input", self.analog)
        for name in _OUTPUT_WORDS:
            self.set(name, self.outputs)
        for n in range(1, OUTPUTS + 1):
            self.set(f"output_{n}", bool(self.outputs >> (n - 1) & 1))
        for n in range(1, INPUTS + 1):
            self.set(f"input_{n}", bool(self.forced_inputs >> (n - 1) & 1))


class MotecSimulator(Simulator):
    """Several drives on one serial server; drives can be unplugged and plugged back."""

    def __init__(self, drives: Sequence[MotecSimDrive], *, tick_s: float = TICK_S) -> None:
        super().__init__(drives, tick_s=tick_s)
        self.drives: dict[int, MotecSimDrive] = {d.unit_id: d for d in drives}
        self.unplugged: set[int] = set()

    def drive(self, unit_id: int) -> MotecSimDrive:
        return self.drives[unit_id]

    def unplug(self, unit_id: int) -> None:
        """The drive goes silent (and stops ticking) until ``plug``."""
        self.unplugged.add(unit_id)
        self._rebuild()

    def power_cycle(self, unit_id: int) -> None:
        """Restart drive ``unit_id`` (see ``MotecSimDrive.power_cycle``)."""
        self.drives[unit_id].power_cycle()

    def plug(self, unit_id: int) -> None:
        self.unplugged.discard(unit_id)
        self._rebuild()

    def _rebuild(self) -> None:
        # Rebinding (not mutating) the dict: the server and the tick loop read
        # ``devices`` from another thread; an iteration in progress keeps the old one.
        self.devices = {u: d for u, d in self.drives.items() if u not in self.unplugged}

    def start_serial(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUDRATE,
        parity: str = "N",
        stopbits: int = 1,
    ) -> None:
        super().start_serial(port, baudrate, parity, stopbits)


def make_simulator(
    unit_ids: Iterable[int] = (1,),
    *,
    reply_delay_s: float = 0.0,
    counts_per_rev: int = DEFAULT_COUNTS_PER_REV,
    accel_rpm_s: float = DEFAULT_ACCEL_RPM_S,
    move_speed_rpm: float = DEFAULT_MOVE_SPEED_RPM,
) -> MotecSimulator:
    ids = list(unit_ids)
    if len(set(ids)) != len(ids) or not ids:
        raise ValueError(f"unit ids {ids} must be distinct and not empty")
    sim = MotecSimulator(
        [
            MotecSimDrive(
                u,
                counts_per_rev=counts_per_rev,
                accel_rpm_s=accel_rpm_s,
                move_speed_rpm=move_speed_rpm,
            )
            for u in ids
        ]
    )
    sim.reply_delay_s = reply_delay_s
    return sim
