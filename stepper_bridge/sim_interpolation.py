"""The stepper simulator's line and arc interpolation: one job (its pair, points, speed and
progress) and the geometry of its path. The simulator (``sim.StepperSimDevice``) starts a
job from the interpolation registers and moves its two motors along it each tick: first
each motor to the start at its own speed ("approach"), then along the path at the
interpolation speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class Interpolation:
    kind: str  # "line" or "arc"
    motors: tuple[int, int]
    start: tuple[float, float]  # coordinates
    end: tuple[float, float]
    rpm: float
    center: tuple[float, float] = (0.0, 0.0)
    sweep: float = 0.0  # signed angle of the arc (rad), ccw positive
    phase: str = "approach"  # "approach" (each motor to the start), then "path"
    travelled: float = 0.0  # along the path, user units
    length: float = 0.0
    done: list[int] = field(default_factory=list)

    def point_at(self, fraction: float) -> tuple[float, ...]:
        """The path's point (coordinates) after ``fraction`` of its length."""
        if self.kind == "line":
            return tuple(s + (e - s) * fraction for s, e in zip(self.start, self.end, strict=True))
        radius = math.dist(self.center, self.start)
        angle = _angle(self.center, self.start) + self.sweep * fraction
        point = (
            self.center[0] + radius * math.cos(angle),
            self.center[1] + radius * math.sin(angle),
        )
        if fraction >= 1.0:
            point = self.end
        return point


def center_arc(
    start: tuple[float, float], end: tuple[float, float], center: tuple[float, float], ccw: bool
) -> tuple[tuple[float, float], float]:
    """Arc mode 0 (start, end, centre): the centre and the signed sweep (rad, ccw +)."""
    sweep = _angle(center, end) - _angle(center, start)
    if ccw and sweep <= 0:
        sweep += 2 * math.pi
    if not ccw and sweep >= 0:
        sweep -= 2 * math.pi
    return center, sweep


def three_point_arc(
    start: tuple[float, float], via: tuple[float, float], end: tuple[float, float]
) -> tuple[tuple[float, float], float] | None:
    """Arc mode 1 (start, a middle point, end): the centre and the signed sweep through
    ``via``; None when the three points are on one line."""
    center = _circumcenter(start, via, end)
    if center is None:
        return None
    to_via = (_angle(center, via) - _angle(center, start)) % (2 * math.pi)
    to_end = (_angle(center, end) - _angle(center, start)) % (2 * math.pi)
    sweep = to_end if to_via <= to_end else to_end - 2 * math.pi
    return center, sweep


def _angle(center: tuple[float, float], point: tuple[float, float]) -> float:
    return math.atan2(point[1] - center[1], point[0] - center[0])


def _circumcenter(
    p: tuple[float, float], q: tuple[float, float], r: tuple[float, float]
) -> tuple[float, float] | None:
    d = 2 * (p[0] * (q[1] - r[1]) + q[0] * (r[1] - p[1]) + r[0] * (p[1] - q[1]))
    if abs(d) < 1e-12:
        return None
    pp, qq, rr = p[0] ** 2 + p[1] ** 2, q[0] ** 2 + q[1] ** 2, r[0] ** 2 + r[1] ** 2
    x = (pp * (q[1] - r[1]) + qq * (r[1] - p[1]) + rr * (p[1] - q[1])) / d
    y = (pp * (r[0] - q[0]) + qq * (p[0] - r[0]) + rr * (q[0] - p[0])) / d
    return (x, y)
