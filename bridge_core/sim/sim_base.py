"""Simulator base: a real pymodbus server whose datastore follows a register map.

Each simulated unit (``SimulatedDevice``) serves exactly the addresses its map defines
(exception 0x02 elsewhere), refuses requests that cut a multi-register value in two,
refuses function codes the device lacks (``FC|0x80, 0x01``, over TCP and RTU alike:
``strict_decoder``), takes only FF00 / 0000 on FC 05 (0x03 otherwise), keeps a write log
the tests assert on,
and calls behaviour hooks (device ``sim.py`` modules make axes move, alarms appear ...).
A multi-drop server stays silent for unit ids it does not own, as an RS-485 device does.

The datastore plugs into pymodbus 3.16 as an "old simulator" ``ModbusServerContext``
(the server then calls ``async_getValues``/``async_setValues`` on it directly), which
gives async hooks for reply delays and withheld replies. Pinned: see
docs/architecture.md, "pymodbus pitfalls we work around".
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import math
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, ClassVar

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.transport import serialtransport as _serialtransport

from ..wire.codec import Value, decode, encode
from ..wire.registers import DeviceLimits, Register, RegisterMap, Table, ValueType
from ..wire.serial_port import open_serial
from .personality import (
    DelayRange,
    add_delay_argument,
    chosen_ignore,
)
from .rtu_framing import slave_framer
from .strict_decoding import strict_decoder
from .tcp_serving import InOrderHandler

FUNCTION_TABLES: dict[int, Table] = {
    1: Table.COIL,
    5: Table.COIL,
    15: Table.COIL,
    2: Table.DISCRETE_INPUT,
    3: Table.HOLDING,
    6: Table.HOLDING,
    16: Table.HOLDING,
    22: Table.HOLDING,
    23: Table.HOLDING,
    4: Table.INPUT,
}
ILLEGAL_FUNCTION = int(ExcCodes.ILLEGAL_FUNCTION)
ILLEGAL_ADDRESS = int(ExcCodes.ILLEGAL_ADDRESS)
ILLEGAL_VALUE = int(ExcCodes.ILLEGAL_VALUE)
DEVICE_FAILURE = int(ExcCodes.DEVICE_FAILURE)
TICK_S = 0.01
ECHO_FUNCTIONS = frozenset({5, 6})


class _JsonRecord:
    """A log record as one JSON line (``table`` by name, tuples as lists)."""

    def to_json(self) -> str:
        data = dataclasses.asdict(self)  # type: ignore[call-overload]
        data["table"] = data["table"].value
        return json.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in data.items()})

    @classmethod
    def from_json(cls, line: str) -> Any:
        data = json.loads(line)
        data["table"] = Table(data["table"])
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def _read_lines(path: Path) -> list[str]:
    """The complete lines of a log file (the simulator may be writing the next one)."""
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.splitlines() if text.endswith("\n") else text.splitlines()[:-1]
    return [line for line in lines if line]


@dataclass(frozen=True)
class WriteRecord(_JsonRecord):
    """One accepted write, as the device saw it (``ignored``: acknowledged and changed
    nothing, a device playing ``--ignore``)."""

    time: float
    unit_id: int
    function_code: int
    table: Table
    address: int
    values: tuple[int, ...]
    ignored: bool = False


def read_write_log(path: Path) -> list[WriteRecord]:
    return [WriteRecord.from_json(line) for line in _read_lines(path)]


@dataclass(frozen=True)
class ReadRecord(_JsonRecord):
    """One read request as the device handled it (``time``: wall clock when its values
    were taken), refused ones included; tests order a node's stamps against these."""

    time: float
    unit_id: int
    function_code: int
    table: Table
    address: int
    count: int

    def covers(self, table: Table, address: int) -> bool:
        return self.table is table and self.address <= address < self.address + self.count


def read_read_log(path: Path) -> list[ReadRecord]:
    """The records of a ``--read-log`` file."""
    return [ReadRecord.from_json(line) for line in _read_lines(path)]


# A hook sees a write before it lands and may refuse it with an exception code.
WriteGuard = Callable[[WriteRecord], int | None]
WriteHook = Callable[[WriteRecord], None]


