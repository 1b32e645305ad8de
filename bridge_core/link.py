"""The link: one pymodbus client (TCP or RTU) behind a small interface.

Only this module (and ``sim_base``) imports pymodbus; its API moves between minor
versions (see shared/notes/pymodbus-and-timing.md), so the version is pinned and every
pymodbus error is translated here into ``bridge_core.errors``.

Shape:
- ``ModbusLink`` owns the client and a ``PriorityLock``: one transaction at a time, commands
  before polls, FIFO within a priority (so several drives on one bus take turns fairly).
- ``DeviceChannel`` is one unit id on a link, with its own health, capped exponential
  reconnect backoff and counters, so a dead drive on a shared RS-485 bus backs off on its
  own while the others keep their rate.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from .channel import Priority
from .errors import DeviceException, FrameError, LinkDown, LinkError, LinkTimeout
from .registers import Table
from .serial_timing import TimedSerialClient

# pymodbus logs every refused connect and timeout on its own (and repeats itself); the
# channel counts and reports them in diagnostics, so its logger only speaks when critical.
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

# First reconnect delay; it doubles per failure up to the node's reconnect_max_s.
RECONNECT_INITIAL_S = 0.25
LATENCY_SAMPLES = 512
UNIT_ID_MIN = 0
UNIT_ID_MAX = 247


class PriorityLock:
    """A mutex that hands over to waiting commands first, then in arrival order."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._busy = False
        self._waiting: list[tuple[int, int]] = []
        self._tickets = itertools.count()

    def acquire(self, priority: Priority) -> None:
        with self._cond:
            if self._busy or self._waiting:
                me = (int(priority), next(self._tickets))
                heapq.heappush(self._waiting, me)
                while self._busy or self._waiting[0] != me:
                    self._cond.wait()
                heapq.heappop(self._waiting)
            self._busy = True

    def release(self) -> None:
        with self._cond:
            self._busy = False
            if self._waiting:
                self._cond.notify_all()

    @contextmanager
    def hold(self, priority: Priority) -> Iterator[None]:
        self.acquire(priority)
        try:
            yield
        finally:
            self.release()


# ---------------------------------------------------------------- requests (pymodbus-free)


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


# ---------------------------------------------------------------- settings


@dataclass(frozen=True)
class TcpSettings:
    host: str = "127.0.0.1"
    port: int = 502
    timeout_s: float = 0.5

    def describe(self) -> str:
        return f"tcp://{self.host}:{self.port}"


@dataclass(frozen=True)
class SerialSettings:
    port: str
    baudrate: int = 9600
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8
    timeout_s: float = 0.5

    def describe(self) -> str:
        return f"{self.port}@{self.baudrate}{self.bytesize}{self.parity}{self.stopbits}"


LinkSettings = TcpSettings | SerialSettings


# ---------------------------------------------------------------- link


