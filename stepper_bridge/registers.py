"""Register map of the 5-axis stepper motion controller (Modbus RTU, RS-232 / RS-485).

Source: the controller's Modbus manual (seed 002, docs/manuals.md). Section
names below: §2 protocol addresses, §3 default link settings, §4 function codes, §5(1)
holding registers, §5(2) coils, §5(3) special modes, §6 example frames.

Readings taken (also in docs/decisions/stepper.md, "stepper decision N"):

- Addresses: holding register 4000N is protocol address N-1, coil 0000N is address N-1
  (§2: "40001 对应协议寻址地址为 0x0000 ... 线圈寄存器地址 00003 对应协议地址也是 0x0002").
- 32-bit values (lead, run distance, coordinates, interpolation points, baud rate) are
  LOW word first (§6 note: "低16位在前,高16位在后"); bytes inside a word are big-endian.
- Every motor block is 10 registers: step angle, microstep, start frequency, accel
  frequency, direction, speed, lead (2), run distance (2). The §6(3) FC 10 example writes
  "run distance" at address 9-10 (40010-40011); the table (every motor alike) puts motor
  1's distance at 40009-40010 = address 8-9. The table wins: address 9-10 would overwrite
  motor 1's distance high word and motor 2's step angle, so the bridge never sends that
  frame (and the simulator refuses it: it cuts a 32-bit value).
- The §6(4) FC 05 example writes coil address 7 and calls it "single run"; address 7 is
  coil 00008, motor 2 reverse (table). The table wins; the example frame is exactly what
  the bridge sends for motor 2 reverse.
- Outputs 00049-00072 are pairs: output n is switched ON by writing 0xFF00 to coil
  00049 + 2(n-1) and OFF by writing 0xFF00 to coil 00050 + 2(n-1) ("第1路输出开、关";
  24 coils for 12 outputs). 0x0000 to either coil is never sent.
- Scales: step angle x100 (§5(1) 40001: "1.80 ... 实际上数据交互为 180"), lead and run
  distance x100 (40007: "设定 1.00,则实际数据交互为 100"). The realtime coordinates
  (40108+) and the interpolation points are taken to be in the same unit as lead and run
  distance (x100 of the user's unit), which makes "回数据零" (coil 00045: distance 2.00
  run back until the coordinate shows 0) consistent.
- Motor 2's row 40019 says "点动一次移动的距离" (distance of one jog) where motors 1, 3-5
  say "单次运行的距离" (distance of one single run): the same register per motor block.
- Direction (40005+): 0 positive, 1 negative; it is the single run's direction. The
  forward / reverse coils name their direction themselves (§5(2) "按照...速度正方向运行").
- Limits: FC 03/05/06/10 only (§4); at most 49 registers per read or write ("<50");
  replies no sooner than 35 ms on RS-485 (§3). No FC 01: coil-backed state comes from the
  status registers 40124-40172. Undefined rows (40051-40080, 40096-40107, 40118-40123,
  40137-40147, 40160-40167, 40173-40176, 40215-40299) are not in the map: the planner
  never reads through them and the simulator answers 0x02.
- Interpolation pair types (40182 / 40202): the type rows say 1 = motors 1+2, 2 = 1+3,
  3 = 2+3; the point rows below them say 2 = 2+3, 3 = 1+3. Descriptions follow the type
  rows (INTERPOLATION_PAIRS); types 2 and 3 are refused until the node's
  interpolation_pair_reading says which reading the controller follows.
- Value ranges: where the manual gives one (direction 0/1, input numbers 1-13 or 0 for
  none, homing order 0-5, interpolation type 0-3, arc mode and direction 0/1, device id
  1-255, system mode 0-5, baud rates 4800/9600/19200/38400) it is enforced; elsewhere the
  register's own range, and > 0 where a zero would make the motor math meaningless (step
  angle, microstep, lead).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from bridge_core.wire.registers import (
    Access,
    DeviceLimits,
    Register,
    RegisterMap,
    Table,
    ValueType,
    WordOrder,
)
from bridge_core.wire.serial_timing import char_time_s

if TYPE_CHECKING:
    from bridge_core.wire.transport import SerialSettings

H = "§5(1) holding"
C = "§5(2) coil"
M = "§5(3) special mode"
LOW = WordOrder.LOW_FIRST
RW = Access.READ_WRITE

MOTORS = 5
INPUTS = 13
OUTPUTS = 12
MOTOR_BLOCK = 10  # registers per motor's basic parameters
MOTOR_COILS = 5  # coils per motor: single run, forward, reverse, home, stop
DISTANCE_SCALE = 100  # lead, run distance, coordinates: x100 of the user's unit
STEP_ANGLE_SCALE = 100
U16_MAX = 0xFFFF
U32_MAX = 0xFFFF_FFFF
U32_SCALED_MAX = U32_MAX / DISTANCE_SCALE
I32_SCALED_MIN = -(1 << 31) / DISTANCE_SCALE
I32_SCALED_MAX = ((1 << 31) - 1) / DISTANCE_SCALE

# §3: "485 接口通信时每帧数据响应时间不能低于 35ms".
REPLY_DELAY_S = 0.035
MAX_REGISTERS_PER_REQUEST = 49  # §4: "可连续读取<50 个寄存器", "可连续写<50 个寄存器"
# The longest reply: a read of 49 registers (unit, function, byte count, 98 data bytes, CRC).
LONGEST_REPLY_BYTES = 5 + 2 * MAX_REGISTERS_PER_REQUEST
# The reply timeout counts from the request's last byte, so it must cover those 35 ms and
# the longest reply (107 ms at 9600 baud, 215 ms at 4800), plus a margin, rounded up to
# 10 ms: 0.15 s at 9600 baud 8N1, 0.26 s at 4800, 0.10 s at 19200, 0.07 s at 38400
# (``reply_timeout_floor_s``; stepper decision 7). A lower ``timeout_s`` is refused at
# start (stepper_bridge.node). The other reading (the host must leave 35 ms between
# frames) is served by ``frame_gap_s``.
TIMEOUT_MARGIN_S = 0.005
TIMEOUT_STEP_S = 0.01
FUNCTION_CODES = frozenset({0x03, 0x05, 0x06, 0x10})  # §4
DEFAULT_BAUDRATE = 9600  # §3
BAUD_RATES = (4800, 9600, 19200, 38400)  # §5(1) 40213: "一般为:4800,9600,19200,38400"
SYSTEM_MODES = range(0, 6)  # §5(3) 40300: 0 normal, modes 1-5
# §5(1) 40212: "范围 1-255": the register's range. A request can address only 1-247 (Modbus
# RTU; 248-255 are reserved), so the bridge's unit ids stop there (bridge_core.wire.channel).
DEVICE_IDS = range(1, 256)

# Fields of a motor block, in address order: (field, offset, type, scale, unit, min, max).
MOTOR_FIELDS: tuple[tuple[str, int, ValueType, float, str, float, float], ...] = (
    ("step_angle", 0, ValueType.U16, STEP_ANGLE_SCALE, "deg", 0.01, U16_MAX / STEP_ANGLE_SCALE),
    ("microstep", 1, ValueType.U16, 1, "", 1, U16_MAX),
    ("start_frequency", 2, ValueType.U16, 1, "Hz", 0, U16_MAX),
    ("accel_frequency", 3, ValueType.U16, 1, "Hz", 0, U16_MAX),
    ("direction", 4, ValueType.U16, 1, "", 0, 1),
    ("speed", 5, ValueType.U16, 1, "rpm", 0, U16_MAX),
    ("lead", 6, ValueType.U32, DISTANCE_SCALE, "unit/rev", 0.01, U32_SCALED_MAX),
    ("run_distance", 8, ValueType.U32, DISTANCE_SCALE, "unit", 0, U32_SCALED_MAX),
)
MOTOR_FIELD_NAMES = tuple(f[0] for f in MOTOR_FIELDS)

# Coils per motor, offset within the motor's 5 coils (§5(2) 00001-00025).
MOTOR_ACTIONS = ("run_once", "forward", "reverse", "home", "stop")

# All-motor and system coils: name -> coil number 0000N (protocol address N-1).
SYSTEM_COILS: dict[str, int] = {
    "emergency_stop": 42,  # 系统急停: every motor stops, every output off
    "zero_coordinates": 44,  # 坐标清零
    "return_to_zero": 45,  # 回数据零: run back until the coordinates read 0
    "home_all": 46,  # 顺序回零: mechanical home in the 40177-40181 order
    "factory_reset": 73,  # 电机参数初始化: 恢复出厂设置
    "save_parameters": 96,  # 数据保存
    "clear_all_parameters": 97,  # 数据清零: every parameter 0
    "all_outputs_on": 98,
    "all_outputs_off": 99,
    "arc_start": 100,
    "arc_stop": 101,
    "line_start": 102,
    "line_stop": 103,
}
OUTPUT_COIL_FIRST = 49  # 00049-00072: output n on = 49 + 2(n-1), off = 50 + 2(n-1)

# Interpolation pairs: type -> (first motor, second motor), 0 = none. The manual reads the
# type two ways (stepper decision 11):
# - the type rows 40182 and 40202: "设定1表示电机1、2实现插补;设定2表示电机1,3实现插补;
#   设定3表示2,3电机插补" (1 = motors 1+2, 2 = 1+3, 3 = 2+3);
# - every point row (40184-40199, 40203-40210): first coordinate "若为类型 1、3,则为 1 号
#   电机...;若为类型 2, 则为 2 号电机", second "若为类型 1,则为 2 号电机...;若为类型2、3,
#   则为3号电机" (1 = 1+2, 2 = 2+3, 3 = 1+3).
# Descriptions follow the type rows: they define the register written, say it identically
# twice, and name the pairs in order. Types 2 and 3 are refused until the node's
# interpolation_pair_reading names the reading a hardware check showed (stepper
# decision 19, stepper_bridge.interpolation.pair_axes).
INTERPOLATION_PAIRS: dict[int, tuple[int, int]] = {1: (1, 2), 2: (1, 3), 3: (2, 3)}
# The point rows' reading, kept to tell which motors the two readings disagree on.
INTERPOLATION_PAIRS_POINT_ROWS: dict[int, tuple[int, int]] = {1: (1, 2), 2: (2, 3), 3: (1, 3)}
ARC_MODE_CENTER = 0  # 40183 = 0: start, end and centre points
ARC_MODE_THREE_POINTS = 1  # 40183 = 1: start, end and a middle point
# §5(1) "其中4号电机不能运行" during line or arc interpolation.
MOTOR_FORBIDDEN_DURING_INTERPOLATION = 4
# 40182-40211, in address order: arc (40182-40201) then line (40202-40211). §5(1) 40201 /
# 40211: "插补过程运行中不可调节" (not adjustable while an interpolation runs).
ARC_REGISTERS = (
    "arc_pair",
    "arc_mode",
    "arc_start_a",
    "arc_start_b",
    "arc_end_a",
    "arc_end_b",
    "arc_center_a",
    "arc_center_b",
    "arc_via_a",
    "arc_via_b",
    "arc_direction",
    "arc_speed",
)
LINE_REGISTERS = (
    "line_pair",
    "line_start_a",
    "line_start_b",
    "line_end_a",
    "line_end_b",
    "line_speed",
)
INTERPOLATION_REGISTERS = ARC_REGISTERS + LINE_REGISTERS
# Link settings (40212-40214): read into diagnostics, never written by the bridge (a write
# would move the controller off the id / baud rate the bridge talks to; stepper decision 13).
LINK_REGISTERS = ("device_id", "baud_rate")


def holding(plc: int) -> int:
    """Protocol address of holding register 4000N (§2)."""
    return plc - 40001


def coil(plc: int) -> int:
    """Protocol address of coil 0000N (§2)."""
    return plc - 1


def motor_base(motor: int) -> int:
    return (motor - 1) * MOTOR_BLOCK


def motor_register(motor: int, field: str) -> str:
    return f"motor{motor}_{field}"


def motor_coil(motor: int, action: str) -> int:
    """Protocol address of a motor's command coil (§5(2) 00001-00025)."""
    return (motor - 1) * MOTOR_COILS + MOTOR_ACTIONS.index(action)


