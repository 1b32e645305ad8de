"""Register map of the Huacheng R6 controller's Modbus TCP slave.

Source: "R6 系统-ModbusTCP 从站使用说明书" V3.0 (seed 000, docs/manuals.md).
Section names below: §2 data format, §3.x examples, §4 the FC 03/04/06/10 address table,
§5 the FC 01/05 coil table.

The readings taken where the manual contradicts itself, or says nothing, are recorded once,
with the manual's words, in docs/decisions/r6.md; comments here cite them by number. What
this map encodes: 32/64-bit values high word first (decision 1), the mode names (2), output
boards 0-3 only (3), global speed as one 16-bit register (4), the parameter table read to
22299 but written only to 22229 (5), the decimal column over the hex column (10), the rows
the host does not offer left out (11), torque as a fraction of rated (13), world U, V, W in
degrees (14), point data raw (15).
"""

from __future__ import annotations

from bridge_core.wire.registers import (
    Access,
    DeviceLimits,
    Register,
    RegisterMap,
    Table,
    ValueType,
    WordOrder,
    register_array,
)

T = "§4 address table"
HIGH = WordOrder.HIGH_FIRST  # 32/64-bit values high word first (decision 1)
I32_MIN, I32_MAX = -(1 << 31), (1 << 31) - 1  # parameters and point values are int32
U32_MAX = 0xFFFF_FFFF  # counters, counter ids and a board's outputs are uint32
MAX_AXES = 8
MAX_IO_BOARDS = 5
M_BOARDS = 3
# §5's coil numbering of the outputs: board b's point p is coil 32·b + p (decision 19), IO
# boards 0-4, M boards 5-7, EU board 8.
FIRST_M_BOARD = MAX_IO_BOARDS
EU_BOARD = FIRST_M_BOARD + M_BOARDS
POINTS_PER_BOARD = 32
MAX_COUNTERS = 1024
MAX_VERSION_BYTES = 128
PARAMETER_COUNT = 1000
# §3.3.4 gives the writable range as "0x4f4c (20300)~0x56d5 (22229)": index 964 is the last
# whole value inside it. Indexes 965-999 (of 0-999) are read, never written (decision 5).
PARAMETER_WRITE_LAST_INDEX = (22229 - 20300) // 2
PARAMETER_BASE = 20300
TORQUE_RATED_RAW = 2580  # §3.1.13: 2580 = one times rated torque
POSITION_SCALE = 1000  # §3.1.8 / §3.1.9: value x 1000 as int32
GLOBAL_SPEED_SCALE = 10  # §3.2.2: 0-1000 = 0.0-100.0 %
OUTPUT_BOARDS_ACCEPTED = range(0, 4)  # R6 decision 3
OUTPUT_POINTS = range(0, 32)
POINT_VALUES_PER_POINT = (4, 6)  # §4 30003: "6 个数据为一点 还是 4 个"
POINT_AXIS_MASK_MAX = 0x3F  # §4 30004: bits 0-5 = axes 1-6
POINT_DATA_FIRST = 30007
POINT_DATA_LAST = 40000
POINT_FRAME_MAX_BYTES = 256  # §3.3.5: split frames above 256 bytes

# §5's coil table: (name, first coil, count, the manual's rows and output names, octal).
COIL_BANKS = (
    ("y_output", 0, 160, "§5 rows 0-159 (Y010-Y247)"),
    ("m_output", 160, 96, "§5 rows 160-255 (M010-M147)"),
    ("eu_output", 256, 32, "§5 rows 256-287 (EUY010-EUY047)"),
)

MODE_NAMES = {1: "manual", 2: "auto", 3: "configuration"}


def mode_name(mode: int) -> str:
    return MODE_NAMES.get(mode, f"unknown({mode})")


# Command registers 20000-20006 (§3.2.1, §4): any value executes; FC 06 only.
COMMANDS: dict[str, int] = {
    "stop": 20000,
    "pause": 20001,
    "single_cycle": 20002,
    "start": 20003,
    "stop_button": 20004,
    "clear_alarm_and_next": 20005,
    "clear_alarm_and_continue": 20006,
}

# The commands that end motion: tried on the wire even while the link is marked down.
STOP_COMMANDS = frozenset({"stop", "pause", "stop_button"})

# Rows the host's network port does not offer (§4 rows marked "主机网口不支持" etc.).
NOT_OFFERED: dict[str, range] = {
    "mold number (主机网口不支持)": range(65, 130),
    "current user and mold list (主机无该项)": range(2472, 2538),
    "stacking edit (主机无该功能)": range(20059, 20072),
    "photo and mold switching (主机不支持)": range(22130, 22132),
}


def _overlaps_not_offered(address: int) -> bool:
    return any(address in rows or address + 1 in rows for rows in NOT_OFFERED.values())


