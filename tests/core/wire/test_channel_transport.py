"""The channel and its transport: lock ordering, backoff, faults over TCP and RTU (real
sockets and ptys).

The error translation tests drive the real pymodbus clients against replay peers on a
socket or a pty and check the ``bridge_core.wire.errors`` type and the cause behind it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress

import pytest
from pymodbus.exceptions import ModbusIOException

from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.channel import DeviceChannel, Priority, PriorityLock
from bridge_core.wire.errors import DeviceException, FrameError, LinkDown, LinkTimeout
from bridge_core.wire.link_stats import Backoff
from bridge_core.wire.ports import free_port
from bridge_core.wire.registers import (
    Access,
    DeviceLimits,
    Register,
    RegisterMap,
    ValueType,
    register_array,
)
from bridge_core.wire.requests import ReadRegisters
from bridge_core.wire.serial_timing import ReplyCrcError, ReplyFromOtherUnit
from bridge_core.wire.transport import (
    ModbusLink,
    ReplyFromOtherTransaction,
    SerialSettings,
    TcpSettings,
)

from ...support.fakes import ScriptedBus
from ...support.replay import ReplayServer
from ...support.replay import Step as TcpStep
from ...support.rtu_replay import RtuReplay, rtu_frame
from ...support.rtu_replay import Step as RtuStep
from ...support.serial_pair import socat_pair

TEST_MAP = RegisterMap(
    "test",
    (
        *register_array(
            "word", 0, 10, ValueType.U16, "test", access=Access.READ_WRITE, first_index=0
        ),
        Register("big", 10, ValueType.I32, "test", access=Access.READ_WRITE),
    ),
    DeviceLimits(max_read_registers=12),
)


def wait_until(predicate, timeout: float = 10.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.005)


def test_priority_lock_serves_feeds_then_commands_first_then_fifo() -> None:
    lock = PriorityLock()
    order: list[str] = []
    holder_in = threading.Event()
    release = threading.Event()

    def holder() -> None:
        with lock.hold(Priority.POLL):
            holder_in.set()
            release.wait(5)

    def waiter(name: str, priority: Priority) -> None:
        with lock.hold(priority):
            order.append(name)

    threads = [threading.Thread(target=holder)]
    threads[0].start()
    holder_in.wait(5)
    for name, priority in [
        ("poll-1", Priority.POLL),
        ("poll-2", Priority.POLL),
        ("command-1", Priority.COMMAND),
        ("command-2", Priority.COMMAND),
        ("feed-1", Priority.KEEPALIVE),
    ]:
        t = threading.Thread(target=waiter, args=(name, priority))
        t.start()
        threads.append(t)
        waiting = len(threads) - 1
        wait_until(lambda n=waiting: len(lock._waiting) == n)
    release.set()
    for t in threads:
        t.join(5)
    assert order == ["feed-1", "command-1", "command-2", "poll-1", "poll-2"]


def test_a_retry_lets_a_queued_feed_go_first() -> None:
    """A read of a device that just died is retried, but each attempt takes the lock on
    its own: a watchdog feed to a live device queued during the first timeout goes
    before the retry, so no request waits for more than one timeout."""
    bus = ScriptedBus()
    dying = DeviceChannel(bus, 7, retries=1)
    live = DeviceChannel(bus, 1, retries=1)
    dying.read_registers(0, 1)  # connected: its reads get a retry
    bus.executed.clear()
    timeout = threading.Event()
    bus.script[7] = [timeout, LinkTimeout("unit 7: no reply")]
    failed: list[BaseException] = []

    def poll_dying() -> None:
        try:
            dying.read_registers(0, 1)
        except LinkTimeout as err:
            failed.append(err)

    poller = threading.Thread(target=poll_dying)
    poller.start()
    assert bus.entered.wait(10)
    feeder = threading.Thread(target=lambda: live.write_register(3, 9, Priority.KEEPALIVE))
    feeder.start()
    wait_until(lambda: len(bus.lock._waiting) == 1)
    timeout.set()
    poller.join(10)
    feeder.join(10)
    assert [(unit, type(r).__name__) for unit, r in bus.executed] == [
        (7, "ReadRegisters"),
        (1, "WriteRegister"),
        (7, "ReadRegisters"),
    ]
    assert failed and not dying.connected and live.connected


def _quietly(call: Callable[[], object]) -> None:
    """Run ``call``; the timeout of the absent device is expected."""
    with suppress(LinkTimeout):
        call()


def test_a_stop_goes_in_the_next_free_slot() -> None:
    """On a shared line a stop queued behind another device's transaction goes
    right after it, before the commands and polls that queued up earlier (feeds aside)."""
    bus = ScriptedBus()
    absent = DeviceChannel(bus, 7, retries=0)
    live = DeviceChannel(bus, 1, retries=0)
    stopping = DeviceChannel(bus, 3, retries=0)
    blocked = threading.Event()
    bus.script[7] = [blocked]
    calls: list[tuple[Callable[[], object], bool]] = [
        (lambda: absent.read_registers(0, 1), True),  # in progress until released
        (lambda: live.read_registers(0, 1), False),  # a poll
        (lambda: live.write_coil(5, True), False),  # a command
        (lambda: stopping.write_coil(4, True, Priority.STOP), False),
    ]
    threads = []
    for queued, (call, first) in enumerate(calls):
        t = threading.Thread(target=_quietly, args=(call,))
        t.start()
        threads.append(t)
        if first:
            assert bus.entered.wait(10)
        else:
            wait_until(lambda n=queued: len(bus.lock._waiting) == n)
    blocked.set()
    for t in threads:
        t.join(10)
    assert [(unit, type(r).__name__) for unit, r in bus.executed] == [
        (7, "ReadRegisters"),
        (3, "WriteCoil"),
        (1, "WriteCoil"),
        (1, "ReadRegisters"),
    ]


def test_backoff_doubles_up_to_the_cap() -> None:
    now = [100.0]
    backoff = Backoff(0.25, 2.0, clock=lambda: now[0])
    delays = []
    for _ in range(6):
        backoff.failed()
        delays.append(backoff.delay_s)
    assert delays == [0.25, 0.5, 1.0, 2.0, 2.0, 2.0]
    assert not backoff.ready()
    now[0] += 2.0
    assert backoff.ready()
    backoff.succeeded()
    assert backoff.delay_s == 0.0 and backoff.ready()


@pytest.fixture
def tcp_sim() -> Iterator[tuple[Simulator, int]]:
    sim = Simulator([SimulatedDevice(TEST_MAP, 1)])
    port = sim.start_tcp()
    yield sim, port
    sim.stop()


def test_tcp_withheld_replies_time_out_and_recover(tcp_sim: tuple[Simulator, int]) -> None:
    sim, port = tcp_sim
    channel = DeviceChannel(
        ModbusLink(TcpSettings(port=port, timeout_s=0.2)), 1, retries=1, reconnect_max_s=0.5
    )
    sim.device.set("big", -5)
    assert channel.read_registers(10, 2) == [0xFFFF, 0xFFFB]
    sim.withhold_replies = True
    with pytest.raises(LinkTimeout):
        channel.read_registers(0, 1)
    assert channel.stats.timeouts == 2  # one retry for a read
    assert not channel.connected
    sim.withhold_replies = False
    wait_until(channel.may_attempt, timeout=2)
    assert channel.read_registers(0, 1) == [0]
    assert channel.connected and channel.stats.reconnects == 1


def test_writes_are_never_retried(tcp_sim: tuple[Simulator, int]) -> None:
    sim, port = tcp_sim
    channel = DeviceChannel(ModbusLink(TcpSettings(port=port, timeout_s=0.2)), 1, retries=3)
    channel.read_registers(0, 1)
    sim.withhold_replies = True
    with pytest.raises(LinkTimeout):
        channel.write_register(3, 9)
    assert channel.stats.timeouts == 1


def test_exception_reply_keeps_the_link_up(tcp_sim: tuple[Simulator, int]) -> None:
    _, port = tcp_sim
    channel = DeviceChannel(ModbusLink(TcpSettings(port=port, timeout_s=0.5)), 1)
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
        channel.read_registers(11, 1)  # cuts the int32 at 10-11
    assert channel.connected


def test_server_gone_and_back(tcp_sim: tuple[Simulator, int]) -> None:
    sim, port = tcp_sim
    channel = DeviceChannel(
        ModbusLink(TcpSettings(port=port, timeout_s=0.3)), 1, retries=0, reconnect_max_s=0.4
    )
    channel.read_registers(0, 2)
    sim.stop()
    with pytest.raises((LinkDown, LinkTimeout)):
        channel.read_registers(0, 2)
    assert not channel.connected
    # Refused connects back off, capped at reconnect_max_s.
    for _ in range(4):
        wait_until(channel.may_attempt, timeout=1.0)
        with pytest.raises(LinkDown):
            channel.read_registers(0, 2)
    assert channel.backoff.delay_s == pytest.approx(0.4)
    sim.start_tcp(port=port)
    wait_until(channel.may_attempt, timeout=1.0)
    assert channel.read_registers(0, 2) == [0, 0]
    assert channel.connected and channel.stats.reconnects == 1


def test_rtu_several_units_on_one_pty_bus() -> None:
    devices = [SimulatedDevice(TEST_MAP, unit) for unit in (1, 2, 5)]
    for unit, device in zip((1, 2, 5), devices, strict=True):
        device.set("word_1", unit * 100)
    sim = Simulator(devices)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, baudrate=115200)
        try:
            link = ModbusLink(SerialSettings(bridge_end, 115200, timeout_s=0.3))
            channels = {
                u: DeviceChannel(link, u, retries=0, reconnect_max_s=5.0) for u in (1, 2, 5, 7)
            }
            for unit in (1, 2, 5):
                assert channels[unit].read_registers(0, 2) == [0, unit * 100]
            channels[2].write_registers(10, [0x1234, 0x5678])
            assert devices[1].get("big") == 0x12345678
            assert [r.unit_id for r in devices[1].write_log] == [2]
            assert devices[0].write_log == [] and devices[2].write_log == []
            # Unit 7 is not on the bus: it stays silent, times out and backs off on its own...
            with pytest.raises(LinkTimeout):
                channels[7].read_registers(0, 1)
            assert not channels[7].may_attempt()
            # ...while the others keep working on the same port.
            assert link.is_open
            for unit in (1, 2, 5):
                assert channels[unit].read_registers(1, 1) == [unit * 100]
                assert channels[unit].connected
            # Broadcast (unit 0) writes reach every unit and get no reply.
            broadcast = DeviceChannel(link, 0)
            broadcast.write_register(4, 77)
            wait_until(lambda: all(d.get("word_4") == 77 for d in devices), timeout=2)
            link.close()
        finally:
            sim.stop()


def test_rtu_unit_nobody_serves_times_out_and_the_served_one_answers() -> None:
    # Only unit 3 is on the bus. (A reply *from* the wrong unit: the replay tests below.)
    sim_device = SimulatedDevice(TEST_MAP, 3)
    sim = Simulator([sim_device])
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, baudrate=115200)
        try:
            link = ModbusLink(SerialSettings(bridge_end, 115200, timeout_s=0.3))
            # The simulator ignores requests for unit 1: silence, so a timeout.
            channel = DeviceChannel(link, 1, retries=0)
            with pytest.raises(LinkTimeout):
                channel.read_registers(0, 1)
            assert DeviceChannel(link, 3).read_registers(0, 1) == [0]
            link.close()
        finally:
            sim.stop()


def test_a_write_to_a_device_marked_down_waits_its_short_timeout() -> None:
    """A stop sent while the device is marked down has its own short reply timeout
    (down_write_timeout_s). A probe of a device that is down (a read) waits the link's
    timeout, or a device that answers later than the short wait is never found again
    (docs/behaviour.md, "Link loss and stale data"). Reads and writes to a live device
    keep the link's."""
    sim_device = SimulatedDevice(TEST_MAP, 3)
    sim = Simulator([sim_device])
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, baudrate=115200)
        try:
            link = ModbusLink(SerialSettings(bridge_end, 115200, timeout_s=0.8))
            # The short timeout still leaves a loaded host time for the last write's reply.
            channel = DeviceChannel(link, 3, retries=0, down_write_timeout_s=0.25)
            channel.write_register(1, 5)  # connected from here on
            sim.withhold_replies = True
            with pytest.raises(LinkTimeout, match=r"within 0\.8 s"):
                channel.write_register(1, 6)  # connected: the link's timeout
            assert not channel.connected
            with pytest.raises(LinkTimeout, match=r"within 0\.25 s"):
                channel.write_register(1, 7)  # marked down: the short one
            channel.backoff.succeeded()
            with pytest.raises(LinkTimeout, match=r"within 0\.8 s"):
                channel.read_registers(0, 1)  # a probe: the link's timeout
            sim.withhold_replies = False
            channel.write_register(1, 8)  # a stop that gets through: up again
            assert channel.connected and sim_device.get("word_1") == 8
            link.close()
        finally:
            sim.stop()


