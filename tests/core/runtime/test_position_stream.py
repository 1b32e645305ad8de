"""The stream guard's position streams: ``zero_stops=False``, ``follow`` and
``Deferred``, with a fake device and a fake clock."""

from __future__ import annotations

import threading

import pytest

from bridge_core.runtime.stream_guard import Deferred, StreamGuard
from bridge_core.wire.errors import CommandRejected, LinkTimeout

from ...support.fakes import FakeClock


class Axis:
    """Records sends and stops; ``busy`` makes a send of a stream that commanded before
    raise ``Deferred``; ``fail`` makes the next writes time out."""

    def __init__(self) -> None:
        self.log: list[tuple[str, int, float | None]] = []
        self.busy = False
        self.fail = 0

    def send(self, key: int, value: float, previous: float | None) -> None:
        if self.busy and previous is not None:
            raise Deferred
        if self.fail:
            self.fail -= 1
            raise LinkTimeout("no reply")
        self.log.append(("send", key, value))

    def stop(self, key: int) -> None:
        if self.fail:
            self.fail -= 1
            raise LinkTimeout("no reply")
        self.log.append(("stop", key, None))


def pair() -> tuple[StreamGuard[int], StreamGuard[int], Axis, Axis, FakeClock]:
    """A velocity guard and a position guard that follows it."""
    clock = FakeClock()
    jog, target = Axis(), Axis()
    velocity = StreamGuard((1, 2), jog.send, jog.stop, timeout_s=0.5, clock=clock)
    position = StreamGuard(
        (1, 2),
        target.send,
        target.stop,
        timeout_s=0.5,
        stop_when_idle=False,
        zero_stops=False,
        min_interval_s=0.2,
        clock=clock,
    )
    position.follow(velocity)
    return velocity, position, jog, target, clock


def test_zero_is_a_target_not_a_stop() -> None:
    _, position, _, target, clock = pair()
    assert position.command(1, 5.0)
    clock.now = 1.0
    assert position.command(1, 0.0)  # a target: sent, not a stop
    assert not position.command(1, 0.0)  # a repeat writes nothing
    assert target.log == [("send", 1, 5.0), ("send", 1, 0.0)]
    assert position[1].active and not position[1].locked


def test_a_zero_target_waits_for_the_rate_like_any_value() -> None:
    _, position, _, _, clock = pair()
    position.offer(1, 3.0)
    position.command(1, position.take(1) or 0.0)
    clock.now = 0.05
    assert not position.offer(1, 0.0)  # not ready at once: the rate applies to 0 too
    assert position.ready() == []
    clock.now = 0.25
    assert position.ready() == [1]


def test_a_halt_drops_an_offered_zero_target() -> None:
    _, position, _, target, _ = pair()
    position.command(1, 2.0)
    position.offer(1, 0.0)
    assert position.stop_all() == []
    assert position.take(1) is None  # a 0 target is not a stop someone asked for
    assert target.log[-1] == ("stop", 1, None) and position[1].locked


def test_a_target_held_where_the_joint_stands_unlocks_a_position_stream() -> None:
    """A stopped position stream moves again only on a target ``near`` where the
    joint stands (judged by joint_commands) that the controller holds (a repeat of the
    previous arrival) or that comes after timeout_s of silence; never on silence alone,
    never on a trajectory that runs on through the stop, never on a target from afar."""
    velocity, position, _, target, clock = pair()
    position.offer(1, 2.0, near=True)
    position.command(1, position.take(1) or 0.0)
    velocity.taken_over(1, locked=True)  # a stop service of the motor
    assert position[1].locked and not position[1].active
    with pytest.raises(CommandRejected, match="stopped"):
        position.command(1, 0.0)  # 0 is a target: refused, does not unlock
    # A trajectory that runs on: every target new, near where the joint stopped.
    for step in range(5):
        clock.now += 0.01
        position.offer(1, 2.01 + step * 0.01, near=True)
    with pytest.raises(CommandRejected, match="hold a target"):
        position.command(1, position.take(1) or 0.0)
    clock.now += 0.6
    assert position.due() == [] and not position.expire(1)  # silence alone: still locked
    position.offer(1, 9.0)  # after silence, but from afar
    clock.now += 0.01
    position.offer(1, 9.0)  # held, but from afar
    with pytest.raises(CommandRejected, match="stopped"):
        position.command(1, position.take(1) or 0.0)
    clock.now += 0.01
    position.offer(1, 2.01, near=True)  # a new target where it stands, not yet held
    with pytest.raises(CommandRejected, match="stopped"):
        position.command(1, position.take(1) or 0.0)
    clock.now += 0.01
    position.offer(1, 2.01, near=True)  # held: the controller holds the joint there
    assert position.command(1, position.take(1) or 0.0)
    assert target.log[-1] == ("send", 1, 2.01)
    velocity.taken_over(1, locked=True)
    position.hear(1)  # refused before the guard (inactive): an arrival, not silence
    clock.now += 0.3
    position.hear(1)
    clock.now += 0.3
    position.offer(1, 2.02, near=True)
    with pytest.raises(CommandRejected, match="stopped"):
        position.command(1, position.take(1) or 0.0)
    clock.now += 0.6  # a new trajectory after real silence, starting where it stands
    position.offer(1, 2.03, near=True)
    assert position.command(1, position.take(1) or 0.0)


