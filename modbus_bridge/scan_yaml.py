"""What ``modbus_scan`` writes: a description skeleton and a summary of the blocks found.

The skeleton is a description file as ``modbus_bridge`` loads it (description_schema.py):
one read-only row per address that answered, named by table and 0-based wire address
(``holding_12`` is the manual's 40013), raw types (``u16`` for a register, ``bool`` for a
bit; ``u32`` / ``u64`` for a value that answered only whole), the link it was scanned
over, and the exceptions seen as YAML comments. It knows no names, word order, scale or
unit: the user takes them from the manual (docs/bridges/modbus.md, "modbus_scan").
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from bridge_core.wire.errors import EXCEPTION_NAMES
from bridge_core.wire.registers import Table

from .scan_probe import NO_REPLY, TableScan, contiguous, span_text

# The type of a row per registers it takes: a plain register, a value that answered whole.
ROW_TYPES = {1: "u16", 2: "u32", 4: "u64"}
ROW_MANUAL = "not in a manual yet: found by modbus_scan (FC {fc:02d} answered)"
LARGEST_NOTE = "the largest read that answered: the manual may allow more"
DEVICE_MANUAL = "none yet: scanned by modbus_scan; take each row from the device's manual"


@dataclass(frozen=True)
class ScanSetup:
    """How the device was reached and scanned (the skeleton's ``device`` and header)."""

    name: str
    unit_id: int
    link_yaml: str  # the ``link:`` mapping's body, one line: ``tcp: {host: ..., port: ...}``
    link_text: str  # as the summary names it: ``tcp://127.0.0.1:502``
    timeout_s: float
    when: str  # ISO time of the scan


def code_text(code: int) -> str:
    """``ILLEGAL DATA ADDRESS (0x02)``, or ``no reply``."""
    if code == NO_REPLY:
        return "no reply"
    return f"{EXCEPTION_NAMES.get(code, 'EXCEPTION')} (0x{code:02X})"


def refusal_runs(scan: TableScan) -> list[tuple[int, int, int]]:
    """Refused addresses as runs of one code: (first, count, code)."""
    runs: list[tuple[int, int, int]] = []
    for address in sorted(scan.refused):
        code = scan.refused[address]
        if runs and runs[-1][0] + runs[-1][1] == address and runs[-1][2] == code:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1, code)
        else:
            runs.append((address, 1, code))
    return runs


def _ranges_text(scan: TableScan) -> str:
    return ", ".join(span_text(first, last - first + 1) for first, last in scan.ranges)


def _status_lines(scan: TableScan) -> list[str]:
    """What the table's scan says beside its blocks: not served, incomplete, refusals."""
    name, fc = scan.table.value, scan.function_code
    lines = [f"{name} (FC {fc:02d}), scanned {_ranges_text(scan)}"]
    if scan.not_served:
        return [lines[0] + f": {code_text(0x01)}: the device does not serve this table"]
    if scan.scanned_to is not None:
        lines.append(f"  incomplete: the request budget ran out at {name} {scan.scanned_to}")
    for first, count, code in refusal_runs(scan):
        lines.append(f"  {name} {span_text(first, count)}: {code_text(code)}")
    for (first, count), code in sorted(scan.parts.items()):
        lines.append(
            f"  {name} {span_text(first, count)} as one read: {code_text(code)} "
            "(the device takes this block in parts)"
        )
    return lines


def _rows(scan: TableScan) -> list[str]:
    table, fc = scan.table, scan.function_code
    manual = json.dumps(ROW_MANUAL.format(fc=fc))
    lines: list[str] = []
    for first, count in contiguous(scan.found()):
        unit = "bits" if table.is_bit else "registers"
        lines.append(f"  # {table.value} {span_text(first, count)}: {count} {unit} answered")
        address = first
        while address < first + count:
            width = scan.whole_values.get(address, 1)
            kind = "bool" if table.is_bit else ROW_TYPES[width]
            row = (
                f"{{name: {table.value}_{address}, table: {table.value}, address: {address}, "
                f"type: {kind}, access: R, manual: {manual}}}"
            )
            whole = f"  # answered only whole ({width} registers)" if width > 1 else ""
            lines.append(f"  - {row}{whole}")
            address += width
    return lines


