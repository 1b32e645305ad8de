"""Recording the wire: every transaction of a link as one ``WireFrame`` (the bridge
parameter ``record_wire``; docs/tools.md, "Recording the wire").

Plain Python, no pymodbus and no ROS. ``transport.ModbusLink`` owns a ``WireTap`` only when
recording is on (off, nothing is installed and nothing is counted): pymodbus hands it the
bytes of a one-at-a-time transaction through its ``trace_packet`` hook (the whole ADU as
sent and as received, TCP and RTU alike), the TCP pipeline hands it the frames it builds
and cuts itself; the link tells it how each transaction ended. The tap calls a plain
callback under the link lock, so the callback must not block: the ROS side gives it
``FrameQueue.put`` (bounded; what does not fit is dropped and counted) and publishes from
its own thread (``bridge_core.ros.node_wire``).
"""

from __future__ import annotations

import itertools
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum

from . import requests as rq
from .registers import Table

# Frames waiting for the publisher: at 100 transactions per second, 10 s of them.
FRAME_QUEUE_DEPTH = 1000


class Outcome(IntEnum):
    """How a transaction ended (``msg_defs/msg/ModbusFrame``'s constants, same numbers)."""

    OK = 0
    EXCEPTION = 1
    TIMEOUT = 2
    LINK_DOWN = 3
    FRAME_ERROR = 4


@dataclass(frozen=True, slots=True)
class WireFrame:
    """One transaction: its request and reply ADUs (b"" when there was none), when the
    request went out and the reply came (or the wait ended), both ``time.time()``."""

    sequence: int
    rtu: bool
    unit_id: int
    function_code: int
    request: bytes
    reply: bytes
    sent_at: float
    replied_at: float
    outcome: Outcome
    exception_code: int = 0


WireCallback = Callable[[WireFrame], None]


class WireTap:
    """The frames of one link: sequence numbers, and the bytes of the transaction in
    progress (the caller holds the link lock, so one transaction at a time)."""

    def __init__(self, callback: WireCallback, *, rtu: bool) -> None:
        self.callback = callback
        self.rtu = rtu
        self._sequence = itertools.count(1)
        self._request = b""
        self._reply = b""
        self._sent_at = 0.0
        self._number = 0

    def next_sequence(self) -> int:
        return next(self._sequence)

    def begin(self) -> None:
        """A one-at-a-time transaction starts: forget the last one's bytes."""
        self._request = self._reply = b""
        self._sent_at = 0.0
        self._number = 0

    def packet(self, sending: bool, data: bytes) -> bytes:
        """pymodbus's ``trace_packet`` hook: the request as sent, then the reply as
        received so far (the last call holds the frame it decoded). Returns ``data``."""
        if sending:
            self._request, self._reply = bytes(data), b""
            self._sent_at = time.time()
            self._number = self.next_sequence()
        else:
            self._reply = bytes(data)
        return data

    def ended(
        self,
        unit_id: int,
        function_code: int,
        outcome: Outcome,
        exception_code: int = 0,
    ) -> None:
        """The one-at-a-time transaction ended: its frame goes to the callback."""
        now = time.time()
        number = self._number or self.next_sequence()  # never sent: numbered now
        self.callback(
            WireFrame(
                sequence=number,
                rtu=self.rtu,
                unit_id=unit_id,
                function_code=function_code,
                request=self._request,
                reply=self._reply if outcome is not Outcome.LINK_DOWN else b"",
                sent_at=self._sent_at or now,
                replied_at=now,
                outcome=outcome,
                exception_code=exception_code,
            )
        )

    def pipelined(
        self,
        sequence: int,
        unit_id: int,
        request: bytes,
        sent_at: float,
        reply: bytes,
        outcome: Outcome,
        exception_code: int = 0,
    ) -> None:
        """A pipelined read ended (``pipeline.TcpPipeline`` keeps its bytes)."""
        function_code = request[TCP_FUNCTION_OFFSET] if len(request) > TCP_FUNCTION_OFFSET else 0
        self.callback(
            WireFrame(
                sequence=sequence,
                rtu=False,
                unit_id=unit_id,
                function_code=function_code,
                request=request,
                reply=reply,
                sent_at=sent_at,
                replied_at=time.time(),
                outcome=outcome,
                exception_code=exception_code,
            )
        )


# The function code's offset in a Modbus TCP ADU (after the 7-byte MBAP header).
TCP_FUNCTION_OFFSET = 7

# Function codes (Modbus Application Protocol V1.1b3 §6) of the requests the link sends.
_READ_CODES = {Table.COIL: 0x01, Table.DISCRETE_INPUT: 0x02, Table.HOLDING: 0x03, Table.INPUT: 0x04}
_WRITE_CODES: dict[type, int] = {
    rq.WriteCoil: 0x05,
    rq.WriteRegister: 0x06,
    rq.WriteCoils: 0x0F,
    rq.WriteRegisters: 0x10,
    rq.MaskWriteRegister: 0x16,
    rq.ReadWriteRegisters: 0x17,
}


def function_code(request: rq.Request) -> int:
    """The Modbus function code ``request`` goes out with."""
    if isinstance(request, rq.ReadRegisters | rq.ReadBits):
        return _READ_CODES[request.table]
    return _WRITE_CODES[type(request)]


class FrameQueue:
    """Frames on their way to a publisher: ``put`` never blocks (a full queue drops the
    new frame and counts it), ``get`` waits. Between the link (poll thread) and ROS."""

    def __init__(self, depth: int = FRAME_QUEUE_DEPTH) -> None:
        self._queue: queue.Queue[WireFrame] = queue.Queue(depth)
        self._lock = threading.Lock()
        self.closed = False
        self.dropped = 0  # frames that found the queue full
        self.queued = 0

    def put(self, frame: WireFrame) -> None:
        try:
            self._queue.put_nowait(frame)
        except queue.Full:
            with self._lock:
                self.dropped += 1
            return
        with self._lock:
            self.queued += 1

    def get(self, timeout_s: float | None = None) -> WireFrame | None:
        """The next frame, or None after ``timeout_s`` with none."""
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def close(self) -> None:
        """The reader ends at its next ``get`` timeout (it checks ``closed``)."""
        self.closed = True


__all__ = [
    "FRAME_QUEUE_DEPTH",
    "FrameQueue",
    "Outcome",
    "WireCallback",
    "WireFrame",
    "WireTap",
    "function_code",
]
