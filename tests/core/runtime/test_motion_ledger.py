"""The ledger of motions services started (what a halt stops besides streams and goals)."""

from __future__ import annotations

from bridge_core.runtime.motion_ledger import MotionLedger
from bridge_core.wire.errors import LinkTimeout, NotConfirmed


def test_a_halt_stops_every_started_motion_once_and_keeps_a_failed_one() -> None:
    ledger = MotionLedger()
    log: list[str] = []
    fail = {"motor 2"}

    def stop(axis: str) -> None:
        if axis in fail:
            raise LinkTimeout("no reply")
        log.append(f"stop {axis}")

    ledger.started("motor 1", "motor 1 forward", lambda: stop("motor 1"))
    ledger.started("motor 2", "motor 2 reverse", lambda: stop("motor 2"))
    ledger.started("motor 3", "motor 3 home", lambda: stop("motor 3"))
    ledger.stopped("motor 3")  # its stop service was acknowledged
    results = {r.axis: r.error for r in ledger.stop_all()}
    assert log == ["stop motor 1"]  # motor 3 was stopped already
    assert results["motor 1"] is None and isinstance(results["motor 2"], LinkTimeout)
    assert ledger.moving() == {"motor 2": "motor 2 reverse"}  # tried again at the next halt
    fail.clear()
    ledger.stop_all()
    assert log == ["stop motor 1", "stop motor 2"] and ledger.moving() == {}


def test_a_newer_start_of_an_axis_replaces_the_older() -> None:
    ledger = MotionLedger()
    stops: list[str] = []
    ledger.started(1, "forward", lambda: stops.append("first"))
    ledger.started(1, "reverse", lambda: stops.append("second"))
    ledger.stop_all()
    assert stops == ["second"]


def test_a_failed_halt_stop_is_pending_until_a_retry_gets_it_through() -> None:
    ledger = MotionLedger()
    down = [True]
    sent: list[int] = []

    def stop(axis: int) -> None:
        if down[0]:
            raise LinkTimeout("no reply")
        sent.append(axis)

    ledger.started(1, "motor 1 forward", lambda: stop(1))
    ledger.started(2, "motor 2 forward", lambda: stop(2))
    assert ledger.retry_pending() == []  # nothing failed yet: a retry sends nothing
    ledger.stopped(2)
    assert [r.error is not None for r in ledger.stop_all()] == [True]
    assert [r.error is not None for r in ledger.retry_pending()] == [True]  # still down
    down[0] = False
    assert [r.error for r in ledger.retry_pending()] == [None]
    assert sent == [1] and ledger.moving() == {}


def test_a_halt_stop_not_confirmed_is_kept_for_the_next_halt_not_retried() -> None:
    """The device answered the stop and did not show it (NotConfirmed): retrying on a
    timer would not help; the next halt tries it again."""
    ledger = MotionLedger()
    tried: list[int] = []

    def stop() -> None:
        tried.append(1)
        raise NotConfirmed("sent, read moving 1")

    ledger.started("program", "start", stop)
    assert [type(r.error) for r in ledger.stop_all()] == [NotConfirmed]
    assert not ledger.pending() and ledger.retry_pending() == []
    assert ledger.moving() == {"program": "start"}
    ledger.stop_all()
    assert tried == [1, 1]