class SimulatedDevice:
    """Memory and behaviour of one unit id, driven by a register map."""

    # The motion writes this device can be told to ignore (``--ignore``): name -> what
    # it is; ``write_names`` says which of them a write is.
    IGNORABLE: ClassVar[Mapping[str, str]] = {}

    def __init__(
        self,
        register_map: RegisterMap,
        unit_id: int = 1,
        *,
        limits: DeviceLimits | None = None,
        extra_addresses: dict[Table, Iterable[int]] | None = None,
        whole_values: bool = True,
        whole_value_writes: bool | None = None,
    ) -> None:
        self.map = register_map
        self.unit_id = unit_id
        self.limits = limits or register_map.limits
        self.whole_values = whole_values
        # A write that cuts a multi-register value is refused too, unless the device is
        # known to store what it gets word by word (default: as for reads).
        self.whole_value_writes = whole_values if whole_value_writes is None else whole_value_writes
        self.lock = threading.RLock()
        self.words: dict[tuple[Table, int], int] = {}
        # Per name: the register as ``set`` encodes it, the last value set and its words.
        self._last_set: dict[str, tuple[Register, Value, tuple[int, ...]]] = {}
        self.readable: set[tuple[Table, int]] = set()
        self.writable: set[tuple[Table, int]] = set()
        for reg in register_map:
            for address in reg.addresses():
                key = (reg.table, address)
                self.words[key] = 0
                if reg.access.readable:
                    self.readable.add(key)
                if reg.access.writable:
                    self.writable.add(key)
        for table, addresses in (extra_addresses or {}).items():
            for address in addresses:
                self.words.setdefault((table, address), 0)
                self.readable.add((table, address))
                if table.writable:
                    self.writable.add((table, address))
        self.write_log: list[WriteRecord] = []
        self.write_guards: list[WriteGuard] = []
        self.write_hooks: list[WriteHook] = []
        self.log_file: IO[str] | None = None
        # Read log, off by default (one record per read request when on): ``read_log``
        # in memory while ``log_reads`` is set, and/or JSON lines to ``read_log_file``.
        self.log_reads = False
        self.read_log: list[ReadRecord] = []
        self.read_log_file: IO[str] | None = None
        # Fault injection: address ranges that answer with a given exception code.
        self.forced_exceptions: list[tuple[Table, range, int]] = []
        # Personality: the motion writes (names of ``IGNORABLE``) acknowledged and ignored.
        self.ignore: frozenset[str] = frozenset()

    def write_names(self, record: WriteRecord) -> frozenset[str]:
        """Which of ``IGNORABLE`` this write is (device simulators override)."""
        return frozenset()

    def ignores(self, record: WriteRecord) -> bool:
        """Whether this device, playing ``--ignore``, leaves this write without effect."""
        return bool(self.ignore) and bool(self.write_names(record) & self.ignore)

    # ------------------------------------------------------------ values by name
    def get(self, name: str) -> Value:
        reg = self.map[name]
        with self.lock:
            return decode(reg, [self.words[(reg.table, a)] for a in reg.addresses()])

    def set(self, name: str, value: Value) -> None:
        """Set a value as the device itself would (no write-range check, no log).

        A tick sets dozens of values 100 times a second, most of them unchanged: the words
        of the last value set under ``name`` are kept, and a value whose words the table
        holds already is not stored again (a store of the same words changes nothing, the
        R6 simulator's coil and row mirror included)."""
        last = self._last_set.get(name)
        if last is not None and _same_value(last[1], value):
            reg, _, words = last
        else:
            reg = last[0] if last is not None else self._unchecked(name)
            words = tuple(encode(reg, value))
            self._last_set[name] = (reg, value, words)
        with self.lock:
            table, address = reg.table, reg.address
            if all(self.words[(table, address + i)] == w for i, w in enumerate(words)):
                return
            self.set_words(table, address, words)

    def _unchecked(self, name: str) -> Register:
        """The register without its write range: the device's own values are not writes."""
        return dataclasses.replace(self.map[name], minimum=None, maximum=None)

    def set_words(self, table: Table, address: int, values: Sequence[int]) -> None:
        with self.lock:
            for offset, word in enumerate(values):
                self.words[(table, address + offset)] = int(word)

    def get_words(self, table: Table, address: int, count: int) -> list[int]:
        with self.lock:
            return [self.words[(table, address + i)] for i in range(count)]

    # ------------------------------------------------------------ Modbus side
    def _check(self, table: Table, address: int, count: int, writing: bool) -> int | None:
        allowed = self.writable if writing else self.readable
        for a in range(address, address + count):
            if (table, a) not in allowed:
                return ILLEGAL_ADDRESS
        for forced_table, forced, code in self.forced_exceptions:
            if forced_table is table and any(a in forced for a in range(address, address + count)):
                return code
        if self.limits.homogeneous_requests and not table.is_bit and not writing:
            widths = {
                owner.count
                for a in range(address, address + count)
                if (owner := self.map.owner_at(table, a)) is not None
                and owner.value_type is not ValueType.STRING
            }
            if len(widths) > 1 or (widths == {ValueType.U64.words} and count != widths.pop()):
                return ILLEGAL_ADDRESS  # mixed widths, or more than one 64-bit value
        if (self.whole_value_writes if writing else self.whole_values) and not table.is_bit:
            # Strings may be read in part (R6 version: (length + 1) / 2 registers).
            for a in (address, address + count - 1):
                reg = self.map.owner_at(table, a)
                if (
                    reg is not None
                    and reg.value_type is not ValueType.STRING
                    and (reg.address < address or reg.end > address + count)
                ):
                    return ILLEGAL_ADDRESS
        return None

    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        table = FUNCTION_TABLES[function_code]
        if self.log_reads or self.read_log_file is not None:
            record = ReadRecord(time.time(), self.unit_id, function_code, table, address, count)
            self._log_read(record)
        limit = self.limits.max_read_bits if table.is_bit else self.limits.max_read_registers
        if count > limit:
            return ILLEGAL_ADDRESS
        with self.lock:
            code = self._check(table, address, count, writing=False)
            if code is not None:
                return code
            return [self.words[(table, address + i)] for i in range(count)]

    def _log_read(self, record: ReadRecord) -> None:
        with self.lock:
            if self.log_reads:
                self.read_log.append(record)
            if self.read_log_file is not None:
                self.read_log_file.write(record.to_json() + "\n")
                self.read_log_file.flush()

    def write(self, function_code: int, address: int, values: Sequence[int]) -> int | None:
        table = FUNCTION_TABLES[function_code]
        if not table.is_bit and len(values) > self.limits.max_write_registers:
            return ILLEGAL_ADDRESS
        record = WriteRecord(
            time.time(), self.unit_id, function_code, table, address, tuple(int(v) for v in values)
        )
        with self.lock:
            code = self._check(table, address, len(values), writing=True)
            if code is not None:
                return code
            for guard in self.write_guards:
                code = guard(record)
                if code is not None:
                    return code
            if self.ignores(record):
                self._log_write(dataclasses.replace(record, ignored=True))
                return None
            self.set_words(table, address, record.values)
            self._log_write(record)
            for hook in self.write_hooks:
                hook(record)
        return None

    def _log_write(self, record: WriteRecord) -> None:
        self.write_log.append(record)
        if self.log_file is not None:
            self.log_file.write(record.to_json() + "\n")
            self.log_file.flush()

    def writes_to(self, address: int, table: Table = Table.HOLDING) -> list[WriteRecord]:
        with self.lock:
            return [
                r
                for r in self.write_log
                if r.table is table and r.address <= address < r.address + len(r.values)
            ]

    def tick(self, dt: float) -> None:
        """Advance behaviour by ``dt`` seconds; device simulators override."""


