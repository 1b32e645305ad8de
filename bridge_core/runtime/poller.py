"""The poll loop every bridge shares, in plain Python (clock injectable, no rclpy).

What it owns (docs/architecture.md, "The read path"):

- pacing: one poll per period, never bursting to catch up after an overrun;
- the "may attempt" guard: a device that is down is probed only when its reconnect
  backoff has elapsed, and ``link_up`` runs before the first poll after a (re)connect;
- outcomes: a ``PollIncomplete`` skips one cycle; a device exception (the device answered,
  but refused part of the poll) makes the device re-derive its plan from its configuration
  (R6: re-read the axis and board counts, §3.1.8) instead of failing forever; a lost
  link is reported once per loss; any other error is reported and never ends the loop;
- the link's "up": a good poll confirms it to the channel's ``LinkState``, which owns the
  up/down state and tells its listeners (this poller's reports among them) each edge,
  whichever transaction (a poll, a command, a stop) lost the link;
- the hand-off to the publisher thread: the newest snapshots wait in a short queue
  (the oldest is dropped when the publisher falls behind), so building and publishing the
  messages overlaps the device's time to answer the next request.

How a device reads its registers (``read_blocks``, ``read_named``) is ``bridge_core.runtime.reads``:
the device modules import that, and only the node side imports this module.
"""

from __future__ import annotations

import contextlib
import enum
import queue
import threading
import time
import traceback
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Generic, Protocol, TypeVar

from ..wire.errors import DeviceException, LinkError, PollIncomplete
from ..wire.link_state import LinkEvent, LinkState
from .diagnostics import RateTracker
from .reads import read_splits

Snapshot = TypeVar("Snapshot")
PUBLISH_BACKLOG = 8  # snapshots waiting for the publisher before the oldest is dropped
PUBLISH_WAIT_S = 0.1  # how often the idle publisher thread looks at its stop flag
THREAD_JOIN_S = 5.0
POLL_RATE_MIN_HZ = 0.01
# A failure the loop reported already (same type and text) is said again at most this
# often, one line with its count and without its traceback (printed the first time only).
REPEAT_REPORT_S = 5.0
# Failures remembered for that (the oldest forgotten first): a bounded set.
FAILURES_REMEMBERED = 64


class PollOutcome(enum.Enum):
    SKIPPED = "skipped"  # backing off a device that is down
    PUBLISHED = "published"
    INCOMPLETE = "incomplete"  # no consistent snapshot this cycle (e.g. re-planned)
    REFUSED = "refused"  # the device answered a poll request with an exception
    SPLIT = "split"  # a merged read the device refused is read in parts from now on
    LINK_LOST = "link lost"
    # Reports only (tick() returns LINK_LOST for these too):
    UNREACHABLE = "unreachable"  # the first failure of a device never reached
    STILL_DOWN = "still down"  # each further failed attempt while it is down
    FAILED = "failed"  # an unexpected error (a bug, a value no message holds)


class PollChannel(Protocol):
    """What the poller needs of a ``DeviceChannel``."""

    @property
    def connected(self) -> bool: ...
    @property
    def link_state(self) -> LinkState: ...
    def may_attempt(self) -> bool: ...
    def command_session(self, *, probe: bool = False) -> AbstractContextManager[int]: ...


def next_deadline(deadline: float, now: float, period_s: float) -> float:
    """The next poll time: one period on, or now after an overrun (never a burst)."""
    deadline += period_s
    return now if deadline <= now else deadline


