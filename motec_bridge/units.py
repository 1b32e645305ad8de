"""MOTEC drive units <-> SI for one joint (docs/bridges/motec.md, ``joint_states``).

The drive counts encoder counts and rpm; ROS speaks radians and rad/s. ``DriveScale``
converts one drive's joint, refusing a value that leaves the drive's registers. No ROS here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bridge_core.runtime.checks import check_converted, check_finite

from .registers import MOTEC_MAP

SPEED_LIMIT_RPM = 32767  # 0xAE is a signed 16-bit register


@dataclass(frozen=True)
class DriveScale:
    """Drive units <-> SI for one joint (docs/bridges/motec.md, ``joint_states``).

    ``counts_per_rev``: encoder counts per motor revolution; ``gear_ratio``: motor
    revolutions per joint revolution. rad = counts / (counts_per_rev x gear) x 2 pi;
    rad/s = rpm x 2 pi / 60 / gear.
    """

    counts_per_rev: float = 10000.0
    gear_ratio: float = 1.0

    def __post_init__(self) -> None:
        for what, value in (
            ("counts_per_rev", self.counts_per_rev),
            ("gear_ratio", self.gear_ratio),
        ):
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{what} must be positive and finite, got {value}")

    def position(self, counts: int) -> float:
        return counts / (self.counts_per_rev * self.gear_ratio) * 2.0 * math.pi

    def velocity(self, rpm: float) -> float:
        return rpm * 2.0 * math.pi / 60.0 / self.gear_ratio

    def to_counts(self, rad: float) -> int:
        check_finite("position", rad)
        kind = MOTEC_MAP["target_distance"].value_type
        counts = check_converted(
            f"position {rad:g} rad in counts",
            rad / (2.0 * math.pi) * self.counts_per_rev * self.gear_ratio,
            kind.raw_min,
            kind.raw_max,
        )
        return round(counts)

    def to_rpm(self, rad_s: float) -> float:
        check_finite("velocity", rad_s)
        return check_converted(
            f"velocity {rad_s:g} rad/s in rpm",
            rad_s * 60.0 / (2.0 * math.pi) * self.gear_ratio,
            -SPEED_LIMIT_RPM,
            SPEED_LIMIT_RPM,
        )
