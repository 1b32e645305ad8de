"""Read planner: the fewest requests a device permits for a set of registers.

Merging is worth it on every link (a TCP round trip on loopback costs ~0.1-0.2 ms, an RTU
transaction at 9600 baud tens of ms), but a device may refuse requests that span
undefined addresses, cut a 32-bit value in two, or exceed its own register limit, so
the planner only merges where the map and the device's limits allow.
"""

from __future__ import annotations

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
    if end - start > limits.max_gap:
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


def _same_kind(first: Register, other: Register) -> bool:
    """May ``other`` join a request that ``first`` opened, on a homogeneous device?"""
    return first.count == other.count and first.count < ValueType.U64.words


def plan_reads(
    register_map: RegisterMap, wanted: Iterable[Register], limits: DeviceLimits | None = None
) -> list[ReadRequest]:
    """Cover ``wanted`` with as few requests as ``limits`` allow, never cutting a value."""
    limits = limits or register_map.limits
    by_table: dict[Table, list[Register]] = {}
    for reg in wanted:
        if not reg.access.readable:
            raise ValueError(f"{reg.name} is write-only")
        by_table.setdefault(reg.table, []).append(reg)
    requests: list[ReadRequest] = []
    for table in sorted(by_table, key=lambda t: t.value):
        limit = limits.max_read_bits if table.is_bit else limits.max_read_registers
        regs = sorted(set(by_table[table]), key=lambda r: r.address)
        current: list[Register] = []
        start = end = 0
        for reg in regs:
            if reg.count > limit:
                raise ValueError(f"{reg.name} is larger than one request allows ({limit})")
            if (
                current
                and reg.end - start <= limit
                and reg.address >= end
                and _gap_is_readable(register_map, table, end, reg.address, limits, reg.count)
                and (not limits.homogeneous_requests or _same_kind(current[0], reg))
            ):
                current.append(reg)
                end = reg.end
                continue
            if current:
                requests.append(ReadRequest(table, start, end - start, tuple(current)))
            current, start, end = [reg], reg.address, reg.end
        if current:
            requests.append(ReadRequest(table, start, end - start, tuple(current)))
    return requests


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
