"""bridge_core.runtime.keepalive: the watchdog feeder thread (no ROS, real threads)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from bridge_core.runtime.keepalive import Keepalive

WAIT_S = 10.0


def wait_until(predicate: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.002)


class Watchdog:
    """A device whose next feed is due ``period_s`` after its last write."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.armed = True
        self.feeds: list[float] = []
        self.asked = 0
        self.errors: list[Exception] = []
        self.fail_next = False
        self.lock = threading.Lock()

    def next_feed(self) -> float | None:
        with self.lock:
            self.asked += 1
            if not self.armed:
                return None
            # Never fed: due now (not at 0 + period on the monotonic clock, which is in
            # the future on a machine up for less than a period).
            return self.feeds[-1] + self.period_s if self.feeds else time.monotonic()

    def feed(self) -> None:
        with self.lock:
            if self.fail_next:
                self.fail_next = False
                raise RuntimeError("the line is busy")
            self.feeds.append(time.monotonic())


def test_feeds_when_due_and_never_early() -> None:
    dog = Watchdog(0.05)
    keepalive = Keepalive("test", dog.next_feed, dog.feed, dog.errors.append)
    keepalive.start()
    try:
        wait_until(lambda: len(dog.feeds) >= 5, "five feeds")
    finally:
        keepalive.close()
    gaps = [later - earlier for earlier, later in zip(dog.feeds, dog.feeds[1:], strict=False)]
    assert min(gaps) >= 0.05 - 0.001, gaps  # a wait never ends before its time
    assert dog.errors == []


def test_nothing_to_feed_feeds_nothing_and_wake_looks_again_at_once() -> None:
    dog = Watchdog(0.05)
    dog.armed = False
    # A long idle check: only wake() can make the thread look again in time.
    keepalive = Keepalive("test", dog.next_feed, dog.feed, dog.errors.append, idle_check_s=60.0)
    keepalive.start()
    try:
        wait_until(lambda: dog.asked >= 1, "the thread asked once")
        assert dog.feeds == []
        with dog.lock:
            dog.armed = True
        keepalive.wake()
        wait_until(lambda: len(dog.feeds) >= 1, "a feed after wake()")
    finally:
        keepalive.close()


def test_a_failed_feed_is_reported_and_the_feeds_go_on() -> None:
    dog = Watchdog(0.02)
    dog.fail_next = True
    keepalive = Keepalive("test", dog.next_feed, dog.feed, dog.errors.append, idle_check_s=0.01)
    keepalive.start()
    try:
        wait_until(lambda: len(dog.feeds) >= 3, "feeds after the failure")
    finally:
        keepalive.close()
    assert [str(err) for err in dog.errors] == ["the line is busy"]


def test_close_ends_the_thread() -> None:
    dog = Watchdog(3600.0)
    keepalive = Keepalive("test-close", dog.next_feed, dog.feed, dog.errors.append)
    keepalive.start()
    wait_until(lambda: len(dog.feeds) == 1, "the first feed (never fed before)")
    keepalive.close()
    assert not any(t.name == "test-close" for t in threading.enumerate())
