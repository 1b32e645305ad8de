"""``~/joint_commands`` (docs/ros2_control.md): a ``sensor_msgs/JointState`` command message checked
whole, then handed to the joints' stream guards. Plain Python (no rclpy).

The far end is ros2_control's topic-based system (``joint_state_topic_hardware_interface``,
docs/ros2_control.md): every control cycle it may publish ``name`` with ``position`` or
``velocity`` targets in SI units (rad, m, rad/s, m/s). A node lists the joints it can move
as ``CommandJoint``s (the names of its ``joint_states``), each with the stream that takes a
position target and the one that takes a velocity (the jog / velocity guard the node's
command topics already use), and ``plan`` checks one message against them:

- its shape: ``position`` and ``velocity`` empty or as long as ``name``, no name twice,
  no ``effort``; exactly one of ``position`` and ``velocity`` given (both or neither is
  refused); every name one of the node's joints, and each joint one that takes that kind;
- the state of the node that drives each joint (its ``gate``): a joint whose node is
  inactive, under ``read_only`` or without its link has its value refused, unless it is
  a velocity 0 (a stop always goes). When every joint named is refused so, the message is
  refused whole; else only those joints' values are (counted by their own node; when
  the whole message was refused, a MOTEC drive's deactivate stopped the other drives of its
  bus) and the others apply;
- every value finite and, converted by the joint's own conversion (the one its
  ``joint_states`` uses), inside the joint's limits;
- a position target no farther than ``joint_command_max_jump`` (rad or m; 0: no check)
  from the joint's newest published position when its position stream does not run: a
  jump is not a trajectory (the stock interface publishes its initial command values, 0
  unless given, until a controller claims them: without this rule the joints would be
  driven there; docs/ros2_control.md, decision 3); while it runs, from its previous
  target, by ``joint_command_max_jump`` per command period (1 / ``command_rate_hz``, the
  stream's write interval) since that target came, at least one: a controller cycle that
  comes late does not end the trajectory;
- a joint is driven by one kind at a time: a velocity while its position stream may still
  move it (or the reverse) is refused; a 0 velocity is always taken.

Any other failure refuses the whole message (``Refused``: its kind and one line) and
nothing is offered to any guard; each joint's node counts refusals by kind
(``RefusalCounts``) and says the first of each kind in one WARN. A refused value still
counts as an arrival for its streams (``refused_arrival``: the guard's lock rule never
takes refused messages for silence). A message that passes is offered to the guards
(``apply``): newest value wins, the guard's rate limit, deadman and locks apply from there;
a position target within ``unlock_tolerance`` of the joint's newest published position is
offered as ``near`` (``StreamGuard.settles``: what may unlock a stopped stream). A message
names only the joints it commands; the others keep what they do.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..wire.errors import CommandRejected
from .checks import bounded_text, listed
from .parameters import ParameterSpec
from .stream_guard import StreamGuard

TOPIC = "~/joint_commands"
# The largest position jump a message may ask (rad or m), default: far more than a 100 Hz
# trajectory moves between two messages, far less than a drive to 0 from afar.
MAX_JUMP_DEFAULT = 0.1
MAX_JUMP_LIMIT = 1e6


# How near where a joint stands a target must be to unlock its stopped position stream, as
# a share of joint_command_max_jump (of its default when the check is off): 1 mm or 1 mrad
# at the default, what a controller holding the joint where it stands (or a trajectory
# starting there) publishes, far less than what a trajectory still running towards a
# target the stop cut short is off by (docs/ros2_control.md).
UNLOCK_SHARE = 0.01


def unlock_tolerance(max_jump: float) -> float:
    """How near where a joint stands a position target must be to unlock its stopped
    stream (``StreamGuard.settles``): ``UNLOCK_SHARE`` of ``joint_command_max_jump``, or of
    its default when the check is off (0): a stop is never undone by a target from afar."""
    return UNLOCK_SHARE * (max_jump if max_jump > 0 else MAX_JUMP_DEFAULT)


MAX_JUMP_SPEC = ParameterSpec(
    "joint_command_max_jump",
    MAX_JUMP_DEFAULT,
    "joint_commands: a position target farther than this (rad or m) from the joint's "
    "newest published position when its position stream is not running, or from its "
    "previous target by more than this per command period since that one came, is "
    "refused, the whole message; 0: no check",
    0.0,
    MAX_JUMP_LIMIT,
    live=True,
)
DIAGNOSTICS_KEY = "joint_commands refused"  # the count by kind in a node's diagnostics
POSITION = "position"
VELOCITY = "velocity"

# Why a message was refused: the keys of the diagnostics' count, each said once in a WARN.
MALFORMED = "malformed"
BOTH_GIVEN = "both position and velocity"
NEITHER_GIVEN = "neither position nor velocity"
UNKNOWN_JOINT = "unknown joint"
NOT_TAKEN = "a kind the joint does not take"
NOT_FINITE = "not finite"
OUT_OF_LIMITS = "outside the joint's limits"
OTHER_KIND_MOVING = "the joint moves under the other kind"
JUMP = "too far from where the joint is"
INACTIVE = "inactive"
READ_ONLY = "read_only"
LINK_DOWN = "link down"
REFUSAL_KINDS = (
    MALFORMED,
    BOTH_GIVEN,
    NEITHER_GIVEN,
    UNKNOWN_JOINT,
    NOT_TAKEN,
    NOT_FINITE,
    OUT_OF_LIMITS,
    JUMP,
    OTHER_KIND_MOVING,
    INACTIVE,
    READ_ONLY,
    LINK_DOWN,
)


class Refused(Exception):
    """A message refused whole: ``kind`` (one of ``REFUSAL_KINDS``) and one line."""

    def __init__(self, kind: str, text: str) -> None:
        super().__init__(text)
        self.kind = kind
        self.text = bounded_text(text)


@dataclass(frozen=True)
class CommandStream:
    """Where one kind of a joint's command goes: ``guard``'s stream ``key``, the value
    converted by ``convert`` (SI -> what the guard's writer takes, the units its own topic
    offers, which the writer's own conversion turns into the device's: a MOTEC velocity
    stays rad/s, a stepper velocity is rpm; ``CommandRejected`` outside the joint's
    limits)."""

    guard: StreamGuard[Any]
    key: Hashable
    convert: Callable[[float], float]

    @property
    def may_move(self) -> bool:
        return self.guard[self.key].may_move


# gate() -> None while the node takes commands, else (kind, reason): INACTIVE, READ_ONLY,
# LINK_DOWN. offer(guard, key, value, near): the node's StreamHost.offer (wakes its writer).
Gate = Callable[[], tuple[str, str] | None]
Offer = Callable[[StreamGuard[Any], Hashable, float, bool], None]


@dataclass(frozen=True)
class CommandJoint:
    """One joint of ``~/joint_commands``: its name (as in ``joint_states``), the streams
    of the kinds it takes (None: not taken), the state of the node that drives it, and
    that node's ``offer``."""

    name: str
    position: CommandStream | None
    velocity: CommandStream | None
    gate: Gate
    offer: Offer
    # The joint's newest published position (SI; None: none yet, or NaN) and the node's
    # joint_command_max_jump (0: no check).
    here: Callable[[], float | None] = lambda: None
    max_jump: Callable[[], float] = lambda: 0.0
    # The last position target a message gave it (``apply``): (SI value, clock() when it
    # came), the reference of the next one while its position stream runs.
    last_target: list[tuple[float, float]] = field(default_factory=list)
    clock: Callable[[], float] = time.monotonic
    # The refusal count of the node that drives the joint (None: the topic's own).
    counts: RefusalCounts | None = None

    def stream(self, kind: str) -> CommandStream | None:
        return self.position if kind == POSITION else self.velocity

    def other(self, kind: str) -> CommandStream | None:
        return self.velocity if kind == POSITION else self.position


