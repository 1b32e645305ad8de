"""The Modbus requests a channel hands to its transport, and their replies (pymodbus-free).

They are the vocabulary between ``channel.DeviceChannel`` (which builds them) and
``transport.ModbusLink`` (which sends them), so they live apart from both: the channel
must not import the transport (and with it pymodbus) to name a request.
``bridge_core.wire.transport`` re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass

from .registers import Table


@dataclass(frozen=True)
class ReadRegisters:
    address: int
    count: int
    table: Table = Table.HOLDING
    is_write = False


@dataclass(frozen=True)
class ReadBits:
    address: int
    count: int
    table: Table = Table.COIL
    is_write = False


@dataclass(frozen=True)
class WriteRegister:
    address: int
    value: int
    is_write = True


@dataclass(frozen=True)
class WriteRegisters:
    address: int
    values: tuple[int, ...]
    is_write = True


@dataclass(frozen=True)
class WriteCoil:
    address: int
    on: bool
    is_write = True


@dataclass(frozen=True)
class WriteCoils:
    address: int
    values: tuple[bool, ...]
    is_write = True


@dataclass(frozen=True)
class MaskWriteRegister:
    address: int
    and_mask: int
    or_mask: int
    is_write = True


@dataclass(frozen=True)
class ReadWriteRegisters:
    read_address: int
    read_count: int
    write_address: int
    values: tuple[int, ...]
    is_write = True


Request = (
    ReadRegisters
    | ReadBits
    | WriteRegister
    | WriteRegisters
    | WriteCoil
    | WriteCoils
    | MaskWriteRegister
    | ReadWriteRegisters
)
Reply = list[int] | list[bool] | None
