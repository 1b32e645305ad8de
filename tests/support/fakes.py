"""Fakes the plain-Python unit tests share: one clock for the code that takes a
``clock: Callable[[], float]`` (the monotonic time it reads), set by hand; a channel and a
device for the poller (tests/core/runtime/test_poller.py, tests/modbus/test_round3.py); a
scripted transport under a real ``DeviceChannel`` (tests/core/wire, tests/core/runtime)."""

from __future__ import annotations

import contextlib
import threading

from bridge_core.wire.channel import PriorityLock
from bridge_core.wire.errors import DeviceException, LinkError, LinkTimeout
from bridge_core.wire.link_state import LinkState
from bridge_core.wire.requests import Reply, Request


class FakeClock:
    """A clock that stands still at ``now`` until a test moves it (``clock.now += 0.5``)."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


class FakeChannel:
    """may_attempt / connected / link_state as a DeviceChannel would report them."""

    def __init__(self) -> None:
        self.link_state = LinkState()
        self.backoff_elapsed = True

    @property
    def connected(self) -> bool:
        return self.link_state.connected

    @connected.setter
    def connected(self, up: bool) -> None:
        # As DeviceChannel: an answer, or a failure (a poll's or a command's).
        if up:
            self.link_state.answered()
        else:
            self.link_state.went_down("no reply")

    def command_session(self, *, probe: bool = False) -> contextlib.AbstractContextManager[int]:
        return contextlib.nullcontext(self.link_state.epoch)

    def may_attempt(self) -> bool:
        return self.connected or self.backoff_elapsed


class FakeDevice:
    """Raises the queued errors one poll at a time, else returns a counter snapshot."""

    def __init__(self, channel: FakeChannel) -> None:
        self.channel = channel
        self.errors: list[Exception] = []
        self.polls = 0
        self.link_ups = 0
        self.replans = 0

    def poll(self) -> int:
        self.polls += 1
        if self.errors:
            error = self.errors.pop(0)
            if isinstance(error, LinkError) and not isinstance(error, DeviceException):
                self.channel.connected = False  # as the channel marks it down
            raise error
        self.channel.connected = True
        return self.polls

    def link_up(self) -> None:
        self.link_ups += 1

    def replan(self) -> None:
        self.replans += 1


class ScriptedBus:
    """A Transport whose replies are scripted per unit: a value, an error to raise, or
    an Event to block on first (so a test can queue other requests behind one)."""

    def __init__(self) -> None:
        self.lock = PriorityLock()
        self.is_serial = True
        self.is_open = True
        self.executed: list[tuple[int, Request]] = []
        self.script: dict[int, list[object]] = {}
        self.entered = threading.Event()

    def describe(self) -> str:
        return "scripted bus"

    def open(self) -> None:
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def execute(self, unit_id: int, request: Request, timeout_s: float | None = None) -> Reply:
        self.executed.append((unit_id, request))
        script = self.script.get(unit_id)
        step = script.pop(0) if script else [0]
        if isinstance(step, threading.Event):
            self.entered.set()
            assert step.wait(10), "the test never let the request finish"
            raise LinkTimeout(f"unit {unit_id}: no reply")
        if isinstance(step, Exception):
            raise step
        return None if request.is_write else list(step)  # type: ignore[call-overload]

    def frame_time_s(self, request: object) -> float:
        return 0.0
