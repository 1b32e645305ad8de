"""Every simulator answers like a strict device: raw frames on a real TCP socket
and a real pty.

- a function code the device does not have is ``FC|0x80, 0x01`` (ILLEGAL FUNCTION with the
  code echoed), including the ones pymodbus would otherwise answer itself (07, 08, 11,
  2B) and codes pymodbus does not know (over RTU framed by their CRC);
- FC 05 takes only FF00 (on) and 0000 (off): any other value is ILLEGAL DATA VALUE and
  writes nothing;
- a unit that is not there stays silent, whatever the code.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator

import pytest
import serial
from pymodbus.framer import FramerRTU

from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.registers import Access, DeviceLimits, Register, RegisterMap, Table, ValueType

from ...support.serial_pair import socat_pair

UNIT = 1
BAUD = 19200
STRICT_MAP = RegisterMap(
    "strict",
    (
        Register("word", 0, ValueType.U16, "test", access=Access.READ_WRITE),
        # write-only: the device lacks FC 01 (a map refuses a readable coil without it)
        Register("coil", 0, ValueType.BOOL, "test", table=Table.COIL, access=Access.WRITE),
    ),
    DeviceLimits(function_codes=frozenset({3, 5, 6, 16})),
)
# (function code, request body) of codes this device lacks; pymodbus answers 07, 08, 11
# and 2B on its own unless told not to.
FOREIGN = [
    (0x01, "0000 0001"),
    (0x02, "0000 0001"),
    (0x04, "0000 0001"),
    (0x07, ""),
    (0x08, "0000 1234"),
    (0x0F, "0000 0002 01 03"),
    (0x11, ""),
    (0x17, "0000 0001 0000 0001 02 0000"),
    (0x2B, "0E 01 00"),
]
UNKNOWN_TO_PYMODBUS = [(0x41, "00"), (0x64, "")]


def make_sim() -> tuple[Simulator, SimulatedDevice]:
    device = SimulatedDevice(STRICT_MAP, UNIT)
    return Simulator([device]), device


@pytest.fixture
def tcp() -> Iterator[tuple[int, SimulatedDevice]]:
    sim, device = make_sim()
    port = sim.start_tcp()
    try:
        yield port, device
    finally:
        sim.stop()


def tcp_request(port: int, pdu: bytes, unit: int = UNIT) -> bytes | None:
    """The reply PDU, or None when the unit stays silent."""
    with socket.create_connection(("127.0.0.1", port), timeout=1.0) as sock:
        sock.sendall(struct.pack(">HHHB", 7, 0, len(pdu) + 1, unit) + pdu)
        try:
            header = sock.recv(7)
        except TimeoutError:
            return None
        if not header:
            return None
        length = struct.unpack(">HHH", header[:6])[2] - 1
        return sock.recv(length)


@pytest.mark.parametrize(("function", "body"), FOREIGN + UNKNOWN_TO_PYMODBUS)
def test_tcp_answers_a_foreign_function_code_with_its_own_code(
    tcp: tuple[int, SimulatedDevice], function: int, body: str
) -> None:
    port, device = tcp
    reply = tcp_request(port, bytes([function]) + bytes.fromhex(body))
    assert reply == bytes([function | 0x80, 0x01])
    assert tcp_request(port, bytes([function]) + bytes.fromhex(body), unit=9) is None
    assert device.write_log == []


def test_tcp_single_coil_takes_only_ff00_and_0000(tcp: tuple[int, SimulatedDevice]) -> None:
    port, device = tcp
    for value in (0x1234, 0x0001, 0xFFFF, 0x00FF):
        reply = tcp_request(port, struct.pack(">BHH", 5, 0, value))
        assert reply == bytes([0x85, 0x03]), hex(value)
    assert device.write_log == [] and device.get("coil") is False
    assert tcp_request(port, struct.pack(">BHH", 5, 0, 0xFF00)) == bytes.fromhex("05 0000 FF00")
    assert device.get("coil") is True
    assert tcp_request(port, struct.pack(">BHH", 5, 0, 0x0000)) == bytes.fromhex("05 0000 0000")
    assert device.get("coil") is False
    # The codes the device has still work.
    assert tcp_request(port, struct.pack(">BHH", 6, 0, 77)) == struct.pack(">BHH", 6, 0, 77)
    assert tcp_request(port, struct.pack(">BHH", 3, 0, 1)) == bytes([3, 2, 0, 77])


@pytest.fixture
def rtu() -> Iterator[tuple[serial.Serial, SimulatedDevice]]:
    sim, device = make_sim()
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        try:
            with serial.Serial(bridge_end, BAUD, timeout=1.0) as port:
                yield port, device
        finally:
            sim.stop()


def rtu_request(port: serial.Serial, pdu: bytes, reply_length: int, unit: int = UNIT) -> bytes:
    """Send ``unit + pdu + CRC``; the reply's PDU (CRC checked), b"" when silent."""
    frame = bytes([unit]) + pdu
    port.reset_input_buffer()
    port.write(frame + FramerRTU.compute_CRC(frame).to_bytes(2, "big"))
    reply = bytes(port.read(reply_length))
    if not reply:
        return b""
    assert reply[0] == unit, reply.hex(" ")
    assert FramerRTU.check_CRC(reply[:-2], int.from_bytes(reply[-2:], "big")), reply.hex(" ")
    return reply[1:-2]


# Codes pymodbus cannot frame (0x41) too, framed by their CRC: before,
# such a request got no reply and the next request was lost with it.
@pytest.mark.parametrize(("function", "body"), FOREIGN + UNKNOWN_TO_PYMODBUS)
def test_rtu_answers_a_foreign_function_code_with_its_own_code(
    rtu: tuple[serial.Serial, SimulatedDevice], function: int, body: str
) -> None:
    port, device = rtu
    assert rtu_request(port, bytes([function]) + bytes.fromhex(body), 5) == bytes(
        [function | 0x80, 0x01]
    )
    assert rtu_request(port, bytes([function]) + bytes.fromhex(body), 5, unit=9) == b""
    # The line is still in step: a supported request right after is answered.
    assert rtu_request(port, struct.pack(">BHH", 3, 0, 1), 7) == bytes([3, 2, 0, 0])
    assert device.write_log == []


def test_rtu_single_coil_takes_only_ff00_and_0000(
    rtu: tuple[serial.Serial, SimulatedDevice],
) -> None:
    port, device = rtu
    assert rtu_request(port, struct.pack(">BHH", 5, 0, 0x1234), 5) == bytes([0x85, 0x03])
    assert device.write_log == [] and device.get("coil") is False
    on = struct.pack(">BHH", 5, 0, 0xFF00)
    assert rtu_request(port, on, 8) == on
    assert device.get("coil") is True
