"""A channel's batches of reads: pipelined on TCP when asked, one at a time otherwise.

``DeviceChannel.transact_many`` runs here (pymodbus-free, like the channel). With
``max_in_flight`` N > 1 on a link that can pipeline (``ModbusLink.can_pipeline``: TCP) a
batch holds the link lock and keeps up to N reads in flight (``ModbusLink.send_pipelined``
/ ``receive_pipelined``, ``wire.pipeline``); otherwise it is ``transact`` for each read.
docs/architecture.md, "Pipelined Modbus TCP":

- Stops, feeds and commands keep their priority: before each further request the batch
  asks the lock whether a caller of higher priority waits; if one does it sends no more,
  collects the replies in flight, lets the waiter go, and takes the lock again for the
  rest. So a stop waits for the replies already in flight (about one round trip), never
  for the rest of the poll.
- The first failure while N > 1 (a reply that matches no request in flight, a timeout, a
  closed connection) ends pipelining for this channel: from then on it sends one request
  at a time, for as long as the channel lives (a node restart tries N again). A device
  that mishandles pipelining may do worse than drop a request, so the bridge does not
  keep probing it. The requests left unanswered are sent again one at a time at once
  (reads only: nothing is written twice), with the channel's usual retries and its
  rules for a lost link; the fallback is said once (``Pipelining.news``: the node WARNs)
  and counted (diagnostics "pipelining fallbacks").
- A batch starts pipelining only on an open connection to a device that answers; while
  it is down, the next read goes one at a time (probe, reconnect, backoff as ever).
- Wire budget (``WireTally.note``): each reply notes its own round trip (sent to
  answered) as the turnaround, and counts the share of it the wire spent on it alone:
  the time since the previous reply of the batch (or since it was sent, if later) over
  its round trip. A batch sent in one go thus counts about one round trip, a window of N
  over M reads about M / N.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from .errors import DeviceException, FrameError, LinkDown, LinkError, LinkTimeout, NotSent
from .requests import Reply, Request

if TYPE_CHECKING:
    from .channel import DeviceChannel, Priority

# ``max_in_flight``: 1 (one request at a time, the default) up to this. Sixteen covers a
# whole poll of every bridge (R6: 13 reads) and stays below what Modbus TCP devices and
# gateways commonly queue per connection.
MAX_IN_FLIGHT_RANGE = (1, 16)


class Pipelining:
    """One channel's pipelining: the window asked, whether it fell back, and news of it."""

    def __init__(self, max_in_flight: int = 1) -> None:
        low, high = MAX_IN_FLIGHT_RANGE
        if not low <= max_in_flight <= high:
            raise ValueError(f"max_in_flight {max_in_flight} outside {low}..{high}")
        self.max_in_flight = max_in_flight
        self.fallbacks = 0  # times pipelining was given up (diagnostics)
        self.fell_back = False
        self._news: list[str] = []
        self._lock = threading.Lock()

    @property
    def window(self) -> int:
        """Requests a batch may have in flight now."""
        return 1 if self.fell_back else self.max_in_flight

    def fall_back(self, where: str, error: LinkError) -> None:
        with self._lock:
            if self.fell_back:
                return
            self.fell_back = True
            self.fallbacks += 1
            self._news.append(
                f"{where}: pipelining ({self.max_in_flight} requests in flight) failed "
                f"({error}); sending one request at a time from now on (a restart tries "
                "again)"
            )

    def news(self) -> list[str]:
        """What to say since the last call (the fallback, once)."""
        with self._lock:
            news, self._news = self._news, []
        return news


class PipelinedLink(Protocol):
    """What a batch needs of a link beside ``channel.Transport`` (``ModbusLink``)."""

    @property
    def can_pipeline(self) -> bool: ...
    def send_pipelined(self, unit_id: int, request: Request) -> int: ...
    def receive_pipelined(self) -> tuple[int, Reply | DeviceException]: ...


Item = tuple[int, Request]  # a request and its index in the batch


class _Source:
    """The batch's requests in order: those given back first, then ``next_request``'s."""

    def __init__(self, next_request: Callable[[], Request | None]) -> None:
        self._next = next_request
        self._back: deque[Item] = deque()
        self._count = 0

    def take(self) -> Item | None:
        if self._back:
            return self._back.popleft()
        request = self._next()
        if request is None:
            return None
        self._count += 1
        return self._count - 1, request

    def give_back(self, items: list[Item]) -> None:
        self._back.extendleft(reversed(items))


