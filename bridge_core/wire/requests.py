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


@dataclass(frozen=True)
class Span:
    """Registers (or bits) ``address`` .. ``address + count - 1`` of one table."""

    table: Table
    address: int
    count: int = 1

    def overlaps(self, other: Span) -> bool:
        return (
            self.table is other.table
            and self.address < other.address + other.count
            and other.address < self.address + self.count
        )


def written_span(request: Request) -> Span | None:
    """What a write request may change on the device (None for a read)."""
    if isinstance(request, WriteRegister):
        return Span(Table.HOLDING, request.address)
    if isinstance(request, WriteRegisters):
        return Span(Table.HOLDING, request.address, len(request.values))
    if isinstance(request, WriteCoil):
        return Span(Table.COIL, request.address)
    if isinstance(request, WriteCoils):
        return Span(Table.COIL, request.address, len(request.values))
    if isinstance(request, MaskWriteRegister):
        return Span(Table.HOLDING, request.address)
    if isinstance(request, ReadWriteRegisters):
        return Span(Table.HOLDING, request.write_address, len(request.values))
    return None
