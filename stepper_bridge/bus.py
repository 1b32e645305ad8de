"""Several stepper controllers on one RS-485 line (§5(1) 40212: "主-从模式的多机通信").

``stepper_bus`` (``python -m stepper_bridge.bus``) starts one process on one serial port, as
MOTEC does:

- ``stepper_bus``: the bus owner (``bridge_core.ros.process.BusNode``) with the serial
  parameters (``serial_port``, ``baudrate``, ``parity``, ``stopbits``, ``timeout_s``,
  ``frame_gap_s``) and ``unit_ids`` (1-247, Modbus RTU's addresses, though 40212 takes
  1-255; at most ``MAX_CONTROLLERS_PER_BUS``: the manual advises "建议 485 总线在没有中继器
  的情况下,挂载控制器个数<12 个"). It opens the one link.
- ``stepper_<id>`` per unit id: the single-controller node (``StepperBridgeNode``) on the
  shared link, with its own channel, poll, topics, services, parameters and jog deadman.

The controllers take turns request by request (the link's PriorityLock, commands first).
Every node publishes ``joint_states`` in the process's namespace, so each controller needs
its own ``joint_prefix`` (a params file's ``/**/stepper_<id>:`` block): equal prefixes
are refused at start. ``python -m stepper_bridge.node`` stays the one-controller bridge.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from bridge_core.ros.process import BusNode, spin_nodes
from bridge_core.wire.channel import UNIT_ID_MAX
from bridge_core.wire.errors import ConfigurationError

from .interface import STEPPER_DEFAULTS
from .node import StepperBridgeNode, check_reply_timeout
from .registers import DEVICE_IDS

BUS_NODE_NAME = "stepper_bus"
# 40212: "挂载控制器个数<12 个" without a repeater.
MAX_CONTROLLERS_PER_BUS = 11
# 40212 takes 1-255, but an RTU request addresses 1-247 only (248-255 are reserved): a
# controller set to 248-255 cannot be reached, so such ids are refused at start.
BUS_UNIT_IDS = range(DEVICE_IDS.start, UNIT_ID_MAX + 1)


def controller_node_name(unit_id: int) -> str:
    return f"stepper_{unit_id}"


class StepperBusNode(BusNode):
    """The RS-485 line shared by every controller node of the process."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(BUS_NODE_NAME, STEPPER_DEFAULTS, unit_id_range=BUS_UNIT_IDS, **kwargs)
        check_reply_timeout(self.settings)
        if len(self.unit_ids) > MAX_CONTROLLERS_PER_BUS:
            raise ConfigurationError(
                f"unit_ids: {len(self.unit_ids)} controllers on one bus; the manual advises "
                f"fewer than 12 without a repeater (40212: 挂载控制器个数<12 个)"
            )


def build_nodes(nodes: list[Node]) -> None:
    """The bus owner first, then one node per controller on its link."""
    bus = StepperBusNode()
    nodes.append(bus)
    for unit in bus.unit_ids:
        nodes.append(StepperBridgeNode(controller_node_name(unit), link=bus.link, unit_id=unit))
    prefixes: dict[str, str] = {}
    for node in nodes[1:]:
        assert isinstance(node, StepperBridgeNode)
        other = prefixes.setdefault(node.joint_prefix, node.get_name())
        if other != node.get_name():
            raise ConfigurationError(
                f"{other} and {node.get_name()} both have joint_prefix "
                f"{node.joint_prefix!r}: their joint names would collide on joint_states; "
                "give each controller its own (a /**/stepper_<id>: block)"
            )


def main(args: Sequence[str] | None = None) -> int:
    return spin_nodes(build_nodes, args)


if __name__ == "__main__":
    sys.exit(main())
