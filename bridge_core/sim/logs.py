"""The simulators' logs: accepted writes and (off by default) read requests, as JSON
lines a test or a user reads back (``--write-log`` / ``--read-log``)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Protocol

from ..wire.registers import Table


class LoggingDevice(Protocol):
    """A simulated unit's log files (``sim_base.SimulatedDevice``)."""

    log_file: IO[str] | None
    read_log_file: IO[str] | None


class LoggedSimulator(Protocol):
    """A simulator's units (``serving.Simulator``), named here so sim_base and serving
    import this module and never the other way round."""

    @property
    def devices(self) -> Mapping[int, LoggingDevice]: ...


class _JsonRecord:
    """A log record as one JSON line (``table`` by name, tuples as lists)."""

    def to_json(self) -> str:
        data = dataclasses.asdict(self)  # type: ignore[call-overload]
        data["table"] = data["table"].value
        return json.dumps({k: list(v) if isinstance(v, tuple) else v for k, v in data.items()})

    @classmethod
    def from_json(cls, line: str) -> Any:
        data = json.loads(line)
        data["table"] = Table(data["table"])
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def _read_lines(path: Path) -> list[str]:
    """The complete lines of a log file (the simulator may be writing the next one)."""
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.splitlines() if text.endswith("\n") else text.splitlines()[:-1]
    return [line for line in lines if line]


@dataclass(frozen=True)
class WriteRecord(_JsonRecord):
    """One accepted write, as the device saw it (``ignored``: acknowledged and changed
    nothing, a device playing ``--ignore``)."""

    time: float
    unit_id: int
    function_code: int
    table: Table
    address: int
    values: tuple[int, ...]
    ignored: bool = False


def read_write_log(path: Path) -> list[WriteRecord]:
    return [WriteRecord.from_json(line) for line in _read_lines(path)]


@dataclass(frozen=True)
class ReadRecord(_JsonRecord):
    """One read request as the device handled it (``time``: wall clock when its values
    were taken), refused ones included; tests order a node's stamps against these."""

    time: float
    unit_id: int
    function_code: int
    table: Table
    address: int
    count: int

    def covers(self, table: Table, address: int) -> bool:
        return self.table is table and self.address <= address < self.address + self.count


def read_read_log(path: Path) -> list[ReadRecord]:
    """The records of a ``--read-log`` file."""
    return [ReadRecord.from_json(line) for line in _read_lines(path)]


def add_log_arguments(parser: argparse.ArgumentParser) -> None:
    """The simulators' log options: accepted writes, and (off by default) read requests."""
    parser.add_argument("--write-log", type=Path, help="append every accepted write (JSON lines)")
    parser.add_argument(
        "--read-log",
        type=Path,
        help="append every read request with the time it was handled (JSON lines)",
    )


def open_logs(args: argparse.Namespace, sim: LoggedSimulator) -> list[IO[str]]:
    """Attach ``--write-log`` / ``--read-log`` files to every unit; the files to close."""
    write_log = args.write_log.open("a") if args.write_log else None
    read_log = args.read_log.open("a") if args.read_log else None
    for device in sim.devices.values():
        device.log_file = write_log
        device.read_log_file = read_log
    return [f for f in (write_log, read_log) if f is not None]