class ModbusLink:
    """One client and its transaction lock. Callers hold ``lock`` around ``execute``."""

    def __init__(self, settings: LinkSettings) -> None:
        self.settings = settings
        self.lock = PriorityLock()
        self.is_serial = isinstance(settings, SerialSettings)
        # retries=0: retrying is DeviceChannel's decision (reads only, never writes).
        self._client: ModbusTcpClient | ModbusSerialClient
        if isinstance(settings, TcpSettings):
            self._client = ModbusTcpClient(
                settings.host, port=settings.port, timeout=settings.timeout_s, retries=0
            )
        else:
            self._client = TimedSerialClient(
                settings.port,
                baudrate=settings.baudrate,
                parity=settings.parity,
                stopbits=settings.stopbits,
                bytesize=settings.bytesize,
                timeout=settings.timeout_s,
                retries=0,
            )
        self._open = False

    def describe(self) -> str:
        return self.settings.describe()

    @property
    def is_open(self) -> bool:
        return self._open

    def open(self) -> None:
        try:
            ok = self._client.connect()
        except (OSError, ModbusException) as err:
            raise LinkDown(f"cannot open {self.describe()}: {err}") from err
        if not ok:
            raise LinkDown(f"cannot open {self.describe()}")
        self._open = True

    def close(self) -> None:
        self._open = False
        with suppress(OSError):
            self._client.close()  # type: ignore[no-untyped-call]

    def execute(self, unit_id: int, request: Request) -> Reply:
        """One transaction; pymodbus errors come out as ``LinkError`` subclasses."""
        if not self._open:
            raise LinkDown(f"{self.describe()} is not open")
        try:
            response = self._send(unit_id, request)
        except ConnectionException as err:
            self.close()
            raise LinkDown(f"connection to {self.describe()} lost: {err}") from err
        except ModbusIOException as err:
            text = str(err)
            if "device id" in text or "transaction id" in text:
                raise FrameError(f"unit {unit_id}: mismatched reply: {text}") from err
            raise LinkTimeout(
                f"unit {unit_id}: no reply within {self.settings.timeout_s} s"
            ) from err
        except ModbusException as err:
            raise FrameError(f"unit {unit_id}: {err}") from err
        except OSError as err:
            self.close()
            raise LinkDown(f"{self.describe()}: {err}") from err
        if response is None:  # broadcast: no reply expected
            return None
        if response.isError():
            raise DeviceException(
                int(response.function_code) & 0x7F, int(getattr(response, "exception_code", 0))
            )
        if isinstance(request, ReadBits):
            bits: list[bool] = response.bits[: request.count]  # pymodbus: already bools
            return bits
        if isinstance(request, ReadRegisters | ReadWriteRegisters):
            registers: list[int] = response.registers  # pymodbus decodes them to ints
            return registers
        return None

    def _send(self, unit_id: int, request: Request):  # type: ignore[no-untyped-def]
        c = self._client
        broadcast = unit_id == 0
        match request:
            case ReadRegisters(address, count, Table.HOLDING):
                return c.read_holding_registers(address, count=count, device_id=unit_id)
            case ReadRegisters(address, count, Table.INPUT):
                return c.read_input_registers(address, count=count, device_id=unit_id)
            case ReadBits(address, count, Table.COIL):
                return c.read_coils(address, count=count, device_id=unit_id)
            case ReadBits(address, count, Table.DISCRETE_INPUT):
                return c.read_discrete_inputs(address, count=count, device_id=unit_id)
            case WriteRegister(address, value):
                return c.write_register(
                    address, value, device_id=unit_id, no_response_expected=broadcast
                )
            case WriteRegisters(address, values):
                return c.write_registers(
                    address, list(values), device_id=unit_id, no_response_expected=broadcast
                )
            case WriteCoil(address, on):
                return c.write_coil(address, on, device_id=unit_id, no_response_expected=broadcast)
            case WriteCoils(address, values):
                return c.write_coils(
                    address, list(values), device_id=unit_id, no_response_expected=broadcast
                )
            case MaskWriteRegister(address, and_mask, or_mask):
                return c.mask_write_register(
                    address=address, and_mask=and_mask, or_mask=or_mask, device_id=unit_id
                )
            case ReadWriteRegisters(read_address, read_count, write_address, values):
                return c.readwrite_registers(
                    read_address=read_address,
                    read_count=read_count,
                    write_address=write_address,
                    values=list(values),
                    device_id=unit_id,
                )
        raise ValueError(f"unsupported request {request!r}")


# ---------------------------------------------------------------- per-device channel


class Backoff:
    """Capped exponential delay between reconnect attempts."""

    def __init__(
        self, initial_s: float, max_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.initial_s = min(initial_s, max_s)
        self.max_s = max_s
        self._clock = clock
        self.failures = 0
        self.next_attempt = 0.0

    @property
    def delay_s(self) -> float:
        if self.failures == 0:
            return 0.0
        return float(min(self.max_s, self.initial_s * 2 ** (self.failures - 1)))

    def failed(self) -> None:
        self.failures += 1
        self.next_attempt = self._clock() + self.delay_s

    def succeeded(self) -> None:
        self.failures = 0
        self.next_attempt = 0.0

    def ready(self) -> bool:
        return self._clock() >= self.next_attempt


@dataclass
class LinkStats:
    """Counters for diagnostics; written under the link lock, read from any thread."""

    transactions: int = 0
    timeouts: int = 0
    exceptions: int = 0
    frame_errors: int = 0
    reconnects: int = 0
    connect_failures: int = 0
    last_error: str = ""
    last_error_time: float = 0.0
    latencies_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_SAMPLES))


