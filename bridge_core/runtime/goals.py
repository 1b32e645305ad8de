"""Motion goals: the plain-Python half of the bridges' actions (docs/actions.md).

An action goal starts a motion on the device and follows it through the polls until the
device shows it ended, or until something ends it first: its client cancels it, a newer
goal on the same axis preempts it, its time limit passes, the link drops, or the node
stops every motion it started (deactivate, exit, ``read_only``). Whoever ends a goal
first wins; the ones that need the motion stopped send the stop.

- ``Motion``: one goal's motion on one device (what it occupies, how it starts and
  stops, how a poll shows its progress); each bridge's ``device.py`` has its kinds.
- ``GoalRun``: one goal's life, fed with snapshots by the poller's publisher thread and
  told of cancel / preemption / shutdown by the node; ``next_ending`` says when it is over.

``bridge_core.ros.node_actions`` puts these behind rclpy action servers. No ROS here.
"""

from __future__ import annotations

import enum
import math
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

SnapshotT = TypeVar("SnapshotT")

# A motion that never showed as running is judged on this many polls begun after its start
# was acknowledged, and no sooner than START_GRACE_S after it: a device may set its
# running flag a little after the command (and a zero-length move never sets it).
START_POLLS = 2
START_GRACE_S = 0.5
# A poll is several requests: its position may have been read while the motion still ran
# and its running flag after it ended. Short of the target, the verdict waits for this
# many idle polls (the second one read every value after the motion had ended).
CONFIRM_POLLS = 2
# A goal's thread looks at its link and deadline at least this often even with no poll.
GOAL_CHECK_PERIOD_S = 0.25


class Outcome(enum.IntEnum):
    """How a goal ended; the numbers are ``msg_defs/msg/MotionOutcome``'s constants."""

    REACHED = 0
    STOPPED = 1
    FAULT = 2
    LIMIT = 3
    LINK_LOST = 4
    CANCELLED = 5
    PREEMPTED = 6
    TIMED_OUT = 7
    HALTED = 8
    REFUSED = 9


# Endings that must stop the motion themselves (the device did not end it).
STOPPING_OUTCOMES = frozenset(
    {Outcome.LINK_LOST, Outcome.CANCELLED, Outcome.PREEMPTED, Outcome.TIMED_OUT, Outcome.HALTED}
)


@dataclass(frozen=True)
class Verdict:
    """One goal's ending: the outcome, one line, and the device's fault if it had one."""

    outcome: Outcome
    message: str
    fault_code: int = 0
    fault_text: str = ""


class Motion(ABC, Generic[SnapshotT]):
    """One goal's motion; plain Python over a bridge's device layer.

    The constructor checks the goal (a bad one raises ``CommandRejected`` and nothing is
    written); ``start`` writes; ``judge`` is given every snapshot of a poll begun after the
    start was acknowledged and says when the motion is over.
    """

    #: What the motion occupies (e.g. motor numbers): a newer goal on any of them preempts.
    axes: frozenset[Hashable] = frozenset()
    #: The command in words, for replies and the console ("motor 1 move_by 0.05 m").
    what: str = "motion"
    #: REACHED too waits for a second idle poll: the result reports values (a cycle time)
    #: that a poll may have read before the motion ended.
    confirm_reached: bool = False

    def __init__(self) -> None:
        self.seen_running = False
        self.idle_polls = 0

    def default_timeout_s(self, node_default_s: float) -> float:
        """The goal's time limit when it gives ``timeout_s`` 0: the node's
        ``goal_timeout_s`` (so a goal whose client vanished ends by itself). A motion with
        a limit of its own (judged in ``judge``) returns 0 (none here). A motion meant to
        run until stopped (an R6 continuous run_cycle) keeps the node's: the user who
        wants it unbounded sets ``goal_timeout_s`` 0 (R6 decision 27)."""
        return node_default_s

    @abstractmethod
    def start(self) -> None:
        """Write the motion's command (runs inside the node's command guard)."""

    @abstractmethod
    def stop(self) -> str:
        """Stop this motion on the device; returns what was done."""

    @abstractmethod
    def running(self, snapshot: SnapshotT) -> bool:
        """Whether the device shows the motion still going."""

    def fault(self, snapshot: SnapshotT) -> Verdict | None:
        """A device fault or alarm that ends the goal at once, running or not."""
        return None

    def ended(self, snapshot: SnapshotT) -> Verdict:
        """The verdict once the device stands still: where it stands decides."""
        return Verdict(Outcome.REACHED, f"{self.what}: done")

    def feedback(self, snapshot: SnapshotT) -> dict[str, Any]:
        """Fields of the action's feedback message."""
        return {}

    def result(self, snapshot: SnapshotT | None) -> dict[str, Any]:
        """Fields of the action's result message besides the outcome."""
        return {}

    def judge(self, snapshot: SnapshotT, since_start_s: float = math.inf) -> Verdict | None:
        """None while the motion goes on (or may not have shown yet that it started).
        ``since_start_s``: how long ago the start was acknowledged."""
        if (verdict := self.fault(snapshot)) is not None:
            return verdict
        if self.running(snapshot):
            self.seen_running = True
            self.idle_polls = 0
            return None
        self.idle_polls += 1
        if not self.seen_running and (
            self.idle_polls < START_POLLS or since_start_s < START_GRACE_S
        ):
            return None
        verdict = self.ended(snapshot)
        confirm = self.confirm_reached or verdict.outcome is not Outcome.REACHED
        if confirm and self.idle_polls < CONFIRM_POLLS:
            return None  # the position may have been read before the motion ended
        return verdict


