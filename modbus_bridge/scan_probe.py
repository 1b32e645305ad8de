"""How ``modbus_scan`` finds what a device answers: reads only, bounded and paced.

A table's address ranges are read in blocks of the largest size a request may carry; a
block the device refuses (an exception, or no reply while the device still answers
elsewhere) is split in two, down to single addresses, which finds the addresses that
answer and the exception each other one gets. Split points fall on multiples of
``SPLIT_ALIGN`` where they can, so a 32- or 64-bit value at an aligned address is never
cut in two (a strict device refuses a read that cuts a value: it would look undefined).
In a register table, each run of refused registers is then read again with odd split
points (``odd_pass``: values at odd addresses), and what is still refused next to an
answer as 2- and 4-register values from each answering edge inward
(``join_cut_values``): a value a split did cut answers whole. Last, each merged block is
read once whole (``confirm_blocks``), as the bridge would poll it.

Every request goes through ``Prober.read``, which counts it against the budget, keeps the
pause before it, and tells a device that stopped answering (``DeviceStopped``) from one
that is silent for one range only. The reader is a ``BlockReader``: read functions only,
so nothing here can write (``modbus_bridge.scan`` gives it a ``DeviceChannel``).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Protocol

from bridge_core.wire.errors import DeviceException, FrameError, LinkDown, LinkTimeout
from bridge_core.wire.registers import READ_FUNCTION, Table

# Requests without a reply in a row, before any address answered, after which the device
# is taken as not there (wrong address, unit id or line settings).
SILENT_REQUESTS_LIMIT = 3
# Split points of a refused block fall on multiples of this where the block allows: a
# 32- or 64-bit value at an address that is a multiple of its width is never cut.
SPLIT_ALIGN = 4
# Widths tried for a value a split cut: 32- and 64-bit values.
WHOLE_VALUE_WIDTHS = (2, 4)
# What a refused address's "code" is when the device did not answer it (not a Modbus
# exception code, which are 1..255).
NO_REPLY = 0
ILLEGAL_FUNCTION = 0x01


class BlockReader(Protocol):
    """The reads a scan sends (``DeviceChannel`` has them): nothing that writes."""

    def read_registers(self, address: int, count: int, table: Table = ...) -> list[int]: ...
    def read_bits(self, address: int, count: int, table: Table = ...) -> list[bool]: ...


class DeviceStopped(Exception):
    """The device no longer answers (or never did): the scan ends with this one line."""


class BudgetSpent(Exception):
    """The request budget is used up: the scan ends with what it found so far."""


class FunctionNotServed(Exception):
    """The table's read function answered ILLEGAL FUNCTION before any address answered."""


@dataclass
class TableScan:
    """What one table's scan found."""

    table: Table
    ranges: tuple[tuple[int, int], ...]  # first, last address (inclusive)
    answered: set[int] = field(default_factory=set)
    # Single addresses refused: address -> exception code (NO_REPLY: no answer).
    refused: dict[int, int] = field(default_factory=dict)
    # Values that answered only whole (a split had cut them): first address -> registers.
    whole_values: dict[int, int] = field(default_factory=dict)
    codes: Counter[int] = field(default_factory=Counter)  # every refusal's code, counted
    largest_read: int = 0  # the most registers / bits one answered request carried
    # Merged blocks (first, count) refused as one read: the code (``confirm_blocks``).
    parts: dict[tuple[int, int], int] = field(default_factory=dict)
    not_served: bool = False  # ILLEGAL FUNCTION: the table's read function is not served
    scanned_to: int | None = None  # the budget ran out here (None: every range done)

    @property
    def function_code(self) -> int:
        return READ_FUNCTION[self.table]

    def found(self) -> set[int]:
        """Every address that answered, in a block or as part of a whole value."""
        addresses = set(self.answered)
        for start, width in self.whole_values.items():
            addresses.update(range(start, start + width))
        return addresses


