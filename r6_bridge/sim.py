"""Simulator of the R6 controller's Modbus TCP slave, on the shared simulator base.

Behaviour (from the manual; the readings taken where it is unclear are R6 decisions 6, 11
and 16-19 of docs/decisions/r6.md, quoted again where they are coded):
- serves exactly the §4/§5 map; undefined, reserved and "not offered" rows answer 0x02;
- FC 04 reads the same rows as FC 03 (§4's title: "功能码 0x03、0x04、0x06、0x10 地址表定义");
- 32-bit blocks must be read whole (from their first register, in pairs);
- axis positions and IO boards beyond the configured counts answer 0x02 (§3.1.6, §3.1.8),
  for the boards' FC 01 coils as for their FC 03 rows;
- commands 20000-20006 only with FC 06 (§3.2.1), else 0x01;
- a program of steps (waypoints the axes move to, speed scaled by the global speed) runs
  in cycles: start runs cycle after cycle, single cycle (20002) runs to the end of the
  current cycle and stops; stop (20000) returns the program to its first step, pause
  (20001) keeps the step it reached; an alarm halts the program where it is, 20006
  clears it and continues that step, 20005 clears it and continues with the next step;
- counter ids past the counter count read 0xFF bytes (§3.1.3);
- §5's coils and §4's output rows 2227-2244 are one memory (coil 32·b + p is bit p of
  board b's output word); output point (20056-20058) sets the same bits; counters, the
  parameter table and point upload keep what is written.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

from bridge_core.sim.command_line import add_tcp_arguments, serve_tcp_until_signalled
from bridge_core.sim.logs import ReadRecord, WriteRecord
from bridge_core.sim.personality import add_ignore_argument
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import (
    FUNCTION_TABLES,
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    SimulatedDevice,
)
from bridge_core.wire.codec import int_to_words, words_to_int
from bridge_core.wire.registers import Table, WordOrder

from . import sim_readings as readings
from .registers import (
    COIL_BANKS,
    COMMANDS,
    MAX_AXES,
    MAX_COUNTERS,
    MAX_IO_BOARDS,
    PARAMETER_COUNT,
    PARAMETER_WRITE_LAST_INDEX,
    R6_MAP,
    parameter_address,
)

HIGH = WordOrder.HIGH_FIRST
MANUAL_VERSION = "AM8-QC-RXE-7.8.02-bate7_FAKE_TGF_ENCODER"  # §3.1.2 example
AXIS_SPEED_DEG_S = 30.0  # axis 1 at 100 % global speed; axis a: 10 % less per axis
# R6 decision 3: 20056 takes boards 0-3 (general IO under every reading of §3.3.3 and
# the table); 4-7 (the table's maximum, 7) name different boards in the two, so refused.
OUTPUT_BOARDS_ACCEPTED = range(0, 4)
# R6 decision 5: parameter indexes 965-999 (22230-22299) are read only.
READ_ONLY_PARAMETER_ROWS = range(
    parameter_address(PARAMETER_WRITE_LAST_INDEX + 1), parameter_address(PARAMETER_COUNT)
)
AUTO_MODE = 2  # 2185: "2 自动"
DEFAULT_COUNTERS = {0: (10, 0), 1: (10, 5)}  # id: (target, current), §3.1.4 example
# §3.1.3: "若实际数量少于请求的数量则将剩余的使用 0xFF 填充" (decision 6: every padding byte
# is 0xFF, so a counter id past the count reads 0xFFFF 0xFFFF).
COUNTER_PADDING_WORD = 0xFFFF
BUFFER_LENGTH_MAX = 0xFFFF  # 30001 is one 16-bit register
POINTS_PER_BOARD = 32
# §4 output rows: IO boards 0-4 (2227-2236), M boards 0-2 (2237-2242), EU board 0
# (2243-2244), two registers per board, "16~31" in the first and "0~15" in the second.
OUTPUT_ROWS = range(R6_MAP["io_board_output_0"].address, R6_MAP["eu_board_output"].end)
# §5 coils: Y010-Y247 (0-159), M010-M147 (160-255), EUY010-EUY047 (256-287): 32 per board,
# the same nine boards in the same order (the octal names count 32 outputs per board).
OUTPUT_COILS = range(COIL_BANKS[0][1], COIL_BANKS[-1][1] + COIL_BANKS[-1][2])
if len(OUTPUT_COILS) != len(OUTPUT_ROWS) * 16:
    raise AssertionError("§5 coils and §4 output rows must cover the same boards")
FIRST_POSITION = R6_MAP["axis_position_1"].address
POSITION_ROWS_END = R6_MAP[f"axis_position_{MAX_AXES}"].end


def axis_speed_deg_s(axis: int) -> float:
    """Degrees per second of axis 1..8 at 100 % global speed (distinct per axis)."""
    return round(AXIS_SPEED_DEG_S * (1.0 - 0.1 * (axis - 1)), 3)


def _default_program() -> tuple[tuple[float, ...], ...]:
    """Three steps per cycle: out, across, home (2 s, 4 s, 2 s at 100 % global speed; axis
    1 swings +-60 deg). Long enough that a few seconds of watching see the axes move on."""
    out = tuple(
        (1.0 if a % 2 == 1 else -1.0) * 2.0 * axis_speed_deg_s(a) for a in range(1, MAX_AXES + 1)
    )
    return (out, tuple(-p for p in out), (0.0,) * MAX_AXES)


DEFAULT_PROGRAM = _default_program()


def coil_to_row_bit(coil: int) -> tuple[int, int]:
    """The §4 output register and bit that hold §5 coil ``coil`` (one memory)."""
    board, point = divmod(coil - OUTPUT_COILS.start, POINTS_PER_BOARD)
    high_word = OUTPUT_ROWS.start + 2 * board  # "16~31" at the board's first register
    return (high_word, point - 16) if point >= 16 else (high_word + 1, point)


def row_first_coil(row: int) -> int:
    """The §5 coil of bit 0 of §4 output register ``row``."""
    board, second = divmod(row - OUTPUT_ROWS.start, 2)
    return OUTPUT_COILS.start + POINTS_PER_BOARD * board + (0 if second else 16)


# The motion writes this controller can play deaf to (``--ignore``): name -> the write.
IGNORABLE: dict[str, str] = {
    "stop": "20000 stop (FC 06)",
    "pause": "20001 pause (FC 06)",
    "single_cycle": "20002 single cycle (FC 06)",
    "start": "20003 start button (FC 06)",
    "stop_button": "20004 stop button (FC 06)",
    "clear_alarm": "20005 / 20006 clear the alarm and run on (FC 06)",
    "speed": "20200 global speed (FC 06)",
}
_IGNORABLE_AT: dict[int, str] = {
    **{COMMANDS[name]: name for name in ("stop", "pause", "single_cycle", "start", "stop_button")},
    COMMANDS["clear_alarm_and_next"]: "clear_alarm",
    COMMANDS["clear_alarm_and_continue"]: "clear_alarm",
    R6_MAP["global_speed"].address: "speed",
}
# When 2401 ("上模周期") is written (R6 decision 23 leaves it open; ``--cycle-time-at``):
# at a cycle's end, the time of the cycle that just ended, or at a cycle's start, the
# time of the last cycle completed before it.
CYCLE_TIME_AT = ("end", "start")


class R6SimDevice(SimulatedDevice):
    IGNORABLE: ClassVar[Mapping[str, str]] = IGNORABLE

    def __init__(self, axis_count: int = 6, io_board_count: int = 1, unit_id: int = 1) -> None:
        super().__init__(R6_MAP, unit_id)
        self.running = False
        # The program: one waypoint per step (degrees, axes 1-8); a test may shorten it.
        self.program: tuple[tuple[float, ...], ...] = DEFAULT_PROGRAM
        self.step = 0  # the step the program runs (or resumes at)
        self.single_cycle = False  # stop at the end of the current cycle (20002)
        self.halted_by_alarm = False  # an alarm stopped the running program
        self.cycles_completed = 0
        self._time_in_cycle_ms = 0.0
        # When 2401 is written ("end" or "start", CYCLE_TIME_AT); the time of the last
        # completed cycle, which "start" writes when the next cycle begins.
        self.cycle_time_at = "end"
        self._completed_cycle_ms: int | None = None
        self._serving_fc04 = False
        # Personalities (sim_readings: the other readings of decisions 1, 8, 11, 21).
        self.low_word_first = False
        self.answer_past_counts = False
        self.answer_undefined = False
        self.m_boards_offered = True
        self.counters: dict[int, list[int]] = {k: list(v) for k, v in DEFAULT_COUNTERS.items()}
        self.points: dict[int, list[int]] = {}
        self.point_counts: dict[int, int] = {}  # points stored per data source
        self.write_guards.append(self._guard)
        self.write_hooks.append(self._on_write)
        self.set_version(MANUAL_VERSION)
        self.set("mode", 2)
        self.set("axis_count", axis_count)
        self.set("io_board_count", io_board_count)
        self.set("machine_id", 1)
        self.set("homed", 1)
        self.set("global_speed", 50.0)
        self._publish_counters()

    def set_version(self, text: str) -> None:
        data = text.encode("latin-1")
        # §3.1.2 example: length 0x29 for a 40-character string, i.e. the NUL counts.
        self.set("version_length", len(data) + 1)
        self.set("version", text)

    def set_counters(self, counters: dict[int, tuple[int, int]]) -> None:
        """The controller's counters (id: (target, current)), as its program defines them."""
        with self.lock:
            self.counters = {k: list(v) for k, v in counters.items()}
            self._publish_counters()

    def set_alarm(self, code: int) -> None:
        """Raise (or, with 0, drop) an alarm; an alarm halts the program where it is."""
        with self.lock:
            self.set("alarm_code", code)
            if code and self.running:
                self.running = False
                self.halted_by_alarm = True
            elif not code:
                self.halted_by_alarm = False

    def write_names(self, record: WriteRecord) -> frozenset[str]:
        if record.table is not Table.HOLDING:
            return frozenset()
        return frozenset(_IGNORABLE_AT[a] for a in _span(record) if a in _IGNORABLE_AT)

    def set_cycle_time_at(self, when: str) -> None:
        """When 2401 is written: "end" (a cycle's end) or "start" (a cycle's start)."""
        if when not in CYCLE_TIME_AT:
            raise ValueError(f"cycle time at {when!r}: one of {', '.join(CYCLE_TIME_AT)}")
        with self.lock:
            self.cycle_time_at = when

    @property
    def axis_count(self) -> int:
        return int(self.get("axis_count"))

    # ------------------------------------------------------------ one output memory
    def set_words(self, table: Table, address: int, values: Sequence[int]) -> None:
        """Every store goes through here: keep §5's coils and §4's output rows one memory
        (decision 19), whichever side a write, a command or the simulator itself changes."""
        with self.lock:
            super().set_words(table, address, values)
            for offset, word in enumerate(values):
                at = address + offset
                if table is Table.COIL and at in OUTPUT_COILS:
                    row, bit = coil_to_row_bit(at)
                    old = self.words[(Table.HOLDING, row)]
                    new = old | (1 << bit) if word else old & ~(1 << bit)
                    super().set_words(Table.HOLDING, row, [new])
                elif table is Table.HOLDING and at in OUTPUT_ROWS:
                    bits = [(int(word) >> bit) & 1 for bit in range(16)]
                    super().set_words(Table.COIL, row_first_coil(at), bits)

    # ------------------------------------------------------------ Modbus behaviour
    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        with self.lock:
            table = FUNCTION_TABLES[function_code]
            code = self._refused_by_counts(table, address, count)
            if code is None and not self.m_boards_offered:
                code = ILLEGAL_ADDRESS if readings.m_board_refused(table, address, count) else None
            if code is not None:
                return code
            if self.answer_undefined and readings.undefined(self.map, table, address, count):
                return [0] * count  # decision 11's other reading: no 0x02 outside the map
            if function_code != 4:
                return self._answer(table, address, super().read(function_code, address, count))
            # §4 "功能码 0x03、0x04、0x06、0x10 地址表定义": FC 04 reads the FC 03 rows (the
            # read log still says FC 04).
            self._serving_fc04 = True
            try:
                return self._answer(table, address, super().read(3, address, count))
            finally:
                self._serving_fc04 = False

    def _answer(self, table: Table, address: int, words: list[int] | int) -> list[int] | int:
        """With ``low_word_first`` (decision 1's other reading), every whole 32/64-bit value
        of the answer is sent low word first."""
        if not self.low_word_first or isinstance(words, int) or table.is_bit:
            return words
        return readings.low_word_first(self.map, table, address, words)

    def _log_read(self, record: ReadRecord) -> None:
        if self._serving_fc04:
            record = dataclasses.replace(record, function_code=4)
        super()._log_read(record)

    def _refused_by_counts(self, table: Table, address: int, count: int) -> int | None:
        """§3.1.6 / §3.1.8: only the axes and IO boards in use are valid addresses (not
        with ``answer_past_counts``: decision 8's other reading)."""
        if self.answer_past_counts:
            return None
        axes = int(self.get("axis_count"))
        boards = int(self.get("io_board_count"))
        end = address + count
        if table is Table.COIL:
            # The boards' coils are their output rows (decision 19): the same count rule.
            first_invalid = OUTPUT_COILS.start + POINTS_PER_BOARD * boards
            last = OUTPUT_COILS.start + POINTS_PER_BOARD * MAX_IO_BOARDS
            if address < last and end > first_invalid and first_invalid < last:
                return ILLEGAL_ADDRESS
            return None
        first_invalid_axis = FIRST_POSITION + 2 * axes
        if address < POSITION_ROWS_END and end > first_invalid_axis < POSITION_ROWS_END:
            return ILLEGAL_ADDRESS
        for base in (2187, 2227):
            first_invalid_board = base + 2 * boards
            last = base + 2 * MAX_IO_BOARDS
            if address < last and end > first_invalid_board and first_invalid_board < last:
                return ILLEGAL_ADDRESS
        return None

    def _guard(self, record: WriteRecord) -> int | None:
        if record.table is Table.HOLDING:
            if any(a in COMMANDS.values() for a in _span(record)) and record.function_code != 6:
                return ILLEGAL_FUNCTION
            if record.address == R6_MAP["global_speed"].address and record.values[0] > 1000:
                return ILLEGAL_VALUE
            if any(a in READ_ONLY_PARAMETER_ROWS for a in _span(record)):
                # R6 decision 5: §3.3.4's writable range ends at 22229 (index 964).
                return ILLEGAL_ADDRESS
            if record.address == R6_MAP["output_board"].address:
                board, point, state = ([*list(record.values), 0, 0, 0])[:3]
                if (
                    len(record.values) != 3
                    or board not in OUTPUT_BOARDS_ACCEPTED
                    or point > 31
                    or state > 1
                ):
                    return ILLEGAL_VALUE
            if (
                record.address == R6_MAP["counter_select_id"].address
                and words_to_int(record.values[:2], False, HIGH) not in self.counters
            ):
                return ILLEGAL_VALUE
        return None

    def _on_write(self, record: WriteRecord) -> None:
        address = record.address
        if record.table is not Table.HOLDING:
            return
        if address in COMMANDS.values():
            self._command(address)
        elif address == R6_MAP["output_board"].address:
            board, point, state = record.values
            if board < MAX_IO_BOARDS:
                name = f"io_board_output_{board}"
                bits = int(self.get(name))
                bits = bits | (1 << point) if state else bits & ~(1 << point)
                self.set(name, bits)
        elif address == R6_MAP["counter_select_id"].address:
            self._publish_counters()
        elif address == R6_MAP["counter_modify_id"].address and len(record.values) == 6:
            counter_id = words_to_int(record.values[0:2], False, HIGH)
            current = words_to_int(record.values[4:6], False, HIGH)
            if counter_id in self.counters:
                self.counters[counter_id][1] = current  # the host never changes the target
            self._publish_counters()
        elif address == R6_MAP["point_count"].address:
            count, clear = record.values[0], record.values[1]
            source = int(self.get("point_source_id"))
            per_point = int(self.get("point_values_per_point"))
            data = record.values[2:]
            values = [words_to_int(data[k : k + 2], True, HIGH) for k in range(0, len(data), 2)]
            stored = [] if clear == 1 else self.points.get(source, [])
            self.points[source] = stored + values[: count * per_point]
            self.point_counts[source] = (
                0 if clear == 1 else self.point_counts.get(source, 0)
            ) + count
            self._publish_buffer_length()
        elif address == R6_MAP["data_source_view_id"].address:
            self._publish_buffer_length()

    def _publish_buffer_length(self) -> None:
        """30001 for the source selected at 30000: its stored points (R6 decision 20:
        the manual names no unit; 30005 counts points)."""
        source = int(self.get("data_source_view_id"))
        self.set(
            "data_source_buffer_length", min(self.point_counts.get(source, 0), BUFFER_LENGTH_MAX)
        )

    # ------------------------------------------------------------ the program
    def _command(self, address: int) -> None:
        name = {v: k for k, v in COMMANDS.items()}[address]
        alarm = int(self.get("alarm_code"))
        if name in ("start", "single_cycle"):
            # An alarm blocks both until it is cleared. 20003 "启动按键" runs cycle after
            # cycle; 20002 "进入单循环" runs to the end of the current cycle, then stops
            # (decision 16). Either resumes at the step the program is at.
            # Only in auto mode and homed (R6 decision 23: the bridge's reading; a
            # controller that ignores the start is what the bridge must notice).
            if alarm == 0 and int(self.get("mode")) == AUTO_MODE and int(self.get("homed")):
                self.running = True
                self.single_cycle = name == "single_cycle"
        elif name == "pause":
            # 20001 "暂停当前动作(启动从当前步开始)": the step is kept.
            self.running = False
        elif name in ("stop", "stop_button"):
            # 20000 "立即停止当前动作(启动从头开始)": the next start begins at the first
            # step; 20004 "stopButton:停止按键" is taken as the same stop (decision 17).
            self.running = False
            self._reset_program()
        elif name in ("clear_alarm_and_next", "clear_alarm_and_continue"):
            # 20005 "清除报警后运行下一条指令", 20006 "清除报警并继续自动运行:(自动运行
            # 状态下)" (decision 18): both clear the alarm; only a program the alarm halted
            # runs on, 20006 at the step it stopped (in auto mode only), 20005 at the next.
            halted = self.halted_by_alarm
            self.set("alarm_code", 0)
            self.halted_by_alarm = False
            if not halted:
                return
            if name == "clear_alarm_and_continue":
                self.running = int(self.get("mode")) == AUTO_MODE
            else:
                self.running = not self._next_step()

    def _reset_program(self) -> None:
        self.step = 0
        self.single_cycle = False
        self.halted_by_alarm = False
        self._time_in_cycle_ms = 0.0
        self.set("current_cycle_time", 0)

    def _next_step(self) -> bool:
        """Go on to the next step; at the end of the program a cycle is complete.
        Returns True when that ended a single cycle (the program stops)."""
        self.step += 1
        if self.step < len(self.program):
            return False
        self.step = 0
        self.cycles_completed += 1
        elapsed_ms = int(self._time_in_cycle_ms)
        if elapsed_ms == (self._completed_cycle_ms or int(self.get("last_cycle_time"))):
            # Never the last cycle's time to the millisecond: the bridge reads an unchanged
            # 2401 as a cycle it cannot prove finished (R6 decision 23, the safe side), and
            # this simulator's cycles, the same path at the same speed, often tie.
            elapsed_ms += 1
        self._completed_cycle_ms = elapsed_ms
        if self.cycle_time_at == "end":
            self.set("last_cycle_time", elapsed_ms)
        self._time_in_cycle_ms = 0.0
        self.set("current_cycle_time", 0)
        if self.single_cycle:
            self.single_cycle = False
            self.running = False
            return True
        return False

    def _publish_counters(self) -> None:
        ids = sorted(self.counters)
        self.set("counter_count", len(ids))
        first = R6_MAP["counter_id_0"].address
        words: list[int] = []
        for counter_id in ids:
            words += int_to_words(counter_id, 2, False, HIGH)
        words += [COUNTER_PADDING_WORD] * (2 * MAX_COUNTERS - len(words))
        self.set_words(Table.HOLDING, first, words)
        selected = int(self.get("counter_select_id"))
        target, current = self.counters.get(selected, [0, 0])
        self.set_words(
            Table.HOLDING, R6_MAP["counter_target"].address, int_to_words(target, 2, False, HIGH)
        )
        self.set_words(
            Table.HOLDING, R6_MAP["counter_current"].address, int_to_words(current, 2, False, HIGH)
        )

    def tick(self, dt: float) -> None:
        with self.lock:
            axes = min(int(self.get("axis_count")), MAX_AXES)
            speed_fraction = float(self.get("global_speed")) / 100.0
            moving = self.running and speed_fraction > 0
            if self.step >= len(self.program):  # a test gave a shorter program
                self.step = 0
            target = self.program[self.step] if moving else ()
            arrived = True
            for a in range(1, MAX_AXES + 1):
                deg_s = 0.0
                if moving and a <= axes:
                    position = float(self.get(f"axis_position_{a}"))
                    left = round(target[a - 1] - position, 3)
                    limit = axis_speed_deg_s(a) * speed_fraction
                    if abs(left) > limit * dt:
                        arrived = False
                        deg_s = math.copysign(limit, left)
                        self.set(f"axis_position_{a}", round(position + deg_s * dt, 3))
                    elif left:
                        deg_s = left / dt if dt > 0 else 0.0
                        self.set(f"axis_position_{a}", target[a - 1])
                self.set(f"axis_speed_{a}", round(deg_s * 60.0 / 360.0))
                self.set(f"axis_torque_{a}", round(0.2 + 0.1 * math.sin(a), 3) if deg_s else 0.0)
            if moving:
                if (
                    self.cycle_time_at == "start"
                    and self.step == 0
                    and self._time_in_cycle_ms == 0.0
                    and self._completed_cycle_ms is not None
                ):
                    # A cycle begins: 2401 gets the last completed cycle's time.
                    self.set("last_cycle_time", self._completed_cycle_ms)
                self._time_in_cycle_ms += dt * 1000.0
                self.set("current_cycle_time", int(self._time_in_cycle_ms))
                if arrived:
                    self._next_step()
            self.set("moving", 1 if self.running and speed_fraction > 0 else 0)
            # The tool follows axes 1-3 loosely so the TCP pose changes too.
            p = [float(self.get(f"axis_position_{a}")) for a in (1, 2, 3)]
            self.set("world_x", round(400.0 + p[0], 3))
            self.set("world_y", round(100.0 + p[1], 3))
            self.set("world_z", round(300.0 + p[2], 3))
            self.set("world_w", round(p[0] / 2.0, 3))


