"""The Modbus requests a channel hands to its transport, and their replies (pymodbus-free).

They are the vocabulary between ``channel.DeviceChannel`` (which builds them) and
``transport.ModbusLink`` (which sends them), so they live apart from both: the channel
must not import the transport (and with it pymodbus) to name a request.
``bridge_core.wire.transport`` re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass

from .registers import Table

# Unit id 0 is a broadcast on a serial line: every device acts on it, none answers (Modbus
# over serial line §2.1). Modbus TCP has no broadcast: there it is an address like any other.
BROADCAST_UNIT = 0


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


# ---------------------------------------------------------------- frame sizes

# PDU bytes (Modbus Application Protocol V1.1b3 §6): function code (1), then per function:
PDU_FUNCTION = 1
PDU_ADDRESS_COUNT = 4  # starting address (2) + quantity (2)
PDU_BYTE_COUNT = 1
PDU_ECHO = 5  # function + address (2) + value or quantity (2): FC 05, 06, 0F/10 replies
PDU_MASK_WRITE = 7  # function + address (2) + AND mask (2) + OR mask (2), also the reply
REGISTER_BYTES = 2
BITS_PER_BYTE = 8
# Around the PDU: RTU adds the unit id (1) and the CRC (2) (serial line spec §2.5.1);
# TCP the MBAP header (7, unit id included) (Modbus TCP spec §3.1.3).
RTU_ADU_OVERHEAD = 3
TCP_ADU_OVERHEAD = 7


def pdu_bytes(request: Request) -> tuple[int, int]:
    """Bytes of ``request``'s PDU and of its normal reply's PDU (the wire budget)."""
    read_header = PDU_FUNCTION + PDU_ADDRESS_COUNT
    if isinstance(request, ReadRegisters):
        return read_header, PDU_FUNCTION + PDU_BYTE_COUNT + REGISTER_BYTES * request.count
    if isinstance(request, ReadBits):
        return read_header, PDU_FUNCTION + PDU_BYTE_COUNT + -(-request.count // BITS_PER_BYTE)
    if isinstance(request, WriteRegister | WriteCoil):
        return PDU_ECHO, PDU_ECHO
    if isinstance(request, WriteRegisters):
        return read_header + PDU_BYTE_COUNT + REGISTER_BYTES * len(request.values), PDU_ECHO
    if isinstance(request, WriteCoils):
        packed = -(-len(request.values) // BITS_PER_BYTE)
        return read_header + PDU_BYTE_COUNT + packed, PDU_ECHO
    if isinstance(request, MaskWriteRegister):
        return PDU_MASK_WRITE, PDU_MASK_WRITE
    # Read/write multiple (FC 0x17): read address and quantity, write address and
    # quantity, byte count, the values; the reply carries the registers read.
    written = REGISTER_BYTES * len(request.values)
    request_pdu = PDU_FUNCTION + 2 * PDU_ADDRESS_COUNT + PDU_BYTE_COUNT + written
    return request_pdu, PDU_FUNCTION + PDU_BYTE_COUNT + REGISTER_BYTES * request.read_count
