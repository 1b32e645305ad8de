"""Orientation conversions of bridge_core.runtime.units: the rotation vector (axis times angle)
the xArm reports beside roll/pitch/yaw (I64-72), against known rotations."""

from __future__ import annotations

import math
import random

import pytest

from bridge_core.runtime.units import (
    euler_xyz_deg_to_quaternion,
    quaternion_angle_deg,
    quaternion_to_rotation_vector_deg,
    rotation_vector_deg_to_quaternion,
)

H = math.sqrt(0.5)


@pytest.mark.parametrize(
    ("vector", "quaternion"),
    [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        ((90.0, 0.0, 0.0), (H, 0.0, 0.0, H)),
        ((0.0, 0.0, -90.0), (0.0, 0.0, -H, H)),
        ((0.0, 180.0, 0.0), (0.0, 1.0, 0.0, 0.0)),
    ],
)
def test_rotation_vector_known_rotations(
    vector: tuple[float, float, float], quaternion: tuple[float, float, float, float]
) -> None:
    assert rotation_vector_deg_to_quaternion(*vector) == pytest.approx(quaternion, abs=1e-12)
    assert quaternion_to_rotation_vector_deg(quaternion) == pytest.approx(vector, abs=1e-9)


def test_rotation_vector_agrees_with_roll_pitch_yaw() -> None:
    """Roll 180 then yaw 90 (fixed axes) is a half turn about (1, 1, 0)/sqrt 2; and any
    roll/pitch/yaw survives the trip through the rotation vector."""
    half = 180.0 * H
    q = euler_xyz_deg_to_quaternion(180.0, 0.0, 90.0)
    assert quaternion_to_rotation_vector_deg(q) == pytest.approx((half, half, 0.0), abs=1e-9)
    rng = random.Random(10)
    for _ in range(200):
        q = euler_xyz_deg_to_quaternion(
            rng.uniform(-180, 180), rng.uniform(-89, 89), rng.uniform(-180, 180)
        )
        back = rotation_vector_deg_to_quaternion(*quaternion_to_rotation_vector_deg(q))
        assert quaternion_angle_deg(q, back) < 1e-6
        rx, ry, rz = quaternion_to_rotation_vector_deg(q)
        assert math.sqrt(rx * rx + ry * ry + rz * rz) <= 180.0 + 1e-9


def test_quaternion_angle_ignores_the_sign() -> None:
    q = euler_xyz_deg_to_quaternion(10.0, 20.0, 30.0)
    assert quaternion_angle_deg(q, tuple(-c for c in q)) == pytest.approx(0.0, abs=1e-6)  # type: ignore[arg-type]
    assert quaternion_angle_deg(q, euler_xyz_deg_to_quaternion(10.0, 20.0, 33.0)) == pytest.approx(
        3.0, abs=1e-6
    )
