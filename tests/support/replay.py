"""A Modbus TCP peer that replays a manual's example exchanges over a real socket.

Like minimalmodbus's recorded-frame fake serial, but on TCP: each step names the request
PDU the bridge must send (unit id + function code + data, byte-exact) and the reply PDU
to answer with. The MBAP transaction id is echoed (unless a step names another, to play a
stale reply), so the client's own numbering does not matter; every mismatch is recorded
for the test to assert on.
"""

from __future__ import annotations

import socket
import struct
import threading
from dataclasses import dataclass, field

MBAP_LENGTH = 7


def frame(hex_text: str) -> bytes:
    return bytes.fromhex(hex_text.replace("0x", "").replace(",", " "))


def pdu_of(manual_frame: str) -> bytes:
    """Unit id + PDU of a frame printed with its MBAP header (the header is dropped)."""
    data = frame(manual_frame)
    return data[6:]


@dataclass
class Step:
    request: bytes  # unit id + PDU
    reply: bytes  # unit id + PDU
    meaning: str = ""
    reply_tid: int | None = None  # None: echo the request's transaction id


@dataclass
class ReplayServer:
    steps: list[Step]
    received: list[bytes] = field(default_factory=list)
    mismatches: list[str] = field(default_factory=list)
    bad_lengths: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", 0))
        self._listener.listen(1)
        self.port = self._listener.getsockname()[1]
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _recv_exact(self, conn: socket.socket, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = conn.recv(n - len(data))
            if not chunk:
                raise ConnectionError("peer closed")
            data += chunk
        return data

    def _serve(self) -> None:
        try:
            conn, _ = self._listener.accept()
        except OSError:
            return
        with conn:
            for step in self.steps:
                try:
                    header = self._recv_exact(conn, 6)
                    tid, protocol, length = struct.unpack(">HHH", header)
                    body = self._recv_exact(conn, length)
                except (ConnectionError, OSError):
                    self.mismatches.append(f"connection closed before: {step.meaning}")
                    return
                self.received.append(body)
                if protocol != 0:
                    self.bad_lengths.append(f"protocol id {protocol} in {step.meaning}")
                if body != step.request:
                    self.mismatches.append(
                        f"{step.meaning}: expected {step.request.hex(' ')}, got {body.hex(' ')}"
                    )
                reply_tid = tid if step.reply_tid is None else step.reply_tid
                reply = struct.pack(">HHH", reply_tid, 0, len(step.reply)) + step.reply
                conn.sendall(reply)

    def close(self) -> None:
        self._listener.close()
        self._thread.join(5)
