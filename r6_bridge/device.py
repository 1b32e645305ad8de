"""R6 device model: polls into typed snapshots, commands into checked writes.

No ROS here. Every command validates all of its inputs before the first write, so a
refused command writes nothing. The program's checks and read backs are in program.py,
the output writes in outputs.py, the counters in counters.py, the point upload in
upload.py, the action goals in motions.py. "R6 decision N" is reading N of
docs/decisions/r6.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from bridge_core.runtime.checks import check_whole_number
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S, PollGroups
from bridge_core.runtime.reads import holds, read_named
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value, encode, int_to_words, words_to_int
from bridge_core.wire.errors import (
    CommandRejected,
    FrameError,
    LinkError,
    NotConfirmed,
    PollIncomplete,
)
from bridge_core.wire.planner import ReadRequest, plan_reads
from bridge_core.wire.registers import MAX_WRITE_REGISTERS

from . import counters, outputs
from .program import (
    START_COMMANDS,
    check_program_command,
    confirm_cleared,
    confirm_halted,
    confirm_start,
)
from .registers import (
    COMMANDS,
    HIGH,
    I32_MAX,
    I32_MIN,
    M_BOARDS,
    MAX_AXES,
    MAX_IO_BOARDS,
    MAX_VERSION_BYTES,
    PARAMETER_COUNT,
    PARAMETER_WRITE_LAST_INDEX,
    R6_MAP,
    STOP_COMMANDS,
    mode_name,
    parameter_address,
    parameter_offered,
)
from .upload import PointUploadSteps

# joint_states is stamped with the read time of the block holding the axis positions,
# ~/tcp_pose with that of the world block (read just before it), ~/state with the time the
# blocks before those two were read (R6 decision 26).
STAMP_REGISTER = "axis_position_1"
WORLD_STAMP_REGISTER = "world_x"
# The slow group (R6 decision 28): read every slow_poll_period_s, and at the next
# poll after a write to it. The axis count is configuration (§3.1.7; a count that shrinks
# is also caught at once by the refused read of an axis no longer in use); the global
# speed is a setting (§3.2.2) that ~/set_global_speed reads back itself. Everything else
# moves by itself or is judged by a motion (alarm, moving, cycle times), or shares a
# request with such a row; the IO board outputs stay fast: a running program switches them.
SLOW_NAMES = frozenset({"axis_count", "global_speed"})


@dataclass(frozen=True)
class R6Snapshot:
    """One full poll, in the manual's units (deg, mm, rpm, fraction of rated torque)."""

    read_time: float  # wall clock (time.time()) when the axis positions were read
    mode: int
    alarm_code: int
    moving: bool
    homed: bool
    global_speed_percent: float
    current_cycle_time_ms: int
    last_cycle_time_ms: int
    machine_id: int
    axis_count: int
    io_board_count: int
    io_board_inputs: tuple[int, ...]
    io_board_outputs: tuple[int, ...]
    axis_positions_deg: tuple[float, ...]
    axis_speeds_rpm: tuple[int, ...]
    axis_torques_rated: tuple[float, ...]
    world: dict[str, float] = field(default_factory=dict)
    # When the world block (~/tcp_pose) and the other rows (~/state) were read; 0: as
    # read_time (a snapshot built by hand).
    world_read_time: float = 0.0
    state_read_time: float = 0.0
    slow_read_time: float = 0.0  # when the slow group (SLOW_NAMES) was read
    # Only with ``m_boards`` / ``eu_board`` (R6 decision 21): empty / None otherwise.
    m_board_inputs: tuple[int, ...] = ()
    m_board_outputs: tuple[int, ...] = ()
    eu_board_input: int | None = None
    eu_board_output: int | None = None

    @property
    def mode_name(self) -> str:
        return mode_name(self.mode)


