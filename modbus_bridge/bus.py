"""``modbus_bus -p device_file:=FILE``: several described devices on one RTU line.

One process: a bus owner (``ModbusBusNode``, node ``modbus_bus``: the line's parameters,
``serial_port`` / ``baudrate`` / ``parity`` / ``stopbits`` / ``frame_gap_s`` /
``timeout_s``, their defaults from the file's ``line``) and one ``ModbusBridgeNode`` per
device of the file, named after it, on the bus's one link (the MOTEC bridge's pattern:
``bridge_core.ros.process.BusNode``). The devices take turns on the line through its
priority lock; each has its own poll rate, diagnostics, lifecycle and commands.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from bridge_core.ros.node_parameters import ParameterNode
from bridge_core.ros.process import BusNode, spin_nodes
from bridge_core.runtime.parameters import DeviceDefaults
from bridge_core.wire.channel import UNIT_ID_MAX
from bridge_core.wire.errors import ConfigurationError

from .description import Description
from .interface import BUS_NODE_NAME, LINE_FILE_SPEC, defaults_of
from .node import ModbusBridgeNode, described_by_parameter


class ModbusBusNode(BusNode):
    """The owner of a description file's RTU line."""

    def __init__(self, **kwargs: Any) -> None:
        self.description: Description | None = None
        super().__init__(
            BUS_NODE_NAME,
            self._defaults_from_file,
            unit_id_range=range(1, UNIT_ID_MAX + 1),
            unit_ids=self._unit_ids,
            **kwargs,
        )

    def _defaults_from_file(self, node: ParameterNode) -> DeviceDefaults:
        path, description = described_by_parameter(node, LINE_FILE_SPEC)
        if description.line is None:
            raise ConfigurationError(
                f"{path} describes one device with its own link: run modbus_bridge for it"
            )
        self.description = description
        return defaults_of(description.devices[0], description.line)

    def _unit_ids(self) -> list[int]:
        assert self.description is not None
        return [device.unit_id for device in self.description.devices]


def build_nodes(nodes: list[Node]) -> None:
    bus = ModbusBusNode()
    nodes.append(bus)
    assert bus.description is not None
    for device in bus.description.devices:
        nodes.append(
            ModbusBridgeNode(device, link=bus.link, devices_on_line=len(bus.description.devices))
        )


def main(args: Sequence[str] | None = None) -> int:
    return spin_nodes(build_nodes, args)


if __name__ == "__main__":
    sys.exit(main())
