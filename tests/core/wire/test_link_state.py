"""One owner of the link state: the channel's ``LinkState`` tells the poller and the node
(a listener standing in for ``~/connected``) every edge, whichever transaction caused it.

A real ``DeviceChannel`` on a real TCP socket to a pymodbus simulator; a command's loss
is a write whose reply the simulator withholds.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import pytest

from bridge_core.runtime.poller import Poller, PollOutcome
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import LinkTimeout
from bridge_core.wire.link_state import LinkEvent, LinkState
from bridge_core.wire.registers import Access, Register, RegisterMap, ValueType
from bridge_core.wire.transport import ModbusLink, TcpSettings

MAP = RegisterMap(
    "link",
    (
        Register("status", 0, ValueType.U16, "test"),
        Register("speed", 1, ValueType.U16, "test", access=Access.READ_WRITE),
    ),
)
TIMEOUT_S = 0.2
WAIT_S = 10.0


@pytest.fixture
def sim() -> Iterator[Simulator]:
    simulator = Simulator([SimulatedDevice(MAP, 1)])
    simulator.start_tcp()
    yield simulator
    simulator.stop()


def make_channel(sim: Simulator) -> DeviceChannel:
    port = sim.port
    return DeviceChannel(
        ModbusLink(TcpSettings(port=port, timeout_s=TIMEOUT_S)), 1, retries=0, reconnect_max_s=0.3
    )


class Bench:
    """A channel with a poller and a node-side listener, as ``BridgeNode`` wires them."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.channel = make_channel(sim)
        self.reports: list[tuple[PollOutcome, str]] = []
        self.link_ups: list[int] = []  # the channel generation each link-up work ran on
        self.node: list[LinkEvent] = []  # what the node heard (~/connected follows it)
        self.during_poll: Callable[[], None] = lambda: None
        self.poller: Poller[list[int]] = Poller(
            self.channel,
            self._poll,
            lambda _snapshot: None,
            rate_hz=10.0,
            link_up=lambda: self.link_ups.append(self.channel.generation),
            report=lambda outcome, text: self.reports.append((outcome, text)),
        )
        self.channel.link_state.add_listener(lambda event, _text: self.node.append(event))

    def _poll(self) -> list[int]:
        values = self.channel.read_registers(0, 2)
        hook, self.during_poll = self.during_poll, lambda: None
        hook()  # after the poll's last reply, before the poller is back
        return values

    def outcomes(self) -> list[PollOutcome]:
        return [outcome for outcome, _ in self.reports]

    def command_loses_the_link(self) -> None:
        """A command on another thread whose write gets no reply."""
        failed: list[BaseException] = []

        def command() -> None:
            with self.channel.labelled("set speed"), self.channel.command_session():
                try:
                    self.channel.write_register(1, 9)
                except LinkTimeout as err:
                    failed.append(err)

        self.sim.withhold_replies = True
        try:
            self.on_thread(command)
        finally:
            self.sim.withhold_replies = False
        assert failed and not self.channel.connected

    def stop_reconnects(self) -> None:
        """A stop sent while the link is marked down (no session) gets through."""
        self.on_thread(lambda: self.channel.write_register(1, 0))
        assert self.channel.connected

    @staticmethod
    def on_thread(work: Callable[[], object]) -> None:
        thread = threading.Thread(target=work)
        thread.start()
        thread.join(WAIT_S)
        assert not thread.is_alive()


def wait_until(predicate: Callable[[], bool]) -> None:
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


