"""Simulator of the 5-axis stepper controller's Modbus RTU slave, on the shared base.

Behaviour (from the manual, plus what a test needs to see; "stepper decision N" is reading
N of docs/decisions/stepper.md):

- serves the §5 map: FC 03/05/06/10 only (others: exception 0x01), at most 49 registers
  per read or write and undefined rows (40051-40080, 40096-40107, ...) answer 0x02, as
  does a read that cuts a 32-bit value; a write is stored word by word, as the manual's own
  §6(3) example at address 9 needs; values outside the manual's ranges answer 0x03 (not the
  bridge's own non-zero minimums);
- replies after ``reply_delay_s`` (35 ms by default, §3; 0 for fast tests);
- each motor has a physical position; its coordinate (40108+) is that position minus an
  offset that "zero coordinates" and homing set. Forward / reverse run at the speed
  register's rpm x lead (units per second, read live: "运行中可以调节") until the stop
  coil, the e-stop or the limit input in that direction; a single run covers the run
  distance in the direction register's sense; home runs in reverse until the motor's
  home input is on, then its coordinate is 0 (unless ``zero_at_home`` is False: a
  controller that leaves it, stepper decision 20); "return to zero" runs each motor back to
  coordinate 0; "home all" homes the motors of 40177-40181 one after the other. Speed 0
  (or lead 0) does not run ("若速度为0则不运行");
- switches: each motor's home and negative limit switch is at physical 0, its positive
  limit at ``travel`` (500.00 units); an input is on when a switch assigned to it
  (40081-40095) is active, or when a test forces it (``set_input``). The simulator starts
  with the mode-1 layout (motor m: positive limit IN(2m-1), negative limit and home IN2m)
  and every motor 50.00 units from its home switch, coordinate 0;
- outputs: 0xFF00 to coil 00049+2(n-1) switches output n on, to 00050+2(n-1) off; all on
  / all off; the e-stop stops every motor, every interpolation and switches every output
  off;
- line and arc interpolation: the pair's motors (by the type rows, 40182 / 40202; a test
  sets ``pair_reading`` to "point_rows" to play a controller that follows the point rows,
  stepper decision 19) first run to the start point each at its own speed, then
  follow the line / arc at the interpolation speed (rpm x the first motor's lead); the stop
  coils end it;
- while a line or arc interpolation runs (approach included), a write to 40182-40211 or
  to a start coil (00100 / 00102) answers 0x03 and changes nothing (§5(1) 40201 / 40211
  "插补过程运行中不可调节"; stepper decision 14); the stop coils and the e-stop work;
- factory reset restores the simulator's defaults; clear-all ("数据清零: 清零所有参数")
  zeroes every parameter and sets the device id and baud rate to the manual's factory
  values, id 1 and 9600 ("出厂时默认设备 ID 为 1;通信波特率为 9600"; 0 is in neither
  register's range): from then on the simulator answers unit 1 only, so a request to
  another unit gets no reply, not even that clear-all coil's (stepper decision
  15). A device id written by FC 06 / 10 also takes effect at once. The baud rate is
  stored but the simulator keeps serving at its start baud (a pty has none); save counts.

The special modes 1-5 (input-driven motion, §5(3)) are stored but not simulated.

Personalities (docs/tools.md, "Device personalities"; ``bridge_core.sim.personality``):
``--reply-delay-ms MIN[:MAX]`` and ``--ignore NAME,...`` with the names of ``IGNORABLE``
(per motor: run, forward, reverse, home, stop, speed, direction, distance; system: estop,
to_zero, home_all, line_start, line_stop, arc_start, arc_stop). A motor's stop coil also
ends a line / arc that moves it (stepper decision 23). The other readings of the
decisions ``bridge_commission stepper`` settles (``sim_readings``): ``--word-order high``
(``high_word_first``), ``--answer-undefined``, ``--pair-reading point_rows``,
``--no-zero-at-home`` (``zero_at_home``); a late controller is ``--reply-delay-ms``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from bridge_core.sim.command_line import add_serial_arguments, serve_serial_until_signalled
from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.personality import add_delay_argument, add_ignore_argument
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import ILLEGAL_VALUE, SimulatedDevice
from bridge_core.wire.codec import decode
from bridge_core.wire.registers import Table

from . import sim_readings as readings
from .registers import (
    ARC_MODE_CENTER,
    BAUD_RATES,
    DEFAULT_BAUDRATE,
    INPUTS,
    INTERPOLATION_PAIRS,
    INTERPOLATION_PAIRS_POINT_ROWS,
    INTERPOLATION_REGISTERS,
    MOTOR_ACTIONS,
    MOTOR_COILS,
    MOTORS,
    OUTPUT_COIL_FIRST,
    OUTPUTS,
    REPLY_DELAY_S,
    STEPPER_MAP,
    SYSTEM_COILS,
    motor_register,
)
from .sim_interpolation import Interpolation, center_arc, three_point_arc

TRAVEL = 500.0  # physical position of each positive limit switch, user units
START_POSITION = 50.0  # physical position at power-on (coordinate 0)
FACTORY: dict[str, float] = {
    "step_angle": 1.8,
    "microstep": 8,
    "start_frequency": 200,
    "accel_frequency": 800,
    "direction": 0,
    "speed": 60,
    "lead": 5.0,
    "run_distance": 10.0,
}
# What clear-all leaves in the link settings (stepper decision 15): the manual's
# factory values, the only ones a zeroed controller can have (0 is out of both ranges).
CLEARED_DEVICE_ID = 1  # "出厂时默认设备 ID 为 1"
CLEARED_BAUD_RATE = DEFAULT_BAUDRATE  # "通信波特率为 9600"
# 40182-40211 and the two start coils: refused while an interpolation runs.
_INTERPOLATION_ADDRESSES = range(
    STEPPER_MAP[INTERPOLATION_REGISTERS[0]].address,
    STEPPER_MAP[INTERPOLATION_REGISTERS[-1]].end,
)
_START_COILS = frozenset(STEPPER_MAP[name].address for name in ("arc_start", "line_start"))
_COIL_NAMES = {STEPPER_MAP[name].address: name for name in SYSTEM_COILS}
# Personality (``--ignore``): the motion writes a controller may acknowledge and not obey.
# Per-motor names cover every motor's coil or register alike.
IGNORABLE_MOTOR_COILS = {
    "run": "run_once",
    "forward": "forward",
    "reverse": "reverse",
    "home": "home",
    "stop": "stop",
}
IGNORABLE_MOTOR_REGISTERS = {"speed": "speed", "direction": "direction", "distance": "run_distance"}
IGNORABLE_SYSTEM_COILS = {
    "estop": "emergency_stop",
    "to_zero": "return_to_zero",
    "home_all": "home_all",
    "line_start": "line_start",
    "line_stop": "line_stop",
    "arc_start": "arc_start",
    "arc_stop": "arc_stop",
}
IGNORABLE: dict[str, str] = {
    "run": "each motor's single-run coil (00001, 00006, ...)",
    "forward": "each motor's forward coil (00002, 00007, ...)",
    "reverse": "each motor's reverse coil (00003, 00008, ...)",
    "home": "each motor's home coil (00004, 00009, ...)",
    "stop": "each motor's stop coil (00005, 00010, ...)",
    "speed": "a write to a motor's speed register (40006, 40016, ...)",
    "direction": "a write to a motor's direction register (40005, 40015, ...)",
    "distance": "a write to a motor's run distance (40009-40010, 40019-40020, ...)",
    "estop": "the system e-stop coil (00042)",
    "to_zero": "the return-to-zero coil (00045)",
    "home_all": "the home-all coil (00046)",
    "line_start": "the line interpolation start coil (00102)",
    "line_stop": "the line interpolation stop coil (00103)",
    "arc_start": "the arc interpolation start coil (00100)",
    "arc_stop": "the arc interpolation stop coil (00101)",
}
_IGNORABLE_COILS: dict[int, str] = {
    **{
        STEPPER_MAP[motor_register(m, action)].address: name
        for m in range(1, MOTORS + 1)
        for name, action in IGNORABLE_MOTOR_COILS.items()
    },
    **{STEPPER_MAP[coil].address: name for name, coil in IGNORABLE_SYSTEM_COILS.items()},
}
_IGNORABLE_REGISTERS: dict[int, str] = {
    address: name
    for m in range(1, MOTORS + 1)
    for name, field_name in IGNORABLE_MOTOR_REGISTERS.items()
    for address in STEPPER_MAP[motor_register(m, field_name)].addresses()
}
_OUTPUT_COILS = range(OUTPUT_COIL_FIRST - 1, OUTPUT_COIL_FIRST - 1 + 2 * OUTPUTS)
READ_HOLDING = 0x03


@dataclass
class Motion:
    """What one motor is doing: 'forward', 'reverse', 'single', 'home' or 'to_coordinate'."""

    kind: str
    target: float = 0.0  # physical position for 'single' / 'to_coordinate'


# Non-zero minimums the bridge sets for its own unit arithmetic (step angle, microstep,
# lead), not ranges the manual states: the device takes 0 (the §6(3) example writes 0 to
# 40011 under the table's reading), so the simulator does too.
_BRIDGE_ONLY_MINIMUMS = ("_step_angle", "_microstep", "_lead")


class StepperSimDevice(SimulatedDevice):
    IGNORABLE = IGNORABLE

    def __init__(self, unit_id: int = 1, travel: float = TRAVEL) -> None:
        # Writes are stored word by word (the manual's own §6(3) FC 10 example cuts two
        # 32-bit values: stepper decision 2); reads must still take whole values.
        super().__init__(STEPPER_MAP, unit_id, whole_value_writes=False)
        self.travel = travel
        self.position = {m: START_POSITION for m in range(1, MOTORS + 1)}
        self.offset = {m: START_POSITION for m in range(1, MOTORS + 1)}
        self.motion: dict[int, Motion | None] = {m: None for m in range(1, MOTORS + 1)}
        self.interpolation: Interpolation | None = None
        self.homing_queue: list[int] = []
        self.forced_inputs: set[int] = set()
        self.saves = 0
        # Which reading of pair types 2 and 3 this controller follows: "type_rows" (1+3,
        # 2+3) or "point_rows" (2+3, 1+3).
        self.pair_reading = "type_rows"
        # Whether homing sets the coordinate to 0 at the home switch (the manual does not
        # say; stepper decision 20): False plays a controller that leaves it.
        self.zero_at_home = True
        # A controller that answers a read of undefined rows (40118-40123, ...) with zeros
        # instead of 0x02 (stepper decisions 7, 21's other reading; ``--answer-undefined``).
        self.answer_undefined = False
        # 32-bit values read high word first (decision 1's other reading; reads only).
        self.high_word_first = False
        # Told (old id, new id) when the device id changes, so the server answers the new
        # unit only (make_simulator re-keys its units).
        self.on_unit_id_change: Callable[[int, int], None] = lambda _old, _new: None
        self.write_guards.append(self._guard)
        self.write_hooks.append(self._on_write)
        self.factory_defaults()
        self._update_status()

    # ------------------------------------------------------------ state for tests
    def factory_defaults(self) -> None:
        with self.lock:
            for m in range(1, MOTORS + 1):
                for name, value in FACTORY.items():
                    self.set(motor_register(m, name), value)
                self.set(motor_register(m, "positive_limit_input"), 2 * m - 1)
                self.set(motor_register(m, "negative_limit_input"), 2 * m)
                self.set(motor_register(m, "home_input"), 2 * m)
                self.set(motor_register(m, "reciprocations"), 0)
                self.set(f"homing_order_{m}", 0)
            self.set("system_mode", 0)
            self.set("device_id", self.unit_id)
            self.set("baud_rate", DEFAULT_BAUDRATE)

    def coordinate(self, motor: int) -> float:
        with self.lock:
            return self.position[motor] - self.offset[motor]

    def set_input(self, number: int, on: bool) -> None:
        """Force input 1-13 on (or release it) as a wired switch would."""
        with self.lock:
            if on:
                self.forced_inputs.add(number)
            else:
                self.forced_inputs.discard(number)
            self._update_status()

    def input_on(self, number: int) -> bool:
        if number == 0:
            return False
        if number in self.forced_inputs:
            return True
        for m in range(1, MOTORS + 1):
            p = self.position[m]
            if p <= 0.0 and number in (self._assigned(m, "negative"), self._assigned(m, "home")):
                return True
            if p >= self.travel and number == self._assigned(m, "positive"):
                return True
        return False

    def _assigned(self, motor: int, which: str) -> int:
        field_name = "home_input" if which == "home" else f"{which}_limit_input"
        return int(self.get(motor_register(motor, field_name)))

    def _speed(self, motor: int, rpm: float | None = None) -> float:
        """User units per second at ``rpm`` (default: the motor's speed register)."""
        rpm = float(self.get(motor_register(motor, "speed"))) if rpm is None else rpm
        return rpm / 60.0 * float(self.get(motor_register(motor, "lead")))

    # ------------------------------------------------------------ Modbus behaviour
    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        """The other readings of decisions 1, 7 and 21 (``sim_readings``): 32-bit values
        high word first, undefined rows answered with zeros (each read logged as any)."""
        result = super().read(function_code, address, count)
        if function_code != READ_HOLDING:
            return result
        if isinstance(result, int):
            if (
                self.answer_undefined
                and count <= self.limits.max_read_registers
                and readings.undefined(self.map, address, count)
            ):
                return [0] * count
            return result
        return (
            readings.high_word_first(self.map, address, result) if self.high_word_first else result
        )

    def write_names(self, record: WriteRecord) -> frozenset[str]:
        """Which of ``IGNORABLE`` a write is: a motion coil written ON, or a write that
        covers a motor's speed, direction or run distance (all of it is then ignored)."""
        if record.table is Table.COIL:
            name = _IGNORABLE_COILS.get(record.address)
            return frozenset({name}) if name is not None and record.values[0] else frozenset()
        if record.table is not Table.HOLDING:
            return frozenset()
        addresses = range(record.address, record.address + len(record.values))
        return frozenset(_IGNORABLE_REGISTERS[a] for a in addresses if a in _IGNORABLE_REGISTERS)

    def _guard(self, record: WriteRecord) -> int | None:
        """Values outside the manual's ranges: ILLEGAL DATA VALUE. (Function codes the
        controller lacks never get here: the server refuses them, ``strict_decoder``.)"""
        end = record.address + len(record.values)
        if self.interpolation is not None and (
            (record.table is Table.COIL and record.address in _START_COILS and record.values[0])
            or (
                record.table is Table.HOLDING
                and record.address < _INTERPOLATION_ADDRESSES.stop
                and end > _INTERPOLATION_ADDRESSES.start
            )
        ):
            return ILLEGAL_VALUE  # "插补过程运行中不可调节"
        if record.table is not Table.HOLDING:
            return None
        seen: set[str] = set()
        for address in range(record.address, end):
            reg = self.map.owner_at(Table.HOLDING, address)
            if reg is None or reg.name in seen:
                continue
            seen.add(reg.name)
            # The value as it would stand after the write: a write may cut a 32-bit value
            # (the §6(3) example does), the rest keeps what the device holds.
            words = [
                record.values[a - record.address]
                if record.address <= a < end
                else self.words[(Table.HOLDING, a)]
                for a in reg.addresses()
            ]
            value = decode(reg, words)
            assert isinstance(value, int | float)
            minimum = None if reg.name.endswith(_BRIDGE_ONLY_MINIMUMS) else reg.minimum
            if (minimum is not None and value < minimum) or (
                reg.maximum is not None and value > reg.maximum
            ):
                return ILLEGAL_VALUE
            if reg.name == "baud_rate" and value not in BAUD_RATES:
                return ILLEGAL_VALUE
        return None

    def _on_write(self, record: WriteRecord) -> None:
        if record.table is Table.HOLDING:
            self._apply_device_id()
            return
        if not record.values[0]:
            return  # 0x0000 to a command coil does nothing
        address = record.address
        if address < MOTORS * MOTOR_COILS:
            motor, k = divmod(address, MOTOR_COILS)
            self._motor_command(motor + 1, MOTOR_ACTIONS[k])
        elif address in _OUTPUT_COILS:
            output, off = divmod(address - (OUTPUT_COIL_FIRST - 1), 2)
            self.set(f"output_{output + 1}", 0 if off else 1)
        elif address in _COIL_NAMES:
            self._system_command(_COIL_NAMES[address])
        self._update_status()

    def _motor_command(self, motor: int, action: str) -> None:
        if action == "stop":
            self.motion[motor] = None
            if motor in self.homing_queue:
                self.homing_queue.clear()
            if self.interpolation is not None and motor in self.interpolation.motors:
                # "电机 1 急停": the motor stops, and with it the line / arc it was part of
                # (stepper decision 23).
                self.interpolation = None
            return
        if self._speed(motor) <= 0:
            return  # speed 0: "若速度为0则不运行"
        if action in ("forward", "reverse", "home"):
            self.motion[motor] = Motion(action)
        elif action == "run_once":
            distance = float(self.get(motor_register(motor, "run_distance")))
            sign = -1.0 if int(self.get(motor_register(motor, "direction"))) else 1.0
            self.motion[motor] = Motion("single", self.position[motor] + sign * distance)

    def _system_command(self, name: str) -> None:
        if name == "emergency_stop":
            self._stop_all()
            for n in range(1, OUTPUTS + 1):
                self.set(f"output_{n}", 0)
        elif name == "zero_coordinates":
            for m in range(1, MOTORS + 1):
                self.offset[m] = self.position[m]
        elif name == "return_to_zero":
            for m in range(1, MOTORS + 1):
                if self._speed(m) > 0 and self.coordinate(m) != 0:
                    self.motion[m] = Motion("to_coordinate", self.offset[m])
        elif name == "home_all":
            order = [int(self.get(f"homing_order_{k}")) for k in range(1, MOTORS + 1)]
            self.homing_queue = [m for m in order if m]
            self._next_homing()
        elif name == "factory_reset":
            self._stop_all()
            self.factory_defaults()
        elif name == "save_parameters":
            self.saves += 1
        elif name == "clear_all_parameters":
            self._stop_all()
            for reg in self.map.in_table(Table.HOLDING):
                if reg.access.writable:
                    self.set_words(Table.HOLDING, reg.address, [0] * reg.count)
            self.set("device_id", CLEARED_DEVICE_ID)
            self.set("baud_rate", CLEARED_BAUD_RATE)
            self._apply_device_id()
        elif name in ("all_outputs_on", "all_outputs_off"):
            for n in range(1, OUTPUTS + 1):
                self.set(f"output_{n}", 1 if name == "all_outputs_on" else 0)
        elif name in ("arc_start", "line_start"):
            self._start_interpolation(name.split("_")[0])
        elif (
            name in ("arc_stop", "line_stop")
            and self.interpolation
            and self.interpolation.kind == name.split("_")[0]
        ):
            self.interpolation = None

    def _apply_device_id(self) -> None:
        """The device id register takes effect at once: answer the new unit only."""
        new = int(self.get("device_id"))
        if new != self.unit_id:
            old, self.unit_id = self.unit_id, new
            self.on_unit_id_change(old, new)

    def _stop_all(self) -> None:
        for m in range(1, MOTORS + 1):
            self.motion[m] = None
        self.interpolation = None
        self.homing_queue.clear()

    def _next_homing(self) -> None:
        while self.homing_queue:
            motor = self.homing_queue[0]
            if self._speed(motor) > 0:
                self.motion[motor] = Motion("home")
                return
            self.homing_queue.pop(0)

    def _start_interpolation(self, kind: str) -> None:
        prefix = kind
        pair = int(self.get(f"{prefix}_pair"))
        if pair not in INTERPOLATION_PAIRS:
            return
        pairs = INTERPOLATION_PAIRS_POINT_ROWS if self.pair_reading == "point_rows" else None
        a, b = (pairs or INTERPOLATION_PAIRS)[pair]

        def point(name: str) -> tuple[float, float]:
            return (float(self.get(f"{name}_a")), float(self.get(f"{name}_b")))

        start, end = point(f"{prefix}_start"), point(f"{prefix}_end")
        rpm = float(self.get(f"{prefix}_speed"))
        if rpm <= 0:
            return
        job = Interpolation(kind, (a, b), start, end, rpm)
        if kind == "line":
            job.length = math.dist(start, end)
        else:
            if int(self.get("arc_mode")) == ARC_MODE_CENTER:
                arc = center_arc(
                    start, end, point("arc_center"), bool(int(self.get("arc_direction")))
                )
            else:
                found = three_point_arc(start, point("arc_via"), end)
                if found is None:
                    return
                arc = found
            job.center, job.sweep = arc
            job.length = abs(job.sweep) * math.dist(job.center, start)
        for m in job.motors:
            self.motion[m] = None
        self.interpolation = job

    # ------------------------------------------------------------ time
    def tick(self, dt: float) -> None:
        with self.lock:
            for m in range(1, MOTORS + 1):
                self._move_motor(m, dt)
            if self.interpolation is not None:
                self._move_interpolation(self.interpolation, dt)
            self._update_status()

    def _blocked(self, motor: int, direction: float) -> bool:
        """Whether the limit input in ``direction`` stops the motor."""
        which = "positive" if direction > 0 else "negative"
        return self.input_on(self._assigned(motor, which))

    def _move_motor(self, m: int, dt: float) -> None:
        motion = self.motion[m]
        if motion is None:
            return
        v = self._speed(m)
        p = self.position[m]
        if motion.kind == "forward":
            direction, target = 1.0, math.inf
        elif motion.kind in ("reverse", "home"):
            direction, target = -1.0, -math.inf
        else:
            if motion.target == p:
                self._finish(m)
                return
            direction, target = (1.0 if motion.target > p else -1.0), motion.target
        if motion.kind == "home" and self.input_on(self._assigned(m, "home")):
            if self.zero_at_home:
                self.offset[m] = p  # at the home switch: the coordinate is 0
            self._finish(m)
            return
        if self._blocked(m, direction):
            self._finish(m)
            return
        step = direction * v * dt
        new = p + step
        if (direction > 0 and new >= target) or (direction < 0 and new <= target):
            new = target
        # Switches are at 0 and travel: stop on them rather than beyond.
        if p > 0.0 >= new and direction < 0:
            new = 0.0
        if p < self.travel <= new and direction > 0:
            new = self.travel
        self.position[m] = new
        if new == target:
            self._finish(m)

    def _finish(self, m: int) -> None:
        motion = self.motion[m]
        was_homing = motion is not None and motion.kind == "home"
        self.motion[m] = None
        if was_homing and self.homing_queue and self.homing_queue[0] == m:
            self.homing_queue.pop(0)
            self._next_homing()

    def _move_interpolation(self, job: Interpolation, dt: float) -> None:
        a, b = job.motors
        if job.phase == "approach":
            arrived = True
            for m, goal in ((a, job.start[0]), (b, job.start[1])):
                target = goal + self.offset[m]
                p = self.position[m]
                if abs(target - p) > 1e-9:
                    step = self._speed(m) * dt
                    self.position[m] = (
                        target if abs(target - p) <= step else p + math.copysign(step, target - p)
                    )
                    arrived = arrived and self.position[m] == target
            if arrived:
                job.phase = "path"
            return
        previous = (self.position[a], self.position[b])
        job.travelled = min(job.length, job.travelled + self._speed(a, job.rpm) * dt)
        fraction = job.travelled / job.length if job.length > 0 else 1.0
        point = job.point_at(fraction)
        for m, value, before in zip((a, b), point, previous, strict=True):
            new = value + self.offset[m]
            if new != before and self._blocked(m, new - before):
                self.interpolation = None
                return
            self.position[m] = new
        if fraction >= 1.0:
            self.interpolation = None

    def _update_status(self) -> None:
        moving_by_interpolation = set(self.interpolation.motors) if self.interpolation else set()
        for m in range(1, MOTORS + 1):
            self.set(motor_register(m, "coordinate"), round(self.coordinate(m), 2))
            running = self.motion[m] is not None or m in moving_by_interpolation
            self.set(motor_register(m, "running"), 1 if running else 0)
        for n in range(1, INPUTS + 1):
            self.set(f"input_{n}", 1 if self.input_on(n) else 0)


def make_simulator(
    unit_id: int = 1, reply_delay_s: float = REPLY_DELAY_S, travel: float = TRAVEL
) -> Simulator:
    return make_bus_simulator([unit_id], reply_delay_s, travel)


def make_bus_simulator(
    unit_ids: Sequence[int], reply_delay_s: float = REPLY_DELAY_S, travel: float = TRAVEL
) -> Simulator:
    """Controllers on one RS-485 line (40212 "主-从模式的多机通信"), one per unit id."""
    devices = [StepperSimDevice(unit, travel) for unit in unit_ids]
    sim = Simulator(devices)
    sim.reply_delay_s = reply_delay_s

    def rekey(old: int, new: int) -> None:
        sim.devices = {new if uid == old else uid: d for uid, d in sim.devices.items()}

    for device in devices:
        device.on_unit_id_change = rekey
    return sim


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="5-axis stepper controller Modbus RTU simulator")
    add_serial_arguments(parser, DEFAULT_BAUDRATE, "/tmp/stepper")
    parser.add_argument("--unit-id", type=int, default=1)
    add_delay_argument(
        parser,
        REPLY_DELAY_S * 1000,
        "delay before every reply, after the request's last byte (manual: at least 35 ms "
        "on RS-485)",
    )
    add_ignore_argument(parser, StepperSimDevice.IGNORABLE)
    parser.add_argument("--travel", type=float, default=TRAVEL, help="positive limit, units")
    readings.add_arguments(parser)
    args = parser.parse_args(argv)
    sim = make_simulator(args.unit_id, args.reply_delay_ms.low_s, args.travel)
    device = sim.device
    assert isinstance(device, StepperSimDevice)
    readings.apply(device, args)
    serve_serial_until_signalled(
        sim,
        args,
        lambda where: (
            f"stepper_sim listening on {where} (unit {args.unit_id}, "
            f"{args.baudrate} baud, reply delay {args.reply_delay_ms.text})"
        ),
    )


if __name__ == "__main__":
    main()
