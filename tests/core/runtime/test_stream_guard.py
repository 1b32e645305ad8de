"""The stream guard (jog / cmd_velocity rules) with a fake device and a fake clock."""

from __future__ import annotations

import pytest

from bridge_core.runtime.stream_guard import STOP_RETRY_GAP_S, StreamGuard
from bridge_core.wire.errors import CommandRejected, LinkTimeout

from ...support.fakes import FakeClock


class Motors:
    """Records sends and stops; the next ``fail`` writes time out."""

    def __init__(self) -> None:
        self.log: list[tuple[str, int, float | None, float | None]] = []
        self.fail = 0

    def _maybe_fail(self) -> None:
        if self.fail:
            self.fail -= 1
            raise LinkTimeout("no reply")

    def send(self, key: int, value: float, previous: float | None) -> None:
        self._maybe_fail()
        self.log.append(("send", key, value, previous))

    def stop(self, key: int) -> None:
        self._maybe_fail()
        self.log.append(("stop", key, None, None))


def make(stop_when_idle: bool = True) -> tuple[StreamGuard[int], Motors, FakeClock]:
    motors, clock = Motors(), FakeClock()
    guard = StreamGuard(
        (1, 2),
        motors.send,
        motors.stop,
        timeout_s=0.5,
        stop_when_idle=stop_when_idle,
        clock=clock,
    )
    return guard, motors, clock


def test_newest_value_counts_and_repeats_write_nothing() -> None:
    guard, motors, _ = make()
    assert guard.command(1, 100.0)
    assert not guard.command(1, 100.0)
    assert guard.command(1, 120.0)
    assert motors.log == [("send", 1, 100.0, None), ("send", 1, 120.0, 100.0)]


def test_zero_stops_once() -> None:
    guard, motors, _ = make()
    guard.command(1, 50.0)
    assert guard.command(1, 0.0)
    assert not guard.command(1, 0.0) and not guard.command(1, 0.0)
    assert [entry[0] for entry in motors.log] == ["send", "stop"]


def test_first_zero_of_an_idle_stream_depends_on_the_device() -> None:
    stepper, stepper_motors, _ = make(stop_when_idle=True)
    assert stepper.command(2, 0.0)  # the motor may run from a service: stop it
    motec, motec_motors, _ = make(stop_when_idle=False)
    assert not motec.command(2, 0.0)  # 0xAE also limits a position move: leave it
    assert stepper_motors.log == [("stop", 2, None, None)] and motec_motors.log == []


def test_lock_after_a_service_stop_until_a_zero_never_silence() -> None:
    """Silence no longer unlocks a stopped stream; only a 0 does."""
    guard, _, clock = make()
    guard.command(1, 50.0)
    guard.taken_over(1, locked=True)
    with pytest.raises(CommandRejected, match="send 0"):
        guard.command(1, 60.0)
    guard.offer(1, 60.0)
    clock.now += 0.6
    assert guard.due() == []  # locked, not moving: nothing for the deadman
    clock.now += 5.0
    guard.offer(1, 60.0)  # after long silence: still refused
    with pytest.raises(CommandRejected, match="stopped"):
        guard.command(1, guard.take(1) or 0.0)
    assert guard.command(1, 0.0)  # a 0 unlocks, and stops once (the service may have moved it)
    assert guard.command(1, 70.0)


def test_lost_write_leaves_a_stop_pending_until_acknowledged() -> None:
    guard, motors, _ = make()
    motors.fail = 1
    with pytest.raises(LinkTimeout):
        guard.command(1, 80.0)
    assert guard[1].may_move and guard[1].stop_pending
    motors.fail = 1
    with pytest.raises(LinkTimeout):
        guard.stop(1)
    assert guard[1].may_move  # still the deadman's
    assert guard.stop(1)
    assert not guard[1].may_move
    # After the lost write the next command is sent whole (previous unknown).
    guard.command(1, 80.0)
    assert motors.log[-1] == ("send", 1, 80.0, None)


def test_a_pending_stop_is_due_at_once_until_acknowledged() -> None:
    """The deadman retries a lost stop every period, not only after the stream fell
    silent: commands may keep arriving (refused while the link is down)."""
    guard, motors, clock = make()
    guard.offer(1, 30.0)
    guard.command(1, 30.0)
    assert guard.due() == [] and guard.pending_stops() == []
    motors.fail = 1
    with pytest.raises(LinkTimeout):
        guard.stop(1)
    clock.now = 0.01
    guard.offer(1, 30.0)  # still commanded: not silent
    assert guard.due() == [] and guard.pending_stops() == [1]  # the bus rests a moment
    clock.now = 0.01 + STOP_RETRY_GAP_S
    assert guard.due() == [1] and guard.pending_stops() == [1]
    assert guard.expire(1)
    assert motors.log[-1] == ("stop", 1, None, None)
    assert guard.due() == [] and guard.pending_stops() == []


