"""A test client that behaves as ros2_control's stock topic-based hardware interface.

``TopicSystem`` does, per control cycle, what ``JointStateTopicSystem`` does (Jazzy release,
docs/ros2_control.md): ``read()`` takes the newest ``JointState`` of its state topic
(subscribed with the sensor-data QoS) into its state interfaces, by name; ``write()`` sums
|position state - position command| over all its joints and publishes nothing while the sum
is at most ``trigger_joint_command_threshold``; else one ``JointState`` with every joint's
name and, per joint, its position or velocity command (depth-1 publisher). Commands and
states start at 0 (no ``initial_value``), as in the 0.2.x releases; with
``nan_until_claimed`` the commands start as NaN, as in the 1.x releases (docs/ros2_control.md,
"The interface's releases"), and the NaN difference publishes them every cycle. ``run``
plays a trajectory at ``rate_hz`` (100, the usual controller manager rate) as a controller
would write it into the command interfaces.
"""

from __future__ import annotations

import itertools
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from .ros import Client

DEFAULT_THRESHOLD = 1e-5  # trigger_joint_command_threshold's default
EVERY_CYCLE = -1.0  # docs/ros2_control.md: velocity control needs it
CONTROL_RATE_HZ = 100.0
COMMAND_DEPTH = 1  # rclcpp::QoS(1) of the interface's publisher


@dataclass
class Sent:
    """One published command: monotonic and wall-clock time just after the publish, the
    values by joint, and the wall-clock time just before it (the subscriber may have the
    message before this thread runs again: a lower bound from the arrival uses that one)."""

    monotonic: float
    wall: float
    values: dict[str, float]
    wall_before: float


