"""Unit conversions to REP 103 SI units, shared by the bridges (plain Python)."""

from __future__ import annotations

import math

DEG = math.pi / 180.0
RPM_TO_RAD_S = 2.0 * math.pi / 60.0
MM = 1e-3


def euler_xyz_deg_to_quaternion(u: float, v: float, w: float) -> tuple[float, float, float, float]:
    """U, V, W (deg) as rotations about fixed X, Y, Z in that order: R = Rz(W) Ry(V) Rx(U).

    Both R6 (U, V, W) and xArm (roll, pitch, yaw) give orientation this way; it is the usual
    fixed-axis roll-pitch-yaw reading (REP 103's), written down in the README.
    """
    hr, hp, hy = u * DEG / 2.0, v * DEG / 2.0, w * DEG / 2.0
    cr, sr, cp, sp, cy, sy = (
        math.cos(hr),
        math.sin(hr),
        math.cos(hp),
        math.sin(hp),
        math.cos(hy),
        math.sin(hy),
    )
    return (
        sr * cp * cy - cr * sp * sy,  # x
        cr * sp * cy + sr * cp * sy,  # y
        cr * cp * sy - sr * sp * cy,  # z
        cr * cp * cy + sr * sp * sy,  # w
    )
