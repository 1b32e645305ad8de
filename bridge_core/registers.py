"""Register maps as validated data.

A map is the single source of truth for a device: the node decodes polls with it, the
simulator serves it, the tests check it against the manual and the docs are written from
it. Every entry cites the manual section it comes from.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

# Modbus Application Protocol V1.1b3 limits (§6.3, §6.12, §6.1, §6.11).
MAX_ADDRESS = 0xFFFF
MAX_READ_REGISTERS = 125
MAX_WRITE_REGISTERS = 123
MAX_READ_BITS = 2000
MAX_WRITE_BITS = 1968


class Table(enum.Enum):
    """The four Modbus data tables."""

    COIL = "coil"
    DISCRETE_INPUT = "discrete_input"
    HOLDING = "holding"
    INPUT = "input"

    @property
    def is_bit(self) -> bool:
        return self in (Table.COIL, Table.DISCRETE_INPUT)

    @property
    def writable(self) -> bool:
        return self in (Table.COIL, Table.HOLDING)


class ValueType(enum.Enum):
    """How the words of one value are interpreted; value = (signed, words)."""

    BOOL = ("bool", False, 1)
    U16 = ("u16", False, 1)
    I16 = ("i16", True, 1)
    U32 = ("u32", False, 2)
    I32 = ("i32", True, 2)
    U64 = ("u64", False, 4)
    I64 = ("i64", True, 4)
    F32 = ("f32", True, 2)  # IEEE 754 binary32, words in the register's word order
    F64 = ("f64", True, 4)  # IEEE 754 binary64
    STRING = ("string", False, 0)  # length given per register entry

    def __init__(self, label: str, signed: bool, words: int) -> None:
        self.label = label
        self.signed = signed
        self.words = words

    @property
    def bits(self) -> int:
        return 16 * self.words

    @property
    def is_float(self) -> bool:
        return self in (ValueType.F32, ValueType.F64)

    @property
    def raw_min(self) -> int:
        return -(1 << (self.bits - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        if self is ValueType.BOOL:
            return 1
        return (1 << (self.bits - 1)) - 1 if self.signed else (1 << self.bits) - 1


class WordOrder(enum.Enum):
    """Order of the 16-bit words of a multi-word value; bytes inside a word are big-endian."""

    HIGH_FIRST = "high_first"
    LOW_FIRST = "low_first"


class Access(enum.Enum):
    READ = "r"
    WRITE = "w"
    READ_WRITE = "rw"

    @property
    def readable(self) -> bool:
        return self is not Access.WRITE

    @property
    def writable(self) -> bool:
        return self is not Access.READ


@dataclass(frozen=True)
class Register:
    """One value of a device: where it lives, how it is coded, where the manual says so.

    ``scale`` is raw per engineering unit and ``offset`` is in engineering units:
    ``value = raw / scale + offset``, ``raw = round((value - offset) * scale)`` (floats
    unrounded). ``minimum``/``maximum`` bound writes, in engineering units.
    """

    name: str
    address: int
    value_type: ValueType
    doc: str
    table: Table = Table.HOLDING
    access: Access = Access.READ
    word_order: WordOrder = WordOrder.HIGH_FIRST
    scale: float = 1.0
    unit: str = ""
    offset: float = 0.0
    minimum: float | None = None
    maximum: float | None = None
    length: int = 0  # registers, STRING only
    description: str = ""

    def __post_init__(self) -> None:
        problems = []
        if not self.name.isidentifier():
            problems.append("name must be an identifier")
        if not self.doc:
            problems.append("doc must cite the manual")
        if self.value_type is ValueType.STRING:
            if self.length <= 0:
                problems.append("STRING needs a length in registers")
        elif self.length:
            problems.append("length is for STRING only")
        if self.table.is_bit != (self.value_type is ValueType.BOOL):
            problems.append("bit tables hold BOOL values and only they do")
        if not self.address >= 0 or self.address + self.count - 1 > MAX_ADDRESS:
            problems.append("address out of 0..65535")
        if self.scale <= 0:
            problems.append("scale must be positive")
        if self.access.writable and not self.table.writable:
            problems.append(f"{self.table.value} table is read-only")
        if self.minimum is not None and self.maximum is not None and self.minimum > self.maximum:
            problems.append("minimum > maximum")
        if problems:
            raise ValueError(f"register {self.name!r} @ {self.address}: " + "; ".join(problems))

    @property
    def count(self) -> int:
        """Registers (or bits) the value occupies."""
        return self.length if self.value_type is ValueType.STRING else self.value_type.words

    @property
    def end(self) -> int:
        """One past the last address."""
        return self.address + self.count

    def addresses(self) -> range:
        return range(self.address, self.end)


def register_array(
    name: str,
    first_address: int,
    count: int,
    value_type: ValueType,
    doc: str,
    *,
    first_index: int = 1,
    description_format: str = "",
    **fields: object,
) -> list[Register]:
    """Registers ``{name}_{i}`` laid out back to back, e.g. one per axis.

    ``description_format`` names each one after the manual, e.g. ``"OUTPUT{index}"``.
    """
    step = value_type.words
    return [
        Register(
            name=f"{name}_{first_index + i}",
            address=first_address + i * step,
            value_type=value_type,
            doc=doc,
            description=description_format.format(index=first_index + i),
            **fields,  # type: ignore[arg-type]
        )
        for i in range(count)
    ]


@dataclass(frozen=True)
class DeviceLimits:
    """What a device accepts per request; the read planner and the simulator obey it."""

    max_read_registers: int = MAX_READ_REGISTERS
    max_write_registers: int = MAX_WRITE_REGISTERS
    max_read_bits: int = MAX_READ_BITS
    # May a read span addresses that no register of the map defines?
    read_undefined_ok: bool = False
    # Largest run of unwanted (but readable) registers the planner reads through to merge
    # (in a bit table, 16 bits a register); None: no cap, the fewest requests.
    max_gap: int | None = 16
    function_codes: frozenset[int] = frozenset({1, 2, 3, 4, 5, 6, 15, 16})
    # Only registers of one width per request, and 64-bit values one at a time: for
    # devices whose manual makes every block read from its own first register (R6).
    homogeneous_requests: bool = False
    # Minimum delay before the device answers (seconds); simulators reproduce it.
    reply_delay_s: float = 0.0

    def __post_init__(self) -> None:
        if not 1 <= self.max_read_registers <= MAX_READ_REGISTERS:
            raise ValueError("max_read_registers out of 1..125")
        if not 1 <= self.max_write_registers <= MAX_WRITE_REGISTERS:
            raise ValueError("max_write_registers out of 1..123")
        if self.max_gap is not None and self.max_gap < 0:
            raise ValueError("max_gap must be >= 0")


@dataclass(frozen=True)
class RegisterMap:
    """A validated, immutable set of registers of one device."""

    device: str
    registers: tuple[Register, ...]
    limits: DeviceLimits = field(default_factory=DeviceLimits)

    def __post_init__(self) -> None:
        names: set[str] = set()
        owner: dict[tuple[Table, int], str] = {}
        for reg in self.registers:
            if reg.name in names:
                raise ValueError(f"{self.device}: duplicate register name {reg.name!r}")
            names.add(reg.name)
            for address in reg.addresses():
                key = (reg.table, address)
                if key in owner:
                    raise ValueError(
                        f"{self.device}: {reg.name!r} overlaps {owner[key]!r} at "
                        f"{reg.table.value} {address}"
                    )
                owner[key] = reg.name
        object.__setattr__(self, "_by_name", {r.name: r for r in self.registers})
        object.__setattr__(self, "_owner", owner)

    def __getitem__(self, name: str) -> Register:
        by_name: dict[str, Register] = self._by_name  # type: ignore[attr-defined]
        return by_name[name]

    def __contains__(self, name: object) -> bool:
        return name in self._by_name  # type: ignore[attr-defined]

    def __iter__(self) -> Iterator[Register]:
        return iter(self.registers)

    def __len__(self) -> int:
        return len(self.registers)

    def select(self, names: Iterable[str]) -> list[Register]:
        return [self[n] for n in names]

    def owner_at(self, table: Table, address: int) -> Register | None:
        """The register that holds ``address``, if any."""
        owner: dict[tuple[Table, int], str] = self._owner  # type: ignore[attr-defined]
        name = owner.get((table, address))
        return None if name is None else self[name]

    def is_defined(self, table: Table, address: int) -> bool:
        return (table, address) in self._owner  # type: ignore[attr-defined]

    def in_table(self, table: Table) -> list[Register]:
        return sorted((r for r in self.registers if r.table is table), key=lambda r: r.address)


def whole_values_only(
    register_map: RegisterMap, table: Table, address: int, count: int
) -> Sequence[Register]:
    """Registers touched by ``address..address+count``; raises if one is cut in two."""
    touched: dict[str, Register] = {}
    for a in range(address, address + count):
        reg = register_map.owner_at(table, a)
        if reg is not None:
            touched[reg.name] = reg
    for reg in touched.values():
        if reg.address < address or reg.end > address + count:
            raise ValueError(
                f"request {address}+{count} cuts {reg.name} ({reg.address}+{reg.count})"
            )
    return list(touched.values())
