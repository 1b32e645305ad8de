"""How the serial simulators cut the byte stream into requests, as a slave on a line does.

Why: a real RTU slave ends a frame at 3.5 characters of silence (serial line spec
§2.5.1.1), so a frame cut short (a cable pulled mid-frame, a line blackout) costs only
that frame. A pty carries no silence, and a loaded simulator cannot time one. pymodbus
3.16's ``FramerRTU`` drops everything it holds when a candidate frame fails its CRC; with
the bytes arriving one by one (as the line relay paces them) that drop falls inside the
next request, whose tail starts the next failing candidate, and so on: a simulator that
had taken the first byte of a request cut by a 300 ms blackout answered nothing for
seconds after the line came back (seen in CI; ``tests/core/sim/test_rtu_framing.py``).

``SlaveFramerRTU`` hunts instead:

- a candidate whose CRC fails costs one byte (the next offset is tried at once);
- a candidate still waiting for bytes (garbage whose function code or byte count promises
  a long frame) does not hold the line: a whole, CRC-valid request to a unit the
  simulator serves (or broadcast) that ends at the last byte received is taken;
- bytes before the first candidate that may still complete are dropped.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from pymodbus.framer.rtu import FramerRTU

from ..wire.serial_timing import crc_matches

# RTU frames: unit, function code and CRC at least; 256 bytes at most (serial line spec).
RTU_MIN_FRAME = 4
RTU_MAX_FRAME = 256
BROADCAST_UNIT = 0
CRC_SIZE = 2


def crc_frame_size(data: bytes) -> int:
    """RTU frame size of a request whose function code does not tell its length: the
    first length whose last two bytes are the CRC of the rest (a real slave ends a frame
    at 3.5 characters of silence, which a pty does not carry). 0: not complete yet; past
    the longest RTU frame, all of it (the CRC fails and the framer drops it)."""
    for size in range(RTU_MIN_FRAME, min(len(data), RTU_MAX_FRAME) + 1):
        if crc_matches(data[:size]):
            return size
    return 0 if len(data) < RTU_MAX_FRAME else len(data)


class SlaveFramerRTU(FramerRTU):
    """``FramerRTU`` that finds the next request after garbage (see the module doc)."""

    units: Callable[[], Iterable[int]] = staticmethod(tuple)  # set by slave_framer()

    def decode(self, data: bytes) -> tuple[int, int, int, bytes]:
        waiting: int | None = None  # offset of the first candidate still incomplete
        for start in range(len(data) - RTU_MIN_FRAME + 1):
            pdu_class = self.decoder.lookupPduClass(data[start:])
            if pdu_class is None:
                continue
            size = pdu_class.calculateRtuFrameSize(data[start:])
            end = start + size
            if not size or end > len(data):
                if waiting is None:
                    waiting = start
                continue
            if waiting is not None and (
                end != len(data) or data[start] not in {BROADCAST_UNIT, *self.units()}
            ):
                continue  # inside what may still be the waiting frame
            if crc_matches(data[start:end]):
                return end, data[start], 0, data[start + 1 : end - CRC_SIZE]
        if waiting is None:  # keep only bytes that may still start a frame
            return max(0, len(data) - RTU_MIN_FRAME + 1), 0, 0, self.EMPTY
        return waiting, 0, 0, self.EMPTY


def slave_framer(units: Callable[[], Iterable[int]]) -> type[SlaveFramerRTU]:
    """A ``SlaveFramerRTU`` class for a server (pymodbus makes one per connection) whose
    simulator serves ``units()``."""
    return type("SlaveFramerRTU", (SlaveFramerRTU,), {"units": staticmethod(units)})