class _MapContext(ModbusServerContext):
    """pymodbus datastore adapter; bypasses the deprecated base constructor on purpose."""

    def __init__(self, simulator: Simulator) -> None:
        self.old_simulator = True
        self.simdevices = []
        self._sim = simulator
        # FC 05 / 06 reply with the request's value (an echo): pymodbus builds the echo
        # by reading the address back after the write, which a device that changed the
        # value at once (a command register it clears, an ignored write) would not give.
        self._echo: dict[tuple[int, int, int], list[int]] = {}

    def device_ids(self) -> list[int]:
        """The units a broadcast reaches (pymodbus asks only then)."""
        return [u for u in self._sim.devices if u not in self._sim.deaf_to_broadcast]

    def _device(self, device_id: int, function_code: int) -> SimulatedDevice:
        sim = self._sim
        if sim.withhold_replies or device_id not in sim.devices:
            # With ignore_missing_devices the server then sends nothing, like a silent slave.
            raise NoSuchIdException(f"unit {device_id} silent")
        return sim.devices[device_id]

    async def refuse(self, device_id: int, function_code: int, code: ExcCodes) -> ExcCodes:
        """An exception reply from the unit, with its reply delay; a unit that is not
        there stays silent (``NoSuchIdException``), as for every other request."""
        self._device(device_id, function_code)
        await self._sim.delay()
        return code

    async def async_getValues(  # noqa: N802 - pymodbus name
        self, device_id: int, func_code: int, address: int, count: int = 1
    ) -> Any:
        device = self._device(device_id, func_code)
        if func_code in ECHO_FUNCTIONS:
            # pymodbus reads back what FC 05/06 just wrote to build the echo reply; the
            # register may be write-only, so this is not a Modbus read.
            echoed = self._echo.pop((device_id, func_code, address), None)
            words = echoed or device.get_words(FUNCTION_TABLES[func_code], address, count)
            return [bool(w) for w in words] if func_code == 5 else words
        await self._sim.delay()
        if func_code not in device.limits.function_codes:
            return ExcCodes.ILLEGAL_FUNCTION
        result = device.read(func_code, address, count)
        if isinstance(result, int):
            return ExcCodes(result)
        if FUNCTION_TABLES[func_code].is_bit:
            return [bool(v) for v in result]
        return result

    async def async_setValues(  # noqa: N802 - pymodbus name
        self, device_id: int, func_code: int, address: int, values: Sequence[int] | Sequence[bool]
    ) -> Any:
        sim = self._sim
        if sim.withhold_replies:
            words = tuple(int(v) for v in values)
            table = FUNCTION_TABLES[func_code]
            sim.withheld_writes.append(
                WriteRecord(time.time(), device_id, func_code, table, address, words)
            )
        device = self._device(device_id, func_code)
        await self._sim.delay()
        if func_code not in device.limits.function_codes:
            return ExcCodes.ILLEGAL_FUNCTION
        written = [int(v) for v in values]
        result = device.write(func_code, address, written)
        if result is None and func_code in ECHO_FUNCTIONS:
            self._echo[(device_id, func_code, address)] = written
        return None if result is None else ExcCodes(result)


