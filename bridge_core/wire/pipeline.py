"""Pipelined Modbus TCP: several reads in flight on one connection, replies matched by id.

Why: a Modbus TCP device's poll is several requests, and a sequential client waits one
round trip for each (R6: 13 per poll, 65 ms on a 5 ms link). The Modbus TCP spec lets a
client send more requests before the first reply and match each reply by its MBAP
transaction id (Modbus Messaging on TCP/IP Implementation Guide V1.0b §4.2); many
devices and gateways accept it, some answer only one request at a time
(docs/architecture.md, "Pipelined Modbus TCP").

pymodbus 3.16's sync client cannot: its transaction manager sends one request and reads
until that request's reply (skipping others). ``TcpPipeline`` works beside it on the same
socket (``ModbusTcpClient.socket``): it frames each request itself (the client's
``FramerSocket`` with a transaction id from the client's own counter, so a later
sequential request never reuses one in flight), sends each in its own ``sendall`` on a
socket with TCP_NODELAY (``transport.CheckedTcpClient`` sets it), and decodes replies with
the client's framer and its client-side PDU decoder.

Replies are acknowledged at once (``TCP_QUICKACK`` after every ``recv``, Linux). Why: a
client that sends requests right after replies looks interactive to Linux, which then
delays its ACKs (40 ms or more) to carry them on the next data segment. One request at a
time, the next request carries the ACK. Pipelined, all requests are already out: the
ACK of the device's first reply is delayed, and a device that leaves Nagle's algorithm
on holds every further small reply until it comes: one delayed-ACK interval per window (R6, 13
reads per poll at window 13: 22.7 polls/s against 440 one at a time; with the quick ACK
1777; bench/README.md, "A device that leaves Nagle on"). The option is not sticky (the
kernel leaves quick-ACK mode again when we send), hence once per ``recv``; where the OS
has no such option (not Linux) the pipeline runs as before.

Only reads are pipelined: a write that goes out behind another may or may not happen
when the connection breaks, and the bridge never retries a write (the channel's rule).

Failures come out as ``bridge_core.wire.errors`` types, like ``ModbusLink.execute``:
no reply within the timeout of the oldest request in flight -> ``LinkTimeout``; a reply
with a transaction id not in flight, from another unit, or one that does not decode ->
``FrameError``; a closed or broken connection -> ``LinkDown``. After any of them the
pipeline forgets what was in flight (the link closes the socket). A Modbus exception
reply is the answer to its request (``DeviceException``, returned, not raised).
"""

from __future__ import annotations

import select
import socket
import time
from dataclasses import dataclass

from pymodbus.client import ModbusTcpClient
from pymodbus.pdu import ModbusPDU
from pymodbus.pdu import bit_message as pdu_bit
from pymodbus.pdu import register_message as pdu_reg

from . import requests as rq
from .errors import DeviceException, FrameError, LinkDown, LinkError, LinkTimeout
from .registers import Table
from .requests import Reply, Request
from .wire_tap import Outcome, WireTap

RECV_CHUNK = 4096
# A reply is at most one MBAP header (7) and a 253-byte PDU; more buffered than a full
# window of them means the peer sends what nobody asked for.
MAX_ADU = 260

# Linux's TCP_QUICKACK (tcp(7)); None where the OS has none.
TCP_QUICKACK: int | None = getattr(socket, "TCP_QUICKACK", None)

_READS: dict[Table, type[ModbusPDU]] = {
    Table.HOLDING: pdu_reg.ReadHoldingRegistersRequest,
    Table.INPUT: pdu_reg.ReadInputRegistersRequest,
    Table.COIL: pdu_bit.ReadCoilsRequest,
    Table.DISCRETE_INPUT: pdu_bit.ReadDiscreteInputsRequest,
}


@dataclass
class InFlight:
    """One request on the wire: what was asked, of whom, and when it left."""

    request: rq.ReadRegisters | rq.ReadBits
    unit_id: int
    sent_at: float  # time.perf_counter() after its sendall
    # Recording the wire only (``wire_tap``): its ADU, sequence number and wall-clock time.
    frame: bytes = b""
    sequence: int = 0
    sent_wall: float = 0.0


