"""``modbus_doc FILE``: a description's register table (and joints, commands) as Markdown.

Written from the same validated description the node and simulator use, so the table a
reader sees is the map the bridge runs.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from bridge_core.runtime.interface_doc import table
from bridge_core.wire.registers import Access, Register, ValueType
from bridge_core.wire.transport import SerialSettings

from .description import (
    EXIT_BAD_DESCRIPTION,
    Description,
    Device,
    load_for_command,
)
from .description_schema import RtuLinkSpec

ACCESS_TEXT = {Access.READ: "R", Access.READ_WRITE: "RW", Access.WRITE: "W"}  # the file's
REGISTER_COLUMNS = (
    "name",
    "table",
    "address",
    "type",
    "word order",
    "scale",
    "offset",
    "unit",
    "access",
    "poll",
    "range",
    "values",
    "manual",
    "description",
)


def devices_text(count: int) -> str:
    """``1 device``, ``2 devices``."""
    return f"{count} device" + ("" if count == 1 else "s")


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def address_text(register: Register, written: str = "") -> str:
    """The address (or span) in decimal and hex, as manuals print either (``2100H``);
    led by the file's own notation (``written``) where it was not decimal."""
    last = register.end - 1
    decimal = f"{register.address}" if last == register.address else f"{register.address}-{last}"
    hexadecimal = f"0x{register.address:04X}" + (
        f"-0x{last:04X}" if last != register.address else ""
    )
    if written and written.lower() != hexadecimal.split("-")[0].lower():
        return f"{written} ({decimal}, {hexadecimal})"
    if written:
        return f"{hexadecimal} ({decimal})"
    return f"{decimal} ({hexadecimal})"


def register_row(
    register: Register, allowed: Sequence[float] = (), written: str = "", poll: str = ""
) -> list[str]:
    """One table row; ``allowed``: the register's ``values`` (the only writes allowed);
    ``written``: its address as the file wrote it, if not in decimal; ``poll``: its rate
    group (fast, slow, never; none for a write-only register)."""
    kind = register.value_type
    words = register.count
    span = address_text(register, written)
    type_text = f"string[{register.length}]" if kind is ValueType.STRING else kind.label
    multiword = words > 1 and kind is not ValueType.STRING
    limits = ""
    if register.minimum is not None or register.maximum is not None:
        limits = f"{_number(register.minimum or 0)} .. {_number(register.maximum or 0)}"
    return [
        f"`{register.name}`",
        register.table.value,
        span,
        type_text,
        register.word_order.value if multiword else "",
        _number(register.scale) if register.scale != 1.0 else "",
        _number(register.offset) if register.offset != 0.0 else "",
        register.unit,
        ACCESS_TEXT[register.access],
        "" if register.access is Access.WRITE else poll,
        limits,
        ", ".join(_number(value) for value in allowed),
        _cell(register.doc),
        _cell(register.description),
    ]


def _link_line(device: Device) -> list[str]:
    """The device's default link, as its file gives it (none: the line's, or the node's)."""
    if device.link is None:
        return []
    if device.link.tcp is not None:
        tcp = device.link.tcp
        where = f"Modbus TCP {tcp.host}:{tcp.port}, max_in_flight {tcp.max_in_flight}"
    else:
        assert device.link.rtu is not None
        rtu = device.link.rtu
        where = f"Modbus RTU {_line_text(rtu)}" + (
            f", frame gap {rtu.frame_gap_s} s" if rtu.frame_gap_s else ""
        )
    return [f"Link (default): {where}, timeout {device.link.timeout_s} s."]


def _line_text(rtu: RtuLinkSpec) -> str:
    """``/dev/ttyUSB0 19200 8E1``: the port and its format as the bridges' diagnostics say it."""
    settings = SerialSettings(rtu.serial_port, rtu.baudrate, rtu.parity, rtu.stopbits)
    return f"{rtu.serial_port} {settings.line_text()}"


def _limits_line(device: Device) -> str:
    """What the device accepts on the wire (its limits) and the poll rate; the bits per
    read only where the file has coils or discrete inputs."""
    limits = device.register_map.limits
    codes = " ".join(f"{code:02X}" for code in sorted(limits.function_codes))
    has_bits = any(r.table.is_bit for r in device.register_map)
    bits = f", {limits.max_read_bits} bits per read" if has_bits else ""
    return (
        f"Function codes {codes}; at most {limits.max_read_registers} registers per read, "
        f"{limits.max_write_registers} per write{bits}; "
        + (
            "reads may span undefined rows"
            if limits.read_undefined_ok
            else "no read spans an undefined row"
        )
        + (f"; reply delay {limits.reply_delay_s} s" if limits.reply_delay_s else "")
        + f"; poll {_number(device.spec.device.poll_rate_hz)} Hz."
    )


