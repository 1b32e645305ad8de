"""``bridge_commission``'s reply times: the statistics of the timed requests and the
``timeout_s`` and ``poll_rate_hz`` they recommend (plain Python; ``runtime.commission``
re-exports them)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from .parameters import TIMEOUT_MAX_S

# Reply times: requests timed by default (``--samples``), and the recommendations' rules.
REPLY_SAMPLES_DEFAULT = 300
REPLY_SAMPLES_RANGE = (10, 100_000)
TIMEOUT_OVER_MAX = 3.0  # recommended timeout_s: this many times the slowest reply seen,
TIMEOUT_FLOOR_S = 0.1  # never below this (a loaded host stalls a reply that long),
TIMEOUT_STEP_S = 0.01  # rounded up to this step
POLL_RATE_HEADROOM = 0.5  # recommended poll rate: this share of what the line carries
POLL_RATE_STEP_HZ = 0.1  # rounded down to this step
PERCENTILES = (50.0, 99.0)


@dataclass(frozen=True)
class ReplyTimes:
    """Reply times of ``count`` requests (seconds), and how many got no reply."""

    count: int
    failures: int
    p50_s: float
    p99_s: float
    max_s: float

    @property
    def text(self) -> str:
        return (
            f"{self.count} requests: p50 {self.p50_s * 1000:.2f} ms, p99 "
            f"{self.p99_s * 1000:.2f} ms, max {self.max_s * 1000:.2f} ms, "
            f"{self.failures} without a reply"
        )


def percentile(sorted_s: Sequence[float], percent: float) -> float:
    """Nearest rank: the smallest sample with at least ``percent`` % at or below it."""
    if not sorted_s:
        return math.nan
    rank = max(1, math.ceil(percent / 100.0 * len(sorted_s)))
    return sorted_s[rank - 1]


def reply_times(samples_s: Sequence[float], failures: int = 0) -> ReplyTimes:
    ordered = sorted(samples_s)
    p50, p99 = (percentile(ordered, p) for p in PERCENTILES)
    return ReplyTimes(
        len(ordered) + failures, failures, p50, p99, ordered[-1] if ordered else math.nan
    )


def recommend_timeout_s(times: ReplyTimes, low_s: float) -> float:
    """``timeout_s`` for this line: ``TIMEOUT_OVER_MAX`` x the slowest reply, at least
    ``TIMEOUT_FLOOR_S`` and the bridge's own minimum ``low_s``, rounded up to
    ``TIMEOUT_STEP_S``, at most ``TIMEOUT_MAX_S``."""
    wanted = max(TIMEOUT_OVER_MAX * times.max_s, TIMEOUT_FLOOR_S, low_s)
    steps = math.ceil(round(wanted / TIMEOUT_STEP_S, 6))
    return min(round(steps * TIMEOUT_STEP_S, 6), TIMEOUT_MAX_S)


def carried_poll_rate_hz(times: ReplyTimes, requests_per_poll: int) -> float:
    """Polls per second the line carries one request at a time at the median reply."""
    return 1.0 / (max(requests_per_poll, 1) * times.p50_s)


def recommend_poll_rate_hz(carried_hz: float, default_hz: float, low_hz: float) -> float:
    """The bridge's default poll rate, or ``POLL_RATE_HEADROOM`` of what the line carries
    when that is less (rounded down to ``POLL_RATE_STEP_HZ``, at least ``low_hz``)."""
    wanted = min(default_hz, POLL_RATE_HEADROOM * carried_hz)
    steps = math.floor(round(wanted / POLL_RATE_STEP_HZ, 6))
    return max(round(steps * POLL_RATE_STEP_HZ, 6), low_hz)
