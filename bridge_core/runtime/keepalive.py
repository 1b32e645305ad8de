"""A device watchdog fed from a thread of its own (the MOTEC lifeguard, §3.4).

Why a thread and not an rclpy timer: a timer callback waits for a free executor thread,
and under a command flood or a slow subscriber the executor runs late by more than a
watchdog's margin. This thread sleeps until the next feed is due, then waits only for the
link, where feeds go first (``Priority.KEEPALIVE``). So the longest gap between two feeds
is bounded by the feed period, ``FEED_WAKE_S`` and the line, which is what a watchdog time
is checked against (``motec_bridge.lifeguard.lifeguard_min_ms``).

Plain Python (no ROS): the owner says when the next feed is due and how to feed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

# Allowance for the feeding thread waking late plus the feed's own frame. A wake-up takes
# well under 10 ms on an idle host, but this is not a real-time OS: the scheduler, the GIL
# and a busy machine (measured with bench/lifeguard_gaps.py --burners 2) take their share.
FEED_WAKE_S = 0.1
# How often the thread looks again while nothing is to be fed (not armed, link down).
IDLE_CHECK_S = 0.05
JOIN_TIMEOUT_S = 5.0


class Keepalive:
    """Calls ``feed()`` whenever ``next_feed()`` (a ``clock()`` time, or None: nothing to
    feed now) has passed. ``feed`` errors go to ``on_error``; the thread never dies of one."""

    def __init__(
        self,
        name: str,
        next_feed: Callable[[], float | None],
        feed: Callable[[], None],
        on_error: Callable[[Exception], None],
        *,
        idle_check_s: float = IDLE_CHECK_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._next_feed = next_feed
        self._feed = feed
        self._on_error = on_error
        self._idle_check_s = idle_check_s
        self._clock = clock
        self._wake = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def wake(self) -> None:
        """Look at ``next_feed`` again now (the watchdog time or the link changed)."""
        self._wake.set()

    def close(self) -> None:
        self._closed = True
        self._wake.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(JOIN_TIMEOUT_S)

    def _run(self) -> None:
        while not self._closed:
            self._wake.clear()
            wait_s = self._idle_check_s
            due = self._next_feed()
            if due is not None:
                wait_s = due - self._clock()
                if wait_s <= 0:
                    try:
                        self._feed()
                    except Exception as err:  # reported; the feeds go on
                        self._on_error(err)
                        wait_s = self._idle_check_s
                    else:
                        # A feed that did not move the due time must not spin the thread.
                        wait_s = self._idle_check_s
                        due = self._next_feed()
                        if due is not None and due > self._clock():
                            wait_s = due - self._clock()
            if wait_s > 0:
                self._wake.wait(wait_s)


__all__ = ["FEED_WAKE_S", "IDLE_CHECK_S", "Keepalive"]
