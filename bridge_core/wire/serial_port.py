"""The serial port under the RTU client and the simulators: opening it, writing to it.

Plain pyserial (no pymodbus): ``open_serial`` opens a device path in one configure with
every setting (a ``ParityTolerantSerial``, which accepts a tty that drops the parity bit)
and any other pyserial URL as pyserial does; ``write_all`` writes a whole frame and judges
the write by the bytes that left, not by the clock.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import termios
import time
from collections.abc import Callable
from typing import Any

import serial


def write_all(
    fd: int, data: bytes, stall_s: float, clock: Callable[[], float] = time.monotonic
) -> int:
    """Write every byte of ``data`` to the (non-blocking) descriptor ``fd``.

    A write is judged by the bytes that left: pyserial's ``write`` with a write timeout
    checks its deadline after ``os.write`` returned and raises SerialTimeoutException for
    a frame that was in fact written whole whenever the process was descheduled for
    longer than the timeout (seen: a flood on a loaded machine closed live links).
    Here only a buffer that stays full for ``stall_s`` is an error.
    """
    view = memoryview(data)
    written = 0
    deadline = clock() + stall_s
    while written < len(data):
        try:
            written += os.write(fd, view[written:])
            continue
        except BlockingIOError:
            pass
        remaining = deadline - clock()
        if remaining <= 0:
            raise serial.SerialTimeoutException(
                f"{written} of {len(data)} bytes written: the output buffer stayed full"
            )
        select.select([], [fd], [], remaining)
    return written


class ParityTolerantSerial(serial.Serial):  # type: ignore[misc]
    """A pyserial port that accepts a tty which does not keep the parity bit.

    A Linux pty has no parity: it takes PARENB on the first configure and drops it, and
    every later configure that asks for it again (pyserial compares the whole termios
    block, so setting a timeout after opening is one) fails in ``tcsetattr`` with EINVAL;
    a port opened once with parity may also refuse it on the next open. Such a port is
    configured without the parity bit after one INFO line; everything else (and every
    real UART, which keeps PARENB) is untouched. The line's timing still counts the
    configured characters (``char_time_s``: 11 bits for 8E1, 8O1, 8N2).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.parity_dropped = False
        super().__init__(*args, **kwargs)

    _parity: str  # pyserial's (untyped)

    def _reconfigure_port(self, force_update: bool = False) -> None:
        if self.parity_dropped:
            self._without_parity(force_update)
            return
        try:
            super()._reconfigure_port(force_update)
        except termios.error as err:
            if self._parity == serial.PARITY_NONE or err.args[0] != errno.EINVAL:
                raise
            self._parity_dropped()
            self._without_parity(force_update)
            return
        kept = self.fd is None or termios.tcgetattr(self.fd)[2] & termios.PARENB
        if self._parity != serial.PARITY_NONE and not kept:
            self._parity_dropped()

    def _without_parity(self, force_update: bool) -> None:
        wanted = self._parity
        self._parity = serial.PARITY_NONE
        try:
            super()._reconfigure_port(force_update)
        finally:
            self._parity = wanted

    def _parity_dropped(self) -> None:
        self.parity_dropped = True
        port = str(self.portstr)
        if port in _PARITY_DROPPED_SAID:  # once per port and process, not per reconnect
            return
        _PARITY_DROPPED_SAID.add(port)
        _PARITY_LOG.info(
            "[INFO] [serial]: %s does not keep the parity bit (a pty): configured without "
            "it; the line timing still counts parity %s",
            port,
            self._parity,
        )


# The one INFO line of a port that drops the parity bit goes to stderr, beside the node's
# own console lines (the process configures no Python logging of its own).
_PARITY_LOG = logging.getLogger(f"{__name__}.parity")
_PARITY_LOG.setLevel(logging.INFO)
_PARITY_LOG.propagate = False
_PARITY_LOG.addHandler(logging.StreamHandler())
_PARITY_DROPPED_SAID: set[str] = set()


def open_serial(url: str, *args: Any, **kwargs: Any) -> Any:
    """``serial.serial_for_url``, with a plain device path opened as a
    ``ParityTolerantSerial`` in one configure (every setting given here, applied on open)."""
    if "://" in url:
        return serial.serial_for_url(url, *args, **kwargs)
    do_not_open = kwargs.pop("do_not_open", False)
    port = ParityTolerantSerial(None, *args, **kwargs)
    port.port = url
    if not do_not_open:
        port.open()
    return port


__all__ = ["ParityTolerantSerial", "open_serial", "write_all"]