@pytest.mark.parametrize("at_start", [True, False], ids=["at_start", "after_outage"])
def test_a_device_answering_late_within_the_timeout_is_found(at_start: bool) -> None:
    """A device that answers later than the stop's short wait but within the link's
    timeout is connected at start and found again after an outage:
    stepper at 35-300 ms with timeout_s 0.5, stop_timeout_s 0.15. Stops keep the short
    wait."""
    sim_device = SimulatedDevice(TEST_MAP, 3)
    sim = Simulator([sim_device])
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, baudrate=115200)
        try:
            link = ModbusLink(SerialSettings(bridge_end, 115200, timeout_s=1.0))
            channel = DeviceChannel(link, 3, retries=0, down_write_timeout_s=0.15)
            if not at_start:
                channel.read_registers(0, 1)
                sim.withhold_replies = True
                with pytest.raises(LinkTimeout):
                    channel.read_registers(0, 1)
                sim.withhold_replies = False
                channel.backoff.succeeded()
            assert not channel.connected
            sim.set_reply_delay(0.3, 0.4)
            assert channel.read_registers(0, 1) == [0]  # the probe waits past 0.15 s
            assert channel.connected
            # A stop to the device marked down keeps the short wait.
            sim.withhold_replies = True
            with pytest.raises(LinkTimeout):
                channel.read_registers(0, 1)
            with pytest.raises(LinkTimeout, match=r"within 0\.15 s"):
                channel.write_register(1, 7)
            link.close()
        finally:
            sim.stop()


