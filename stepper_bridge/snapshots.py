"""What a stepper poll reads and returns: the read plans (every poll, the slow group, the
configuration), the snapshot and configuration types, and the configuration decoded from
the cached values.

A poll reads three status blocks (running flags 40168-40172 first, then coordinates
40108-40117 and inputs 40124-40136: three requests, the undefined rows between them cannot
be read through); the outputs 40148-40159 are the slow group, read every
``slow_poll_period_s`` (stepper decision 21). The configuration is read whole when the link
comes up, then refreshed one request per poll (``StepperDevice``). No ROS here.
"""

from __future__ import annotations

from dataclasses import dataclass

from bridge_core.wire.codec import Value
from bridge_core.wire.planner import ReadRequest, plan_reads
from bridge_core.wire.registers import Table
from bridge_core.wire.requests import Span

from .registers import (
    INPUTS,
    INTERPOLATION_REGISTERS,
    LINK_REGISTERS,
    MOTOR_FIELD_NAMES,
    MOTORS,
    OUTPUTS,
    STEPPER_MAP,
    SYSTEM_COILS,
    coil,
    motor_register,
    output_coil,
)

LIMIT_FIELDS = ("positive_limit_input", "negative_limit_input", "home_input")


@dataclass(frozen=True)
class MotorConfig:
    """One motor's parameters as last read (or written) by the bridge."""

    step_angle_deg: float
    microstep: int
    start_frequency_hz: int
    accel_frequency_hz: int
    direction: int  # 0 positive, 1 negative: the single run's direction
    speed_rpm: int
    lead: float  # user units per revolution
    run_distance: float  # user units
    positive_limit_input: int  # input 1-13, 0 none
    negative_limit_input: int
    home_input: int
    reciprocations: int  # system mode 1 round trips, 0 endless


@dataclass(frozen=True)
class InterpolationConfig:
    """40182-40211 as last read (or written): the last line / arc set up, user units.

    Points are (first motor, second motor) of the pair, by the type rows' reading
    (registers.INTERPOLATION_PAIRS)."""

    arc_pair: int
    arc_mode: int
    arc_start: tuple[float, float]
    arc_end: tuple[float, float]
    arc_center: tuple[float, float]
    arc_via: tuple[float, float]
    arc_counterclockwise: bool
    arc_speed_rpm: int
    line_pair: int
    line_start: tuple[float, float]
    line_end: tuple[float, float]
    line_speed_rpm: int


@dataclass(frozen=True)
class StepperConfig:
    motors: tuple[MotorConfig, ...]
    homing_order: tuple[int, ...]
    system_mode: int
    interpolation: InterpolationConfig
    device_id: int  # 40212: read only (stepper decision 13: never written)
    baud_rate: int  # 40213-40214


@dataclass(frozen=True)
class StepperSnapshot:
    """One poll: status as read now, configuration as last read."""

    read_time: float  # wall clock when the coordinates were read (joint_states)
    # When the running flags, read first, were read (~/state): a state stamped after a
    # stop shows flags read after it (the stop may go between the two reads).
    state_read_time: float
    slow_read_time: float  # wall clock when the slow group (the outputs) was read
    coordinates: tuple[float, ...]  # user units (register / 100)
    running: tuple[bool, ...]
    inputs: tuple[bool, ...]  # input 1 first
    outputs: tuple[bool, ...]  # output 1 first; the slow group, read at slow_read_time
    config: StepperConfig


def _fast_names() -> list[str]:
    """Every poll (stepper decision 21): what moves by itself and what the motions
    judge: the running flags (a motion ends, a limit or the home switch stops a motor),
    the coordinates (joint_states), the inputs (the limit and home switches)."""
    names = [motor_register(m, "coordinate") for m in range(1, MOTORS + 1)]
    names += [f"input_{n}" for n in range(1, INPUTS + 1)]
    names += [motor_register(m, "running") for m in range(1, MOTORS + 1)]
    return names


def _slow_names() -> list[str]:
    """Every ``slow_poll_period_s``: the outputs change only by coils (00049-00072, all
    outputs on / off, the e-stop: ``OUTPUTS_TOUCHED_BY``), which refresh them at the next
    poll; nothing the bridge decides reads them."""
    return [f"output_{n}" for n in range(1, OUTPUTS + 1)]


