"""What a device model needs from a link, without importing the link.

Device modules (``device.py``) talk to this Protocol, so they stay free of pymodbus and
can be driven by ``bridge_core.link.DeviceChannel`` or by any fake in a test.
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import IntEnum
from typing import Protocol

from .registers import Table


class Priority(IntEnum):
    """Commands go before polls on a link (``link.PriorityLock``)."""

    COMMAND = 0
    POLL = 1


class RegisterIO(Protocol):
    """The Modbus operations a device model uses (``bridge_core.link.DeviceChannel``)."""

    def read_registers(
        self, address: int, count: int, table: Table = ..., priority: Priority = ...
    ) -> list[int]: ...
    def read_bits(
        self, address: int, count: int, table: Table = ..., priority: Priority = ...
    ) -> list[bool]: ...
    def write_register(self, address: int, value: int) -> None: ...
    def write_registers(self, address: int, values: Sequence[int]) -> None: ...
    def write_coil(self, address: int, on: bool) -> None: ...
    def write_coils(self, address: int, values: Sequence[bool]) -> None: ...
    def mask_write_register(self, address: int, and_mask: int, or_mask: int) -> None: ...
    def read_write_registers(
        self, read_address: int, read_count: int, write_address: int, values: Sequence[int]
    ) -> list[int]: ...
