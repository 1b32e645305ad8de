"""An RTU peer on the device end of a pty pair that replays a manual's example frames.

Each step names the request frame the bridge must send (CRC included) and the reply to
answer with (b"" for none: a broadcast). Frames are built without their CRC and completed
by pymodbus's RTU framer, never typed by hand.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import serial
from pymodbus.framer import FramerRTU


def rtu_frame(unit: int, pdu_hex: str) -> bytes:
    """``unit`` + the hex PDU + the CRC pymodbus computes (low byte first on the wire)."""
    body = bytes([unit]) + bytes.fromhex(pdu_hex)
    return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")


@dataclass
class Step:
    request: bytes
    reply: bytes  # b"": no reply (broadcast)
    meaning: str = ""


@dataclass
class RtuReplay:
    """Answers each expected request frame with its reply; records what arrived."""

    port: str
    steps: list[Step]
    baudrate: int = 115200
    received: list[bytes] = field(default_factory=list)
    mismatches: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._serial = serial.Serial(self.port, self.baudrate, timeout=3.0)
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        for step in self.steps:
            data = self._serial.read(len(step.request))
            self.received.append(data)
            if data != step.request:
                self.mismatches.append(
                    f"{step.meaning}: expected {step.request.hex(' ')}, got {data.hex(' ')}"
                )
                return
            if step.reply:
                self._serial.write(step.reply)
                self._serial.flush()

    def close(self) -> None:
        self._thread.join(5)
        self._serial.close()
