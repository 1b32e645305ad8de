"""Errors of the bridge layers, translated at the edge so callers never see pymodbus types."""

from __future__ import annotations

# Modbus exception codes (Modbus Application Protocol V1.1b3, §7) and their names.
ILLEGAL_DATA_ADDRESS = 0x02  # a read of a row the device does not serve is refused so
EXCEPTION_NAMES: dict[int, str] = {
    0x01: "ILLEGAL FUNCTION",
    ILLEGAL_DATA_ADDRESS: "ILLEGAL DATA ADDRESS",
    0x03: "ILLEGAL DATA VALUE",
    0x04: "SERVER DEVICE FAILURE",
    0x05: "ACKNOWLEDGE",
    0x06: "SERVER DEVICE BUSY",
    0x08: "MEMORY PARITY ERROR",
    0x0A: "GATEWAY PATH UNAVAILABLE",
    0x0B: "GATEWAY TARGET DEVICE FAILED TO RESPOND",
}


class BridgeError(Exception):
    """Base of every error the bridge layers raise."""


class CommandRejected(BridgeError, ValueError):
    """A command was refused before anything was written (range, unknown target, guards)."""


class LinkError(BridgeError):
    """A transaction with the device failed."""


class LinkDown(LinkError):
    """The link is not connected, or the connection was lost."""


class NotSent(LinkDown):
    """Nothing went on the wire: the link could not be opened, or a command that waited
    through a link loss was withdrawn. (Any other LinkError on a write may or may not
    have reached the device.)"""


class LinkTimeout(LinkError):
    """The device did not answer within the timeout."""


class FrameError(LinkError):
    """A reply arrived but was garbled (CRC error, wrong unit id, wrong length)."""


class DeviceException(LinkError):
    """The device answered with a Modbus exception response."""

    def __init__(self, function_code: int, exception_code: int) -> None:
        self.function_code = function_code
        self.exception_code = exception_code
        self.name = EXCEPTION_NAMES.get(exception_code, f"EXCEPTION 0x{exception_code:02X}")
        super().__init__(
            f"{self.name} (exception 0x{exception_code:02X} to function 0x{function_code:02X})"
        )


class NotConfirmed(BridgeError):
    """A write went out and was acknowledged, but the value read back does not show it
    (the message says what was written and what was seen)."""


class PollIncomplete(BridgeError):
    """A poll could not produce a consistent snapshot (e.g. the device re-configured mid-poll).

    The link is fine; the node skips this cycle instead of publishing a mixed state.
    """


class ConfigurationError(BridgeError, ValueError):
    """A start-up parameter has the wrong type or value; the node does not start."""