class SimulatorStartError(RuntimeError):
    """The server could not listen (port in use, serial port missing): a one-line exit."""


def _same_value(a: Value, b: Value) -> bool:
    """Whether ``a`` and ``b`` encode to the same words: same type and equal, and for
    floats the same sign too (-0.0 == 0.0; a NaN is never equal, so it is encoded anew)."""
    if type(a) is not type(b) or a != b:
        return False
    return not isinstance(a, float) or math.copysign(1.0, a) == math.copysign(1.0, b)  # type: ignore[arg-type]


class Simulator:
    """A pymodbus server for one or more simulated units, run on a background thread."""

    def __init__(self, devices: Sequence[SimulatedDevice], *, tick_s: float = TICK_S) -> None:
        self.devices = {d.unit_id: d for d in devices}
        self.tick_s = tick_s
        self.withhold_replies = False
        # The writes (FC 05, 06, 15, 16, 23) that came in whole (framing and CRC checked by
        # the server) while replies were withheld: proof that a write reached a silent
        # device's wire, e.g. a stop tried on a dead line.
        self.withheld_writes: list[WriteRecord] = []
        # Units that miss every broadcast (noise on their stub) and still answer the rest.
        self.deaf_to_broadcast: set[int] = set()
        # Each reply waits a delay drawn in [reply_delay_s, reply_delay_max_s] (None:
        # exactly reply_delay_s); ``set_reply_delay`` sets both.
        self.reply_delay_s = max(d.limits.reply_delay_s for d in devices)
        self.reply_delay_max_s: float | None = None
        # TCP (``tcp_serving``): a simulated network round trip drawn in [round_trip_s,
        # round_trip_max_s] (requests in flight overlap, order kept), a device that drops a
        # request arriving while one is unanswered, and one that leaves Nagle on.
        self.round_trip_s = 0.0
        self.round_trip_max_s: float | None = None
        self.one_request_at_a_time = False
        self.nagle = False
        # Per accepted TCP connection, in order: TCP_NODELAY as the socket holds it.
        self.connections_nodelay: list[bool] = []
        self._random = random.Random()
        self.dropped: list[tuple[float, int]] = []  # (time, transaction id) of dropped ones
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._tick_errors: set[str] = set()  # the tick error lines printed (once each)
        self.port: int = 0

    @property
    def device(self) -> SimulatedDevice:
        """The only (or first) unit, for single-device simulators."""
        return next(iter(self.devices.values()))

    def set_reply_delay(self, low_s: float, high_s: float | None = None) -> None:
        """Each reply waits a delay drawn in [low_s, high_s] (RTU: the device's; TCP: the
        round trip, ``tcp_serving``): the ``--reply-delay-ms MIN[:MAX]`` personality."""
        self.reply_delay_s, self.reply_delay_max_s = low_s, high_s

    def set_round_trip(self, low_s: float, high_s: float | None = None) -> None:
        self.round_trip_s, self.round_trip_max_s = low_s, high_s

    def _draw(self, low: float, high: float | None) -> float:
        if high is None or high <= low:
            return max(0.0, low)
        return self._random.uniform(max(0.0, low), high)

    def reply_delay(self) -> float:
        """The delay of the next reply (drawn anew each time)."""
        return self._draw(self.reply_delay_s, self.reply_delay_max_s)

    def round_trip(self) -> float:
        """The next request's round trip (drawn anew each time)."""
        return self._draw(self.round_trip_s, self.round_trip_max_s)

    def ignore(self, names: Iterable[str]) -> None:
        """Every unit acknowledges the named motion writes and changes nothing
        (``--ignore``); an unknown name is a ValueError naming the known ones."""
        chosen = frozenset(names)
        for device in self.devices.values():
            unknown = chosen - set(device.IGNORABLE)
            if unknown:
                raise ValueError(
                    f"unknown motion write {', '.join(sorted(unknown))}; "
                    f"names: {', '.join(sorted(device.IGNORABLE))}"
                )
            device.ignore = chosen

    async def delay(self) -> None:
        delay = self.reply_delay()
        if delay > 0:
            await asyncio.sleep(delay)

    def start_tcp(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Serve Modbus TCP on ``host:port`` (0 = a free port); returns the port."""

        def make_server(ctx: ModbusServerContext) -> ModbusTcpServer:
            server = ModbusTcpServer(ctx, address=(host, port), ignore_missing_devices=True)
            # Requests answered in order, pipelined ones too (pymodbus's handler loses them).
            server.callback_new_connection = lambda: InOrderHandler(server, self)  # type: ignore[method-assign]
            return server

        self._start(make_server, tcp=True)
        return self.port

    def start_serial(
        self, port: str, baudrate: int = 9600, parity: str = "N", stopbits: int = 1
    ) -> None:
        _tolerate_dropped_parity()

        def make_server(ctx: ModbusServerContext) -> ModbusSerialServer:
            server = ModbusSerialServer(
                ctx,
                port=port,
                baudrate=baudrate,
                parity=parity,
                stopbits=stopbits,
                ignore_missing_devices=True,
                broadcast_enable=True,
            )
            # Back in step at the next request after a cut frame (pymodbus's framer is not).
            server.framer = slave_framer(lambda: self.devices)
            return server

        self._start(make_server, tcp=False)

    def _start(self, make_server: Callable[[ModbusServerContext], Any], *, tcp: bool) -> None:
        if self._thread is not None:
            raise RuntimeError("simulator already running")
        self._ready.clear()
        self._error = None
        self._thread = threading.Thread(
            target=lambda: asyncio.run(self._main(make_server, tcp)),
            name="modbus-sim",
            daemon=True,
        )
        self._thread.start()
        if not self._ready.wait(10):
            raise RuntimeError("simulator did not start within 10 s")
        if self._error is not None:
            self._thread.join()
            self._thread = None
            raise SimulatorStartError(f"simulator failed to start: {self._error}") from self._error

    async def _main(self, make_server: Callable[[ModbusServerContext], Any], tcp: bool) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        try:
            server = make_server(_MapContext(self))
            allowed = set().union(*(d.limits.function_codes for d in self.devices.values()))
            strict_decoder(server.decoder, allowed, tcp=tcp, units=lambda: self.devices)
            await server.serve_forever(background=True)
            transport = getattr(server, "transport", None)
            sockets = getattr(transport, "sockets", None)
            if sockets:
                self.port = int(sockets[0].getsockname()[1])
        except BaseException as err:  # reported to the starting thread
            self._error = err
            self._ready.set()
            return
        self._ready.set()
        last = time.monotonic()
        try:
            while not self._stop.is_set():
                # A plain sleep (a stop is seen within a tick): asyncio.wait_for on the
                # stop event made a task and a timeout every tick, ~5 % of a core.
                await asyncio.sleep(self.tick_s)
                now = time.monotonic()
                for device in self.devices.values():
                    self._tick(device, now - last)
                last = now
        finally:
            await server.shutdown()

    def _tick(self, device: SimulatedDevice, dt: float) -> None:
        """One device's tick: an error in it is logged (one stderr line per distinct
        error and unit) and the simulator keeps serving, instead of the server stopping
        silently with its thread."""
        try:
            device.tick(dt)
        except Exception as err:  # any device fault: keep serving
            line = f"simulator: unit {device.unit_id} tick failed: {type(err).__name__}: {err}"
            if line not in self._tick_errors:
                self._tick_errors.add(line)
                print(line, file=sys.stderr, flush=True)

    def stop(self) -> None:
        if self._thread is None:
            return
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None:
            loop.call_soon_threadsafe(stop.set)
        self._thread.join(10)
        self._thread = None

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def serve_until_signalled(sim: Simulator, banner: str, port_file: Path | None = None) -> None:
    """The simulators' command-line loop: announce, wait for SIGINT/SIGTERM, stop.

    ``banner`` is printed (flushed) once the server listens: tests wait for that line;
    ``port_file`` receives the bound TCP port (useful with ``--port 0``).
    """
    if port_file is not None:
        port_file.write_text(str(sim.port))
    print(banner, flush=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    done.wait()
    sim.stop()


class _SerialModule:
    """pyserial as pymodbus's serial transport sees it, with ``serial_for_url`` opening a
    plain path as ``serial_port.ParityTolerantSerial``."""

    def __init__(self, module: Any) -> None:
        self._module = module

    def __getattr__(self, name: str) -> Any:
        return open_serial if name == "serial_for_url" else getattr(self._module, name)


def _tolerate_dropped_parity() -> None:
    """pymodbus's server transport opens its port, then sets its timeouts: a second
    configure, which a pty given parity (8E1, 8O1) refuses with EINVAL. Its port is opened
    through ``open_serial`` instead (once per process; pymodbus has no hook for it)."""
    module: Any = _serialtransport
    if not isinstance(module.serial, _SerialModule):
        module.serial = _SerialModule(module.serial)


class PtyPair:
    """Two linked pseudo-terminals from socat: ``link`` for the bridge, one for the server."""

    def __init__(self, link: Path) -> None:
        socat = shutil.which("socat")
        if socat is None:
            raise RuntimeError("--pty needs socat (apt-get install socat)")
        self._tmp = tempfile.TemporaryDirectory()
        self.link = link
        self.device_end = Path(self._tmp.name) / "device"
        self.proc = subprocess.Popen(
            [socat, f"pty,raw,echo=0,link={link}", f"pty,raw,echo=0,link={self.device_end}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + 10
        while not (link.exists() and self.device_end.exists()):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise RuntimeError("socat did not create the pty pair")
            time.sleep(0.01)

    def close(self) -> None:
        end_socat(self.proc)
        self._tmp.cleanup()


SOCAT_TERM_WAIT_S = 5.0  # socat 1.7.4 now and then misses a SIGTERM (seen in CI): then SIGKILL


def end_socat(proc: subprocess.Popen[bytes], term_wait_s: float = SOCAT_TERM_WAIT_S) -> None:
    """Stop a socat pty pair: SIGTERM, and SIGKILL if it has not gone ``term_wait_s``
    later, so the ptys vanish either way."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(term_wait_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def add_log_arguments(parser: argparse.ArgumentParser) -> None:
    """The simulators' log options: accepted writes, and (off by default) read requests."""
    parser.add_argument("--write-log", type=Path, help="append every accepted write (JSON lines)")
    parser.add_argument(
        "--read-log",
        type=Path,
        help="append every read request with the time it was handled (JSON lines)",
    )


