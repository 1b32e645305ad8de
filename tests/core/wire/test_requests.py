"""Frame sizes of the requests (the wire budget's arithmetic): the examples of the Modbus
Application Protocol spec V1.1b3 §6 as known vectors, and pymodbus's own encoding (what
goes on the wire) over a sweep of sizes."""

from __future__ import annotations

from typing import Any

import pytest
from pymodbus.pdu import bit_message, register_message

from bridge_core.wire.registers import Table
from bridge_core.wire.requests import (
    MaskWriteRegister,
    ReadBits,
    ReadRegisters,
    ReadWriteRegisters,
    Request,
    WriteCoil,
    WriteCoils,
    WriteRegister,
    WriteRegisters,
    pdu_bytes,
)
from bridge_core.wire.transport import SerialSettings, TcpSettings

# (request, request PDU, reply PDU) from the spec's examples (hex as printed there).
SPEC_EXAMPLES = [
    # §6.1 read coils 20-38: request 01 00 13 00 13, response 01 03 CD 6B 05
    (ReadBits(19, 19, Table.COIL), "01 00 13 00 13", "01 03 CD 6B 05"),
    # §6.2 read discrete inputs 197-218: response 02 03 AC DB 35
    (ReadBits(196, 22, Table.DISCRETE_INPUT), "02 00 C4 00 16", "02 03 AC DB 35"),
    # §6.3 read holding registers 108-110
    (ReadRegisters(107, 3), "03 00 6B 00 03", "03 06 02 2B 00 00 00 64"),
    # §6.4 read input register 9
    (ReadRegisters(8, 1, Table.INPUT), "04 00 08 00 01", "04 02 00 0A"),
    # §6.5 write single coil 173 ON (echo)
    (WriteCoil(172, True), "05 00 AC FF 00", "05 00 AC FF 00"),
    # §6.6 write single register 2 = 3 (echo)
    (WriteRegister(1, 3), "06 00 01 00 03", "06 00 01 00 03"),
    # §6.11 write 10 coils from 20
    (WriteCoils(19, (True,) * 10), "0F 00 13 00 0A 02 CD 01", "0F 00 13 00 0A"),
    # §6.12 write 2 registers from 2
    (WriteRegisters(1, (10, 258)), "10 00 01 00 02 04 00 0A 01 02", "10 00 01 00 02"),
    # §6.16 mask write register 5 (echo)
    (MaskWriteRegister(4, 0xF2, 0x25), "16 00 04 00 F2 00 25", "16 00 04 00 F2 00 25"),
    # §6.17 read 6 registers from 4, write 3 from 15
    (
        ReadWriteRegisters(3, 6, 14, (255, 255, 255)),
        "17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF",
        "17 0C 00 FE 0A CD 00 01 00 03 00 0D 00 FF",
    ),
]


@pytest.mark.parametrize(("request_", "sent", "answer"), SPEC_EXAMPLES)
def test_pdu_sizes_of_the_spec_examples(request_: Request, sent: str, answer: str) -> None:
    assert pdu_bytes(request_) == (len(bytes.fromhex(sent)), len(bytes.fromhex(answer)))


@pytest.mark.parametrize("count", [1, 2, 7, 8, 9, 16, 17, 125])
def test_pdu_sizes_match_pymodbus_encoding(count: int) -> None:
    """pymodbus's PDU bodies plus the function code byte, for reads and writes of ``count``."""
    fc = 1
    registers = [0] * count
    bits = [True] * count
    cases: list[tuple[Request, Any, Any]] = [
        (
            ReadRegisters(0, count),
            register_message.ReadHoldingRegistersRequest(address=0, count=count),
            register_message.ReadHoldingRegistersResponse(registers=registers),
        ),
        (
            ReadBits(0, count),
            bit_message.ReadCoilsRequest(address=0, count=count),
            bit_message.ReadCoilsResponse(bits=bits),
        ),
        (
            WriteRegisters(0, tuple(registers)),
            register_message.WriteMultipleRegistersRequest(address=0, registers=registers),
            register_message.WriteMultipleRegistersResponse(address=0, count=count),
        ),
        (
            WriteCoils(0, tuple(bits)),
            bit_message.WriteMultipleCoilsRequest(address=0, bits=bits),
            bit_message.WriteMultipleCoilsResponse(address=0, count=count),
        ),
    ]
    for ours, request_pdu, reply_pdu in cases:
        expected = (fc + len(request_pdu.encode()), fc + len(reply_pdu.encode()))
        assert pdu_bytes(ours) == expected, ours


def test_rtu_frame_time_of_a_stepper_read_at_9600() -> None:
    """10 registers at 9600 8N1: request 8 bytes, reply 5 + 20, at 10 bits a character,
    and t3.5 (3.5 characters): 36.5 characters = 38.02 ms."""
    settings = SerialSettings("/dev/null", baudrate=9600)
    assert settings.frame_time_s(ReadRegisters(0, 10)) == pytest.approx(36.5 * 10 / 9600)


def test_rtu_frame_time_counts_parity_and_a_longer_frame_gap() -> None:
    even = SerialSettings("/dev/null", baudrate=9600, parity="E")
    assert even.frame_time_s(WriteRegister(0, 1)) == pytest.approx((16 + 3.5) * 11 / 9600)
    gap = SerialSettings("/dev/null", baudrate=115200, frame_gap_s=0.01)
    assert gap.frame_time_s(WriteRegister(0, 1)) == pytest.approx(16 * 10 / 115200 + 0.01)


def test_tcp_frames_are_left_to_the_measured_round_trip() -> None:
    assert TcpSettings().frame_time_s(ReadRegisters(0, 125)) == 0.0
