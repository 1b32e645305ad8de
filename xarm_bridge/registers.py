"""Register map of the UFactory xArm controller's Modbus TCP interface.

Source: "UF_ModbusTCP_Manual" (seed 001, docs/manuals.md), its appendix
tables: coils (C), discrete inputs (D), holding registers (H), input registers (I).

Readings taken (also in docs/decisions/xarm.md, "xArm decision N"):

- All values are 16-bit big-endian; scaled values (x10, x1000) are signed 16-bit
  (docs/manuals.md, "Word order and framing, per device"); the 32-bit counter I34-35 is
  high word first ("0x22 存储计数器的高16位").
- Joint temperatures: the table says "86 ~ 102 | 0x60~0x66"; 86 would overlap the TCP and
  base offsets and the joint angles, so the hex column (96-102, 7 joints) wins.
- The "reserved 36 ~ 63 | 0x23 ~0x3F" row: 0x23 is the counter's low word; 36 (0x24) wins.
- Only the channels the manual calls valid ("当前仅16路/2路有效") are exposed for writing:
  controller DO 0-15, tool DO 0-1, controller AO 0-1; tool AO has "0 路有效": none. The
  map keeps every address the table defines so the simulator serves them all.
- Arm mode H32 / state H33 values are not in the Modbus manual; the xArm SDK's are used
  (mode 0-13 as the C146-159 motion-mode coils; set_state 0 = start, 3 = pause, 4 = stop).
- IO state is read bit by bit (FC 01/02), which the manual defines unambiguously, rather
  than from the DI/DO words. Their bit order (bit n of H0 = DO n, H1 = DO 16-31) is xArm
  decision 9; only the device layer's FC 0x16 mask write relies on it.
- Arms with fewer than 7 joints (xArm 5, xArm 6, Lite 6): ``joint_count`` of the node
  (xArm decision 11); the map keeps all seven rows of every per-joint table.
"""

from __future__ import annotations

from bridge_core.wire.registers import (
    Access,
    DeviceLimits,
    Register,
    RegisterMap,
    Table,
    ValueType,
    register_array,
)

A = "appendix"
JOINTS = 7  # rows per joint table (J1-J7); an arm has JOINT_COUNTS of them
JOINT_COUNTS = range(5, JOINTS + 1)  # xArm 5, xArm 6 and Lite 6, xArm 7
CONTROLLER_DIGITAL_CHANNELS = 32
CONTROLLER_DIGITAL_VALID = 16
TOOL_DIGITAL_CHANNELS = 8
TOOL_DIGITAL_VALID = 2
ANALOG_CHANNELS = 4
CONTROLLER_ANALOG_OUTPUT_VALID = 2
CONTROLLER_ANALOG_INPUT_VALID = 2
TOOL_ANALOG_INPUT_VALID = 2
ANALOG_SCALE = 1000  # "寄存器的值是实际值的1000倍"
POSE_SCALE = 10  # "寄存器的值是实际值的10倍"
MOTION_MODES = 14  # C146-159: modes 0-13
OFFLINE_TASK_ADDRESS = 0x30
OFFLINE_TASK_MAX = 16  # "往0x30地址写最多16个寄存器"
# Analog output range in volts: the Modbus manual gives none; the xArm SDK's
# set_cgpio_analog takes 0-10 V.
ANALOG_OUTPUT_MIN_V = 0.0
ANALOG_OUTPUT_MAX_V = 10.0

FIRST_TOOL_DIGITAL = 32
BRAKE_FIRST = 128
ENABLE_FIRST = 135
COIL_REDUCED_MODE = 142
COIL_FENCE_MODE = 143
COIL_PAUSED = 144
COIL_STOPPED = 145
MOTION_MODE_FIRST = 146
USER_COILS = range(256, 512)  # "用户自定义使用"

# xArm SDK values for H33 writes (set_state) and reads (get_state).
SET_STATE_START = 0
SET_STATE_PAUSE = 3
SET_STATE_STOP = 4
SETTABLE_STATES = (SET_STATE_START, SET_STATE_PAUSE, SET_STATE_STOP)
STATE_NAMES = {
    1: "in motion",
    2: "sleeping",
    3: "paused",
    4: "stopped",
    5: "config changed",
}
MODE_NAMES = {
    0: "position",
    1: "servo",
    2: "joint teaching",
    3: "cartesian teaching",
    4: "joint velocity",
    5: "cartesian velocity",
    6: "joint online trajectory",
    7: "cartesian online trajectory",
}