def test_the_follower_shares_the_leaders_lock_and_takeovers() -> None:
    velocity, position, _, _, _ = pair()
    assert position.lock is velocity.lock
    position.command(1, 4.0)
    position.command(2, 4.0)
    velocity.taken_over(1, locked=False)  # homing or a goal took motor 1 over
    assert not position[1].active and not position[1].locked and position[2].active
    velocity.hold(2)  # a stop coil of other registers
    assert position[2].locked and position[2].active  # its own stop is still due
    velocity.stop_failed(2)  # an e-stop lost on the link
    assert position[2].stop_pending


def test_a_writer_of_one_waits_while_the_other_stops() -> None:
    """One RLock: a stop of the velocity stream and a write of the position stream never
    interleave (the position send runs while another thread waits for the lock)."""
    velocity, position, _, target, _ = pair()
    entered, release = threading.Event(), threading.Event()
    order: list[str] = []

    def slow_send(key: int, value: float, previous: float | None) -> None:
        entered.set()
        release.wait(5)
        order.append("send")

    position._send = slow_send
    writer = threading.Thread(target=position.command, args=(1, 3.0))
    writer.start()
    assert entered.wait(5)

    def stop() -> None:
        velocity.stop(1)
        order.append("stop")

    stopper = threading.Thread(target=stop)
    stopper.start()
    stopper.join(0.2)
    assert stopper.is_alive()  # waits for the position write to finish
    release.set()
    writer.join(5)
    stopper.join(5)
    assert order == ["send", "stop"]
    assert target.log == []


def test_a_deferred_value_waits_for_the_next_pass() -> None:
    _, position, _, target, clock = pair()
    assert position.command(1, 5.0)
    target.busy = True  # still running to 5.0
    clock.now = 0.3
    position.offer(1, 6.0)
    assert not position.command(1, position.take(1) or 0.0)  # deferred: nothing written
    assert target.log == [("send", 1, 5.0)]
    assert position[1].value == 5.0 and position[1].offered == 6.0  # offered again
    clock.now = 0.4
    assert position.ready() == []  # the rate applies to the retry too
    position.offer(1, 7.0)  # a newer value replaces the deferred one
    target.busy = False
    clock.now = 0.6
    assert position.ready() == [1]
    assert position.command(1, position.take(1) or 0.0)
    assert target.log[-1] == ("send", 1, 7.0)


def test_a_deferred_value_does_not_replace_a_newer_one() -> None:
    _, position, _, target, clock = pair()
    position.command(1, 5.0)
    target.busy = True
    clock.now = 0.3
    value = 6.0
    position.offer(1, 7.0)  # arrived while 6.0 was being tried
    assert not position.command(1, value)
    assert position[1].offered == 7.0


def test_a_lost_position_write_leaves_its_stop_pending() -> None:
    _, position, _, target, _ = pair()
    target.fail = 1
    with pytest.raises(LinkTimeout):
        position.command(1, 5.0)
    assert position[1].stop_pending and position.due() == [1]
    assert position.expire(1)
    assert target.log == [("stop", 1, None)]


def test_the_deadman_drops_a_value_that_waited_past_the_silence() -> None:
    """A target deferred (the motor still ran the previous one) when the client fell
    silent is never written after the deadman's stop."""
    _, position, _, target, clock = pair()
    position.offer(1, 5.0)
    position.command(1, position.take(1) or 0.0)
    target.busy = True
    clock.now = 0.3
    position.offer(1, 6.0)
    assert not position.command(1, position.take(1) or 0.0)  # deferred, offered again
    clock.now = 0.9  # 0.6 s since the newest message: silent
    assert position.due() == [1]
    assert position.expire(1)
    assert position[1].offered is None and position.ready() == []
    assert target.log == [("send", 1, 5.0), ("stop", 1, None)]
