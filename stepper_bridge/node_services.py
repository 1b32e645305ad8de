"""The stepper node's services and action goals, registered on a ``StepperBridgeNode``
(docs/bridges/stepper.md): per motor (``~/motor_<n>/...``) and for the controller, each
command's reply saying what was written and read back (stepper decision 23); line / arc
requests and goals prepared once, in controller units, so the service and the action agree.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from bridge_core.ros.node_actions import ActionHost
from bridge_core.ros.node_services import Command, ServiceHost, Started, trigger
from bridge_core.runtime.checks import board_zero_index, listed
from bridge_core.wire.errors import CommandRejected

from .device import StepperDevice
from .interface import ACTIONS, EXPANSION, SERVICES
from .motions import CoilMotion, HomeMotion, InterpolationMotion, MoveByMotion
from .registers import INTERPOLATION_PAIRS, MOTOR_FORBIDDEN_DURING_INTERPOLATION, MOTORS
from .snapshots import StepperSnapshot
from .units import JointScale

if TYPE_CHECKING:
    from rclpy.impl.rcutils_logger import RcutilsLogger

T = TypeVar("T")


class StepperServicesOwner(Protocol):
    """What the services and actions here use of their node (``StepperBridgeNode``),
    named here so the node imports this module and never the other way round."""

    @property
    def device(self) -> StepperDevice: ...

    @property
    def scales(self) -> Sequence[JointScale]: ...

    @property
    def goal_tolerance(self) -> float: ...

    @property
    def zero_after_home(self) -> bool: ...

    @property
    def last_snapshot(self) -> StepperSnapshot | None: ...

    @property
    def command_services(self) -> ServiceHost: ...

    @property
    def actions(self) -> ActionHost: ...

    def to_units(self, motor: int, si: float) -> float: ...

    def run_command(self, what: str, action: Callable[[], T]) -> tuple[bool, str, T | None]: ...

    def get_logger(self) -> RcutilsLogger: ...


# Axes of the node's motion ledger (what services set moving; a halt stops them).
ALL_MOTORS = "all motors"  # home_all / return_to_zero
PAIR = "interpolation"  # line_move / arc_move
ALL_MOTOR_MOTIONS = ("home_all", "return_to_zero")
EVERY_AXIS = (ALL_MOTORS, PAIR, *(("motor", n) for n in range(1, MOTORS + 1)))


# ~/clear_all_parameters: the manual's clear-all ("清零所有参数") reaches the link settings.
CLEAR_ALL_WARNING = (
    "the link may be lost: clear-all may reset the device id (40212) and baud rate "
    "(40213) to 1 and 9600 (stepper decision 15)"
)


# ------------------------------------------------------------ services
def create_services(node: StepperServicesOwner) -> None:
    """A service per row of ``interface.SERVICES``, each answered by its handler here
    (a per-motor row's: a function of the motor)."""
    d = node.device

    def motor_started(motor: int) -> Started:
        return (("motor", motor), _bind(d.motor_action, motor, "stop"))

    def motor_action(motor: int, motor_action: str) -> Command[object]:
        stop = motor_action == "stop"
        return trigger(
            f"motor {motor} {motor_action}",
            _bind(d.motor_action, motor, motor_action),
            stop=stop,
            starts=None if stop else motor_started(motor),
            stops_axes=(("motor", motor),) if stop else (),
            fill=_said,
        )

    def move_by(motor: int) -> Command[object]:
        started = motor_started(motor)
        return Command(
            lambda r: f"motor {motor} move_by {r.distance}",
            lambda r: d.move_by(motor, node.to_units(motor, r.distance)),
            starts=lambda _r: started,
            fill=_said,
        )

    def configure(motor: int) -> Command[object]:
        return Command(
            lambda _r: f"motor {motor} configure",
            lambda r: d.configure(
                motor,
                step_angle_deg=r.step_angle_deg,
                microstep=r.microstep,
                start_frequency_hz=r.start_frequency_hz,
                accel_frequency_hz=r.accel_frequency_hz,
                speed_rpm=r.speed_rpm,
                lead=r.lead,
            ),
        )

    def set_speed(motor: int) -> Command[object]:
        return Command(
            lambda r: f"motor {motor} set_speed {r.value} rpm",
            lambda r: d.set_speed(motor, r.value),
            fill=_said,
        )

    def set_direction(motor: int) -> Command[object]:
        return Command(
            lambda r: f"motor {motor} set_direction {r.value}",
            lambda r: d.set_direction(motor, r.value),
        )

    def set_run_distance(motor: int) -> Command[object]:
        return Command(
            lambda r: f"motor {motor} set_run_distance {r.value}",
            lambda r: _set_run_distance(node, motor, r.value),
        )

    def set_round_trips(motor: int) -> Command[object]:
        return Command(
            lambda r: f"motor {motor} set_round_trips {r.value}",
            lambda r: d.set_round_trips(motor, r.value),
        )

    def set_limit_inputs(motor: int) -> Command[object]:
        return Command(
            lambda r: (
                f"motor {motor} limit inputs +{r.positive_limit} -{r.negative_limit} home {r.home}"
            ),
            lambda r: d.set_limit_inputs(motor, r.positive_limit, r.negative_limit, r.home),
        )

    def system_command(system_command: str) -> Command[object]:
        return trigger(
            system_command,
            _bind(d.system_command, system_command),
            stop=system_command == "emergency_stop",
            starts=(ALL_MOTORS, lambda: _stop_every_motor(node))
            if system_command in ALL_MOTOR_MOTIONS
            else None,
            stops_axes=EVERY_AXIS if system_command == "emergency_stop" else (),
            fill=_said,
        )

    def destructive_command(destructive_command: str) -> Command[None]:
        return Command(
            lambda _r: destructive_command,
            lambda r: _destructive(node, destructive_command, r.confirm),
            fill=_clear_all_reply if destructive_command == "clear_all_parameters" else None,
        )

    pair_started = (PAIR, d.stop_interpolation)
    node.command_services.create(
        SERVICES,
        {
            "~/motor_{motor}/{motor_action}": motor_action,
            "~/motor_{motor}/move_by": move_by,
            "~/motor_{motor}/configure": configure,
            "~/motor_{motor}/set_speed": set_speed,
            "~/motor_{motor}/set_direction": set_direction,
            "~/motor_{motor}/set_run_distance": set_run_distance,
            "~/motor_{motor}/set_round_trips": set_round_trips,
            "~/motor_{motor}/set_limit_inputs": set_limit_inputs,
            "~/{system_command}": system_command,
            "~/{destructive_command}": destructive_command,
            "~/set_output": Command(
                lambda r: f"set_output {r.index} {'on' if r.state else 'off'}",
                lambda r: d.set_output(
                    board_zero_index("stepper controller", r.board, r.index), r.state
                ),
            ),
            "~/set_all_outputs": Command(
                lambda r: f"set_all_outputs {'on' if r.data else 'off'}",
                lambda r: d.set_all_outputs(r.data),
            ),
            "~/set_homing_order": Command(
                lambda r: f"set_homing_order {listed(r.motors, 'motors', bracketed=True)}",
                lambda r: d.set_homing_order([int(m) for m in r.motors]),
            ),
            "~/set_system_mode": Command(
                lambda r: f"set_system_mode {r.value}",
                lambda r: d.set_system_mode(r.value),
            ),
            "~/line_move": Command(
                lambda r: _pair_move_text("line_move", r.pair),
                lambda r: _prepare_line(node, r).send(True),
                starts=lambda _r: pair_started,
                fill=_said,
            ),
            "~/arc_move": Command(
                lambda r: _pair_move_text("arc_move", r.pair),
                lambda r: _prepare_arc(node, r).send(True),
                starts=lambda _r: pair_started,
                fill=_said,
            ),
            "~/stop_interpolation": trigger(
                "stop_interpolation",
                d.stop_interpolation,
                stop=True,
                stops_axes=(PAIR,),
                fill=_said,
            ),
        },
        EXPANSION,
    )


def _stop_every_motor(node: StepperServicesOwner) -> str:
    """Each motor's own stop coil (not the e-stop, which also switches every output
    off), every one tried, then the running flags read back: what a halt sends after
    a service's ``home_all`` / ``return_to_zero``."""
    return node.device.stop_motors(range(1, MOTORS + 1))


# ------------------------------------------------------------ actions
def create_actions(node: StepperServicesOwner) -> None:
    """The timed motions as actions (docs/actions.md), beside their services: one per
    row of ``interface.ACTIONS``."""
    d = node.device
    every_motor = tuple(range(1, MOTORS + 1))

    def move_by(motor: int) -> Callable[[Any], MoveByMotion]:
        return lambda goal: MoveByMotion(
            d,
            node.scales,
            motor,
            node.to_units(motor, goal.distance),
            float(goal.distance),
            tolerance=node.goal_tolerance,
        )

    def home(motor: int) -> Callable[[Any], HomeMotion]:
        return lambda _goal: HomeMotion(
            d, node.scales, "home", (motor,), tolerance=node.goal_tolerance, zero=_zero(node)
        )

    node.actions.create(
        ACTIONS,
        {
            "~/motor_{motor}/move_by": move_by,
            "~/motor_{motor}/home": home,
            "~/home_all": lambda _goal: HomeMotion(
                d,
                node.scales,
                "home_all",
                every_motor,
                tolerance=node.goal_tolerance,
                homed=_homing_order(node),
                zero=_zero(node),
            ),
            "~/return_to_zero": lambda _goal: CoilMotion(
                d, node.scales, "return_to_zero", every_motor, tolerance=node.goal_tolerance
            ),
            "~/line_move": lambda goal: _pair_motion(node, _prepare_line(node, goal)),
            "~/arc_move": lambda goal: _pair_motion(node, _prepare_arc(node, goal)),
        },
        EXPANSION,
    )


def _zero(
    node: StepperServicesOwner,
) -> Callable[[Sequence[int]], tuple[bool, str, dict[int, float] | None]] | None:
    """zero_after_home: the zero coordinates coil as a guarded command, read back."""
    if not node.zero_after_home:
        return None
    return lambda motors: node.run_command(
        "zero coordinates after homing", lambda: node.device.zero_coordinates(motors)
    )


def _homing_order(node: StepperServicesOwner) -> list[int]:
    order = [m for m in node.device.config.homing_order if m]
    if not order:
        raise CommandRejected(
            "the homing order (40177-40181) names no motor: home_all would home nothing "
            "(set it with ~/set_homing_order)"
        )
    return order


# ------------------------------------------------------------ line / arc
def _prepare_line(node: StepperServicesOwner, r: Any) -> _PairMove:
    """A LineMove request or LineMotion goal checked (every refusal before a write)
    and in controller units: one preparation, so the service and the action agree."""
    _check_interpolation_allowed(node)
    start, end = _pair_points(node, r.pair, (r.start, "start"), (r.end, "end"))
    pair, speed = r.pair, int(r.speed_rpm)
    node.device.check_line_move(pair, start, end, speed)
    return _PairMove(
        pair,
        end,
        _pair_move_text("line_move", pair),
        lambda confirm: node.device.line_move(pair, start, end, speed, confirm=confirm),
    )


def _prepare_arc(node: StepperServicesOwner, r: Any) -> _PairMove:
    """An ArcMove request or ArcMotion goal, as ``_prepare_line``."""
    _check_interpolation_allowed(node)
    start, end, center, via = _pair_points(
        node, r.pair, (r.start, "start"), (r.end, "end"), (r.center, "center"), (r.via, "via")
    )
    pair, speed = r.pair, int(r.speed_rpm)
    args = (pair, r.mode, start, end, center, via)
    node.device.check_arc_move(*args, speed)
    counterclockwise = bool(r.counterclockwise)
    return _PairMove(
        pair,
        end,
        _pair_move_text("arc_move", pair),
        lambda confirm: node.device.arc_move(*args, counterclockwise, speed, confirm=confirm),
    )


def _pair_motion(node: StepperServicesOwner, move: _PairMove) -> InterpolationMotion:
    """The action of a prepared line / arc: its send is the goal's begin."""
    return InterpolationMotion(
        node.device,
        node.scales,
        move.pair,
        move.end,
        move.what,
        lambda: move.send(False),  # the goal's polls judge its start
        tolerance=node.goal_tolerance,
    )


def _pair_points(
    node: StepperServicesOwner, pair: int, *points: tuple[Sequence[float], str]
) -> list[tuple[float, float]]:
    """Each (SI point, name) in the pair's controller units, checked in order; (0, 0)
    for a pair that does not exist, which the device's check refuses with its text."""
    return [_pair_units(node, pair, point, what) or (0.0, 0.0) for point, what in points]


def _set_run_distance(node: StepperServicesOwner, motor: int, distance: float) -> None:
    """Run distance in m / rad like move_by's; a magnitude (the sign is 40005+)."""
    if math.isfinite(distance) and distance < 0:
        raise CommandRejected(
            f"run distance {distance} is negative: it is a magnitude, the direction is "
            "set_direction (or use move_by)"
        )
    node.device.set_run_distance(motor, node.to_units(motor, distance))


def _destructive(node: StepperServicesOwner, name: str, confirm: str) -> None:
    """Factory reset / clear-all. Clear-all warns (WARN log) before its coil is sent:
    its reply may never come if the controller moves off the bridge's id or baud."""
    if name == "clear_all_parameters" and confirm == name:
        node.get_logger().warn(f"clear_all_parameters: {CLEAR_ALL_WARNING}")
    node.device.destructive_command(name, confirm)


def _clear_all_reply(response: Any, _result: object) -> None:
    response.message = f"{response.message}; {CLEAR_ALL_WARNING}"


def _pair_units(
    node: StepperServicesOwner, pair: int, point: Sequence[float], what: str
) -> tuple[float, float] | None:
    if pair not in INTERPOLATION_PAIRS:
        return None  # the device layer refuses the pair with the full message
    a, b = node.device.pair_axes(pair)  # refused while the reading is unset
    if len(point) != 2:
        raise CommandRejected(f"{what} needs 2 coordinates")
    return (node.to_units(a, point[0]), node.to_units(b, point[1]))


def _check_interpolation_allowed(node: StepperServicesOwner) -> None:
    s = node.last_snapshot
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
