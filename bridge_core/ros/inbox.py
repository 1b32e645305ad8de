"""Command topics that may flood, on a hidden node and a thread of their own.

A node's ``MultiThreadedExecutor`` builds its wait set from every entity of every node of
the process (parameter and lifecycle services, timers, actions: ~80 on a MOTEC bus of three
drives) for each message it takes. A ``sensor_msgs/JointState`` flood of 1000 msg/s spent
most of the process's CPU in that loop (py-spy: ``_wait_for_ready_callbacks``), and beside
two CPU burners the poll threads then got too little of it (stepper 1 of 2 polls, MOTEC 6
of 10 in 2 s). An ``Inbox`` takes such a topic on a node of its own (hidden: its name
starts with ``_``; no parameter services, no rosout) spun by a ``SingleThreadedExecutor``
in a thread of its own: a message there costs one wait on one subscription.

The topic keeps the owner's name: it is resolved by the owner (its namespace, its name
for ``~``, its remaps), so ``ros2 topic info`` shows the subscription on ``_<owner>_inbox``
and a remap given for the owner still applies. The callbacks must be quick and never
write on the wire (they offer values to stream guards, whose writers run on the owner's
executor).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

# How long the inbox thread waits for a message before it looks whether it should end.
INBOX_WAIT_S = 0.1
INBOX_JOIN_S = 2.0  # close(): how long to wait for the thread (it ends within INBOX_WAIT_S)


class Inbox:
    """A hidden node ``_<owner>_inbox`` and its thread, for ``owner``'s flooding topics."""

    def __init__(self, owner: Node) -> None:
        self.owner = owner
        self.node = Node(
            f"_{owner.get_name()}_inbox",
            namespace=owner.get_namespace(),
            context=owner.context,
            # The owner resolves the names (its remaps); none may apply twice.
            use_global_arguments=False,
            start_parameter_services=False,
            enable_rosout=False,
        )
        self._executor = SingleThreadedExecutor(context=owner.context)
        self._executor.add_node(self.node)
        self._running = True
        self._thread = threading.Thread(
            target=self._spin, name=f"{owner.get_name()} inbox", daemon=True
        )
        self._thread.start()

    def subscribe(
        self, msg_type: Any, topic: str, callback: Callable[[Any], None], depth: int
    ) -> str:
        """Subscribe ``callback`` to the owner's ``topic``; returns the resolved name."""
        name = self.owner.resolve_topic_name(topic)
        self.node.create_subscription(msg_type, name, callback, depth)
        return name

    def _spin(self) -> None:
        while self._running:
            try:
                self._executor.spin_once(timeout_sec=INBOX_WAIT_S)
            except ExternalShutdownException:
                return
            except Exception:  # the context went away, or the executor was shut down
                if not self._running or not self.owner.context.ok():
                    return
                raise

    def close(self) -> None:
        """End the thread, then the node (idempotent)."""
        if not self._running:
            return
        self._running = False
        self._thread.join(INBOX_JOIN_S)
        self._executor.shutdown(timeout_sec=INBOX_JOIN_S)
        self.node.destroy_node()


__all__ = ["INBOX_JOIN_S", "INBOX_WAIT_S", "Inbox"]