def test_a_commands_link_loss_reaches_the_poller_and_the_node_with_no_call_between(
    sim: Simulator,
) -> None:
    bench = Bench(sim)
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.node == [LinkEvent.UP]
    bench.command_loses_the_link()
    # Nobody called the poller or the node: the channel told both, once, naming the command.
    assert bench.outcomes() == [PollOutcome.LINK_LOST]
    assert bench.reports[0][1].startswith("set speed: "), bench.reports
    assert bench.node == [LinkEvent.UP, LinkEvent.LOST]
    # A stop that fails too while the link is down is no further loss.
    sim.withhold_replies = True
    with pytest.raises(LinkTimeout):
        bench.channel.write_register(1, 0)
    sim.withhold_replies = False
    assert bench.outcomes() == [PollOutcome.LINK_LOST]
    assert bench.node == [LinkEvent.UP, LinkEvent.LOST]
    # Up again only with a good poll.
    wait_until(bench.channel.may_attempt)
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.node == [LinkEvent.UP, LinkEvent.LOST, LinkEvent.UP]
    assert bench.outcomes() == [PollOutcome.LINK_LOST]


def test_link_up_after_a_commands_reconnect_runs_the_link_up_work_once_per_generation(
    sim: Simulator,
) -> None:
    """Also when the loss and the reconnect land between a poll's last reply and the
    poller's return (the poll's connection is gone: its confirmation must not count)."""
    bench = Bench(sim)
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.link_ups == [0]  # before the first poll, while down
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.link_ups == [0]  # same connection: no link-up work

    def lose_and_reconnect() -> None:
        bench.command_loses_the_link()
        bench.stop_reconnects()

    bench.during_poll = lose_and_reconnect
    assert bench.poller.tick() is PollOutcome.PUBLISHED  # read before the loss
    assert bench.channel.generation == 2 and bench.link_ups == [0]
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.link_ups == [0, 2]
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.link_ups == [0, 2]
    # Between two polls.
    lose_and_reconnect()
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.link_ups == [0, 2, 3]
    assert bench.outcomes() == [PollOutcome.LINK_LOST, PollOutcome.LINK_LOST]


def test_a_loss_after_a_polls_last_reply_is_not_followed_by_connected(sim: Simulator) -> None:
    """The rare race: a command lost the link after a poll's last reply and before the
    poller said "up": ``~/connected`` must stay false until a poll on the new link."""
    bench = Bench(sim)
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    bench.channel.mark_down("another poll's loss")  # down: the next poll is a probe
    wait_until(bench.channel.may_attempt)
    bench.during_poll = bench.command_loses_the_link
    assert bench.poller.tick() is PollOutcome.PUBLISHED  # the probe's reply came first
    assert bench.node == [LinkEvent.UP, LinkEvent.LOST]
    assert not bench.channel.connected
    wait_until(bench.channel.may_attempt)
    assert bench.poller.tick() is PollOutcome.PUBLISHED
    assert bench.node == [LinkEvent.UP, LinkEvent.LOST, LinkEvent.UP]


# ---------------------------------------------------------------- the state alone


def test_edges_are_announced_once_each() -> None:
    state = LinkState()
    heard: list[tuple[LinkEvent, str]] = []
    remove = state.add_listener(lambda event, text: heard.append((event, text)))
    state.went_down("cannot open")
    state.went_down("cannot open")
    assert heard == [(LinkEvent.UNREACHABLE, "cannot open")]
    state.answered()
    epoch = state.epoch
    assert state.link_up_due and state.confirm(epoch)
    assert not state.link_up_due
    assert state.confirm(epoch)  # a further good poll: no edge
    state.lose("short reply")
    state.went_down("no reply")
    assert heard[1:] == [(LinkEvent.UP, ""), (LinkEvent.LOST, "short reply")]
    assert state.losses == 2
    state.answered()
    assert not state.confirm(epoch)  # a poll begun before the loss confirms nothing
    remove()
    assert state.confirm(state.epoch)
    assert len(heard) == 3


def test_a_failing_listener_does_not_break_the_link_or_the_others() -> None:
    state = LinkState()
    heard: list[LinkEvent] = []

    def broken(_event: LinkEvent, _text: str) -> None:
        raise RuntimeError("a bug")

    state.add_listener(broken)
    state.add_listener(lambda event, _text: heard.append(event))
    state.went_down("no reply")
    assert heard == [LinkEvent.UNREACHABLE] and not state.connected