def test_a_device_that_is_down_is_probed_once_not_retried(tcp_sim: tuple[Simulator, int]) -> None:
    sim, port = tcp_sim
    channel = DeviceChannel(
        ModbusLink(TcpSettings(port=port, timeout_s=0.2)), 1, retries=2, reconnect_max_s=0.3
    )
    sim.withhold_replies = True
    with pytest.raises(LinkTimeout):
        channel.read_registers(0, 1)  # never connected: one probe
    assert channel.stats.timeouts == 1
    sim.withhold_replies = False
    wait_until(channel.may_attempt, timeout=2)
    channel.read_registers(0, 1)
    sim.withhold_replies = True
    with pytest.raises(LinkTimeout):
        channel.read_registers(0, 1)  # connected: 1 + 2 retries
    assert channel.stats.timeouts == 1 + 3


def test_a_command_that_waited_through_a_link_loss_is_not_sent(
    tcp_sim: tuple[Simulator, int],
) -> None:
    # A command passes the node's "connected" guard, waits for the lock while a poll
    # fails (device marked down, TCP closed); the poll's reconnect must not carry it.
    sim, port = tcp_sim
    channel = DeviceChannel(
        ModbusLink(TcpSettings(port=port, timeout_s=0.2)), 1, retries=0, reconnect_max_s=0.3
    )
    channel.read_registers(0, 1)
    with channel.command_session():
        sim.withhold_replies = True
        with pytest.raises(LinkTimeout):
            channel.read_registers(0, 1)  # the poll fails meanwhile
        sim.withhold_replies = False
        wait_until(channel.may_attempt, timeout=2)
        with pytest.raises(LinkDown, match="not sent"):
            channel.write_register(3, 9)
    assert sim.device.write_log == []
    # Outside a stale session (a new command after the reconnect) writes go through.
    channel.read_registers(0, 1)
    with channel.command_session():
        channel.write_register(3, 9)
    assert [r.values for r in sim.device.write_log] == [(9,)]


