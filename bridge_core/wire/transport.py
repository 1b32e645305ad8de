"""The transport: one pymodbus client (TCP or RTU) behind a small interface.

Together with ``serial_timing`` (our RTU client) and ``bridge_core.sim`` (the simulators) this is
the only module that imports pymodbus; its API moves between minor versions
(docs/architecture.md, "pymodbus pitfalls we work around"), so the version is pinned and
every pymodbus error is translated here into ``bridge_core.wire.errors``.

``ModbusLink`` is only the pipe: open, close, and ``execute`` one request for one unit id
under the caller's hold of its ``lock``. The policy (retries, backoff, health, priorities)
is ``bridge_core.wire.channel.DeviceChannel``'s. The request dataclasses are defined in the
pymodbus-free ``bridge_core.wire.requests`` and re-exported here.

How pymodbus 3.16.1's sync clients report a failed transaction, and what it becomes here,
told apart by exception type (never by the message text):

- no reply, or not all of it, within the timeout: the transaction manager catches its own
  ``TimeoutError`` and raises ``ModbusIOException`` built from the request (``fcode`` is
  the request's function code) -> ``LinkTimeout``;
- a reply from another unit id, or (TCP) with another transaction id: pymodbus's framer
  skips it and reads on (so it used to surface as a timeout, or as a ``ModbusIOException``
  of the same shape for a unit-0 request or a transaction id of 0). Our own checks see it
  first and raise ``ReplyFromOtherUnit`` / ``ReplyFromOtherTransaction``
  (``CheckedTcpClient`` below, ``serial_timing.TimedSerialClient`` on RTU) -> ``FrameError``;
- an RTU reply that fails its CRC: skipped by the framer too; ``TimedSerialClient``
  raises ``ReplyCrcError`` -> ``FrameError``;
- a complete frame whose PDU pymodbus cannot decode: ``ModbusIOException`` from the framer
  without a function code (``fcode is None``) -> ``FrameError``;
- refused, closed or broken connection: ``ConnectionException`` or ``OSError`` ->
  ``LinkDown`` (the client is closed);
- a Modbus exception reply is not an error to pymodbus; ``execute`` raises
  ``DeviceException`` for it.
"""

from __future__ import annotations

import logging
import socket
import threading
from contextlib import suppress
from dataclasses import dataclass
from typing import Any

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from . import requests as rq
from .channel import PriorityLock
from .errors import DeviceException, FrameError, LinkDown, LinkError, LinkTimeout
from .pipeline import TcpPipeline
from .registers import Table
from .requests import BROADCAST_UNIT, Reply, Request
from .serial_timing import (
    ReplyFrameError,
    ReplyFromOtherUnit,
    ReplyMismatch,
    TimedSerialClient,
    char_time_s,
    longest_hold_s,
    silence_s,
)
from .wire_tap import Outcome, WireCallback, WireTap, function_code

__all__ = [
    "CheckedTcpClient",
    "LinkSettings",
    "ModbusLink",
    "ReplyFromOtherTransaction",
    "SerialSettings",
    "TcpSettings",
]


class _LastConnectError(logging.Handler):
    """Keeps pymodbus's last error message per thread, printed nowhere.

    pymodbus 3.16's ``connect()`` catches the OS error of a failed open (``connection
    refused``, ``no such file or directory``) and only logs it; ``ModbusLink.open`` takes
    the reason from here so the bridge can say it (docs/behaviour.md, "Stale data": a
    device never reached is a WARN with the OS's reason).
    """

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self._local = threading.local()

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        # pymodbus says a message again only as "Repeating....", then not at all: the
        # link keeps the reason it saw first (``ModbusLink.open``).
        if not message.startswith("Repeating"):
            self._local.message = message

    def take(self) -> str:
        message, self._local.message = getattr(self._local, "message", ""), ""
        return str(message)


# pymodbus logs every refused connect and timeout on its own (and repeats itself); the
# channel counts and reports them in diagnostics, so its logger prints nothing itself:
# its errors only reach _LAST_ERROR (the reason of a failed open).
_LAST_ERROR = _LastConnectError()
_pymodbus_logger = logging.getLogger("pymodbus")
_pymodbus_logger.setLevel(logging.ERROR)
_pymodbus_logger.propagate = False
_pymodbus_logger.handlers = [_LAST_ERROR]


# ---------------------------------------------------------------- settings


@dataclass(frozen=True)
class TcpSettings:
    host: str = "127.0.0.1"
    port: int = 502
    timeout_s: float = 0.5

    def describe(self) -> str:
        return f"tcp://{self.host}:{self.port}"

    def longest_hold_s(self) -> float:
        """The longest one transaction holds the link: its reply timeout (a reconnect aside)."""
        return self.timeout_s

    def frame_time_s(self, request: Request) -> float:
        """Wire time of ``request`` and its reply beside the round trip: none counted (on a
        LAN a frame takes microseconds; the measured round trip holds it)."""
        return 0.0