def function_codes(scans: Sequence[TableScan]) -> list[int]:
    """The read function codes of the tables where something answered."""
    return sorted({scan.function_code for scan in scans if scan.found()})


def skeleton(setup: ScanSetup, scans: Sequence[TableScan], requests: int) -> str:
    """The description skeleton (YAML text); call it only when something answered."""
    registers = [s for s in scans if not s.table.is_bit and s.found()]
    bits = [s for s in scans if s.table.is_bit and s.found()]
    header = [
        f"# Written by modbus_scan on {setup.when}: unit {setup.unit_id} at "
        f"{setup.link_text}, {requests} read requests (FC 01/02/03/04 only: it never writes).",
        "# A skeleton: every row is a raw, read-only value named by its table and 0-based",
        "# wire address (holding_12 is the manual's 40013). The scan cannot know what a",
        "# value means, its word order, scale, offset or unit, nor which registers form one",
        "# 32-bit value: name the rows, set type, word_order, scale, unit, access and manual",
        "# from the device's manual, and drop what you do not need",
        "# (docs/bridges/modbus.md, 'modbus_scan').",
        "#",
        "# What each table answered besides the rows below:",
    ]
    for scan in scans:
        header += [f"#   {line}" for line in _status_lines(scan)]
    device = [
        "device:",
        f"  name: {setup.name}",
        f"  title: {json.dumps(f'scanned by modbus_scan on {setup.when}')}",
        f"  manual: {json.dumps(DEVICE_MANUAL)}",
        "  link:",
        f"    {setup.link_yaml}",
        f"    timeout_s: {setup.timeout_s}",
        f"  unit_id: {setup.unit_id}",
        f"  function_codes: {function_codes(scans)}",
    ]
    if registers:
        largest = max(s.largest_read for s in registers)
        device.append(f"  max_read_registers: {largest}  # {LARGEST_NOTE}")
    if bits:
        largest = max(s.largest_read for s in bits)
        device.append(f"  max_read_bits: {largest}  # {LARGEST_NOTE}")
    rows = ["registers:"]
    for scan in scans:
        rows += _rows(scan)
    return "\n".join([*header, *device, "", *rows, ""])


def summary(scans: Sequence[TableScan]) -> list[str]:
    """The blocks found, as a table, and each table's refusals counted by code."""
    lines = [f"{'table':<15} {'FC':>2} {'first':>6} {'last':>6} {'count':>6}  whole values"]
    for scan in scans:
        for first, count in contiguous(scan.found()):
            widths = Counter(
                ROW_TYPES[width]
                for address, width in scan.whole_values.items()
                if first <= address < first + count
            )
            whole = ", ".join(f"{n} {kind}" for kind, n in sorted(widths.items()))
            lines.append(
                f"{scan.table.value:<15} {scan.function_code:02d} {first:>6} "
                f"{first + count - 1:>6} {count:>6}  {whole}".rstrip()
            )
    for scan in scans:
        if scan.not_served:
            lines.append(f"{scan.table.value}: {code_text(0x01)}: not served")
            continue
        seen = ", ".join(f"{code_text(c)} x{n}" for c, n in sorted(scan.codes.items()))
        if seen:
            lines.append(f"{scan.table.value}: refusals seen: {seen}")
    return lines


def scanned_tables(scans: Sequence[TableScan]) -> str:
    """``holding 0-999, coil 0-99`` (the scan's first lines)."""
    return ", ".join(f"{s.table.value} {_ranges_text(s)}" for s in scans)


TABLE_ORDER = (Table.HOLDING, Table.INPUT, Table.COIL, Table.DISCRETE_INPUT)
