"""Register map of the MOTEC β servo drive (Modbus RTU slave, RS-232 / RS-485 multi-drop).

Source: "MOTEC 伺服驱动器 MODBUS 操作手册" (seed 003, docs/manuals.md). Sections
cited below: §1.1.2 RS-485 (31 drives), §1.2-1.3 link settings (115200 8N1), §2 function
codes and §2.1-2.6 their frames, §2.7 exception replies, §3.1.1 FC 06 example (0x6D),
§3.1.2 FC 16 example (0x26) and the word order note, §3.2 FC 03 example (0xAC), §3.3 IO
(§3.3.1 FC 01 and 0xC6, §3.3.2 FC 02 and 0xC5, §3.3.3 FC 05 and 0x79, §3.3.4 0x109), §3.4
lifeguard (0x112, 0x114), §3.5 save to flash (0x35), §4.1 position mode steps 1-8, §4.2
velocity mode steps 1-5, §4.3 fault code (0xC8), §5 touch panels (Pr.N numbering).

The manual has NO register table: every register below comes from a worked example, and
the manual is silent on most ranges. Readings taken (also in docs/decisions/motec.md,
"MOTEC decision N"):

- Address = parameter number: §3.4 calls 0x112 / 0x114 "Pr.274" / "Pr.276" and §5.2
  calls 0x28 "Pr.40", 0x26-0x27 "Pr.38 和 Pr.39", 0xAE "174" (a touch panel adds 1).
  §5.1 also says "第 41 号参数是电机使能" for address 4100 (= Pr.40 + 1) and calls the
  start button's 4200 (= Pr.41 + 1) nothing: the +1 rule of §5.2 wins, 41 is the
  panel's number, not the parameter's.
- 32-bit values (distance 0x26, setpoint 0xAA, position 0xAC, fault 0xC8) are HIGH word
  first (§3.1.2 and §3.2 notes: 0x12345678 -> 0x1234 at the lower address). §5.1's
  "5x" / "4x" panel types only say that the panel's default 4x order is the other one;
  §5.1's "高八位" (high 8 bits) for a 16-bit word is a slip for the high word.
- The parameter table is contiguous (Pr.0 ... Pr.276 at least): §2.7 describes exception
  0x02 as a read running past the end of the table. So reads may span unnamed parameters
  (``read_undefined_ok``; the poll reads through 0x2A-0x2C and 0xC7), and the simulator
  serves every address up to 0x114, the highest the manual names. Unnamed parameters are
  never written.
- Operation mode 0x24: only 0 = network mode is given (§4.1 step 1); motion commands over
  Modbus need it (§4 "只有驱动器的操作模式是网络模式的时候"). Other values are shown as
  ``other(n)``.
- Control mode 0x25: 1 velocity (§4.2 step 2), 2 position (§4.1 step 2). §3.4 names a
  current mode too, without its value: shown as ``other(n)``, never written.
- Motion mode 0x2D: 0 relative, 1 absolute (§4.1 step 3).
- Enable 0x28: 1 enabled, 0 released (§4.1 step 4). Its "release" example echoes
  ``00 01`` in the reply: a copy error (an FC 06 reply repeats the request, §2.5).
- Start 0x29: 1 starts the move (§4.1 step 6). The register is titled "运动/停止寄存器"
  (move / stop register), so 0 is taken as "stop the move" (``~/stop`` in position mode).
- Speed setpoint 0xAE: signed rpm, sign = direction (§4.2 step 3). The same example's
  column calls it "设置最高速度" (set the maximum speed): in position mode it is taken as
  the move's speed limit (``~/move``'s ``max_velocity``). Actual speed 0xAF: signed rpm.
- Position setpoint 0xAA ("位置设定值") is taken as the trajectory's present command,
  0xAC ("位置实际值") as the encoder position, both int32 counts.
- Fault code 0xC8-0xC9: read as one 32-bit value, high word first (§4.3 reads 2
  registers). The manual's only texts: 0 "无故障" (no fault), 1 "有故障" (fault).
- Digital IO: 3 outputs (OUTPUT1-3), 8 inputs (INPUT1-8) (§3.3). The FC 01 / FC 02
  examples read 9 bits from address 0 and answer ``07 00`` / ``C0 00``: bit k is
  OUTPUT(k+1) / INPUT(k+1), so OUTPUTn is coil n-1 and the FC 05 example's address 2 is
  OUTPUT3 (its text says OUTPUT2: an error; "three outputs, all on" = 0x07 only holds
  with bit 0 = OUTPUT1). §3.3.2's "例如读取5个输入" with a count of 9 is the same copy
  slip. The coil / input tables are 16 bits wide ("以16位数据存储的 低位有效 高位用0
  补齐"); the byte count formula "(N/8) + (N mod 8)" is wrong for N = 3 (the example
  with N = 9 is right by chance): ceil(N/8), as Modbus says.
- §3.3.2 says inputs are read "只能使用02号功能码" (only with FC 02) and then that 0xC5
  holds them for FC 03: both are in the map; the poll uses 0xC5 / 0xC6 (one FC 03 with
  the fault code) and the device layer offers FC 01 / FC 02 too.
- Outputs: 0xC6 holds them (§3.3.1, FC 03); §3.3.3 says 0x79 holds them too and then
  that FC 06 "在0x00C6地址内的后6位" switches them. The bridge switches outputs with FC 05
  only (unambiguous); the simulator accepts FC 06 at 0x79 and 0xC6 alike (low 3 bits)
  and keeps both registers equal.
- Analog input 0x109: read only (§3.3.4); unit and sign not given: signed raw counts.
- Analog-mode max speed 0x6D (§3.1.1): unit not given; taken as rpm, 0-65535.
- Lifeguard 0x112 (ms, 0 = off) and 0x114 (9999 = on) (§3.4); it works only in network
  mode. What counts as a "指令信号" (command from the host) is not said: the bridge feeds
  the watchdog with a write (it rewrites 0x112), which also covers the strictest reading.
- Distance 0x26-0x27: signed 32-bit (§4.1 step 5 "32位有符号数"); the touch-panel
  example limits it to -2147483647 ... 2147483647 (§5.1), which the map enforces.
- Save 0x35: write 1, the drive clears it when done (§3.5).
- Ranges the manual does not give (speeds, analog max speed, lifeguard time) are the
  register's own; the node adds ``max_speed_rpm`` for speed commands.
- CRC: every frame table of §2-§4 lists "CRC 校验码高位" (high byte) before the low
  byte, but the drive is "与 MODBUS RTU 通讯规约相兼容" (§1.2) and §6's getCRC16 is the
  Modbus CRC: the low byte goes first on the wire, as in every Modbus RTU device (the
  tests check §6's routine against pymodbus).
- Velocity control: §4.2 step 4 says writing 1 to 0x28 starts the motor at the set
  speed. The bridge zeroes 0xAE before enabling in velocity control and before switching
  to it, so neither ``~/enable`` nor ``~/set_control_mode`` starts motion by itself.
- The manual gives no fault reset, no acceleration or profile-speed register, no
  "done" / "moving" flag addresses (§4.3 names such flags without addresses), no reply
  delay and no value for current control: the bridge does not invent them (``moving`` in
  ``~/state`` is derived from speed and setpoint); a fault is cleared by a restart, the
  only recovery the manual describes (§3.4, §3.5; MOTEC decision 16: the simulator keeps
  it latched until ``power_cycle``).
- Fault word halves, IO tables, parameters by number, RS-232 / RS-485, broadcast start:
  MOTEC decisions 7 and 12-15.
"""

