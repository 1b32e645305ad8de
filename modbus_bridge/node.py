"""ROS 2 node for any Modbus device described by a YAML file (``modbus_bridge``).

``-p device_file:=FILE`` names the description (``modbus_bridge/description.py``); its
link settings are the defaults of the usual link parameters (``host``, ``port``,
``serial_port``, ``baudrate`` ...), which override them. Everything else is the shared
runtime of the four hand-written bridges (``bridge_core.ros.node_base.BridgeNode``): polling,
stale data, diagnostics, lifecycle, the command guard, the deadman of command streams.

Interfaces: ``joint_states`` (the file's joints in SI, REP 103), ``~/state``
(``msg_defs/DeviceValues``), ``~/read`` / ``~/write`` by register name, and the file's
named Trigger, value (``SetValue``) and coil (``SetBool``) services and Float64 command
topics.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.lifecycle import LifecycleState, TransitionCallbackReturn
from std_msgs.msg import Float64

from bridge_core.ros.joint_commands import JointCommandTopic
from bridge_core.ros.node_base import BridgeNode
from bridge_core.ros.node_parameters import ParameterNode
from bridge_core.ros.node_services import Command
from bridge_core.ros.node_services import trigger as trigger_service
from bridge_core.ros.process import spin_node
from bridge_core.runtime.checks import listed
from bridge_core.runtime.diagnostics import Level, Report
from bridge_core.runtime.joint_commands import MAX_JUMP_SPEC
from bridge_core.runtime.keepalive import FEED_WAKE_S, Keepalive
from bridge_core.runtime.parameters import DeviceDefaults, ParameterSpec
from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.wire.codec import Value
from bridge_core.wire.errors import CommandRejected, ConfigurationError, DeviceException, LinkError
from bridge_core.wire.registers import ValueType
from bridge_core.wire.transport import ModbusLink
from msg_defs.msg import DeviceValues

from .description import (
    Description,
    Device,
    TopicSpec,
    load,
)
from .device import KEEPALIVE_FEEDS_PER_PERIOD, DescribedDevice, DeviceSnapshot
from .doc import devices_text
from .interface import (
    DEVICE_FILE_SPEC,
    JOINT_COMMAND_PARAMETERS,
    NODE_NAME,
    SERVICES,
    commanded,
    defaults_of,
    expansion,
    stream_parameters,
)
from .joint_commands import JointStreams


def _number(value: Value) -> float:
    if isinstance(value, str):
        return math.nan
    return float(value)


def joint_positions(positions: Sequence[float], joints: int) -> Sequence[float]:
    """joint_states' ``position``: one per joint always, NaN for a joint without a position
    register (decision 14): a file of velocity-only joints (a VFD) publishes NaN, as beside
    a position joint, not an empty array (docs/bridges/modbus.md,
    "Velocity-only joints"). ``velocity`` and ``effort`` stay empty when no joint has them."""
    return positions if positions else (math.nan,) * joints


def described_by_parameter(node: ParameterNode, spec: ParameterSpec) -> tuple[str, Description]:
    """The ``device_file`` parameter (start-up only) and the description it names, read
    before the link parameters (their defaults come from it)."""
    values = node.declare_specs([spec])
    path = str(values["device_file"])
    if not path:
        raise ConfigurationError("no device description: give -p device_file:=FILE")
    if not Path(path).is_file():
        raise ConfigurationError(f"parameter device_file:={path}: no such file")
    return path, load(path)


def keepalive_floor_s(devices_on_line: int, hold_s: float) -> float:
    """The shortest watchdog time the bridge can keep fed on this link (the MOTEC
    lifeguard's bound): a feed falls due a third of the time after the last, wakes up to
    ``FEED_WAKE_S`` late and waits for the transaction in progress and the other devices'
    feeds (``hold_s`` each), so time / 3 + FEED_WAKE_S + devices x hold_s <= time."""
    feeds = KEEPALIVE_FEEDS_PER_PERIOD
    return (FEED_WAKE_S + devices_on_line * hold_s) * feeds / (feeds - 1)


class ModbusBridgeNode(BridgeNode[DeviceSnapshot]):
    """One described device: its file from ``device_file``, or (a device on a line a
    ``ModbusBusNode`` owns) ``device`` with the bus's ``link``, named after the device."""

    def __init__(
        self,
        device: Device | None = None,
        *,
        link: ModbusLink | None = None,
        devices_on_line: int = 1,
        **kwargs: Any,
    ) -> None:
        self.description: Description | None = None
        if device is None:
            super().__init__(NODE_NAME, self._defaults_from_file, link=link, **kwargs)
            assert self.description is not None
            device = self.description.device
        else:
            super().__init__(
                device.name, defaults_of(device), link=link, unit_id=device.unit_id, **kwargs
            )
        self.described: Device = device
        self.device: DescribedDevice = DescribedDevice(
            self.channel, self.described, slow_period_s=self.slow_poll_period_s
        )
        self.hardware_id = f"{self.described.name}@{self.channel.describe()}"
        self.joint_names = [f"{self.joint_prefix}{joint.name}" for joint in self.described.joints]
        self.units: list[str] = [
            self.described.register_map[name].unit for name in self.device_names()
        ]
        self.state_pub: Any = self.create_publisher(DeviceValues, "~/state", 10)
        self._create_services()
        self._create_topics()
        self.keepalive_floor_s = keepalive_floor_s(
            devices_on_line, self.link.settings.longest_hold_s()
        )
        self.keepalive_error: str | None = None  # arming failed, or a period below the floor
        self.keepalive_refused: str | None = None  # the last feed's refusal
        self.configured = False  # lifecycle: the keepalive is fed while configured
        spec = self.described.keepalive
        if (
            spec is not None
            and spec.period_s is not None
            and spec.period_s < self.keepalive_floor_s
        ):
            raise ConfigurationError(
                f"{self.get_name()}: keepalive period_s {spec.period_s} s is below "
                f"{self.keepalive_floor_s:.3f} s, the longest feed gap this link can cause "
                f"(1.5 x ({FEED_WAKE_S:g} s wake-up + {devices_on_line} device(s) x "
                f"{self.link.settings.longest_hold_s():.3f} s, the longest transaction))"
            )
        # Fed from a thread of its own at the link's top priority (bridge_core.runtime.keepalive).
        self.keepalive: Keepalive | None = None
        if self.device.keepalive is not None:
            self.keepalive = self.start_keepalive(
                "keepalive", self._next_feed, self._feed_keepalive
            )

    def _defaults_from_file(self, node: ParameterNode) -> DeviceDefaults:
        path, description = described_by_parameter(node, DEVICE_FILE_SPEC)
        if description.line is not None:
            raise ConfigurationError(
                f"{path} describes {devices_text(len(description.devices))} on one line: "
                "run modbus_bus for it (modbus_bridge serves a file of one device)"
            )
        self.description = description
        return defaults_of(description.device)

    def device_names(self) -> tuple[str, ...]:
        return self.described.state_names

    def on_link_up(self) -> None:
        """The keepalive arms (the device may have been power-cycled, its watchdog time
        changed); pending stops went out before (``BridgeNode._link_up``)."""
        feeder = self.device.keepalive
        if feeder is None or self.read_only:
            return
        try:
            feeder.disarm()
            feeder.arm()
        except DeviceException as err:
            self.keepalive_error = f"arming the keepalive failed: the device answered {err}"
            self.get_logger().error(self.keepalive_error)
            return
        self.keepalive_error = None
        if feeder.period_s is not None and feeder.period_s < self.keepalive_floor_s:
            self.keepalive_error = (
                f"the device's keepalive time {feeder.period_s:g} s is below "
                f"{self.keepalive_floor_s:.3f} s, the longest feed gap this link can cause: "
                "it may trip"
            )
            self.get_logger().error(self.keepalive_error)
        if self.keepalive is not None:
            self.keepalive.wake()

    def _next_feed(self) -> float | None:
        feeder = self.device.keepalive
        if feeder is None or self.read_only or not self.configured:
            return None
        if not self.channel.connected:
            feeder.disarm()  # armed again (read again) on reconnect
            return None
        return feeder.next_feed()

    def _feed_keepalive(self) -> None:
        feeder = self.device.keepalive
        assert feeder is not None
        try:
            with self.channel.command_session():  # not across a reconnect: it arms first
                feeder.due()
            self.keepalive_refused = None
        except LinkError as err:  # the poll reports the link
            self.get_logger().warn(f"keepalive feed failed: {err}", throttle_duration_sec=5.0)
        except DeviceException as err:  # tried again (arming: after KEEPALIVE_ARM_RETRY_S)
            self.keepalive_refused = f"the keepalive: the device answered {err}"
            self.get_logger().error(self.keepalive_refused, throttle_duration_sec=5.0)

    # The keepalive is fed while the node is configured (inactive too: it still owns the
    # device); cleanup ends the feeds, as an exit does, and the device's watchdog trips.
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.configured = True
        if self.keepalive is not None:
            self.keepalive.wake()
        return super().on_configure(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.configured = False
        return super().on_cleanup(state)

    def close(self) -> None:
        try:
            super().close()  # stops first
        finally:
            if self.keepalive is not None:
                self.keepalive.close()

    # ------------------------------------------------------------ polling
    def poll_groups(self) -> PollGroups:
        return self.device.groups

    def poll_device(self) -> DeviceSnapshot:
        return self.device.poll()

    def publish_snapshot(self, snapshot: DeviceSnapshot) -> None:
        if self.joint_names:
            self.publish_joints(
                snapshot.read_time,
                joint_positions(snapshot.positions, len(self.joint_names)),
                snapshot.velocities,
                snapshot.efforts,
            )
        message = self.stamped(DeviceValues(), snapshot.read_time)
        message.slow_stamp = self.stamp(snapshot.slow_read_time)
        message.names = list(snapshot.names)
        message.values = [_number(value) for value in snapshot.values]
        message.units = self.units
        message.texts = [value if isinstance(value, str) else "" for value in snapshot.values]
        self.state_pub.publish(message)

    def device_report(self) -> Report | None:
        spec = self.described.spec.device
        values = [("device", spec.name), ("registers polled", str(len(self.described.state_names)))]
        feeder = self.device.keepalive
        if feeder is not None:
            state = "armed" if feeder.armed else "not armed"
            if feeder.period_s is not None:
                state += f", {feeder.period_s:g} s"
            state += ", NOT fed (read_only)" if self.read_only else ", fed by the bridge"
            values.append(("keepalive", state))
            values.append(("keepalive floor on this link", f"{self.keepalive_floor_s:.3f} s"))
        elif (watchdog_s := self.described.frame_watchdog_s) is not None:
            # keepalive mode any_frame: every request resets the device's watchdog.
            values.append(("keepalive", f"any frame, {watchdog_s:g} s, fed by the polls"))
        if moving := self.service_motions.moving():
            values.append(("motion started", ", ".join(sorted(str(g) for g in moving))))
        if self.keepalive_error or self.keepalive_refused:
            return Report(Level.WARN, str(self.keepalive_error or self.keepalive_refused), values)
        return Report(Level.OK, "connected", values)

    # ------------------------------------------------------------ services
    # The handler of each row of interface.SERVICES (a file's triggers, values and coils:
    # a function of the name).
    def _create_services(self) -> None:
        device = self.device
        commands = self.described.commands
        triggers = {t.name: t for t in commands.triggers}
        coils = {c.name: c for c in commands.coils}

        def fill_read(response: Any, values: dict[str, Value]) -> None:
            register_map = self.described.register_map
            response.names = list(values)
            response.values = [_number(v) for v in values.values()]
            response.units = [register_map[name].unit for name in values]
            response.texts = [v if isinstance(v, str) else "" for v in values.values()]

        def trigger_command(trigger: str) -> Command[object]:
            spec = triggers[trigger]
            # A starts_motion trigger's group is in the node's motion ledger once its write
            # went out, with its group's stop trigger: every way out sends that stop.
            exit_stop = device.exit_stops.get(spec.group) if spec.starts_motion else None
            return trigger_service(
                trigger,
                _bind(device.trigger, trigger),
                stop=spec.stop,
                starts=None
                if exit_stop is None
                else (spec.group, _bind(device.trigger, exit_stop)),
                stops_axes=(spec.group,) if spec.stop else (),
            )

        def value_command(value: str) -> Command[object]:
            return Command(
                _describe_value(value),
                _set_value(device, value),
                fill=lambda response, written: setattr(response, "message", f"{written}: done"),
            )

        def coil_command(coil: str) -> Command[object]:
            return Command(
                _describe_coil(coil),
                _set_coil(device, coil),
                stop=_stops_when(coils[coil].stop_on),
            )

        self.command_services.create(
            SERVICES,
            {
                "~/read": Command(
                    lambda r: f"read {listed(r.names, 'names')}",
                    lambda r: device.read(list(r.names)),
                    writes=False,
                    fill=fill_read,
                ),
                "~/write": Command(
                    lambda r: f"write {r.name}",
                    lambda r: device.write(r.name, self._write_value(r)),
                    fill=lambda response, written: setattr(response, "message", f"{written}: done"),
                ),
                "~/{trigger}": trigger_command,
                "~/{value}": value_command,
                "~/{coil}": coil_command,
            },
            expansion(self.described),
        )

    def _published_position(self, index: int) -> float | None:
        """Joint ``index``'s position in the newest joint_states (SI), None before it."""
        s = self.last_snapshot
        return None if s is None or not s.positions else s.positions[index]

    def _write_value(self, request: Any) -> Value:
        name = str(request.name)
        if name not in self.described.register_map:
            raise CommandRejected(f"no register named {name!r}")
        kind = self.described.register_map[name].value_type
        if kind is ValueType.STRING:
            return str(request.text)
        if kind is ValueType.BOOL:
            if request.value not in (0.0, 1.0):
                raise CommandRejected(f"{name} takes 0 or 1, not {request.value}")
            return bool(request.value)
        return float(request.value)

    # ------------------------------------------------------------ command topics
    def _create_topics(self) -> None:
        for topic in self.described.commands.topics:
            timeout_name, rate_name = (spec.name for spec in stream_parameters(topic))
            self.declare_specs(stream_parameters(topic))
            guard: StreamGuard[str] = StreamGuard(
                [topic.name],
                _sender(self.device, topic),
                _stopper(self.device, topic),
                timeout_s=float(self.param(timeout_name)),
                stop_when_idle=False,
            )
            self.device.attach_stream(topic.name, guard)
            self.streams.topic(
                guard,
                Float64,
                {topic.name: f"~/{topic.name}"},
                _describe_stream(topic.name),
                lambda msg: float(msg.data),
                convert=_converter(self.device, topic),
                timeout_parameter=timeout_name,
                rate_parameter=rate_name,
            )
        if commanded(self.described):
            self._create_joint_commands()

    def _create_joint_commands(self) -> None:
        """``~/joint_commands`` (modbus_bridge/joint_commands.py): a joint's velocity goes
        through the stream of the command topic on its register, when there is one."""
        values = self.declare_specs(JOINT_COMMAND_PARAMETERS)
        self.max_jump = float(values[MAX_JUMP_SPEC.name])
        self.on_parameter(MAX_JUMP_SPEC.name, lambda value: setattr(self, "max_jump", value))
        topic_guards = {
            topic.register_name: (self.device.guards[topic.name], topic.name, topic.scale)
            for topic in self.described.commands.topics
        }
        self.joint_streams = JointStreams(
            self.device, topic_guards, float(values["command_timeout_s"])
        )
        for stream in self.joint_streams.own():
            self.streams.stream(
                stream.guard,
                _describe_stream(stream.key),
                stop_what=lambda key: f"{key} joint_commands stream",
            )
        self.joint_commands = JointCommandTopic(
            self,
            self.joint_streams.command_joints(
                self.joint_prefix,
                self.command_gate(),
                self.streams.offer,
                self._published_position,
                lambda: self.max_jump,
            ),
        )
        self.joint_command_refusals = self.joint_commands.counts


def _bind(action: Any, name: str) -> Any:
    return lambda: action(name)


def _describe_value(name: str) -> Any:
    return lambda r: f"{name} {r.value}"


def _set_value(device: DescribedDevice, name: str) -> Any:
    return lambda r: device.set_value(name, float(r.value))


def _describe_coil(name: str) -> Any:
    return lambda r: f"{name} {'on' if r.data else 'off'}"


def _set_coil(device: DescribedDevice, name: str) -> Any:
    return lambda r: device.set_coil(name, bool(r.data))


def _stops_when(stop_on: bool | None) -> Any:
    """A coil whose ``stop_on`` value ends motion: tried at once, like every stop."""
    return lambda r: stop_on is not None and bool(r.data) == stop_on


def _describe_stream(name: str) -> Any:
    return lambda _key, value: f"{name} {value}"


def _sender(device: DescribedDevice, topic: TopicSpec) -> Any:
    return lambda _key, value, _previous: device.send_stream(topic, value)


def _stopper(device: DescribedDevice, topic: TopicSpec) -> Any:
    return lambda _key: device.stop_stream(topic)


def _converter(device: DescribedDevice, topic: TopicSpec) -> Any:
    return lambda _key, value: device.stream_value(topic, value)


def main(args: Sequence[str] | None = None) -> int:
    return spin_node(ModbusBridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