def output_coil(output: int, on: bool) -> int:
    """Protocol address of output ``output``'s ON (or OFF) coil (decision on 00049-00072)."""
    return coil(OUTPUT_COIL_FIRST + 2 * (output - 1) + (0 if on else 1))


def _reg(
    name: str,
    plc: int,
    value_type: ValueType = ValueType.U16,
    *,
    access: Access = RW,
    scale: float = 1.0,
    unit: str = "",
    minimum: float | None = None,
    maximum: float | None = None,
    doc: str = H,
    description: str = "",
) -> Register:
    return Register(
        name=name,
        address=holding(plc),
        value_type=value_type,
        doc=f"{doc} {plc}" if value_type.words == 1 else f"{doc} {plc}-{plc + 1}",
        access=access,
        word_order=LOW,
        scale=scale,
        unit=unit,
        minimum=minimum,
        maximum=maximum,
        description=description,
    )


def _point(name: str, plc: int, description: str) -> Register:
    """An absolute interpolation coordinate: int32 low word first, x100 user units."""
    return _reg(
        name,
        plc,
        ValueType.I32,
        scale=DISTANCE_SCALE,
        unit="unit",
        minimum=I32_SCALED_MIN,
        maximum=I32_SCALED_MAX,
        description=description,
    )


def _coil_register(name: str, plc: int, description: str) -> Register:
    # Coils are write-only: the device has no FC 01 (§4).
    return Register(
        name=name,
        address=coil(plc),
        value_type=ValueType.BOOL,
        doc=f"{C} {plc:05d}",
        table=Table.COIL,
        access=Access.WRITE,
        description=description,
    )


