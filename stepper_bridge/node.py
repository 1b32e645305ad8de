"""ROS 2 node for the 5-axis stepper controller (docs/bridges/stepper.md; "stepper decision
N" is reading N of docs/decisions/stepper.md).

Units: ``joint_states`` and every positional command (``move_by``, ``line_move``,
``arc_move``) are SI per motor: a prismatic motor's coordinate (user units) / its
``units_per_meter`` in metres, a revolute motor's coordinate / ``units_per_revolution``
x 2 pi in radians (units per joint revolution; 0 takes the lead read from the controller,
40007+, i.e. no reduction). ``configure`` and ``~/state`` keep the controller's own units
(user units, rpm, Hz, degrees of step angle).

Jog: ``~/motor_<n>/jog`` (std_msgs/Float64, motor rpm, sign = direction, 0 = stop) with a
deadman: when no jog message arrived for ``command_timeout_s`` the bridge sends the
motor's stop coil itself, and keeps trying until the link lets it (a jog that was running
when the link dropped is stopped as soon as the link is back). A jog writes its speed to
the motor's speed register; when the jog ends (0, deadman, stop service, e-stop,
shutdown) the configured speed is written back after the stop (a failure is logged and
shown in diagnostics, and retried).

Interpolation pairs: types 2 and 3 are refused until ``interpolation_pair_reading`` says
which of the manual's two readings the controller follows (stepper decisions 11,
19); a line / arc goal that moves a motor outside the configured pair is stopped; a second
line / arc is refused while one this bridge started runs (decision 14).

Replies: a command that starts, stops or changes motion succeeds only when the
controller's state read back shows it, and says what was written and read (stepper
decision 23); halts and stream stops that are not shown log "not confirmed".

Standalone setters per motor: ``set_speed`` (rpm, like ``configure`` and the jog),
``set_direction`` (0/1), ``set_run_distance`` (m / rad, like ``move_by``) and
``set_round_trips`` (mode 1; stepper decision 16). The device id and baud rate are shown in
diagnostics and never written (decision 13).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from std_msgs.msg import Float64

from bridge_core.ros.joint_commands import JointCommandTopic
from bridge_core.ros.node_base import BridgeNode, copy_fields
from bridge_core.ros.process import spin_node
from bridge_core.runtime.diagnostics import Level, Report
from bridge_core.runtime.joint_commands import MAX_JUMP_SPEC
from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.wire.errors import ConfigurationError
from bridge_core.wire.transport import SerialSettings
from msg_defs.msg import StepperState

from .device import StepperDevice
from .interface import PARAMETERS, STEPPER_DEFAULTS
from .joint_commands import MotorTargets, command_joints
from .node_services import create_actions, create_services
from .registers import (
    LONGEST_REPLY_BYTES,
    MOTORS,
    REPLY_DELAY_S,
    reply_timeout_floor_s,
)
from .snapshots import StepperSnapshot
from .units import joint_scales

# StepperState fields copied from the snapshot, and per-motor configuration fields.
STATE_FIELDS = ("running", "coordinates", "inputs", "outputs")
MOTOR_FIELDS = (
    "step_angle_deg",
    "microstep",
    "start_frequency_hz",
    "accel_frequency_hz",
    "direction",
    "speed_rpm",
    "lead",
    "run_distance",
    "positive_limit_input",
    "negative_limit_input",
    "home_input",
)
# StepperState name -> MotorConfig field, where they differ.
MOTOR_FIELDS_RENAMED = {"round_trips": "reciprocations"}
INTERPOLATION_FIELDS = (
    "arc_pair",
    "arc_mode",
    "arc_start",
    "arc_end",
    "arc_center",
    "arc_via",
    "arc_counterclockwise",
    "arc_speed_rpm",
    "line_pair",
    "line_start",
    "line_end",
    "line_speed_rpm",
)


def check_reply_timeout(settings: object) -> None:
    """Refuse (one line) a ``timeout_s`` below the floor at the line's baud rate
    (``registers.reply_timeout_floor_s``, stepper decision 7)."""
    if not isinstance(settings, SerialSettings):
        return
    floor = reply_timeout_floor_s(settings)
    if settings.timeout_s < floor - 1e-9:
        raise ConfigurationError(
            f"timeout_s {settings.timeout_s:g} is below {floor:.2f} s, the least a reply can "
            f"take at {settings.baudrate} baud: the controller answers no sooner than "
            f"{REPLY_DELAY_S * 1000:.0f} ms after a request and the longest reply is "
            f"{LONGEST_REPLY_BYTES} bytes (stepper decision 7)"
        )


class StepperBridgeNode(BridgeNode[StepperSnapshot]):
    """The 5-axis stepper controller: one node per controller, on its own serial line."""

    def __init__(self, node_name: str = "stepper_bridge", **kwargs: Any) -> None:
        super().__init__(node_name, STEPPER_DEFAULTS, **kwargs)
        settings = self.link.settings
        if self._owned_link is not None:
            check_reply_timeout(settings)  # a bus checks its own line (StepperBusNode)
        if isinstance(settings, SerialSettings):
            # Stops and probes while the controller is down wait this long for a reply.
            self.channel.down_write_timeout_s = min(
                reply_timeout_floor_s(settings), settings.timeout_s
            )
        values = self.declare_specs(PARAMETERS)
        self.scales = joint_scales(
            values["joint_types"], values["units_per_meter"], values["units_per_revolution"]
        )
        self.device = StepperDevice(
            self.channel,
            config_refresh_s=float(values["config_refresh_s"]),
            slow_period_s=self.slow_poll_period_s,
            jog_timeout_s=float(values["command_timeout_s"]),
            pair_reading=str(values["interpolation_pair_reading"]).lower(),
        )
        self.device.on_speed_restore_failure = self._speed_restore_failed
        self.goal_tolerance = float(values["goal_tolerance"])
        self.zero_after_home = bool(values["zero_after_home"])
        self.on_parameter("goal_tolerance", lambda value: setattr(self, "goal_tolerance", value))
        self.joint_names = [f"{self.joint_prefix}motor_{m}" for m in range(1, MOTORS + 1)]
        self.state_pub = self.create_publisher(StepperState, "~/state", 10)
        create_services(self)
        create_actions(self)
        self.streams.topic(
            self.device.jogs,
            Float64,
            {n: f"~/motor_{n}/jog" for n in range(1, MOTORS + 1)},
            lambda n, rpm: f"motor {n} jog {rpm} rpm",
            lambda msg: float(msg.data),
            convert=self.device.check_jog,
        )
        # ~/joint_commands (stepper_bridge/joint_commands.py): velocities into the jog
        # streams above, position targets into a stream of their own.
        self.max_jump = float(values[MAX_JUMP_SPEC.name])
        self.on_parameter(MAX_JUMP_SPEC.name, lambda value: setattr(self, "max_jump", value))
        self.targets = MotorTargets(self.device)
        self.streams.stream(
            self.targets.guard,
            lambda n, units: f"motor {n} position target {units:g} units",
            convert=self.targets.observe,
            stop_what=lambda n: f"motor {n} position stream",
        )
        self.joint_commands = JointCommandTopic(
            self,
            command_joints(
                self.joint_names,
                self.device,
                self.targets,
                self.scales,
                self.command_gate(),
                self.streams.offer,
                self._published_position,
                lambda: self.max_jump,
            ),
        )
        self.joint_command_refusals = self.joint_commands.counts

    # ------------------------------------------------------------ units
    def _published_position(self, motor: int) -> float | None:
        """The motor's position in the newest joint_states (SI), None before the first."""
        s = self.last_snapshot
        if s is None:
            return None
        k = motor - 1
        return self.scales[k].to_si(s.coordinates[k], s.config.motors[k].lead)

    def to_units(self, motor: int, si: float) -> float:
        """SI (m or rad) -> controller units for ``motor``."""
        return self.scales[motor - 1].to_units(float(si), self._lead(motor))

    def _lead(self, motor: int) -> float:
        """The device's lead where the motor's conversion needs it (else 0, unused)."""
        return self.device.lead(motor) if self.scales[motor - 1].needs_lead() else 0.0

    def _speed_restore_failed(self, motor: int, rpm: int, err: Exception) -> None:
        self.get_logger().warn(
            f"motor {motor}: writing back its configured speed {rpm} rpm after the jog "
            f"failed: {err}; retried at the next stop or motion command"
        )

    # ------------------------------------------------------------ polling
    def on_link_up(self) -> None:
        # The controller may have been changed (or replaced) while the link was down.
        self.device.invalidate_config()

    def poll_groups(self) -> PollGroups:
        return self.device.groups

    def poll_device(self) -> StepperSnapshot:
        return self.device.poll()

    def replan(self) -> None:
        # A refused status read: re-read the configuration before the next poll.
        self.device.invalidate_config()

    def publish_snapshot(self, s: StepperSnapshot) -> None:
        if (why := self.device.take_wrong_pair()) is not None:
            self._stop_wrong_pair(why)
        motors = s.config.motors
        positions = [self.scales[k].to_si(s.coordinates[k], motors[k].lead) for k in range(MOTORS)]
        self.publish_joints(s.read_time, positions)
        m = copy_fields(self.stamped(StepperState(), s.state_read_time), s, STATE_FIELDS)
        m.slow_stamp = self.stamp(s.slow_read_time)
        copy_fields(m, s.config, ("system_mode", "homing_order"))
        for name in MOTOR_FIELDS:  # one list per field, an item per motor
            setattr(m, name, [getattr(c, name) for c in motors])
        for name, field in MOTOR_FIELDS_RENAMED.items():
            setattr(m, name, [getattr(c, field) for c in motors])
        copy_fields(m, s.config.interpolation, INTERPOLATION_FIELDS)
        m.interpolation_running = self.device.interpolation_run is not None
        self.state_pub.publish(m)

    def _stop_wrong_pair(self, why: str) -> None:
        """A line / arc (service or goal) moved a motor outside its configured pair: the
        interpolation stops now (a goal following it also ends HALTED, decision 19)."""
        ok, message, _ = self.run_command(
            "stop_interpolation (wrong motors)",
            self.device.stop_interpolation,
            stop=True,
            own_motion=True,
        )
        if not ok:
            self.device.wrong_pair_not_stopped()  # tried again after the next poll
        self.get_logger().error(
            f"line / arc stopped: {why}" if ok else f"line / arc NOT stopped: {why}; {message}"
        )

    def device_report(self) -> Report | None:
        s = self.last_snapshot
        if s is None:
            return None
        running = [str(k + 1) for k, r in enumerate(s.running) if r]
        values = [
            # 40212-40214, read only: what the controller says its link settings are.
            ("device id", str(s.config.device_id)),
            ("baud rate", str(s.config.baud_rate)),
            ("system mode", str(s.config.system_mode)),
            ("interpolation pair reading", self.device.pair_reading),
            ("motors running", ", ".join(running) or "none"),
            (
                "jogging",
                ", ".join(str(n) for n in range(1, MOTORS + 1) if self.device.jogging(n)) or "none",
            ),
        ]
        failures = dict(self.device.speed_restore_failures)  # a copy: commands change it
        values.append(
            (
                "jog speed restore failed",
                "; ".join(f"motor {m}: {why}" for m, why in sorted(failures.items())) or "none",
            )
        )
        unknown = [
            str(k + 1)
            for k in range(MOTORS)
            if self.scales[k].needs_lead() and s.config.motors[k].lead <= 0
        ]
        if unknown:
            return Report(
                Level.WARN,
                f"lead 0 on revolute motor(s) {', '.join(unknown)}: position unknown (NaN)",
                values,
            )
        if failures:
            return Report(
                Level.WARN,
                f"motor(s) {', '.join(map(str, sorted(failures)))}: the configured speed "
                "could not be written back after a jog (it is retried)",
                values,
            )
        if s.config.system_mode:
            return Report(
                Level.WARN,
                f"system mode {s.config.system_mode}: the controller's inputs drive the motors",
                values,
            )
        return Report(Level.OK, "connected", values)


def main(args: Sequence[str] | None = None) -> int:
    return spin_node(StepperBridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
