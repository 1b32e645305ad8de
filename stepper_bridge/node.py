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

import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from bridge_core.ros.joint_commands import JointCommandTopic
from bridge_core.ros.node_base import BridgeNode, copy_fields
from bridge_core.ros.process import spin_node
from bridge_core.runtime.checks import board_zero_index, listed
from bridge_core.runtime.diagnostics import Level, Report
from bridge_core.runtime.joint_commands import MAX_JUMP_SPEC
from bridge_core.runtime.rate_groups import PollGroups
from bridge_core.wire.errors import CommandRejected, ConfigurationError
from bridge_core.wire.serial_timing import char_time_s
from bridge_core.wire.transport import SerialSettings
from msg_defs.action import ArcMotion, LineMotion, StepperMoveBy, StepperRun
from msg_defs.msg import StepperState
from msg_defs.srv import (
    ArcMove,
    ConfigureMotor,
    ConfirmedCommand,
    LineMove,
    MoveBy,
    SetHomingOrder,
    SetInteger,
    SetLimitInputs,
    SetOutput,
    SetValue,
)

from .device import DESTRUCTIVE_COMMANDS, SYSTEM_COMMANDS, StepperDevice
from .interface import PARAMETERS, STEPPER_DEFAULTS
from .joint_commands import MotorTargets, command_joints
from .motions import CoilMotion, HomeMotion, InterpolationMotion, MoveByMotion
from .registers import (
    INTERPOLATION_PAIRS,
    LONGEST_REPLY_BYTES,
    MOTOR_ACTIONS,
    MOTOR_FORBIDDEN_DURING_INTERPOLATION,
    MOTORS,
    REPLY_DELAY_S,
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
# ~/clear_all_parameters: the manual's clear-all ("清零所有参数") reaches the link settings.
CLEAR_ALL_WARNING = (
    "the link may be lost: clear-all may reset the device id (40212) and baud rate "
    "(40213) to 1 and 9600 (stepper decision 15)"
)


# §3: "485 接口通信时每帧数据响应时间不能低于 35ms": the controller answers no sooner than
# 35 ms after a request (stepper decision 7). The reply timeout counts from the
# request's last byte, so it must cover those 35 ms and the longest reply (a 49-register
# read, 103 bytes: 107 ms at 9600 baud, 215 ms at 4800), plus a margin, rounded up to
# 10 ms: 0.15 s at 9600 baud 8N1, 0.26 s at 4800, 0.10 s at 19200, 0.07 s at 38400
# (``reply_timeout_floor_s``). A lower ``timeout_s`` is refused at start. The other
# reading (the host must leave 35 ms between frames) is served by ``frame_gap_s``.
TIMEOUT_MARGIN_S = 0.005
TIMEOUT_STEP_S = 0.01


def reply_timeout_floor_s(settings: SerialSettings) -> float:
    """The least reply timeout the manual's 35 ms rule allows on this line (s)."""
    char = char_time_s(settings.baudrate, settings.bytesize, settings.parity, settings.stopbits)
    least = REPLY_DELAY_S + LONGEST_REPLY_BYTES * char + TIMEOUT_MARGIN_S
    return math.ceil(round(least / TIMEOUT_STEP_S, 6)) * TIMEOUT_STEP_S


def check_reply_timeout(settings: object) -> None:
    """Refuse (one line) a ``timeout_s`` below the floor at the line's baud rate."""
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


# Axes of the node's motion ledger (what services set moving; a halt stops them).
ALL_MOTORS = "all motors"  # home_all / return_to_zero
PAIR = "interpolation"  # line_move / arc_move
ALL_MOTOR_MOTIONS = ("home_all", "return_to_zero")
EVERY_AXIS = (ALL_MOTORS, PAIR, *(("motor", n) for n in range(1, MOTORS + 1)))


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
        self._create_services()
        self._create_actions()
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

    # ------------------------------------------------------------ services
    # One table: a row per service of each motor and of the controller (type, name, log
    # text, device call); splitting it would scatter the node's interface.
    def _create_services(self) -> None:
        d = self.device
        for n in range(1, MOTORS + 1):
            ns = f"~/motor_{n}"
            motor_started = (("motor", n), _bind(d.motor_action, n, "stop"))
            for action in MOTOR_ACTIONS:
                self._read_back_trigger(
                    f"{ns}/{action}",
                    f"motor {n} {action}",
                    _bind(d.motor_action, n, action),
                    stop=action == "stop",
                    starts=None if action == "stop" else motor_started,
                    stops_axes=(("motor", n),) if action == "stop" else (),
                )
            self.command_service(
                MoveBy,
                f"{ns}/move_by",
                lambda r, n=n: f"motor {n} move_by {r.distance}",  # type: ignore[misc]
                lambda r, n=n: d.move_by(n, self.to_units(n, r.distance)),  # type: ignore[misc]
                starts=lambda _r, started=motor_started: started,  # type: ignore[misc]
                fill=_said,
            )
            self.command_service(
                ConfigureMotor,
                f"{ns}/configure",
                lambda _r, n=n: f"motor {n} configure",  # type: ignore[misc]
                lambda r, n=n: d.configure(  # type: ignore[misc]
                    n,
                    step_angle_deg=r.step_angle_deg,
                    microstep=r.microstep,
                    start_frequency_hz=r.start_frequency_hz,
                    accel_frequency_hz=r.accel_frequency_hz,
                    speed_rpm=r.speed_rpm,
                    lead=r.lead,
                ),
            )
            self.command_service(
                SetInteger,
                f"{ns}/set_speed",
                lambda r, n=n: f"motor {n} set_speed {r.value} rpm",  # type: ignore[misc]
                lambda r, n=n: d.set_speed(n, r.value),  # type: ignore[misc]
                fill=_said,
            )
            self.command_service(
                SetInteger,
                f"{ns}/set_direction",
                lambda r, n=n: f"motor {n} set_direction {r.value}",  # type: ignore[misc]
                lambda r, n=n: d.set_direction(n, r.value),  # type: ignore[misc]
            )
            self.command_service(
                SetValue,
                f"{ns}/set_run_distance",
                lambda r, n=n: f"motor {n} set_run_distance {r.value}",  # type: ignore[misc]
                lambda r, n=n: self._set_run_distance(n, r.value),  # type: ignore[misc]
            )
            self.command_service(
                SetInteger,
                f"{ns}/set_round_trips",
                lambda r, n=n: f"motor {n} set_round_trips {r.value}",  # type: ignore[misc]
                lambda r, n=n: d.set_round_trips(n, r.value),  # type: ignore[misc]
            )
            self.command_service(
                SetLimitInputs,
                f"{ns}/set_limit_inputs",
                lambda r, n=n: (  # type: ignore[misc]
                    f"motor {n} limit inputs +{r.positive_limit} -{r.negative_limit} home {r.home}"
                ),
                lambda r, n=n: d.set_limit_inputs(  # type: ignore[misc]
                    n, r.positive_limit, r.negative_limit, r.home
                ),
            )
        for name in SYSTEM_COMMANDS:
            self._read_back_trigger(
                f"~/{name}",
                name,
                _bind(d.system_command, name),
                stop=name == "emergency_stop",
                starts=(ALL_MOTORS, self._stop_every_motor) if name in ALL_MOTOR_MOTIONS else None,
                stops_axes=EVERY_AXIS if name == "emergency_stop" else (),
            )
        for name in DESTRUCTIVE_COMMANDS:
            self.command_service(
                ConfirmedCommand,
                f"~/{name}",
                lambda _r, name=name: name,  # type: ignore[misc]
                lambda r, name=name: self._destructive(name, r.confirm),  # type: ignore[misc]
                fill=self._clear_all_reply if name == "clear_all_parameters" else None,
            )
        self.command_service(
            SetOutput,
            "~/set_output",
            lambda r: f"set_output {r.index} {'on' if r.state else 'off'}",
            lambda r: d.set_output(
                board_zero_index("stepper controller", r.board, r.index), r.state
            ),
        )
        self.command_service(
            SetBool,
            "~/set_all_outputs",
            lambda r: f"set_all_outputs {'on' if r.data else 'off'}",
            lambda r: d.set_all_outputs(r.data),
        )
        self.command_service(
            SetHomingOrder,
            "~/set_homing_order",
            lambda r: f"set_homing_order {listed(r.motors, 'motors', bracketed=True)}",
            lambda r: d.set_homing_order([int(m) for m in r.motors]),
        )
        self.command_service(
            SetInteger,
            "~/set_system_mode",
            lambda r: f"set_system_mode {r.value}",
            lambda r: d.set_system_mode(r.value),
        )
        pair_started = (PAIR, d.stop_interpolation)
        self.command_service(
            LineMove,
            "~/line_move",
            lambda r: _pair_move_text("line_move", r.pair),
            lambda r: self._prepare_line(r).send(True),
            starts=lambda _r: pair_started,
            fill=_said,
        )
        self.command_service(
            ArcMove,
            "~/arc_move",
            lambda r: _pair_move_text("arc_move", r.pair),
            lambda r: self._prepare_arc(r).send(True),
            starts=lambda _r: pair_started,
            fill=_said,
        )
        self._read_back_trigger(
            "~/stop_interpolation",
            "stop_interpolation",
            d.stop_interpolation,
            stop=True,
            stops_axes=(PAIR,),
        )

    def _read_back_trigger(
        self,
        name: str,
        what: str,
        action: Callable[[], object],
        *,
        stop: bool = False,
        starts: tuple[Any, Callable[[], object]] | None = None,
        stops_axes: Sequence[Any] = (),
    ) -> None:
        """A std_srvs/Trigger service whose reply says what was written and read back
        (the device's text), as ``trigger_service`` otherwise."""
        self.command_service(
            Trigger,
            name,
            lambda _request: what,
            lambda _request: action(),
            stop=stop,
            starts=None if starts is None else lambda _request: starts,
            stops_axes=lambda _request: stops_axes,
            fill=_said,
        )

    def _stop_every_motor(self) -> str:
        """Each motor's own stop coil (not the e-stop, which also switches every output
        off), every one tried, then the running flags read back: what a halt sends after
        a service's ``home_all`` / ``return_to_zero``."""
        return self.device.stop_motors(range(1, MOTORS + 1))

    # ------------------------------------------------------------ actions
    def _create_actions(self) -> None:
        """The timed motions as actions (docs/actions.md), beside their services."""
        d = self.device
        every_motor = tuple(range(1, MOTORS + 1))
        for n in every_motor:
            self.actions.motion(
                StepperMoveBy,
                f"~/motor_{n}/move_by",
                lambda goal, n=n: MoveByMotion(  # type: ignore[misc]
                    d,
                    self.scales,
                    n,
                    self.to_units(n, goal.distance),
                    float(goal.distance),
                    tolerance=self.goal_tolerance,
                ),
            )
            self.actions.motion(
                StepperRun,
                f"~/motor_{n}/home",
                lambda _goal, n=n: HomeMotion(  # type: ignore[misc]
                    d, self.scales, "home", (n,), tolerance=self.goal_tolerance, zero=self._zero()
                ),
            )
        self.actions.motion(
            StepperRun,
            "~/home_all",
            lambda _goal: HomeMotion(
                d,
                self.scales,
                "home_all",
                every_motor,
                tolerance=self.goal_tolerance,
                homed=self._homing_order(),
                zero=self._zero(),
            ),
        )
        self.actions.motion(
            StepperRun,
            "~/return_to_zero",
            lambda _goal: CoilMotion(
                d, self.scales, "return_to_zero", every_motor, tolerance=self.goal_tolerance
            ),
        )
        self.actions.motion(
            LineMotion, "~/line_move", lambda goal: self._pair_motion(self._prepare_line(goal))
        )
        self.actions.motion(
            ArcMotion, "~/arc_move", lambda goal: self._pair_motion(self._prepare_arc(goal))
        )

    def _zero(self) -> Callable[[Sequence[int]], tuple[bool, str, dict[int, float] | None]] | None:
        """zero_after_home: the zero coordinates coil as a guarded command, read back."""
        if not self.zero_after_home:
            return None
        return lambda motors: self.run_command(
            "zero coordinates after homing", lambda: self.device.zero_coordinates(motors)
        )

    def _homing_order(self) -> list[int]:
        order = [m for m in self.device.config.homing_order if m]
        if not order:
            raise CommandRejected(
                "the homing order (40177-40181) names no motor: home_all would home nothing "
                "(set it with ~/set_homing_order)"
            )
        return order

    # ------------------------------------------------------------ line / arc
    def _prepare_line(self, r: Any) -> _PairMove:
        """A LineMove request or LineMotion goal checked (every refusal before a write)
        and in controller units: one preparation, so the service and the action agree."""
        self._check_interpolation_allowed()
        start, end = self._pair_points(r.pair, (r.start, "start"), (r.end, "end"))
        pair, speed = r.pair, int(r.speed_rpm)
        self.device.check_line_move(pair, start, end, speed)
        return _PairMove(
            pair,
            end,
            _pair_move_text("line_move", pair),
            lambda confirm: self.device.line_move(pair, start, end, speed, confirm=confirm),
        )

    def _prepare_arc(self, r: Any) -> _PairMove:
        """An ArcMove request or ArcMotion goal, as ``_prepare_line``."""
        self._check_interpolation_allowed()
        start, end, center, via = self._pair_points(
            r.pair, (r.start, "start"), (r.end, "end"), (r.center, "center"), (r.via, "via")
        )
        pair, speed = r.pair, int(r.speed_rpm)
        args = (pair, r.mode, start, end, center, via)
        self.device.check_arc_move(*args, speed)
        counterclockwise = bool(r.counterclockwise)
        return _PairMove(
            pair,
            end,
            _pair_move_text("arc_move", pair),
            lambda confirm: self.device.arc_move(*args, counterclockwise, speed, confirm=confirm),
        )

    def _pair_motion(self, move: _PairMove) -> InterpolationMotion:
        """The action of a prepared line / arc: its send is the goal's begin."""
        return InterpolationMotion(
            self.device,
            self.scales,
            move.pair,
            move.end,
            move.what,
            lambda: move.send(False),  # the goal's polls judge its start
            tolerance=self.goal_tolerance,
        )

    def _pair_points(
        self, pair: int, *points: tuple[Sequence[float], str]
    ) -> list[tuple[float, float]]:
        """Each (SI point, name) in the pair's controller units, checked in order; (0, 0)
        for a pair that does not exist, which the device's check refuses with its text."""
        return [self._pair_units(pair, point, what) or (0.0, 0.0) for point, what in points]

    def _set_run_distance(self, motor: int, distance: float) -> None:
        """Run distance in m / rad like move_by's; a magnitude (the sign is 40005+)."""
        if math.isfinite(distance) and distance < 0:
            raise CommandRejected(
                f"run distance {distance} is negative: it is a magnitude, the direction is "
                "set_direction (or use move_by)"
            )
        self.device.set_run_distance(motor, self.to_units(motor, distance))

    def _destructive(self, name: str, confirm: str) -> None:
        """Factory reset / clear-all. Clear-all warns (WARN log) before its coil is sent:
        its reply may never come if the controller moves off the bridge's id or baud."""
        if name == "clear_all_parameters" and confirm == name:
            self.get_logger().warn(f"clear_all_parameters: {CLEAR_ALL_WARNING}")
        self.device.destructive_command(name, confirm)

    @staticmethod
    def _clear_all_reply(response: Any, _result: object) -> None:
        response.message = f"{response.message}; {CLEAR_ALL_WARNING}"

    def _pair_units(
        self, pair: int, point: Sequence[float], what: str
    ) -> tuple[float, float] | None:
        if pair not in INTERPOLATION_PAIRS:
            return None  # the device layer refuses the pair with the full message
        a, b = self.device.pair_axes(pair)  # refused while the reading is unset
        if len(point) != 2:
            raise CommandRejected(f"{what} needs 2 coordinates")
        return (self.to_units(a, point[0]), self.to_units(b, point[1]))

    def _check_interpolation_allowed(self) -> None:
        s = self.last_snapshot
        motor = MOTOR_FORBIDDEN_DURING_INTERPOLATION
        if s is not None and s.running[motor - 1]:
            raise CommandRejected(
                f"motor {motor} is running: the manual forbids it during interpolation"
            )


@dataclass(frozen=True)
class _PairMove:
    """A checked line / arc: the pair, its end (controller units), its text, and
    ``send(confirm)`` (the writes and the start coil, the start read back with
    ``confirm``; the device checks again just before them)."""

    pair: int
    end: tuple[float, float]
    what: str
    send: Callable[[bool], str]


def _pair_move_text(kind: str, pair: int) -> str:
    return f"{kind} pair {pair}"


def _bind(action: Callable[..., object], *args: Any) -> Callable[[], object]:
    return lambda: action(*args)


def _said(response: Any, result: object) -> None:
    """A confirmed command's reply: what was written and read back."""
    if result:
        response.message = f"{response.message}: {result}"


def main(args: Sequence[str] | None = None) -> int:
    return spin_node(StepperBridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
