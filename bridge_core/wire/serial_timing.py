"""RTU wire timing for pymodbus's sync serial client.

pymodbus 3.16's ``ModbusSerialClient`` has two timing gaps on a real RS-485 line (measured;
docs/architecture.md, "pymodbus pitfalls we work around"):

- it never waits for the 3.5-character silence before sending, so it may start a request
  while a device still treats the line as inside the previous frame (devices then merge
  or drop frames);
- it finds the end of a reply by polling the port until the byte count stops growing,
  which costs 4-8 ms per transaction at 9600 baud and 1-2 ms at 115200.

``TimedSerialClient`` fixes both and keeps the rest of pymodbus: its framer and CRC check
decide whether a reply is good, its transaction manager does retries, and the client's
``timeout`` still bounds the wait for a reply. pymodbus's framer silently skips a frame
that fails its CRC or comes from another unit id and reads on, so a bad reply would only
surface as a timeout: once the framer has rejected what arrived, this client raises its
own ``ReplyCrcError`` / ``ReplyFromOtherUnit`` (both ``ReplyFrameError``), which the
transport reports as a ``FrameError`` by type. Override points:

- ``send``: waits for the silence (draining stray bytes, which restart it), writes, and
  works out from the request frame how long the reply will be;
- ``recv(None)`` (called by ``TransactionManager.sync_get_response``): reads exactly that
  many bytes and returns at the last one; after an exception function code (byte 2) it
  reads 5 bytes. A whole, good frame of the unit that cannot answer the request (``answers``:
  a late reply to an earlier one) is skipped and the next one read. Unknown function
  codes, ASCII framing, local echo and ports without a file descriptor keep pymodbus's own
  behaviour.

Timing rules are from "MODBUS over Serial Line, Specification and Implementation Guide
V1.02" §2.5.1.1 (framing) and §2.4.1 (master states).
"""

from __future__ import annotations

import logging
import math
import os
import select
import time
from typing import Any

import serial
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ConnectionException, ModbusException
from pymodbus.framer import FramerRTU
from pymodbus.logging import Log

from .requests import BROADCAST_UNIT
from .serial_port import open_serial, write_all

_log = logging.getLogger(__name__)

# ---------------------------------------------------------------- protocol timing limits

START_BITS = 1
# Frames are separated by at least 3.5 character times of silence (spec §2.5.1.1).
SILENCE_CHARS = 3.5
# Above 19200 baud the spec fixes the silence instead of scaling it with the baud rate.
FIXED_TIMING_ABOVE_BAUD = 19200
SILENCE_FIXED_S = 0.00175
# After a broadcast nobody answers; the master waits a "turnaround delay" so every device
# can process it before the next request (spec §2.4.1: typically 100 to 200 ms).
BROADCAST_TURNAROUND_S = 0.1
# A frame whose length is unknown (fallback paths only) ends after this much silence at
# least: USB adapters deliver bytes in bursts, so the wire's 3.5 characters is too short.
FALLBACK_FRAME_GAP_S = 0.005
# How long a request may wait for room in the port's output buffer (it is empty between
# transactions: a frame that cannot leave in this time means a stuck port or adapter).
WRITE_STALL_S = 1.0
# time.sleep overshoots by ~50-100 us (timer slack); the last stretch of a silence wait
# is spun on the clock so the request leaves within a few us of the silence's end.
SPIN_S = 100e-6

# ---------------------------------------------------------------- frame layout

# The longest RTU frame (spec §2.5.1: 256 bytes, address and CRC included).
MAX_RTU_FRAME_BYTES = 256

EXCEPTION_FLAG = 0x80
# unit id, function code, exception code, CRC (2).
EXCEPTION_REPLY_LEN = 5
# unit id, function code, byte count, CRC (2): the frame around a read reply's data.
READ_REPLY_OVERHEAD = 5
# Replies that echo the request's first fields (unit, function, 4 bytes, CRC).
ECHO_REPLY_LEN = 8
MASK_WRITE_REPLY_LEN = 10
CRC_LEN = 2
MIN_FRAME_LEN = 4

