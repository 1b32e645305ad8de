"""The link policy, without pymodbus: what a device model needs and how a device is served.

- ``RegisterIO``: the Modbus operations a device model (``device.py``) uses, so device
  modules stay free of pymodbus and can be driven by ``DeviceChannel`` or by any fake.
- ``PriorityLock``: one transaction at a time on a link, commands before polls, FIFO within
  a priority (so several drives on one bus take turns fairly).
- ``DeviceChannel``: one unit id on a ``Transport`` (``bridge_core.wire.transport.ModbusLink``),
  with its own health, capped exponential reconnect ``Backoff`` and ``LinkStats``, so a dead
  drive on a shared RS-485 bus backs off on its own while the others keep their rate. It
  owns the device's ``LinkState`` (``bridge_core.wire.link_state``): every transaction updates
  it, and its listeners hear when the link goes up or down.

Nothing here imports pymodbus or ``bridge_core.wire.transport``; errors arrive already
translated into ``bridge_core.wire.errors`` types.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from enum import IntEnum
from typing import Any, Protocol

from .batches import Pipelining, run_batch
from .errors import DeviceException, FrameError, LinkDown, LinkError, LinkTimeout, NotSent
from .link_state import LinkState
from .link_stats import Backoff, LinkStats, WireTally
from .registers import Table
from .requests import (
    BROADCAST_UNIT,
    MaskWriteRegister,
    ReadBits,
    ReadRegisters,
    ReadWriteRegisters,
    Reply,
    Request,
    Span,
    WriteCoil,
    WriteCoils,
    WriteRegister,
    WriteRegisters,
    written_span,
)

# First reconnect delay; it doubles per failure up to the node's reconnect_max_s.
RECONNECT_INITIAL_S = 0.25
# Frame times kept per read request (a poll repeats the same few reads; writes vary).
FRAME_TIME_CACHE = 256
UNIT_ID_MIN = 0
UNIT_ID_MAX = 247


class Priority(IntEnum):
    """Who goes first on a link (``PriorityLock``): watchdog feeds, stops, commands, polls.

    A feed goes before commands so that the longest it can wait for the line is one
    transaction per device on the link (the bound ``lifeguard_ms`` is checked against);
    it is one short write to a live device, so a stop waits a few ms for it at most.
    A stop goes in the next free slot, before other devices' commands and polls: on a
    shared line it waits for the one transaction in progress (a probe of a device that is
    down included: it waits the link's timeout, so that a late device is found again) and
    any feeds.
    """

    KEEPALIVE = 0
    STOP = 1
    COMMAND = 2
    POLL = 3


class RegisterIO(Protocol):
    """The Modbus operations a device model uses (``DeviceChannel``)."""

    def read_registers(
        self, address: int, count: int, table: Table = ..., priority: Priority = ...
    ) -> list[int]: ...
    def read_bits(
        self, address: int, count: int, table: Table = ..., priority: Priority = ...
    ) -> list[bool]: ...
    def write_register(self, address: int, value: int, priority: Priority = ...) -> None: ...
    def write_registers(self, address: int, values: Sequence[int]) -> None: ...
    def write_coil(self, address: int, on: bool, priority: Priority = ...) -> None: ...
    def write_coils(self, address: int, values: Sequence[bool]) -> None: ...
    def mask_write_register(self, address: int, and_mask: int, or_mask: int) -> None: ...
    def read_write_registers(
        self, read_address: int, read_count: int, write_address: int, values: Sequence[int]
    ) -> list[int]: ...


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

    def waiting_before(self, priority: Priority) -> bool:
        """Whether a caller of higher priority than ``priority`` waits (a pipelined batch
        sends no further request then: ``batches``)."""
        with self._cond:
            return bool(self._waiting) and self._waiting[0][0] < priority

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


class Transport(Protocol):
    """The link a ``DeviceChannel`` runs on (``bridge_core.wire.transport.ModbusLink``).

    ``execute`` raises only ``bridge_core.wire.errors`` types: ``LinkDown`` (not open, refused,
    lost), ``LinkTimeout`` (no reply), ``FrameError`` (a reply that is not the answer) and
    ``DeviceException`` (the device answered with an exception).
    """

    @property
    def lock(self) -> PriorityLock: ...
    @property
    def is_serial(self) -> bool: ...
    @property
    def is_open(self) -> bool: ...
    def describe(self) -> str: ...
    def open(self) -> None: ...
    def close(self) -> None: ...
    def execute(self, unit_id: int, request: Request, timeout_s: float | None = None) -> Reply: ...
    def frame_time_s(self, request: Request) -> float: ...


class DeviceChannel:
    """One device (unit id) on a link: transactions, health and reconnect policy."""

    def __init__(
        self,
        link: Transport,
        unit_id: int,
        *,
        retries: int = 1,
        reconnect_max_s: float = 5.0,
        down_write_timeout_s: float | None = None,
        max_in_flight: int = 1,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``max_in_flight``: reads of one batch (``transact_many``) sent before the first
        reply, on a link that can pipeline (TCP); 1 sends one request at a time."""
        if not UNIT_ID_MIN <= unit_id <= UNIT_ID_MAX:
            raise ValueError(f"unit id {unit_id} outside {UNIT_ID_MIN}..{UNIT_ID_MAX}")
        self.link = link
        self.unit_id = unit_id
        self.retries = retries
        # Reply timeout of a write (a stop, a watchdog feed) or a stop-priority request to
        # a device marked down: a stop repeated while the line is dead must not be the one
        # still waiting out a long timeout when the line comes back (None: the link's
        # timeout). A read that looks for the device again waits the link's timeout: a
        # device answering later than this short wait would never be found. On a shared
        # line a stop may so wait for one probe of an absent device, once per reconnect
        # period of that device (docs/behaviour.md, "Link loss and stale data").
        self.down_write_timeout_s = down_write_timeout_s
        self.backoff = Backoff(RECONNECT_INITIAL_S, reconnect_max_s, clock)
        self.stats = LinkStats()
        self.link_state = LinkState()
        self._session = threading.local()
        # When each thread's last reply arrived (``replied_at``): taken under the link lock.
        self._replied = threading.local()
        self._write_listeners: list[Callable[[Span], None]] = []
        self._frame_times: dict[Request, float] = {}
        self.pipelining = Pipelining(max_in_flight)

    def add_write_listener(self, listener: Callable[[Span], None]) -> Callable[[], None]:
        """``listener(span)`` for every write put on the wire (landed or not), under the
        link lock: it must not transact (a device's slow group marks itself due)."""
        self._write_listeners.append(listener)

        def remove() -> None:
            if listener in self._write_listeners:
                self._write_listeners.remove(listener)

        return remove

    @property
    def wire(self) -> WireTally:
        """What this device's transactions cost the wire (``runtime.wire_budget``)."""
        return self.stats.wire

    @property
    def connected(self) -> bool:
        """True while the device's last transaction succeeded (or answered an exception)."""
        return self.link_state.connected

    @property
    def generation(self) -> int:
        """Bumped each time the device comes up (by a poll, or by a stop sent while down)."""
        return self.link_state.generation

    def may_attempt(self) -> bool:
        """Whether a poll should try the device now (connected, or backoff elapsed)."""
        return self.link_state.connected or self.backoff.ready()

    @contextmanager
    def labelled(self, what: str) -> Iterator[None]:
        """Name this thread's transactions: a loss they cause is announced as ``what: error``
        (the node names each command so)."""
        outer = getattr(self._session, "label", None)
        self._session.label = what
        try:
            yield
        finally:
            self._session.label = outer

    @contextmanager
    def command_session(self, *, probe: bool = False) -> Iterator[int]:
        """Tie this thread's transactions to the connection they started on.

        Inside it, every transaction is refused (``LinkDown``, nothing sent) once the
        device was marked down after the session began, even if a poll has reconnected
        since: nothing is queued across a reconnect
        (docs/architecture.md, "The write path"). The node's command guard wraps each
        command in one, the poller each poll that starts on a live link (its rest is not
        sent once a command lost the link); stops run outside.

        ``probe``: for a poll that starts while the device is down: its transactions may
        reconnect, but are refused once the device is marked down again after the session
        began (a stop that failed meanwhile is pending, and goes first on the next try).

        Yields the epoch it began on: a poll that got through confirms the link with it
        (``LinkState.confirm``), which a loss since then refuses.
        """
        state = self.link_state
        epoch = state.epoch
        if probe:
            self._session.epoch = (epoch, False)
        else:
            self._session.epoch = (epoch if state.connected else -1, True)
        try:
            yield epoch
        finally:
            self._session.epoch = None

    def writes_tried(self) -> int:
        """Writes this thread has put on the wire through this channel (a counter: a
        command compares it before and after, to say whether anything of it went out)."""
        return int(getattr(self._session, "writes", 0))

    def mark_down(self, error: LinkError | str) -> None:
        """The device failed on the link: down (its listeners hear of a loss), backing off."""
        text = str(error)
        self.stats.last_error = text
        self.stats.last_error_time = time.time()
        if self.link_state.connected or self.backoff.ready():
            self.backoff.failed()
        if not self.link.is_serial:
            # TCP: drop the socket so a late reply cannot be taken for the next answer.
            self.link.close()
        label = getattr(self._session, "label", None)
        self.link_state.went_down(f"{label}: {text}" if label else text)

    def transact(self, request: Request, priority: Priority = Priority.POLL) -> Reply:
        """Run one request; reads are retried ``retries`` times, writes never are.

        Nor are probes of a device that is down: on a shared RS-485 bus every retry of a
        dead drive holds the bus for another timeout while the live drives wait. Each
        attempt takes the link lock on its own, so a feed or a command that queued up
        meanwhile goes between a failed attempt and its retry: no request ever waits for
        more than one timeout of another device.
        """
        attempts = 1 if request.is_write or not self.link_state.connected else 1 + self.retries
        last: LinkError = LinkDown("no attempt made")
        for attempt in range(attempts):
            outcome = self._attempt(request, priority, final=attempt == attempts - 1)
            if not isinstance(outcome, LinkError):
                return outcome
            last = outcome
            if isinstance(outcome, LinkDown):
                break
        raise last

    def _attempt(self, request: Request, priority: Priority, *, final: bool) -> Reply | LinkError:
        """One try under the link lock: the reply, or the link error (the device is marked
        down after the ``final`` try fails, or at once if the link itself is down)."""
        lock = self.link.lock
        state = self.link_state
        lock.acquire(priority)  # acquire/release, not a context manager: the poll hot path
        try:
            self.check_session()
            try:
                if not self.link.is_open:
                    try:
                        self.link.open()
                    except LinkDown as err:
                        raise NotSent(str(err)) from err
                started = time.perf_counter()
                if request.is_write:  # on the wire from here on, whatever comes back
                    self._session.writes = self.writes_tried() + 1
                    span = written_span(request)
                    if span is not None:
                        for listener in tuple(self._write_listeners):
                            listener(span)
                if (
                    not state.connected
                    and self.down_write_timeout_s
                    and self._short(request, priority)
                ):
                    reply = self.link.execute(self.unit_id, request, self.down_write_timeout_s)
                else:
                    reply = self.link.execute(self.unit_id, request)
            except DeviceException as err:
                # The device is alive and said no: not a link failure.
                self.stats.exceptions += 1
                self.stats.last_error = str(err)
                self.stats.last_error_time = time.time()
                self._note_alive()
                raise
            except (LinkTimeout, FrameError) as err:
                if isinstance(err, LinkTimeout):
                    self.stats.timeouts += 1
                else:
                    self.stats.frame_errors += 1
                if not self.link.is_serial:
                    self.link.close()
                if final:
                    self.mark_down(err)
                return err
            except LinkDown as err:
                self.stats.connect_failures += 1
                self.mark_down(err)
                return err
            self.note_reply()
            stats = self.stats
            stats.transactions += 1
            elapsed = time.perf_counter() - started
            stats.latencies_s.append(elapsed)
            if self.unit_id != BROADCAST_UNIT or not self.link.is_serial:  # else no reply
                stats.wire.note(self.frame_time_s(request), elapsed, priority is Priority.POLL)
            if not state.connected:
                self._note_alive()
            return reply
        finally:
            lock.release()

    def note_reply(self) -> None:
        """A reply to the calling thread's request arrived now (the link lock held)."""
        self._replied.at = time.time()

    def replied_at(self) -> float:
        """When the reply to the calling thread's last request arrived (wall clock; 0.0:
        none yet). Taken under the link lock, so it precedes whatever the next holder of
        the lock sends: a stop that goes between two reads of a poll comes after the first
        read's time, however late the polling thread looks at the clock."""
        return float(getattr(self._replied, "at", 0.0))

    @staticmethod
    def _short(request: Request, priority: Priority) -> bool:
        """Whether a request to a device marked down waits only ``down_write_timeout_s``:
        writes (a stop, a feed) and anything at stop priority or above do; a read that
        looks for the device again (a probe, the start-up configuration read) waits the
        link's timeout, or a device that answers later than the short wait is never
        found (stepper at 35-300 ms with ``timeout_s`` 0.5)."""
        return request.is_write or priority <= Priority.STOP

    def check_session(self) -> None:
        """Under the link lock: ``NotSent`` if this thread's session (``command_session``)
        began on a connection that has been lost since."""
        session = getattr(self._session, "epoch", None)
        state = self.link_state
        if session is not None and (
            session[0] != state.epoch or (session[1] and not state.connected)
        ):
            raise NotSent(
                f"{self.describe()}: the link was lost while the command waited; not sent"
            )

    @property
    def pipelines(self) -> bool:
        """Whether ``transact_many`` would keep several reads in flight now (a TCP link,
        ``max_in_flight`` > 1, no fallback)."""
        return self.pipelining.window > 1 and bool(getattr(self.link, "can_pipeline", False))

    def transact_many(
        self,
        next_request: Callable[[], Request | None],
        on_reply: Callable[[int, Reply | DeviceException], None],
        priority: Priority = Priority.POLL,
    ) -> None:
        """Reads one after another, pipelined up to ``max_in_flight`` where the link can.

        ``next_request()`` gives the next read (None: no more); ``on_reply(index, outcome)``
        gets each answer (the values, or the ``DeviceException`` the device answered) with
        the index of its request in the order they were given, as they arrive (pipelined
        under the link lock, one at a time right after each ``transact``; ``replied_at``
        is the arrival time either way; it must not transact). One at a time
        (``max_in_flight`` 1, a serial link, after a fallback) it is exactly ``transact``
        for each; a link error raises as ``transact`` does. How a batch keeps stops first
        and falls back: ``batches``.
        """
        run_batch(self, next_request, on_reply, priority)

    def frame_time_s(self, request: Request) -> float:
        """The link's ``frame_time_s``, kept for reads (a poll sends the same ones again)."""
        if request.is_write:
            return self.link.frame_time_s(request)
        frame = self._frame_times.get(request)
        if frame is None:
            if len(self._frame_times) >= FRAME_TIME_CACHE:
                self._frame_times.clear()
            frame = self._frame_times[request] = self.link.frame_time_s(request)
        return frame

    def _note_alive(self) -> None:
        state = self.link_state
        if not state.connected:
            if state.ever_connected:
                self.stats.reconnects += 1
            state.answered()
        self.backoff.succeeded()

    # Convenience wrappers, named after the Modbus functions they send.
    def read_registers(
        self,
        address: int,
        count: int,
        table: Table = Table.HOLDING,
        priority: Priority = Priority.POLL,
    ) -> list[int]:
        return _exactly(self.transact(ReadRegisters(address, count, table), priority), count)

    def read_bits(
        self,
        address: int,
        count: int,
        table: Table = Table.COIL,
        priority: Priority = Priority.POLL,
    ) -> list[bool]:
        # execute() made them bools already.
        return _exactly(self.transact(ReadBits(address, count, table), priority), count)

    def write_register(
        self, address: int, value: int, priority: Priority = Priority.COMMAND
    ) -> None:
        self.transact(WriteRegister(address, value), priority)

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        self.transact(WriteRegisters(address, tuple(values)), Priority.COMMAND)

    def write_coil(self, address: int, on: bool, priority: Priority = Priority.COMMAND) -> None:
        self.transact(WriteCoil(address, on), priority)

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


def _exactly(reply: object, count: int) -> list[Any]:
    """The first ``count`` values of a read's reply; a shorter reply is a FrameError.

    A longer one is cut: bits come padded to whole bytes, and a device may send more.
    """
    assert isinstance(reply, list)
    if len(reply) < count:
        raise FrameError(f"short reply: {len(reply)} of {count} values")
    return reply[:count]
