"""bridge_core.runtime.goals: how a goal's run decides its ending (no ROS, fake clock)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from bridge_core.runtime.goals import (
    CONFIRM_POLLS,
    START_GRACE_S,
    START_POLLS,
    GoalRun,
    Motion,
    Outcome,
    Verdict,
    needs_stop,
    within,
)

from ...support.fakes import FakeClock


@dataclass
class Snap:
    moving: bool
    position: float
    fault: int = 0


class FakeMotion(Motion[Snap]):
    """A move to ``target`` that records its writes."""

    what = "fake move"

    def __init__(self, target: float = 10.0) -> None:
        super().__init__()
        self.target = target
        self.writes: list[str] = []

    def start(self) -> None:
        self.writes.append("start")

    def stop(self) -> str:
        self.writes.append("stop")
        return "stopped"

    def running(self, snapshot: Snap) -> bool:
        return snapshot.moving

    def fault(self, snapshot: Snap) -> Verdict | None:
        if snapshot.fault:
            return Verdict(Outcome.FAULT, "fault", snapshot.fault, "overcurrent")
        return None

    def ended(self, snapshot: Snap) -> Verdict:
        if within(snapshot.position, self.target, 0.1):
            return Verdict(Outcome.REACHED, "reached")
        return Verdict(Outcome.STOPPED, "short")


def started_run(timeout_s: float = 0.0, clock: FakeClock | None = None) -> GoalRun[Snap]:
    run = GoalRun(FakeMotion(), timeout_s=timeout_s, clock=clock or FakeClock(100.0))
    run.started(1000.0)
    return run


def judge(run: GoalRun[Snap], snap: Snap, connected: bool = True) -> Verdict | None:
    run.offer(snap, poll_started=1001.0)
    return run.next_ending(connected, run.take_snapshot())


def test_a_poll_begun_before_the_start_was_acknowledged_is_not_judged() -> None:
    run = started_run()
    run.offer(Snap(False, 0.0), poll_started=999.9)  # began before the ack at 1000.0
    assert run.take_snapshot() is None
    run.offer(Snap(False, 0.0), poll_started=1000.0)
    assert run.take_snapshot() == Snap(False, 0.0)


def test_a_snapshot_offered_before_the_start_is_dropped() -> None:
    run = GoalRun(FakeMotion())
    run.offer(Snap(True, 0.0), poll_started=5.0)
    assert run.take_snapshot() is None


def test_reached_when_it_stopped_at_the_target_after_running() -> None:
    run = started_run()
    assert judge(run, Snap(True, 3.0)) is None
    verdict = judge(run, Snap(False, 10.05))
    assert verdict is not None and verdict.outcome is Outcome.REACHED


def test_stopped_short_of_the_target_on_a_second_idle_poll() -> None:
    """The first idle poll may be torn (position read while running, flag after the
    stop): short of the target is only believed on the next one."""
    run = started_run()
    assert judge(run, Snap(True, 3.0)) is None
    assert judge(run, Snap(False, 9.0)) is None  # torn: it went on to 10.0
    verdict = judge(run, Snap(False, 10.0))
    assert verdict is not None and verdict.outcome is Outcome.REACHED
    run = started_run()
    assert judge(run, Snap(True, 3.0)) is None
    for _ in range(CONFIRM_POLLS - 1):
        assert judge(run, Snap(False, 4.0)) is None
    verdict = judge(run, Snap(False, 4.0))
    assert verdict is not None and verdict.outcome is Outcome.STOPPED


def test_reached_waits_for_a_second_idle_poll_when_the_motion_asks() -> None:
    run = started_run()
    run.motion.confirm_reached = True
    assert judge(run, Snap(True, 3.0)) is None
    for _ in range(CONFIRM_POLLS - 1):
        assert judge(run, Snap(False, 10.0)) is None
    verdict = judge(run, Snap(False, 10.0))
    assert verdict is not None and verdict.outcome is Outcome.REACHED


def test_a_motion_not_yet_shown_running_gets_start_polls_and_time() -> None:
    """A flag may come late: idle polls count only from START_POLLS on and after
    START_GRACE_S (fast polls must not end a motion whose flag rises 0.1 s late)."""
    clock = FakeClock(100.0)
    run = started_run(clock=clock)
    for _ in range(START_POLLS + 3):
        assert judge(run, Snap(False, 0.0)) is None  # many polls, too soon
    clock.now += START_GRACE_S
    verdict = judge(run, Snap(False, 0.0))
    assert verdict is not None and verdict.outcome is Outcome.STOPPED
    run = started_run(clock=clock)
    clock.now += START_GRACE_S
    for _ in range(START_POLLS - 1):
        assert judge(run, Snap(False, 0.0)) is None  # late enough, too few polls
    verdict = judge(run, Snap(False, 0.0))
    assert verdict is not None and verdict.outcome is Outcome.STOPPED


def test_a_zero_length_move_is_reached_without_ever_running() -> None:
    clock = FakeClock(100.0)
    run = started_run(clock=clock)
    clock.now += START_GRACE_S
    run.motion.target = 0.0  # type: ignore[attr-defined]
    verdicts = [judge(run, Snap(False, 0.0)) for _ in range(START_POLLS)]
    assert verdicts[:-1] == [None] * (START_POLLS - 1)
    assert verdicts[-1] is not None and verdicts[-1].outcome is Outcome.REACHED


def test_a_fault_ends_it_at_once_even_while_running() -> None:
    run = started_run()
    verdict = judge(run, Snap(True, 3.0, fault=7))
    assert verdict == Verdict(Outcome.FAULT, "fault", 7, "overcurrent")


def test_the_time_limit() -> None:
    clock = FakeClock(100.0)
    run = started_run(timeout_s=2.0, clock=clock)
    clock.now += 1.9
    assert run.next_ending(True, None) is None
    assert run.wait_s() == pytest.approx(0.1)
    clock.now += 0.1
    verdict = run.next_ending(True, None)
    assert verdict is not None and verdict.outcome is Outcome.TIMED_OUT


def test_no_time_limit_with_zero() -> None:
    clock = FakeClock(100.0)
    run = started_run(timeout_s=0.0, clock=clock)
    clock.now += 1e6
    assert run.next_ending(True, None) is None


@pytest.mark.parametrize("timeout_s", [-1.0, float("nan"), float("inf")])
def test_a_bad_time_limit_is_refused(timeout_s: float) -> None:
    with pytest.raises(ValueError):
        GoalRun(FakeMotion(), timeout_s=timeout_s)


def test_a_lost_link_ends_it() -> None:
    run = started_run()
    verdict = judge(run, Snap(True, 3.0), connected=False)
    assert verdict is not None and verdict.outcome is Outcome.LINK_LOST


def test_the_goals_own_reasons_come_first() -> None:
    """Halt, then cancel, then preemption, then the link, then what the device shows."""
    run = started_run()
    run.preempt("newer goal")
    first = run.next_ending(False, Snap(True, 1.0, fault=3))
    assert first is not None and first.outcome is Outcome.PREEMPTED
    assert "newer goal" in first.message
    run.cancel()
    second = run.next_ending(False, None)
    assert second is not None and second.outcome is Outcome.CANCELLED
    run.halt("the node was deactivated")
    third = run.next_ending(True, None)
    assert third is not None and third.outcome is Outcome.HALTED
    assert run.halted == "the node was deactivated"


def test_one_ending_wins() -> None:
    run = started_run()
    assert run.claim(Verdict(Outcome.CANCELLED, "a"))
    assert not run.claim(Verdict(Outcome.HALTED, "b"))
    assert run.verdict == Verdict(Outcome.CANCELLED, "a")
    assert not run.done.is_set()
    run.finish(True, "stop: done")
    assert run.done.is_set() and run.stop_sent


def test_which_outcomes_send_a_stop() -> None:
    stopping = {o for o in Outcome if needs_stop(o)}
    assert stopping == {
        Outcome.LINK_LOST,
        Outcome.CANCELLED,
        Outcome.PREEMPTED,
        Outcome.TIMED_OUT,
        Outcome.HALTED,
    }


def test_within_allows_float_rounding_only() -> None:
    assert within(50.01, 50.0, 0.01)  # 0.010000000000005116 in binary
    assert not within(50.02, 50.0, 0.01)
    assert not within(float("nan"), 0.0, 1.0)
