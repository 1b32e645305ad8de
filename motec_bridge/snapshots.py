"""What a MOTEC poll reads and returns: the read plans, the standstill band, the snapshot,
mode and configuration types, and the one fresh read of the modes. No ROS here.

Polling: 2 reads per drive every poll (0xAA-0xAF, 0xC5-0xC9), and the slow group's 2
(0x24-0x2D, 0x109) every ``slow_poll_period_s`` (MOTEC decision 20; see registers.py on
reading through unnamed parameters). The configuration (analog max speed 0x6D, lifeguard
0x112 / 0x114) is read whole when the link comes up, then one request per poll every
``config_refresh_s``, and the cache follows the bridge's own writes (``MotecDevice``).
"MOTEC decision N" is reading N of docs/decisions/motec.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from bridge_core.runtime.reads import read_blocks
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.codec import Value
from bridge_core.wire.planner import ReadRequest, plan_reads

from .registers import (
    INPUTS,
    LIFEGUARD_OFF_MS,
    MOTEC_MAP,
    OPERATION_MODE_NETWORK,
    OUTPUT1_COIL_DEFAULT,
    OUTPUTS,
    control_mode_name,
    operation_mode_name,
)

# A servo at rest dithers by a count or two and shows an rpm or two in 0xAF (MOTEC
# decision 17): |0xAF| within this band counts as standing still.
STANDSTILL_SPEED_RPM = 3

CONFIG_NAMES = ("analog_max_speed", "lifeguard_time", "lifeguard_mode")
MODE_NAMES = ("operation_mode", "control_mode", "target_distance", "enable", "start")

# Rate groups (MOTEC decision 20). Fast, every poll: 0xAA-0xAF (joint_states, the
# moves' verdicts) and 0xC5-0xC9 (the fault code: a move ends FAULT at once; the inputs
# share the request). Slow: 0x24-0x2D (the modes, enable, start: host-written; a drive
# that drops enable on a lifeguard trip also raises its fault code, which is fast; every
# command that depends on a mode reads it at command priority) and 0x109 (the analog
# input: nothing the bridge decides reads it).
FAST_NAMES = (
    "position_setpoint",
    "position_actual",
    "speed_setpoint",
    "speed_actual",
    "input_word",
    "output_state",
    "fault_code",
)
SLOW_NAMES = (*MODE_NAMES, "motion_mode", "analog_input")
STATUS_NAMES = (*FAST_NAMES, *SLOW_NAMES)
STATUS_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(STATUS_NAMES))
FAST_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(FAST_NAMES))
SLOW_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(SLOW_NAMES))
CONFIG_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(CONFIG_NAMES))
MODE_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(MODE_NAMES))
OUTPUT_WORD_PLAN: list[ReadRequest] = plan_reads(MOTEC_MAP, MOTEC_MAP.select(("output_word",)))
# A stop's check: 0xAA-0xAF in one read (the actual position and speed; decision 22).
MOTION_PLAN: list[ReadRequest] = plan_reads(
    MOTEC_MAP, MOTEC_MAP.select(("position_setpoint", "position_actual", "speed_actual"))
)
# joint_states is stamped with the read time of the block holding the actual position.
STAMP_REGISTER = "position_actual"


@dataclass(frozen=True)
class Modes:
    """What decides whether the drive may move over Modbus (0x24, 0x25, 0x28)."""

    operation_mode: int
    control_mode: int
    enabled: bool

    @property
    def network(self) -> bool:
        return self.operation_mode == OPERATION_MODE_NETWORK

    def describe(self) -> str:
        return (
            f"operation mode {operation_mode_name(self.operation_mode)}, control mode "
            f"{control_mode_name(self.control_mode)}, {'enabled' if self.enabled else 'disabled'}"
        )


@dataclass(frozen=True)
class MotecConfig:
    analog_max_speed_rpm: int
    lifeguard_time_ms: int
    lifeguard_mode: int

    @property
    def lifeguard_armed(self) -> bool:
        """Taken as armed unless 0x112 reads 0: §3.4 arms it with a non-zero time and mode
        9999, and gives no other mode's meaning, so a drive with a time and any mode may
        be watching (MOTEC decision 9)."""
        return self.lifeguard_time_ms != LIFEGUARD_OFF_MS


@dataclass(frozen=True)
class MotecSnapshot:
    """One poll of one drive (drive units)."""

    read_time: float  # wall clock when 0xAA-0xAF were read
    slow_read_time: float  # wall clock when the slow group was read (modes, analog input)
    modes: Modes
    motion_mode: int
    target_distance: int  # counts, as last written
    start: int
    position_setpoint: int  # counts
    position_actual: int  # counts
    speed_setpoint_rpm: int
    speed_actual_rpm: int
    input_word: int
    output_word: int
    fault_code: int
    analog_input: int
    config: MotecConfig
    output1_coil: int = OUTPUT1_COIL_DEFAULT  # bit of OUTPUT1 in 0xC6 / 0x79 / FC 01
    # The IO tables (``read_io_tables``): 0x79, FC 01 and FC 02; None when not read.
    output_word_79: int | None = None
    coil_outputs: tuple[bool, ...] | None = None
    discrete_inputs: tuple[bool, ...] | None = None

    @property
    def fault_flag(self) -> int:
        """0xC8, the high word: §4.3 writes "0—无故障" / "1—有故障" beside it (decision 7)."""
        return self.fault_code >> 16

    @property
    def fault_detail(self) -> int:
        """0xC9, the low word: the manual gives none of its values."""
        return self.fault_code & 0xFFFF

    @property
    def inputs(self) -> tuple[bool, ...]:
        return tuple(bool(self.input_word >> k & 1) for k in range(INPUTS))

    @property
    def outputs(self) -> tuple[bool, ...]:
        return output_bits(self.output_word, self.output1_coil)

    @property
    def moving(self) -> bool:
        """Derived (the manual gives no motion flag's address): turning, or not yet at
        the setpoint (with no band: ``stands`` is the verdict a goal waits for)."""
        return self.speed_actual_rpm != 0 or self.position_setpoint != self.position_actual

    @property
    def turning(self) -> bool:
        """|0xAF| above the standstill band (a resting servo's dither is not motion)."""
        return abs(self.speed_actual_rpm) > STANDSTILL_SPEED_RPM

    def stands(self, tolerance_counts: int) -> bool:
        """At rest: |0xAF| within the standstill band and the actual position within
        ``tolerance_counts`` of the setpoint (decision 17)."""
        return (
            not self.turning
            and abs(self.position_setpoint - self.position_actual) <= tolerance_counts
        )


def output_bits(word: int, output1_coil: int) -> tuple[bool, ...]:
    """OUTPUT1-3 from an output word whose bit ``output1_coil`` is OUTPUT1 (decision 6)."""
    return tuple(bool(word >> (k + output1_coil) & 1) for k in range(OUTPUTS))


def read_modes(io: RegisterIO) -> Modes:
    """0x24-0x29 now, at command priority (one FC 03)."""
    v: dict[str, Value] = {}
    for request in MODE_PLAN:
        v.update(read_blocks(io, (request,), Priority.COMMAND)[0])
    return Modes(int(v["operation_mode"]), int(v["control_mode"]), bool(v["enable"]))
