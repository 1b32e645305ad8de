"""``stepper_bridge`` with an injected fatal error, for the exit-stops-motion tests.

Run as ``python -m tests.support.fatal_bridge --ros-args ...``: the real stepper node,
plus a timer whose callback raises (an error no callback handles, like a bug would) as
soon as one of its command streams may move a motor. The process must stop that motion
before it exits.
"""

from __future__ import annotations

import sys

from rclpy.node import Node

from bridge_core.ros.process import spin_nodes
from stepper_bridge.node import StepperBridgeNode

CHECK_S = 0.05


class InjectedFatalError(RuntimeError):
    pass


def build(nodes: list[Node]) -> None:
    node = StepperBridgeNode()
    nodes.append(node)

    def fail_once_moving() -> None:
        if any(guard.moving() for guard in node.streams.guards):
            raise InjectedFatalError("injected: an error no callback handles")

    node.create_timer(CHECK_S, fail_once_moving)


if __name__ == "__main__":
    sys.exit(spin_nodes(build))