class TcpPipeline:
    """Requests in flight on one ``ModbusTcpClient``'s socket, matched by transaction id.

    The caller (``ModbusLink``, under its link lock) sends with ``send`` and takes replies
    with ``receive``; ``reset`` forgets everything (the socket was closed). ``tap``: gets
    every request's frame, answered or lost (recording the wire; None: nothing kept).
    """

    def __init__(
        self, client: ModbusTcpClient, timeout_s: float, tap: WireTap | None = None
    ) -> None:
        self._client = client
        self.timeout_s = timeout_s
        self.tap = tap
        self._in_flight: dict[int, InFlight] = {}
        self._buffer = b""

    @property
    def in_flight(self) -> int:
        return len(self._in_flight)

    def reset(self) -> None:
        self._in_flight.clear()
        self._buffer = b""

    def send(self, unit_id: int, request: Request) -> int:
        """Put ``request`` on the wire in a segment of its own; its transaction id."""
        if not isinstance(request, rq.ReadRegisters | rq.ReadBits):
            raise ValueError(f"only reads are pipelined, not {request!r}")
        sock = self._client.socket
        if sock is None:
            raise LinkDown("the connection is closed")
        tid = self._client.transaction.getNextTID()
        pdu = _READS[request.table](address=request.address, count=request.count, dev_id=unit_id)
        pdu.transaction_id = tid
        frame = self._client.framer.buildFrame(pdu)
        try:
            sock.settimeout(self.timeout_s)  # blocking with a bound (pymodbus left it non-blocking)
            sock.sendall(frame)
        except OSError as err:
            raise LinkDown(f"send failed: {err}") from err
        flight = InFlight(request, unit_id, time.perf_counter())
        if self.tap is not None:
            flight.frame, flight.sequence = bytes(frame), self.tap.next_sequence()
            flight.sent_wall = time.time()
        self._in_flight[tid] = flight
        return tid

    def receive(self) -> tuple[int, InFlight, Reply | DeviceException]:
        """The next reply to arrive, whichever request it answers (the Modbus TCP spec lets
        a server answer out of order): its transaction id, its request, its outcome."""
        if not self._in_flight:
            raise ValueError("nothing in flight")
        oldest = min(f.sent_at for f in self._in_flight.values())
        deadline = oldest + self.timeout_s
        if self.tap is not None:
            return self._receive_recorded(self.tap, deadline)
        while True:
            frame = self._take_frame()
            if frame is not None:
                return self._match(*frame)
            self._read_more(deadline)

    def _receive_recorded(
        self, tap: WireTap, deadline: float
    ) -> tuple[int, InFlight, Reply | DeviceException]:
        """``receive`` with each request's frame to ``tap``: the answered one, or every one
        in flight when the link fails (the link then forgets them)."""
        try:
            while True:
                raw = self._buffer
                frame = self._take_frame()
                if frame is not None:
                    reply = raw[: len(raw) - len(self._buffer)]
                    tid, flight, outcome = self._match(*frame)
                    if isinstance(outcome, DeviceException):
                        code, kind = outcome.exception_code, Outcome.EXCEPTION
                    else:
                        code, kind = 0, Outcome.OK
                    tap.pipelined(
                        flight.sequence,
                        flight.unit_id,
                        flight.frame,
                        flight.sent_wall,
                        reply,
                        kind,
                        code,
                    )
                    return tid, flight, outcome
                self._read_more(deadline)
        except LinkError as err:
            kind = (
                Outcome.TIMEOUT
                if isinstance(err, LinkTimeout)
                else Outcome.LINK_DOWN
                if isinstance(err, LinkDown)
                else Outcome.FRAME_ERROR
            )
            for flight in sorted(self._in_flight.values(), key=lambda f: f.sequence):
                tap.pipelined(
                    flight.sequence, flight.unit_id, flight.frame, flight.sent_wall, b"", kind
                )
            raise

    def _take_frame(self) -> tuple[int, int, bytes] | None:
        """(transaction id, unit id, PDU) of the first whole frame buffered, or None."""
        framer = self._client.framer
        length, unit_id, tid, pdu = framer.decode(self._buffer)
        if not length:
            if len(self._buffer) >= framer.MIN_SIZE and self._buffer[2:4] != b"\x00\x00":
                raise FrameError(f"reply with protocol id {self._buffer[2:4].hex()}")
            if len(self._buffer) > MAX_ADU:
                raise FrameError("reply longer than any Modbus frame")
            return None
        self._buffer = self._buffer[length:]
        return tid, unit_id, pdu

    def _read_more(self, deadline: float) -> None:
        sock = self._client.socket
        if sock is None:
            raise LinkDown("the connection is closed")
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            raise LinkTimeout(f"no reply within {self.timeout_s} s ({self.in_flight} in flight)")
        try:
            ready, _, _ = select.select([sock], [], [], remaining)
            if not ready:
                raise LinkTimeout(
                    f"no reply within {self.timeout_s} s ({self.in_flight} in flight)"
                )
            data = sock.recv(RECV_CHUNK)
            quick_ack(sock)
        except (OSError, ValueError) as err:  # ValueError: select on a closed socket
            raise LinkDown(f"receive failed: {err}") from err
        if not data:
            raise LinkDown(f"the device closed the connection ({self.in_flight} in flight)")
        self._buffer += data

    def _match(
        self, tid: int, unit_id: int, pdu: bytes
    ) -> tuple[int, InFlight, Reply | DeviceException]:
        flight = self._in_flight.pop(tid, None)
        if flight is None:
            raise FrameError(f"reply to transaction {tid}, which is not in flight")
        if unit_id != flight.unit_id:
            raise FrameError(f"reply from unit {unit_id} to a request to unit {flight.unit_id}")
        response = self._client.framer.decoder.decode(pdu)
        if response is None:
            raise FrameError(f"undecodable reply to transaction {tid}")
        if response.isError():
            code = int(getattr(response, "exception_code", 0))
            return tid, flight, DeviceException(int(response.function_code) & 0x7F, code)
        request = flight.request
        expected = _READS[request.table].function_code
        if int(response.function_code) != expected:
            raise FrameError(f"reply with function {response.function_code} to function {expected}")
        if isinstance(request, rq.ReadBits):
            bits = list(response.bits[: request.count])
            return tid, flight, bits
        registers = list(response.registers)
        return tid, flight, registers


def quick_ack(sock: socket.socket) -> None:
    """Acknowledge what ``sock`` received now, not after the delayed-ACK timer (see the
    module's docstring); a no-op where the OS has no TCP_QUICKACK."""
    if TCP_QUICKACK is not None:
        sock.setsockopt(socket.IPPROTO_TCP, TCP_QUICKACK, 1)


__all__ = ["TCP_QUICKACK", "InFlight", "TcpPipeline", "quick_ack"]