def test_writes_tried_counts_what_went_on_the_wire(tcp_sim: tuple[Simulator, int]) -> None:
    """A command's reply says "nothing was sent" only when none of its writes went out:
    the channel counts the writes this thread put on the wire (a timed-out one too), and
    not one refused before sending."""
    sim, port = tcp_sim
    channel = DeviceChannel(
        ModbusLink(TcpSettings(port=port, timeout_s=0.2)), 1, retries=0, reconnect_max_s=0.3
    )
    before = channel.writes_tried()
    channel.read_registers(0, 1)
    assert channel.writes_tried() == before
    with channel.command_session():
        channel.write_register(3, 9)
        assert channel.writes_tried() == before + 1
        sim.withhold_replies = True
        with pytest.raises(LinkTimeout):
            channel.write_register(3, 10)  # may have landed: counted
        assert channel.writes_tried() == before + 2
        sim.withhold_replies = False
        wait_until(channel.may_attempt, timeout=2)
        with pytest.raises(LinkDown, match="not sent"):
            channel.write_register(3, 11)
        assert channel.writes_tried() == before + 2
    seen: list[int] = []
    other = threading.Thread(target=lambda: seen.append(channel.writes_tried()))
    other.start()
    other.join(5)
    assert seen == [0]  # per thread: another command's writes are not this one's


