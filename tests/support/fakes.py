"""Fakes the plain-Python unit tests share: one clock for the code that takes a
``clock: Callable[[], float]`` (the monotonic time it reads), set by hand."""

from __future__ import annotations


class FakeClock:
    """A clock that stands still at ``now`` until a test moves it (``clock.now += 0.5``)."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now