@dataclass
class TopicSystem:
    client: Client
    commands_topic: str
    states_topic: str
    joints: Sequence[str]
    interface: str  # "position" or "velocity": the joints' command interface
    threshold: float = DEFAULT_THRESHOLD
    state_position: dict[str, float] = field(default_factory=dict)
    state_velocity: dict[str, float] = field(default_factory=dict)
    command: dict[str, float] = field(default_factory=dict)
    sent: list[Sent] = field(default_factory=list)
    nan_until_claimed: bool = False

    def __post_init__(self) -> None:
        for name in self.joints:
            self.state_position.setdefault(name, 0.0)
            self.state_velocity.setdefault(name, 0.0)
            self.command.setdefault(name, math.nan if self.nan_until_claimed else 0.0)
        self._latest: Any = None
        self.seen: set[str] = set()  # joints any state message named
        self._lock = threading.Lock()
        node = self.client.node
        self.publisher = node.create_publisher(JointState, self.commands_topic, COMMAND_DEPTH)
        self.subscription = node.create_subscription(
            JointState, self.states_topic, self._state, qos_profile_sensor_data
        )

    def _state(self, msg: Any) -> None:
        with self._lock:
            self._latest = msg
            self.seen.update(msg.name)

    def read(self) -> None:
        """The newest state message into the state interfaces of the joints it names."""
        with self._lock:
            latest = self._latest
        if latest is None:
            return
        for i, name in enumerate(latest.name):
            if name not in self.state_position:
                continue
            self.state_position[name] = float(latest.position[i])
            if len(latest.velocity):
                self.state_velocity[name] = float(latest.velocity[i])

    def write(self) -> bool:
        """Publish the commands unless the position difference is within the threshold.
        With velocity command interfaces the position commands stay 0 (the interface
        compares positions only)."""
        position_command = self.command if self.interface == "position" else {}
        diff = sum(abs(self.state_position[n] - position_command.get(n, 0.0)) for n in self.joints)
        if diff <= self.threshold:
            return False
        msg = JointState()
        msg.header.stamp = self.client.node.get_clock().now().to_msg()
        msg.name = list(self.joints)
        values = [float(self.command[n]) for n in self.joints]
        if self.interface == "position":
            msg.position = values
        else:
            msg.velocity = values
        wall_before = time.time()
        self.publisher.publish(msg)
        self.sent.append(Sent(time.monotonic(), time.time(), dict(self.command), wall_before))
        return True

    def wait_state(self, timeout: float = 20.0) -> None:
        """Until state messages named every joint (the bridges of one bus publish one
        message per drive)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                seen = set(self.seen)
            if all(n in seen for n in self.joints):
                self.read()
                return
            time.sleep(0.01)
        raise AssertionError(f"no state of {list(self.joints)} on {self.states_topic}")

    def run(
        self,
        trajectory: Callable[[float], Mapping[str, float]],
        duration_s: float,
        rate_hz: float = CONTROL_RATE_HZ,
        until: threading.Event | None = None,
    ) -> float:
        """Cycles of read, command = ``trajectory(t)``, write for ``duration_s`` (or until
        ``until`` is set); returns the wall-clock time of the first cycle (t = 0)."""
        period = 1.0 / rate_hz
        start = time.monotonic()
        wall = time.time()
        cycle = 0
        while True:
            t = time.monotonic() - start
            if t > duration_s or (until is not None and until.is_set()):
                return wall
            self.read()
            self.command.update(trajectory(t))
            self.write()
            cycle += 1
            time.sleep(max(0.0, start + cycle * period - time.monotonic()))

    def run_unclaimed(self, duration_s: float, rate_hz: float = CONTROL_RATE_HZ) -> None:
        """Cycles before a controller claims the command interfaces: they hold their
        initial values (0), which the interface publishes once it read a state away
        from them (docs/ros2_control.md, decision 3)."""
        self.run(lambda _t: {}, duration_s, rate_hz)

    def close(self) -> None:
        self.client.node.destroy_publisher(self.publisher)
        self.client.node.destroy_subscription(self.subscription)


def ramp(start: float, waypoints: Sequence[tuple[float, float]]) -> Callable[[float], float]:
    """Position through ``waypoints`` ((segment duration s, position)) from ``start``,
    linear in each segment, then held at the last."""

    def at(t: float) -> float:
        here = start
        for duration, target in waypoints:
            if t <= duration:
                return here + (target - here) * t / duration
            t -= duration
            here = target
        return here

    return at


def trapezoid(peak: float, accel_s: float, cruise_s: float) -> Callable[[float], float]:
    """Velocity: up to ``peak`` in ``accel_s``, ``cruise_s`` at it, down in ``accel_s``,
    then 0. Its distance is ``peak x (accel_s + cruise_s)``."""

    def at(t: float) -> float:
        if t < accel_s:
            return peak * t / accel_s
        if t < accel_s + cruise_s:
            return peak
        if t < 2 * accel_s + cruise_s:
            return peak * (2 * accel_s + cruise_s - t) / accel_s
        return 0.0

    return at


def trapezoid_distance(peak: float, accel_s: float, cruise_s: float) -> float:
    return peak * (accel_s + cruise_s)


def sent_distance(sent: Sequence[Sent], joint: str) -> float:
    """The distance the velocities a system published command: each value held from its
    send until the next (the last, a 0 at the end of a trapezoid, adds nothing). A
    velocity test compares the joint with this, not with the ideal profile: beside CPU
    burners the client's own cycles come late (a 0.2 s stall at 3 rad/s before the
    ramp-down is 0.6 rad the ideal profile never commanded)."""
    return sum(
        one.values[joint] * (after.monotonic - one.monotonic)
        for one, after in itertools.pairwise(sent)
    )


def ramp_end(waypoints: Sequence[tuple[float, float]]) -> float:
    return waypoints[-1][1]


def ramp_duration(waypoints: Sequence[tuple[float, float]]) -> float:
    return sum(duration for duration, _ in waypoints)


__all__ = [
    "CONTROL_RATE_HZ",
    "DEFAULT_THRESHOLD",
    "EVERY_CYCLE",
    "Sent",
    "TopicSystem",
    "ramp",
    "ramp_duration",
    "ramp_end",
    "sent_distance",
    "trapezoid",
    "trapezoid_distance",
]
