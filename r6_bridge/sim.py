"""Simulator of the R6 controller's Modbus TCP slave, on the shared simulator base.

Behaviour (from the manual, plus what a test needs to see):
- serves exactly the §4/§5 map; undefined, reserved and "not offered" rows answer 0x02;
- 32-bit blocks must be read whole (from their first register, in pairs);
- axis positions and IO boards beyond the configured counts answer 0x02 (§3.1.6, §3.1.8);
- commands 20000-20006 only with FC 06 (§3.2.1), else 0x01;
- start / single cycle make the axes move (speed scaled by the global speed), stop,
  pause and stop-button halt them; an alarm halts them until cleared (20005 / 20006);
- output point (20056-20058) sets the bit in the board's output word; counters, the
  parameter table and point upload keep what is written.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

from bridge_core.codec import int_to_words, words_to_int
from bridge_core.registers import Table, WordOrder
from bridge_core.sim_base import (
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    SimulatedDevice,
    Simulator,
    WriteRecord,
    add_tcp_arguments,
    serve_tcp_until_signalled,
)

from .registers import COMMANDS, MAX_AXES, MAX_IO_BOARDS, R6_MAP

HIGH = WordOrder.HIGH_FIRST
MANUAL_VERSION = "AM8-QC-RXE-7.8.02-bate7_FAKE_TGF_ENCODER"  # §3.1.2 example
AXIS_SPEED_DEG_S = 30.0  # at 100 % global speed
OUTPUT_BOARD_TABLE_MAX = 7  # §4 row 20056 maximum
DEFAULT_COUNTERS = {0: (10, 0), 1: (10, 5)}  # id: (target, current), §3.1.4 example


class R6SimDevice(SimulatedDevice):
    def __init__(self, axis_count: int = 6, io_board_count: int = 1, unit_id: int = 1) -> None:
        super().__init__(R6_MAP, unit_id)
        self.running = False
        self.counters: dict[int, list[int]] = {k: list(v) for k, v in DEFAULT_COUNTERS.items()}
        self.points: dict[int, list[int]] = {}
        self.axis_directions = [1.0 if a % 2 == 0 else -1.0 for a in range(MAX_AXES)]
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
        self._time_in_cycle_ms = 0.0

    def set_version(self, text: str) -> None:
        data = text.encode("latin-1")
        # §3.1.2 example: length 0x29 for a 40-character string, i.e. the NUL counts.
        self.set("version_length", len(data) + 1)
        self.set("version", text)

    def set_alarm(self, code: int) -> None:
        with self.lock:
            self.set("alarm_code", code)
            if code:
                self.running = False

    @property
    def axis_count(self) -> int:
        return int(self.get("axis_count"))

    # ------------------------------------------------------------ Modbus behaviour
    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        with self.lock:
            axes = int(self.get("axis_count"))
            boards = int(self.get("io_board_count"))
            end = address + count
            first_invalid_axis = R6_MAP["axis_position_1"].address + 2 * axes
            if address < 2284 and end > first_invalid_axis and first_invalid_axis < 2284:
                return ILLEGAL_ADDRESS
            for base in (2187, 2227):
                first_invalid_board = base + 2 * boards
                last = base + 2 * MAX_IO_BOARDS
                if address < last and end > first_invalid_board and first_invalid_board < last:
                    return ILLEGAL_ADDRESS
            return super().read(function_code, address, count)

    def _guard(self, record: WriteRecord) -> int | None:
        if record.table is Table.HOLDING:
            if any(a in COMMANDS.values() for a in _span(record)) and record.function_code != 6:
                return ILLEGAL_FUNCTION
            if record.address == R6_MAP["global_speed"].address and record.values[0] > 1000:
                return ILLEGAL_VALUE
            if record.address == R6_MAP["output_board"].address:
                board, point, state = ([*list(record.values), 0, 0, 0])[:3]
                if (
                    len(record.values) != 3
                    or board > OUTPUT_BOARD_TABLE_MAX
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

    def _command(self, address: int) -> None:
        name = {v: k for k, v in COMMANDS.items()}[address]
        alarm = int(self.get("alarm_code"))
        if name in ("start", "single_cycle"):
            self.running = alarm == 0
        elif name in ("stop", "pause", "stop_button"):
            self.running = False
        elif name in ("clear_alarm_and_next", "clear_alarm_and_continue"):
            self.set("alarm_code", 0)
            self.running = name == "clear_alarm_and_continue" and int(self.get("mode")) == 2

    def _publish_counters(self) -> None:
        ids = sorted(self.counters)
        self.set("counter_count", len(ids))
        for k, counter_id in enumerate(ids):
            self.set(f"counter_id_{k}", counter_id)
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
            axes = int(self.get("axis_count"))
            speed_fraction = float(self.get("global_speed")) / 100.0
            moving = self.running and speed_fraction > 0
            self.set("moving", 1 if moving else 0)
            for a in range(1, MAX_AXES + 1):
                axis_speed = AXIS_SPEED_DEG_S * (1.0 - 0.1 * (a - 1))  # distinct per axis
                deg_s = (
                    axis_speed * speed_fraction * self.axis_directions[a - 1]
                    if moving and a <= axes
                    else 0.0
                )
                if deg_s:
                    position = float(self.get(f"axis_position_{a}")) + deg_s * dt
                    if abs(position) > 170.0:  # turn around before the joint limit
                        self.axis_directions[a - 1] *= -1
                    self.set(f"axis_position_{a}", round(position, 3))
                self.set(f"axis_speed_{a}", round(deg_s * 60.0 / 360.0))
                self.set(f"axis_torque_{a}", round(0.2 + 0.1 * math.sin(a), 3) if moving else 0.0)
            if moving:
                self._time_in_cycle_ms += dt * 1000.0
                if self._time_in_cycle_ms > 5000.0:
                    self.set("last_cycle_time", int(self._time_in_cycle_ms))
                    self._time_in_cycle_ms = 0.0
                self.set("current_cycle_time", int(self._time_in_cycle_ms))
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
    args = parser.parse_args(argv)
    sim = make_simulator(args.axes, args.io_boards)
    device = sim.device
    assert isinstance(device, R6SimDevice)
    device.set("mode", args.mode)
    device.set_alarm(args.alarm)
    device.running = args.running and not args.alarm
    serve_tcp_until_signalled(sim, args, "r6_sim")


if __name__ == "__main__":
    main()
