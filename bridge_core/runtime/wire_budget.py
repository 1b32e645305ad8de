"""The wire budget: what a device's polls ask of its link, against what the link carries.

Why: a poll rate the line cannot carry used to be taken silently; the poller just ran late
(docs/architecture.md, "The wire budget"). The budget is worked out from the link's frame
arithmetic (bytes at the baud rate, t3.5: ``Transport.frame_time_s``) and the turnaround
the channel measures (the device's reply delay on a serial line, the round trip on TCP:
``WireTally``):

- one fast cycle: the transactions of the device's last poll that read no slow group,
  each its frames plus the median turnaround;
- one slow refresh: the slow plan's requests, computed the same way;
- load: fast cycle x poll rate + slow refresh / slow period, a share of the wire's time
  (1.0: the line is busy all the time);
- achievable poll rate: what is left beside the slow group, over the fast cycle.

A bus owner sums its devices' loads (``line_load``): they share one wire. Commands, stops
and watchdog feeds come on top; they are short and rare next to the polls.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

from ..wire.link_stats import WireTally
from ..wire.requests import Request
from .rate_groups import PollGroups
from .reads import as_request

T = TypeVar("T")
WIRE_FULL = 1.0  # a load above it: the wire cannot carry the rates asked


@dataclass(frozen=True)
class Budget:
    """One device's (or, summed, one line's) use of its wire at the rates asked."""

    fast_cycle_s: float  # one poll without a slow refresh, on the wire
    slow_refresh_s: float  # one read of the slow group, on the wire
    poll_rate_hz: float
    slow_period_s: float
    turnaround_s: float  # the median measured reply delay (RTU) / round trip (TCP)

    @property
    def slow_share(self) -> float:
        return self.slow_refresh_s / self.slow_period_s

    @property
    def load(self) -> float:
        return self.fast_cycle_s * self.poll_rate_hz + self.slow_share

    @property
    def achievable_hz(self) -> float:
        """The poll rate the wire carries beside the slow group (inf: a poll costs nothing)."""
        if self.fast_cycle_s <= 0.0:
            return math.inf
        return max(0.0, WIRE_FULL - self.slow_share) / self.fast_cycle_s

    @property
    def exceeded(self) -> bool:
        return self.load > WIRE_FULL


class BudgetChannel(Protocol):
    """What the budget needs of a ``DeviceChannel``."""

    @property
    def wire(self) -> WireTally: ...
    def frame_time_s(self, request: Request) -> float: ...


class WireBudget:
    """A device's budget, from its polls (``around``) and its slow plan.

    It is said once (``warning``) after the node starts and after every change of a rate
    (``rearm``), as soon as a fast cycle and a turnaround have been measured.
    """

    def __init__(
        self,
        channel: BudgetChannel,
        groups: Callable[[], PollGroups],
        poll_rate_hz: Callable[[], float],
    ) -> None:
        self._channel = channel
        self._groups = groups
        self._poll_rate_hz = poll_rate_hz
        self._lock = threading.Lock()
        self._fast: tuple[float, float] | None = None  # round trips, their frames (s)
        self._armed = True
        self.generation = 0  # bumped by ``rearm``: a bus owner re-judges its line

    def around(self, poll: Callable[[], T]) -> T:
        """Run ``poll``, noting what it cost the wire when it read no slow group."""
        wire = self._channel.wire
        groups = self._groups()
        polls, frames, slow_reads = wire.polls, wire.poll_frames_s, groups.slow_reads
        result = poll()
        if groups.slow_reads == slow_reads:
            with self._lock:
                self._fast = (wire.polls - polls, wire.poll_frames_s - frames)
        return result

    def rearm(self) -> None:
        """A rate changed: judge the budget again and say it if it is exceeded."""
        with self._lock:
            self._armed = True
            self.generation += 1

    def budget(self) -> Budget | None:
        """The budget at the rates asked now (None until a fast poll was measured)."""
        turnaround = self._channel.wire.turnaround_s()
        with self._lock:
            fast = self._fast
        if fast is None or turnaround is None:
            return None
        count, frames = fast
        groups = self._groups()
        slow = [self._channel.frame_time_s(as_request(r)) for r in groups.slow]
        return Budget(
            fast_cycle_s=frames + count * turnaround,
            slow_refresh_s=sum(slow) + len(slow) * turnaround,
            poll_rate_hz=self._poll_rate_hz(),
            slow_period_s=groups.period_s,
            turnaround_s=turnaround,
        )

    def warning(self, what: str) -> str | None:
        """The one-line WARN when the budget is exceeded, once per start or rate change
        (None: nothing to say now)."""
        with self._lock:
            if not self._armed:
                return None
        budget = self.budget()
        if budget is None:
            return None
        with self._lock:
            self._armed = False
        return exceeded_text(what, budget) if budget.exceeded else None


def exceeded_text(what: str, budget: Budget) -> str:
    return (
        f"{what}: poll_rate_hz {budget.poll_rate_hz:g} needs {budget.load:.0%} of the wire "
        f"({budget.fast_cycle_s * 1e3:.1f} ms a poll, slow group {budget.slow_share:.0%}); "
        f"it carries about {budget.achievable_hz:.1f} Hz"
    )


def line_load(budgets: Sequence[Budget]) -> float:
    """The share of one wire the devices on it use together."""
    return sum(b.load for b in budgets)


def line_text(what: str, budgets: Sequence[Budget]) -> str:
    """The bus owner's WARN: the devices' rates together exceed their line."""
    load = line_load(budgets)
    scale = WIRE_FULL / load if load > 0 else 1.0
    rates = ", ".join(f"{b.poll_rate_hz * scale:.1f}" for b in budgets)
    return (
        f"{what}: the polls of its {len(budgets)} devices need {load:.0%} of the line; "
        f"at the same proportions it carries about {rates} Hz"
    )


def budget_values(budget: Budget | None, serial: bool) -> list[tuple[str, str]]:
    """The diagnostics key-values of one device's budget."""
    turnaround = "reply delay (ms)" if serial else "round trip (ms)"
    if budget is None:
        return [("wire load (%)", "n/a"), ("achievable poll rate (Hz)", "n/a"), (turnaround, "n/a")]
    achievable = budget.achievable_hz
    return [
        ("wire load (%)", f"{budget.load * 100:.1f}"),
        (
            "achievable poll rate (Hz)",
            "unbounded" if math.isinf(achievable) else f"{achievable:.1f}",
        ),
        ("wire time per poll (ms)", f"{budget.fast_cycle_s * 1e3:.1f}"),
        (turnaround, f"{budget.turnaround_s * 1e3:.1f}"),
    ]


__all__ = [
    "WIRE_FULL",
    "Budget",
    "BudgetChannel",
    "WireBudget",
    "budget_values",
    "exceeded_text",
    "line_load",
    "line_text",
]
