"""The stepper node's services and action goals, registered on a ``StepperBridgeNode``
(docs/bridges/stepper.md): per motor (``~/motor_<n>/...``) and for the controller, each
command's reply saying what was written and read back (stepper decision 23); line / arc
requests and goals prepared once, in controller units, so the service and the action agree.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from std_srvs.srv import SetBool, Trigger

from bridge_core.runtime.checks import board_zero_index, listed
from bridge_core.wire.errors import CommandRejected
from msg_defs.action import ArcMotion, LineMotion, StepperMoveBy, StepperRun
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

from .device import DESTRUCTIVE_COMMANDS, SYSTEM_COMMANDS
from .motions import CoilMotion, HomeMotion, InterpolationMotion, MoveByMotion
from .registers import (
    INTERPOLATION_PAIRS,
    MOTOR_ACTIONS,
    MOTOR_FORBIDDEN_DURING_INTERPOLATION,
    MOTORS,
)

if TYPE_CHECKING:
    from .node import StepperBridgeNode

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
# One table: a row per service of each motor and of the controller (type, name, log
# text, device call); splitting it would scatter the node's interface.
def create_services(node: StepperBridgeNode) -> None:
    d = node.device
    for n in range(1, MOTORS + 1):
        ns = f"~/motor_{n}"
        motor_started = (("motor", n), _bind(d.motor_action, n, "stop"))
        for action in MOTOR_ACTIONS:
            _read_back_trigger(
                node,
                f"{ns}/{action}",
                f"motor {n} {action}",
                _bind(d.motor_action, n, action),
                stop=action == "stop",
                starts=None if action == "stop" else motor_started,
                stops_axes=(("motor", n),) if action == "stop" else (),
            )
        node.command_service(
            MoveBy,
            f"{ns}/move_by",
            lambda r, n=n: f"motor {n} move_by {r.distance}",  # type: ignore[misc]
            lambda r, n=n: d.move_by(n, node.to_units(n, r.distance)),  # type: ignore[misc]
            starts=lambda _r, started=motor_started: started,  # type: ignore[misc]
            fill=_said,
        )
        node.command_service(
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
        node.command_service(
            SetInteger,
            f"{ns}/set_speed",
            lambda r, n=n: f"motor {n} set_speed {r.value} rpm",  # type: ignore[misc]
            lambda r, n=n: d.set_speed(n, r.value),  # type: ignore[misc]
            fill=_said,
        )
        node.command_service(
            SetInteger,
            f"{ns}/set_direction",
            lambda r, n=n: f"motor {n} set_direction {r.value}",  # type: ignore[misc]
            lambda r, n=n: d.set_direction(n, r.value),  # type: ignore[misc]
        )
        node.command_service(
            SetValue,
            f"{ns}/set_run_distance",
            lambda r, n=n: f"motor {n} set_run_distance {r.value}",  # type: ignore[misc]
            lambda r, n=n: _set_run_distance(node, n, r.value),  # type: ignore[misc]
        )
        node.command_service(
            SetInteger,
            f"{ns}/set_round_trips",
            lambda r, n=n: f"motor {n} set_round_trips {r.value}",  # type: ignore[misc]
            lambda r, n=n: d.set_round_trips(n, r.value),  # type: ignore[misc]
        )
        node.command_service(
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
        _read_back_trigger(
            node,
            f"~/{name}",
            name,
            _bind(d.system_command, name),
            stop=name == "emergency_stop",
            starts=(ALL_MOTORS, lambda: _stop_every_motor(node))
            if name in ALL_MOTOR_MOTIONS
            else None,
            stops_axes=EVERY_AXIS if name == "emergency_stop" else (),
        )
    for name in DESTRUCTIVE_COMMANDS:
        node.command_service(
            ConfirmedCommand,
            f"~/{name}",
            lambda _r, name=name: name,  # type: ignore[misc]
            lambda r, name=name: _destructive(node, name, r.confirm),  # type: ignore[misc]
            fill=_clear_all_reply if name == "clear_all_parameters" else None,
        )
    node.command_service(
        SetOutput,
        "~/set_output",
        lambda r: f"set_output {r.index} {'on' if r.state else 'off'}",
        lambda r: d.set_output(board_zero_index("stepper controller", r.board, r.index), r.state),
    )
    node.command_service(
        SetBool,
        "~/set_all_outputs",
        lambda r: f"set_all_outputs {'on' if r.data else 'off'}",
        lambda r: d.set_all_outputs(r.data),
    )
    node.command_service(
        SetHomingOrder,
        "~/set_homing_order",
        lambda r: f"set_homing_order {listed(r.motors, 'motors', bracketed=True)}",
        lambda r: d.set_homing_order([int(m) for m in r.motors]),
    )
    node.command_service(
        SetInteger,
        "~/set_system_mode",
        lambda r: f"set_system_mode {r.value}",
        lambda r: d.set_system_mode(r.value),
    )
    pair_started = (PAIR, d.stop_interpolation)
    node.command_service(
        LineMove,
        "~/line_move",
        lambda r: _pair_move_text("line_move", r.pair),
        lambda r: _prepare_line(node, r).send(True),
        starts=lambda _r: pair_started,
        fill=_said,
    )
    node.command_service(
        ArcMove,
        "~/arc_move",
        lambda r: _pair_move_text("arc_move", r.pair),
        lambda r: _prepare_arc(node, r).send(True),
        starts=lambda _r: pair_started,
        fill=_said,
    )
    _read_back_trigger(
        node,
        "~/stop_interpolation",
        "stop_interpolation",
        d.stop_interpolation,
        stop=True,
        stops_axes=(PAIR,),
    )


def _read_back_trigger(
    node: StepperBridgeNode,
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
    node.command_service(
        Trigger,
        name,
        lambda _request: what,
        lambda _request: action(),
        stop=stop,
        starts=None if starts is None else lambda _request: starts,
        stops_axes=lambda _request: stops_axes,
        fill=_said,
    )


def _stop_every_motor(node: StepperBridgeNode) -> str:
    """Each motor's own stop coil (not the e-stop, which also switches every output
    off), every one tried, then the running flags read back: what a halt sends after
    a service's ``home_all`` / ``return_to_zero``."""
    return node.device.stop_motors(range(1, MOTORS + 1))


