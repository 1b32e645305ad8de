"""``~/joint_commands`` checks (bridge_core/runtime/joint_commands.py, docs/ros2_control.md),
without ROS: a whole message is refused or offered, never a part of it."""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import Any

import pytest

from bridge_core.runtime import joint_commands as jc
from bridge_core.runtime.joint_commands import (
    CommandJoint,
    CommandStream,
    RefusalCounts,
    Refused,
    apply,
    plan,
)
from bridge_core.runtime.stream_guard import StreamGuard
from bridge_core.wire.errors import CommandRejected

LIMIT = 2.0  # |value| above this is outside the fake joints' limits
SCALE = 100.0  # SI -> the fake guards' units


def convert(si: float) -> float:
    if abs(si) > LIMIT:
        raise CommandRejected(f"{si} outside -{LIMIT}..{LIMIT}")
    return si * SCALE


@dataclass
class Node:
    """What a node gives its joints: a gate, an offer that records, positions."""

    closed: tuple[str, str] | None = None
    offered: list[tuple[Hashable, float]] = field(default_factory=list)
    here: dict[str, float | None] = field(default_factory=dict)
    max_jump: float = 0.5
    near: list[bool] = field(default_factory=list)

    def gate(self) -> tuple[str, str] | None:
        return self.closed

    def offer(self, guard: StreamGuard[Any], key: Hashable, value: float, near: bool) -> None:
        self.offered.append((key, value))
        self.near.append(near)
        guard.offer(key, value, near=near)


def guard(zero_stops: bool = True) -> StreamGuard[str]:
    return StreamGuard(
        ["a", "b", "c"],
        lambda _k, _v, _p: None,
        lambda _k: None,
        timeout_s=0.5,
        zero_stops=zero_stops,
    )


def joints(node: Node) -> tuple[dict[str, CommandJoint], StreamGuard[str], StreamGuard[str]]:
    """Joints a and b take both kinds, c only velocity."""
    velocity, position = guard(), guard(zero_stops=False)
    position.follow(velocity)
    made = {}
    for name in ("a", "b", "c"):
        made[name] = CommandJoint(
            name,
            None if name == "c" else CommandStream(position, name, convert),
            CommandStream(velocity, name, convert),
            node.gate,
            node.offer,
            lambda name=name: node.here.get(name, 0.0),  # type: ignore[misc]
            lambda: node.max_jump,
        )
    return made, velocity, position


def refused(
    kind: str, node: Node, *message: Any, made: dict[str, CommandJoint] | None = None
) -> Refused:
    """``plan`` of ``message`` refuses it with ``kind`` in one line, offering nothing."""
    offered = len(node.offered)
    with pytest.raises(Refused) as caught:
        plan(made if made is not None else joints(node)[0], *message)
    assert caught.value.kind == kind, caught.value.text
    assert caught.value.text.strip() and "\n" not in caught.value.text
    assert len(node.offered) == offered
    return caught.value


def test_a_position_message_is_offered_converted() -> None:
    node = Node()
    made, _, position = joints(node)
    apply(plan(made, ["a", "b"], [0.1, -0.2], []))
    assert node.offered == [("a", 10.0), ("b", -20.0)]
    assert position["a"].offered == 10.0


def test_a_velocity_message_goes_to_the_velocity_guard() -> None:
    node = Node()
    made, velocity, position = joints(node)
    apply(plan(made, ["c", "a"], [], [1.0, 0.5]))
    assert velocity["c"].offered == 100.0 and velocity["a"].offered == 50.0
    assert position["a"].offered is None


def test_a_partial_message_commands_only_its_joints() -> None:
    node = Node()
    made, velocity, _ = joints(node)
    apply(plan(made, ["b"], [], [0.3]))
    assert node.offered == [("b", 30.0)]
    assert velocity["a"].offered is None and velocity["c"].offered is None


@pytest.mark.parametrize(
    ("kind", "message"),
    [
        (jc.BOTH_GIVEN, (["a"], [0.1], [0.1])),
        (jc.NEITHER_GIVEN, (["a"], [], [])),
        (jc.UNKNOWN_JOINT, (["a", "z"], [], [0.1, 0.1])),
        (jc.NOT_TAKEN, (["c"], [0.1], [])),
        (jc.NOT_TAKEN, (["a"], [], [], [1.0])),  # effort
        (jc.MALFORMED, ([], [], [])),
        (jc.MALFORMED, (["a", "a"], [], [0.1, 0.1])),
        (jc.MALFORMED, (["a", "b"], [0.1], [])),  # a system mixing kinds
        (jc.UNKNOWN_JOINT, (["a", "b", "c", "d"], [], [0.0] * 4)),
        (jc.NOT_FINITE, (["a"], [math.nan], [])),
        (jc.NOT_FINITE, (["a", "b"], [], [0.1, math.inf])),
        (jc.OUT_OF_LIMITS, (["a", "b"], [], [0.1, 3.0])),
    ],
)
def test_a_bad_message_is_refused_whole(kind: str, message: tuple[Any, ...]) -> None:
    refused(kind, Node(), *message)


