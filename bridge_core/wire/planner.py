"""Read planner: the fewest requests a device permits for a set of registers.

Merging is worth it on every link (a TCP round trip on loopback costs ~0.1-0.2 ms, an RTU
transaction at 9600 baud tens of ms), but a device may refuse requests that span
undefined addresses, cut a 32-bit value in two, or exceed its own register limit, so
the planner only merges where the map and the device's limits allow.
"""

from __future__ import annotations

import bisect
import functools
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from .codec import Value
from .registers import DeviceLimits, Register, RegisterMap, Table, ValueType, WordOrder


@dataclass(frozen=True)
class ReadRequest:
    """One read transaction and the registers it serves."""

    table: Table
    address: int
    count: int
    registers: tuple[Register, ...]

    @property
    def end(self) -> int:
        return self.address + self.count

    @functools.cached_property
    def decoder(self) -> BlockDecoder:
        return BlockDecoder(self)

    @functools.cached_property
    def names(self) -> frozenset[str]:
        """The names of the registers it serves (a poll asks every cycle: cached)."""
        return frozenset(reg.name for reg in self.registers)

    @functools.cached_property
    def bit_offsets(self) -> tuple[tuple[str, int], ...]:
        return tuple((reg.name, reg.address - self.address) for reg in self.registers)


# A bit table's gap is counted in bits, a register table's in registers; a gap cap given in
# registers allows the same bytes of bits (16 bits travel in the bytes of one register).
BITS_PER_REGISTER = 16


def _gap_is_readable(
    register_map: RegisterMap,
    table: Table,
    start: int,
    end: int,
    limits: DeviceLimits,
    width: int = 1,
) -> bool:
    """Whether reading through ``start..end`` is allowed: every address readable and whole."""
    if start == end:
        return True
    if limits.max_gap is not None:
        cap = limits.max_gap * (BITS_PER_REGISTER if table.is_bit else 1)
        if end - start > cap:
            return False
    address = start
    while address < end:
        owner = register_map.owner_at(table, address)
        if owner is None:
            if not limits.read_undefined_ok:
                return False
            address += 1
            continue
        if not owner.access.readable or owner.address < start or owner.end > end:
            return False
        if limits.homogeneous_requests and owner.count != width:
            return False
        address = owner.end
    return True


def plan_reads(
    register_map: RegisterMap, wanted: Iterable[Register], limits: DeviceLimits | None = None
) -> list[ReadRequest]:
    """Cover ``wanted`` with the fewest requests ``limits`` allow, never cutting a value;
    of plans with as few requests, one that reads the fewest registers (or bits)."""
    limits = limits or register_map.limits
    by_table: dict[Table, list[Register]] = {}
    for reg in wanted:
        if not reg.access.readable:
            raise ValueError(f"{reg.name} is write-only")
        by_table.setdefault(reg.table, []).append(reg)
    requests: list[ReadRequest] = []
    for table in sorted(by_table, key=lambda t: t.value):
        regs = sorted(set(by_table[table]), key=lambda r: r.address)
        requests += _plan_table(register_map, table, regs, limits)
    return requests


def _plan_table(
    register_map: RegisterMap, table: Table, regs: Sequence[Register], limits: DeviceLimits
) -> list[ReadRequest]:
    """A dynamic programme over the sorted registers: ``best[i]`` is the cost (requests,
    then values read) of reading ``regs[i:]``, its first request serving ``regs[i:cut[i]]``.

    A request serves a run of consecutive wanted registers (one that serves two serves
    every wanted register between them), and a run that may not be read in one request
    cannot grow into one that may (the span only grows, a refused gap stays inside it),
    so the first request reaches as far as the first refusal or the request limit.
    As fast as the greedy planner it replaced (bench/planner_bench.py: the R6 map's 2384
    registers in ~8-16 ms on a loaded 2-core machine, both).
    """
    limit = limits.max_read_bits if table.is_bit else limits.max_read_registers
    count = len(regs)
    # Plain lists for the loops (the R6 map plans ~2400 registers at start-up).
    starts = [reg.address for reg in regs]
    widths = [reg.count for reg in regs]
    ends = [start + width for start, width in zip(starts, widths, strict=True)]
    for reg, width in zip(regs, widths, strict=True):
        if width > limit:
            raise ValueError(f"{reg.name} is larger than one request allows ({limit})")
    # joins[j]: may regs[j] share a request with regs[j - 1] (the gap between them
    # readable; on a homogeneous device, the same width, 64-bit values alone)?
    homogeneous = limits.homogeneous_requests
    joins = [False] * count
    for j in range(1, count):
        width = widths[j]
        joins[j] = (
            not homogeneous or (width == widths[j - 1] and width < ValueType.U64.words)
        ) and (
            ends[j - 1] == starts[j]
            or _gap_is_readable(register_map, table, ends[j - 1], starts[j], limits, width)
        )
    # breaks[i]: the first j > i that may not join regs[j - 1] (count: none)
    breaks = [count] * (count + 1)
    for i in range(count - 2, -1, -1):
        breaks[i] = i + 1 if not joins[i + 1] else breaks[i + 1]
    # floor[i]: the values regs[i:] hold, the fewest any plan of them can read
    floor = [0] * (count + 1)
    for i in range(count - 1, -1, -1):
        floor[i] = floor[i + 1] + ends[i] - starts[i]
    best_requests = [0] * (count + 1)
    best_values = [0] * (count + 1)
    cut = [count] * (count + 1)
    for i in range(count - 1, -1, -1):
        first = starts[i]
        # The farthest register the first request may reach: fewer registers left never
        # take more requests, so it gives the fewest; then, going back over the choices
        # with as many requests, the one reading the fewest values (a tie: the longer).
        reach = min(breaks[i], bisect.bisect_right(ends, first + limit, i)) - 1
        fewest = best_requests[reach + 1] + 1
        values = best_values[reach + 1] + ends[reach] - first
        cut[i] = reach + 1
        j = reach - 1
        while values > floor[i] and j >= i and best_requests[j + 1] + 1 == fewest:
            candidate = best_values[j + 1] + ends[j] - first
            if candidate < values:
                values, cut[i] = candidate, j + 1
            j -= 1
        best_requests[i], best_values[i] = fewest, values
    requests: list[ReadRequest] = []
    i = 0
    while i < count:
        served = tuple(regs[i : cut[i]])
        start = served[0].address
        requests.append(ReadRequest(table, start, served[-1].end - start, served))
        i = cut[i]
    return requests


