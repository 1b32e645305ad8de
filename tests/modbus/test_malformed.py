"""Malformed description files: one line ``FILE:LINE: key: what is wrong`` and exit 2 from
modbus_doc, modbus_sim and modbus_bridge alike, never a traceback.

The cases are in ``malformed_cases.py``. modbus_doc and modbus_sim run in this process
(their ``main``); modbus_bridge runs every case in one child process that calls its
``main`` once per file (rclpy init and shutdown each time), and a few cases run each
command as the user does, as its own process.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from modbus_bridge import doc, sim
from modbus_bridge.description import DescriptionError, load
from tests.support.ros import ROOT, refused_at_start

from .malformed_cases import BASE, CASES, Case

EXIT_BAD_DESCRIPTION = 2
IDS = [case[0] for case in CASES]


def write_case(directory: Path, case: Case) -> Path:
    name, old, new, _line, _words = case
    if isinstance(new, bytes):
        data = new
    elif not old:
        data = new.encode()
    else:
        assert old in BASE, name
        data = BASE.replace(old, new, 1).encode("utf-8", "surrogateescape")
    path = directory / f"{name}.yaml"
    path.write_bytes(data)
    return path


def expect(path: Path, case: Case, line: str) -> None:
    _name, _old, _new, number, words = case
    assert "\n" not in line.strip() and "Traceback" not in line, line
    assert f"{path}:{number}: " in line and words in line, line


def test_there_are_at_least_60_cases() -> None:
    assert len(CASES) >= 60 and len(set(IDS)) == len(IDS)


def test_the_base_file_is_good(tmp_path: Path) -> None:
    path = tmp_path / "base.yaml"
    path.write_text(BASE)
    assert load(path).device.name == "pump"


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_load_names_the_faults_line(tmp_path: Path, case: Case) -> None:
    path = write_case(tmp_path, case)
    with pytest.raises(DescriptionError) as caught:
        load(path)
    expect(path, case, caught.value.lines()[0])
    expect(path, case, str(caught.value))


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_modbus_doc_and_modbus_sim_say_one_line_and_exit_2(
    tmp_path: Path, case: Case, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_case(tmp_path, case)
    for main, args in ((doc.main, [str(path)]), (sim.main, ["--device-file", str(path)])):
        assert main(args) == EXIT_BAD_DESCRIPTION
        captured = capsys.readouterr()
        assert captured.out == ""
        lines = captured.err.splitlines()
        assert len(lines) == 1, captured.err
        expect(path, case, lines[0])


# Runs modbus_bridge's main once per file (argv[1:]) and prints, per file, one JSON line:
# the exit code and what it wrote to stderr.
# A case that takes longer than CASE_STALL_S has hung (one takes ~0.2 s): the runner then
# prints every thread's stack and exits, well before pytest-timeout would end the test with
# nothing but the test process's own stack (once, on an idle machine: 300 s, the child's
# output lost, never seen again in 24 runs of 4 side by side).
CASE_STALL_S = 60
BRIDGE_RUNNER = f"""
import contextlib, faulthandler, io, json, sys
from modbus_bridge.node import main
for path in sys.argv[1:]:
    faulthandler.dump_traceback_later({CASE_STALL_S}, exit=True, file=sys.__stderr__)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["--ros-args", "-p", "device_file:=" + path])
    faulthandler.cancel_dump_traceback_later()
    print(json.dumps({{"path": path, "code": code, "stderr": err.getvalue()}}), flush=True)
"""


def test_modbus_bridge_says_one_line_and_exits_2_for_every_case(tmp_path: Path) -> None:
    paths = [write_case(tmp_path, case) for case in CASES]
    result = subprocess.run(
        [sys.executable, "-c", BRIDGE_RUNNER, *map(str, paths)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, f"runner exit {result.returncode}: {result.stderr[-6000:]}"
    assert "Traceback" not in result.stderr, result.stderr
    runs = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    assert len(runs) == len(CASES), result.stdout + result.stderr
    for case, path, run in zip(CASES, paths, runs, strict=True):
        assert run["path"] == str(path) and run["code"] == EXIT_BAD_DESCRIPTION, run
        lines = run["stderr"].splitlines()
        assert len(lines) == 1, run
        expect(path, case, lines[0])


@pytest.mark.parametrize("name", ["binary_file", "python_tag", "recursive_alias", "unit_id_0_rtu"])
def test_each_command_as_its_own_process(tmp_path: Path, name: str) -> None:
    case = next(case for case in CASES if case[0] == name)
    path = write_case(tmp_path, case)
    expect(path, case, refused_at_start("modbus_bridge.doc", [str(path)]))
    expect(path, case, refused_at_start("modbus_bridge.sim", ["--device-file", str(path)]))
    line = refused_at_start("modbus_bridge.node", ["--ros-args", "-p", f"device_file:={path}"])
    expect(path, case, line)


def test_what_a_user_may_write_is_read_as_yaml_1_2(tmp_path: Path) -> None:
    """Hex addresses, parity words, merge keys; ``yes`` is text, never a boolean."""
    text = (
        BASE.replace("address: 10\n", "address: 0x2100\n")
        .replace(
            "    tcp: {host: 127.0.0.1, port: 1502}\n",
            "    rtu: {serial_port: /dev/ttyUSB0, parity: even, stopbits: 1}\n",
        )
        .replace("    unit: rpm\n", "    unit: rpm\n    description: yes\n")
    )
    path = tmp_path / "vfd.yaml"
    path.write_text(text)
    device = load(path).device
    assert device.register_map["speed"].address == 0x2100
    assert device.link is not None and device.link.rtu is not None
    assert device.link.rtu.parity == "E"
    assert device.register_map["speed"].description == "yes"
    assert device.address_texts == {"speed": "0x2100"}
    for word, letter in (("none", "N"), ("odd", "O"), ("EVEN", "E"), ("n", "N")):
        path.write_text(text.replace("parity: even", f"parity: {word}"))
        link = load(path).device.link
        assert link is not None and link.rtu is not None and link.rtu.parity == letter


def test_a_misspelt_key_is_the_line_the_user_sees(tmp_path: Path) -> None:
    path = tmp_path / "typo.yaml"
    path.write_text(BASE.replace("    address: 10\n", "    adress: 10\n"))
    with pytest.raises(DescriptionError) as caught:
        load(path)
    # the typo alone: the "missing address" it causes is the same mistake
    assert str(caught.value) == (
        f"{path}:12: registers[0].adress: unknown key: did you mean `address`? (allowed: "
        "name, table, address, type, manual, length, word_order, scale, offset, unit, "
        "access, range, values, poll, description)"
    )


def test_ros_parity_parameter_read_as_a_boolean_gets_the_quote_hint(tmp_path: Path) -> None:
    """ROS reads ``-p parity:=N`` as YAML: N is false. The refusal says how to quote it."""
    path = tmp_path / "rtu.yaml"
    path.write_text(
        BASE.replace(
            "    tcp: {host: 127.0.0.1, port: 1502}\n",
            f"    rtu: {{serial_port: {tmp_path / 'no_such_port'}}}\n",
        )
    )
    line = refused_at_start(
        "modbus_bridge.node",
        ["--ros-args", "-p", f"device_file:={path}", "-p", "parity:=N", "-p", "autostart:=false"],
    )
    assert "parameter parity" in line and "boolean false" in line
    assert "-p \"parity:='N'\"" in line
