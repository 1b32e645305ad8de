"""A described device's ``~/joint_commands`` (docs/ros2_control.md). No ROS here.

A joint with a ``command`` block in its description takes position targets, velocities, or
both (modbus_bridge decision 18, docs/decisions/modbus.md):

- a value in SI (rad, m, rad/s, m/s) is written as value / ``to_si`` of its command
  register (the unit factor, ``factor`` and ``per_revolution``, as ``joint_states`` reads
  its registers), checked as ``~/write`` checks a value (the register's ``range`` and
  ``values``, its type): those are the joint's limits;
- **velocity**: the stream of the command topic that writes the same register, if the file
  has one (the same guard: one stream per register), else a stream of its own; 0 is its
  stop;
- **position**: a stream of its own (following the joint's velocity stream when it has
  one); its stop holds the joint where it is: the position register read now, written
  as the target;
- while the file requires its keepalive, a motion (a non-zero velocity, any target) is
  refused until it is armed, as a ``starts_motion`` trigger is.

The streams of joints without a command topic have the node's ``command_timeout_s`` deadman
and ``command_rate_hz``; a stop trigger or a stop coil locks them as it locks the command
topics (``DescribedDevice._as_stop``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from bridge_core.runtime.joint_commands import CommandJoint, CommandStream, Gate, Offer
from bridge_core.runtime.stream_guard import StreamGuard

from .description import Joint
from .description_joints import JointSource
from .device import DescribedDevice


@dataclass(frozen=True)
class JointStream:
    """A stream of ``~/joint_commands``: its guard and key, whether the node must give it
    a writer (``own``: not a command topic's, whose writer exists already), and what a
    register value is divided by to be offered (a command topic's ``scale``: its writer
    takes message values and multiplies them back)."""

    guard: StreamGuard[str]
    key: str
    own: bool
    per_register: float = 1.0


class JointStreams:
    """The command streams of every joint of ``device`` that has a ``command``."""

    def __init__(
        self,
        device: DescribedDevice,
        topic_guards: Mapping[str, tuple[StreamGuard[str], str, float]],
        timeout_s: float,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``topic_guards``: register name -> (guard, key, scale) of the command topic
        writing it."""
        self.device = device
        self.position: dict[str, JointStream] = {}
        self.velocity: dict[str, JointStream] = {}
        for joint in device.device.joints:
            command = joint.command
            if command is None:
                continue
            if command.velocity is not None:
                shared = topic_guards.get(command.velocity.register)
                if shared is not None:
                    guard, key, scale = shared
                    self.velocity[joint.name] = JointStream(guard, key, False, scale)
                else:
                    guard = StreamGuard(
                        [joint.name],
                        _sender(device, joint.name, command.velocity),
                        _velocity_stopper(device, command.velocity),
                        timeout_s=timeout_s,
                        stop_when_idle=False,
                        clock=clock,
                    )
                    device.attach_joint_stream(guard, joint.name, command.velocity.register)
                    self.velocity[joint.name] = JointStream(guard, joint.name, own=True)
            if command.position is not None:
                assert joint.position is not None  # the loader refuses it otherwise
                guard = StreamGuard(
                    [joint.name],
                    _sender(device, joint.name, command.position),
                    _holder(device, joint.position, command.position),
                    timeout_s=timeout_s,
                    stop_when_idle=False,
                    zero_stops=False,
                    clock=clock,
                )
                leader = self.velocity.get(joint.name)
                if leader is not None:
                    guard.follow(leader.guard)
                device.attach_joint_stream(guard, joint.name, command.position.register)
                self.position[joint.name] = JointStream(guard, joint.name, own=True)

    def own(self) -> list[JointStream]:
        """The streams the node gives a writer and deadman (``StreamHost.stream``)."""
        return [s for s in (*self.velocity.values(), *self.position.values()) if s.own]

    def command_joints(
        self,
        prefix: str,
        gate: Gate,
        offer: Offer,
        here: Callable[[int], float | None],
        max_jump: Callable[[], float],
    ) -> list[CommandJoint]:
        """The ``CommandJoint`` of each commanded joint, named as in ``joint_states``;
        ``here(index)``: the newest published position of the file's joint ``index``."""
        joints: list[CommandJoint] = []
        for index, joint in enumerate(self.device.device.joints):
            if joint.command is None:
                continue
            joints.append(
                CommandJoint(
                    f"{prefix}{joint.name}",
                    self._stream(joint, self.position, joint.command.position),
                    self._stream(joint, self.velocity, joint.command.velocity),
                    gate,
                    offer,
                    lambda index=index: here(index),  # type: ignore[misc]
                    max_jump,
                )
            )
        return joints

    def _stream(
        self, joint: Joint, streams: dict[str, JointStream], source: JointSource | None
    ) -> CommandStream | None:
        if source is None:
            return None
        stream = streams[joint.name]
        device = self.device
        return CommandStream(
            stream.guard,
            stream.key,
            lambda si: register_value(device, source, si) / stream.per_register,
        )


def register_value(device: DescribedDevice, source: JointSource, si: float) -> float:
    """An SI command as the value of ``source``'s register, checked as a write of it is
    (range, values, type): CommandRejected outside them."""
    value = si / source.to_si
    register = device.map[source.register]
    if not register.value_type.is_float and register.scale == 1.0 and register.offset == 0.0:
        value = float(round(value))  # a whole-number register: its nearest step
    device.words_for(source.register, value)
    return value


def _sender(
    device: DescribedDevice, name: str, source: JointSource
) -> Callable[[str, float, float | None], None]:
    """A stream's writer (velocity or position): the keepalive rule, then the register."""

    def send(_key: str, value: float, _previous: float | None) -> None:
        device.check_keepalive(name)
        device.write(source.register, value)

    return send


def _velocity_stopper(device: DescribedDevice, source: JointSource) -> Callable[[str], None]:
    def stop(_key: str) -> None:
        device.write(source.register, 0.0)

    return stop


def _holder(
    device: DescribedDevice, position: JointSource, command: JointSource
) -> Callable[[str], None]:
    """A position stream's stop: the target set to where the joint is now."""

    def hold(_key: str) -> None:
        here = float(device.read([position.register])[position.register]) * position.to_si
        device.write(command.register, here / command.to_si)

    return hold


__all__ = ["JointStream", "JointStreams", "register_value"]