def split_request(request: ReadRequest) -> tuple[ReadRequest, ...]:
    """The reads of a merged read the device refused (ILLEGAL DATA ADDRESS) without the
    addresses between its registers (a row the device does not serve, though the map
    allowed it). Empty for a read without gaps: its refusal is the registers' own."""
    regs = sorted(request.registers, key=lambda r: r.address)
    if not regs:
        return ()
    runs: list[list[Register]] = [[regs[0]]]
    for reg in regs[1:]:
        if reg.address == runs[-1][-1].end:
            runs[-1].append(reg)
        else:
            runs.append([reg])
    if len(runs) == 1:
        return ()
    return tuple(
        ReadRequest(request.table, run[0].address, run[-1].end - run[0].address, tuple(run))
        for run in runs
    )


# struct codes of high-word-first values: the words are big-endian, so the whole block is
# one big-endian byte string and each value one struct field.
_STRUCT_CODES = {
    ValueType.U16: "H",
    ValueType.I16: "h",
    ValueType.U32: "I",
    ValueType.I32: "i",
    ValueType.U64: "Q",
    ValueType.I64: "q",
    ValueType.F32: "f",
    ValueType.F64: "d",
}


class BlockDecoder:
    """Decodes one planned register request with a single precompiled ``struct``.

    The hot path of every poll: bench/r6_bench.py measured the per-value decoder at about
    a third of the device layer's CPU. Same results as ``codec.decode`` (tested).
    """

    def __init__(self, request: ReadRequest) -> None:
        self.count = request.count
        self._words = struct.Struct(f">{request.count}H")
        fields: list[str] = []
        # (name, kind, scale, offset, word count) per unpacked field, in order
        self._plan: list[tuple[str, str, float, float, int]] = []
        position = request.address
        for reg in sorted(request.registers, key=lambda r: r.address):
            if reg.address > position:
                fields.append(f"{2 * (reg.address - position)}x")
            kind = reg.value_type
            if kind is ValueType.STRING:
                fields.append(f"{2 * reg.count}s")
                self._plan.append((reg.name, "string", 1.0, 0.0, 1))
            elif kind is ValueType.BOOL:
                fields.append("H")
                self._plan.append((reg.name, "bool", 1.0, 0.0, 1))
            elif kind.words == 1 or reg.word_order is WordOrder.HIGH_FIRST:
                fields.append(_STRUCT_CODES[kind])
                self._plan.append((reg.name, "int", reg.scale, reg.offset, 1))
            else:  # low word first: unpack the words, join them in reverse
                fields.append(f"{kind.words}H")
                joined = "float" if kind.is_float else "signed" if kind.signed else "unsigned"
                self._plan.append((reg.name, joined, reg.scale, reg.offset, kind.words))
            position = reg.end
        self._values = struct.Struct(">" + "".join(fields))

    def __call__(self, words: Sequence[int]) -> dict[str, Value]:
        if len(words) < self.count:
            raise ValueError(f"reply has {len(words)} values, request asked for {self.count}")
        fields = self._values.unpack(self._words.pack(*words[: self.count]))
        values: dict[str, Value] = {}
        index = 0
        for name, kind, scale, offset, nwords in self._plan:
            raw: int | float | str | bool
            if kind == "int":
                raw = fields[index]
            elif kind == "bool":
                raw = bool(fields[index])
            elif kind == "string":
                raw = fields[index].rstrip(b"\x00").decode("latin-1")
            else:
                joined = 0
                for word in reversed(fields[index : index + nwords]):
                    joined = (joined << 16) | word
                if kind == "signed" and joined >= 1 << (16 * nwords - 1):
                    joined -= 1 << (16 * nwords)
                raw = joined
                if kind == "float":
                    raw = struct.unpack(
                        ">f" if nwords == 2 else ">d", joined.to_bytes(2 * nwords, "big")
                    )[0]
            index += nwords
            if (scale != 1.0 or offset != 0.0) and not isinstance(raw, str | bool):
                raw = raw / scale + offset
            values[name] = raw
        return values


def decode_reply(request: ReadRequest, words: Sequence[int] | Sequence[bool]) -> dict[str, Value]:
    """Values of the request's registers from the words (or bits) the device returned."""
    if len(words) < request.count:
        raise ValueError(f"reply has {len(words)} values, request asked for {request.count}")
    if not request.table.is_bit:
        return request.decoder(words)
    # Bit tables hold one BOOL per address: pick them out by precomputed offset.
    return {name: bool(words[offset]) for name, offset in request.bit_offsets}


def merge_values(parts: Iterable[Mapping[str, Value]]) -> dict[str, Value]:
    merged: dict[str, Value] = {}
    for part in parts:
        merged.update(part)
    return merged