# Controller error and warning texts: the Modbus manual has none; these are the xArm
# Python SDK's code tables (doc/api/xarm_api_code.md) and UFACTORY's control-box codes.
ERROR_TEXTS = {
    1: "emergency stop button on the control box pushed",
    2: "emergency IO of the control box triggered",
    3: "emergency stop button of the three-state switch pressed",
    10: "servo motor error",
    **{10 + j: f"servo motor {j} error" for j in range(1, JOINTS + 1)},
    19: "tool GPIO error",
    21: "kinematic error",
    22: "collision error",
    23: "joints angle exceed limit",
    24: "speed exceeds limit",
    25: "planning error",
    26: "Linux RT error",
    27: "command reply error",
    28: "gripper error",
    29: "other errors",
    30: "teach mode current abnormality",
    31: "collision caused abnormal current",
    33: "controller GPIO error",
}
WARNING_TEXTS = {
    11: "command buffer full",
    12: "parameter error",
    13: "the instruction does not exist",
    14: "command has no solution",
}

WORLD = ("x", "y", "z", "roll", "pitch", "yaw")
ROTATION_VECTOR = ("rx", "ry", "rz")  # I70-72: the TCP orientation as axis times angle (deg)
# The pose's roll/pitch/yaw and the rotation vector rx/ry/rz are two readings of one
# orientation, each rounded to 0.1 deg per value: they agree within ~0.2 deg. More than
# this says the Euler convention of ~/tcp_pose (docs/bridges/r6.md) is not the controller's
# (xArm decision 13: the node's diagnostics and bridge_commission's check).
ORIENTATION_MISMATCH_DEG = 1.0


def _scaled(name: str, address: int, scale: float, unit: str, doc: str) -> Register:
    """A signed 16-bit input register scaled by 10 or 1000 (docs/manuals.md, word order)."""
    return Register(name, address, ValueType.I16, doc, table=Table.INPUT, scale=scale, unit=unit)


def _coils(name: str, first: int, count: int, doc: str, first_index: int = 0) -> list[Register]:
    return register_array(
        name,
        first,
        count,
        ValueType.BOOL,
        doc,
        first_index=first_index,
        table=Table.COIL,
        access=Access.READ_WRITE,
    )


def _coil(name: str, address: int, doc: str) -> Register:
    return Register(name, address, ValueType.BOOL, doc, table=Table.COIL, access=Access.READ_WRITE)