# One table: the manual's §5 rows in address order; splitting it would scatter the map.
def _build() -> tuple[Register, ...]:
    regs: list[Register] = []
    # Motor 1-5 basic parameters, 40001-40050.
    for motor in range(1, MOTORS + 1):
        for field, offset, value_type, scale, unit, low, high in MOTOR_FIELDS:
            regs.append(
                _reg(
                    motor_register(motor, field),
                    40001 + motor_base(motor) + offset,
                    value_type,
                    scale=scale,
                    unit=unit,
                    minimum=low,
                    maximum=high,
                    description=f"motor {motor} {field.replace('_', ' ')}",
                )
            )
    # Input assignment of each motor's limits and home switch, 40081-40095 (0 = none).
    for motor in range(1, MOTORS + 1):
        for k, field in enumerate(("positive_limit_input", "negative_limit_input", "home_input")):
            regs.append(
                _reg(
                    motor_register(motor, field),
                    40081 + 3 * (motor - 1) + k,
                    minimum=0,
                    maximum=INPUTS,
                    description=f"motor {motor} {field.replace('_', ' ')} (input 1-13, 0 none)",
                )
            )
    # Realtime coordinates, 40108-40117, signed 32-bit.
    for motor in range(1, MOTORS + 1):
        regs.append(
            _reg(
                motor_register(motor, "coordinate"),
                40108 + 2 * (motor - 1),
                ValueType.I32,
                access=Access.READ,
                scale=DISTANCE_SCALE,
                unit="unit",
                description=f"motor {motor} realtime coordinate",
            )
        )
    # Status registers: inputs 1-13, outputs 1-12, motors running 1-5 (1 = ON).
    regs += [
        _reg(f"input_{n}", 40123 + n, access=Access.READ, description=f"input {n} state")
        for n in range(1, INPUTS + 1)
    ]
    regs += [
        _reg(f"output_{n}", 40147 + n, access=Access.READ, description=f"output {n} state")
        for n in range(1, OUTPUTS + 1)
    ]
    regs += [
        _reg(
            motor_register(m, "running"),
            40167 + m,
            access=Access.READ,
            description=f"motor {m} running",
        )
        for m in range(1, MOTORS + 1)
    ]
    # Mechanical homing order, 40177-40181: 0 none, 1-5 a motor.
    regs += [
        _reg(
            f"homing_order_{k}",
            40176 + k,
            minimum=0,
            maximum=MOTORS,
            description=f"motor homed {k}th by home_all (0 none)",
        )
        for k in range(1, MOTORS + 1)
    ]
    # Arc interpolation, 40182-40201.
    regs += [
        _reg("arc_pair", 40182, minimum=0, maximum=3, description="0 none, 1: 1+2, 2: 1+3, 3: 2+3"),
        _reg("arc_mode", 40183, minimum=0, maximum=1, description="0 start/end/centre, 1 3 points"),
        # Point descriptions follow the type rows' reading (INTERPOLATION_PAIRS).
        _point("arc_start_a", 40184, "first motor's start (type 1, 2: motor 1; 3: motor 2)"),
        _point("arc_start_b", 40186, "second motor's start (type 1: motor 2; 2, 3: motor 3)"),
        _point("arc_end_a", 40188, "first motor's end"),
        _point("arc_end_b", 40190, "second motor's end"),
        _point("arc_center_a", 40192, "first motor's centre"),
        _point("arc_center_b", 40194, "second motor's centre"),
        _point("arc_via_a", 40196, "first motor's middle point"),
        _point("arc_via_b", 40198, "second motor's middle point"),
        _reg("arc_direction", 40200, minimum=0, maximum=1, description="0 clockwise, 1 ccw"),
        _reg("arc_speed", 40201, unit="rpm", minimum=0, maximum=U16_MAX),
    ]
    # Line interpolation, 40202-40211.
    regs += [
        _reg("line_pair", 40202, minimum=0, maximum=3, description="as arc_pair"),
        _point("line_start_a", 40203, "first motor's start (type 1, 2: motor 1; 3: motor 2)"),
        _point("line_start_b", 40205, "second motor's start (type 1: motor 2; 2, 3: motor 3)"),
        _point("line_end_a", 40207, "first motor's end"),
        _point("line_end_b", 40209, "second motor's end"),
        _reg("line_speed", 40211, unit="rpm", minimum=0, maximum=U16_MAX),
    ]
    # Device id and baud rate, 40212-40214 (the baud rate takes effect at once).
    regs += [
        _reg("device_id", 40212, minimum=DEVICE_IDS.start, maximum=DEVICE_IDS.stop - 1),
        _reg(
            "baud_rate",
            40213,
            ValueType.U32,
            unit="baud",
            minimum=min(BAUD_RATES),
            maximum=max(BAUD_RATES),
        ),
    ]
    # Special modes, 40300-40305.
    regs.append(
        _reg(
            "system_mode",
            40300,
            minimum=SYSTEM_MODES.start,
            maximum=SYSTEM_MODES.stop - 1,
            doc=M,
            description="0 normal, 1-5 input-driven modes",
        )
    )
    regs += [
        _reg(
            motor_register(m, "reciprocations"),
            40300 + m,
            minimum=0,
            maximum=U16_MAX,
            doc=M,
            description=f"mode 1 round trips of motor {m} (0 = endless)",
        )
        for m in range(1, MOTORS + 1)
    ]
    # Coils (write only).
    for motor in range(1, MOTORS + 1):
        for k, action in enumerate(MOTOR_ACTIONS):
            regs.append(
                _coil_register(
                    motor_register(motor, action),
                    1 + (motor - 1) * MOTOR_COILS + k,
                    f"motor {motor} {action.replace('_', ' ')}",
                )
            )
    for name, plc in SYSTEM_COILS.items():
        regs.append(_coil_register(name, plc, name.replace("_", " ")))
    for n in range(1, OUTPUTS + 1):
        first = OUTPUT_COIL_FIRST + 2 * (n - 1)
        regs.append(_coil_register(f"output_{n}_on", first, f"output {n} on"))
        regs.append(_coil_register(f"output_{n}_off", first + 1, f"output {n} off"))
    return tuple(regs)


STEPPER_LIMITS = DeviceLimits(
    max_read_registers=MAX_REGISTERS_PER_REQUEST,
    max_write_registers=MAX_REGISTERS_PER_REQUEST,
    function_codes=FUNCTION_CODES,
    reply_delay_s=REPLY_DELAY_S,
    read_undefined_ok=False,
)
STEPPER_MAP = RegisterMap("stepper", _build(), STEPPER_LIMITS)

# Undefined holding rows (PLC numbers, inclusive): nothing is read or written there.
UNDEFINED_HOLDING = (
    (40051, 40080),
    (40096, 40107),
    (40118, 40123),
    (40137, 40147),
    (40160, 40167),
    (40173, 40176),
    (40215, 40299),
)


def reply_timeout_floor_s(settings: SerialSettings) -> float:
    """The least reply timeout the manual's 35 ms rule allows on this line (s)."""
    char = char_time_s(settings.baudrate, settings.bytesize, settings.parity, settings.stopbits)
    least = REPLY_DELAY_S + LONGEST_REPLY_BYTES * char + TIMEOUT_MARGIN_S
    return math.ceil(round(least / TIMEOUT_STEP_S, 6)) * TIMEOUT_STEP_S