@dataclass(frozen=True)
class Planned:
    """One value of a message that passed: offered to ``stream``'s guard by ``apply``."""

    joint: CommandJoint
    stream: CommandStream
    value: float  # in the guard's units
    si: float  # as the message gave it
    kind: str
    near: bool = False  # a position target within unlock_tolerance of where the joint is


class Plan(list[Planned]):
    """``plan``'s values to offer, and ``refused``: the joints whose own node refused
    their values (its gate), each with its ``Refused``; the rest of the message applies."""

    def __init__(self, planned: Sequence[Planned] = ()) -> None:
        super().__init__(planned)
        self.refused: list[tuple[CommandJoint, Refused]] = []


def gate_of(
    active: Callable[[], bool],
    read_only: Callable[[], bool],
    connected: Callable[[], bool],
    what: str,
) -> Gate:
    """A node's gate: the same order as its command guard (``run_command``)."""

    def gate() -> tuple[str, str] | None:
        if not active():
            return INACTIVE, f"{what} is not active (lifecycle): nothing was written"
        if read_only():
            return READ_ONLY, f"{what}: read_only is set, nothing was written"
        if not connected():
            return LINK_DOWN, f"{what} is not connected: nothing was written"
        return None

    return gate


def plan(
    joints: Mapping[str, CommandJoint],
    names: Sequence[str],
    positions: Sequence[float],
    velocities: Sequence[float],
    efforts: Sequence[float] = (),
) -> Plan:
    """Check a whole message (see the module's text); raises ``Refused``, else the values
    to offer, in the message's order (and the joints refused by their own node)."""
    names = list(names)
    count = len(names)
    if count == 0:
        raise Refused(MALFORMED, "joint_commands names no joint")
    if len(set(names)) != count:
        twice = sorted(name for name, seen in Counter(names).items() if seen > 1)
        raise Refused(MALFORMED, f"joint_commands names {listed(twice, 'joints')} twice")
    for given, values in (("position", positions), ("velocity", velocities)):
        if len(values) not in (0, count):
            raise Refused(
                MALFORMED,
                f"joint_commands has {len(values)} {given} values for {count} names "
                "(give one per name, or none)",
            )
    if len(efforts):
        raise Refused(
            NOT_TAKEN, "joint_commands: effort commands are not taken (position or velocity)"
        )
    if len(positions) and len(velocities):
        raise Refused(
            BOTH_GIVEN,
            "joint_commands gives both position and velocity: give one kind per message",
        )
    if not len(positions) and not len(velocities):
        raise Refused(NEITHER_GIVEN, "joint_commands gives neither position nor velocity")
    kind, values = (POSITION, positions) if len(positions) else (VELOCITY, velocities)
    unknown = [n for n in names if n not in joints]
    if unknown:
        known = listed(sorted(joints), "joints")
        raise Refused(
            UNKNOWN_JOINT,
            f"joint_commands names {listed(unknown, 'joints')}, not a joint of this node "
            f"(its joints: {known})",
        )
    named = [joints[n] for n in names]
    refused = [j.name for j in named if j.stream(kind) is None]
    if refused:
        raise Refused(
            NOT_TAKEN, f"joint_commands: {listed(refused, 'joints')} take no {kind} commands"
        )
    floats = [float(v) for v in values]
    bad = [f"{j.name} {v}" for j, v in zip(named, floats, strict=True) if not math.isfinite(v)]
    if bad:
        raise Refused(NOT_FINITE, f"joint_commands: {listed(bad, 'values')} is not a finite {kind}")
    planned = Plan()
    gated: list[tuple[CommandJoint, float]] = []
    for joint, value in zip(named, floats, strict=True):
        closed = None if kind == VELOCITY and value == 0.0 else joint.gate()
        if closed is None:
            gated.append((joint, value))
        else:
            gate_refusal = Refused(closed[0], f"joint_commands refused: {closed[1]}")
            planned.refused.append((joint, gate_refusal))
    if not gated:
        raise planned.refused[0][1]
    for joint, value in gated:
        stream = joint.stream(kind)
        assert stream is not None
        try:
            converted = stream.convert(value)
        except CommandRejected as err:
            raise Refused(
                OUT_OF_LIMITS, f"joint_commands: {joint.name} {kind} {value:g}: {err}"
            ) from None
        if kind == POSITION:
            _check_jump(joint, value)
        other = joint.other(kind)
        a_stop = kind == VELOCITY and value == 0.0
        if other is not None and other.may_move and not a_stop:
            how = (
                "send a 0 velocity (or none for command_timeout_s)"
                if kind == POSITION
                else "send no position target for command_timeout_s (its deadman stops it)"
            )
            raise Refused(
                OTHER_KIND_MOVING,
                f"joint_commands: {joint.name} still moves under {_other_kind(kind)} "
                f"commands: {how} before {kind} ones",
            )
        planned.append(Planned(joint, stream, converted, value, kind, _near(joint, value, kind)))
    return planned