def _config_names() -> list[str]:
    names = [motor_register(m, f) for m in range(1, MOTORS + 1) for f in MOTOR_FIELD_NAMES]
    names += [motor_register(m, f) for m in range(1, MOTORS + 1) for f in LIMIT_FIELDS]
    names += [f"homing_order_{k}" for k in range(1, MOTORS + 1)]
    names += ["system_mode"]
    names += [motor_register(m, "reciprocations") for m in range(1, MOTORS + 1)]
    names += list(INTERPOLATION_REGISTERS) + list(LINK_REGISTERS)
    return names


_RUNNING_REGISTERS = frozenset(motor_register(m, "running") for m in range(1, MOTORS + 1))
# The running flags are read first: a coordinate read after a flag that says "stands" is
# where the motor stopped. In address order (coordinates first) a motor that stops between
# the two reads would be reported standing at a coordinate from before its last step.
FAST_PLAN: list[ReadRequest] = sorted(
    plan_reads(STEPPER_MAP, STEPPER_MAP.select(_fast_names())),
    key=lambda request: not any(r.name in _RUNNING_REGISTERS for r in request.registers),
)
SLOW_PLAN: list[ReadRequest] = plan_reads(STEPPER_MAP, STEPPER_MAP.select(_slow_names()))
# The writes that change an output besides the outputs' own rows (which are read only).
_OUTPUT_COILS = range(output_coil(1, True), output_coil(OUTPUTS, False) + 1)
OUTPUTS_TOUCHED_BY: tuple[Span, ...] = (
    Span(Table.COIL, _OUTPUT_COILS.start, len(_OUTPUT_COILS)),
    *(
        Span(Table.COIL, coil(SYSTEM_COILS[name]))
        for name in (
            "emergency_stop",
            "all_outputs_on",
            "all_outputs_off",
            "factory_reset",
            "clear_all_parameters",
        )
    ),
)
# joint_states is stamped with the read time of the block holding the coordinates.
STAMP_REGISTER = motor_register(1, "coordinate")
CONFIG_PLAN: list[ReadRequest] = plan_reads(STEPPER_MAP, STEPPER_MAP.select(_config_names()))


def decode_config(v: dict[str, Value]) -> StepperConfig:
    """The configuration as decoded from the cached values (by register name)."""

    def i(name: str) -> int:
        return int(v[name])

    motors = tuple(
        MotorConfig(
            step_angle_deg=float(v[motor_register(m, "step_angle")]),
            microstep=i(motor_register(m, "microstep")),
            start_frequency_hz=i(motor_register(m, "start_frequency")),
            accel_frequency_hz=i(motor_register(m, "accel_frequency")),
            direction=i(motor_register(m, "direction")),
            speed_rpm=i(motor_register(m, "speed")),
            lead=float(v[motor_register(m, "lead")]),
            run_distance=float(v[motor_register(m, "run_distance")]),
            positive_limit_input=i(motor_register(m, "positive_limit_input")),
            negative_limit_input=i(motor_register(m, "negative_limit_input")),
            home_input=i(motor_register(m, "home_input")),
            reciprocations=i(motor_register(m, "reciprocations")),
        )
        for m in range(1, MOTORS + 1)
    )

    def point(name: str) -> tuple[float, float]:
        return (float(v[f"{name}_a"]), float(v[f"{name}_b"]))

    interpolation = InterpolationConfig(
        arc_pair=i("arc_pair"),
        arc_mode=i("arc_mode"),
        arc_start=point("arc_start"),
        arc_end=point("arc_end"),
        arc_center=point("arc_center"),
        arc_via=point("arc_via"),
        arc_counterclockwise=bool(i("arc_direction")),
        arc_speed_rpm=i("arc_speed"),
        line_pair=i("line_pair"),
        line_start=point("line_start"),
        line_end=point("line_end"),
        line_speed_rpm=i("line_speed"),
    )
    return StepperConfig(
        motors=motors,
        homing_order=tuple(i(f"homing_order_{k}") for k in range(1, MOTORS + 1)),
        system_mode=i("system_mode"),
        interpolation=interpolation,
        device_id=i("device_id"),
        baud_rate=i("baud_rate"),
    )