@dataclass(frozen=True)
class SerialSettings:
    port: str
    baudrate: int = 9600
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8
    timeout_s: float = 0.5
    # Least silence between two frames on the line, when a device needs more than the
    # 3.5 characters Modbus RTU requires (0: t3.5 only).
    frame_gap_s: float = 0.0

    def line_text(self) -> str:
        """Baud rate and character format as manuals print them: ``19200 8E1``."""
        return f"{self.baudrate} {self.bytesize}{self.parity}{self.stopbits}"

    def describe(self) -> str:
        return f"{self.port}@{self.line_text()}"

    def longest_hold_s(self) -> float:
        """The longest one transaction can hold this line (``serial_timing.longest_hold_s``)."""
        return longest_hold_s(
            self.baudrate,
            self.timeout_s,
            frame_gap_s=self.frame_gap_s,
            bytesize=self.bytesize,
            parity=self.parity,
            stopbits=self.stopbits,
        )

    def frame_time_s(self, request: Request) -> float:
        """Wire time of ``request`` and its reply, and the silence that separates two
        transactions (t3.5, or ``frame_gap_s``): one transaction but the device's turnaround."""
        request_pdu, reply_pdu = rq.pdu_bytes(request)
        char = char_time_s(self.baudrate, self.bytesize, self.parity, self.stopbits)
        silence = silence_s(self.baudrate, self.bytesize, self.parity, self.stopbits)
        frames = request_pdu + reply_pdu + 2 * rq.RTU_ADU_OVERHEAD
        return frames * char + max(silence, self.frame_gap_s)


LinkSettings = TcpSettings | SerialSettings


def _open_reason(message: str) -> str:
    """The OS's words from pymodbus's "Connection to (host, port) failed: [Errno 111]
    Connection refused" or pyserial's "[Errno 2] could not open port X: [Errno 2] No such
    file or directory: 'X'": the text after the last errno, lower case."""
    if "]" in message:
        message = message.rsplit("]", 1)[1]
    message = message.split(": '", 1)[0].strip(" :")
    return message[:1].lower() + message[1:]


# ---------------------------------------------------------------- TCP reply check

# MBAP header: transaction id (2), protocol id (2), length (2), unit id (1).
MBAP_HEADER_LEN = 7
MBAP_TID = slice(0, 2)
MBAP_UNIT = 6


class ReplyFromOtherTransaction(ReplyMismatch):
    """A TCP reply carried another transaction id than the request (a stale or foreign reply)."""

    field = "transaction id"