def _near(joint: CommandJoint, target: float, kind: str) -> bool:
    """A position target within ``unlock_tolerance`` of the joint's newest published
    position: it may unlock a stopped stream (``StreamGuard.settles``)."""
    if kind != POSITION:
        return False
    here = joint.here()
    if here is None or not math.isfinite(here):
        return False
    return abs(target - here) <= unlock_tolerance(joint.max_jump())


def refused_arrival(joints: Sequence[CommandJoint]) -> None:
    """Values for ``joints`` arrived and were refused: each of their streams heard them
    (``StreamGuard.hear``), so a stopped stream never takes them for silence."""
    for joint in joints:
        for stream in (joint.position, joint.velocity):
            if stream is not None:
                stream.guard.hear(stream.key)


def _check_jump(joint: CommandJoint, target: float) -> None:
    """A target within ``max_jump`` of the previous one while the joint's position stream
    runs, else of the joint's newest published position."""
    limit = joint.max_jump()
    if limit <= 0:
        return
    stream = joint.position
    if stream is not None and stream.may_move and joint.last_target:
        reference, came = joint.last_target[-1]
        what = "its previous target"
        period = stream.guard.min_interval_s
        if period > 0:  # max_jump per command period since the previous target, at least 1
            limit *= max(1.0, (joint.clock() - came) / period)
    else:
        here = joint.here()
        if here is None or not math.isfinite(here):
            raise Refused(
                JUMP,
                f"joint_commands: {joint.name} has no position published yet: no target taken",
            )
        reference, what = here, "where it is"
    if abs(target - reference) > limit:
        raise Refused(
            JUMP,
            f"joint_commands: {joint.name} target {target:g} is {abs(target - reference):g} "
            f"from {what} ({reference:g}), more than joint_command_max_jump allows "
            f"({limit:g}): a jump is not a trajectory (docs/ros2_control.md)",
        )


