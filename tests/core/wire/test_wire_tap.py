"""Recording the wire (``record_wire``): the frames a link hands its callback, over real
TCP sockets and a real pty against the simulators' server, and the bounded queue.

Each frame carries the whole ADU as on the wire: the request as sent, the reply as heard
(MBAP header on TCP, unit id and CRC on RTU), and its outcome.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from pymodbus.framer import FramerRTU

from bridge_core.runtime.reads import read_plan
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import DeviceException, LinkTimeout
from bridge_core.wire.planner import plan_reads
from bridge_core.wire.registers import Access, DeviceLimits, RegisterMap, ValueType, register_array
from bridge_core.wire.transport import ModbusLink, SerialSettings, TcpSettings
from bridge_core.wire.wire_tap import FrameQueue, Outcome, WireFrame

from ...support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty

WORDS = 12
MAP = RegisterMap(
    "wire tap test",
    tuple(
        register_array(
            "word", 0, WORDS, ValueType.U16, "test", access=Access.READ_WRITE, first_index=0
        )
    ),
    DeviceLimits(max_read_registers=4),
)
PLAN = plan_reads(MAP, MAP.select([f"word_{i}" for i in range(WORDS)]))
ILLEGAL_ADDRESS = 0x02


def make_simulator() -> Simulator:
    device = SimulatedDevice(MAP, 1)
    for i in range(WORDS):
        device.set(f"word_{i}", 100 + i)
    return Simulator([device])


@contextmanager
def tcp_channel(max_in_flight: int = 1) -> Iterator[tuple[DeviceChannel, list[WireFrame]]]:
    sim = make_simulator()
    port = sim.start_tcp()
    frames: list[WireFrame] = []
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=2.0), wire=frames.append)
    try:
        yield DeviceChannel(link, 1, max_in_flight=max_in_flight), frames
    finally:
        link.close()
        sim.stop()


def mbap(adu: bytes) -> tuple[int, int, int, int, bytes]:
    """(transaction id, protocol id, length, unit id, PDU) of a Modbus TCP ADU."""
    tid, protocol, length, unit = struct.unpack(">HHHB", adu[:7])
    return tid, protocol, length, unit, adu[7:]


def test_tcp_one_at_a_time_frames_hold_the_whole_adus_and_the_outcome() -> None:
    with tcp_channel() as (channel, frames):
        assert channel.read_registers(2, 3) == [102, 103, 104]
        channel.write_register(5, 7)
        with pytest.raises(DeviceException):
            channel.read_registers(WORDS + 10, 1)
    read, write, refused = frames
    assert [f.outcome for f in frames] == [Outcome.OK, Outcome.OK, Outcome.EXCEPTION]
    assert [f.sequence for f in frames] == [1, 2, 3]
    assert not read.rtu and read.unit_id == 1 and read.function_code == 0x03
    tid, protocol, length, unit, pdu = mbap(read.request)
    assert (protocol, length, unit, pdu) == (0, 6, 1, bytes.fromhex("0300020003"))
    reply_tid, _, _, _, reply_pdu = mbap(read.reply)
    assert reply_tid == tid
    assert reply_pdu == bytes.fromhex("0306") + struct.pack(">3H", 102, 103, 104)
    assert read.sent_at <= read.replied_at
    assert write.function_code == 0x06 and mbap(write.reply)[4] == mbap(write.request)[4]
    assert refused.exception_code == ILLEGAL_ADDRESS
    assert mbap(refused.reply)[4] == bytes([0x83, ILLEGAL_ADDRESS])


def test_pipelined_reads_give_one_frame_per_request_each_with_its_own_reply() -> None:
    with tcp_channel(max_in_flight=4) as (channel, frames):
        channel.read_registers(0, 1)  # connected: a batch pipelines on a live link only
        assert channel.pipelines
        frames.clear()
        assert read_plan(channel, PLAN).values == {f"word_{i}": 100 + i for i in range(WORDS)}
    assert len(frames) == len(PLAN)
    assert sorted(f.sequence for f in frames) == [f.sequence for f in frames]
    for frame, request in zip(frames, PLAN, strict=True):
        assert frame.outcome is Outcome.OK
        tid, _, _, _, pdu = mbap(frame.request)
        assert pdu == struct.pack(">BHH", 0x03, request.address, request.count)
        reply_tid, _, _, _, reply_pdu = mbap(frame.reply)
        assert reply_tid == tid
        first = 100 + request.address
        assert reply_pdu[2:] == struct.pack(
            f">{request.count}H", *range(first, first + request.count)
        )


def test_rtu_frames_are_whole_rtu_adus_with_their_crc() -> None:
    sim = make_simulator()
    frames: list[WireFrame] = []
    with served_on_pty(sim, 115200) as port:
        link = ModbusLink(
            SerialSettings(port, 115200, timeout_s=PTY_REPLY_TIMEOUT_S), wire=frames.append
        )
        try:
            assert DeviceChannel(link, 1).read_registers(0, 2) == [100, 101]
        finally:
            link.close()
    (frame,) = frames
    assert frame.rtu and frame.outcome is Outcome.OK
    for adu in (frame.request, frame.reply):
        assert FramerRTU.check_CRC(adu[:-2], int.from_bytes(adu[-2:], "big"))
    assert frame.request[:-2] == bytes.fromhex("010300000002")
    assert frame.reply[:-2] == bytes.fromhex("010304") + struct.pack(">2H", 100, 101)


def test_a_timeout_is_a_frame_with_no_reply() -> None:
    """A request that got no reply is on the wire: recorded, with the time the wait ended
    (a connect that fails puts nothing on the wire: no frame)."""
    peer = socket.socket()
    peer.bind(("127.0.0.1", 0))
    peer.listen()  # the backlog accepts; nobody answers
    frames: list[WireFrame] = []
    settings = TcpSettings("127.0.0.1", peer.getsockname()[1], timeout_s=0.2)
    link = ModbusLink(settings, wire=frames.append)
    try:
        with pytest.raises(LinkTimeout):
            DeviceChannel(link, 1, retries=0).read_registers(0, 1)
    finally:
        link.close()
        peer.close()
    (timeout,) = frames
    assert timeout.outcome is Outcome.TIMEOUT and timeout.function_code == 3
    assert mbap(timeout.request)[4] == bytes.fromhex("0300000001")
    assert timeout.reply == b"" and timeout.replied_at - timeout.sent_at >= 0.2


def test_without_a_callback_nothing_is_installed() -> None:
    """Off (the default), the link gives pymodbus no trace hook and the pipeline no tap."""
    link = ModbusLink(TcpSettings("127.0.0.1", 1))
    client = link._client
    assert client.transaction.trace_packet == client.transaction.dummy_trace_packet
    assert link._pipeline is not None and link._pipeline.tap is None
    assert link._tap is None
    recorded = ModbusLink(TcpSettings("127.0.0.1", 1), wire=lambda frame: None)
    assert recorded._tap is not None
    assert recorded._client.transaction.trace_packet == recorded._tap.packet


def frame(sequence: int) -> WireFrame:
    return WireFrame(sequence, False, 1, 3, b"q", b"r", 0.0, 0.0, Outcome.OK)


def test_a_full_queue_drops_the_new_frame_and_counts_it() -> None:
    """The link never waits for the publisher: past the queue's depth frames are dropped
    (and counted), the ones queued keep their order."""
    queue = FrameQueue(depth=3)
    for sequence in range(1, 6):
        queue.put(frame(sequence))
    assert (queue.queued, queue.dropped) == (3, 2)
    taken = [queue.get(0.0) for _ in range(4)]
    assert [f.sequence if f else None for f in taken] == [1, 2, 3, None]
    queue.put(frame(6))
    assert queue.get(0.0) == frame(6) and queue.dropped == 2