class CheckedTcpClient(ModbusTcpClient):
    """``ModbusTcpClient`` that reports a reply to another unit or transaction at once.

    pymodbus 3.16's framer skips such a reply and keeps reading until the timeout. This
    client remembers the MBAP header of the request it sent and compares the first reply
    header with it: another transaction id raises ``ReplyFromOtherTransaction``, another
    unit id ``ReplyFromOtherUnit`` (both ``ReplyFrameError``, so the transport reports a
    ``FrameError`` and the channel drops the socket). Same constructor as the base class.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._request_header = b""
        self._reply_header = b""

    def connect(self) -> bool:
        """Connect, with Nagle off: a pipelined request must leave at once, not wait for
        the previous one's acknowledgement (``pipeline``). One request at a time sends the
        same bytes either way."""
        fresh = self.socket is None  # pymodbus calls connect() before every request
        ok = bool(super().connect())  # type: ignore[no-untyped-call]  # untyped in 3.16
        if ok and fresh and self.socket is not None:
            self.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return ok

    def send(self, request: bytes, addr: tuple[Any, ...] | None = None) -> int:
        self._request_header = bytes(request[:MBAP_HEADER_LEN])
        self._reply_header = b""
        return int(super().send(request, addr))

    def recv(self, size: int | None) -> bytes:
        data: bytes = super().recv(size)
        missing = MBAP_HEADER_LEN - len(self._reply_header)
        if data and missing > 0 and len(self._request_header) == MBAP_HEADER_LEN:
            self._reply_header += data[:missing]
            if len(self._reply_header) == MBAP_HEADER_LEN:
                self._check_reply_header()
        return data

    def _check_reply_header(self) -> None:
        sent, got = self._request_header, self._reply_header
        if got[MBAP_TID] != sent[MBAP_TID]:
            raise ReplyFromOtherTransaction(
                int.from_bytes(sent[MBAP_TID], "big"), int.from_bytes(got[MBAP_TID], "big")
            )
        if got[MBAP_UNIT] != sent[MBAP_UNIT]:
            raise ReplyFromOtherUnit(sent[MBAP_UNIT], got[MBAP_UNIT])


# ---------------------------------------------------------------- link


class ModbusLink:
    """One client and its transaction lock. Callers hold ``lock`` around ``execute``.

    ``wire``: called with every transaction as a ``wire_tap.WireFrame`` (the parameter
    ``record_wire``), under the lock, so it must not block; None installs nothing.
    """

    def __init__(self, settings: LinkSettings, wire: WireCallback | None = None) -> None:
        self.settings = settings
        self._open_failure = ""  # the OS's reason of the last failed open
        self.lock = PriorityLock()
        self.is_serial = isinstance(settings, SerialSettings)
        self._tap = WireTap(wire, rtu=self.is_serial) if wire is not None else None
        # pymodbus's own hook gives the whole ADUs of a one-at-a-time transaction.
        trace: dict[str, Any] = {"trace_packet": self._tap.packet} if self._tap else {}
        # retries=0: retrying is DeviceChannel's decision (reads only, never writes).
        self._client: ModbusTcpClient | ModbusSerialClient
        self._pipeline: TcpPipeline | None = None
        if isinstance(settings, TcpSettings):
            self._client = CheckedTcpClient(
                settings.host, port=settings.port, timeout=settings.timeout_s, retries=0, **trace
            )
            self._pipeline = TcpPipeline(self._client, settings.timeout_s, tap=self._tap)
        else:
            self._client = TimedSerialClient(
                settings.port,
                baudrate=settings.baudrate,
                parity=settings.parity,
                stopbits=settings.stopbits,
                bytesize=settings.bytesize,
                timeout=settings.timeout_s,
                retries=0,
                min_frame_gap_s=settings.frame_gap_s,
                **trace,
            )
        self._open = False

    def describe(self) -> str:
        return self.settings.describe()

    @property
    def is_open(self) -> bool:
        return self._open

    def frame_time_s(self, request: Request) -> float:
        """``request``'s wire time but the device's turnaround (the wire budget's part)."""
        return self.settings.frame_time_s(request)

    def open(self) -> None:
        _LAST_ERROR.take()
        try:
            ok = self._client.connect()
        except (OSError, ModbusException) as err:
            raise LinkDown(f"cannot open {self.describe()}: {err}") from err
        if not ok:
            reason = _open_reason(_LAST_ERROR.take()) or self._open_failure
            self._open_failure = reason
            raise LinkDown(f"cannot open {self.describe()}" + (f": {reason}" if reason else ""))
        self._open = True

    def close(self) -> None:
        self._open = False
        if self._pipeline is not None:
            self._pipeline.reset()
        with suppress(OSError):
            self._client.close()  # type: ignore[no-untyped-call]  # untyped in pymodbus 3.16

    def execute(self, unit_id: int, request: Request, timeout_s: float | None = None) -> Reply:
        """One transaction; pymodbus errors come out as ``LinkError`` subclasses.

        ``timeout_s``: a shorter reply timeout for this one (RTU; a TCP link keeps its own).
        """
        if self._tap is None:
            return self._execute(unit_id, request, timeout_s)
        return self._execute_recorded(self._tap, unit_id, request, timeout_s)

    def _execute_recorded(
        self, tap: WireTap, unit_id: int, request: Request, timeout_s: float | None
    ) -> Reply:
        """``_execute``, and its frame to the tap however it ends."""
        tap.begin()
        code = function_code(request)
        try:
            reply = self._execute(unit_id, request, timeout_s)
        except DeviceException as err:
            tap.ended(unit_id, code, Outcome.EXCEPTION, err.exception_code)
            raise
        except LinkTimeout:
            tap.ended(unit_id, code, Outcome.TIMEOUT)
            raise
        except FrameError:
            tap.ended(unit_id, code, Outcome.FRAME_ERROR)
            raise
        except LinkDown:
            tap.ended(unit_id, code, Outcome.LINK_DOWN)
            raise
        tap.ended(unit_id, code, Outcome.OK)
        return reply

    def _execute(self, unit_id: int, request: Request, timeout_s: float | None) -> Reply:
        if not self._open:
            raise LinkDown(f"{self.describe()} is not open")
        timed = isinstance(self._client, TimedSerialClient) and timeout_s is not None
        if timed:
            self._client.reply_timeout_s = timeout_s  # type: ignore[union-attr]
        try:
            response = self._send(unit_id, request)
        except ConnectionException as err:
            self.close()
            raise LinkDown(f"connection to {self.describe()} lost: {err}") from err
        except ReplyFrameError as err:  # our own checks: CRC, unit id, transaction id
            raise FrameError(f"unit {unit_id}: mismatched reply: {err.string}") from err
        except ModbusIOException as err:
            if err.fcode is None:  # the framer's "unable to decode": a reply came
                raise FrameError(f"unit {unit_id}: undecodable reply: {err.string}") from err
            waited = timeout_s if timed else self.settings.timeout_s
            raise LinkTimeout(f"unit {unit_id}: no reply within {waited} s") from err
        except ModbusException as err:
            raise FrameError(f"unit {unit_id}: {err}") from err
        except OSError as err:
            self.close()
            raise LinkDown(f"{self.describe()}: {err}") from err
        finally:
            if timed:
                self._client.reply_timeout_s = None  # type: ignore[union-attr]
        if response is None:  # a serial broadcast: no reply expected
            return None
        if response.isError():
            raise DeviceException(
                int(response.function_code) & 0x7F, int(getattr(response, "exception_code", 0))
            )
        if isinstance(request, rq.ReadBits):
            bits: list[bool] = response.bits[: request.count]  # pymodbus: already bools
            return bits
        if isinstance(request, rq.ReadRegisters | rq.ReadWriteRegisters):
            registers: list[int] = response.registers  # pymodbus decodes them to ints
            return registers
        return None

    @property
    def can_pipeline(self) -> bool:
        """Whether reads may be pipelined (TCP; a serial line carries one frame at a time)."""
        return self._pipeline is not None

    def send_pipelined(self, unit_id: int, request: Request) -> int:
        """Send a read without waiting for replies to those in flight (``pipeline``); its
        tag (the transaction id) names its reply in ``receive_pipelined``."""
        pipeline = self._pipeline
        if pipeline is None:
            raise ValueError(f"{self.describe()} does not pipeline")
        if not self._open:
            raise LinkDown(f"{self.describe()} is not open")
        try:
            return pipeline.send(unit_id, request)
        except LinkError:
            self.close()  # replies in flight must not be taken for later answers
            raise

    def receive_pipelined(self) -> tuple[int, Reply | DeviceException]:
        """The next reply of those in flight: its tag and the values (or the device's
        exception). A ``LinkError`` closes the connection and forgets the rest."""
        pipeline = self._pipeline
        if pipeline is None:
            raise ValueError(f"{self.describe()} does not pipeline")
        try:
            tag, _flight, outcome = pipeline.receive()
        except LinkError as err:
            self.close()
            if isinstance(err, LinkDown):
                raise LinkDown(f"connection to {self.describe()} lost: {err}") from err
            raise
        return tag, outcome

    def _send(self, unit_id: int, request: Request):  # type: ignore[no-untyped-def]
        c = self._client
        # Unit 0 is a broadcast on a serial line only (Modbus over serial line §2.1: no
        # reply). Modbus TCP has no broadcast: unit 0 is an address like any other (the
        # Modbus TCP spec's "0 or 0xFF" for a device reached by its IP address), so its
        # replies are awaited; a stop to unit 0 is done only when its reply says so.
        broadcast = unit_id == BROADCAST_UNIT and self.is_serial
        match request:
            case rq.ReadRegisters(address, count, Table.HOLDING):
                return c.read_holding_registers(address, count=count, device_id=unit_id)
            case rq.ReadRegisters(address, count, Table.INPUT):
                return c.read_input_registers(address, count=count, device_id=unit_id)
            case rq.ReadBits(address, count, Table.COIL):
                return c.read_coils(address, count=count, device_id=unit_id)
            case rq.ReadBits(address, count, Table.DISCRETE_INPUT):
                return c.read_discrete_inputs(address, count=count, device_id=unit_id)
            case rq.WriteRegister(address, value):
                return c.write_register(
                    address, value, device_id=unit_id, no_response_expected=broadcast
                )
            case rq.WriteRegisters(address, values):
                return c.write_registers(
                    address, list(values), device_id=unit_id, no_response_expected=broadcast
                )
            case rq.WriteCoil(address, on):
                return c.write_coil(address, on, device_id=unit_id, no_response_expected=broadcast)
            case rq.WriteCoils(address, values):
                return c.write_coils(
                    address, list(values), device_id=unit_id, no_response_expected=broadcast
                )
            case rq.MaskWriteRegister(address, and_mask, or_mask):
                return c.mask_write_register(
                    address=address, and_mask=and_mask, or_mask=or_mask, device_id=unit_id
                )
            case rq.ReadWriteRegisters(read_address, read_count, write_address, values):
                return c.readwrite_registers(
                    read_address=read_address,
                    read_count=read_count,
                    write_address=write_address,
                    values=list(values),
                    device_id=unit_id,
                )
        raise ValueError(f"unsupported request {request!r}")
