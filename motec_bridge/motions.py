"""The MOTEC drive's action goals (docs/actions.md): ``MoveToMotion`` (``~/move_to``), one
point-to-point move followed through the polls and judged from the actual position and
speed, with its default time limit (``move_time_limit_s``, MOTEC decision 17). No ROS here.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from typing import Any

from bridge_core.runtime.goals import Motion, Outcome, Verdict

from .device import MotecDevice
from .registers import fault_text
from .snapshots import MotecSnapshot
from .units import DriveScale

# ~/move_to's default time limit: the move's time at its speed limit times this margin,
# plus an allowance for the ramps (the manual gives no acceleration; decision 17).
MOVE_TIME_MARGIN = 2.0
MOVE_TIME_ALLOWANCE_S = 2.0


def move_time_limit_s(
    distance_counts: int, speed_rpm: float, counts_per_rev: float, margin: float
) -> float:
    """A move's default time limit: ``distance`` at ``speed_rpm`` (motor counts per
    revolution ``counts_per_rev``) times ``margin``, plus ``MOVE_TIME_ALLOWANCE_S`` for
    the ramps. A 0 rpm limit gives no limit (the move is refused anyway)."""
    if speed_rpm <= 0:
        return math.inf
    travel_s = distance_counts / counts_per_rev / (speed_rpm / 60.0)
    return travel_s * margin + MOVE_TIME_ALLOWANCE_S


class MoveToMotion(Motion[MotecSnapshot]):
    """``~/move_to``: one point-to-point move followed through the polls (docs/actions.md). Over
    when the drive stands (``MotecSnapshot.stands``: |0xAF| within the standstill band, 0xAC
    within ``tolerance_counts`` of 0xAA) on two polls in a row: at the target within
    ``tolerance_counts`` it is REACHED, elsewhere STOPPED (a stop service, a disable, the
    drive); a fault code ends it at once. Its stop is ``~/stop``'s, verified.
    ``time_limit_margin`` > 0 (and no goal ``timeout_s``): the goal is stopped and TIMED_OUT
    after the move's time at its speed limit times the margin plus ``MOVE_TIME_ALLOWANCE_S``
    (decision 17)."""

    axes: frozenset[Hashable] = frozenset({"drive"})
    confirm_reached = True  # "stands" on two polls, REACHED too

    def __init__(
        self,
        device: MotecDevice,
        scale: DriveScale,
        position_rad: float,
        *,
        relative: bool,
        max_velocity_rad_s: float,
        tolerance_counts: int,
        time_limit_margin: float = 0.0,
    ) -> None:
        super().__init__()
        self.device = device
        self.scale = scale
        self.counts = scale.to_counts(position_rad)
        self.speed_rpm = scale.to_rpm(max_velocity_rad_s)
        device.check_move(self.counts, self.speed_rpm)
        self.relative = relative
        self.tolerance_counts = tolerance_counts
        self.time_limit_margin = time_limit_margin
        self.time_limit_s = math.inf  # set at the start (distance and speed known then)
        self.target = self.counts  # absolute; a relative move's is known at its start
        self.what = f"move_to {'by' if relative else 'to'} {position_rad:g} rad"

    def start(self) -> None:
        # Where the drive is now: a relative move's target, an absolute one's distance.
        position = int(self.device.read_named("position_actual")["position_actual"])
        if self.relative:
            self.target = position + self.counts
        if self.time_limit_margin > 0:
            rpm = self.speed_rpm or abs(
                int(self.device.read_named("speed_setpoint")["speed_setpoint"])
            )
            self.time_limit_s = move_time_limit_s(
                abs(self.target - position),
                rpm,
                self.scale.counts_per_rev,
                self.time_limit_margin,
            )
        # A relative goal is sent as the absolute target it computed: the drive counts a
        # relative move from its setpoint when 0x29 is written, which a move still under
        # way shifts after this read, and the goal would judge a target the drive never
        # had (MOTEC decision 19).
        self.device.move(self.target, relative=False, speed_rpm=self.speed_rpm)

    def stop(self) -> str:
        return self.device.stop_move()

    def running(self, snapshot: MotecSnapshot) -> bool:
        return not snapshot.stands(self.tolerance_counts)

    def default_timeout_s(self, node_default_s: float) -> float:
        """Its own limit from the distance and the speed (decision 17) is judged on the
        polls; the node's ``goal_timeout_s`` stays a backstop for when no poll comes (a
        device that refuses every poll but the link is up)."""
        return node_default_s

    def judge(self, snapshot: MotecSnapshot, since_start_s: float = math.inf) -> Verdict | None:
        if since_start_s != math.inf and since_start_s > self.time_limit_s:
            if (verdict := self.fault(snapshot)) is not None:
                return verdict
            return Verdict(
                Outcome.TIMED_OUT,
                f"{self.what}: not done within {self.time_limit_s:.3g} s, the default limit "
                f"(the move's time at {self.speed_rpm or 'the drive'}'s speed limit x "
                f"{self.time_limit_margin:g} + {MOVE_TIME_ALLOWANCE_S:g} s; goal timeout_s "
                "sets another, the node's move_time_margin 0 none)",
            )
        return super().judge(snapshot, since_start_s)

    def fault(self, snapshot: MotecSnapshot) -> Verdict | None:
        code = snapshot.fault_code
        if not code:
            return None
        text = fault_text(code)
        return Verdict(Outcome.FAULT, f"{self.what}: drive fault {code}: {text}", code, text)

    def ended(self, snapshot: MotecSnapshot) -> Verdict:
        short = self.target - snapshot.position_actual
        if abs(short) <= self.tolerance_counts:
            return Verdict(Outcome.REACHED, f"{self.what}: reached ({short} counts from target)")
        return Verdict(
            Outcome.STOPPED,
            f"{self.what}: the drive stopped {self.scale.position(short):.6g} rad "
            f"({short} counts) short of the target",
        )

    def feedback(self, snapshot: MotecSnapshot) -> dict[str, Any]:
        return {
            "position": self.scale.position(snapshot.position_actual),
            "velocity": self.scale.velocity(snapshot.speed_actual_rpm),
            "distance_to_go": self.scale.position(self.target - snapshot.position_actual),
        }

    def result(self, snapshot: MotecSnapshot | None) -> dict[str, Any]:
        position = math.nan if snapshot is None else self.scale.position(snapshot.position_actual)
        return {"position": position, "target_counts": self.target}