from __future__ import annotations

import functools

from bridge_core.wire.registers import (
    Access,
    DeviceLimits,
    Register,
    RegisterMap,
    Table,
    ValueType,
    register_array,
)

RW = Access.READ_WRITE
R = Access.READ

# §1.3: "驱动器上电后默认的通讯速率为 115200bps"; §1.2: 8 data bits, no parity, 1 stop bit.
DEFAULT_BAUDRATE = 115200
# §2.1-2.6: "01~31 驱动器地址"; §1.1.2: "支持31台联网". 0 = broadcast (§2.4-2.6).
UNIT_IDS = range(1, 32)
BROADCAST_UNIT = 0
# §1.1.1: "RS232通讯口最多可以支持连接8台驱动器联网"; §1.1.2 RS-485: "支持31台联网". The
# line's kind is not visible on the wire: the bus node's ``interface`` parameter names it.
INTERFACE_RS485 = "rs485"
INTERFACE_RS232 = "rs232"
MAX_DRIVES = {INTERFACE_RS485: len(UNIT_IDS), INTERFACE_RS232: 8}
FUNCTION_CODES = frozenset({0x01, 0x02, 0x03, 0x05, 0x06, 0x10})  # §2 表 2
# The highest parameter the manual names (Pr.276, §3.4): the simulator's table ends here.
LAST_PARAMETER = 0x114