_DONE = "done"
_YIELD = "yield"  # a caller of higher priority waits: release, take the lock again
_ONE = "one"  # not connected now: the next request one at a time


def run_batch(
    channel: DeviceChannel,
    next_request: Callable[[], Request | None],
    on_reply: Callable[[int, Reply | DeviceException], None],
    priority: Priority,
) -> None:
    """``DeviceChannel.transact_many`` (see the module's docstring)."""
    source = _Source(next_request)
    link = channel.link
    pipelined = bool(getattr(link, "can_pipeline", False))
    while True:
        if not pipelined or channel.pipelining.window <= 1:
            while (item := source.take()) is not None:
                _one(channel, item, on_reply, priority)
            return
        outcome = _hold(channel, source, on_reply, priority)
        if outcome == _DONE:
            return
        if outcome == _ONE:
            item = source.take()
            if item is None:
                return
            _one(channel, item, on_reply, priority)


def _one(
    channel: DeviceChannel,
    item: Item,
    on_reply: Callable[[int, Reply | DeviceException], None],
    priority: Priority,
) -> None:
    index, request = item
    try:
        reply = channel.transact(request, priority)
    except DeviceException as err:
        on_reply(index, err)
        return
    on_reply(index, reply)


def _hold(
    channel: DeviceChannel,
    source: _Source,
    on_reply: Callable[[int, Reply | DeviceException], None],
    priority: Priority,
) -> str:
    """One hold of the link lock with up to ``window`` reads in flight."""
    link: PipelinedLink = channel.link  # type: ignore[assignment]
    lock = channel.link.lock
    stats = channel.stats
    poll = priority.name == "POLL"
    in_flight: dict[int, tuple[int, Request, float]] = {}  # tag: index, request, sent at
    sending: Item | None = None
    last_arrival = 0.0
    calling = False
    lock.acquire(priority)
    try:
        channel.check_session()
        if not channel.link.is_open or not channel.link_state.connected:
            return _ONE
        window = channel.pipelining.window
        try:
            while True:
                while len(in_flight) < window:
                    if lock.waiting_before(priority):
                        break
                    sending = source.take()
                    if sending is None:
                        break
                    tag = link.send_pipelined(channel.unit_id, sending[1])
                    in_flight[tag] = (*sending, time.perf_counter())
                    sending = None
                if not in_flight:
                    return _YIELD if lock.waiting_before(priority) else _DONE
                tag, outcome = link.receive_pipelined()
                arrival = time.perf_counter()
                index, request, sent = in_flight.pop(tag)
                round_trip = arrival - sent
                own = arrival - max(sent, last_arrival)
                last_arrival = arrival
                stats.transactions += 1
                stats.latencies_s.append(round_trip)
                share = min(1.0, own / round_trip) if round_trip > 0 else 1.0
                stats.wire.note(channel.frame_time_s(request), round_trip, poll, share)
                if isinstance(outcome, DeviceException):
                    stats.exceptions += 1
                    stats.last_error = str(outcome)
                    stats.last_error_time = time.time()
                channel.note_reply()
                calling = True  # an error of the caller's is not the wire's
                on_reply(index, outcome)
                calling = False
        except (LinkTimeout, FrameError, LinkDown) as err:
            if isinstance(err, NotSent) or calling:
                if in_flight:
                    channel.link.close()
                raise
            if isinstance(err, LinkTimeout):
                stats.timeouts += 1
            elif isinstance(err, FrameError):
                stats.frame_errors += 1
            stats.last_error = str(err)
            stats.last_error_time = time.time()
            channel.link.close()  # the link did already; a late reply must find no socket
            channel.pipelining.fall_back(channel.describe(), err)
            unanswered = [(index, request) for index, request, _ in in_flight.values()]
            if sending is not None:
                unanswered.append(sending)
            source.give_back(sorted(unanswered, key=lambda item: item[0]))
            return _YIELD  # the rest one at a time (the window is 1 now)
        except BaseException:
            if in_flight:
                channel.link.close()  # replies in flight must not answer a later request
            raise
    finally:
        lock.release()


__all__ = ["MAX_IN_FLIGHT_RANGE", "PipelinedLink", "Pipelining", "run_batch"]