FC_READ_COILS = 0x01
FC_READ_DISCRETE_INPUTS = 0x02
FC_READ_HOLDING = 0x03
FC_READ_INPUT = 0x04
FC_WRITE_COIL = 0x05
FC_WRITE_REGISTER = 0x06
FC_READ_EXCEPTION_STATUS = 0x07
FC_COMM_EVENT_COUNTER = 0x0B
FC_WRITE_COILS = 0x0F
FC_WRITE_REGISTERS = 0x10
FC_MASK_WRITE = 0x16
FC_READ_WRITE_REGISTERS = 0x17

# unit id, function code, byte count: enough to know any listed reply's length.
REPLY_HEAD_LEN = 3
_READ_FUNCTIONS = frozenset(
    {
        FC_READ_COILS,
        FC_READ_DISCRETE_INPUTS,
        FC_READ_HOLDING,
        FC_READ_INPUT,
        FC_READ_WRITE_REGISTERS,
    }
)
# Writes whose reply repeats the request's address and value (05 / 06) or quantity.
_ECHO_FUNCTIONS = frozenset({FC_WRITE_COIL, FC_WRITE_REGISTER, FC_WRITE_COILS, FC_WRITE_REGISTERS})
# Replies whose length is fixed by their function code, whatever the request asked.
_FIXED_REPLY_LEN = {
    **dict.fromkeys(_ECHO_FUNCTIONS, ECHO_REPLY_LEN),
    FC_COMM_EVENT_COUNTER: ECHO_REPLY_LEN,  # status word, event count
    FC_MASK_WRITE: MASK_WRITE_REPLY_LEN,
    FC_READ_EXCEPTION_STATUS: EXCEPTION_REPLY_LEN,  # unit, function, status byte, CRC
}

# Request length (with CRC) each rule needs to read its count field.
_REQUEST_LEN_READ = 8
_REQUEST_LEN_READ_WRITE = 13


def char_time_s(baudrate: int, bytesize: int = 8, parity: str = "N", stopbits: int = 1) -> float:
    """Seconds per character: start bit, data bits, parity bit if any, stop bits."""
    bits = START_BITS + bytesize + (0 if parity.upper() == "N" else 1) + stopbits
    return bits / baudrate


def silence_s(baudrate: int, bytesize: int = 8, parity: str = "N", stopbits: int = 1) -> float:
    """The inter-frame silence t3.5 (fixed 1.75 ms above 19200 baud)."""
    if baudrate > FIXED_TIMING_ABOVE_BAUD:
        return SILENCE_FIXED_S
    return SILENCE_CHARS * char_time_s(baudrate, bytesize, parity, stopbits)


def longest_hold_s(
    baudrate: int,
    timeout_s: float,
    *,
    frame_gap_s: float = 0.0,
    bytesize: int = 8,
    parity: str = "N",
    stopbits: int = 1,
) -> float:
    """The longest one transaction can hold the line (``TimedSerialClient``).

    The silence before the request (t3.5, or a longer ``frame_gap_s``), the longest
    request frame, then the reply timeout, counted from the request's last byte: a reply
    must be complete by then, so a transaction that gets its answer is never longer than
    one that times out. (After a broadcast the next request also waits
    ``BROADCAST_TURNAROUND_S``; the bridges broadcast only to release every drive.)
    """
    char = char_time_s(baudrate, bytesize, parity, stopbits)
    silence = max(silence_s(baudrate, bytesize, parity, stopbits), frame_gap_s)
    return silence + MAX_RTU_FRAME_BYTES * char + timeout_s


def expected_reply_length(request: bytes) -> int | None:
    """Bytes of the normal reply to an RTU request frame (CRC included).

    0 for a broadcast (unit 0: no device answers), None when the function code's reply
    length does not follow from the request (then the caller falls back to silence).
    """
    if len(request) < MIN_FRAME_LEN:
        return None
    if request[0] == BROADCAST_UNIT:
        return 0
    function = request[1]
    if function in (FC_READ_COILS, FC_READ_DISCRETE_INPUTS) and len(request) >= _REQUEST_LEN_READ:
        bits = int.from_bytes(request[4:6], "big")
        return READ_REPLY_OVERHEAD + math.ceil(bits / 8)
    if function in (FC_READ_HOLDING, FC_READ_INPUT) and len(request) >= _REQUEST_LEN_READ:
        return READ_REPLY_OVERHEAD + 2 * int.from_bytes(request[4:6], "big")
    if function == FC_READ_WRITE_REGISTERS and len(request) >= _REQUEST_LEN_READ_WRITE:
        return READ_REPLY_OVERHEAD + 2 * int.from_bytes(request[4:6], "big")
    return _FIXED_REPLY_LEN.get(function)