OUTPUTS = 3  # §3.3: "3路数字输出口"
INPUTS = 8  # §3.3: "8路数字输入口"
# Decision 6: OUTPUTn is coil n-1 (FC 01 example: "07" = three outputs on). §3.3.3's only
# FC 05 example writes "OUTPUT2" to 0x0002 (coil n): ``output1_coil`` = 1 follows it.
OUTPUT1_COIL_DEFAULT = 0
OUTPUT1_COIL_CHOICES = (0, 1)
BIT_TABLE_WIDTH = 16  # §3.3.1 / §3.3.2: "以16位数据存储的 ... 低位有效"

OPERATION_MODE_NETWORK = 0  # §4.1 step 1
CONTROL_MODE_VELOCITY = 1  # §4.2 step 2
CONTROL_MODE_POSITION = 2  # §4.1 step 2
CONTROL_MODES = {CONTROL_MODE_VELOCITY: "velocity", CONTROL_MODE_POSITION: "position"}
MOTION_RELATIVE = 0  # §4.1 step 3: "0-相对运行模式"
MOTION_ABSOLUTE = 1  # §4.1 step 3: "1-绝对运行模式"
ENABLE_ON = 1  # §4.1 step 4
ENABLE_OFF = 0
START_MOVE = 1  # §4.1 step 6
STOP_MOVE = 0  # decision: 0x29 is the "运动/停止寄存器"
SAVE_TO_FLASH = 1  # §3.5
LIFEGUARD_ACTIVE = 9999  # §3.4: "参数Pr.276为9999时 ... 启动lifeguard功能" (0x270F, §3.4.2)
LIFEGUARD_OFF_MS = 0  # §3.4: "当Pr.274为非零值 ..."
# §3.4 arms the lifeguard only with Pr.276 = 9999; any other mode leaves it off. The
# bridge writes 0 to disarm (the manual names no "off" value).
LIFEGUARD_MODE_OFF = 0
FAULT_NONE = 0  # §4.3: "0—无故障"
FAULT_PRESENT = 1  # §4.3: "1—有故障"
# The flag as the whole uint32 (0xC9 = 1) or as the high word §4.3 prints it beside
# (0xC8 = 1, 0xC9 = 0): which half a drive fills is not shown (decision 7).
FAULT_TEXTS = {
    FAULT_NONE: "no fault (无故障)",
    FAULT_PRESENT: "fault (有故障)",
    FAULT_PRESENT << 16: "fault (有故障)",
}

I32_MAX = (1 << 31) - 1
DISTANCE_MIN = -I32_MAX  # §5.1: "-2147483647~~2147483647"
DISTANCE_MAX = I32_MAX
I16_MAX = (1 << 15) - 1
U16_MAX = 0xFFFF


# A MOTEC register: (name, address, value type, manual reference, ...), read-only unless
# said otherwise; 32-bit values high word first (the Register default, decision 2).
_reg = functools.partial(Register, access=R)