def within(value: float, target: float, tolerance: float) -> bool:
    """``value`` within ``tolerance`` of ``target``, up to float rounding (50.01 - 50.00 is
    0.010000000000005 in binary floating point)."""
    slack = 1e-9 * max(1.0, abs(target))
    return math.isfinite(value) and abs(value - target) <= tolerance + slack


class GoalRun(Generic[SnapshotT]):
    """One accepted goal from its start to its result; thread-safe.

    The node's action thread runs it (``started``, then ``next_ending`` after each wake);
    the poller's publisher thread ``offer``s snapshots; the node's other threads ``cancel``,
    ``preempt`` or ``halt`` it. ``claim`` lets exactly one of them end it; that one sends
    the stop if the outcome needs one and calls ``finish``.
    """

    def __init__(
        self,
        motion: Motion[SnapshotT],
        *,
        timeout_s: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not math.isfinite(timeout_s) or timeout_s < 0:
            raise ValueError(f"timeout_s {timeout_s} must be 0 (none) or a positive time")
        self.motion = motion
        self.timeout_s = timeout_s
        self._clock = clock
        self.deadline = math.inf
        self.wake = threading.Event()
        self.done = threading.Event()
        self._lock = threading.Lock()
        self.started_at: float | None = None  # time.monotonic() the start was acknowledged
        self._started_clock = 0.0  # clock() then
        self._snapshot: SnapshotT | None = None  # newest fresh snapshot not yet judged
        self.last_snapshot: SnapshotT | None = None  # newest fresh snapshot judged
        self._cancelled = False
        self._preempted_by: str | None = None
        self._halted: str | None = None
        self.verdict: Verdict | None = None
        self.thread: threading.Thread | None = None  # the goal's own thread, once it runs
        self.starting = False  # its start is being written (it had its turn)
        self.stop_sent = False
        self.stop_message = ""

    # ---------------------------------------------------------------- from other threads
    def offer(self, snapshot: SnapshotT, poll_started: float) -> None:
        """A published snapshot; kept only if its poll began after the start's ack."""
        with self._lock:
            if self.started_at is None or poll_started < self.started_at:
                return
            self._snapshot = snapshot
        self.wake.set()

    def cancel(self) -> None:
        with self._lock:
            self._cancelled = True
        self.wake.set()

    def preempt(self, by: str) -> None:
        with self._lock:
            self._preempted_by = by
        self.wake.set()

    def halt(self, reason: str) -> None:
        with self._lock:
            self._halted = reason
        self.wake.set()

    # ---------------------------------------------------------------- the goal's thread
    def started(self, at: float) -> None:
        """The start was acknowledged at ``at`` (``time.monotonic()``, the clock the polls'
        begin times use: a wall clock stepped back by NTP must not hide every poll)."""
        with self._lock:
            self.started_at = at
            self._started_clock = self._clock()
            if self.timeout_s:
                self.deadline = self._started_clock + self.timeout_s

    def wait_s(self) -> float:
        """How long the goal's thread may sleep before it must look again."""
        return max(0.0, min(GOAL_CHECK_PERIOD_S, self.deadline - self._clock()))

    def take_snapshot(self) -> SnapshotT | None:
        with self._lock:
            snapshot, self._snapshot = self._snapshot, None
        if snapshot is not None:
            self.last_snapshot = snapshot
        return snapshot

    def next_ending(self, connected: bool, snapshot: SnapshotT | None) -> Verdict | None:
        """What ends the goal now, if anything; the goal's own reasons come first, then
        the link, the deadline, and last what the newest fresh snapshot shows."""
        what = self.motion.what
        if (verdict := self.requested_ending()) is not None:
            return verdict
        if not connected:
            return Verdict(Outcome.LINK_LOST, f"{what}: the link was lost during the goal")
        if self._clock() >= self.deadline:
            return Verdict(Outcome.TIMED_OUT, f"{what}: not done within {self.timeout_s:g} s")
        if snapshot is not None:
            return self.motion.judge(snapshot, self._clock() - self._started_clock)
        return None

    def requested_ending(self) -> Verdict | None:
        """The goal's own reasons to end (halt, cancel, preemption), first to last."""
        what = self.motion.what
        with self._lock:
            cancelled, preempted_by, halted = self._cancelled, self._preempted_by, self._halted
        if halted is not None:
            return Verdict(Outcome.HALTED, f"{what}: stopped, {halted}")
        if cancelled:
            return Verdict(Outcome.CANCELLED, f"{what}: cancelled")
        if preempted_by is not None:
            return Verdict(Outcome.PREEMPTED, f"{what}: preempted by {preempted_by}")
        return None

    def claim(self, verdict: Verdict) -> bool:
        """End the goal with ``verdict`` unless it has ended already; True: the caller
        ended it (and then sends the stop if the outcome needs one, and ``finish``es)."""
        with self._lock:
            if self.verdict is not None:
                return False
            self.verdict = verdict
            return True

    def finish(self, stop_sent: bool = False, stop_message: str = "") -> None:
        self.stop_sent = stop_sent
        self.stop_message = stop_message
        self.done.set()
        self.wake.set()

    @property
    def ended(self) -> bool:
        return self.verdict is not None

    @property
    def preempted_by(self) -> str | None:
        """What preempted this goal (None: nothing did)."""
        return self._preempted_by

    @property
    def halted(self) -> str | None:
        """Why the node halted this goal (None: it did not)."""
        return self._halted


def needs_stop(outcome: Outcome) -> bool:
    return outcome in STOPPING_OUTCOMES


__all__ = [
    "CONFIRM_POLLS",
    "GOAL_CHECK_PERIOD_S",
    "START_GRACE_S",
    "START_POLLS",
    "GoalRun",
    "Motion",
    "Outcome",
    "Verdict",
    "needs_stop",
    "within",
]