def test_deadman_stops_silent_streams_only() -> None:
    guard, motors, clock = make()
    guard.offer(1, 30.0)
    guard.command(1, 30.0)
    guard.offer(2, 40.0)
    guard.command(2, 40.0)
    clock.now = 0.4
    guard.offer(2, 40.0)
    clock.now = 0.6
    assert guard.due() == [1]
    assert guard.expire(1)
    assert guard.moving() == [2]
    assert motors.log[-1] == ("stop", 1, None, None)


def test_stop_all_tries_every_stream_and_returns_failures() -> None:
    guard, motors, _ = make()
    guard.command(1, 10.0)
    guard.command(2, 20.0)
    motors.fail = 1  # the first stop is lost
    failures = guard.stop_all()
    assert [key for key, _ in failures] == [1]
    assert guard.moving() == [1]  # still pending: a later stop_all retries it
    assert guard.stop_all() == [] and guard.moving() == []


def test_forget_values_keeps_the_deadman_on_a_moving_stream() -> None:
    guard, motors, _ = make()
    guard.command(1, 10.0)
    guard.forget_values()  # reconnect: the device may hold another speed
    assert guard[1].may_move
    guard.command(1, 10.0)  # not a repeat any more: sent whole
    assert motors.log[-1] == ("send", 1, 10.0, None)


def test_unknown_stream_is_refused() -> None:
    guard, _, _ = make()
    with pytest.raises(CommandRejected, match="no stream 9"):
        guard.command(9, 1.0)


def test_offers_coalesce_and_wake_the_writer_only_when_a_write_may_go() -> None:
    guard, motors, clock = make()
    guard.min_interval_s = 0.1
    assert guard.offer(1, 50.0)  # first value: at once
    assert guard.ready() == [1] and guard.take(1) == 50.0
    guard.command(1, 50.0)
    assert not guard.offer(1, 50.0)  # a repeat: the periodic pass drops it
    clock.now = 0.05
    assert not guard.offer(1, 60.0)  # inside the interval: waits
    assert not guard.offer(1, 70.0)  # ... and replaces the 60
    assert guard.ready() == []
    assert guard.offer(1, 0.0)  # a 0 goes at once, and overtakes the 70
    assert guard.ready() == [1] and guard.take(1) == 0.0
    assert guard.take(1) is None
    clock.now = 0.2
    assert guard.offer(1, 80.0)  # interval passed
    assert motors.log == [("send", 1, 50.0, None)]


def test_a_repeat_in_another_unit_wakes_no_writer() -> None:
    """A topic offers rad/s, the guard holds rpm: a repeat is judged against the value last
    taken, in the units offered. Before, a constant 1000 msg/s flood woke the writer (and
    the executor) once per message: the bridge at 100 % of a core (bench/stream_flood.py,
    phase "constant"). A new value after a run of repeats goes at once (the rate limit
    counts writes only)."""
    guard, motors, clock = make()
    guard.min_interval_s = 0.1
    assert guard.offer(1, 5.0) and guard.command(1, (guard.take(1) or 0.0) * 10)
    clock.now = 0.2
    assert not guard.offer(1, 5.0)  # the repeat: nothing to wake
    assert not guard.command(1, (guard.take(1) or 0.0) * 10)  # the periodic pass: nothing
    assert not guard.offer(1, 5.0)
    assert guard.offer(1, 6.0)  # new, and 0.2 s since the last write: at once
    assert guard.command(1, (guard.take(1) or 0.0) * 10)
    guard.forget_values()  # a reconnect: the device may hold another speed
    clock.now = 0.35
    assert guard.offer(1, 6.0)  # no repeat: sent whole again
    assert motors.log == [("send", 1, 50.0, None), ("send", 1, 60.0, 50.0)]


def test_after_stop_follows_the_acknowledged_stops() -> None:
    """after_stop (the stepper's speed restore) runs after the stops it follows: once per
    stop(), once after all of stop_all()'s stops, never for a stop that failed."""
    motors, clock = Motors(), FakeClock()
    after: list[list[int]] = []

    def follow(keys: list[int]) -> None:
        motors.log.append(("after", len(after), None, None))
        after.append(keys)

    guard = StreamGuard(
        (1, 2), motors.send, motors.stop, timeout_s=0.5, clock=clock, after_stop=follow
    )
    guard.command(1, 100.0)
    guard.command(2, 100.0)
    guard.stop_all()
    assert [entry[0] for entry in motors.log] == ["send", "send", "stop", "stop", "after"]
    assert after == [[1, 2]]
    guard.command(1, 0.0)  # stop_all locked the streams: a 0 unlocks
    guard.command(2, 0.0)
    guard.command(1, 100.0)
    assert guard.command(1, 0.0)
    assert after[-1] == [1]
    guard.command(2, 100.0)
    motors.fail = 1
    with pytest.raises(LinkTimeout):
        guard.stop(2)
    assert len(after) == 2  # the failed stop is followed by nothing
    assert guard.stop_all() == [] and after[-1] == [2]


