"""How an action goal of a bridge node ends in ROS: its result message and final state.

Part of the node base (imports rclpy), for ``node_actions``. Every result carries a
``MotionOutcome`` (the verdict's outcome, message and fault, and whether a stop was
acknowledged); the goal handle ends succeeded only when the motion was REACHED, canceled
for a cancel the client asked for, and aborted otherwise; the console says how it ended
(INFO when reached, WARN otherwise).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node

from ..runtime.goals import GoalRun, Outcome, Verdict

# How long a cancelled goal's result waits for rclpy to have moved it to CANCELING.
CANCEL_STATE_WAIT_S = 1.0
CANCEL_STATE_POLL_S = 0.005


def finish_run(
    node: Node,
    run: GoalRun[Any],
    handle: ServerGoalHandle,
    action_type: Any,
    name: str,
    fields: dict[str, Any],
) -> Any:
    """The result of a motion goal whose run ended (its stop's answer appended)."""
    verdict = run.verdict or Verdict(Outcome.HALTED, f"{run.motion.what}: ended")
    message = verdict.message
    if run.stop_message:
        message += f"; {run.stop_message}"
    return send_result(node, action_type, handle, name, verdict, message, run.stop_sent, fields)


def send_result(
    node: Node,
    action_type: Any,
    handle: ServerGoalHandle,
    name: str,
    verdict: Verdict,
    message: str,
    stop_sent: bool,
    fields: dict[str, Any],
) -> Any:
    """End the goal as ``verdict`` says and return its result."""
    result = result_of(action_type, verdict, message, stop_sent, fields)
    if verdict.outcome is Outcome.CANCELLED:
        # The cancel callback runs before rclpy moves the goal to CANCELING.
        _wait_for(lambda: handle.is_cancel_requested, CANCEL_STATE_WAIT_S)
    if verdict.outcome is Outcome.REACHED:
        handle.succeed()
    elif verdict.outcome is Outcome.CANCELLED and handle.is_cancel_requested:
        handle.canceled()
    else:
        handle.abort()
    line = f"{name}: {verdict.outcome.name}: {message}"
    if verdict.outcome is Outcome.REACHED:
        node.get_logger().info(line)
    else:
        node.get_logger().warn(line)
    return result


def refuse_goal(node: Node, action_type: Any, handle: ServerGoalHandle, message: str) -> Any:
    """Abort an accepted goal that wrote nothing (outcome REFUSED)."""
    handle.abort()
    node.get_logger().warn(message)
    return result_of(action_type, Verdict(Outcome.REFUSED, message), message)


def result_of(
    action_type: Any,
    verdict: Verdict,
    message: str,
    stop_sent: bool = False,
    fields: dict[str, Any] | None = None,
) -> Any:
    """The action's result message: ``fields`` and the ``MotionOutcome`` of ``verdict``."""
    result = filled(action_type.Result(), fields or {})
    outcome = result.outcome
    outcome.code = int(verdict.outcome)
    outcome.name = verdict.outcome.name
    outcome.message = message
    outcome.fault_code = int(verdict.fault_code)
    outcome.fault_text = verdict.fault_text
    outcome.stop_sent = bool(stop_sent)
    return result


def filled(msg: Any, fields: dict[str, Any]) -> Any:
    """``msg`` with the named fields set (a result's or a feedback's)."""
    for field, value in fields.items():
        setattr(msg, field, value)
    return msg


def _wait_for(condition: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(CANCEL_STATE_POLL_S)
    return True


__all__ = ["filled", "finish_run", "refuse_goal", "result_of", "send_result"]