def open_logs(args: argparse.Namespace, sim: Simulator) -> list[IO[str]]:
    """Attach ``--write-log`` / ``--read-log`` files to every unit; the files to close."""
    write_log = args.write_log.open("a") if args.write_log else None
    read_log = args.read_log.open("a") if args.read_log else None
    for device in sim.devices.values():
        device.log_file = write_log
        device.read_log_file = read_log
    return [f for f in (write_log, read_log) if f is not None]


def add_network_arguments(
    parser: argparse.ArgumentParser, delay_default_ms: float | None = 0.0
) -> None:
    """The TCP simulators' network options (``tcp_serving``, ``personality``)."""
    add_delay_argument(
        parser,
        delay_default_ms,
        "simulated network round trip (half each way); pipelined requests overlap, their "
        "order is kept",
    )
    parser.add_argument(
        "--one-request-at-a-time",
        action="store_true",
        help="drop a request that arrives while one is unanswered (a device that does not "
        "pipeline)",
    )
    parser.add_argument(
        "--nagle", action="store_true", help="leave Nagle's algorithm on for the replies"
    )


def apply_ignore(sim: Simulator, args: argparse.Namespace) -> None:
    """``--ignore`` of a simulator's command line, on every unit (names checked by argparse)."""
    names = chosen_ignore(args)
    if names:
        sim.ignore(names)


