"""A MOTEC drive's part of the bus owner's ``~/joint_commands`` (docs/ros2_control.md).
No ROS here.

One joint per drive (``drive_<id>``, as in ``joint_states``):

- **velocity** (rad/s): ``DriveScale.to_rpm`` and the drive's ``max_speed_rpm``, exactly as
  ``~/cmd_velocity``, offered to the drive's **cmd_velocity guard** (``MotecDevice.stream``):
  the same stream, with its rate, deadman (0xAE = 0), lock after ``~/stop`` or a disable,
  and its first value's check of network mode, velocity control and enable;
- **position** (rad): ``DriveScale.to_counts`` (the conversion of ``joint_states``, in
  reverse), an absolute target. The first target of a stream is a ``~/move`` to it
  (modes read fresh: network mode, position control, enabled; the speed limit 0xAE
  written from ``position_max_velocity`` when it is > 0, else the drive's own 0xAE, which
  must then be > 0); each newer target writes the motion mode (absolute), the target
  (0x26-0x27) and 0x29 = 1 again, and the drive turns towards it from where it is
  (MOTEC decision 21, docs/decisions/motec.md). Its stop is ``~/move_to``'s: 0x29 = 0, verified.

The position stream follows the velocity guard (one lock; ``~/stop``, a disable or a mode
change takes both over) and has the drive's ``command_timeout_s`` deadman and
``command_rate_hz``. The joint is judged by its own drive node's state (``gate``) and its
refusals count in that node's diagnostics (``counts``): a drive deactivated refuses its
own values, the other drives of the bus apply theirs.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from bridge_core.runtime.joint_commands import (
    CommandJoint,
    CommandStream,
    Gate,
    Offer,
    RefusalCounts,
)
from bridge_core.runtime.stream_guard import StreamGuard

from .device import VELOCITY_STREAM, MotecDevice
from .units import DriveScale


class DriveTarget:
    """The drive's position stream (target counts), following its velocity guard."""

    def __init__(
        self,
        device: MotecDevice,
        speed_rpm: Callable[[], float],
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.device = device
        self.speed_rpm = speed_rpm  # the speed limit of a stream's first move (0: the drive's)
        self.guard: StreamGuard[int] = StreamGuard(
            (VELOCITY_STREAM,),
            self._send,
            self._stop,
            timeout_s=device.stream.timeout_s,
            stop_when_idle=False,
            zero_stops=False,
            clock=clock,
        )
        self.guard.follow(device.stream)
        device.streams.append(self.guard)  # a reconnect forgets what it sent

    def _send(self, _key: int, counts: float, previous: float | None) -> None:
        if previous is None:
            self.device.move(round(counts), relative=False, speed_rpm=self.speed_rpm())
        else:
            self.device.retarget(round(counts))

    def _stop(self, _key: int) -> None:
        self.device.stop_move()


def command_joint(
    name: str,
    device: MotecDevice,
    target: DriveTarget,
    scale: DriveScale,
    gate: Gate,
    offer: Offer,
    here: Callable[[], float | None],
    max_jump: Callable[[], float],
    counts: RefusalCounts,
) -> CommandJoint:
    """The drive's ``CommandJoint`` for the bus owner's topic; ``here``: its newest
    published position (rad); ``counts``: its node's refusals."""
    return CommandJoint(
        name,
        CommandStream(target.guard, VELOCITY_STREAM, lambda rad: _target(device, scale, rad)),
        CommandStream(
            device.stream, VELOCITY_STREAM, lambda rad_s: _velocity(device, scale, rad_s)
        ),
        gate,
        offer,
        here,
        max_jump,
        counts=counts,
    )


def _velocity(device: MotecDevice, scale: DriveScale, rad_s: float) -> float:
    """A velocity checked as ``~/cmd_velocity`` checks it (rpm within ``max_speed_rpm``),
    offered in rad/s: the stream's writer converts what its topic and this one offer."""
    device.check_velocity(scale.to_rpm(rad_s))
    return rad_s


def _target(device: MotecDevice, scale: DriveScale, rad: float) -> float:
    """A position in counts, inside the target register's range (``check_move``)."""
    counts = scale.to_counts(rad)
    device.check_move(counts, 0.0)
    return float(counts)


__all__ = ["DriveTarget", "command_joint"]
