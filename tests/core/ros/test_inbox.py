"""The inbox: command topics taken on a thread of the node's own, not by the executor."""

from __future__ import annotations

import functools
import threading
from collections.abc import Iterator
from typing import Any

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.utilities import try_shutdown
from std_msgs.msg import Float64

from bridge_core.ros.inbox import Inbox
from tests.support.ros import wait_for, wait_subscribed

pytestmark = pytest.mark.ros
MESSAGES = 300


class CountingExecutor(MultiThreadedExecutor):
    """Counts the passes of the executor's loop (one per message it takes)."""

    def __init__(self, context: Context) -> None:
        super().__init__(num_threads=2, context=context)
        self.passes = 0

    def _wait_for_ready_callbacks(self, *args: Any, **kwargs: Any) -> Any:
        self.passes += 1
        return super()._wait_for_ready_callbacks(*args, **kwargs)


@pytest.fixture
def ros() -> Iterator[tuple[Context, CountingExecutor, Node, Node]]:
    context = Context()
    rclpy.init(context=context)
    executor = CountingExecutor(context)
    owner = Node("owner", context=context)
    sender = Node("sender", context=context)
    executor.add_node(owner)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield context, executor, owner, sender
    finally:
        executor.shutdown()
        spinner.join(5)
        owner.destroy_node()
        sender.destroy_node()
        try_shutdown(context=context)


def received(got: list[Any], count: int) -> bool:
    return len(got) >= count


def test_a_flood_reaches_the_callback_without_the_executors_loop(ros: Any) -> None:
    """Every message of a paced flood reaches the callback, on the inbox's thread, while
    the executor's loop (its wait set of every entity of every node) runs far less than
    once per message: before the inbox, one pass per message."""
    _, executor, owner, sender = ros
    inbox = Inbox(owner)
    got: list[tuple[float, str]] = []
    inbox.subscribe(
        Float64, "~/cmd", lambda m: got.append((m.data, threading.current_thread().name)), 10
    )
    publisher = sender.create_publisher(Float64, "/owner/cmd", 10)
    wait_subscribed(publisher)
    passes = executor.passes
    for i in range(MESSAGES):
        publisher.publish(Float64(data=float(i)))
        if i % 5 == 4:
            wait_for(functools.partial(received, got, i + 1), 20.0, f"message {i}")  # paced
    assert [value for value, _ in got] == [float(i) for i in range(MESSAGES)]
    assert {thread for _, thread in got} == {"owner inbox"}
    assert executor.passes - passes < MESSAGES / 10, executor.passes - passes
    inbox.close()


def test_a_failing_callback_is_said_once_and_the_topic_goes_on(ros: Any) -> None:
    _, _, owner, sender = ros
    inbox = Inbox(owner)
    got: list[float] = []

    def callback(msg: Any) -> None:
        if msg.data < 0:
            raise ValueError("a bug")
        got.append(msg.data)

    inbox.subscribe(Float64, "~/cmd", callback, 10)
    publisher = sender.create_publisher(Float64, "/owner/cmd", 10)
    wait_subscribed(publisher)
    publisher.publish(Float64(data=-1.0))
    publisher.publish(Float64(data=2.0))
    wait_for(lambda: got == [2.0], 20.0, "the message after the failing one")
    inbox.close()


def test_a_topic_added_later_joins_and_close_ends_the_thread(ros: Any) -> None:
    _, _, owner, sender = ros
    inbox = Inbox(owner)
    got: list[str] = []
    inbox.subscribe(Float64, "~/a", lambda _m: got.append("a"), 10)
    inbox.subscribe(Float64, "~/b", lambda _m: got.append("b"), 10)
    b = sender.create_publisher(Float64, "/owner/b", 10)
    wait_subscribed(b)
    b.publish(Float64(data=1.0))
    wait_for(lambda: got == ["b"], 20.0, "the later topic's message")
    thread = inbox._thread
    assert thread is not None
    inbox.close()
    assert not thread.is_alive()
    inbox.close()  # twice is fine
