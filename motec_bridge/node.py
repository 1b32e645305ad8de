"""ROS 2 nodes for MOTEC β servo drives on one RS-485 bus (docs/bridges/motec.md).

One process, one serial port, one node per drive. ``main`` starts:

- ``motec_bridge``: the bus owner (``MotecBusNode``, bus.py). It has the serial
  parameters (``serial_port``, ``baudrate``, ``parity``, ``stopbits``, ``timeout_s``)
  ``unit_ids`` and ``interface`` (rs485 / rs232: at most 31 / 8 drives, §1.1), opens the
  one ``ModbusLink`` every drive shares, and offers ``~/disable_all`` (one broadcast write,
  unit 0: 0x28 = 0 on every drive, unanswered) and ``~/start_all`` (every drive's modes
  read, then a broadcast 0x29 = 1: a synchronised start, MOTEC decision 15).
- ``motec_<id>`` per unit id: a ``BridgeNode`` (``MotecDriveNode``, here) given the
  shared link and its unit id as Python values, with its own ``DeviceChannel`` (so its
  own backoff: a dead drive is retried on its own schedule, the others keep their poll
  slots), poll thread, topics, services and parameters. It declares no serial
  parameters (they are the bus's) and never closes the link (the bus node does, after
  every drive stopped).

Parameters: a params file's ``/**:`` block reaches every node of the process (bus and
drives); a ``/**/motec_<id>:`` block overrides one drive; ``-p name:=value`` on the
command line reaches every node. See config/motec.yaml.

Fairness: every transaction holds the link's PriorityLock (FIFO within a priority,
commands first), so drives polling at the same rate take turns request by request.

Units: ``joint_states`` position = 0xAC counts / (``counts_per_rev`` x ``gear_ratio``)
x 2 pi (rad), velocity = 0xAF rpm x 2 pi / 60 / ``gear_ratio`` (rad/s); ``~/move`` and
``~/cmd_velocity`` take the same units. ``~/state`` stays in counts and rpm.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from typing import Any

from rclpy.lifecycle import LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from std_msgs.msg import Float64

from bridge_core.ros.node_base import BridgeNode, copy_fields
from bridge_core.ros.node_services import Command, trigger
from bridge_core.ros.process import spin_nodes
from bridge_core.runtime.checks import board_zero_index
from bridge_core.runtime.diagnostics import Level, Report
from bridge_core.runtime.joint_commands import MAX_JUMP_SPEC, CommandJoint, RefusalCounts
from bridge_core.runtime.keepalive import IDLE_CHECK_S
from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.wire.errors import ConfigurationError, DeviceException, LinkError
from bridge_core.wire.transport import ModbusLink
from msg_defs.msg import MotecState

from .bus import MotecBusNode
from .device import VELOCITY_STREAM, MotecDevice
from .interface import DRIVE_ACTIONS, DRIVE_SERVICES, MOTEC_DEFAULTS, drive_parameters
from .joint_commands import DriveTarget, command_joint
from .lifeguard import lifeguard_bound_text, lifeguard_min_ms
from .motions import MoveToMotion
from .registers import control_mode_name, fault_text, operation_mode_name
from .snapshots import MotecSnapshot
from .units import DriveScale

# MotecState fields copied as they are from the snapshot and its configuration.
STATE_FIELDS = (
    "motion_mode",
    "start",
    "target_distance",
    "fault_code",
    "position_setpoint",
    "position_actual",
    "speed_setpoint_rpm",
    "speed_actual_rpm",
    "moving",
    "inputs",
    "outputs",
    "input_word",
    "output_word",
    "analog_input",
)
CONFIG_FIELDS = ("analog_max_speed_rpm", "lifeguard_time_ms", "lifeguard_mode", "lifeguard_armed")


def drive_node_name(unit_id: int) -> str:
    return f"motec_{unit_id}"


# The axis of what a drive node's services set moving (its motion ledger).
DRIVE = "drive"


class MotecDriveNode(BridgeNode[MotecSnapshot]):
    """One drive on the shared bus."""

    def __init__(
        self, unit_id: int, link: ModbusLink, *, drives_on_bus: int = 1, **kwargs: Any
    ) -> None:
        super().__init__(
            drive_node_name(unit_id), MOTEC_DEFAULTS, link=link, unit_id=unit_id, **kwargs
        )
        self.unit_id = unit_id
        # The shortest lifeguard time this bus can keep fed (docs/bridges/motec.md, "Lifeguard").
        hold_s = link.settings.longest_hold_s()
        self.lifeguard_floor_ms = lifeguard_min_ms(drives_on_bus, hold_s)
        self.lifeguard_bound = lifeguard_bound_text(drives_on_bus, hold_s)
        values = self.declare_specs(drive_parameters(drives_on_bus, hold_s))
        self.scale = DriveScale(float(values["counts_per_rev"]), float(values["gear_ratio"]))
        self.lifeguard_ms = int(values["lifeguard_ms"])
        if reason := self._lifeguard_refusal(self.lifeguard_ms):
            raise ConfigurationError(f"{self.get_name()}: {reason}")
        self.device = MotecDevice(
            self.channel,
            max_speed_rpm=int(values["max_speed_rpm"]),
            config_refresh_s=float(values["config_refresh_s"]),
            slow_period_s=self.slow_poll_period_s,
            velocity_timeout_s=float(values["command_timeout_s"]),
            output1_coil=int(values["output1_coil"]),
            read_io_tables=bool(values["read_io_tables"]),
            allow_unlisted_parameters=bool(values["allow_unlisted_parameters"]),
        )
        self.lifeguard_error: str | None = None
        self.goal_tolerance_counts = int(values["goal_tolerance_counts"])
        self.on_parameter(
            "goal_tolerance_counts", lambda value: setattr(self, "goal_tolerance_counts", value)
        )
        self.move_time_margin = float(values["move_time_margin"])
        self.on_parameter(
            "move_time_margin", lambda value: setattr(self, "move_time_margin", float(value))
        )
        # read_only stops the lifeguard feeds: refused while the drive is armed (item 5).
        self.on_parameter_write("read_only", self._read_only_refusal)
        self.joint_names = [f"{self.joint_prefix}drive_{unit_id}"]
        self.state_pub = self.create_publisher(MotecState, "~/state", 10)
        self._create_services()
        self.streams.topic(
            self.device.stream,
            Float64,
            {VELOCITY_STREAM: "~/cmd_velocity"},
            lambda _key, rad_s: f"cmd_velocity {rad_s} rad/s",
            lambda msg: float(msg.data),
            convert=lambda _key, rad_s: self.device.check_velocity(self.scale.to_rpm(rad_s)),
        )
        # The bus owner's ~/joint_commands (motec_bridge/joint_commands.py): velocities
        # into the stream above, position targets into one of their own.
        self.max_jump = float(values[MAX_JUMP_SPEC.name])
        self.on_parameter(MAX_JUMP_SPEC.name, lambda value: setattr(self, "max_jump", value))
        self.position_max_velocity = float(values["position_max_velocity"])
        self.on_parameter(
            "position_max_velocity",
            lambda value: setattr(self, "position_max_velocity", float(value)),
        )
        # This drive's own refusals of the bus owner's topic (in its own diagnostics).
        self.joint_refusals = RefusalCounts()
        self.joint_command_refusals = self.joint_refusals
        self.target = DriveTarget(
            self.device, lambda: self.scale.to_rpm(self.position_max_velocity)
        )
        self.streams.stream(
            self.target.guard,
            lambda _key, counts: f"position target {counts:g} counts",
            stop_what=lambda _key: "position stream",
        )
        self.configured = False  # lifecycle: set by on_configure (autostart does it at once)
        self.on_parameter_write("lifeguard_ms", self._set_lifeguard)
        self.keepalive = self.start_keepalive("lifeguard", self._next_feed, self._feed_lifeguard)

    # ------------------------------------------------------------ polling
    def on_link_up(self) -> None:
        # The drive may have been power-cycled (or swapped) while the link was down.
        self.device.invalidate_config()
        if self.lifeguard_ms and not self.read_only:
            try:
                self.device.arm_lifeguard(self.lifeguard_ms)
                self.lifeguard_error = None
            except DeviceException as err:
                self.lifeguard_error = f"arming the lifeguard failed: the drive answered {err}"
                self.get_logger().error(self.lifeguard_error)

    def poll_groups(self) -> PollGroups:
        return self.device.groups

    def poll_device(self) -> MotecSnapshot:
        return self.device.poll()

    def publish_snapshot(self, s: MotecSnapshot) -> None:
        self.publish_joints(
            s.read_time,
            [self.scale.position(s.position_actual)],
            [self.scale.velocity(s.speed_actual_rpm)],
        )
        m = copy_fields(self.stamped(MotecState(), s.read_time), s, STATE_FIELDS)
        m.slow_stamp = self.stamp(s.slow_read_time)
        copy_fields(m, s.config, CONFIG_FIELDS)
        m.unit_id = self.unit_id
        m.operation_mode = s.modes.operation_mode
        m.operation_mode_name = operation_mode_name(s.modes.operation_mode)
        m.control_mode = s.modes.control_mode
        m.control_mode_name = control_mode_name(s.modes.control_mode)
        m.enabled = s.modes.enabled
        m.fault_text = fault_text(s.fault_code)
        m.fault_flag = s.fault_flag
        m.fault_detail = s.fault_detail
        m.output1_coil = s.output1_coil
        m.io_tables_read = s.coil_outputs is not None
        if s.coil_outputs is not None and s.discrete_inputs is not None:
            m.output_word_0x79 = s.output_word_79 or 0
            m.coil_outputs = list(s.coil_outputs)
            m.discrete_inputs = list(s.discrete_inputs)
        self.state_pub.publish(m)

    def command_joint(self) -> CommandJoint:
        """This drive's joint of the bus owner's ``~/joint_commands``."""
        return command_joint(
            self.joint_names[0],
            self.device,
            self.target,
            self.scale,
            self.command_gate(),
            self.streams.offer,
            self._published_position,
            lambda: self.max_jump,
            self.joint_refusals,
        )

    def _published_position(self) -> float | None:
        """The drive's position in the newest joint_states (rad), None before the first."""
        s = self.last_snapshot
        return None if s is None else self.scale.position(s.position_actual)

    def lifeguard_time_ms(self) -> int:
        """The watchdog time the bridge feeds: its parameter, or the drive's own setting."""
        if self.lifeguard_ms:
            return self.lifeguard_ms
        if self.device.has_config and self.device.config.lifeguard_armed:
            return self.device.config.lifeguard_time_ms
        return 0

    def device_report(self) -> Report | None:
        s = self.last_snapshot
        if s is None:
            return None
        d = self.device
        lifeguard = "off"
        if s.config.lifeguard_armed:
            lifeguard = f"armed, {s.config.lifeguard_time_ms} ms"
            lifeguard += ", NOT fed (read_only)" if self.read_only else ", fed by the bridge"
        stream = "idle"
        if d.streaming:
            stream = f"commanding {d.stream_rpm} rpm"
        elif d.stream_locked:
            stream = "locked after ~/stop (send 0)"
        values = [
            ("unit id", str(self.unit_id)),
            (
                "operation mode",
                f"{s.modes.operation_mode} ({operation_mode_name(s.modes.operation_mode)})",
            ),
            ("control mode", f"{s.modes.control_mode} ({control_mode_name(s.modes.control_mode)})"),
            ("enabled", str(s.modes.enabled).lower()),
            ("fault code", f"{s.fault_code} (0x{s.fault_code:08X}): {fault_text(s.fault_code)}"),
            ("position (counts)", str(s.position_actual)),
            ("speed (rpm)", str(s.speed_actual_rpm)),
            ("analog input (raw)", str(s.analog_input)),
            ("lifeguard", lifeguard),
            ("lifeguard_ms floor on this bus", f"{self.lifeguard_floor_ms} ms"),
            ("cmd_velocity", stream),
        ]
        if s.fault_code:
            return Report(
                Level.ERROR, f"drive fault {s.fault_code}: {fault_text(s.fault_code)}", values
            )
        if self.lifeguard_error:
            return Report(Level.WARN, self.lifeguard_error, values)
        if (
            s.config.lifeguard_armed
            and not self.read_only
            and s.config.lifeguard_time_ms < self.lifeguard_floor_ms
        ):
            return Report(
                Level.WARN,
                f"the drive's lifeguard time {s.config.lifeguard_time_ms} ms is below "
                f"{self.lifeguard_floor_ms} ms, the longest feed gap this bus can cause: "
                f"it may trip (set lifeguard_ms)",
                values,
            )
        if s.config.lifeguard_armed and self.read_only:
            return Report(
                Level.WARN, "the drive's lifeguard is armed but read_only stops the feed", values
            )
        return Report(Level.OK, "connected", values)

    # ------------------------------------------------------------ services
    # The handler of each row of interface.DRIVE_SERVICES / DRIVE_ACTIONS.
    def _create_services(self) -> None:
        d = self.device
        self.command_services.create(
            DRIVE_SERVICES,
            {
                "~/enable": Command(
                    lambda r: f"enable {'on' if r.data else 'off'}",
                    lambda r: d.enable(bool(r.data)),
                    stop=lambda r: not r.data,  # a disable ends motion: tried even while down
                    stops_axes=lambda r: () if r.data else (DRIVE,),
                ),
                "~/set_control_mode": Command(
                    lambda r: f"set_control_mode {control_mode_name(r.mode)}",
                    self._set_control_mode,
                ),
                "~/move": Command(
                    lambda r: f"move {'by' if r.relative else 'to'} {r.position} rad",
                    self._move,
                    fill=lambda response, counts: setattr(response, "counts", counts),
                    # A halt stops the move it set going: 0x29 = 0 at once, verified
                    # (stop_move; ~/stop's mode read first could keep it off the wire on a
                    # bad line).
                    starts=lambda _r: (DRIVE, d.stop_move),
                ),
                "~/stop": trigger("stop", d.stop, stop=True, fill=_said, stops_axes=(DRIVE,)),
                "~/save_to_flash": trigger("save_to_flash", d.save_to_flash),
                "~/set_output": Command(
                    lambda r: f"set_output {r.index} {'on' if r.state else 'off'}",
                    lambda r: d.set_output(board_zero_index("drive", r.board, r.index), r.state),
                ),
                "~/set_analog_max_speed": Command(
                    lambda r: f"set_analog_max_speed {r.value} rpm",
                    lambda r: d.set_analog_max_speed(r.value),
                ),
                "~/read_parameter": Command(
                    lambda r: f"read_parameter Pr.{r.index}",
                    lambda r: d.read_parameter(int(r.index)),
                    writes=False,
                    fill=lambda response, value: setattr(response, "value", value),
                ),
                "~/write_parameter": Command(
                    lambda r: f"write_parameter Pr.{r.index} = {r.value}",
                    lambda r: d.write_parameter(int(r.index), int(r.value)),
                ),
            },
        )
        self.actions.create(DRIVE_ACTIONS, {"~/move_to": self._move_to})

    def _move_to(self, goal: Any) -> MoveToMotion:
        return MoveToMotion(
            self.device,
            self.scale,
            float(goal.position),
            relative=bool(goal.relative),
            max_velocity_rad_s=float(goal.max_velocity),
            tolerance_counts=self.goal_tolerance_counts,
            # A goal's own timeout_s replaces the default limit.
            time_limit_margin=0.0 if float(goal.timeout_s) > 0 else self.move_time_margin,
        )

    def _set_control_mode(self, r: Any) -> None:
        self.device.set_control_mode(int(r.mode))  # refused while turning, read fresh

    def _move(self, r: Any) -> int:
        counts = self.scale.to_counts(float(r.position))
        rpm = self.scale.to_rpm(float(r.max_velocity))
        self.device.move(counts, relative=bool(r.relative), speed_rpm=rpm)
        return counts

    # ------------------------------------------------------------ lifeguard
    def _lifeguard_refusal(self, time_ms: int) -> str | None:
        """Why ``time_ms`` cannot be kept fed on this bus (None: it can, or 0 = off)."""
        if time_ms == 0 or time_ms >= self.lifeguard_floor_ms:
            return None
        return (
            f"lifeguard_ms {time_ms} is below {self.lifeguard_floor_ms} ms, the longest the "
            f"bridge may go without writing to a drive on this bus = {self.lifeguard_bound}; "
            f"give at least {self.lifeguard_floor_ms}, or lower timeout_s (0 = off)"
        )

    def _set_lifeguard(self, time_ms: int) -> str | None:
        """A run-time ``lifeguard_ms``: arm / re-arm the drive now, or disarm it (0)."""
        if reason := self._lifeguard_refusal(time_ms):
            return reason
        what = f"lifeguard_ms {time_ms}"
        ok, message, _ = self.run_command(
            what,
            lambda: (
                self.device.arm_lifeguard(time_ms) if time_ms else self.device.disarm_lifeguard()
            ),
        )
        if not ok:
            return message
        self.lifeguard_ms = time_ms
        self.lifeguard_error = None
        self.keepalive.wake()
        return None

    def _next_feed(self) -> float | None:
        # Fed while the drive is marked down too, once it was up (armed by on_link_up):
        # a line that comes back within the lifeguard time must find the drive fed
        # before it trips (docs/bridges/motec.md, "Lifeguard").
        if self.read_only or not self.configured or self.channel.generation == 0:
            return None
        time_ms = self.lifeguard_time_ms()
        if not time_ms:
            return None
        if self.channel.connected:
            return self.device.next_feed(time_ms)
        # Down: looked at again every IDLE_CHECK_S, so that once a probe finds the drive
        # the overdue feed goes at once, not at the next try of the down schedule.
        return min(self.device.next_feed(time_ms, down=True), time.monotonic() + IDLE_CHECK_S)

    def _feed_lifeguard(self) -> None:
        time_ms = self.lifeguard_time_ms()
        try:
            if self.channel.connected:
                with self.channel.command_session():
                    self.device.feed_lifeguard(time_ms)
            else:
                # As a stop is sent while down: one try, the short stop timeout, no
                # session (no reconnect to wait for); on next_feed's down schedule.
                self.device.feed_lifeguard(time_ms, down=True)
        except LinkError as err:  # the poll reports the link; nothing else to do here
            self.get_logger().warn(f"lifeguard feed failed: {err}", throttle_duration_sec=5.0)

    def _read_only_refusal(self, value: bool) -> str | None:
        """Why read_only may not be set now: it would end the feeds of an armed drive,
        which then faults and releases its motor (a vertical axis drops)."""
        time_ms = self.lifeguard_time_ms()
        if not value or self.read_only or not time_ms:
            return None
        return (
            f"read_only refused: the drive's lifeguard is armed ({time_ms} ms) and read_only "
            f"ends its feeds, so the drive would fault and release its motor within {time_ms} "
            "ms; set lifeguard_ms to 0 first (disarms the drive), then read_only"
        )

    # The lifeguard is fed while the node is configured (inactive too: it still owns the
    # drive); cleanup ends the feeds, as an exit does, and the armed drive then faults.
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.configured = True
        self.keepalive.wake()
        return super().on_configure(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.configured = False
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        result = super().on_shutdown(state)  # stops first
        self.configured = False
        return result

    def close(self) -> None:
        try:
            super().close()  # stops first
        finally:
            self.keepalive.close()


def _said(response: Any, what: str) -> None:
    response.message += f" ({what})"


def build_nodes(nodes: list[Node]) -> None:
    """The bus owner first, then one node per drive on its link."""
    bus = MotecBusNode()
    nodes.append(bus)
    for unit in bus.unit_ids:
        drive = MotecDriveNode(unit, bus.link, drives_on_bus=len(bus.unit_ids))
        bus.drive_nodes[unit] = drive
        nodes.append(drive)
    bus.command_drives()


def main(args: Sequence[str] | None = None) -> int:
    return spin_nodes(build_nodes, args)


if __name__ == "__main__":
    sys.exit(main())
