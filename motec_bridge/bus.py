"""The MOTEC bus owner: ``motec_bridge``, the node of one serial bus shared by every drive
node of the process (docs/bridges/motec.md). ``motec_bridge.node`` starts it first.

It is a ``bridge_core.ros.process.BusNode`` with the serial parameters (``serial_port``,
``baudrate``, ``parity``, ``stopbits``, ``timeout_s``), ``unit_ids`` and ``interface``
(rs485 / rs232: at most 31 / 8 drives, §1.1). It opens the one ``ModbusLink`` every drive
shares (and closes it, after every drive stopped), and offers ``~/disable_all`` and
``~/start_all`` (broadcast.py: unit-0 writes read back drive by drive, MOTEC decision 15)
and ``~/joint_commands`` (one topic for every drive, joint_commands.py).
"""

from __future__ import annotations

import functools
from typing import Any, Protocol

from std_srvs.srv import Trigger

from bridge_core.ros.joint_commands import JointCommandTopic
from bridge_core.ros.process import BusNode
from bridge_core.runtime.joint_commands import CommandJoint
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import CommandRejected, ConfigurationError, LinkError
from bridge_core.wire.requests import Span

from .broadcast import disable_all, start_all
from .device import MotecDevice
from .interface import BUS_PARAMETERS, MOTEC_DEFAULTS
from .registers import BROADCAST_UNIT, INTERFACE_RS232, MAX_DRIVES, UNIT_IDS

BUS_NODE_NAME = "motec_bridge"


class BusDrive(Protocol):
    """What the bus owner uses of a drive node of its line (``MotecDriveNode``), named
    here so the drive node's module imports this one and never the other way round."""

    @property
    def device(self) -> MotecDevice: ...

    @property
    def read_only(self) -> bool: ...

    def command_joint(self) -> CommandJoint: ...


class MotecBusNode(BusNode):
    """The serial bus shared by every drive node of the process."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(
            BUS_NODE_NAME,
            MOTEC_DEFAULTS,
            unit_id_range=range(min(UNIT_IDS), max(UNIT_IDS) + 1),
            **kwargs,
        )
        values = self.declare_specs(BUS_PARAMETERS)
        interface = str(values["interface"]).lower()
        if len(self.unit_ids) > MAX_DRIVES[interface]:
            raise ConfigurationError(
                f"unit_ids has {len(self.unit_ids)} drives, but an {interface} line takes at "
                f"most {MAX_DRIVES[interface]} (§1.1.1: RS232通讯口最多可以支持连接8台驱动器联网)"
                if interface == INTERFACE_RS232
                else f"unit_ids has {len(self.unit_ids)} drives, more than {MAX_DRIVES[interface]}"
            )
        self.interface = interface
        self.read_only = bool(values["read_only"])
        self.on_parameter("read_only", lambda value: setattr(self, "read_only", bool(value)))
        self.broadcast = DeviceChannel(self.link, BROADCAST_UNIT, retries=0)
        # One channel per drive for start_all's check (its own: no drive node's backoff).
        self.drive_channels = {u: DeviceChannel(self.link, u, retries=0) for u in self.unit_ids}
        # Their writes (and the broadcast's) change what the drive nodes' slow groups hold
        # (0x28, 0x29): those are read again at the next poll.
        self.broadcast.add_write_listener(self._broadcast_written)
        for unit, channel in self.drive_channels.items():
            channel.add_write_listener(functools.partial(self._drive_written, unit))
        # The drive nodes of this process (build_nodes): start_all obeys their read_only.
        self.drive_nodes: dict[int, BusDrive] = {}
        self.create_service(Trigger, "~/disable_all", self._disable_all)
        self.create_service(Trigger, "~/start_all", self._start_all)

    def command_drives(self) -> None:
        """``~/joint_commands``: one topic for every drive of the bus, each name handed to
        its drive node's streams, judged by that node's lifecycle and read_only, and
        counted in that drive's diagnostics (a message refused whole: in the diagnostics
        of each drive it names)."""
        self.joint_commands = JointCommandTopic(
            self, [drive.command_joint() for drive in self.drive_nodes.values()]
        )

    def _broadcast_written(self, span: Span) -> None:
        for unit in self.drive_nodes:
            self._drive_written(unit, span)

    def _drive_written(self, unit: int, span: Span) -> None:
        drive = self.drive_nodes.get(unit)
        if drive is not None:
            drive.device.groups.note_write(span)

    def _disable_all(self, _request: Any, response: Any) -> Any:
        if self.read_only:
            response.success, response.message = False, "disable_all refused: read_only is set"
            return response
        try:
            ok, seen = disable_all(self.broadcast, self.drive_channels)
        except LinkError as err:
            response.success, response.message = False, f"disable_all failed: {err}"
            return response
        response.success = ok
        response.message = (
            f"disable_all: broadcast 0x28 = 0 sent, read back: {seen}"
            if ok
            else f"disable_all: broadcast 0x28 = 0 sent, NOT every drive released: {seen}"
        )
        return response

    def _start_all(self, _request: Any, response: Any) -> Any:
        """Broadcast 0x29 = 1: every drive starts its prepared move at once (guarded)."""
        response.success = False
        if self._state_machine.current_state[1] != "active":
            response.message = "start_all refused: the node is not active (lifecycle)"
        elif self.read_only:
            response.message = "start_all refused: read_only is set, nothing was written"
        else:
            read_only = [u for u, node in self.drive_nodes.items() if node.read_only]
            try:
                ok, seen = start_all(self.broadcast, self.drive_channels, read_only)
            except CommandRejected as err:
                response.message = f"start_all refused: {err}"
            except LinkError as err:
                response.message = f"start_all failed: {err}"
            else:
                response.success = ok
                response.message = (
                    f"start_all: broadcast 0x29 = 1 sent, read back: {seen}"
                    if ok
                    else f"start_all: broadcast 0x29 = 1 sent, not synchronised: {seen}"
                )
        return response