@dataclass
class Prober:
    """Sends the scan's reads: paced, counted against the budget, silence judged."""

    reader: BlockReader
    budget: int
    pause_s: float
    clock: Callable[[], float] = time.monotonic
    sleep: Callable[[float], None] = time.sleep
    requests: int = 0
    _last_end: float | None = None
    _silent_in_a_row: int = 0
    _alive_at: tuple[Table, int] | None = None  # one address that answered: a liveness check

    def read(self, table: Table, address: int, count: int) -> int | None:
        """One read: None if it answered, else the exception code (``NO_REPLY``: none,
        while the device still answers elsewhere). Raises ``DeviceStopped``, ``BudgetSpent``."""
        try:
            self._send(table, address, count)
        except DeviceException as err:
            self._silent_in_a_row = 0
            return err.exception_code
        except (LinkTimeout, FrameError) as err:
            return self._silence(table, address, count, err)
        self._silent_in_a_row = 0
        self._alive_at = (table, address)
        return None

    def _send(self, table: Table, address: int, count: int) -> None:
        if self.requests >= self.budget:
            raise BudgetSpent(f"{table.value} {address}")
        if self._last_end is not None:
            wait = self._last_end + self.pause_s - self.clock()
            if wait > 0:
                self.sleep(wait)
        self.requests += 1
        try:
            if table.is_bit:
                self.reader.read_bits(address, count, table)
            else:
                self.reader.read_registers(address, count, table)
        except LinkDown as err:
            raise DeviceStopped(f"the link is down: {err}") from None
        finally:
            self._last_end = self.clock()

    def _silence(self, table: Table, address: int, count: int, err: Exception) -> int:
        what = f"{table.value} {span_text(address, count)}"
        alive = self._alive_at
        if alive is None:
            self._silent_in_a_row += 1
            if self._silent_in_a_row >= SILENT_REQUESTS_LIMIT:
                raise DeviceStopped(
                    f"no reply to {self._silent_in_a_row} requests in a row (last: {what}: "
                    f"{err}); check the address or port, unit id and line settings"
                )
            return NO_REPLY
        try:
            self._send(*alive, 1)
        except (LinkTimeout, FrameError) as again:
            raise DeviceStopped(
                f"the device stopped answering: {what}: {err}, and {alive[0].value} "
                f"{alive[1]}, which answered before: {again}"
            ) from None
        except DeviceException:
            pass  # it answers: only that range was silent
        return NO_REPLY


def span_text(address: int, count: int) -> str:
    """``12`` or ``12-15``."""
    return str(address) if count == 1 else f"{address}-{address + count - 1}"


def split_point(address: int, count: int, odd: bool = False) -> int:
    """Where a refused block is split: near its middle, on a multiple of ``SPLIT_ALIGN``
    (else of 2) inside it where there is one, so aligned values are not cut; ``odd``: on
    an odd address (the second pass, for values at odd addresses)."""
    middle = address + count // 2
    for align in (2,) if odd else (SPLIT_ALIGN, 2):
        below = middle - middle % align + (1 if odd else 0)
        for point in sorted((below - align, below, below + align), key=lambda p: abs(p - middle)):
            if address < point < address + count:
                return point
    return middle


def probe_block(
    prober: Prober, scan: TableScan, address: int, count: int, odd: bool = False
) -> None:
    """Read a block; if it is refused, split it down to single addresses."""
    code = prober.read(scan.table, address, count)
    if code is None:
        scan.answered.update(range(address, address + count))
        for done in range(address, address + count):
            scan.refused.pop(done, None)
        scan.largest_read = max(scan.largest_read, count)
        return
    scan.codes[code] += 1
    if code == ILLEGAL_FUNCTION and not scan.answered:
        raise FunctionNotServed
    if count == 1:
        scan.refused[address] = code
        return
    point = split_point(address, count, odd)
    probe_block(prober, scan, address, point - address, odd)
    probe_block(prober, scan, point, address + count - point, odd)


