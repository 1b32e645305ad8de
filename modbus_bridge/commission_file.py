"""The file behind ``bridge_commission modbus``: the description ``device_file`` names,
the node it makes (``node_of``: its parameters and their defaults, as modbus_bridge
declares them), the commissioning of that file (``bind``: its rows and its ping), and
the bridge's ``DescribedDevice`` on the tool's channel (``setup``, reads only). Shared by
commission_steps.py (read-only checks) and commission_guided.py. No ROS here.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bridge_core.runtime.commission import Commissioning, Probe
from bridge_core.runtime.interface import NodeInterface
from bridge_core.wire.channel import Priority, RegisterIO
from bridge_core.wire.errors import ConfigurationError
from bridge_core.wire.planner import ReadRequest
from bridge_core.wire.registers import Register, RegisterMap, Table

from .description import Device, load
from .device import DescribedDevice, poll_plan
from .doc import devices_text
from .interface import described_nodes

DEVICE_FILE = "device_file"  # the parameter that names the description
LISTED_MAX = 8  # rows named in one finding; the rest counted


@dataclass
class Target:
    """``probe.device`` of the modbus checks: the file, its device, and the bridge's
    ``DescribedDevice`` on the tool's channel."""

    file: str
    device: Device
    described: DescribedDevice


def target(probe: Probe) -> Target:
    found = probe.device
    assert isinstance(found, Target), "setup() runs first"
    return found


# ---------------------------------------------------------------- the file
def description_of(values: Mapping[str, Any]) -> Device:
    """The device of the file ``device_file`` names; ``ConfigurationError`` (one line) as
    the bridge says it, and for a file of several devices on a line (modbus_bus's)."""
    path = str(values.get(DEVICE_FILE, ""))
    if not path:
        raise ConfigurationError("no device description: give -p device_file:=FILE")
    if not Path(path).is_file():
        raise ConfigurationError(f"parameter device_file:={path}: no such file")
    description = load(path)
    if description.line is not None:
        raise ConfigurationError(
            f"{path} describes {devices_text(len(description.devices))} on one line: "
            "bridge_commission modbus takes a file of one device (modbus_bridge's)"
        )
    return description.device


def node_of(values: Mapping[str, Any]) -> NodeInterface:
    """The node ``modbus_bridge`` runs for the file (its parameters and their defaults)."""
    description_of(values)  # the same one-line refusals as the bridge
    return described_nodes(str(values[DEVICE_FILE]))[0]


def _first_readable(register_map: RegisterMap) -> Register:
    readable = [r for r in register_map if r.access.readable]
    if not readable:
        raise ConfigurationError(f"{register_map.device}: no readable register to check")
    return min(readable, key=lambda r: (r.count, r.table.value, r.address))


def ping_row(register: Register, io: RegisterIO) -> object:
    """One short read, timed for the reply times: the file's shortest readable row."""
    if register.table.is_bit:
        return io.read_bits(register.address, 1, register.table, Priority.COMMAND)
    return io.read_registers(register.address, register.count, register.table, Priority.COMMAND)


def bind(commissioning: Commissioning, values: Mapping[str, Any]) -> Commissioning:
    """The commissioning of the file ``device_file`` names: its rows and its ping."""
    register_map = description_of(values).register_map
    ping = functools.partial(ping_row, _first_readable(register_map))
    return dataclasses.replace(commissioning, register_map=register_map, ping=ping)


def ping_placeholder(_io: RegisterIO) -> object:
    raise AssertionError("bind() gives the file's ping")


def setup(probe: Probe) -> None:
    """The file's facts for the report (reads only: the described device is built, not
    polled)."""
    device = description_of(probe.values)
    probe.device = Target(str(probe.values[DEVICE_FILE]), device, DescribedDevice(probe.io, device))
    fast, slow, _ = poll_plan(device)
    keepalive = device.keepalive
    if keepalive is not None:
        period = (
            f"{keepalive.period_s:g} s"
            if keepalive.period_s is not None
            else f"from {keepalive.period_register}"
        )
        fed = f"{keepalive.register} ({keepalive.mode}), watchdog time {period}"
    elif device.frame_watchdog_s is not None:
        fed = f"any frame, watchdog time {device.frame_watchdog_s:g} s"
    else:
        fed = "none"
    probe.facts.update(
        {
            "description": str(probe.values[DEVICE_FILE]),
            "device": device.spec.device.title or device.name,
            "registers": str(len(device.register_map.registers)),
            "joints": ", ".join(j.name for j in device.joints) or "none",
            "poll plan": f"{len(fast)} requests, slow group {len(slow)}",
            "keepalive": fed,
        }
    )


def requests_per_poll(probe: Probe) -> int:
    """The requests of one poll without the slow group (decision 17)."""
    return len(poll_plan(target(probe).device)[0])


def refusal_reason(_reg: Register, _probe: Probe) -> str | None:
    """Every row of a file is one the device serves (the file says so): none expected."""
    return None


def listed(names: Sequence[str]) -> str:
    shown = ", ".join(names[:LISTED_MAX])
    return shown + (f" and {len(names) - LISTED_MAX} more" if len(names) > LISTED_MAX else "")


def span(request: ReadRequest) -> str:
    return f"{request.table.value} {request.address}+{request.count}"


def read_rows(io: RegisterIO, table: Table, address: int, count: int) -> list[int]:
    if table.is_bit:
        return [int(b) for b in io.read_bits(address, count, table, Priority.COMMAND)]
    return io.read_registers(address, count, table, Priority.COMMAND)


def poll_time(io: RegisterIO, plan: Sequence[ReadRequest]) -> float:
    started = time.perf_counter()
    for request in plan:
        read_rows(io, request.table, request.address, request.count)
    return time.perf_counter() - started