def parameter_offered(index: int) -> bool:
    """Index 915 (22130-22131) collides with the unsupported photo / mold rows: refused."""
    return 0 <= index < PARAMETER_COUNT and not _overlaps_not_offered(PARAMETER_BASE + 2 * index)


# One table: a row per register of the manual's §4 and §5; splitting it would scatter the map.
def _build() -> tuple[Register, ...]:
    regs: list[Register] = [
        Register(
            "version_length",
            0,
            ValueType.U16,
            "§3.1.1, §4 row 0",
            unit="bytes",
            description="length of the version string in bytes",
        ),
        Register(
            "version",
            1,
            ValueType.STRING,
            "§3.1.2, §4 rows 1-64",
            length=64,
            description="read (length + 1) / 2 registers from 1",
        ),
        Register("counter_count", 130, ValueType.U16, "§3.1.3, §4 row 130"),
        *register_array(
            "counter_id",
            131,
            MAX_COUNTERS,
            ValueType.U32,
            "§3.1.3, §4 rows 131-2178",
            first_index=0,
        ),
        Register(
            "counter_select_id",
            2179,
            ValueType.U32,
            "§3.1.4, §4 rows 2179-2180",
            access=Access.READ_WRITE,
            description="write an id, then read 2179-2184",
        ),
        Register("counter_target", 2181, ValueType.U32, "§3.1.4, §4 rows 2181-2182"),
        Register("counter_current", 2183, ValueType.U32, "§3.1.4, §4 rows 2183-2184"),
        Register("mode", 2185, ValueType.U16, "§3.1.5, §4 row 2185"),
        Register(
            "io_board_count",
            2186,
            ValueType.U16,
            "§3.1.6, §4 row 2186",
            minimum=0,
            maximum=MAX_IO_BOARDS,
        ),
        *register_array(
            "io_board_input",
            2187,
            MAX_IO_BOARDS,
            ValueType.U32,
            "§3.1.6, §4 rows 2187-2196",
            first_index=0,
        ),
        *register_array(
            "m_board_input", 2197, M_BOARDS, ValueType.U32, f"{T} rows 2197-2202", first_index=0
        ),
        Register("eu_board_input", 2203, ValueType.U32, f"{T} rows 2203-2204"),
        *register_array(
            "io_board_output",
            2227,
            MAX_IO_BOARDS,
            ValueType.U32,
            "§3.1.6, §3.3.1, §4 rows 2227-2236",
            first_index=0,
            access=Access.READ_WRITE,
        ),
        *register_array(
            "m_board_output",
            2237,
            M_BOARDS,
            ValueType.U32,
            f"{T} rows 2237-2242",
            first_index=0,
            access=Access.READ_WRITE,
        ),
        Register(
            "eu_board_output", 2243, ValueType.U32, f"{T} rows 2243-2244", access=Access.READ_WRITE
        ),
        Register(
            "axis_count", 2267, ValueType.U16, "§3.1.7, §4 row 2267", minimum=0, maximum=MAX_AXES
        ),
        *register_array(
            "axis_position",
            2268,
            MAX_AXES,
            ValueType.I32,
            "§3.1.8, §4 rows 2268-2283",
            scale=POSITION_SCALE,
            unit="deg",
        ),
    ]
    # §3.1.9 says "单位为 mm" for all eight; U, V, W are read as degrees (decision 14).
    for i, (axis, unit) in enumerate(
        [
            ("x", "mm"),
            ("y", "mm"),
            ("z", "mm"),
            ("u", "deg"),
            ("v", "deg"),
            ("w", "deg"),
            ("m7", ""),
            ("m8", ""),
        ]
    ):
        regs.append(
            Register(
                f"world_{axis}",
                2332 + 2 * i,
                ValueType.I32,
                "§3.1.9, §4 rows 2332-2347",
                scale=POSITION_SCALE,
                unit=unit,
            )
        )
    regs += [
        Register("alarm_code", 2396, ValueType.U16, "§3.1.10, §4 row 2396"),
        Register(
            "current_cycle_time", 2397, ValueType.U64, "§3.1.11, §4 rows 2397-2400", unit="ms"
        ),
        Register("last_cycle_time", 2401, ValueType.U64, "§3.1.11, §4 rows 2401-2404", unit="ms"),
        Register("machine_id", 2405, ValueType.U16, "§3.1.12, §4 row 2405"),
        *register_array(
            "axis_torque",
            2406,
            MAX_AXES,
            ValueType.I16,
            "§3.1.13, §4 rows 2406-2413",
            scale=TORQUE_RATED_RAW,
            unit="rated",
        ),
        *register_array(
            "axis_speed", 2438, MAX_AXES, ValueType.I16, "§3.1.14, §4 rows 2438-2445", unit="rpm"
        ),
        Register("moving", 2470, ValueType.U16, "§3.1.15, §4 row 2470"),
        Register("homed", 2471, ValueType.U16, "§4 row 2471"),
    ]
    regs += [
        Register(
            f"command_{name}",
            address,
            ValueType.U16,
            "§3.2.1, §4 rows 20000-20006",
            access=Access.WRITE,
        )
        for name, address in COMMANDS.items()
    ]
    regs += [
        Register(
            "counter_modify_id",
            20050,
            ValueType.U32,
            "§3.3.2, §4 rows 20050-20051",
            access=Access.WRITE,
        ),
        Register(
            "counter_modify_target",
            20052,
            ValueType.U32,
            "§3.3.2, §4 rows 20052-20053",
            access=Access.WRITE,
            description="ignored by the host",
        ),
        Register(
            "counter_modify_current",
            20054,
            ValueType.U32,
            "§3.3.2, §4 rows 20054-20055",
            access=Access.WRITE,
        ),
        Register(
            "output_board",
            20056,
            ValueType.U16,
            "§3.3.3, §4 row 20056",
            access=Access.WRITE,
            minimum=OUTPUT_BOARDS_ACCEPTED.start,
            maximum=OUTPUT_BOARDS_ACCEPTED.stop - 1,
        ),
        Register(
            "output_point",
            20057,
            ValueType.U16,
            "§3.3.3, §4 row 20057",
            access=Access.WRITE,
            minimum=OUTPUT_POINTS.start,
            maximum=OUTPUT_POINTS.stop - 1,
        ),
        Register(
            "output_state",
            20058,
            ValueType.U16,
            "§3.3.3, §4 row 20058",
            access=Access.WRITE,
            minimum=0,
            maximum=1,
        ),
        Register(
            "global_speed",
            20200,
            ValueType.U16,
            "§3.2.2, §4 row 20200",
            access=Access.READ_WRITE,
            scale=GLOBAL_SPEED_SCALE,
            unit="%",
            minimum=0.0,
            maximum=100.0,
        ),
        *(
            r
            for r in register_array(
                "parameter",
                PARAMETER_BASE,
                PARAMETER_COUNT,
                ValueType.I32,
                "§3.3.4, §4 rows 20300-22299",
                first_index=0,
                access=Access.READ_WRITE,
            )
            if not _overlaps_not_offered(r.address)
        ),
        Register(
            "data_source_view_id", 30000, ValueType.U16, "§4 row 30000", access=Access.READ_WRITE
        ),
        Register("data_source_buffer_length", 30001, ValueType.U16, "§4 row 30001"),
        Register(
            "point_source_id",
            30002,
            ValueType.U16,
            "§3.3.5, §4 row 30002",
            access=Access.READ_WRITE,
        ),
        Register(
            "point_values_per_point",
            30003,
            ValueType.U16,
            "§3.3.5, §4 row 30003",
            access=Access.READ_WRITE,
        ),
        Register(
            "point_axis_mask",
            30004,
            ValueType.U16,
            "§3.3.5, §4 row 30004",
            access=Access.READ_WRITE,
            minimum=0,
            maximum=POINT_AXIS_MASK_MAX,
        ),
        Register(
            "point_count", 30005, ValueType.U16, "§3.3.5, §4 row 30005", access=Access.READ_WRITE
        ),
        Register(
            "point_clear",
            30006,
            ValueType.U16,
            "§3.3.5, §4 row 30006",
            access=Access.READ_WRITE,
            minimum=0,
            maximum=1,
        ),
        *register_array(
            "point_data",
            POINT_DATA_FIRST,
            (POINT_DATA_LAST - POINT_DATA_FIRST + 1) // 2,  # 30007-40000 inclusive
            ValueType.I32,
            "§3.3.5, §4 rows 30007-40000",
            first_index=0,
            access=Access.WRITE,
        ),
    ]
    # §5: coils, 0xFF00 = on, 0x0000 = off.
    for name, first, count, doc in COIL_BANKS:
        regs += register_array(
            name,
            first,
            count,
            ValueType.BOOL,
            doc,
            first_index=0,
            table=Table.COIL,
            access=Access.READ_WRITE,
        )
    return tuple(regs)


# FC 03 reads, 06/10 writes, 01/05 coils (§5). FC 04 reads the same rows as FC 03 (§4's title
# "功能码 0x03、0x04、0x06、0x10 地址表定义"): the device serves it, this bridge reads with 03.
# Every block read the way the manual's examples read it: 32-bit rows from a value's first
# register in pairs (§3.1.6, §3.1.8, §3.1.9), 64-bit cycle times one at a time ("寄存器数量
# 固定为 4", §3.1.11), never a 16-bit row merged in front of them.
R6_LIMITS = DeviceLimits(
    function_codes=frozenset({1, 3, 4, 5, 6, 16}),
    read_undefined_ok=False,
    homogeneous_requests=True,
)
R6_MAP = RegisterMap("r6", _build(), R6_LIMITS)


def parameter_address(index: int) -> int:
    return PARAMETER_BASE + 2 * index