def personality_text(sim: Simulator, args: argparse.Namespace) -> str:
    """What the banner says of the personality switches in force ('' when none)."""
    parts = []
    if getattr(args, "ignore", None):
        parts.append(f"ignores {','.join(sorted(args.ignore))}")
    if getattr(args, "nagle", False):
        parts.append("Nagle on")
    return f" ({'; '.join(parts)})" if parts else ""


def add_tcp_arguments(parser: argparse.ArgumentParser, default_port: int) -> None:
    """The TCP simulators' options: where to listen, the logs, the port file, the network."""
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=default_port, help="0 picks a free port")
    add_network_arguments(parser)
    add_log_arguments(parser)
    parser.add_argument("--port-file", type=Path, help="write the bound port here once listening")


def serve_tcp_until_signalled(sim: Simulator, args: argparse.Namespace, name: str) -> None:
    """Attach the logs, listen on ``args.host:args.port`` and serve until SIGINT/SIGTERM."""
    open_logs(args, sim)
    delay: DelayRange | None = getattr(args, "reply_delay_ms", None)
    if delay is not None:
        sim.set_round_trip(delay.low_s, delay.high_s)
    sim.one_request_at_a_time = bool(getattr(args, "one_request_at_a_time", False))
    sim.nagle = bool(getattr(args, "nagle", False))
    apply_ignore(sim, args)
    try:
        port = sim.start_tcp(args.host, args.port)
    except SimulatorStartError as err:
        raise SystemExit(
            f"{name}: cannot listen on {args.host}:{args.port}: {err.__cause__}"
        ) from None
    serve_until_signalled(
        sim, f"{name} listening on {args.host}:{port}{personality_text(sim, args)}", args.port_file
    )


