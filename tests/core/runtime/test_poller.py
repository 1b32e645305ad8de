"""The poller with a fake device and a fake clock (no ROS, no sockets)."""

from __future__ import annotations

import threading

import pytest

from bridge_core.runtime.poller import Poller, PollOutcome, next_deadline
from bridge_core.wire.errors import (
    DeviceException,
    FrameError,
    LinkTimeout,
    PollIncomplete,
)
from bridge_core.wire.link_state import LinkEvent

from ...support.fakes import FakeChannel, FakeClock, FakeDevice, ScriptedBus


def listen(channel: FakeChannel) -> list[bool]:
    """What a node would publish on ``~/connected``: each edge the channel announces."""
    ups: list[bool] = []
    channel.link_state.add_listener(lambda event, _text: ups.append(event is LinkEvent.UP))
    return ups


def make(
    channel: FakeChannel, device: FakeDevice, published: list[int], events: list[PollOutcome]
) -> Poller[int]:
    return Poller(
        channel,
        device.poll,
        published.append,
        rate_hz=10.0,
        link_up=device.link_up,
        replan=device.replan,
        report=lambda outcome, _text: events.append(outcome),
        clock=FakeClock(1000.0),
    )


def test_publishes_and_reports_connected_once() -> None:
    channel = FakeChannel()
    device = FakeDevice(channel)
    published: list[int] = []
    ups = listen(channel)
    poller = Poller(channel, device.poll, published.append, rate_hz=5.0)
    assert poller.tick() is PollOutcome.PUBLISHED
    assert poller.tick() is PollOutcome.PUBLISHED
    assert poller.publish_pending() == 2
    assert published == [1, 2]
    assert ups == [True]  # a change, not every poll


def test_device_exception_replans_instead_of_failing_forever() -> None:
    channel = FakeChannel()
    device = FakeDevice(channel)
    events: list[PollOutcome] = []
    published: list[int] = []
    poller = make(channel, device, published, events)
    assert poller.tick() is PollOutcome.PUBLISHED
    device.errors.append(DeviceException(3, 2))  # ILLEGAL DATA ADDRESS: an axis went away
    assert poller.tick() is PollOutcome.REFUSED
    assert device.replans == 1
    assert poller.last_error is not None and "ILLEGAL DATA ADDRESS" in poller.last_error
    assert poller.tick() is PollOutcome.PUBLISHED
    assert poller.last_error is None and poller.failures == 1
    assert events == [PollOutcome.REFUSED]


def test_link_loss_reported_once_and_backoff_respected() -> None:
    channel = FakeChannel()
    device = FakeDevice(channel)
    events: list[PollOutcome] = []
    ups = listen(channel)
    poller = Poller(
        channel,
        device.poll,
        lambda _s: None,
        rate_hz=10.0,
        link_up=device.link_up,
        report=lambda outcome, _text: events.append(outcome),
    )
    assert poller.tick() is PollOutcome.PUBLISHED
    assert device.link_ups == 1  # before the first poll
    device.errors += [LinkTimeout("no reply"), LinkTimeout("no reply")]
    assert poller.tick() is PollOutcome.LINK_LOST
    channel.backoff_elapsed = False
    assert poller.tick() is PollOutcome.SKIPPED
    assert device.polls == 2  # nothing attempted while backing off
    channel.backoff_elapsed = True
    assert poller.tick() is PollOutcome.LINK_LOST
    # The loss once, then each failed probe (the node throttles those on the console).
    assert events == [PollOutcome.LINK_LOST, PollOutcome.STILL_DOWN]
    assert poller.tick() is PollOutcome.PUBLISHED
    assert device.link_ups == 3  # first poll, then each probe of the down device
    assert ups == [True, False, True]


