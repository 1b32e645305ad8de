"""What a stepper command checks first and what its reply names, shared by the device and
its rooms (``jog``, ``interpolation``, ``motions``).

A confirmed command's reply says what was written and what was read back, by the manual's
numbers (stepper decision 23): "motor 1 stop (coil 00005 = ON)", "motor 1 running (40168)
= 0". No ROS here.
"""

from __future__ import annotations

from collections.abc import Sequence

from bridge_core.runtime.checks import check_index, check_whole_number

from .registers import DISTANCE_SCALE, MOTORS, STEPPER_MAP, U16_MAX, motor_coil, motor_register


def check_motor(motor: int) -> None:
    check_index("motor", motor, range(1, MOTORS + 1))


def check_integer(what: str, value: float, low: int = 0, high: int = U16_MAX) -> None:
    check_whole_number(what, value, low, high)


def coil_label(address: int) -> str:
    """The manual's number of a coil ("00005" for motor 1's stop, address 4)."""
    return f"{address + 1:05d}"


def register_label(name: str) -> str:
    """The manual's number of a holding register ("40168" for motor 1's running flag)."""
    return str(40001 + STEPPER_MAP[name].address)


def motor_coils_text(motors: Sequence[int], action: str) -> str:
    return ", ".join(
        f"motor {m} {action.replace('_', ' ')} (coil {coil_label(motor_coil(m, action))} = ON)"
        for m in motors
    )


def register_text(name: str) -> str:
    """ "motor 1 speed (40006)" for a motor's register, "line_pair (40202)" otherwise."""
    reg = STEPPER_MAP[name]
    what = reg.description if reg.name.startswith("motor") and reg.description else name
    return f"{what} ({register_label(name)})"


def flags_text(motors: Sequence[int], value: int) -> str:
    return ", ".join(
        f"motor {m} running ({register_label(motor_register(m, 'running'))}) = {value}"
        for m in motors
    )


def coordinates_text(motors: Sequence[int], before: dict[int, float], now: dict[int, float]) -> str:
    return ", ".join(
        f"motor {m} coordinate ({register_label(motor_register(m, 'coordinate'))}) "
        f"{before[m]:g} -> {now[m]:g}"
        for m in motors
    )


def units_differ(a: float, b: float) -> bool:
    """Two coordinates a step (0.01 unit) or more apart."""
    return round(a * DISTANCE_SCALE) != round(b * DISTANCE_SCALE)
