"""Diagnostic bookkeeping in plain Python (the node base turns it into DiagnosticStatus).

Modelled on diagnostic_updater: a hardware id, OK / WARN / ERROR / STALE levels, a
frequency status over a sliding window, and key-value pairs a technician can read.
"""

from __future__ import annotations

import statistics
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import IntEnum

from ..wire.channel import DeviceChannel

RATE_WINDOW_S = 5.0
# Seconds between a node's /diagnostics statuses (``diagnostic_period_s``): once a second,
# as diagnostic_updater's default period.
DIAGNOSTIC_PERIOD_DEFAULT_S = 1.0
DIAGNOSTIC_PERIOD_RANGE_S = (0.05, 60.0)


class Level(IntEnum):
    """Same values as diagnostic_msgs/DiagnosticStatus."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


class RateTracker:
    """Events per second over a sliding window (diagnostic_updater's FrequencyStatus)."""

    def __init__(
        self, window_s: float = RATE_WINDOW_S, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.window_s = window_s
        self._clock = clock
        self._events: deque[float] = deque()
        self._started = clock()

    def tick(self) -> None:
        self._events.append(self._clock())

    def rate_hz(self) -> float:
        now = self._clock()
        while self._events and self._events[0] < now - self.window_s:
            self._events.popleft()
        span = min(self.window_s, now - self._started)
        return len(self._events) / span if span > 0 else 0.0


def percentile(samples: Iterable[float], fraction: float) -> float:
    data = sorted(samples)
    if not data:
        return float("nan")
    index = min(len(data) - 1, max(0, round(fraction * (len(data) - 1))))
    return data[index]


@dataclass
class Report:
    level: Level
    message: str
    values: list[tuple[str, str]] = field(default_factory=list)


def link_report(
    channel: DeviceChannel,
    *,
    poll_rate: RateTracker,
    target_rate_hz: float,
    poll_failures: int,
) -> Report:
    """The link part of a bridge's diagnostics."""
    stats = channel.stats
    latencies = list(stats.latencies_s)
    connected = channel.connected
    values = [
        ("link", channel.describe()),
        ("link state", "connected" if connected else "disconnected"),
        ("target poll rate (Hz)", f"{target_rate_hz:.2f}"),
        ("achieved poll rate (Hz)", f"{poll_rate.rate_hz():.2f}"),
        ("transaction latency p50 (ms)", _ms(statistics.median(latencies)) if latencies else "n/a"),
        ("transaction latency p99 (ms)", _ms(percentile(latencies, 0.99)) if latencies else "n/a"),
        ("transaction latency max (ms)", _ms(max(latencies)) if latencies else "n/a"),
        ("transactions", str(stats.transactions)),
        ("timeouts", str(stats.timeouts)),
        ("exception responses", str(stats.exceptions)),
        ("CRC / frame errors", str(stats.frame_errors)),
        ("reconnects", str(stats.reconnects)),
        ("failed connects", str(stats.connect_failures)),
        ("failed polls", str(poll_failures)),
        ("reconnect backoff (s)", f"{channel.backoff.delay_s:.2f}"),
        ("last error", stats.last_error or "none"),
    ]
    if not channel.link.is_serial:
        pipelining = channel.pipelining
        values.append(("max in flight", f"{pipelining.window} (asked {pipelining.max_in_flight})"))
        values.append(("pipelining fallbacks", str(pipelining.fallbacks)))
    if connected:
        return Report(Level.OK, "connected", values)
    message = "disconnected"
    if stats.last_error:
        message += f": {stats.last_error}"
    return Report(Level.ERROR, message, values)


def _ms(seconds: float) -> str:
    return f"{seconds * 1000.0:.3f}"