# One table: the manual's appendix tables (C, D, H, I) in order; splitting it would scatter the map.
def _build() -> tuple[Register, ...]:
    regs: list[Register] = [
        *_coils("controller_do", 0, CONTROLLER_DIGITAL_CHANNELS, f"{A} coils 0-31"),
        *_coils("tool_do", FIRST_TOOL_DIGITAL, TOOL_DIGITAL_CHANNELS, f"{A} coils 32-39"),
        *_coils("brake", BRAKE_FIRST, JOINTS, f"{A} coils 128-134", first_index=1),
        *_coils("enable", ENABLE_FIRST, JOINTS, f"{A} coils 135-141", first_index=1),
        _coil("reduced_mode", COIL_REDUCED_MODE, f"{A} coil 142"),
        _coil("fence_mode", COIL_FENCE_MODE, f"{A} coil 143"),
        _coil("paused", COIL_PAUSED, f"{A} coil 144"),
        _coil("stopped", COIL_STOPPED, f"{A} coil 145"),
        *_coils("motion_mode", MOTION_MODE_FIRST, MOTION_MODES, f"{A} coils 146-159"),
        *_coils("user_coil", USER_COILS.start, len(USER_COILS), f"{A} coils 256-511"),
        # Discrete inputs.
        *register_array(
            "controller_di",
            0,
            CONTROLLER_DIGITAL_CHANNELS,
            ValueType.BOOL,
            f"{A} discrete inputs 0-31",
            first_index=0,
            table=Table.DISCRETE_INPUT,
        ),
        *register_array(
            "tool_di",
            FIRST_TOOL_DIGITAL,
            TOOL_DIGITAL_CHANNELS,
            ValueType.BOOL,
            f"{A} discrete inputs 32-39",
            first_index=0,
            table=Table.DISCRETE_INPUT,
        ),
        # Holding registers.
        *register_array(
            "controller_do_word",
            0,
            2,
            ValueType.U16,
            f"{A} holding 0-1",
            first_index=0,
            access=Access.READ_WRITE,
        ),
        Register("tool_do_word", 2, ValueType.U16, f"{A} holding 2", access=Access.READ_WRITE),
        *register_array(
            "controller_ao",
            3,
            ANALOG_CHANNELS,
            ValueType.I16,
            f"{A} holding 3-6",
            first_index=0,
            access=Access.READ_WRITE,
            scale=ANALOG_SCALE,
            unit="V",
            minimum=ANALOG_OUTPUT_MIN_V,
            maximum=ANALOG_OUTPUT_MAX_V,
        ),
        *register_array(
            "tool_ao",
            7,
            ANALOG_CHANNELS,
            ValueType.I16,
            f"{A} holding 7-10",
            first_index=0,
            access=Access.READ_WRITE,
            scale=ANALOG_SCALE,
            unit="V",
        ),
        Register(
            "arm_mode",
            32,
            ValueType.I16,
            f"{A} holding 32",
            access=Access.READ_WRITE,
            minimum=0,
            maximum=MOTION_MODES - 1,
        ),
        Register("arm_state", 33, ValueType.I16, f"{A} holding 33", access=Access.READ_WRITE),
        *register_array(
            "offline_task",
            OFFLINE_TASK_ADDRESS,
            OFFLINE_TASK_MAX,
            ValueType.U16,
            f"{A} holding 48-63",
            first_index=0,
            access=Access.WRITE,
        ),
        # Input registers.
        *register_array(
            "controller_di_word",
            0,
            2,
            ValueType.U16,
            f"{A} input 0-1",
            first_index=0,
            table=Table.INPUT,
        ),
        Register("tool_di_word", 2, ValueType.U16, f"{A} input 2", table=Table.INPUT),
        *[
            _scaled(f"controller_ai_{i}", 3 + i, ANALOG_SCALE, "V", f"{A} input 3-6")
            for i in range(ANALOG_CHANNELS)
        ],
        *[
            _scaled(f"tool_ai_{i}", 7 + i, ANALOG_SCALE, "V", f"{A} input 7-10")
            for i in range(ANALOG_CHANNELS)
        ],
        Register("error_code", 32, ValueType.U16, f"{A} input 32", table=Table.INPUT),
        Register("warning_code", 33, ValueType.U16, f"{A} input 33", table=Table.INPUT),
        Register("counter", 34, ValueType.U32, f"{A} input 34-35", table=Table.INPUT),
    ]
    for i, axis in enumerate((*WORLD, *ROTATION_VECTOR)):
        unit = "mm" if i < 3 else "deg"
        regs.append(_scaled(f"tcp_{axis}", 64 + i, POSE_SCALE, unit, f"{A} input 64-72"))
    regs.append(_scaled("tcp_load_mass", 73, ANALOG_SCALE, "kg", f"{A} input 73"))
    for i, axis in enumerate(("x", "y", "z")):
        regs.append(
            _scaled(f"tcp_load_center_{axis}", 74 + i, POSE_SCALE, "mm", f"{A} input 74-76")
        )
    for i, axis in enumerate(WORLD):
        unit = "mm" if i < 3 else "deg"
        regs.append(_scaled(f"tcp_offset_{axis}", 77 + i, POSE_SCALE, unit, f"{A} input 77-82"))
        regs.append(_scaled(f"base_offset_{axis}", 83 + i, POSE_SCALE, unit, f"{A} input 83-88"))
    regs += [
        _scaled(f"joint_angle_{j}", 88 + j, POSE_SCALE, "deg", f"{A} input 89-95")
        for j in range(1, JOINTS + 1)
    ]
    regs += [
        Register(
            f"joint_temperature_{j}",
            95 + j,
            ValueType.I16,
            f"{A} input 0x60-0x66 (96-102)",
            table=Table.INPUT,
            unit="degC",
        )
        for j in range(1, JOINTS + 1)
    ]
    regs += [
        _scaled(f"joint_speed_{j}", 102 + j, POSE_SCALE, "deg/s", f"{A} input 103-109")
        for j in range(1, JOINTS + 1)
    ]
    regs.append(_scaled("tcp_speed", 110, POSE_SCALE, "mm/s", f"{A} input 110"))
    return tuple(regs)


# FC 01 02 03 04 05 06 0F 10 16 17 ("各种寄存器所支持的ModbusTCP功能码").
XARM_LIMITS = DeviceLimits(
    function_codes=frozenset({0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F, 0x10, 0x16, 0x17}),
    read_undefined_ok=False,
)
XARM_MAP = RegisterMap("xarm", _build(), XARM_LIMITS)

# Writable channels the manual calls valid; everything else is refused before the wire.
WRITABLE_DIGITAL_OUTPUTS = range(0, CONTROLLER_DIGITAL_VALID)
WRITABLE_TOOL_DIGITAL_OUTPUTS = range(0, TOOL_DIGITAL_VALID)
WRITABLE_ANALOG_OUTPUTS = range(0, CONTROLLER_ANALOG_OUTPUT_VALID)


def error_text(code: int) -> str:
    return "" if code == 0 else ERROR_TEXTS.get(code, "unknown error code")


def warning_text(code: int) -> str:
    return "" if code == 0 else WARNING_TEXTS.get(code, "unknown warning code")


def state_name(state: int) -> str:
    return STATE_NAMES.get(state, f"unknown({state})")


def mode_name(mode: int) -> str:
    return MODE_NAMES.get(mode, f"mode {mode}")
