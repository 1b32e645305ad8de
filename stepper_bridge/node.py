"""ROS 2 node for the 5-axis stepper controller (DESIGN §3, stepper_bridge).

Units: ``joint_states`` and every positional command (``move_by``, ``line_move``,
``arc_move``) are SI per motor: a prismatic motor's coordinate (user units) / its
``units_per_meter`` in metres, a revolute motor's coordinate / lead x 2 pi in radians,
with the lead read from the controller (40007+). ``configure`` and ``~/state`` keep the
controller's own units (user units, rpm, Hz, degrees of step angle).

Jog: ``~/motor_<n>/jog`` (std_msgs/Float64, motor rpm, sign = direction, 0 = stop) with a
deadman: when no jog message arrived for ``command_timeout_s`` the bridge sends the
motor's stop coil itself, and keeps trying until the link lets it (a jog that was running
when the link dropped is stopped as soon as the link is back).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

from rcl_interfaces.msg import ParameterType
from std_msgs.msg import Float64
from std_srvs.srv import SetBool

from bridge_core.diagnostics import Level, Report
from bridge_core.errors import CommandRejected
from bridge_core.node_base import DOUBLE, DOUBLE_ARRAY, BridgeNode, _descriptor, spin_node
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
)

from .device import (
    DESTRUCTIVE_COMMANDS,
    SYSTEM_COMMANDS,
    JointScale,
    StepperDevice,
    StepperSnapshot,
)
from .registers import (
    DEFAULT_BAUDRATE,
    INTERPOLATION_PAIRS,
    MOTOR_ACTIONS,
    MOTOR_FORBIDDEN_DURING_INTERPOLATION,
    MOTORS,
)

STRING_ARRAY = ParameterType.PARAMETER_STRING_ARRAY
DEFAULT_POLL_RATE_HZ = 3.0  # a poll takes ~0.29 s at 9600 baud (README)
DEADMAN_PERIOD_MIN_S = 0.02
DEADMAN_PERIOD_MAX_S = 0.1


class StepperBridgeNode(BridgeNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(
            "stepper_bridge",
            transport="rtu",
            device_name="stepper controller",
            default_poll_rate_hz=DEFAULT_POLL_RATE_HZ,
            default_baudrate=DEFAULT_BAUDRATE,
            **kwargs,
        )
        p = self.declare_parameter
        p(
            "joint_types",
            ["prismatic"] * MOTORS,
            _descriptor("per motor: prismatic (m) or revolute (rad)", STRING_ARRAY),
        )
        p(
            "units_per_meter",
            [1000.0] * MOTORS,
            _descriptor("per prismatic motor: controller units per metre (1000: mm)", DOUBLE_ARRAY),
        )
        p(
            "command_timeout_s",
            0.5,
            _descriptor("jog deadman: stop a jogging motor after this silence", DOUBLE, 0.05, 60.0),
        )
        p(
            "config_refresh_s",
            5.0,
            _descriptor("re-read the motor parameters this often", DOUBLE, 0.5, 3600.0),
        )
        self.scales = _joint_scales(self.param("joint_types"), self.param("units_per_meter"))
        self.command_timeout_s = float(self.param("command_timeout_s"))
        self.device = StepperDevice(
            self.channel, config_refresh_s=float(self.param("config_refresh_s"))
        )
        self.last_snapshot: StepperSnapshot | None = None
        self.joint_names = [f"{self.joint_prefix}motor_{m}" for m in range(1, MOTORS + 1)]
        self.state_pub = self.create_publisher(StepperState, "~/state", 10)
        self.jog_seen: dict[int, float] = {}
        self._create_services()
        self._create_jog()

    # ------------------------------------------------------------ units
    def to_units(self, motor: int, si: float) -> float:
        """SI (m or rad) -> controller units for ``motor``."""
        scale = self.scales[motor - 1]
        lead = self.device.lead(motor) if scale.joint_type == "revolute" else 0.0
        return scale.to_units(float(si), lead)

    # ------------------------------------------------------------ polling
    def on_link_up(self) -> None:
        # The controller may have been changed (or replaced) while the link was down.
        self.device.invalidate_config()

    def poll_device(self) -> StepperSnapshot:
        return self.device.poll()

    def publish_snapshot(self, s: StepperSnapshot) -> None:
        self.last_snapshot = s
        motors = s.config.motors
        positions = [self.scales[k].to_si(s.coordinates[k], motors[k].lead) for k in range(MOTORS)]
        self.joint_states_pub.publish(self.joint_state(s.read_time, self.joint_names, positions))
        m = StepperState()
        m.header.stamp = self.stamp(s.read_time)
        m.header.frame_id = self.frame_id
        m.system_mode = s.config.system_mode
        m.running = list(s.running)
        m.coordinates = list(s.coordinates)
        m.inputs = list(s.inputs)
        m.outputs = list(s.outputs)
        m.step_angle_deg = [c.step_angle_deg for c in motors]
        m.microstep = [c.microstep for c in motors]
        m.start_frequency_hz = [c.start_frequency_hz for c in motors]
        m.accel_frequency_hz = [c.accel_frequency_hz for c in motors]
        m.direction = [c.direction for c in motors]
        m.speed_rpm = [c.speed_rpm for c in motors]
        m.lead = [c.lead for c in motors]
        m.run_distance = [c.run_distance for c in motors]
        m.positive_limit_input = [c.positive_limit_input for c in motors]
        m.negative_limit_input = [c.negative_limit_input for c in motors]
        m.home_input = [c.home_input for c in motors]
        m.homing_order = list(s.config.homing_order)
        self.state_pub.publish(m)

    def device_report(self) -> Report | None:
        s = self.last_snapshot
        if s is None:
            return None
        running = [str(k + 1) for k, r in enumerate(s.running) if r]
        values = [
            ("system mode", str(s.config.system_mode)),
            ("motors running", ", ".join(running) or "none"),
            (
                "jogging",
                ", ".join(str(n) for n in range(1, MOTORS + 1) if self.device.jogging(n)) or "none",
            ),
        ]
        unknown = [
            str(k + 1)
            for k in range(MOTORS)
            if self.scales[k].joint_type == "revolute" and s.config.motors[k].lead <= 0
        ]
        if unknown:
            return Report(
                Level.WARN,
                f"lead 0 on revolute motor(s) {', '.join(unknown)}: position unknown (NaN)",
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
    def _create_services(self) -> None:
        d = self.device
        for n in range(1, MOTORS + 1):
            ns = f"~/motor_{n}"
            for action in MOTOR_ACTIONS:
                self.trigger_service(
                    f"{ns}/{action}",
                    f"motor {n} {action}",
                    _bind(d.motor_action, n, action),
                )
            self.command_service(
                MoveBy,
                f"{ns}/move_by",
                lambda r, n=n: f"motor {n} move_by {r.distance}",  # type: ignore[misc]
                lambda r, n=n: d.move_by(n, self.to_units(n, r.distance)),  # type: ignore[misc]
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
            self.trigger_service(f"~/{name}", name, _bind(d.system_command, name))
        for name in DESTRUCTIVE_COMMANDS:
            self.command_service(
                ConfirmedCommand,
                f"~/{name}",
                lambda _r, name=name: name,  # type: ignore[misc]
                lambda r, name=name: d.destructive_command(name, r.confirm),  # type: ignore[misc]
            )
        self.command_service(
            SetOutput,
            "~/set_output",
            lambda r: f"set_output {r.index} {'on' if r.on else 'off'}",
            lambda r: d.set_output(_only_board_zero(r.board, r.index), r.on),
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
            lambda r: f"set_homing_order {list(r.motors)}",
            lambda r: d.set_homing_order([int(m) for m in r.motors]),
        )
        self.command_service(
            SetInteger,
            "~/set_system_mode",
            lambda r: f"set_system_mode {r.value}",
            lambda r: d.set_system_mode(r.value),
        )
        self.command_service(
            LineMove, "~/line_move", lambda r: f"line_move pair {r.pair}", self._line_move
        )
        self.command_service(
            ArcMove, "~/arc_move", lambda r: f"arc_move pair {r.pair}", self._arc_move
        )
        self.trigger_service("~/stop_interpolation", "stop_interpolation", d.stop_interpolation)

    def _pair_units(
        self, pair: int, point: Sequence[float], what: str
    ) -> tuple[float, float] | None:
        if pair not in INTERPOLATION_PAIRS:
            return None  # the device layer refuses the pair with the full message
        a, b = INTERPOLATION_PAIRS[pair]
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

    def _line_move(self, r: Any) -> None:
        self._check_interpolation_allowed()
        start = self._pair_units(r.pair, r.start, "start") or (0.0, 0.0)
        end = self._pair_units(r.pair, r.end, "end") or (0.0, 0.0)
        self.device.line_move(r.pair, start, end, r.speed_rpm)

    def _arc_move(self, r: Any) -> None:
        self._check_interpolation_allowed()
        points = [
            self._pair_units(r.pair, p, what) or (0.0, 0.0)
            for p, what in (
                (r.start, "start"),
                (r.end, "end"),
                (r.center, "center"),
                (r.via, "via"),
            )
        ]
        self.device.arc_move(
            r.pair,
            r.mode,
            points[0],
            points[1],
            points[2],
            points[3],
            r.counterclockwise,
            r.speed_rpm,
        )

    # ------------------------------------------------------------ jog
    def _create_jog(self) -> None:
        for n in range(1, MOTORS + 1):
            self.create_subscription(
                Float64,
                f"~/motor_{n}/jog",
                lambda msg, n=n: self._on_jog(n, float(msg.data)),  # type: ignore[misc]
                10,
                callback_group=self.command_group,
            )
        period = min(DEADMAN_PERIOD_MAX_S, max(DEADMAN_PERIOD_MIN_S, self.command_timeout_s / 5))
        self.deadman_timer = self.create_timer(
            period, self._deadman, callback_group=self.command_group
        )

    def _on_jog(self, motor: int, rpm: float) -> None:
        self.jog_seen[motor] = time.monotonic()
        ok, message, _ = self.run_command(
            f"motor {motor} jog {rpm} rpm", lambda: self.device.jog(motor, rpm)
        )
        if ok:
            return
        self.get_logger().warn(message, throttle_duration_sec=2.0)
        if self.device.jogging(motor):
            # A refused value must not leave the motor running at the previous one.
            self.run_command(f"motor {motor} jog stop", lambda: self.device.jog_stop(motor))

    def _deadman(self) -> None:
        now = time.monotonic()
        for motor in range(1, MOTORS + 1):
            if not (self.device.jogging(motor) or self.device.jog_locked(motor)):
                continue
            seen = self.jog_seen.get(motor)
            if seen is not None and now - seen <= self.command_timeout_s:
                continue
            was_jogging = self.device.jogging(motor)
            ok, message, _ = self.run_command(
                f"motor {motor} jog deadman stop", _bind(self.device.jog_stop, motor)
            )
            if was_jogging:
                if ok:
                    self.get_logger().info(
                        f"motor {motor}: no jog command for {self.command_timeout_s} s, stopped"
                    )
                else:
                    self.get_logger().warn(message, throttle_duration_sec=2.0)


def _bind(action: Callable[..., object], *args: Any) -> Callable[[], object]:
    return lambda: action(*args)


def _only_board_zero(board: int, index: int) -> int:
    if board != 0:
        raise CommandRejected(f"board {board} refused: the controller has one board (board 0)")
    return index


def _joint_scales(types: Sequence[str], units_per_meter: Sequence[float]) -> list[JointScale]:
    types = list(types)[:MOTORS] + ["prismatic"] * (MOTORS - len(types))
    units = [float(u) for u in units_per_meter][:MOTORS]
    units += [1000.0] * (MOTORS - len(units))
    for u in units:
        if not math.isfinite(u) or u <= 0:
            raise ValueError(f"units_per_meter must be positive and finite, got {u}")
    return [JointScale(t, u) for t, u in zip(types, units, strict=True)]


def main(args: Sequence[str] | None = None) -> None:
    spin_node(StepperBridgeNode, args)


if __name__ == "__main__":
    main()