def test_incomplete_and_unexpected_errors_never_end_polling() -> None:
    channel = FakeChannel()
    device = FakeDevice(channel)
    events: list[PollOutcome] = []
    poller = make(channel, device, [], events)
    device.errors += [PollIncomplete("re-planned"), ZeroDivisionError("bug")]
    channel.connected = True
    assert poller.tick() is PollOutcome.INCOMPLETE
    assert poller.tick() is PollOutcome.FAILED
    assert poller.tick() is PollOutcome.PUBLISHED
    assert events == [PollOutcome.INCOMPLETE, PollOutcome.FAILED]


def test_a_slow_publisher_keeps_the_newest_snapshots() -> None:
    channel = FakeChannel()
    device = FakeDevice(channel)
    published: list[int] = []
    poller = make(channel, device, published, [])
    for _ in range(20):
        poller.tick()
    poller.publish_pending()
    assert published == list(range(13, 21))  # PUBLISH_BACKLOG newest
    assert poller.snapshots_dropped == 12


def test_publish_failure_is_reported_not_raised() -> None:
    channel = FakeChannel()
    device = FakeDevice(channel)
    events: list[PollOutcome] = []

    def publish(_snapshot: int) -> None:
        raise OverflowError("value does not fit the message")

    poller = Poller(
        channel,
        device.poll,
        publish,
        rate_hz=10.0,
        report=lambda outcome, _text: events.append(outcome),
    )
    poller.tick()
    assert poller.publish_pending() == 1
    assert events == [PollOutcome.FAILED]
    assert poller.last_error is not None and "publishing failed" in poller.last_error


def test_pacing_never_bursts_after_an_overrun() -> None:
    assert next_deadline(10.0, 10.02, 0.1) == pytest.approx(10.1)
    assert next_deadline(10.0, 10.35, 0.1) == 10.35  # overrun: poll now, no catch-up burst


def test_rate_is_live_and_validated() -> None:
    channel = FakeChannel()
    poller = make(channel, FakeDevice(channel), [], [])
    poller.rate_hz = 2.5
    assert poller.rate_hz == 2.5
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError):
            poller.rate_hz = bad


def test_a_command_that_loses_the_link_is_followed_by_connected_again() -> None:
    """A command's LinkError marks the link down; the next good poll must say up again
    (two owners of the connected state once left it false while polls succeeded)."""
    channel = FakeChannel()
    device = FakeDevice(channel)
    ups = listen(channel)
    events: list[PollOutcome] = []
    poller = Poller(
        channel,
        device.poll,
        lambda _s: None,
        rate_hz=10.0,
        report=lambda outcome, _text: events.append(outcome),
    )
    assert poller.tick() is PollOutcome.PUBLISHED
    channel.connected = False  # a command's failure: the channel's, nobody tells the poller
    assert events == [PollOutcome.LINK_LOST]
    assert poller.tick() is PollOutcome.PUBLISHED
    assert ups == [True, False, True]
    assert events == [PollOutcome.LINK_LOST]


def test_one_link_loss_seen_by_a_command_and_a_poll_at_once_is_reported_once() -> None:
    """A command and a poll fail together on one loss: one LINK_LOST (the console's ERROR
    line) and one connected=false edge, whichever failed first."""
    channel = FakeChannel()
    device = FakeDevice(channel)
    ups = listen(channel)
    events: list[PollOutcome] = []

    def poll() -> int:
        if device.polls:  # the second poll: a command fails on another thread meanwhile
            command = threading.Thread(target=setattr, args=(channel, "connected", False))
            command.start()
            command.join(5)
        return device.poll()

    poller = Poller(
        channel,
        poll,
        lambda _s: None,
        rate_hz=10.0,
        report=lambda outcome, _text: events.append(outcome),
    )
    assert poller.tick() is PollOutcome.PUBLISHED
    device.errors.append(LinkTimeout("no reply"))
    assert poller.tick() is PollOutcome.LINK_LOST
    assert events == [PollOutcome.LINK_LOST]
    assert ups == [True, False]