class R6Device:
    """The R6 controller behind one Modbus channel."""

    def __init__(
        self,
        io: RegisterIO,
        *,
        m_boards: bool = False,
        eu_board: bool = False,
        slow_period_s: float = SLOW_POLL_PERIOD_DEFAULT_S,
    ) -> None:
        """``m_boards``: the controller offers the M boards' values (the manual withholds
        them from the handheld network-port version); ``eu_board``: an EU board is fitted.
        Each adds its IO rows to the poll and lets ``set_output`` switch its outputs."""
        self.io = io
        self.m_boards = m_boards
        self.eu_board = eu_board
        self.stops = 0  # stop / pause / stop_button commands acknowledged (RunCycleMotion)
        # When the controller writes 2401, as a run_cycle goal saw it (decision 23).
        self.cycle_time_written_at: str | None = None
        self._plan: list[ReadRequest] | None = None
        self._plan_counts: tuple[int, int] | None = None
        # The slow group (SLOW_NAMES) and the fast head of the poll (the world block and
        # the axis positions are read after it, each with its own stamp).
        self.groups = PollGroups([], [], period_s=slow_period_s).follow(io)
        self._grouped: list[ReadRequest] | None = None  # the plan the groups were set from
        self._head: list[ReadRequest] = []  # the fast blocks before the world block

    # ------------------------------------------------------------------ polling
    def poll_plan(self, axis_count: int, io_board_count: int) -> list[ReadRequest]:
        """Requests for a full state poll.

        The manual (§3.1.6, §3.1.8) makes only the axes and IO boards in use valid, so the
        plan depends on the two counts, which every poll re-reads in its own blocks.
        """
        axes = min(max(axis_count, 0), MAX_AXES)
        boards = min(max(io_board_count, 0), MAX_IO_BOARDS)
        names = [
            "mode",
            "io_board_count",
            "axis_count",
            "alarm_code",
            "current_cycle_time",
            "last_cycle_time",
            "machine_id",
            "moving",
            "homed",
            "global_speed",
        ]
        names += [f"io_board_input_{b}" for b in range(boards)]
        names += [f"io_board_output_{b}" for b in range(boards)]
        extra: list[str] = []  # M / EU rows (decision 21)
        if self.m_boards:
            extra += [f"m_board_input_{b}" for b in range(M_BOARDS)]
            extra += [f"m_board_output_{b}" for b in range(M_BOARDS)]
        if self.eu_board:
            extra += ["eu_board_input", "eu_board_output"]
        names += [f"axis_position_{a}" for a in range(1, axes + 1)]
        names += [f"world_{w}" for w in ("x", "y", "z", "u", "v", "w", "m7", "m8")]
        names += [f"axis_torque_{a}" for a in range(1, MAX_AXES + 1)]
        names += [f"axis_speed_{a}" for a in range(1, MAX_AXES + 1)]
        plan = plan_reads(R6_MAP, R6_MAP.select(names))
        if extra:
            # Planned apart: merged with the IO boards' rows, a read would run through the
            # rows of boards not in use, which the controller refuses (§3.1.6).
            plan += plan_reads(R6_MAP, R6_MAP.select(extra))
        # The axis positions last, so a position change reaches joint_states soonest (p99
        # latency, bench/r6_bench.py), the world block just before them (the TCP pose read
        # one request from the joints, decision 26); each has its own stamp either way.
        plan.sort(
            key=lambda request: (
                holds(request, STAMP_REGISTER),
                holds(request, WORLD_STAMP_REGISTER),
            )
        )
        return plan

    def read_counts(self) -> tuple[int, int]:
        axis_count = self.io.read_registers(R6_MAP["axis_count"].address, 1)[0]
        boards = self.io.read_registers(R6_MAP["io_board_count"].address, 1)[0]
        return axis_count, boards

    def poll(self) -> R6Snapshot:
        if self._plan is None or self._plan_counts is None:
            self._plan_counts = self.read_counts()
            self._plan = self.poll_plan(*self._plan_counts)
        # One batch (pipelined where the channel does), three times: the rest (with the
        # slow group when it is due), the world block, the axis positions.
        plan = self._plan
        world = [r for r in plan if holds(r, WORLD_STAMP_REGISTER)]
        positions = [r for r in plan if holds(r, STAMP_REGISTER) and r not in world]
        if self._grouped is not plan:
            # The global speed first: slow_stamp is its read time.
            slow = sorted(
                (r for r in plan if r.names <= SLOW_NAMES),
                key=lambda r: "global_speed" not in r.names,
            )
            self._head = [
                r for r in plan if r not in world and r not in positions and r not in slow
            ]
            self.groups.set_plans([*self._head, *world, *positions], slow)
            self._grouped = plan
        read = self.groups.read(self.io)
        values = read.values
        state_time = read.last_time(self._head)
        world_time = read.time_of(WORLD_STAMP_REGISTER)
        read_time = read.time_of(STAMP_REGISTER) if positions else world_time
        axis_count = int(values["axis_count"])
        boards = int(values["io_board_count"])
        if (axis_count, boards) != self._plan_counts:
            # Configuration changed: next poll reads the new set; this one is incomplete.
            self._plan_counts = (axis_count, boards)
            self._plan = self.poll_plan(axis_count, boards)
            raise PollIncomplete(
                f"axis/board count changed to {axis_count}/{boards}; re-planning the poll"
            )
        axes = min(axis_count, MAX_AXES)
        nboards = min(boards, MAX_IO_BOARDS)

        def f(name: str) -> float:
            return float(values[name])

        def i(name: str) -> int:
            return int(values[name])

        return R6Snapshot(
            read_time=read_time,
            world_read_time=world_time,
            slow_read_time=read.slow_read_time,
            state_read_time=state_time,
            mode=i("mode"),
            alarm_code=i("alarm_code"),
            moving=bool(i("moving")),
            homed=bool(i("homed")),
            global_speed_percent=f("global_speed"),
            current_cycle_time_ms=i("current_cycle_time"),
            last_cycle_time_ms=i("last_cycle_time"),
            machine_id=i("machine_id"),
            axis_count=axis_count,
            io_board_count=boards,
            io_board_inputs=tuple(i(f"io_board_input_{b}") for b in range(nboards)),
            io_board_outputs=tuple(i(f"io_board_output_{b}") for b in range(nboards)),
            axis_positions_deg=tuple(f(f"axis_position_{a}") for a in range(1, axes + 1)),
            axis_speeds_rpm=tuple(i(f"axis_speed_{a}") for a in range(1, axes + 1)),
            axis_torques_rated=tuple(f(f"axis_torque_{a}") for a in range(1, axes + 1)),
            world={w: f(f"world_{w}") for w in ("x", "y", "z", "u", "v", "w", "m7", "m8")},
            m_board_inputs=tuple(i(f"m_board_input_{b}") for b in range(M_BOARDS))
            if self.m_boards
            else (),
            m_board_outputs=tuple(i(f"m_board_output_{b}") for b in range(M_BOARDS))
            if self.m_boards
            else (),
            eu_board_input=i("eu_board_input") if self.eu_board else None,
            eu_board_output=i("eu_board_output") if self.eu_board else None,
        )

    def invalidate_plan(self) -> None:
        """Re-read the counts on the next poll: after a reconnect the device may differ, and
        a poll refused with ILLEGAL DATA ADDRESS means axes or boards went away (§3.1.8:
        only the axes in use are valid), which the cached plan would read forever."""
        self._plan = None
        self._plan_counts = None

    # ------------------------------------------------------------------ reads on request
    def read_version(self) -> str:
        """§3.1.1-3.1.2: the length first, then (length + 1) / 2 registers from 1."""
        length = self.io.read_registers(
            R6_MAP["version_length"].address, 1, priority=Priority.COMMAND
        )[0]
        if not 1 <= length <= MAX_VERSION_BYTES:
            raise FrameError(f"version length {length} outside 1..{MAX_VERSION_BYTES}")
        words = self.io.read_registers(
            R6_MAP["version"].address, (length + 1) // 2, priority=Priority.COMMAND
        )
        data = b"".join(w.to_bytes(2, "big") for w in words)[:length]
        return data.rstrip(b"\x00").decode("latin-1")

    def read_named(self, *names: str) -> dict[str, Value]:
        return read_named(self.io, R6_MAP, names)

    def read_mode(self) -> int:
        return int(self.read_named("mode")["mode"])

    def read_counter_ids(self) -> list[int]:
        """§3.1.3: the ids of the counters the controller lists (``counters``)."""
        return counters.read_counter_ids(self.io)

    def read_counter(self, counter_id: int) -> tuple[int, int, int]:
        """§3.1.4: (id, target, current) of one counter, selected and checked."""
        return counters.read_counter(self.io, counter_id)

    def read_data_source_length(self, source_id: int) -> int:
        """§4 rows 30000-30001: select the data source to view, read its buffer length
        (R6 decision 20: points), and check the selection held."""
        check_whole_number("data source id", source_id, 0, 0xFFFF)
        address = R6_MAP["data_source_view_id"].address
        self.io.write_register(address, source_id)
        viewed, length = self.io.read_registers(address, 2, priority=Priority.COMMAND)
        if viewed != source_id:
            raise CommandRejected(
                f"data source {source_id}: the controller shows source {viewed} "
                "(another client selected one in between); try again"
            )
        return int(length)

    def read_parameter(self, index: int) -> int:
        _check_parameter_index(index)
        words = self.io.read_registers(parameter_address(index), 2, priority=Priority.COMMAND)
        return words_to_int(words, True, HIGH)

    # ------------------------------------------------------------------ commands
    def command(self, name: str) -> None:
        """§3.2.1: write 1 (any value executes) with FC 06."""
        if name not in COMMANDS:
            raise CommandRejected(f"unknown R6 command {name!r}; known: {', '.join(COMMANDS)}")
        self.io.write_register(COMMANDS[name], 1)
        if name in STOP_COMMANDS:
            self.stops += 1

    def halt(self, name: str) -> str:
        """stop (20000), pause (20001) or stop button (20004), done only when the
        controller shows the program standing (``program.confirm_halted``, R6 decision
        29); otherwise ``NotConfirmed`` with what was written and read."""
        if name not in STOP_COMMANDS:
            raise CommandRejected(
                f"{name} is not a stop; stops: {', '.join(sorted(STOP_COMMANDS))}"
            )
        self.command(name)
        return confirm_halted(self.io, name)

    def run_program(self, name: str, *, skip_failed_step: bool = False) -> str:
        """A checked 20002 / 20003 / 20005 / 20006 (``program.check_program_command``):
        refused with the reason, nothing written, unless the controller is ready for it.
        Then confirmed (``confirm_start``, ``confirm_cleared``); returns what was read."""
        ready = check_program_command(self.io, name, skip_failed_step=skip_failed_step)
        self.command(name)
        if name in START_COMMANDS:
            return confirm_start(self.io, name, ready)
        return confirm_cleared(self.io, name, ready)

    def set_global_speed(self, percent: float) -> None:
        """§3.2.2: one register, FC 06, 0-1000 = 0.0-100.0 %."""
        reg = R6_MAP["global_speed"]
        (raw,) = encode(reg, float(percent))
        self.io.write_register(reg.address, raw)

    def set_global_speed_read_back(self, percent: float) -> str:
        """``set_global_speed``, then 20200 read back (R6 decision 29: the speed of a
        running program changes only if the controller took it); ``NotConfirmed`` with
        what was written and read when it differs."""
        reg = R6_MAP["global_speed"]
        (raw,) = encode(reg, float(percent))
        self.set_global_speed(percent)
        try:
            read = self.io.read_registers(reg.address, 1, priority=Priority.COMMAND)[0]
        except LinkError as err:
            raise NotConfirmed(f"sent (wrote 20200 = {raw}); the read back failed: {err}") from err
        if read != raw:
            raise NotConfirmed(
                f"sent (wrote 20200 = {raw}, acknowledged); read 20200 = {read} ({read / 10:g} %)"
            )
        return f"wrote 20200 = {raw}; read {read} ({read / 10:g} %)"

    def set_output(
        self, board: int, point: int, on: bool, boards_in_use: int | None = None
    ) -> None:
        """One output point of board 0-8 (``outputs.set_output``); ``boards_in_use``: the
        IO board count the controller last reported (2186), None: read it now."""
        outputs.set_output(
            self.io, board, point, on, boards_in_use, m_boards=self.m_boards, eu_board=self.eu_board
        )

    def write_board_outputs(
        self, board: int, bits: int, mask: int, boards_in_use: int | None = None
    ) -> str:
        """The outputs of one IO board under ``mask`` (``outputs.write_board_outputs``)."""
        return outputs.write_board_outputs(self.io, board, bits, mask, boards_in_use)

    def set_counter(self, counter_id: int, value: int) -> str:
        """§3.3.2: a listed counter's current value, read back (R6 decision 24)."""
        return counters.set_counter(self.io, counter_id, value)

    def write_counter(self, counter_id: int, value: int) -> None:
        """§3.3.2's frame alone: id, target (ignored by the host: 0) and current value."""
        counters.write_counter(self.io, counter_id, value)

    def write_parameter(self, index: int, value: int) -> str:
        """One parameter, read back after the write (R6 decision 24): the host
        acknowledges writes it does not apply (a parameter locked by the program or the
        mode), which would otherwise report done."""
        self.write_parameters(index, [value])
        read = self.read_parameter(index)
        if read != value:
            raise NotConfirmed(f"parameter {index}: wrote {value}, reads {read}")
        return f"parameter {index} reads {read}"

    def write_parameters(self, first_index: int, values: Sequence[int]) -> None:
        """§3.3.4: consecutive int32 parameters in one FC 10 write."""
        if not values:
            raise CommandRejected("no parameter values given")
        if 2 * len(values) > MAX_WRITE_REGISTERS:
            raise CommandRejected(f"at most {MAX_WRITE_REGISTERS // 2} parameters per write")
        for k, value in enumerate(values):
            _check_parameter_index(first_index + k)
            if first_index + k > PARAMETER_WRITE_LAST_INDEX:
                raise CommandRejected(
                    f"parameter {first_index + k} is read-only here: §3.3.4 gives the "
                    f"writable range as 20300-22229 (indexes 0-{PARAMETER_WRITE_LAST_INDEX})"
                )
            check_whole_number(f"parameter {first_index + k}", value, I32_MIN, I32_MAX)
        words: list[int] = []
        for value in values:
            words += int_to_words(value, 2, True, HIGH)
        self.io.write_registers(parameter_address(first_index), words)

    def upload_points(
        self, data_source_id: int, values_per_point: int, axis_mask: int, values: Sequence[int]
    ) -> int:
        """§3.3.5 in one go (the ``~/upload_points`` service): ``PointUploadSteps.send_all``;
        the number of data frames."""
        upload = PointUploadSteps(self, data_source_id, values_per_point, axis_mask, values)
        return upload.send_all()


def _check_parameter_index(index: int) -> None:
    check_whole_number("parameter index", index, 0, PARAMETER_COUNT - 1)
    if not parameter_offered(index):
        raise CommandRejected(
            f"parameter index {index} overlaps registers 22130-22131 "
            "(photo / mold switching), which the R6 host does not support"
        )