# One table: a row per register the manual's examples name; splitting it would scatter the map.
def _build() -> tuple[Register, ...]:
    u16, i16, u32, i32 = ValueType.U16, ValueType.I16, ValueType.U32, ValueType.I32
    regs = [
        _reg(
            "operation_mode",
            0x24,
            u16,
            "§4.1 step 1",
            access=RW,
            minimum=0,
            maximum=U16_MAX,
            description="0 network mode (the only value the manual gives)",
        ),
        _reg(
            "control_mode",
            0x25,
            u16,
            "§4.1 step 2, §4.2 step 2",
            access=RW,
            minimum=0,
            maximum=U16_MAX,
            description="1 velocity, 2 position (current mode: value not given)",
        ),
        _reg(
            "target_distance",
            0x26,
            i32,
            "§3.1.2, §4.1 step 5, §5.1",
            access=RW,
            unit="counts",
            minimum=DISTANCE_MIN,
            maximum=DISTANCE_MAX,
            description="distance (relative) or target (absolute), high word first",
        ),
        _reg(
            "enable",
            0x28,
            u16,
            "§4.1 step 4, §4.2 step 4",
            access=RW,
            minimum=0,
            maximum=1,
            description="1 enable the motor, 0 release it",
        ),
        _reg(
            "start",
            0x29,
            u16,
            "§4.1 step 6",
            access=RW,
            minimum=0,
            maximum=1,
            description="1 start the move; 0 stop it (decision: '运动/停止寄存器')",
        ),
        _reg(
            "motion_mode",
            0x2D,
            u16,
            "§4.1 step 3",
            access=RW,
            minimum=0,
            maximum=1,
            description="0 relative, 1 absolute",
        ),
        _reg(
            "save_to_flash",
            0x35,
            u16,
            "§3.5",
            access=RW,
            minimum=0,
            maximum=1,
            description="write 1 to save the parameters to flash; the drive clears it",
        ),
        _reg(
            "analog_max_speed",
            0x6D,
            u16,
            "§3.1.1",
            access=RW,
            unit="rpm",
            minimum=0,
            maximum=U16_MAX,
            description="analog mode maximum speed (unit not given: rpm assumed)",
        ),
        _reg(
            "output_word",
            0x79,
            u16,
            "§3.3.3",
            access=RW,
            minimum=0,
            maximum=U16_MAX,
            description="digital outputs, bit k = OUTPUT(k+1); the bridge switches with FC 05",
        ),
        _reg(
            "position_setpoint",
            0xAA,
            i32,
            "§4.1 step 7",
            unit="counts",
            description="position setpoint (present trajectory command), high word first",
        ),
        _reg(
            "position_actual",
            0xAC,
            i32,
            "§3.2, §4.1 step 8",
            unit="counts",
            description="actual (encoder) position, high word first",
        ),
        _reg(
            "speed_setpoint",
            0xAE,
            i16,
            "§4.2 step 3, §5.2 (Pr.174)",
            access=RW,
            unit="rpm",
            minimum=-I16_MAX,
            maximum=I16_MAX,
            description="speed setpoint, sign = direction; position mode: speed limit",
        ),
        _reg("speed_actual", 0xAF, i16, "§4.2 step 5", unit="rpm", description="actual speed"),
        _reg(
            "input_word",
            0xC5,
            u16,
            "§3.3.2",
            description="digital inputs, bit k = INPUT(k+1)",
        ),
        _reg(
            "output_state",
            0xC6,
            u16,
            "§3.3.1, §3.3.3",
            access=RW,
            minimum=0,
            maximum=U16_MAX,
            description="digital outputs, bit k = OUTPUT(k+1) (§3.3.3: FC 06 writable)",
        ),
        _reg(
            "fault_code",
            0xC8,
            u32,
            "§4.3",
            description="0 no fault, 1 fault (the manual's only texts), high word first",
        ),
        _reg("analog_input", 0x109, i16, "§3.3.4", description="analog input, raw"),
        _reg(
            "lifeguard_time",
            0x112,
            u16,
            "§3.4, §3.4.1 (Pr.274)",
            access=RW,
            unit="ms",
            minimum=0,
            maximum=U16_MAX,
            description="lifeguard detection time, 0 = off",
        ),
        _reg(
            "lifeguard_mode",
            0x114,
            u16,
            "§3.4, §3.4.2 (Pr.276)",
            access=RW,
            minimum=0,
            maximum=U16_MAX,
            description="9999 = lifeguard on (with a non-zero time)",
        ),
    ]
    regs += register_array(
        "output",
        0,
        OUTPUTS,
        ValueType.BOOL,
        "§3.3.1 (FC 01), §3.3.3 (FC 05)",
        description_format="OUTPUT{index}",
        table=Table.COIL,
        access=RW,
    )
    regs += register_array(
        "input",
        0,
        INPUTS,
        ValueType.BOOL,
        "§3.3.2 (FC 02)",
        description_format="INPUT{index}",
        table=Table.DISCRETE_INPUT,
        access=R,
    )
    return tuple(regs)


