"""``modbus_bridge`` with an injected fatal error, for the exit-stops-motion tests.

Run as ``python -m tests.modbus.fatal_modbus --ros-args ...``: the real node, plus a
timer whose callback raises (an error no callback handles, like a bug would) as soon as a
``starts_motion`` trigger started a motion and a poll read it back. The process must
stop it before it exits.
"""

from __future__ import annotations

import sys

from rclpy.node import Node

from bridge_core.ros.process import spin_nodes
from modbus_bridge.node import ModbusBridgeNode

CHECK_S = 0.05


class InjectedFatalError(RuntimeError):
    pass


def build(nodes: list[Node]) -> None:
    node = ModbusBridgeNode()
    nodes.append(node)

    def fail_once_started() -> None:
        # Once a poll read the started motion back: the start's write is done (a fatal
        # error while it is still on the wire is test_service_motion_stops's case).
        snapshot = node.last_snapshot
        if not node.service_motions.moving() or snapshot is None:
            return
        if dict(zip(snapshot.names, snapshot.values, strict=True)).get("control_word") == 1:
            raise InjectedFatalError("injected: an error no callback handles")

    node.create_timer(CHECK_S, fail_once_started)


if __name__ == "__main__":
    sys.exit(spin_nodes(build))
