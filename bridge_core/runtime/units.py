"""Unit conversions to REP 103 SI units, shared by the bridges (plain Python)."""

from __future__ import annotations

import math

DEG = math.pi / 180.0
RPM_TO_RAD_S = 2.0 * math.pi / 60.0
MM = 1e-3


def euler_xyz_deg_to_quaternion(u: float, v: float, w: float) -> tuple[float, float, float, float]:
    """U, V, W (deg) as rotations about fixed X, Y, Z in that order: R = Rz(W) Ry(V) Rx(U).

    Both R6 (U, V, W) and xArm (roll, pitch, yaw) give orientation this way; it is the usual
    fixed-axis roll-pitch-yaw reading (REP 103's), written down in docs/bridges/r6.md.
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


def rotation_vector_deg_to_quaternion(
    rx: float, ry: float, rz: float
) -> tuple[float, float, float, float]:
    """A rotation vector (axis times angle, deg) as a quaternion (x, y, z, w).

    The axis-angle form needs no Euler convention: the xArm reports its TCP orientation
    both ways (I64-72), so this one checks the other.
    """
    angle = math.sqrt(rx * rx + ry * ry + rz * rz) * DEG
    if angle == 0.0:
        return (0.0, 0.0, 0.0, 1.0)
    k = math.sin(angle / 2.0) * DEG / angle
    return (rx * k, ry * k, rz * k, math.cos(angle / 2.0))


def quaternion_to_rotation_vector_deg(
    q: tuple[float, float, float, float],
) -> tuple[float, float, float]:
    """The rotation vector (deg) of a unit quaternion, its angle within 0..180 deg."""
    x, y, z, w = q
    if w < 0.0:  # q and -q are one rotation: take the one with the shorter angle
        x, y, z, w = -x, -y, -z, -w
    s = math.sqrt(x * x + y * y + z * z)
    if s == 0.0:
        return (0.0, 0.0, 0.0)
    angle_deg = 2.0 * math.atan2(s, w) / DEG
    return (x / s * angle_deg, y / s * angle_deg, z / s * angle_deg)


def quaternion_angle_deg(
    a: tuple[float, float, float, float], b: tuple[float, float, float, float]
) -> float:
    """The angle (deg, 0..180) of the rotation that takes orientation ``a`` to ``b``."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    # conj(a) * b: its vector part's length and its scalar part give the half angle
    # (atan2 stays exact near 0, where acos of the dot product loses half the digits).
    w = aw * bw + ax * bx + ay * by + az * bz
    x = aw * bx - ax * bw - ay * bz + az * by
    y = aw * by + ax * bz - ay * bw - az * bx
    z = aw * bz - ax * by + ay * bx - az * bw
    return 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w)) / DEG
