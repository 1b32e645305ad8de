"""Command topics that may flood, taken by a thread of their own (not the executor).

The process's ``MultiThreadedExecutor`` builds its wait set from every entity of every node of
the process (parameter and lifecycle services, timers, actions: ~80 on a MOTEC bus of three
drives) for each message it takes. A ``sensor_msgs/JointState`` flood of 1000 msg/s spent
most of the process's CPU in that loop (py-spy: ``_wait_for_ready_callbacks``), and beside
two CPU burners the poll threads then got too little of it (stepper 1 of 2 polls, MOTEC 6
of 10 in 2 s). An ``Inbox`` subscription is an ordinary subscription of the node (same
name, remaps, QoS, ``ros2 topic info``), in a callback group the executor never waits on;
a thread of its own waits on it alone (rclpy's own ``wait_for_message`` pattern, on the
pinned rclpy's ``WaitSet``) and takes every queued message per wake-up. One ``Inbox`` per
node (``ParameterNode.inbox``): ``~/joint_commands`` and the jog / velocity stream topics.

The callbacks run on that thread: they must be quick and never write on the wire (they
offer values to stream guards, whose writers run on the node's executor).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import ExitStack
from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.subscription import Subscription

# How long the thread waits for a message before it looks whether it should end.
INBOX_WAIT_S = 1.0
INBOX_JOIN_S = 2.0  # close(): how long to wait for the thread (woken at once)


class _NotTheExecutors(CallbackGroup):
    """A callback group no executor runs: the inbox thread takes its messages."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


class Inbox:
    """The command topics of ``node`` whose messages their callbacks get on one thread of
    the node's own (started by the first ``subscribe``; later ones join its wait set).

    ``close()`` (before the node is destroyed) ends the thread; a callback that raises is
    said once on the node's logger and the thread goes on.
    """

    def __init__(self, node: Node) -> None:
        self.node = node
        self._group = _NotTheExecutors()
        self._topics: list[tuple[Subscription, Callable[[Any], None]]] = []
        self._lock = threading.Lock()
        self._wake = GuardCondition(None, None, node.context)
        self._running = True
        self._paused = threading.Event()  # set by close(): ends a pause after an error
        self._bug_said = False
        self.taken = 0  # messages taken (bench figures)
        self._thread: threading.Thread | None = None

    def subscribe(
        self, msg_type: Any, topic: str, callback: Callable[[Any], None], depth: int
    ) -> Subscription:
        """An ordinary subscription of the node whose messages ``callback`` gets here (the
        thread starts with the first one)."""
        sub = self.node.create_subscription(
            msg_type, topic, lambda _msg: None, depth, callback_group=self._group
        )
        with self._lock:
            self._topics.append((sub, callback))
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run, name=f"{self.node.get_name()} inbox", daemon=True
            )
            self._thread.start()
        self._wake.trigger()  # a running thread takes the new topic into its wait set
        return sub

    def _run(self) -> None:
        context = self.node.context
        topics: list[tuple[Subscription, Callable[[Any], None]]] = []
        wait_set: Any = None
        wait_ns = int(INBOX_WAIT_S * 1e9)
        while self._running and context.ok():
            try:
                with self._lock:
                    if len(self._topics) != len(topics):
                        topics = list(self._topics)
                        wait_set = _rclpy.WaitSet(len(topics), 1, 0, 0, 0, 0, context.handle)
                wait_set.clear_entities()
                with ExitStack() as held:
                    for sub, _ in topics:
                        held.enter_context(sub.handle)
                        wait_set.add_subscription(sub.handle)
                    held.enter_context(self._wake.handle)
                    wait_set.add_guard_condition(self._wake.handle)
                    wait_set.wait(wait_ns)
                ready = wait_set.get_ready_entities("subscription")
                for sub, callback in topics:
                    if sub.handle.pointer in ready:
                        self._drain(sub, callback)
            except Exception as err:  # the context or the node is going away
                if not self._running or not context.ok():
                    return
                self._say_once(f"{self.node.get_name()} inbox: taking messages failed: {err}")
                self._paused.wait(INBOX_WAIT_S)

    def _drain(self, sub: Subscription, callback: Callable[[Any], None]) -> None:
        """Every message queued on ``sub``, oldest first."""
        while self._running:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
            if taken is None:
                return
            self.taken += 1
            try:
                callback(taken[0])
            except Exception as bug:  # a bug must not end the topics
                self._say_once(f"{sub.topic_name}: a message failed: {bug}")

    def _say_once(self, text: str) -> None:
        if not self._bug_said:
            self._bug_said = True
            self.node.get_logger().error(text)

    def close(self) -> None:
        """End the thread (idempotent); the subscriptions go with the node."""
        if not self._running:
            return
        self._running = False
        self._paused.set()
        self._wake.trigger()
        if self._thread is not None:
            self._thread.join(INBOX_JOIN_S)
        self._wake.destroy()


__all__ = ["INBOX_JOIN_S", "INBOX_WAIT_S", "Inbox"]
