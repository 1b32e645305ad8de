"""modbus_doc: the register table of a description as Markdown."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bridge_core.wire.transport import SerialSettings
from modbus_bridge.description import load
from modbus_bridge.doc import REGISTER_COLUMNS, main, markdown

ROOT = Path(__file__).resolve().parents[2]
XARM = ROOT / "config" / "devices" / "xarm.yaml"
MULTIDROP = ROOT / "config" / "devices" / "rtu_multidrop.yaml"


def table_rows(text: str, first_cell: str) -> dict[str, list[str]]:
    """Rows of the Markdown tables whose first cell is a `name`, by name."""
    rows: dict[str, list[str]] = {}
    for line in text.splitlines():
        if line.startswith("| `") and first_cell in line:
            cells = [cell.strip() for cell in line.strip("|").split(" | ")]
            rows[cells[0].strip("`")] = cells
    return rows


def test_every_register_is_a_row_with_its_fields() -> None:
    description = load(XARM)
    text = markdown(description)
    rows = table_rows(text, "")
    for register in description.device.register_map:
        cells = dict(zip(REGISTER_COLUMNS, rows[register.name], strict=True))
        first = f"{register.address}"
        assert cells["address"].split(" ")[0].split("-")[0] == first
        assert f"0x{register.address:04X}" in cells["address"]
        assert cells["table"] == register.table.value
        assert cells["type"] == register.value_type.label
        assert cells["scale"] == ("" if register.scale == 1 else str(int(register.scale)))
        assert cells["unit"] == register.unit
        assert cells["manual"] == register.doc
    assert rows["controller_ao_0"][REGISTER_COLUMNS.index("access")] == "RW"
    assert rows["controller_ao_0"][REGISTER_COLUMNS.index("range")] == "0 .. 10"
    assert rows["controller_ao_0"][REGISTER_COLUMNS.index("values")] == ""
    assert rows["arm_state"][REGISTER_COLUMNS.index("values")] == "0, 3, 4"
    assert rows["counter"][REGISTER_COLUMNS.index("word order")] == "high_first"
    assert rows["counter"][REGISTER_COLUMNS.index("address")] == "34-35 (0x0022-0x0023)"
    # Joints and commands follow the registers.
    assert "| `joint1` | `joint_angle_1` * 0.0174532925199 |" in text
    assert "| `~/stop` | Trigger (stop) | `arm_state` = 4 |" in text
    assert "| `~/set_digital_output_15` | SetBool | `controller_do_15` |" in text


def test_multidrop_file_has_a_section_per_device(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(MULTIDROP)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# rtu_multidrop.yaml: 2 devices on one RTU line")
    assert "## drive_1" in out and "## drive_2" in out
    assert "Line: /dev/ttyUSB0 115200 8N1" in out
    assert out.count("| `cmd_speed`") == 0 and out.count("| `~/cmd_speed` | Float64 topic") == 2


def test_console_script_and_a_bad_file(tmp_path: Path) -> None:
    good = subprocess.run(
        [sys.executable, "-m", "modbus_bridge.doc", str(XARM)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert good.returncode == 0 and "| `joint_angle_7` | input | 95 (0x005F) |" in good.stdout
    bad = tmp_path / "bad.yaml"
    bad.write_text(XARM.read_text().replace("type: i16, scale: 10", "type: i17, scale: 10", 1))
    refused = subprocess.run(
        [sys.executable, "-m", "modbus_bridge.doc", str(bad)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert refused.returncode == 2 and refused.stdout == ""
    (line,) = refused.stderr.splitlines()
    assert line.startswith(f"error: {bad}:") and ".type: Input should be" in line


def test_addresses_in_decimal_and_hex_led_by_the_files_notation(tmp_path: Path) -> None:
    """Manuals print hex (``2100H``); the file may write ``0x2100`` and the table shows
    that first, then decimal; a decimal address gets its hex beside it."""
    path = tmp_path / "vfd.yaml"
    path.write_text(
        "device: {name: vfd, manual: m, link: {tcp: {}}}\n"
        "registers:\n"
        "  - {name: command, table: holding, address: 0x2000, type: u16, access: RW, manual: m}\n"
        "  - {name: frequency, table: holding, address: 0x2101, type: u32, manual: m}\n"
        "  - {name: status, table: holding, address: 8448, type: u16, manual: m}\n"
        "  - {name: fault, table: holding, address: 0o20420, type: u16, manual: m}\n"
    )
    rows = table_rows(markdown(load(path)), "")
    column = REGISTER_COLUMNS.index("address")
    assert rows["command"][column] == "0x2000 (8192)"
    assert rows["frequency"][column] == "0x2101-0x2102 (8449-8450)"
    assert rows["status"][column] == "8448 (0x2100)"
    assert rows["fault"][column] == "0o20420 (8464, 0x2110)"


def test_poll_groups_in_flight_bits_and_the_line_as_manuals_print_it(tmp_path: Path) -> None:
    """Each register's rate group, a TCP link's ``max_in_flight``, the
    bits per read only where the file has bit tables, ``19200 8E1`` (not ``192008E1``)
    and ``1 device``."""
    tcp = tmp_path / "tcp.yaml"
    tcp.write_text(
        "device: {name: meter, manual: m, poll: slow, link: {tcp: {max_in_flight: 4}}}\n"
        "registers:\n"
        "  - {name: power, table: input, address: 0, type: u16, poll: fast, manual: m}\n"
        "  - {name: energy, table: input, address: 1, type: u16, manual: m}\n"
        "  - {name: serial, table: input, address: 2, type: u16, poll: never, manual: m}\n"
        "  - {name: reset, table: holding, address: 9, type: u16, access: W, manual: m}\n"
    )
    text = markdown(load(tcp))
    rows = table_rows(text, "")
    column = REGISTER_COLUMNS.index("poll")
    polls = {name: rows[name][column] for name in ("power", "energy", "serial", "reset")}
    assert polls == {"power": "fast", "energy": "slow", "serial": "never", "reset": ""}
    assert "Modbus TCP 127.0.0.1:502, max_in_flight 4," in text
    assert "bits per read" not in text
    with_coil = tmp_path / "coil.yaml"
    with_coil.write_text(
        tcp.read_text() + "  - {name: relay, table: coil, address: 0, type: bool, manual: m}\n"
    )
    assert "2000 bits per read" in markdown(load(with_coil))

    line = tmp_path / "line.yaml"
    line.write_text(
        "line: {rtu: {serial_port: /dev/ttyUSB1, baudrate: 19200, parity: E}, timeout_s: 0.2}\n"
        "devices:\n"
        "  - device: {name: vfd, manual: m, unit_id: 1}\n"
        "    registers:\n"
        "      - {name: status, table: holding, address: 0, type: u16, manual: m}\n"
    )
    out = markdown(load(line))
    assert out.startswith("# line.yaml: 1 device on one RTU line")
    assert "Line: /dev/ttyUSB1 19200 8E1, timeout 0.2 s." in out


def test_a_serial_link_is_described_with_a_space_before_its_format() -> None:
    """The diagnostics' hardware_id and every log line name a serial link this way."""
    settings = SerialSettings("/dev/ttyUSB0", baudrate=19200, parity="E")
    assert settings.describe() == "/dev/ttyUSB0@19200 8E1"