# ------------------------------------------------------------ actions
def create_actions(node: StepperBridgeNode) -> None:
    """The timed motions as actions (docs/actions.md), beside their services."""
    d = node.device
    every_motor = tuple(range(1, MOTORS + 1))
    for n in every_motor:
        node.actions.motion(
            StepperMoveBy,
            f"~/motor_{n}/move_by",
            lambda goal, n=n: MoveByMotion(  # type: ignore[misc]
                d,
                node.scales,
                n,
                node.to_units(n, goal.distance),
                float(goal.distance),
                tolerance=node.goal_tolerance,
            ),
        )
        node.actions.motion(
            StepperRun,
            f"~/motor_{n}/home",
            lambda _goal, n=n: HomeMotion(  # type: ignore[misc]
                d, node.scales, "home", (n,), tolerance=node.goal_tolerance, zero=_zero(node)
            ),
        )
    node.actions.motion(
        StepperRun,
        "~/home_all",
        lambda _goal: HomeMotion(
            d,
            node.scales,
            "home_all",
            every_motor,
            tolerance=node.goal_tolerance,
            homed=_homing_order(node),
            zero=_zero(node),
        ),
    )
    node.actions.motion(
        StepperRun,
        "~/return_to_zero",
        lambda _goal: CoilMotion(
            d, node.scales, "return_to_zero", every_motor, tolerance=node.goal_tolerance
        ),
    )
    node.actions.motion(
        LineMotion, "~/line_move", lambda goal: _pair_motion(node, _prepare_line(node, goal))
    )
    node.actions.motion(
        ArcMotion, "~/arc_move", lambda goal: _pair_motion(node, _prepare_arc(node, goal))
    )


def _zero(
    node: StepperBridgeNode,
) -> Callable[[Sequence[int]], tuple[bool, str, dict[int, float] | None]] | None:
    """zero_after_home: the zero coordinates coil as a guarded command, read back."""
    if not node.zero_after_home:
        return None
    return lambda motors: node.run_command(
        "zero coordinates after homing", lambda: node.device.zero_coordinates(motors)
    )


def _homing_order(node: StepperBridgeNode) -> list[int]:
    order = [m for m in node.device.config.homing_order if m]
    if not order:
        raise CommandRejected(
            "the homing order (40177-40181) names no motor: home_all would home nothing "
            "(set it with ~/set_homing_order)"
        )
    return order


# ------------------------------------------------------------ line / arc
def _prepare_line(node: StepperBridgeNode, r: Any) -> _PairMove:
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


def _prepare_arc(node: StepperBridgeNode, r: Any) -> _PairMove:
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


def _pair_motion(node: StepperBridgeNode, move: _PairMove) -> InterpolationMotion:
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
    node: StepperBridgeNode, pair: int, *points: tuple[Sequence[float], str]
) -> list[tuple[float, float]]:
    """Each (SI point, name) in the pair's controller units, checked in order; (0, 0)
    for a pair that does not exist, which the device's check refuses with its text."""
    return [_pair_units(node, pair, point, what) or (0.0, 0.0) for point, what in points]


def _set_run_distance(node: StepperBridgeNode, motor: int, distance: float) -> None:
    """Run distance in m / rad like move_by's; a magnitude (the sign is 40005+)."""
    if math.isfinite(distance) and distance < 0:
        raise CommandRejected(
            f"run distance {distance} is negative: it is a magnitude, the direction is "
            "set_direction (or use move_by)"
        )
    node.device.set_run_distance(motor, node.to_units(motor, distance))


def _destructive(node: StepperBridgeNode, name: str, confirm: str) -> None:
    """Factory reset / clear-all. Clear-all warns (WARN log) before its coil is sent:
    its reply may never come if the controller moves off the bridge's id or baud."""
    if name == "clear_all_parameters" and confirm == name:
        node.get_logger().warn(f"clear_all_parameters: {CLEAR_ALL_WARNING}")
    node.device.destructive_command(name, confirm)


def _clear_all_reply(response: Any, _result: object) -> None:
    response.message = f"{response.message}; {CLEAR_ALL_WARNING}"


def _pair_units(
    node: StepperBridgeNode, pair: int, point: Sequence[float], what: str
) -> tuple[float, float] | None:
    if pair not in INTERPOLATION_PAIRS:
        return None  # the device layer refuses the pair with the full message
    a, b = node.device.pair_axes(pair)  # refused while the reading is unset
    if len(point) != 2:
        raise CommandRejected(f"{what} needs 2 coordinates")
    return (node.to_units(a, point[0]), node.to_units(b, point[1]))


def _check_interpolation_allowed(node: StepperBridgeNode) -> None:
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
