"""Stepper units <-> SI per motor (docs/bridges/stepper.md, ``joint_states``).

The controller counts in the user's length unit (lead, run distance, coordinates: the
registers hold x100); ROS speaks metres and radians. ``JointScale`` converts one motor;
``joint_scales`` builds the five from the node's start-up parameters. No ROS here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from bridge_core.runtime.parameters import padded
from bridge_core.wire.errors import CommandRejected, ConfigurationError

from .registers import MOTORS

JOINT_TYPES = ("prismatic", "revolute")
# A prismatic motor's controller units per metre unless configured: the user's unit is mm.
DEFAULT_UNITS_PER_METER = 1000.0


@dataclass(frozen=True)
class JointScale:
    """Device units <-> SI for one motor (docs/bridges/stepper.md, ``joint_states``).

    prismatic: metres = units / ``units_per_meter`` (1000 when the user's unit is mm);
    revolute: radians = units / ``units_per_revolution`` x 2 pi, the user units per JOINT
    revolution (a reduction makes it lead x ratio); 0 takes the lead read from the device
    (units per MOTOR revolution: no reduction).
    """

    joint_type: str = "prismatic"
    units_per_meter: float = DEFAULT_UNITS_PER_METER
    units_per_revolution: float = 0.0

    def __post_init__(self) -> None:
        if self.joint_type not in JOINT_TYPES:
            raise ValueError(f"joint type {self.joint_type!r} is not one of {JOINT_TYPES}")
        if not math.isfinite(self.units_per_meter) or self.units_per_meter <= 0:
            raise ValueError(f"units_per_meter must be positive, got {self.units_per_meter}")
        if not math.isfinite(self.units_per_revolution) or self.units_per_revolution < 0:
            raise ValueError(
                f"units_per_revolution must be 0 (the lead) or positive, "
                f"got {self.units_per_revolution}"
            )

    def needs_lead(self) -> bool:
        """Whether the conversion depends on the lead read from the device."""
        return self.joint_type == "revolute" and self.units_per_revolution == 0

    def units_per_si(self, lead: float) -> float | None:
        """Controller units per metre (prismatic) or per radian (revolute); None when a
        revolute joint takes the lead and the device's lead is unset (0)."""
        if self.joint_type == "prismatic":
            return self.units_per_meter
        per_revolution = self.units_per_revolution or lead
        if per_revolution <= 0:
            return None
        return per_revolution / (2.0 * math.pi)

    def to_si(self, units: float, lead: float) -> float:
        factor = self.units_per_si(lead)
        if factor is None:
            return math.nan  # the device's lead is unset: no angle
        return units / factor

    def to_units(self, si: float, lead: float) -> float:
        if not math.isfinite(si):
            raise CommandRejected(f"{si} is not a finite distance")
        factor = self.units_per_si(lead)
        if factor is None:
            raise CommandRejected("the motor's lead is 0: a revolute angle cannot be converted")
        return si * factor


def joint_scales(
    types: Sequence[str],
    units_per_meter: Sequence[float],
    units_per_revolution: Sequence[float] = (),
) -> list[JointScale]:
    """Per-motor scales from the start-up parameters; a bad value is a ConfigurationError."""
    types = list(types)[:MOTORS] + ["prismatic"] * (MOTORS - len(types))
    for joint_type in types:
        if joint_type not in JOINT_TYPES:
            raise ConfigurationError(
                f"joint_types: {joint_type!r} is not one of {', '.join(JOINT_TYPES)}"
            )
    units = padded(units_per_meter, MOTORS, DEFAULT_UNITS_PER_METER)
    per_revolution = padded(units_per_revolution, MOTORS, 0.0)
    for value in per_revolution:
        if not math.isfinite(value) or value < 0:
            raise ConfigurationError(
                f"units_per_revolution: every value must be 0 (the lead) or positive and "
                f"finite, got {value!r}"
            )
    return [JointScale(t, u, r) for t, u, r in zip(types, units, per_revolution, strict=True)]