def _other_kind(kind: str) -> str:
    return VELOCITY if kind == POSITION else POSITION


def apply(planned: Sequence[Planned]) -> None:
    """Offer each value to its guard (newest wins there; nothing is written here)."""
    for item in planned:
        if item.kind == POSITION:
            item.joint.last_target[:] = [(item.si, item.joint.clock())]
        item.joint.offer(item.stream.guard, item.stream.key, item.value, item.near)


class RefusalCounts:
    """Refused messages by kind (diagnostics); ``add`` says whether it was the first of
    its kind (the one WARN)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counts: dict[str, int] = {}

    def add(self, kind: str) -> bool:
        with self._lock:
            self.counts[kind] = self.counts.get(kind, 0) + 1
            return self.counts[kind] == 1

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self.counts.values())

    def text(self) -> str:
        """``unknown joint: 2, not finite: 1`` in ``REFUSAL_KINDS`` order, or ``none``."""
        with self._lock:
            counts = dict(self.counts)
        shown = [f"{kind}: {counts[kind]}" for kind in REFUSAL_KINDS if kind in counts]
        return ", ".join(shown) or "none"


def message_fields(msg: Any) -> tuple[list[str], list[float], list[float], list[float]]:
    """The fields of a ``JointState`` (or anything with them) that ``plan`` reads."""
    return list(msg.name), list(msg.position), list(msg.velocity), list(msg.effort)


__all__ = [
    "BOTH_GIVEN",
    "DIAGNOSTICS_KEY",
    "INACTIVE",
    "JUMP",
    "LINK_DOWN",
    "MALFORMED",
    "MAX_JUMP_SPEC",
    "NEITHER_GIVEN",
    "NOT_FINITE",
    "NOT_TAKEN",
    "OTHER_KIND_MOVING",
    "OUT_OF_LIMITS",
    "POSITION",
    "READ_ONLY",
    "REFUSAL_KINDS",
    "TOPIC",
    "UNKNOWN_JOINT",
    "UNLOCK_SHARE",
    "VELOCITY",
    "CommandJoint",
    "CommandStream",
    "Gate",
    "Offer",
    "Plan",
    "Planned",
    "RefusalCounts",
    "Refused",
    "apply",
    "gate_of",
    "message_fields",
    "plan",
    "refused_arrival",
    "unlock_tolerance",
]
