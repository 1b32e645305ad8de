"""How the TCP simulators serve a connection: requests in order, a simulated round trip.

Why: pymodbus 3.16's server handler decodes one frame per chunk it receives (a second
request in the same chunk waits for more data) and keeps a single "last request" that a
request arriving meanwhile overwrites, so it loses pipelined requests. ``InOrderHandler``
decodes every whole frame of a chunk, queues them, and answers them one after another in
arrival order, as a device that reads its socket in order does.

Two switches of ``serving.Simulator`` shape it, both live:

- ``round_trip_s`` (``--reply-delay-ms MIN[:MAX]``): a simulated network round trip, half
  on the way in, half on the way out, drawn per request in the range. Each direction is a
  FIFO whose items are released at their arrival time plus the half: requests in flight
  overlap (it does not serialize them), and the order is kept.
- ``nagle`` (``--nagle``): the device leaves Nagle's algorithm on.
- ``one_request_at_a_time`` (``--one-request-at-a-time``): a device that does not
  pipeline: a request arriving while one is unanswered is dropped (and logged in
  ``Simulator.dropped``), so a pipelining client times out and falls back.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from collections.abc import Callable
from typing import Any, Protocol

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException, NoSuchIdException
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.transaction import TransactionManager


class ServedSimulator(Protocol):
    """The switches and records of ``serving.Simulator`` a connection uses, named here so
    serving imports this module and never the other way round."""

    @property
    def nagle(self) -> bool: ...

    @property
    def one_request_at_a_time(self) -> bool: ...

    @property
    def connections_nodelay(self) -> list[bool]: ...

    @property
    def dropped(self) -> list[tuple[float, int]]: ...

    def round_trip(self) -> float: ...


class _Delayed:
    """A FIFO that hands each item on ``delay()`` seconds after it was put (in order)."""

    def __init__(self, deliver: Callable[[Any], None], delay: Callable[[], float]) -> None:
        self._deliver = deliver
        self._delay = delay
        self._queue: asyncio.Queue[tuple[float, Any]] = asyncio.Queue()
        self._pending = 0  # put and not yet handed on (one may be out of the queue)
        self._task = asyncio.get_running_loop().create_task(self._run())

    def put(self, item: Any) -> None:
        delay = self._delay()
        if delay <= 0 and not self._pending:
            self._deliver(item)
            return
        self._pending += 1
        self._queue.put_nowait((time.monotonic() + delay, item))

    async def _run(self) -> None:
        while True:
            due, item = await self._queue.get()
            wait = due - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            self._pending -= 1
            self._deliver(item)

    def cancel(self) -> None:
        self._task.cancel()


class InOrderHandler(ServerRequestHandler):
    """One client connection of a TCP simulator (see the module's docstring)."""

    def __init__(self, owner: Any, sim: ServedSimulator) -> None:
        super().__init__(  # type: ignore[no-untyped-call]  # untyped in pymodbus 3.16
            owner, owner.trace_packet, owner.trace_pdu, owner.trace_connect
        )
        self._sim = sim
        self._unanswered = 0
        self._requests: asyncio.Queue[tuple[ModbusPDU, Any]] | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._inbound: _Delayed | None = None
        self._outbound: _Delayed | None = None

    def _half_trip(self) -> float:
        return self._sim.round_trip() / 2

    def _start(self) -> None:
        if self._requests is None:
            self._requests = asyncio.Queue()
            self._tasks.append(asyncio.get_running_loop().create_task(self._answer_in_order()))
            self._inbound = _Delayed(self._arrived, self._half_trip)
            self._outbound = _Delayed(self._put_on_wire, self._half_trip)

    def callback_connected(self) -> None:
        """``--nagle``: asyncio turns Nagle's algorithm off on every TCP socket
        (TCP_NODELAY); a device that leaves it on holds a small reply while an earlier
        segment of its own is not acknowledged yet."""
        super().callback_connected()
        sock = None if self.transport is None else self.transport.get_extra_info("socket")
        if sock is not None:
            if self._sim.nagle:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 0)
            nodelay = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
            self._sim.connections_nodelay.append(bool(nodelay))

    def callback_data(self, data: bytes, addr: tuple[Any, ...] | None = None) -> int:
        """Every whole frame of ``data``, on its way to the device; the bytes used."""
        self._start()
        assert self._inbound is not None
        used = 0
        while used < len(data):
            try:
                length = TransactionManager.callback_data(self, data[used:], addr)
            except ModbusIOException as exc:  # as pymodbus's handler answers it
                function_code = 0x00 if exc.fcode is None else exc.fcode
                response = ExceptionResponse(
                    function_code,
                    exception_code=ExcCodes.ILLEGAL_FUNCTION,
                    device_id=exc.dev_id,
                    transaction=exc.transaction_id,
                )
                self._outbound_send(response, addr)
                return len(data)
            if not length:
                break
            used += length
            if self.last_pdu is not None:
                self._inbound.put((self.last_pdu, addr))
        return used

    def _arrived(self, item: tuple[ModbusPDU, Any]) -> None:
        """A request reached the device (after the way in)."""
        assert self._requests is not None
        if self._sim.one_request_at_a_time and self._unanswered:
            self._sim.dropped.append((time.time(), int(item[0].transaction_id)))
            return
        self._unanswered += 1
        self._requests.put_nowait(item)

    async def _answer_in_order(self) -> None:
        assert self._requests is not None
        while True:
            pdu, addr = await self._requests.get()
            try:
                response = await self._answer(pdu)
            finally:
                self._unanswered -= 1
            if response is not None:
                self._outbound_send(response, addr)

    async def _answer(self, pdu: ModbusPDU) -> ModbusPDU | None:
        """pymodbus's ``handle_request`` for one given request (not ``last_pdu``)."""
        try:
            response = await pdu.datastore_update(self.server.context, pdu.dev_id)
        except NoSuchIdException:
            return None  # ignore_missing_devices: silent, like a device not addressed
        except Exception:  # the datastore failed: what pymodbus answers
            response = ExceptionResponse(pdu.function_code, ExcCodes.DEVICE_FAILURE)
        response.transaction_id = pdu.transaction_id
        response.dev_id = pdu.dev_id
        return response

    def _outbound_send(self, response: ModbusPDU, addr: Any) -> None:
        packet = self.framer.buildFrame(response)
        if self._outbound is None:
            self._put_on_wire((packet, addr))
        else:
            self._outbound.put((packet, addr))

    def _put_on_wire(self, item: tuple[bytes, Any]) -> None:
        if self.transport is not None:
            with contextlib.suppress(Exception):
                self.send(*item)

    def callback_disconnected(self, exc: Exception | None) -> None:
        for task in self._tasks:
            task.cancel()
        for fifo in (self._inbound, self._outbound):
            if fifo is not None:
                fifo.cancel()
        super().callback_disconnected(exc)


__all__ = ["InOrderHandler"]