def add_serial_arguments(
    parser: argparse.ArgumentParser, default_baudrate: int, example: str
) -> None:
    """The serial simulators' line options: where to serve (a port, or a new pty pair)."""
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--serial", help="serve on this serial port or pty path")
    where.add_argument(
        "--pty",
        type=Path,
        help=f"create a socat pty pair and link the bridge's end here (e.g. {example})",
    )
    parser.add_argument("--baudrate", type=int, default=default_baudrate)
    parser.add_argument("--parity", default="N", choices=("N", "E", "O"))
    parser.add_argument("--stopbits", type=int, default=1, choices=(1, 2))
    add_log_arguments(parser)


def serve_serial_until_signalled(
    sim: Simulator, args: argparse.Namespace, banner: Callable[[str], str]
) -> None:
    """Serve on ``args.serial`` or a new pty pair (``args.pty``) until SIGINT/SIGTERM.

    ``banner(where)`` is the line printed once listening; the logs (``--write-log``,
    ``--read-log``) are attached first, and the pty pair and logs are closed after.
    """
    logs = open_logs(args, sim)
    delay: DelayRange | None = getattr(args, "reply_delay_ms", None)
    if delay is not None:
        sim.set_reply_delay(delay.low_s, delay.high_s)
    apply_ignore(sim, args)
    pair = PtyPair(args.pty) if args.pty else None
    try:
        port = str(pair.device_end) if pair else args.serial
        try:
            sim.start_serial(port, args.baudrate, args.parity, args.stopbits)
        except SimulatorStartError as err:
            raise SystemExit(f"cannot serve on {port}: {err.__cause__}") from None
        where = str(args.pty) if pair else args.serial
        serve_until_signalled(sim, banner(where) + personality_text(sim, args))
    finally:
        sim.stop()
        if pair is not None:
            pair.close()
        for log in logs:
            log.close()
