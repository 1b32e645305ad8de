"""The serial simulators find the next request after a frame cut short, as a slave that
frames by silence does (``bridge_core/sim/rtu_framing.py``).

Seen in CI: a line blackout that began inside a request left its first byte in the MOTEC
simulator; pymodbus's own framer then dropped each following request with the tail of the
one before (the bytes came one by one) and the simulator answered nothing for seconds.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

import pytest
import serial
from pymodbus.framer import FramerRTU
from pymodbus.pdu.decoders import DecodePDU

from bench.line_relay import LineRelay
from bridge_core.sim.rtu_framing import RTU_MIN_FRAME, SlaveFramerRTU, slave_framer
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.sim.strict_decoding import strict_decoder
from bridge_core.wire.registers import Access, DeviceLimits, Register, RegisterMap, ValueType

UNITS = (1, 2, 3)
BAUD = 19200
FUNCTION_CODES = frozenset({3, 6, 16})
REPLY_TIMEOUT_S = 1.0
MAP = RegisterMap(
    "framing",
    tuple(
        Register(f"word_{a}", a, ValueType.U16, "test", access=Access.READ_WRITE)
        for a in range(0x20)
    ),
    DeviceLimits(function_codes=FUNCTION_CODES),
)


def frame(unit: int, pdu: bytes) -> bytes:
    body = bytes([unit]) + pdu
    return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")


def read(unit: int, address: int, count: int) -> bytes:
    return frame(unit, struct.pack(">BHH", 3, address, count))


def write(unit: int, address: int, value: int) -> bytes:
    return frame(unit, struct.pack(">BHH", 6, address, value))


def write_many(unit: int, address: int, values: list[int]) -> bytes:
    data = struct.pack(f">{len(values)}H", *values)
    return frame(unit, struct.pack(">BHHB", 16, address, len(values), len(data)) + data)


# A bridge's cycle on a three-drive line: polls and watchdog feeds, all 8-byte frames (a
# drop of 8 bytes never changes the phase of a misaligned buffer).
CYCLE = [read(u, 0x10, 5) for u in UNITS] + [write(u, 0x12, 1000) for u in UNITS]


def framer() -> SlaveFramerRTU:
    decoder = DecodePDU(True)
    strict_decoder(decoder, FUNCTION_CODES, tcp=False, units=lambda: UNITS)
    return slave_framer(lambda: UNITS)(decoder)


def frames_taken(framer: FramerRTU, before: bytes, requests: list[bytes]) -> list[bytes]:
    """Feed ``before`` then ``requests`` one byte at a time, as a paced line delivers
    them; the whole frames (unit, PDU and CRC) the framer takes, in order."""
    buffer, taken = before, []
    for byte in b"".join(requests):
        buffer += bytes([byte])
        used, _, _, pdu = framer.decode(buffer)
        if used and pdu:
            taken.append(buffer[used - len(pdu) - 3 : used])
        buffer = buffer[used:]
    return taken


@pytest.mark.parametrize("request_index", range(len(CYCLE)))
def test_every_request_after_a_cut_one_is_taken(request_index: int) -> None:
    """Each prefix of each request of the cycle, cut by a blackout, then four cycles:
    every request of them is taken (pymodbus's FramerRTU takes none of them)."""
    cut = CYCLE[request_index]
    after = CYCLE * 4
    for length in range(1, len(cut)):
        assert frames_taken(framer(), cut[:length], after) == after, cut[:length].hex(" ")


def test_garbage_that_promises_a_long_frame_does_not_hold_the_line() -> None:
    """An FC 16 header whose byte count (0xF0) promises 249 bytes, then a request: the
    request is taken at its last byte, not after 249 bytes of later requests."""
    garbage = bytes.fromhex("01 10 00 00 00 78 F0 00 01")
    assert frames_taken(framer(), garbage, [read(2, 0, 1)]) == [read(2, 0, 1)]


def test_a_long_request_is_taken_whole_and_once() -> None:
    """The hunt inside a waiting frame takes only a CRC-valid request to a served unit
    ending at the last byte: a long FC 16 request arriving byte by byte is one frame."""
    requests = [write_many(u, 0, list(range(1, 40))) for u in UNITS] + CYCLE
    assert frames_taken(framer(), b"", requests) == requests


def test_a_chunk_of_garbage_and_a_request_is_taken_at_once() -> None:
    """A loaded simulator reads the cut frame and the next request in one chunk."""
    for length in range(1, 8):
        buffer = CYCLE[0][:length] + CYCLE[1]
        used, unit, _, pdu = framer().decode(buffer)
        assert (used, unit, pdu) == (len(buffer), UNITS[1], CYCLE[1][1:-2]), length


def test_bytes_that_cannot_start_a_frame_are_dropped() -> None:
    """Bytes that are no candidate (function code 0 is none) are dropped, except the
    last few (a frame may start there)."""
    noise = bytes(16)
    used, _, _, pdu = framer().decode(noise)
    assert pdu == b"" and used == len(noise) - RTU_MIN_FRAME + 1


@pytest.fixture
def relayed() -> Iterator[tuple[serial.Serial, Simulator]]:
    """The simulator behind the line relay (bytes paced at the baud rate), as on a bus."""
    sim = Simulator([SimulatedDevice(MAP, u) for u in UNITS])
    with LineRelay(BAUD) as line:
        sim.start_serial(line.device_path, BAUD)
        try:
            with serial.Serial(line.client_path, BAUD, timeout=REPLY_TIMEOUT_S) as port:
                yield port, sim
        finally:
            sim.stop()


def test_the_serial_simulator_answers_the_first_request_after_a_cut_one(
    relayed: tuple[serial.Serial, Simulator],
) -> None:
    port, sim = relayed
    for length in range(1, 8):
        port.write(CYCLE[length % len(CYCLE)][:length])  # cut: never completed
        for unit in UNITS:
            request = write(unit, length, 100 + length)
            port.write(request)
            assert port.read(len(request)) == request, (length, unit)
            assert sim.devices[unit].get(f"word_{length}") == 100 + length