def _span(record: WriteRecord) -> Sequence[int]:
    return range(record.address, record.address + len(record.values))


def make_simulator(axis_count: int = 6, io_board_count: int = 1) -> Simulator:
    return Simulator([R6SimDevice(axis_count=axis_count, io_board_count=io_board_count)])


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Huacheng R6 Modbus TCP simulator")
    add_tcp_arguments(parser, default_port=5020)
    parser.add_argument("--axes", type=int, default=6)
    parser.add_argument("--io-boards", type=int, default=1)
    parser.add_argument("--running", action="store_true", help="start with the axes moving")
    parser.add_argument("--mode", type=int, default=2, help="1 manual, 2 auto, 3 configuration")
    parser.add_argument("--alarm", type=int, default=0, help="start with this alarm code")
    parser.add_argument(
        "--cycle-time-at",
        choices=CYCLE_TIME_AT,
        default="end",
        help="when the last cycle time 2401 is written: at a cycle's end (its own time) or "
        "at the next cycle's start (the last completed cycle's time)",
    )
    readings.add_arguments(parser)
    add_ignore_argument(parser, R6SimDevice.IGNORABLE)
    args = parser.parse_args(argv)
    sim = make_simulator(args.axes, args.io_boards)
    device = sim.device
    assert isinstance(device, R6SimDevice)
    device.set("mode", args.mode)
    device.set_alarm(args.alarm)
    device.running = args.running and not args.alarm
    device.set_cycle_time_at(args.cycle_time_at)
    readings.apply(device, args)
    serve_tcp_until_signalled(sim, args, "r6_sim")


if __name__ == "__main__":
    main()
