"""The test client's own promise (tests/support/ros.py): a goal's response is never lost
to rclpy's ActionClient race, whatever the scheduler does between sending the request
and registering its future.

rclpy registers the future of a goal request only after ``send_goal_request`` returned;
here that call is made slow (a pause after the request is on the wire), so the client's
spin thread, if it were free to run, would take the response first and drop it
("Ignoring unexpected goal response"): the goal would never be answered.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import rclpy
from rclpy.action.server import ActionServer, GoalResponse
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.utilities import try_shutdown

from msg_defs.action import StepperMoveBy

from ..support.ros import ros_client, unique_namespace

pytestmark = pytest.mark.ros

PAUSE_S = 0.5  # far longer than the server takes to answer on loopback


@pytest.fixture
def action_name() -> Iterator[str]:
    """An action server (its own context, node and spin thread) that rejects every goal."""
    context = Context()
    rclpy.init(context=context)
    node = Node("race_server", context=context)
    name = f"{unique_namespace('race')}/move_by"
    server = ActionServer(
        node,
        StepperMoveBy,
        name,
        execute_callback=lambda handle: StepperMoveBy.Result(),
        goal_callback=lambda goal: GoalResponse.REJECT,
    )
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield name
    finally:
        server.destroy()
        executor.shutdown()
        node.destroy_node()
        try_shutdown(context=context)
        thread.join(5)


class SlowSend:
    """An ActionClient handle whose goal requests pause after they are sent."""

    def __init__(self, handle: Any) -> None:
        self._handle = handle

    def __getattr__(self, name: str) -> Any:
        return getattr(self._handle, name)

    def send_goal_request(self, request: Any) -> int:
        sequence = int(self._handle.send_goal_request(request))
        time.sleep(PAUSE_S)  # the response arrives meanwhile
        return sequence


def test_a_goal_response_that_comes_before_its_future_is_registered_is_kept(
    action_name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    from rclpy.action import client as action_client_module

    original_init: Any = action_client_module.ActionClient.__init__

    def init(self: Any, *args: Any, **kwargs: Any) -> None:
        original_init(self, *args, **kwargs)
        self._client_handle = SlowSend(self._client_handle)

    monkeypatch.setattr(action_client_module.ActionClient, "__init__", init)
    with ros_client("race_client") as client:
        # The whole timeout: a response that is dropped never comes.
        goal = client.send_goal(StepperMoveBy, action_name, StepperMoveBy.Goal(), timeout=10.0)
        assert not goal.accepted
        goal.close()
