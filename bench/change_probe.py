"""Register change in a simulator -> the first device-layer snapshot that carries it.

Why: ``read_rates.py`` gives a latency for every case, and a ROS node is not run for
every case (``bridge_bench.py`` drives the TCP nodes only; the stepper and MOTEC cases run
the device layer on the emulated line). The simulator runs in a process of its own, so
its CPU is not the client's: it takes a value over a pipe, sets it as the device would
(``answer_changes``, with a device-specific setter), and answers with the
``time.monotonic()`` right after the set (one clock for every process on Linux, as
``line_relay.py``'s frame times). The client side (``ChangeProbe``) is told of every
snapshot and the time its poll returned (``observe``: where a node would publish it); a
latency sample is the first snapshot carrying the new value minus the set time. Each
value differs from the one the device last showed, so a snapshot that carries it was read
after the set.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing.connection import Connection
from typing import Any, Protocol

CHANGE_GAP_S = (0.020, 0.050)  # pause between a sample and the next change (as bridge_bench)
ANSWER_TIMEOUT_S = 5.0  # the simulator's reply to a change
SEEN_TIMEOUT_S = 5.0  # no snapshot carried the change: counted missed
WAIT_STEP_S = 0.05
FIRST_SNAPSHOT_TIMEOUT_S = 30.0


class StopFlag(Protocol):
    def is_set(self) -> bool: ...


def answer_changes(
    conn: Connection[Any, Any],
    stop: StopFlag,
    set_value: Callable[[float], None],
    poll_s: float = 0.05,
) -> None:
    """The simulator's side, until ``stop`` is set: each value received is set, then the
    monotonic time after the set is sent back."""
    while not stop.is_set():
        if conn.poll(poll_s):
            try:
                value = conn.recv()
            except EOFError:
                return
            set_value(float(value))
            conn.send(time.monotonic())


class ChangeProbe:
    """The client's side: changes values through ``conn`` while ``running`` and times the
    first snapshot that carries each (``read`` takes the value out of a snapshot; values
    are integers in ``low..high``, matched within ``tolerance``)."""

    def __init__(
        self,
        conn: Connection[Any, Any],
        read: Callable[[Any], float],
        low: int,
        high: int,
        *,
        tolerance: float = 0.25,
        seed: int = 1,
    ) -> None:
        self._conn = conn
        self._read = read
        self._low, self._high = low, high
        self._tolerance = tolerance
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._want: float | None = None
        self._hit_at = 0.0
        self._hit = threading.Event()
        self._latest: float | None = None
        self._observed = threading.Event()
        self._stop = threading.Event()
        self.samples_s: list[float] = []
        self.missed = 0
        self.error: str | None = None

    def observe(self, snapshot: object, at: float) -> None:
        """A poll returned ``snapshot`` at ``at`` (``time.monotonic()``); from the poll thread."""
        value = self._read(snapshot)
        with self._lock:
            self._latest = value
            want = self._want
            if want is not None and abs(value - want) <= self._tolerance:
                self._want = None
                self._hit_at = at
                self._hit.set()
        self._observed.set()

    @contextmanager
    def running(self) -> Iterator[ChangeProbe]:
        """Change values in a thread of this process for the duration of the block. The
        first change waits for a snapshot of this block (another probe may have changed
        the register since this one last saw it)."""
        with self._lock:
            self._latest = None
            self._observed.clear()
        self._stop.clear()
        thread = threading.Thread(target=self._run, name="change-probe", daemon=True)
        thread.start()
        try:
            yield self
        finally:
            self._stop.set()
            thread.join(ANSWER_TIMEOUT_S + 1)

    def _next_value(self) -> float:
        with self._lock:
            latest = self._latest
        while True:
            value = float(self._rng.randint(self._low, self._high))
            if latest is None or abs(value - latest) > 2 * self._tolerance:
                return value

    def _run(self) -> None:
        if not self._wait(self._observed, FIRST_SNAPSHOT_TIMEOUT_S):
            return
        while not self._stop.is_set():
            value = self._next_value()
            with self._lock:
                self._want = value  # before the set: a poll may return before the answer
                self._hit.clear()
            self._conn.send(value)
            if not self._conn.poll(ANSWER_TIMEOUT_S):
                self.error = "the simulator did not answer a change"
                return
            set_at = float(self._conn.recv())
            if self._wait(self._hit, SEEN_TIMEOUT_S):
                with self._lock:
                    self.samples_s.append(self._hit_at - set_at)
            elif not self._stop.is_set():
                self.missed += 1
            with self._lock:
                self._want = None
            self._stop.wait(self._rng.uniform(*CHANGE_GAP_S))

    def _wait(self, event: threading.Event, timeout_s: float) -> bool:
        """``event`` within ``timeout_s``; False at once when the probe is stopped."""
        deadline = time.monotonic() + timeout_s
        while not event.wait(WAIT_STEP_S):
            if self._stop.is_set() or time.monotonic() > deadline:
                return False
        return True
