"""``modbus_scan``: a description skeleton from a device nobody described, by reading it.

Read-only (FC 03, 04, 01, 02 and nothing else; its first line says so), bounded (address
ranges per table, the largest block per request, a total request budget) and paced (a
pause between requests). It reads through the wire layer's ``DeviceChannel`` on a
``ModbusLink``, as the bridges do, over TCP or RTU; ``scan_probe`` decides what to read
(blocks, split where refused), ``scan_yaml`` writes the skeleton ``modbus_bridge`` loads
and the summary. A device that stops answering ends the scan with one line (exit 1),
a bad option is one line (exit 2). docs/bridges/modbus.md, "modbus_scan".
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import NoReturn

from bridge_core.wire.channel import UNIT_ID_MAX, DeviceChannel
from bridge_core.wire.registers import MAX_ADDRESS, MAX_READ_BITS, MAX_READ_REGISTERS, Table
from bridge_core.wire.requests import BROADCAST_UNIT
from bridge_core.wire.transport import LinkSettings, ModbusLink, SerialSettings, TcpSettings

from .description_schema import NAME_PATTERN, STANDARD_BAUDRATES, TIMEOUT_RANGE_S
from .scan_probe import BudgetSpent, DeviceStopped, Prober, TableScan, scan_table
from .scan_yaml import TABLE_ORDER, ScanSetup, scanned_tables, skeleton, summary

PROGRAM = "modbus_scan"
READ_ONLY_LINE = (
    f"{PROGRAM}: read-only: it sends reads (FC 03, 04, 01, 02) and never writes to the device"
)
# The addresses of each table read when no --range is given.
DEFAULT_RANGE = (0, 999)
# Requests in all, and the pause after each reply before the next request (a device, or a
# line shared with a running machine, is not flooded: 20 requests per second at most).
DEFAULT_BUDGET = 2000
BUDGET_MAX = 1_000_000
DEFAULT_PAUSE_MS = 50.0
PAUSE_MAX_MS = 10_000.0
DEFAULT_TIMEOUT_S = 0.5
DEFAULT_TCP_PORT = 502
DEFAULT_NAME = "scanned_device"
EXIT_STOPPED = 1
EXIT_BAD_OPTION = 2
RANGE_PATTERN = re.compile(r"^(\d+)(?:-(\d+))?$")


class _Parser(argparse.ArgumentParser):
    """A bad option is one line and exit 2 (no usage block)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_OPTION, f"{PROGRAM}: error: {message}\n")


def _parse_range(text: str) -> tuple[Table, tuple[tuple[int, int], ...]]:
    """``holding:0-99,200-299`` -> the table and its (first, last) ranges."""
    tables = {table.value: table for table in Table}
    name, sep, spans = text.partition(":")
    if not sep or name not in tables:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give TABLE:FIRST-LAST[,FIRST-LAST...], TABLE one of {', '.join(tables)}"
        )
    ranges = []
    for span in spans.split(","):
        match = RANGE_PATTERN.match(span.strip())
        if match is None:
            raise argparse.ArgumentTypeError(f"{text!r}: {span!r} is not FIRST-LAST (decimal)")
        first = int(match.group(1))
        last = int(match.group(2) or first)
        if not first <= last <= MAX_ADDRESS:
            raise argparse.ArgumentTypeError(
                f"{text!r}: {span!r}: need FIRST <= LAST <= {MAX_ADDRESS}"
            )
        ranges.append((first, last))
    return tables[name], tuple(sorted(ranges))


def _bounded(
    kind: type[int] | type[float], low: float, high: float, what: str
) -> Callable[[str], int | float]:
    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text}: outside {low:g} .. {high:g}")
        return value

    return parse


def _name(text: str) -> str:
    if re.match(NAME_PATTERN, text) is None or len(text) > 64:
        raise argparse.ArgumentTypeError(f"{text!r}: a letter, then letters, digits or _")
    return text


def parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog=PROGRAM,
        description="read a Modbus device's tables (never writing) and write a description "
        "skeleton for modbus_bridge",
    )
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--host", help="Modbus TCP: the device's address")
    where.add_argument("--serial", help="Modbus RTU: the serial port (or pty) path")
    p.add_argument("--port", type=_bounded(int, 1, 65535, "a port"), default=DEFAULT_TCP_PORT)
    p.add_argument("--baudrate", type=int, choices=STANDARD_BAUDRATES, default=9600)
    p.add_argument("--parity", choices=("N", "E", "O"), default="N")
    p.add_argument("--stopbits", type=int, choices=(1, 2), default=1)
    p.add_argument("--unit-id", type=_bounded(int, 0, UNIT_ID_MAX, "a unit id"), default=1)
    p.add_argument(
        "--range",
        dest="ranges",
        action="append",
        type=_parse_range,
        metavar="TABLE:FIRST-LAST[,...]",
        help="addresses (0-based, as on the wire) to read; repeat per table: only the "
        f"tables named are read (default: holding, input, coil, discrete_input "
        f"{DEFAULT_RANGE[0]}-{DEFAULT_RANGE[1]})",
    )
    p.add_argument(
        "--max-registers",
        type=_bounded(int, 1, MAX_READ_REGISTERS, "a count"),
        default=MAX_READ_REGISTERS,
        help=f"registers per read at most (default and protocol limit {MAX_READ_REGISTERS})",
    )
    p.add_argument(
        "--max-bits",
        type=_bounded(int, 1, MAX_READ_BITS, "a count"),
        default=MAX_READ_BITS,
        help=f"coils / inputs per read at most (default and protocol limit {MAX_READ_BITS})",
    )
    p.add_argument(
        "--pause-ms",
        type=_bounded(float, 0.0, PAUSE_MAX_MS, "a number"),
        default=DEFAULT_PAUSE_MS,
        help=f"pause after each reply before the next request (default {DEFAULT_PAUSE_MS:g})",
    )
    p.add_argument(
        "--budget",
        type=_bounded(int, 1, BUDGET_MAX, "a count"),
        default=DEFAULT_BUDGET,
        help=f"requests in all; the scan ends there (default {DEFAULT_BUDGET})",
    )
    p.add_argument(
        "--timeout-s",
        type=_bounded(float, *TIMEOUT_RANGE_S, "a number"),
        default=DEFAULT_TIMEOUT_S,
        help=f"reply timeout per request (default {DEFAULT_TIMEOUT_S})",
    )
    p.add_argument("--name", type=_name, default=DEFAULT_NAME, help="the device's name")
    p.add_argument("-o", "--output", type=Path, required=True, help="the skeleton YAML to write")
    return p


def _setup(args: argparse.Namespace) -> tuple[LinkSettings, ScanSetup]:
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    settings: LinkSettings
    if args.host is not None:
        settings = TcpSettings(args.host, args.port, timeout_s=args.timeout_s)
        # Quoted as JSON strings (valid YAML): an IPv6 host or a path may hold ':' or '#'.
        link_yaml = f"tcp: {{host: {json.dumps(args.host)}, port: {args.port}}}"
    else:
        settings = SerialSettings(
            args.serial,
            baudrate=args.baudrate,
            parity=args.parity,
            stopbits=args.stopbits,
            timeout_s=args.timeout_s,
        )
        link_yaml = (
            f"rtu: {{serial_port: {json.dumps(args.serial)}, baudrate: {args.baudrate}, "
            f"parity: {args.parity}, stopbits: {args.stopbits}}}"
        )
    described = settings.describe()
    setup = ScanSetup(args.name, args.unit_id, link_yaml, described, args.timeout_s, when)
    return settings, setup


def _problem(args: argparse.Namespace) -> str | None:
    """What the parser cannot say alone."""
    if args.serial is not None and args.unit_id == BROADCAST_UNIT:
        return "--unit-id 0 is the broadcast on a serial line: no device answers it"
    if not args.output.parent.is_dir():
        return f"--output {args.output}: no directory {args.output.parent}"
    tables = [table for table, _ in args.ranges or ()]
    if len(tables) != len(set(tables)):
        return "--range: one per table (list several ranges after one colon)"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    problem = _problem(args)
    if problem is not None:
        print(f"{PROGRAM}: error: {problem}", file=sys.stderr)
        return EXIT_BAD_OPTION
    print(READ_ONLY_LINE, flush=True)
    given = dict(args.ranges or ())
    scans = [
        TableScan(table, given.get(table, (DEFAULT_RANGE,)))
        for table in TABLE_ORDER
        if not given or table in given
    ]
    settings, setup = _setup(args)
    print(
        f"scanning {setup.link_text} unit {args.unit_id}: {scanned_tables(scans)}; at most "
        f"{args.max_registers} registers / {args.max_bits} bits a read, a {args.pause_ms:g} ms "
        f"pause, {args.budget} requests, timeout {args.timeout_s} s",
        flush=True,
    )
    link = ModbusLink(settings)
    prober = Prober(DeviceChannel(link, args.unit_id, retries=0), args.budget, args.pause_ms / 1e3)
    started = time.monotonic()
    spent = ""
    try:
        for scan in scans:
            block = args.max_bits if scan.table.is_bit else args.max_registers
            scan_table(prober, scan, block)
    except BudgetSpent as err:
        spent = str(err)
        for unread in scans[scans.index(scan) + 1 :]:
            unread.scanned_to = unread.ranges[0][0]
    except DeviceStopped as err:
        print(
            f"{PROGRAM}: error: {setup.link_text} unit {args.unit_id}: {err} "
            f"(after {prober.requests} requests; nothing written to {args.output})",
            file=sys.stderr,
        )
        return EXIT_STOPPED
    finally:
        link.close()
    elapsed = time.monotonic() - started
    for line in summary(scans):
        print(line)
    if not any(scan.found() for scan in scans):
        print(
            f"{PROGRAM}: no address answered in {prober.requests} requests: nothing to "
            f"describe, nothing written to {args.output}",
            file=sys.stderr,
        )
        return EXIT_STOPPED
    args.output.write_text(skeleton(setup, scans, prober.requests), encoding="utf-8")
    if spent:
        print(
            f"{PROGRAM}: the request budget ({args.budget}) ran out at {spent}: the file "
            "holds what was read before it"
        )
    print(f"wrote {args.output} ({prober.requests} requests in {elapsed:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