class Poller(Generic[Snapshot]):
    """Polls a device on its own thread and hands snapshots to a publisher thread."""

    def __init__(
        self,
        channel: PollChannel,
        poll: Callable[[], Snapshot],
        publish: Callable[[Snapshot], None],
        *,
        rate_hz: float,
        link_up: Callable[[], None] = lambda: None,
        replan: Callable[[], None] = lambda: None,
        report: Callable[[PollOutcome, str], None] = lambda _outcome, _text: None,
        name: str = "bridge",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.channel = channel
        self._poll = poll
        self._publish = publish
        self._link_up = link_up
        self._replan = replan
        self._report = report
        self._clock = clock
        self.rate_hz = rate_hz
        self.rate = RateTracker(clock=clock)
        self.failures = 0
        self.snapshots_dropped = 0
        self.last_error: str | None = None
        # Each failure reported: (type, text) -> [when it was last said, repeats since].
        self._failures_said: dict[tuple[str, str], list[float]] = {}
        self._unsubscribe = channel.link_state.add_listener(self._link_changed)
        self._snapshots: queue.Queue[Snapshot] = queue.Queue(maxsize=PUBLISH_BACKLOG)
        self._stop = threading.Event()
        self._wake = threading.Event()
        # Polls run only while active (a lifecycle node's "active" state); a tick holds
        # _tick_lock, so pause() returns once no poll is under way any more.
        self._active = threading.Event()
        self._active.set()
        self._tick_lock = threading.Lock()
        self._threads = [
            threading.Thread(target=self._poll_loop, name=f"{name}-poll", daemon=True),
            threading.Thread(target=self._publish_loop, name=f"{name}-publish", daemon=True),
        ]

    @property
    def rate_hz(self) -> float:
        return self._rate_hz

    @rate_hz.setter
    def rate_hz(self, value: float) -> None:
        """Live: the loop takes the new period from its next cycle on."""
        if not value >= POLL_RATE_MIN_HZ:  # also refuses NaN
            raise ValueError(f"poll rate {value} Hz is below {POLL_RATE_MIN_HZ}")
        self._rate_hz = float(value)
        with contextlib.suppress(AttributeError):  # not yet during __init__
            self._wake.set()

    # ------------------------------------------------------------ one cycle
    def tick(self) -> PollOutcome:
        """One poll attempt; its snapshot (if any) goes to the publisher's queue."""
        if not self.channel.may_attempt():
            return PollOutcome.SKIPPED
        state = self.channel.link_state
        losses = state.losses
        try:
            # Link-up work once per connection, also when a command (a stop sent while
            # the link was down) reconnected it between two polls.
            if state.link_up_due:
                self._link_up()
            # A poll stops at its next request once the link is marked down after it began
            # (a command or a stop failed meanwhile): what the link sends first when it is
            # back is then the link-up work (pending stops first), not the poll's rest. A
            # poll that starts while the link is down is the probe that may reconnect it.
            with self.channel.command_session(probe=not self.channel.connected) as session:
                snapshot = self._poll()
        except PollIncomplete as err:
            self._report(PollOutcome.INCOMPLETE, str(err))
            return PollOutcome.INCOMPLETE
        except DeviceException as err:
            # The device is there but refused part of the poll: its configuration may
            # have changed (fewer axes, a board removed). Re-derive the plan from it.
            self.failures += 1
            self.last_error = f"poll refused by the device: {err}"
            self._replan()
            self._report(PollOutcome.REFUSED, self.last_error)
            return PollOutcome.REFUSED
        except LinkError as err:
            self.failures += 1
            self.last_error = str(err)
            # Down already if the channel saw the fault; a reply too short is a loss too.
            state.lose(str(err))
            if state.losses == losses:  # no loss announced since this poll began
                self._report(PollOutcome.STILL_DOWN, str(err))
            return PollOutcome.LINK_LOST
        except Exception as err:  # a device fault must never end the loop
            self.failures += 1
            self.last_error = f"poll failed: {err}"
            self._report_failure(err, self.last_error)
            return PollOutcome.FAILED
        for news in read_splits(self.channel).news():
            self._report(PollOutcome.SPLIT, news)
        # Up (announced once per connection), unless a command lost the link after the
        # poll's last reply: then its loss stands, and the next poll probes.
        state.confirm(session)
        self.last_error = None
        self.rate.tick()
        self._hand_off(snapshot)
        return PollOutcome.PUBLISHED

    def _report_failure(self, err: Exception, text: str) -> None:
        """A FAILED report: the first of its kind with its traceback (what a bug report
        needs), a repeat as one line at most every ``REPEAT_REPORT_S`` with its count
        (a poll failing every cycle must not print a traceback ten times a second)."""
        key = (type(err).__name__, text)
        now = self._clock()
        said = self._failures_said.get(key)
        if said is None:
            if len(self._failures_said) >= FAILURES_REMEMBERED:
                self._failures_said.pop(next(iter(self._failures_said)))
            self._failures_said[key] = [now, 0]
            self._report(PollOutcome.FAILED, f"{text}\n{traceback.format_exc()}")
            return
        said[1] += 1
        if now - said[0] >= REPEAT_REPORT_S:
            self._report(PollOutcome.FAILED, f"{text} (again, {int(said[1])} time(s) since)")
            said[0], said[1] = now, 0

    def _link_changed(self, event: LinkEvent, text: str) -> None:
        """The channel's link went down (a poll's, a command's or a stop's failure):
        reported once per loss, as LINK_LOST (it was up) or UNREACHABLE (never up yet);
        each further failed poll while it is down is a STILL_DOWN (the node throttles
        those)."""
        if event is LinkEvent.LOST:
            self._report(PollOutcome.LINK_LOST, text)
        elif event is LinkEvent.UNREACHABLE:
            self._report(PollOutcome.UNREACHABLE, text)

    def _hand_off(self, snapshot: Snapshot) -> None:
        try:
            self._snapshots.put_nowait(snapshot)
        except queue.Full:  # the publisher fell behind: drop the oldest, keep the newest
            with contextlib.suppress(queue.Empty):
                self._snapshots.get_nowait()
                self.snapshots_dropped += 1
            with contextlib.suppress(queue.Full):
                self._snapshots.put_nowait(snapshot)

    def publish_pending(self, wait_s: float = 0.0) -> int:
        """Publish the queued snapshots (the publisher thread; tests call it directly)."""
        published = 0
        while True:
            try:
                snapshot = (
                    self._snapshots.get(timeout=wait_s)
                    if wait_s and not published
                    else self._snapshots.get_nowait()
                )
            except queue.Empty:
                return published
            if not self._active.is_set():
                continue  # paused meanwhile: nothing more is published
            try:
                self._publish(snapshot)
            except Exception as err:  # a value the message cannot hold must not kill it
                self.last_error = f"publishing failed: {err}"
                self._report_failure(err, self.last_error)
            published += 1

    # ------------------------------------------------------------ threads
    def start(self) -> None:
        if self._stop.is_set():
            return
        for thread in self._threads:
            if not thread.is_alive():
                thread.start()

    def stop(self, join_s: float = THREAD_JOIN_S) -> None:
        """Stop both threads; returns once they ended (or ``join_s`` passed)."""
        self._stop.set()
        self._wake.set()
        self._unsubscribe()
        for thread in self._threads:
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(join_s)

    @property
    def running(self) -> bool:
        return any(thread.is_alive() for thread in self._threads)

    @property
    def active(self) -> bool:
        return self._active.is_set()

    def pause(self) -> None:
        """No more polls (and nothing more published) until ``resume``; returns once a
        poll under way has ended. Snapshots not yet published are dropped."""
        self._active.clear()
        self._wake.set()
        with self._tick_lock:
            while True:
                try:
                    self._snapshots.get_nowait()
                except queue.Empty:
                    break

    def resume(self) -> None:
        self._active.set()
        self._wake.set()

    def _poll_loop(self) -> None:
        deadline = self._clock()
        while not self._stop.is_set():
            if not self._active.is_set():
                self._wake.clear()
                self._wake.wait(THREAD_JOIN_S)
                deadline = self._clock()
                continue
            with self._tick_lock:
                if self._active.is_set():
                    self.tick()
            deadline = next_deadline(deadline, self._clock(), 1.0 / self._rate_hz)
            delay = deadline - self._clock()
            if delay > 0:
                self._wake.clear()
                if self._wake.wait(delay):  # woken: stop, or a new rate
                    deadline = self._clock()

    def _publish_loop(self) -> None:
        while not self._stop.is_set():
            self.publish_pending(PUBLISH_WAIT_S)


__all__ = ["PollOutcome", "Poller", "next_deadline"]