MOTEC_LIMITS = DeviceLimits(
    function_codes=FUNCTION_CODES,
    # A contiguous parameter table (§2.7): reads may span unnamed parameters, in short gaps.
    read_undefined_ok=True,
    max_gap=16,
    # The manual states no reply delay.
    reply_delay_s=0.0,
)
MOTEC_MAP = RegisterMap("MOTEC β", _build(), MOTEC_LIMITS)


def output_coil(output: int, output1_coil: int = OUTPUT1_COIL_DEFAULT) -> int:
    """Protocol coil address of OUTPUT ``output`` (1-3): bit k = OUTPUT(k+1) (§3.3.1) with
    the default ``output1_coil`` 0; 1 reads §3.3.3's example ("OUTPUT2" at 0x0002)."""
    return output - 1 + output1_coil


# ``~/read_parameter`` / ``~/write_parameter`` (§3.1, §3.2, §5.2: Pr.N is address N). Only
# the parameters the manual names are known (it has no parameter list: no gains, no
# accelerations, MOTEC decision 13); a 32-bit one is addressed by its first (high) word.
# Writable through the service: the named writable parameters that start no motion and
# are not kept by the bridge itself; the others have their own guarded service.
PARAMETER_OWN_SERVICE = {
    "operation_mode": "~/set_control_mode",
    "control_mode": "~/set_control_mode",
    "enable": "~/enable",
    "start": "~/move, ~/stop or motec_bridge/start_all",
    "speed_setpoint": "~/move, ~/cmd_velocity or ~/stop",
    "lifeguard_time": "the lifeguard_ms parameter",
    "lifeguard_mode": "the lifeguard_ms parameter",
    "output_word": "~/set_output (FC 05, decision 6)",
    "output_state": "~/set_output (FC 05, decision 6)",
}


def parameter_register(number: int) -> Register | None:
    """The named holding register whose first address is Pr.``number``, if any."""
    for reg in MOTEC_MAP.in_table(Table.HOLDING):
        if reg.address == number:
            return reg
    return None


def parameter_numbers() -> list[int]:
    return sorted(reg.address for reg in MOTEC_MAP.in_table(Table.HOLDING))


def operation_mode_name(mode: int) -> str:
    return "network" if mode == OPERATION_MODE_NETWORK else f"other({mode})"


def control_mode_name(mode: int) -> str:
    return CONTROL_MODES.get(mode, f"other({mode})")


def fault_text(code: int) -> str:
    """The manual's meaning of a fault code (§4.3 gives only 0 and 1)."""
    if code in FAULT_TEXTS:
        return FAULT_TEXTS[code]
    return f"fault 0x{code:08X} (code not listed in the manual)"


__all__ = [
    "CONTROL_MODE_POSITION",
    "CONTROL_MODE_VELOCITY",
    "DEFAULT_BAUDRATE",
    "LIFEGUARD_ACTIVE",
    "LIFEGUARD_MODE_OFF",
    "MOTEC_LIMITS",
    "MOTEC_MAP",
    "OPERATION_MODE_NETWORK",
    "control_mode_name",
    "fault_text",
    "operation_mode_name",
    "output_coil",
    "parameter_numbers",
    "parameter_register",
]