def test_one_joint_out_of_limits_refuses_the_others_too() -> None:
    error = refused(jc.OUT_OF_LIMITS, Node(), ["a", "b"], [0.1, 2.5], [])
    assert "b position 2.5" in error.text


@pytest.mark.parametrize("kind", [jc.INACTIVE, jc.READ_ONLY, jc.LINK_DOWN])
def test_a_closed_node_refuses_all_but_stops(kind: str) -> None:
    node = Node(closed=(kind, "the reason"))
    refused(kind, node, ["a"], [0.1], [])
    refused(kind, node, ["a", "b"], [], [0.1, 0.1])
    made, velocity, _ = joints(node)
    apply(plan(made, ["a", "b"], [], [0.0, 0.0]))  # a stop always goes
    assert velocity["a"].offered == 0.0 and velocity["b"].offered == 0.0
    velocity.take("a"), velocity.take("b")
    mixed = plan(made, ["a", "b"], [], [0.0, 0.1])  # the stop goes, the motion does not
    assert [(p.joint.name, p.value) for p in mixed] == [("a", 0.0)]
    assert [(j.name, r.kind) for j, r in mixed.refused] == [("b", kind)]


def test_each_joint_is_judged_by_its_own_node() -> None:
    """MOTEC: one topic for joints of several nodes; a node that is inactive
    refuses its own joints' values only, the others apply; refused whole only when every
    joint named is refused."""
    open_node, closed_node = Node(), Node(closed=(jc.INACTIVE, "motec_1 is not active"))
    made, velocity, _ = joints(open_node)
    made["a"] = CommandJoint(
        "a", None, CommandStream(velocity, "a", convert), closed_node.gate, closed_node.offer
    )
    mixed = plan(made, ["a", "b"], [], [0.5, 0.5])
    assert [p.joint.name for p in mixed] == ["b"]
    assert [(j.name, r.kind) for j, r in mixed.refused] == [("a", jc.INACTIVE)]
    refused(jc.INACTIVE, closed_node, ["a"], [], [0.5], made=made)


def test_nan_is_refused_whole_before_any_gate() -> None:
    """The plugin's 1.x releases publish NaN until a controller claims the joints: refused
    as not finite, nothing offered (also while the node is inactive)."""
    refused(jc.NOT_FINITE, Node(), ["a", "b"], [math.nan, math.nan], [])
    refused(jc.NOT_FINITE, Node(closed=(jc.INACTIVE, "x")), ["a"], [], [math.nan])


def test_a_target_where_the_joint_stands_is_offered_near() -> None:
    """``near``: within 1 % of joint_command_max_jump of the newest published position (of
    its default 0.1 when the check is off), what may unlock a stopped stream."""
    node = Node(here={"a": 1.0, "b": 0.0}, max_jump=0.5)
    made, _, _ = joints(node)
    apply(plan(made, ["a", "b"], [1.004, 0.006], []))
    assert node.near == [True, False]
    node.max_jump = 0.0  # no jump check: the unlock tolerance is the default's
    made, _, _ = joints(node)
    apply(plan(made, ["a", "b"], [1.004, 0.0009], []))
    assert node.near[2:] == [False, True]
    assert jc.unlock_tolerance(0.0) == pytest.approx(0.001)
    assert jc.unlock_tolerance(0.3) == pytest.approx(0.003)


def test_refused_values_are_arrivals_for_the_lock_rule() -> None:
    """A stopped position stream does not take refused messages for silence (seen:
    a controller publishing through a deactivate restarted the motor on activation)."""
    node = Node(here={"a": 1.0}, max_jump=0.5)
    made, _, position = joints(node)
    clock = [0.0]
    position._clock = lambda: clock[0]
    position.stop_all()  # the halt
    clock[0] = 1.0
    jc.refused_arrival([made["a"]])  # refused while inactive
    apply(plan(made, ["a"], [1.0], []))  # the first after activation: not after silence
    with pytest.raises(CommandRejected, match="stopped"):
        position.command("a", position.take("a") or 0.0)
    apply(plan(made, ["a"], [1.0], []))  # held where the joint stands: unlocks
    assert position.command("a", position.take("a") or 0.0)


def test_a_target_far_from_where_the_joint_is_is_refused() -> None:
    node = Node(here={"a": 1.0, "b": 0.0}, max_jump=0.5)
    error = refused(jc.JUMP, node, ["a", "b"], [1.2, 0.9], [])
    assert "b target 0.9" in error.text and "joint_command_max_jump" in error.text
    made, _, _ = joints(node)
    apply(plan(made, ["a", "b"], [1.25, 0.5], []))  # b at the limit: taken
    assert node.offered == [("a", 125.0), ("b", 50.0)]