def _joint_lines(device: Device, heading: str) -> list[str]:
    """The joints section: each joint's registers and their factors to SI."""
    if not device.joints:
        return []
    rows = []
    for joint in device.joints:
        cells = [f"`{joint.name}`"]
        for source in (joint.position, joint.velocity, joint.effort):
            cells.append("" if source is None else f"`{source.register}` * {source.to_si:.12g}")
        rows.append(cells)
    return [
        "",
        f"{heading}# Joints (joint_states, SI per REP 103)",
        "",
        *table(("joint", "position", "velocity", "effort"), rows),
    ]


def _command_rows(device: Device) -> list[list[str]]:
    """A row per command the node offers: triggers, values, coils, then topics."""
    commands = device.commands
    rows = []
    for trigger in commands.triggers:
        writes = ", ".join(f"`{w.register_name}` = {w.value}" for w in trigger.writes)
        kind = "Trigger (stop)" if trigger.stop else "Trigger"
        if trigger.starts_motion:
            kind = "Trigger (starts motion: the bridge stops it on exit)"
        rows.append([f"`~/{trigger.name}`", kind, writes, _cell(trigger.description)])
    for value in commands.values:
        rows.append(
            [f"`~/{value.name}`", "SetValue", f"`{value.register_name}`", value.description]
        )
    for coil in commands.coils:
        rows.append([f"`~/{coil.name}`", "SetBool", f"`{coil.register_name}`", coil.description])
    for topic in commands.topics:
        rows.append(
            [
                f"`~/{topic.name}`",
                "Float64 topic",
                f"`{topic.register_name}` = data * {_number(topic.scale)}; deadman "
                f"{topic.timeout_s} s writes {_number(topic.stop_value)}",
                _cell(topic.description),
            ]
        )
    commanded = [
        f"{joint.name}: "
        + ", ".join(
            f"{kind} `{source.register}` = SI / {source.to_si:.12g}"
            for kind, source in (
                ("position", joint.command.position),
                ("velocity", joint.command.velocity),
            )
            if source is not None
        )
        for joint in device.joints
        if joint.command is not None
    ]
    if commanded:
        rows.append(
            [
                "`~/joint_commands`",
                "JointState topic",
                "; ".join(commanded),
                "ros2_control's topic interface (docs/ros2_control.md)",
            ]
        )
    return rows


def _keepalive_lines(device: Device) -> list[str]:
    """The keepalive the node feeds, if the device has one."""
    keepalive = device.keepalive
    if keepalive is None:
        return []
    period = (
        f"{_number(keepalive.period_s)} s"
        if keepalive.period_s is not None
        else f"read from `{keepalive.period_register}`"
    )
    return [
        "",
        f"Keepalive: `{keepalive.register}` ({keepalive.mode}), the device's watchdog "
        f"time {period}, fed three times per period"
        + ("; motion commands wait for it" if device.spec.device.require_keepalive else "")
        + ".",
    ]


def device_markdown(device: Device, heading: str = "##") -> list[str]:
    spec = device.spec.device
    lines = [f"{heading} {spec.name}" + (f": {spec.title}" if spec.title else ""), ""]
    lines.append(f"Manual: {spec.manual}. Unit id {spec.unit_id}.")
    lines += _link_line(device)
    lines.append(_limits_line(device))
    lines += ["", f"{heading}# Registers", ""]
    lines += table(
        REGISTER_COLUMNS,
        [
            register_row(
                r,
                device.allowed_values.get(r.name, ()),
                device.address_texts.get(r.name, ""),
                device.polls.get(r.name, ""),
            )
            for r in device.register_map
        ],
    )
    lines += _joint_lines(device, heading)
    rows = _command_rows(device)
    if rows:
        lines += ["", f"{heading}# Commands", ""]
        lines += table(("name", "kind", "writes", "description"), rows)
    return lines + _keepalive_lines(device)


def markdown(description: Description) -> str:
    lines: list[str] = []
    if description.line is not None and description.line.rtu is not None:
        rtu = description.line.rtu
        lines += [
            f"# {description.path.name}: {devices_text(len(description.devices))} on one RTU line",
            "",
            f"Line: {_line_text(rtu)}, timeout {description.line.timeout_s} s.",
            "",
        ]
    for device in description.devices:
        lines += [*device_markdown(device), ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="print a device description as Markdown")
    parser.add_argument("file", help="device description YAML")
    args = parser.parse_args(argv)
    description = load_for_command(args.file)
    if description is None:
        return EXIT_BAD_DESCRIPTION
    sys.stdout.write(markdown(description))
    return 0


if __name__ == "__main__":
    sys.exit(main())