class DeviceChannel:
    """One device (unit id) on a link: transactions, health and reconnect policy."""

    def __init__(
        self,
        link: ModbusLink,
        unit_id: int,
        *,
        retries: int = 1,
        reconnect_max_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not UNIT_ID_MIN <= unit_id <= UNIT_ID_MAX:
            raise ValueError(f"unit id {unit_id} outside {UNIT_ID_MIN}..{UNIT_ID_MAX}")
        self.link = link
        self.unit_id = unit_id
        self.retries = retries
        self.backoff = Backoff(RECONNECT_INITIAL_S, reconnect_max_s, clock)
        self.stats = LinkStats()
        self._connected = False
        self._ever_connected = False
        # Bumped whenever the device is marked down: a command started on an older epoch
        # must not run on a link that was lost (and maybe reopened) meanwhile.
        self._epoch = 0
        self._session = threading.local()

    @property
    def connected(self) -> bool:
        """True while the device's last transaction succeeded (or answered an exception)."""
        return self._connected

    def may_attempt(self) -> bool:
        """Whether a poll should try the device now (connected, or backoff elapsed)."""
        return self._connected or self.backoff.ready()

    @contextmanager
    def command_session(self) -> Iterator[None]:
        """Tie this thread's transactions to the connection they started on.

        Inside it, every transaction is refused (``LinkDown``, nothing sent) once the
        device was marked down after the session began, even if a poll has reconnected
        since: DESIGN §2, nothing is queued across a reconnect. The node's command guard
        wraps each command in one; polls and link-up probes run outside.
        """
        self._session.epoch = self._epoch if self._connected else -1
        try:
            yield
        finally:
            self._session.epoch = None

    def mark_down(self, error: LinkError | str) -> None:
        self._epoch += 1
        text = str(error)
        self.stats.last_error = text
        self.stats.last_error_time = time.time()
        if self._connected or self.backoff.ready():
            self.backoff.failed()
        self._connected = False
        if not self.link.is_serial:
            # TCP: drop the socket so a late reply cannot be taken for the next answer.
            self.link.close()

    def transact(self, request: Request, priority: Priority = Priority.POLL) -> Reply:
        """Run one request; reads are retried ``retries`` times, writes never are.

        Nor are probes of a device that is down: on a shared RS-485 bus every retry of a
        dead drive holds the bus for another timeout while the live drives wait.
        """
        attempts = 1 if request.is_write or not self._connected else 1 + self.retries
        lock = self.link.lock
        lock.acquire(priority)  # acquire/release, not a context manager: the poll hot path
        try:
            session = getattr(self._session, "epoch", None)
            if session is not None and (session != self._epoch or not self._connected):
                raise LinkDown(
                    f"{self.describe()}: the link was lost while the command waited; not sent"
                )
            last: LinkError = LinkDown("no attempt made")
            for _ in range(attempts):
                try:
                    if not self.link.is_open:
                        self.link.open()
                    started = time.perf_counter()
                    reply = self.link.execute(self.unit_id, request)
                except DeviceException as err:
                    # The device is alive and said no: not a link failure.
                    self.stats.exceptions += 1
                    self.stats.last_error = str(err)
                    self.stats.last_error_time = time.time()
                    self._note_alive()
                    raise
                except LinkTimeout as err:
                    self.stats.timeouts += 1
                    last = err
                    if not self.link.is_serial:
                        self.link.close()
                except FrameError as err:
                    self.stats.frame_errors += 1
                    last = err
                    if not self.link.is_serial:
                        self.link.close()
                except LinkDown as err:
                    self.stats.connect_failures += 1
                    last = err
                    break
                else:
                    stats = self.stats
                    stats.transactions += 1
                    stats.latencies_s.append(time.perf_counter() - started)
                    if not self._connected:
                        self._note_alive()
                    return reply
            self.mark_down(last)
            raise last
        finally:
            lock.release()

    def _note_alive(self) -> None:
        if not self._connected:
            if self._ever_connected:
                self.stats.reconnects += 1
            self._ever_connected = True
        self._connected = True
        self.backoff.succeeded()

    # Convenience wrappers, named after the Modbus functions they send.
    def read_registers(
        self,
        address: int,
        count: int,
        table: Table = Table.HOLDING,
        priority: Priority = Priority.POLL,
    ) -> list[int]:
        reply = self.transact(ReadRegisters(address, count, table), priority)
        assert isinstance(reply, list)
        if len(reply) != count:
            if len(reply) < count:
                raise FrameError(f"short reply: {len(reply)} of {count} registers")
            reply = reply[:count]
        return reply  # type: ignore[return-value]

    def read_bits(
        self,
        address: int,
        count: int,
        table: Table = Table.COIL,
        priority: Priority = Priority.POLL,
    ) -> list[bool]:
        reply = self.transact(ReadBits(address, count, table), priority)
        assert isinstance(reply, list)
        return reply  # type: ignore[return-value]  # execute() made them bools already

    def write_register(self, address: int, value: int) -> None:
        self.transact(WriteRegister(address, value), Priority.COMMAND)

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        self.transact(WriteRegisters(address, tuple(values)), Priority.COMMAND)

    def write_coil(self, address: int, on: bool) -> None:
        self.transact(WriteCoil(address, on), Priority.COMMAND)

    def write_coils(self, address: int, values: Sequence[bool]) -> None:
        self.transact(WriteCoils(address, tuple(values)), Priority.COMMAND)

    def mask_write_register(self, address: int, and_mask: int, or_mask: int) -> None:
        """FC 0x16: register = (register AND and_mask) OR (or_mask AND NOT and_mask)."""
        self.transact(MaskWriteRegister(address, and_mask, or_mask), Priority.COMMAND)

    def read_write_registers(
        self, read_address: int, read_count: int, write_address: int, values: Sequence[int]
    ) -> list[int]:
        """FC 0x17: write, then read, in one round trip (the write happens first)."""
        reply = self.transact(
            ReadWriteRegisters(read_address, read_count, write_address, tuple(values)),
            Priority.COMMAND,
        )
        assert isinstance(reply, list)
        return [int(v) for v in reply[:read_count]]

    def describe(self) -> str:
        return f"{self.link.describe()} unit {self.unit_id}"