def frame_length(head: bytes) -> int | None:
    """A reply frame's length from its own first three bytes (unit, function code, then a
    read's byte count), whatever request it answers; None: a function code not listed."""
    if len(head) < REPLY_HEAD_LEN:
        return None
    function = head[1]
    if function & EXCEPTION_FLAG:
        return EXCEPTION_REPLY_LEN
    if function in _READ_FUNCTIONS:
        return READ_REPLY_OVERHEAD + head[2]
    return _FIXED_REPLY_LEN.get(function)


def crc_matches(frame: bytes) -> bool:
    """Whether the last two bytes of an RTU ``frame`` are the CRC of the rest (the client's
    checks here, the simulators' framing in ``bridge_core.sim.rtu_framing``)."""
    return FramerRTU.check_CRC(frame[:-CRC_LEN], int.from_bytes(frame[-CRC_LEN:], "big"))


def answers(request: bytes, reply: bytes) -> bool:
    """Whether a whole ``reply`` frame can be the answer to the ``request`` frame.

    Its function code (or that code with the exception flag), its length, and the fields
    a write's reply repeats: address and value (FC 05 / 06), address and quantity
    (15 / 16), address and masks (22). A read's reply names no address: one of the same
    length is taken (MODBUS over Serial Line §2.4.1: a master discards a reply that
    comes after its timeout, which one that comes after the next request cannot be told
    from).
    """
    function = request[1]
    if reply[1] == function | EXCEPTION_FLAG:
        return True
    if reply[1] != function or len(reply) != expected_reply_length(request):
        return False
    if function in _ECHO_FUNCTIONS:
        return reply[2:6] == request[2:6]
    if function == FC_MASK_WRITE:
        return reply[2:8] == request[2:8]
    return True


class ReplyFrameError(ModbusException):
    """A reply arrived but is not the answer to the request (the transport: ``FrameError``).

    Raised only by our own checks (here and in ``transport.CheckedTcpClient``), never by
    pymodbus, so the transport tells it from pymodbus's own errors by its type.
    """


class ReplyCrcError(ReplyFrameError):
    """An RTU reply failed its CRC check."""

    def __init__(self, frame: bytes) -> None:
        self.frame = frame
        super().__init__(f"reply failed the CRC check: {frame.hex(' ')}")


class ReplyMismatch(ReplyFrameError):
    """A reply that answers another request: a header field differs from the request's."""

    field = "id"

    def __init__(self, expected: int, received: int) -> None:
        self.expected = expected
        self.received = received
        super().__init__(f"reply has {self.field} {received}, request had {self.field} {expected}")


class ReplyFromOtherUnit(ReplyMismatch):
    """A reply came from another unit (device) id than the request was for."""

    field = "device id"