def test_a_reply_too_short_is_a_loss_until_the_next_good_poll() -> None:
    """A LinkError the transport did not see (a short reply: the channel stays connected)
    is a loss all the same, and the next good poll says up again without link-up work
    (the connection was never closed)."""
    channel = FakeChannel()
    ups = listen(channel)
    events: list[PollOutcome] = []
    link_ups: list[int] = []
    replies: list[Exception | None] = [None, FrameError("short reply: 1 of 2 values"), None]

    def poll() -> int:
        channel.connected = True  # answered
        error = replies.pop(0)
        if error is not None:
            raise error
        return 1

    poller = Poller(
        channel,
        poll,
        lambda _s: None,
        rate_hz=10.0,
        link_up=lambda: link_ups.append(channel.link_state.generation),
        report=lambda outcome, _text: events.append(outcome),
    )
    assert [poller.tick() for _ in range(3)] == [
        PollOutcome.PUBLISHED,
        PollOutcome.LINK_LOST,
        PollOutcome.PUBLISHED,
    ]
    assert events == [PollOutcome.LINK_LOST]
    assert ups == [True, False, True]
    assert link_ups == [0] and channel.connected


def test_a_stop_that_reconnected_between_polls_still_gets_the_link_up_work() -> None:
    """A stop sent while the link was down may reconnect it before the next poll: the
    poller must still run link_up (re-read the configuration) once for that connection."""
    channel = FakeChannel()
    device = FakeDevice(channel)
    published: list[int] = []
    events: list[PollOutcome] = []
    poller = make(channel, device, published, events)
    assert poller.tick() is PollOutcome.PUBLISHED
    assert device.link_ups == 1
    assert poller.tick() is PollOutcome.PUBLISHED
    assert device.link_ups == 1  # same connection: no link-up work
    device.errors.append(LinkTimeout("gone"))
    assert poller.tick() is PollOutcome.LINK_LOST
    channel.connected = True  # a stop command got through: a new connection
    assert poller.tick() is PollOutcome.PUBLISHED
    assert device.link_ups == 2
    assert poller.tick() is PollOutcome.PUBLISHED
    assert device.link_ups == 2


def test_a_poll_stops_at_its_next_request_once_a_command_lost_the_link() -> None:
    """The rest of a poll is not sent after the link was marked down mid-poll: when the
    link is back, the first thing sent is the link-up work (pending stops first)."""
    from bridge_core.wire.channel import DeviceChannel

    transport = ScriptedBus()
    channel = DeviceChannel(transport, 1, retries=0)
    channel.read_registers(0, 1)  # connected
    requests_before = len(transport.executed)

    def poll() -> int:
        channel.read_registers(0, 1)
        channel.mark_down("a command timed out")  # another thread's command, meanwhile
        channel.read_registers(1, 1)  # must not be sent
        return 1

    events: list[PollOutcome] = []
    poller = Poller(
        channel,
        poll,
        lambda _snapshot: None,
        rate_hz=10.0,
        report=lambda outcome, _text: events.append(outcome),
        clock=FakeClock(1000.0),
    )
    assert poller.tick() is PollOutcome.LINK_LOST
    assert len(transport.executed) == requests_before + 1


def test_a_probe_poll_yields_to_a_stop_that_failed_while_it_waited() -> None:
    """A poll that starts while the link is down may reconnect it, unless the link was
    marked down again meanwhile (a deadman stop failed: it is pending and goes first)."""
    from bridge_core.wire.channel import DeviceChannel

    transport = ScriptedBus()
    channel = DeviceChannel(transport, 1, retries=0)  # never connected: polls are probes

    def poll() -> int:
        channel.mark_down("the deadman's stop timed out")  # another thread, meanwhile
        channel.read_registers(0, 1)
        return 1

    poller = Poller(channel, poll, lambda _snapshot: None, rate_hz=10.0, clock=FakeClock(1000.0))
    assert poller.tick() is PollOutcome.LINK_LOST
    assert transport.executed == []
    # Without a stop failing meanwhile, the probe (once the backoff allows) reconnects.
    channel.backoff.succeeded()
    poller = Poller(channel, lambda: channel.read_registers(0, 1)[0], lambda _s: None, rate_hz=10.0)
    assert poller.tick() is PollOutcome.PUBLISHED and channel.connected