def blocks_of(first: int, last: int, size: int) -> Iterator[tuple[int, int]]:
    """``first`` .. ``last`` as requests of at most ``size``: (address, count)."""
    for address in range(first, last + 1, size):
        yield address, min(size, last + 1 - address)


def contiguous(addresses: Iterable[int]) -> list[tuple[int, int]]:
    """Addresses merged into runs: (first, count)."""
    runs: list[tuple[int, int]] = []
    for address in sorted(addresses):
        if runs and runs[-1][0] + runs[-1][1] == address:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((address, 1))
    return runs


def refused_runs(scan: TableScan) -> list[tuple[int, int]]:
    """Runs of refused single addresses (first, count), across block edges."""
    return contiguous(scan.refused)


def confirm_blocks(prober: Prober, scan: TableScan, block: int) -> None:
    """Read each merged block once as the bridge would (in requests of at most
    ``block``): the largest read that answers is the skeleton's limit, and a block the
    device takes only in parts is said (``parts``)."""
    for first, count in contiguous(scan.found()):
        for address, length in blocks_of(first, first + count - 1, block):
            if length <= scan.largest_read:
                continue
            code = prober.read(scan.table, address, length)
            if code is None:
                scan.largest_read = length
            else:
                scan.parts[(address, length)] = code


def _whole_at(prober: Prober, scan: TableScan, address: int, end: int) -> int | None:
    """The width of a whole value that answers at ``address`` and ends by ``end``."""
    for width in WHOLE_VALUE_WIDTHS:
        if address + width <= end and prober.read(scan.table, address, width) is None:
            return width
    return None


def _take(scan: TableScan, address: int, width: int) -> None:
    scan.whole_values[address] = width
    scan.largest_read = max(scan.largest_read, width)
    for taken in range(address, address + width):
        scan.refused.pop(taken, None)


def join_cut_values(prober: Prober, scan: TableScan) -> None:
    """Read runs of refused registers next to an answer as whole values, walking in from
    each answering edge while whole values answer (a chain of 32-bit values at odd
    addresses, every one cut by the even split points, is found value by value)."""
    for first, count in refused_runs(scan):
        low, high = first, first + count  # the part of the run not yet explained
        if first - 1 in scan.answered:
            while low < high and (width := _whole_at(prober, scan, low, high)) is not None:
                _take(scan, low, width)
                low += width
        if first + count in scan.answered:
            while low < high:
                width = next(
                    (
                        w
                        for w in WHOLE_VALUE_WIDTHS
                        if high - w >= low and prober.read(scan.table, high - w, w) is None
                    ),
                    None,
                )
                if width is None:
                    break
                _take(scan, high - width, width)
                high -= width


def odd_pass(prober: Prober, scan: TableScan, block: int) -> None:
    """Read each run of refused registers again with odd split points: a 32-bit value at
    an odd address between refused ones is cut by every even split of the first pass."""
    for first, count in refused_runs(scan):
        # Requests start at odd addresses (an even first address was read alone already).
        start = first | 1
        if first + count - start < min(WHOLE_VALUE_WIDTHS):
            continue
        size = block - block % 2 or 1
        for address, length in blocks_of(start, first + count - 1, size):
            probe_block(prober, scan, address, length, odd=True)


def scan_table(prober: Prober, scan: TableScan, block: int) -> None:
    """Scan one table's ranges (``BudgetSpent`` and ``DeviceStopped`` pass through; the
    budget leaves ``scanned_to`` where it stopped): blocks split where refused; for
    registers, then odd split points, then whole values next to answers; then each merged
    block is read once whole."""
    at = scan.ranges[0][0]
    try:
        for first, last in scan.ranges:
            for at, count in blocks_of(first, last, block):
                probe_block(prober, scan, at, count)
        if not scan.table.is_bit:
            at = scan.ranges[-1][1]
            odd_pass(prober, scan, block)
            join_cut_values(prober, scan)
        confirm_blocks(prober, scan, block)
    except FunctionNotServed:
        scan.not_served = True
    except BudgetSpent:
        scan.scanned_to = at
        raise