class TimedSerialClient(ModbusSerialClient):
    """``ModbusSerialClient`` that keeps the RTU inter-frame silence and reads by length.

    Same constructor as ``ModbusSerialClient``, plus ``broadcast_turnaround_s`` and
    ``min_frame_gap_s`` (a longer silence between frames than t3.5).
    """

    def __init__(
        self,
        port: str,
        *,
        broadcast_turnaround_s: float = BROADCAST_TURNAROUND_S,
        min_frame_gap_s: float = 0.0,
        **kwargs: Any,
    ) -> None:
        super().__init__(port, **kwargs)
        params = self.comm_params
        self.char_s = char_time_s(params.baudrate, params.bytesize, params.parity, params.stopbits)
        # The silence kept between frames: t3.5, or longer for a device that needs it.
        self.silence_s = max(
            silence_s(params.baudrate, params.bytesize, params.parity, params.stopbits),
            min_frame_gap_s,
        )
        self.broadcast_turnaround_s = max(broadcast_turnaround_s, self.silence_s)
        self._fd: int | None = None
        self._poller = select.poll()
        # Line state, on time.monotonic(): the next request may start at _ready_at.
        self._ready_at = 0.0
        # The transaction in progress: its request, expected reply length (None: let
        # pymodbus find the end), reply deadline, and the bytes already handed over.
        self._request = b""
        self._expected: int | None = None
        self._deadline = 0.0
        self._returned: bytes | None = None
        # A reply timeout for the next transactions instead of the client's ``timeout``
        # (None: the client's); set by ``ModbusLink.execute(timeout_s=...)``.
        self.reply_timeout_s: float | None = None

    # ------------------------------------------------------------ connection
    def connect(self) -> bool:
        was_open = self.socket is not None
        ok = self._open_port() if not was_open else True
        if ok and not was_open and self.socket is not None:
            try:
                self._fd = int(self.socket.fileno())
            except (AttributeError, OSError, ValueError):  # URL handlers without a descriptor
                self._fd = None
            else:
                # poll, not select: a process with many files may give the port fd > 1023.
                self._poller = select.poll()
                self._poller.register(self._fd, select.POLLIN)
            # The line state is unknown: be silent for one interval before the first request.
            self._ready_at = time.monotonic() + self.silence_s
        return ok

    def _open_port(self) -> bool:
        """pymodbus's ``connect``, with every setting applied in the one configure of the
        open (``open_serial``): pymodbus sets the inter-byte timeout after opening, a
        second configure that a pty given parity refuses."""
        params = self.comm_params
        try:
            self.socket = open_serial(
                str(params.host),
                timeout=params.timeout_connect,
                write_timeout=params.timeout_connect,
                bytesize=params.bytesize,
                stopbits=params.stopbits,
                baudrate=params.baudrate,
                parity=params.parity,
                exclusive=True,
                inter_byte_timeout=self.inter_byte_timeout,  # as pymodbus sets it
            )
        except Exception as err:  # pyserial raises termios and OS errors as they come
            Log.error("{}", err)  # type: ignore[no-untyped-call]  # pymodbus's logger: the link reports it as the reason
            self.close()
        return self.socket is not None

    def close(self) -> None:
        self._fd = None
        super().close()  # type: ignore[no-untyped-call]

    @property
    def _timed(self) -> bool:
        """Whether this client does the RTU timing itself (else: pymodbus's behaviour)."""
        return (
            self._fd is not None
            and isinstance(self.framer, FramerRTU)
            and not self.comm_params.handle_local_echo
        )

    # ------------------------------------------------------------ sending
    def send(self, request: bytes, addr: tuple[Any, ...] | None = None) -> int:
        """Wait for the inter-frame silence, then send ``request``."""
        if not self._timed or not request:
            self._expected = None
            return super().send(request, addr)
        if not self.socket:
            raise ConnectionException(str(self))
        try:
            self._wait_for_silence()
            started = time.monotonic()
            assert self._fd is not None  # _timed
            size = write_all(self._fd, request, WRITE_STALL_S)
        except InterruptedError:
            raise
        except (serial.SerialTimeoutException, OSError):
            self.close()
            raise ConnectionException(str(self)) from None
        # write() returns once the bytes are queued; the last one leaves n chars later.
        sent_at = max(time.monotonic(), started + len(request) * self.char_s)
        self._request = bytes(request)
        self._expected = expected_reply_length(self._request)
        timeout = self.reply_timeout_s
        if timeout is None:
            timeout = self.comm_params.timeout_connect
        self._deadline = sent_at + timeout
        self._returned = None
        if self._expected == 0:
            self._ready_at = sent_at + self.broadcast_turnaround_s
        else:
            self._ready_at = sent_at + self.silence_s
        return int(size)

    def _wait_for_silence(self) -> None:
        """Block until the line has been quiet for t3.5 (stray bytes restart the wait)."""
        assert self.socket is not None
        while True:
            if waiting := int(self.socket.in_waiting):
                # A late reply or noise: it restarts the silence and is not a reply to
                # the coming request.
                stray = self.socket.read(waiting)
                self._heard_at(time.monotonic())
                _log.debug("discarded %d stray bytes before a request: %s", waiting, stray.hex())
            remaining = self._ready_at - time.monotonic()
            if remaining <= 0:
                return
            if remaining > SPIN_S:
                time.sleep(remaining - SPIN_S)
            while time.monotonic() < self._ready_at:
                pass

    def _heard_at(self, when: float) -> None:
        self._ready_at = max(self._ready_at, when + self.silence_s)

    # ------------------------------------------------------------ receiving
    def recv(self, size: int | None) -> bytes:
        """Return the reply frame as soon as its last byte is in (pymodbus asks size=None)."""
        if size is not None or self._expected is None or not self._timed:
            data = super().recv(size)
            if data:  # pymodbus found the end by silence: the line was busy until about now
                self._heard_at(time.monotonic())
            return data
        if not self.socket:
            raise ConnectionException(str(self))
        try:
            if self._returned is None:
                frame = b"" if self._expected == 0 else self._read_frame()
                self._returned = frame
                return frame
            return self._after_rejected(self._returned)
        except (BlockingIOError, InterruptedError):
            raise
        except OSError:
            self.close()
            raise ConnectionException(str(self)) from None

    def _read_frame(self) -> bytes:
        """One reply by its length; short (or empty) if the deadline passes first.

        A whole, good frame from the request's unit that answers another request (a reply
        that came after its own request had timed out, in the buffer only once this
        request was on the wire) is skipped and the next frame read: taken, it would have
        confirmed a write with a poll's reply, or given one read's values to another.
        """
        while True:
            head = self._read_exact(REPLY_HEAD_LEN)
            if len(head) < REPLY_HEAD_LEN:
                return head
            total = frame_length(head)
            if total is None:  # a function code not listed: read until silence
                return head + self._read_until_gap()
            frame = head + self._read_exact(total - REPLY_HEAD_LEN)
            if not self._answers_another(frame, total):
                return frame
            _log.debug("skipped a reply to another request: %s", frame.hex(" "))

    def _answers_another(self, frame: bytes, total: int) -> bool:
        """A whole frame, good CRC, from the request's unit, that cannot answer it."""
        return (
            len(frame) == total
            and frame[0] == self._request[0]
            and crc_matches(frame)
            and not answers(self._request, frame)
        )

    def _after_rejected(self, previous: bytes) -> bytes:
        """pymodbus asks for more after the framer found no reply in ``previous``.

        More bytes on the line (a longer reply than expected) go to the framer. Else, per
        the master state diagram (spec §2.4.1): a frame error ends the transaction at once;
        a reply from an unexpected unit leaves the master waiting for the right one until
        the timeout.
        """
        if more := self._read_until_gap():
            self._returned = previous + more
            return more
        unit = self._request[0]
        if len(previous) >= MIN_FRAME_LEN and not crc_matches(previous):
            raise ReplyCrcError(previous)
        if previous and previous[0] != unit:
            if frame := self._read_frame():
                self._returned = frame
                return frame
            raise ReplyFromOtherUnit(unit, previous[0])
        return b""

    def _read_exact(self, count: int) -> bytes:
        """Read ``count`` bytes, returning early only at the reply deadline.

        Past the deadline, what is already in the buffer is still taken: a thread that
        runs late on a loaded host must not call a reply that arrived a timeout.
        """
        buf = bytearray()
        while len(buf) < count:
            remaining = max(0.0, self._deadline - time.monotonic())
            if not (chunk := self._read_some(count - len(buf), remaining)):
                break
            buf += chunk
        return bytes(buf)

    def _read_until_gap(self) -> bytes:
        """Read until the line is quiet (fallback when the length is unknown)."""
        gap = max(self.silence_s, FALLBACK_FRAME_GAP_S)
        buf = bytearray()
        while True:
            remaining = self._deadline - time.monotonic()
            if not (chunk := self._read_some(256, min(gap, max(0.0, remaining)))):
                break
            buf += chunk
            if remaining <= 0:
                break  # past the deadline: what was there, once (a babbling line ends too)
        return bytes(buf)

    def _read_some(self, count: int, wait_s: float) -> bytes:
        """Up to ``count`` bytes as soon as any arrive, or b"" after ``wait_s``."""
        assert self._fd is not None
        if not self._poller.poll(math.ceil(wait_s * 1000)):
            return b""
        chunk = os.read(self._fd, count)
        if not chunk:
            raise OSError("serial port reports data but returned none (disconnected?)")
        self._heard_at(time.monotonic())
        return chunk