# ---------------------------------------------------------------- error translation, by type

READ_ONE = bytes.fromhex("01 03 0000 0001")  # unit 1, FC 03, address 0, one register
ANSWER_7 = bytes.fromhex("01 03 02 0007")
TCP_TIMEOUT_S = 2.0  # long, so a reply that is reported at once cannot pass for a timeout
RTU_BAUD = 115200


@contextmanager
def tcp_replay(steps: list[TcpStep]) -> Iterator[tuple[ModbusLink, ReplayServer]]:
    server = ReplayServer(steps)
    link = ModbusLink(TcpSettings(port=server.port, timeout_s=TCP_TIMEOUT_S))
    try:
        yield link, server
    finally:
        link.close()
        server.close()
    assert server.mismatches == []


@contextmanager
def rtu_replay(steps: list[RtuStep]) -> Iterator[ModbusLink]:
    with socat_pair() as (bridge_end, device_end, _):
        peer = RtuReplay(device_end, steps, RTU_BAUD)
        link = ModbusLink(SerialSettings(bridge_end, RTU_BAUD, timeout_s=0.3))
        try:
            yield link
        finally:
            link.close()
            peer.close()
        assert peer.mismatches == []


def test_tcp_unit_0_is_an_address_whose_replies_are_awaited() -> None:
    # Modbus TCP has no broadcast: a write to unit 0 waits for its reply like any other,
    # so a device that does not answer is a timeout, not a stop reported done unseen.
    sim = Simulator([SimulatedDevice(TEST_MAP, 0)])
    port = sim.start_tcp()
    try:
        channel = DeviceChannel(ModbusLink(TcpSettings(port=port, timeout_s=0.2)), 0, retries=0)
        channel.write_register(4, 77)  # answered
        assert sim.device.get("word_4") == 77
        with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
            channel.write_register(11, 1)  # cuts the int32 at 10-11: the refusal is heard
        sim.withhold_replies = True
        with pytest.raises(LinkTimeout):
            channel.write_register(4, 78)
        assert channel.stats.timeouts == 1
    finally:
        sim.stop()


def test_tcp_silence_is_a_timeout(tcp_sim: tuple[Simulator, int]) -> None:
    sim, port = tcp_sim
    link = ModbusLink(TcpSettings(port=port, timeout_s=0.2))
    link.open()
    sim.withhold_replies = True
    started = time.monotonic()
    with pytest.raises(LinkTimeout) as caught:
        link.execute(1, ReadRegisters(0, 1))
    assert time.monotonic() - started >= 0.15
    assert isinstance(caught.value.__cause__, ModbusIOException)
    link.close()


@pytest.mark.parametrize(
    ("reply", "reply_tid", "cause"),
    [
        (bytes.fromhex("02 03 02 0007"), None, ReplyFromOtherUnit),
        (ANSWER_7, 0x4242, ReplyFromOtherTransaction),  # e.g. a stale reply
        (ANSWER_7, 0, ReplyFromOtherTransaction),
    ],
    ids=["wrong-unit", "wrong-transaction", "transaction-0"],
)
def test_tcp_mismatched_reply_is_a_frame_error_at_once(
    reply: bytes, reply_tid: int | None, cause: type[Exception]
) -> None:
    with tcp_replay([TcpStep(READ_ONE, reply, "mismatched reply", reply_tid)]) as (link, _):
        channel = DeviceChannel(link, 1, retries=0)
        with pytest.raises(FrameError) as caught:
            channel.read_registers(0, 1)
        # pymodbus alone skips such a reply and waits out the timeout (counted as one).
        assert isinstance(caught.value.__cause__, cause)
        assert channel.stats.frame_errors == 1 and channel.stats.timeouts == 0
        assert not link.is_open  # TCP: the socket is dropped with whatever else is in it


