"""The simulators' server: a real pymodbus server for one or more ``SimulatedDevice``
units, run on a background thread (``Simulator``).

The datastore plugs into pymodbus 3.16 as an "old simulator" ``ModbusServerContext``
(the server then calls ``async_getValues``/``async_setValues`` on it directly), which
gives async hooks for reply delays and withheld replies. Function codes a unit lacks are
refused (``FC|0x80, 0x01``, over TCP and RTU alike: ``strict_decoding``); a multi-drop
server stays silent for unit ids it does not own, as an RS-485 device does. Pinned: see
docs/architecture.md, "pymodbus pitfalls we work around".
"""

from __future__ import annotations

import asyncio
import random
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.transport import serialtransport as _serialtransport

from ..wire.serial_port import open_serial
from .logs import WriteRecord
from .rtu_framing import slave_framer
from .sim_base import FUNCTION_TABLES, SimulatedDevice
from .strict_decoding import strict_decoder
from .tcp_serving import InOrderHandler

TICK_S = 0.01
ECHO_FUNCTIONS = frozenset({5, 6})


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
