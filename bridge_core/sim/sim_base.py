"""The simulated device: one unit's memory and behaviour, driven by a register map.

Each simulated unit (``SimulatedDevice``) serves exactly the addresses its map defines
(exception 0x02 elsewhere), refuses requests that cut a multi-register value in two,
takes only FF00 / 0000 on FC 05 (0x03 otherwise), keeps a write log the tests assert on
(``logs``), and calls behaviour hooks (device ``sim.py`` modules subclass it to make axes
move, alarms appear ...). ``serving.Simulator`` runs the pymodbus server that hands it the
requests (function codes the device lacks are refused there and in ``strict_decoding``);
``command_line`` is the simulators' shared command line.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import IO, ClassVar

from pymodbus.constants import ExcCodes

from ..wire.codec import Value, decode, encode
from ..wire.registers import DeviceLimits, Register, RegisterMap, Table, ValueType
from .logs import ReadRecord, WriteRecord

FUNCTION_TABLES: dict[int, Table] = {
    1: Table.COIL,
    5: Table.COIL,
    15: Table.COIL,
    2: Table.DISCRETE_INPUT,
    3: Table.HOLDING,
    6: Table.HOLDING,
    16: Table.HOLDING,
    22: Table.HOLDING,
    23: Table.HOLDING,
    4: Table.INPUT,
}
ILLEGAL_FUNCTION = int(ExcCodes.ILLEGAL_FUNCTION)
ILLEGAL_ADDRESS = int(ExcCodes.ILLEGAL_ADDRESS)
ILLEGAL_VALUE = int(ExcCodes.ILLEGAL_VALUE)
DEVICE_FAILURE = int(ExcCodes.DEVICE_FAILURE)

# A hook sees a write before it lands and may refuse it with an exception code.
WriteGuard = Callable[[WriteRecord], int | None]
WriteHook = Callable[[WriteRecord], None]


class SimulatedDevice:
    """Memory and behaviour of one unit id, driven by a register map."""

    # The motion writes this device can be told to ignore (``--ignore``): name -> what
    # it is; ``write_names`` says which of them a write is.
    IGNORABLE: ClassVar[Mapping[str, str]] = {}

    def __init__(
        self,
        register_map: RegisterMap,
        unit_id: int = 1,
        *,
        limits: DeviceLimits | None = None,
        extra_addresses: dict[Table, Iterable[int]] | None = None,
        whole_values: bool = True,
        whole_value_writes: bool | None = None,
    ) -> None:
        self.map = register_map
        self.unit_id = unit_id
        self.limits = limits or register_map.limits
        self.whole_values = whole_values
        # A write that cuts a multi-register value is refused too, unless the device is
        # known to store what it gets word by word (default: as for reads).
        self.whole_value_writes = whole_values if whole_value_writes is None else whole_value_writes
        self.lock = threading.RLock()
        self.words: dict[tuple[Table, int], int] = {}
        # Per name: the register as ``set`` encodes it, the last value set and its words.
        self._last_set: dict[str, tuple[Register, Value, tuple[int, ...]]] = {}
        self.readable: set[tuple[Table, int]] = set()
        self.writable: set[tuple[Table, int]] = set()
        for reg in register_map:
            for address in reg.addresses():
                key = (reg.table, address)
                self.words[key] = 0
                if reg.access.readable:
                    self.readable.add(key)
                if reg.access.writable:
                    self.writable.add(key)
        for table, addresses in (extra_addresses or {}).items():
            for address in addresses:
                self.words.setdefault((table, address), 0)
                self.readable.add((table, address))
                if table.writable:
                    self.writable.add((table, address))
        self.write_log: list[WriteRecord] = []
        self.write_guards: list[WriteGuard] = []
        self.write_hooks: list[WriteHook] = []
        self.log_file: IO[str] | None = None
        # Read log, off by default (one record per read request when on): ``read_log``
        # in memory while ``log_reads`` is set, and/or JSON lines to ``read_log_file``.
        self.log_reads = False
        self.read_log: list[ReadRecord] = []
        self.read_log_file: IO[str] | None = None
        # Fault injection: address ranges that answer with a given exception code.
        self.forced_exceptions: list[tuple[Table, range, int]] = []
        # Personality: the motion writes (names of ``IGNORABLE``) acknowledged and ignored.
        self.ignore: frozenset[str] = frozenset()

    def write_names(self, record: WriteRecord) -> frozenset[str]:
        """Which of ``IGNORABLE`` this write is (device simulators override)."""
        return frozenset()

    def ignores(self, record: WriteRecord) -> bool:
        """Whether this device, playing ``--ignore``, leaves this write without effect."""
        return bool(self.ignore) and bool(self.write_names(record) & self.ignore)

    # ------------------------------------------------------------ values by name
    def get(self, name: str) -> Value:
        reg = self.map[name]
        with self.lock:
            return decode(reg, [self.words[(reg.table, a)] for a in reg.addresses()])

    def set(self, name: str, value: Value) -> None:
        """Set a value as the device itself would (no write-range check, no log).

        A tick sets dozens of values 100 times a second, most of them unchanged: the words
        of the last value set under ``name`` are kept, and a value whose words the table
        holds already is not stored again (a store of the same words changes nothing, the
        R6 simulator's coil and row mirror included)."""
        last = self._last_set.get(name)
        if last is not None and _same_value(last[1], value):
            reg, _, words = last
        else:
            reg = last[0] if last is not None else self._unchecked(name)
            words = tuple(encode(reg, value))
            self._last_set[name] = (reg, value, words)
        with self.lock:
            table, address = reg.table, reg.address
            if all(self.words[(table, address + i)] == w for i, w in enumerate(words)):
                return
            self.set_words(table, address, words)

    def _unchecked(self, name: str) -> Register:
        """The register without its write range: the device's own values are not writes."""
        return dataclasses.replace(self.map[name], minimum=None, maximum=None)

    def set_words(self, table: Table, address: int, values: Sequence[int]) -> None:
        with self.lock:
            for offset, word in enumerate(values):
                self.words[(table, address + offset)] = int(word)

    def get_words(self, table: Table, address: int, count: int) -> list[int]:
        with self.lock:
            return [self.words[(table, address + i)] for i in range(count)]

    # ------------------------------------------------------------ Modbus side
    def _check(self, table: Table, address: int, count: int, writing: bool) -> int | None:
        allowed = self.writable if writing else self.readable
        for a in range(address, address + count):
            if (table, a) not in allowed:
                return ILLEGAL_ADDRESS
        for forced_table, forced, code in self.forced_exceptions:
            if forced_table is table and any(a in forced for a in range(address, address + count)):
                return code
        if self.limits.homogeneous_requests and not table.is_bit and not writing:
            widths = {
                owner.count
                for a in range(address, address + count)
                if (owner := self.map.owner_at(table, a)) is not None
                and owner.value_type is not ValueType.STRING
            }
            if len(widths) > 1 or (widths == {ValueType.U64.words} and count != widths.pop()):
                return ILLEGAL_ADDRESS  # mixed widths, or more than one 64-bit value
        if (self.whole_value_writes if writing else self.whole_values) and not table.is_bit:
            # Strings may be read in part (R6 version: (length + 1) / 2 registers).
            for a in (address, address + count - 1):
                reg = self.map.owner_at(table, a)
                if (
                    reg is not None
                    and reg.value_type is not ValueType.STRING
                    and (reg.address < address or reg.end > address + count)
                ):
                    return ILLEGAL_ADDRESS
        return None

    def read(self, function_code: int, address: int, count: int) -> list[int] | int:
        table = FUNCTION_TABLES[function_code]
        if self.log_reads or self.read_log_file is not None:
            record = ReadRecord(time.time(), self.unit_id, function_code, table, address, count)
            self._log_read(record)
        limit = self.limits.max_read_bits if table.is_bit else self.limits.max_read_registers
        if count > limit:
            return ILLEGAL_ADDRESS
        with self.lock:
            code = self._check(table, address, count, writing=False)
            if code is not None:
                return code
            return [self.words[(table, address + i)] for i in range(count)]

    def _log_read(self, record: ReadRecord) -> None:
        with self.lock:
            if self.log_reads:
                self.read_log.append(record)
            if self.read_log_file is not None:
                self.read_log_file.write(record.to_json() + "\n")
                self.read_log_file.flush()

    def write(self, function_code: int, address: int, values: Sequence[int]) -> int | None:
        table = FUNCTION_TABLES[function_code]
        if not table.is_bit and len(values) > self.limits.max_write_registers:
            return ILLEGAL_ADDRESS
        record = WriteRecord(
            time.time(), self.unit_id, function_code, table, address, tuple(int(v) for v in values)
        )
        with self.lock:
            code = self._check(table, address, len(values), writing=True)
            if code is not None:
                return code
            for guard in self.write_guards:
                code = guard(record)
                if code is not None:
                    return code
            if self.ignores(record):
                self._log_write(dataclasses.replace(record, ignored=True))
                return None
            self.set_words(table, address, record.values)
            self._log_write(record)
            for hook in self.write_hooks:
                hook(record)
        return None

    def _log_write(self, record: WriteRecord) -> None:
        self.write_log.append(record)
        if self.log_file is not None:
            self.log_file.write(record.to_json() + "\n")
            self.log_file.flush()

    def writes_to(self, address: int, table: Table = Table.HOLDING) -> list[WriteRecord]:
        with self.lock:
            return [
                r
                for r in self.write_log
                if r.table is table and r.address <= address < r.address + len(r.values)
            ]

    def tick(self, dt: float) -> None:
        """Advance behaviour by ``dt`` seconds; device simulators override."""

    """The server could not listen (port in use, serial port missing): a one-line exit."""


def _same_value(a: Value, b: Value) -> bool:
    """Whether ``a`` and ``b`` encode to the same words: same type and equal, and for
    floats the same sign too (-0.0 == 0.0; a NaN is never equal, so it is encoded anew)."""
    if type(a) is not type(b) or a != b:
        return False
    return not isinstance(a, float) or math.copysign(1.0, a) == math.copysign(1.0, b)  # type: ignore[arg-type]
