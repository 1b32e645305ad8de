"""Pipelined Modbus TCP: replies matched by transaction id, the fallback, stops first.

Against the simulator (``sim.serving`` + ``tcp_serving``, real sockets) and, for replies a
simulator never sends (out of order, to a transaction not in flight), a raw peer.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import pytest

from bridge_core.runtime.reads import read_plan
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.channel import DeviceChannel, Priority
from bridge_core.wire.errors import DeviceException, FrameError
from bridge_core.wire.planner import plan_reads
from bridge_core.wire.registers import Access, DeviceLimits, RegisterMap, ValueType, register_array
from bridge_core.wire.requests import ReadRegisters, Reply, Request, WriteRegister
from bridge_core.wire.transport import ModbusLink, TcpSettings

WORDS = 40
# Forty registers, read four at a time: a poll of ten requests.
MAP = RegisterMap(
    "pipeline test",
    tuple(
        register_array(
            "word", 0, WORDS, ValueType.U16, "test", access=Access.READ_WRITE, first_index=0
        )
    ),
    DeviceLimits(max_read_registers=4),
)
PLAN = plan_reads(MAP, MAP.select([f"word_{i}" for i in range(WORDS)]))
STOP_ADDRESS = 39
WAIT_S = 10.0


def wait_until(predicate: Callable[[], object], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.002)


@contextmanager
def simulated(
    max_in_flight: int, *, round_trip_s: float = 0.0, one_at_a_time: bool = False
) -> Iterator[tuple[Simulator, SimulatedDevice, DeviceChannel]]:
    device = SimulatedDevice(MAP, 1)
    for i in range(WORDS):
        device.set(f"word_{i}", 100 + i)
    device.log_reads = True
    sim = Simulator([device])
    sim.round_trip_s = round_trip_s
    sim.one_request_at_a_time = one_at_a_time
    port = sim.start_tcp()
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=0.5))
    channel = DeviceChannel(link, 1, max_in_flight=max_in_flight)
    try:
        yield sim, device, channel
    finally:
        link.close()
        sim.stop()


def expected() -> dict[str, int]:
    return {f"word_{i}": 100 + i for i in range(WORDS)}


def test_a_pipelined_poll_reads_every_block_and_keeps_several_in_flight() -> None:
    with simulated(4, round_trip_s=0.02) as (_sim, device, channel):
        channel.read_registers(0, 1)  # connected: a batch pipelines on a live link only
        read = read_plan(channel, PLAN)
        assert read.values == expected()
        assert [r.address for r, _, _ in read.times] == [r.address for r in PLAN]
        assert channel.pipelining.fallbacks == 0
        # 10 requests at a 20 ms round trip: one at a time the poll counts 10 round trips
        # in the wire budget, four in flight about ceil(10 / 4) = 3.
        before = channel.wire.polls
        read_plan(channel, PLAN)
        assert channel.wire.polls - before < 6
        assert len(device.read_log) == 1 + 2 * len(PLAN)


def test_max_in_flight_1_sends_one_request_at_a_time() -> None:
    with simulated(1, round_trip_s=0.02) as (_sim, _device, channel):
        channel.read_registers(0, 1)
        sent: list[Request] = []
        real = channel.transact

        def transact(request: Request, priority: Priority = Priority.POLL) -> Reply:
            sent.append(request)
            return real(request, priority)

        channel.transact = transact  # type: ignore[method-assign]
        before = channel.wire.polls
        assert read_plan(channel, PLAN).values == expected()
        assert sent == [ReadRegisters(r.address, r.count, r.table) for r in PLAN]
        assert channel.wire.polls - before == len(PLAN)


def test_a_device_that_answers_one_request_at_a_time_makes_it_fall_back_once() -> None:
    with simulated(8, one_at_a_time=True) as (sim, _device, channel):
        channel.read_registers(0, 1)
        read = read_plan(channel, PLAN)  # the unanswered reads go again, one at a time
        assert read.values == expected()
        assert sim.dropped, "the simulator dropped no pipelined request"
        assert channel.pipelining.fallbacks == 1
        assert channel.pipelining.window == 1
        news = channel.pipelining.news()
        assert len(news) == 1 and "one request at a time" in news[0]
        dropped = len(sim.dropped)
        for _ in range(3):
            assert read_plan(channel, PLAN).values == expected()
        assert len(sim.dropped) == dropped
        assert channel.pipelining.fallbacks == 1
        assert channel.pipelining.news() == []
        assert channel.connected


def test_a_stop_goes_before_the_rest_of_a_pipelined_poll() -> None:
    """The stop is queued while the first reply of a poll is handled (two in flight):
    the device sees at most the reads already sent before it."""
    window = 2
    with simulated(window, round_trip_s=0.02) as (_sim, device, channel):
        channel.read_registers(0, 1)
        device.read_log.clear()
        stopper = threading.Thread(
            target=channel.write_register, args=(STOP_ADDRESS, 1, Priority.STOP)
        )
        requests = iter([ReadRegisters(r.address, r.count) for r in PLAN])
        answered: list[int] = []

        def on_reply(index: int, outcome: Reply | DeviceException) -> None:
            answered.append(index)
            if index == 0:
                stopper.start()
                lock = channel.link.lock
                wait_until(lambda: lock.waiting_before(Priority.POLL), "the stop to queue")

        channel.transact_many(lambda: next(requests, None), on_reply)
        stopper.join(WAIT_S)
        assert sorted(answered) == list(range(len(PLAN)))
        stop = device.writes_to(STOP_ADDRESS)
        assert len(stop) == 1
        before_stop = [r for r in device.read_log if r.time <= stop[0].time]
        # Read 0 (answered), reads 1 and 2 (in flight when the stop queued): no more.
        assert len(before_stop) <= 1 + window, [r.address for r in before_stop]


# ---------------------------------------------------------------- a raw peer


def _reply(tid: int, unit: int, values: list[int]) -> bytes:
    pdu = bytes([3, 2 * len(values)]) + b"".join(v.to_bytes(2, "big") for v in values)
    return (
        tid.to_bytes(2, "big")
        + b"\x00\x00"
        + (len(pdu) + 1).to_bytes(2, "big")
        + bytes([unit])
        + pdu
    )


class Peer:
    """Accepts one connection, reads ``count`` requests (FC 03), answers them with
    ``answer(requests)``: a list of (transaction id, values) in the order to send."""

    def __init__(
        self, count: int, answer: Callable[[list[tuple[int, int, int]]], list[bytes]]
    ) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.count = count
        self.answer = answer
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.server.accept()
        with conn:
            requests: list[tuple[int, int, int]] = []  # tid, address, count
            data = b""
            while len(requests) < self.count:
                chunk = conn.recv(4096)
                if not chunk:
                    return
                data += chunk
                while len(data) >= 12:
                    frame, data = data[:12], data[12:]
                    tid = int.from_bytes(frame[0:2], "big")
                    address = int.from_bytes(frame[8:10], "big")
                    count = int.from_bytes(frame[10:12], "big")
                    requests.append((tid, address, count))
            for frame in self.answer(requests):
                conn.sendall(frame)
            time.sleep(0.5)  # keep the connection until the client is done

    def close(self) -> None:
        self.server.close()


def _values(address: int, count: int) -> list[int]:
    return [1000 + address + i for i in range(count)]


def _batch(
    peer: Peer, reads: list[ReadRegisters], window: int
) -> tuple[DeviceChannel, dict[int, Reply | DeviceException]]:
    link = ModbusLink(TcpSettings("127.0.0.1", peer.port, timeout_s=0.5))
    link.open()
    channel = DeviceChannel(link, 1, max_in_flight=window)
    channel.link_state.answered()  # as after a first poll: the batch pipelines
    pending = iter(reads)
    got: dict[int, Reply | DeviceException] = {}
    channel.transact_many(lambda: next(pending, None), got.__setitem__)
    return channel, got


def test_replies_out_of_order_are_matched_by_transaction_id() -> None:
    reads = [ReadRegisters(10 * i, 2) for i in range(3)]
    peer = Peer(3, lambda requests: [_reply(t, 1, _values(a, c)) for t, a, c in reversed(requests)])
    try:
        channel, got = _batch(peer, reads, window=3)
    finally:
        peer.close()
    assert got == {i: _values(r.address, r.count) for i, r in enumerate(reads)}
    assert channel.pipelining.fallbacks == 0


def test_a_reply_to_no_request_in_flight_falls_back_and_is_said_once() -> None:
    """The first reply carries a transaction id nobody sent: a frame error, the batch
    falls back (the reads go again one at a time; the peer answers no more, so they fail
    as they would on any link)."""
    reads = [ReadRegisters(10 * i, 2) for i in range(3)]
    peer = Peer(3, lambda requests: [_reply(requests[-1][0] + 100, 1, [0, 0])])
    link = ModbusLink(TcpSettings("127.0.0.1", peer.port, timeout_s=0.5))
    link.open()
    channel = DeviceChannel(link, 1, max_in_flight=3, retries=0)
    channel.link_state.answered()
    pending = iter(reads)
    try:
        with pytest.raises(Exception):  # noqa: B017 - the peer answers no more
            channel.transact_many(lambda: next(pending, None), lambda i, o: None)
    finally:
        peer.close()
        link.close()
    assert channel.pipelining.fallbacks == 1
    assert channel.stats.frame_errors == 1
    news = channel.pipelining.news()
    assert len(news) == 1 and "not in flight" in news[0]


def test_writes_are_never_pipelined() -> None:
    with simulated(4) as (_sim, _device, channel):
        channel.read_registers(0, 1)
        with pytest.raises(ValueError, match="only reads"):
            channel.link.send_pipelined(1, WriteRegister(0, 1))  # type: ignore[attr-defined]


def test_an_error_of_the_callers_is_not_a_pipelining_failure() -> None:
    """``on_reply`` raising (a short reply the caller refuses) ends the batch with that
    error; the connection is dropped (replies in flight) but pipelining stays on."""
    with simulated(4) as (_sim, _device, channel):
        channel.read_registers(0, 1)
        requests = iter([ReadRegisters(r.address, r.count) for r in PLAN])

        def on_reply(index: int, outcome: Reply | DeviceException) -> None:
            raise FrameError("refused by the caller")

        with pytest.raises(FrameError, match="by the caller"):
            channel.transact_many(lambda: next(requests, None), on_reply)
        assert channel.pipelining.fallbacks == 0
        assert read_plan(channel, PLAN).values == expected()


# ---------------------------------------------------------------- delayed ACKs

# struct tcp_info (linux/tcp.h): tcpi_segs_out, every segment sent, pure ACKs included.
TCPI_SEGS_OUT = struct.Struct("=I")
TCPI_SEGS_OUT_OFFSET = 136
TCP_INFO_SIZE = 256


def _segments_out(sock: socket.socket) -> int:
    info = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, TCP_INFO_SIZE)
    return int(TCPI_SEGS_OUT.unpack_from(info, TCPI_SEGS_OUT_OFFSET)[0])


@pytest.mark.skipif(not hasattr(socket, "TCP_QUICKACK"), reason="TCP_QUICKACK is Linux's")
def test_a_pipelined_reply_is_acknowledged_before_receive_returns() -> None:
    """Pipelined, every request is already out, so nothing carries the
    ACK of a reply but the ACK itself; Linux delays it (40 ms or more), and a device
    that leaves Nagle on holds its next reply until then (22.7 polls/s against 1777).
    Checked without a clock: the client's own segment count (TCP_INFO, pure ACKs
    included) grows by the request and the ACK of its reply by the time ``receive``
    returns; a delayed ACK is not sent yet then (it would leave 1)."""
    device = SimulatedDevice(MAP, 1)
    sim = Simulator([device])
    sim.nagle = True
    port = sim.start_tcp()
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=2.0))
    try:
        link.open()
        for _ in range(20):  # past the quick ACKs Linux gives a fresh connection
            link.execute(1, ReadRegisters(0, 4))
        sock = link._client.socket  # the real socket the pipeline reads
        assert sock is not None
        counts = []
        for _ in range(20):
            before = _segments_out(sock)
            link.send_pipelined(1, ReadRegisters(0, 4))
            link.receive_pipelined()
            counts.append(_segments_out(sock) - before)
    finally:
        link.close()
        sim.stop()
    assert sim.connections_nodelay == [False]  # the device left Nagle on
    assert all(n >= 2 for n in counts), f"segments per request and reply: {counts}"
