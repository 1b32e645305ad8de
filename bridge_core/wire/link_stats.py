"""A channel's bookkeeping: reconnect backoff, counters, and what the wire carried.

Plain data beside ``channel.DeviceChannel`` (which writes them under its link lock and
re-exports them): ``Backoff`` (capped exponential delay between reconnects),
``LinkStats`` (diagnostics counters) and ``WireTally`` (the wire budget's input).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

LATENCY_SAMPLES = 512
# Turnarounds the wire budget takes its median of (a few seconds of polls at most).
TURNAROUND_SAMPLES = 64


class Backoff:
    """Capped exponential delay between reconnect attempts."""

    def __init__(
        self, initial_s: float, max_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.initial_s = min(initial_s, max_s)
        self.max_s = max_s
        self._clock = clock
        self.failures = 0
        self.next_attempt = 0.0

    @property
    def delay_s(self) -> float:
        if self.failures == 0:
            return 0.0
        return float(min(self.max_s, self.initial_s * 2 ** (self.failures - 1)))

    def failed(self) -> None:
        self.failures += 1
        self.next_attempt = self._clock() + self.delay_s

    def succeeded(self) -> None:
        self.failures = 0
        self.next_attempt = 0.0

    def ready(self) -> bool:
        return self._clock() >= self.next_attempt


@dataclass
class LinkStats:
    """Counters for diagnostics; written under the link lock, read from any thread."""

    transactions: int = 0
    timeouts: int = 0
    exceptions: int = 0
    frame_errors: int = 0
    reconnects: int = 0
    connect_failures: int = 0
    last_error: str = ""
    last_error_time: float = 0.0
    latencies_s: deque[float] = field(default_factory=lambda: deque(maxlen=LATENCY_SAMPLES))
    wire: WireTally = field(default_factory=lambda: WireTally())


@dataclass
class WireTally:
    """What the device's answered transactions cost the wire (the wire budget's input).

    A transaction is its frames (``Transport.frame_time_s``: bytes at the baud rate and the
    silence, 0 on TCP) and the device's turnaround: the rest of the time it took, i.e. the
    reply delay on a serial line, the round trip on TCP. ``polls`` / ``poll_frames_s``
    count the poll-priority ones: a poll's cost is their difference across it.
    """

    polls: float = 0.0  # round trips' worth: a pipelined reply counts its share
    poll_frames_s: float = 0.0
    turnarounds_s: deque[float] = field(default_factory=lambda: deque(maxlen=TURNAROUND_SAMPLES))

    def note(self, frame_s: float, elapsed_s: float, poll: bool, share: float = 1.0) -> None:
        """One answered transaction. ``share``: the part of its turnaround the wire spent on
        it alone, 1 for one request at a time; a pipelined reply that came while others
        were in flight counts less (``batches``), so a batch sent in one go costs about
        one round trip in the budget, as it does on the wire."""
        self.turnarounds_s.append(max(0.0, elapsed_s - frame_s))
        if poll:
            self.polls += share
            self.poll_frames_s += frame_s

    def turnaround_s(self) -> float | None:
        """The median turnaround of the recent transactions (None before the first)."""
        samples = sorted(self.turnarounds_s)
        return samples[len(samples) // 2] if samples else None


__all__ = ["LATENCY_SAMPLES", "TURNAROUND_SAMPLES", "Backoff", "LinkStats", "WireTally"]
