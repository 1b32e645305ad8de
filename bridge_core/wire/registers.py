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


@dataclass(frozen=True)
class Fault:
    """One broken rule: the field at fault (None: the entry as a whole) and what is wrong,
    with what is allowed, worded for any source of registers (a map module, a YAML file).
    ``index``: the position of the register at fault in a ``RegisterMap``."""

    field: str | None
    message: str
    index: int | None = None


class RuleError(ValueError):
    """A ``Register``, ``RegisterMap`` or ``DeviceLimits`` refused: all its faults, so a
    caller can point each at where it was written (modbus_bridge's YAML key and line)."""

    def __init__(self, subject: str, faults: Sequence[Fault]) -> None:
        self.subject = subject
        self.faults = tuple(faults)
        super().__init__(f"{subject}: " + "; ".join(fault.message for fault in self.faults))


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


# The function code that reads each table, and those that write the writable ones
# (single, multiple): a map's registers need them in the device's function codes.
READ_FUNCTION = {Table.COIL: 1, Table.DISCRETE_INPUT: 2, Table.HOLDING: 3, Table.INPUT: 4}
WRITE_FUNCTIONS = {Table.COIL: (5, 15), Table.HOLDING: (6, 16)}


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
        faults = self._faults()
        if faults:
            raise RuleError(f"register {self.name!r} @ {self.address}", faults)

    def _faults(self) -> list[Fault]:
        """The rules this register breaks, each naming its field and what is allowed."""
        kind, table, label = self.value_type, self.table, self.value_type.label
        found: list[Fault] = []
        span = f"(0..{MAX_ADDRESS})"
        if not self.name.isidentifier():
            found.append(Fault("name", f"{self.name!r} is not a name (allowed: an identifier)"))
        if not self.doc:
            found.append(Fault("doc", "empty: cite the manual section the register comes from"))
        if table.is_bit != (kind is ValueType.BOOL):
            allowed = "bool" if table.is_bit else "any type but bool"
            found.append(
                Fault("value_type", f"{label} in the {table.value} table (allowed: {allowed})")
            )
        if kind is ValueType.STRING and self.length <= 0:
            found.append(Fault("length", "missing: a string needs its length in registers"))
        if kind is not ValueType.STRING and self.length:
            found.append(Fault("length", "only a string has a length (its type fixes the size)"))
        if self.access.writable and not table.writable:
            access = self.access.value.upper()
            found.append(Fault("access", f"{access} on the read-only {table.value} table (R)"))
        if self.address < 0:
            found.append(
                Fault("address", f"{self.address}: must be greater than or equal to 0 {span}")
            )
        elif self.address > MAX_ADDRESS:
            found.append(
                Fault(
                    "address", f"{self.address}: must be less than or equal to {MAX_ADDRESS} {span}"
                )
            )
        elif self.end - 1 > MAX_ADDRESS:
            found.append(Fault("address", f"{self.address}+{self.count} runs past {MAX_ADDRESS}"))
        if self.scale <= 0:
            found.append(Fault("scale", f"{self.scale}: must be greater than 0 (raw per unit)"))
        if kind in (ValueType.BOOL, ValueType.STRING) and (
            self.scale != 1.0
            or self.offset != 0.0
            or self.minimum is not None
            or self.maximum is not None
        ):
            found.append(Fault(None, f"a {label} has no scale, offset or range"))
        if self.minimum is not None and self.maximum is not None and self.minimum > self.maximum:
            found.append(Fault("minimum", f"[{self.minimum}, {self.maximum}]: minimum > maximum"))
        return found

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
        found = [
            fault
            for name, top in (
                ("max_read_registers", MAX_READ_REGISTERS),
                ("max_write_registers", MAX_WRITE_REGISTERS),
                ("max_read_bits", MAX_READ_BITS),
            )
            if (fault := _bounded(name, getattr(self, name), 1, top)) is not None
        ]
        if self.max_gap is not None:
            gap = _bounded("max_gap", self.max_gap, 0, MAX_READ_REGISTERS)
            found += [gap] if gap is not None else []
        if found:
            raise RuleError("device limits", found)


def _bounded(name: str, value: int, low: int, high: int) -> Fault | None:
    """A fault if ``value`` is outside ``low..high``."""
    if value < low:
        return Fault(name, f"{value}: must be greater than or equal to {low} ({low}..{high})")
    if value > high:
        return Fault(name, f"{value}: must be less than or equal to {high} ({low}..{high})")
    return None


@dataclass(frozen=True)
class RegisterMap:
    """A validated, immutable set of registers of one device."""

    device: str
    registers: tuple[Register, ...]
    limits: DeviceLimits = field(default_factory=DeviceLimits)

    def __post_init__(self) -> None:
        faults: list[Fault] = []
        owner: dict[tuple[Table, int], str] = {}
        names: set[str] = set()
        for index, reg in enumerate(self.registers):
            faults += [
                Fault(fault.field, fault.message, index)
                for fault in self._faults(reg, names, owner)
            ]
        if faults:
            raise RuleError(self.device, faults)
        object.__setattr__(self, "_by_name", {r.name: r for r in self.registers})
        object.__setattr__(self, "_owner", owner)

    def _faults(
        self, reg: Register, names: set[str], owner: dict[tuple[Table, int], str]
    ) -> list[Fault]:
        """The map's rules for one register: a unique name, a size one read takes, the
        function codes its access needs, and addresses no other register holds."""
        found: list[Fault] = []
        if reg.name in names:
            message = f"duplicate name: register {reg.name!r} defined twice (names are unique)"
            found.append(Fault("name", message))
        names.add(reg.name)
        table, codes = reg.table.value, self.limits.function_codes
        limit = self.limits.max_read_bits if reg.table.is_bit else self.limits.max_read_registers
        if reg.access.readable and reg.count > limit:
            field = "length" if reg.value_type is ValueType.STRING else "value_type"
            found.append(Fault(field, f"{reg.count} registers: more than one read takes ({limit})"))
        read = READ_FUNCTION[reg.table]
        if reg.access.readable and read not in codes:
            message = f"readable {table} needs function code {read} in the device's function_codes"
            found.append(Fault("table", message + " (or access W)"))
        # (a writable register of a read-only table is the Register's fault already)
        writes = WRITE_FUNCTIONS.get(reg.table, ())
        if reg.access.writable and writes and not codes & set(writes):
            either = " or ".join(str(code) for code in writes)
            message = (
                f"writable {table} needs function code {either} in the device's function_codes"
            )
            found.append(Fault("access", message))
        for address in reg.addresses():
            other = owner.setdefault((reg.table, address), reg.name)
            if other != reg.name:
                found.append(
                    Fault(
                        "address",
                        f"{reg.name} overlaps {other} at {table} {address} "
                        "(each address belongs to one register)",
                    )
                )
                break
        return found

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