def test_tcp_undecodable_reply_is_a_frame_error() -> None:
    # Function 0x64 is in no table of pymodbus's decoder.
    with tcp_replay([TcpStep(READ_ONE, bytes.fromhex("01 64 02 0007"), "unknown fc")]) as (
        link,
        _,
    ):
        link.open()
        with pytest.raises(FrameError, match="undecodable"):
            link.execute(1, ReadRegisters(0, 1))


def test_tcp_good_reply_passes_the_header_check() -> None:
    steps = [TcpStep(READ_ONE, ANSWER_7, "first"), TcpStep(READ_ONE, ANSWER_7, "second")]
    with tcp_replay(steps) as (link, _):
        channel = DeviceChannel(link, 1, retries=0)
        assert channel.read_registers(0, 1) == [7]
        assert channel.read_registers(0, 1) == [7]  # next transaction id, same check


def test_short_replies_are_frame_errors_and_padding_is_cut() -> None:
    steps = [
        # FC 03, two registers asked, one sent.
        TcpStep(bytes.fromhex("01 03 0000 0002"), bytes.fromhex("01 03 02 0007"), "1 of 2"),
        # FC 01, ten coils asked, one byte (eight coils) sent.
        TcpStep(bytes.fromhex("01 01 0000 000A"), bytes.fromhex("01 01 01 FF"), "8 of 10"),
        # FC 01, three coils asked, one byte sent: its five padding bits are not coils.
        TcpStep(bytes.fromhex("01 01 0000 0003"), bytes.fromhex("01 01 01 05"), "3 + pad"),
    ]
    with tcp_replay(steps) as (link, server):
        channel = DeviceChannel(link, 1, retries=0)
        with pytest.raises(FrameError, match="short reply: 1 of 2"):
            channel.read_registers(0, 2)
        with pytest.raises(FrameError, match="short reply: 8 of 10"):
            channel.read_bits(0, 10)
        assert channel.read_bits(0, 3) == [True, False, True]
        assert not server.mismatches


def test_refused_connection_is_link_down() -> None:
    link = ModbusLink(TcpSettings(port=free_port(), timeout_s=0.5))  # nothing listens
    with pytest.raises(LinkDown):
        link.open()
    assert not link.is_open
    channel = DeviceChannel(link, 1, retries=2)
    with pytest.raises(LinkDown):
        channel.read_registers(0, 1)
    assert channel.stats.connect_failures == 1 and channel.stats.timeouts == 0


def test_rtu_silence_is_a_timeout() -> None:
    request = rtu_frame(1, "03 0000 0001")
    steps = [RtuStep(request, b"", "silent"), RtuStep(request, rtu_frame(1, "03 02 0008"), "ok")]
    with rtu_replay(steps) as link:
        channel = DeviceChannel(link, 1, retries=0)
        with pytest.raises(LinkTimeout) as caught:
            channel.read_registers(0, 1)
        assert isinstance(caught.value.__cause__, ModbusIOException)
        assert channel.stats.timeouts == 1 and channel.stats.frame_errors == 0
        assert channel.read_registers(0, 1) == [8]


def _bad_crc(frame: bytes) -> bytes:
    return frame[:-1] + bytes([frame[-1] ^ 0xFF])


@pytest.mark.parametrize(
    ("reply", "cause"),
    [
        (_bad_crc(rtu_frame(1, "03 02 0007")), ReplyCrcError),
        (rtu_frame(2, "03 02 0007"), ReplyFromOtherUnit),
    ],
    ids=["bad-crc", "wrong-unit"],
)
def test_rtu_bad_reply_is_a_frame_error_and_the_port_stays_open(
    reply: bytes, cause: type[Exception]
) -> None:
    request = rtu_frame(1, "03 0000 0001")
    steps = [RtuStep(request, reply, "bad"), RtuStep(request, rtu_frame(1, "03 02 0008"), "ok")]
    with rtu_replay(steps) as link:
        channel = DeviceChannel(link, 1, retries=0)
        with pytest.raises(FrameError) as caught:
            channel.read_registers(0, 1)
        assert isinstance(caught.value.__cause__, cause)
        assert channel.stats.frame_errors == 1 and channel.stats.timeouts == 0
        assert link.is_open  # RTU: the port stays open for the other drives on the bus
        assert channel.read_registers(0, 1) == [8]