def test_a_running_stream_is_judged_from_its_previous_target() -> None:
    """Once the position stream runs, the reference is the last target a message gave,
    not the polled position (which lags a moving joint by a poll or more)."""
    node = Node(here={"a": 0.0}, max_jump=0.5)
    made, _, position = joints(node)
    apply(plan(made, ["a"], [0.25], []))
    position.command("a", position.take("a") or 0.0)  # the writer sent it: running
    node.here["a"] = -1.0  # an old poll: far behind
    apply(plan(made, ["a"], [0.7], []))  # 0.45 from the previous target: taken
    error = refused(jc.JUMP, node, ["a"], [1.5], [], made=made)
    assert "from its previous target (0.7)" in error.text
    position.stop("a")  # the deadman: the stream no longer runs
    error = refused(jc.JUMP, node, ["a"], [0.7], [], made=made)
    assert "from where it is (-1)" in error.text


def test_a_late_cycle_of_a_running_stream_does_not_end_the_trajectory() -> None:
    """While the stream runs, max_jump is allowed per command period (the stream's write
    interval) since the previous target came: a controller cycle that comes 0.15 s late
    at 1 rad/s is taken (before, every later target was refused for good); a jump within
    one period is still refused."""
    now = [0.0]
    node = Node(here={"a": 0.0}, max_jump=0.1)
    velocity, position = guard(), guard(zero_stops=False)
    position.min_interval_s = 0.1  # command_rate_hz 10
    joint = CommandJoint(
        "a",
        CommandStream(position, "a", convert),
        CommandStream(velocity, "a", convert),
        node.gate,
        node.offer,
        lambda: node.here["a"],
        lambda: node.max_jump,
        clock=lambda: now[0],
    )
    made = {"a": joint}
    apply(plan(made, ["a"], [0.01], []))
    position.command("a", position.take("a") or 0.0)  # running
    now[0] += 0.01
    error = refused(jc.JUMP, node, ["a"], [0.2], [], made=made)  # 0.19 in 10 ms
    assert "allows (0.1)" in error.text, error.text
    now[0] += 0.15  # the cycle came 0.15 s late: 0.16 s since the previous target
    apply(plan(made, ["a"], [0.17], []))  # 0.16 from it, 0.16 allowed
    assert node.offered[-1] == ("a", 17.0)
    now[0] += 0.01
    apply(plan(made, ["a"], [0.18], []))  # the trajectory goes on


def test_no_target_before_a_position_was_published() -> None:
    refused(jc.JUMP, Node(here={"a": None}), ["a"], [0.0], [])
    refused(jc.JUMP, Node(here={"a": math.nan}), ["a"], [0.0], [])


def test_a_zero_max_jump_checks_nothing() -> None:
    node = Node(here={"a": None}, max_jump=0.0)
    made, _, _ = joints(node)
    apply(plan(made, ["a"], [1.5], []))
    assert node.offered == [("a", 150.0)]


def test_a_velocity_jump_is_not_checked() -> None:
    node = Node(here={"a": 5.0}, max_jump=0.1)
    made, _, _ = joints(node)
    apply(plan(made, ["a"], [], [1.0]))
    assert node.offered == [("a", 100.0)]


def test_one_kind_at_a_time() -> None:
    node = Node()
    made, velocity, position = joints(node)
    position.command("a", 10.0)  # a position stream moves joint a
    error = refused(jc.OTHER_KIND_MOVING, node, ["a"], [], [0.2], made=made)
    assert "under position commands" in error.text
    apply(plan(made, ["a"], [], [0.0]))  # a 0 velocity is always taken
    velocity.command("b", 10.0)
    error = refused(jc.OTHER_KIND_MOVING, node, ["b"], [0.0], [], made=made)
    assert "send a 0 velocity" in error.text


def test_refusals_count_by_kind_and_say_the_first_once() -> None:
    counts = RefusalCounts()
    assert counts.add(jc.NOT_FINITE)
    assert counts.add(jc.UNKNOWN_JOINT)
    assert not counts.add(jc.NOT_FINITE)
    assert counts.total == 3
    assert counts.text() == "unknown joint: 1, not finite: 2"  # REFUSAL_KINDS' order
    assert RefusalCounts().text() == "none"


def test_every_kind_is_listed_once() -> None:
    assert len(set(jc.REFUSAL_KINDS)) == len(jc.REFUSAL_KINDS)


def test_an_oversized_message_is_named_not_echoed() -> None:
    names = [f"joint_{n}" for n in range(3)]
    error = refused(jc.UNKNOWN_JOINT, Node(), names, [], [0.0] * 3)
    assert len(error.text) < 400


def test_the_gate_follows_the_command_guards_order() -> None:
    state = {"active": True, "read_only": True, "connected": False}
    gate = jc.gate_of(
        lambda: state["active"], lambda: state["read_only"], lambda: state["connected"], "n"
    )
    closed = gate()
    assert closed is not None and closed[0] == jc.READ_ONLY
    state["active"] = False
    closed = gate()
    assert closed is not None and closed[0] == jc.INACTIVE
    state.update(active=True, read_only=False)
    closed = gate()
    assert closed is not None and closed[0] == jc.LINK_DOWN
    state["connected"] = True
    assert gate() is None