def test_only_a_zero_that_arrived_after_the_stop_unlocks_it() -> None:
    """The unlock is decided on arrival, never by a timer's turn: a 0 that arrived (and
    coalesced with a newer value before the writer's pass) unlocks the stream, and the
    newer value is applied; a 0 that arrived before the stop cannot undo it; a new press
    after a halt and long silence is refused (the jog topics and
    ~/joint_commands follow one rule)."""
    guard, motors, clock = make()
    guard.hold(1)  # a stop service of the device: the stream never commanded anything
    guard.offer(1, 40.0)
    with pytest.raises(CommandRejected, match="stopped"):
        guard.command(1, guard.take(1) or 0.0)
    guard.min_interval_s = 0.1
    clock.now += 0.2
    guard.offer(1, 0.0)
    guard.offer(1, 45.0)  # coalesces with the 0: the unlock stands
    assert guard.command(1, guard.take(1) or 0.0)
    assert motors.log[-1] == ("send", 1, 45.0, None)
    guard.offer(1, 0.0)  # arrived before the stop, not yet taken
    guard.taken_over(1, locked=True)
    guard.take(1)
    clock.now += 0.2
    guard.offer(1, 50.0)
    with pytest.raises(CommandRejected, match="stopped"):
        guard.command(1, guard.take(1) or 0.0)
    guard.offer(2, 5.0)
    guard.stop_all()  # the halt drops it and locks the stream
    clock.now += 10.0
    guard.offer(2, 6.0)  # a new press after the halt and after silence: refused
    with pytest.raises(CommandRejected, match="send 0"):
        guard.command(2, guard.take(2) or 0.0)
    assert all(entry[1] != 2 for entry in motors.log)


def test_stop_all_drops_offered_values_and_locks_every_stream() -> None:
    """A value offered before a halt (deactivate, exit, read_only) is never written after
    it, and a joystick still held afterwards cannot restart the motor: as after a stop
    service, until a 0 or silence (issue: deactivate during a jog restarted the motor)."""
    guard, motors, clock = make()
    guard.command(1, 10.0)
    guard.offer(1, 30.0)  # arrived, not yet applied by the writer
    guard.offer(2, 5.0)  # a stream that never moved
    guard.stop_all()
    assert motors.log[-1] == ("stop", 1, None, None)
    assert guard.ready() == [] and guard.take(1) is None and guard.take(2) is None
    for key in (1, 2):
        with pytest.raises(CommandRejected, match="stopped"):
            guard.command(key, 30.0)
    assert motors.log == [("send", 1, 10.0, None), ("stop", 1, None, None)]
    guard.command(1, 0.0)  # a 0 unlocks (the motor already stands: nothing written)
    assert guard.command(1, 30.0)
    clock.now += 1.0  # silence does not, the deadman's expire neither
    guard.expire(2)
    with pytest.raises(CommandRejected, match="stopped"):
        guard.command(2, 5.0)


def test_permit_is_asked_under_the_lock_before_every_non_zero_write() -> None:
    guard, motors, _ = make()
    reason: list[str | None] = [None]
    guard.permit = lambda: reason[0]
    assert guard.command(1, 10.0)
    reason[0] = "the node is not active"
    with pytest.raises(CommandRejected, match="not active"):
        guard.command(1, 20.0)
    assert guard.command(1, 0.0)  # stops are never refused
    assert motors.log == [("send", 1, 10.0, None), ("stop", 1, None, None)]


def test_idle_means_nothing_for_the_writer_or_the_deadman() -> None:
    """The node's deadman timer sleeps while its guard is idle: a value offered, a stream
    that may move or a stop pending keeps it awake; a stream only locked does not."""
    guard, motors, _ = make()
    assert guard.idle()
    guard.offer(1, 10.0)
    assert not guard.idle()  # offered, not yet applied
    guard.command(1, guard.take(1) or 0.0)
    assert not guard.idle()  # moving
    motors.fail = 1
    with pytest.raises(LinkTimeout):
        guard.stop(1)
    assert not guard.idle()  # the stop is pending
    guard.stop(1)
    assert guard.idle()
    guard.hold(2)
    assert guard.idle()  # locked only: nothing to watch, an arrival (a 0) unlocks it
