"""``bridge_commission motec`` against the MOTEC simulator on a pty pair (docs/commissioning.md).

The tool runs in-process (``bridge_core.ros.commission.main``, the operator's lines fed by
``Script``) against an in-process simulator of two drives on one bus; it commissions the
first of ``unit_ids``. Against the default drive every read-only check is confirmed and
the guided steps pass; against each personality that plays the other reading of a
decision (docs/tools.md, "Device personalities") exactly that check is contradicted, or
its recommendation changes. Nothing is written without ``yes`` (the write log stays
empty), and every way out of a running move sends its stop (0x29 = 0 in the write log
after the move's 0x29 = 1; the motor stands).
"""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge_core.ros.command_line import EXIT_CONFIGURATION_ERROR
from bridge_core.ros.commission import EXIT_INTERRUPTED, main
from bridge_core.runtime.commission_run import FIRST_LINE
from motec_bridge.commission_guided import LIFEGUARD_TEST_MS
from motec_bridge.commission_steps import lifeguard_floor_ms
from motec_bridge.registers import FAULT_PRESENT, MOTEC_MAP
from motec_bridge.sim import MotecSimDrive, MotecSimulator, make_simulator

from ..support.commission import Script, answers, verdicts
from ..support.ros import ROOT
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty

READ_CHECKS = ("word_order", "unnamed_rows", "lifeguard_settings", "table_end")
GUIDED = (  # in the order they are asked
    "position_stop",
    "setpoint_in_a_move",
    "standstill",
    "new_target",
    "lifeguard_off",
    "fault_halves",
)
NO = ("no",) * len(GUIDED)
SAMPLES = 10  # reply times: enough to exercise the statistics
WAIT_S = 30.0  # a bound, not a measure
START = MOTEC_MAP["start"].address
LIFEGUARD_TIME = MOTEC_MAP["lifeguard_time"].address
LIFEGUARD_MODE = MOTEC_MAP["lifeguard_mode"].address
TURNED_BY_HAND = 123_456  # counts: the word order needs a nonzero position
UNITS = (1, 2)


@pytest.fixture
def bus(tmp_path: Path) -> Iterator[tuple[MotecSimulator, MotecSimDrive, str]]:
    simulator = make_simulator(UNITS)
    drive = simulator.drive(UNITS[0])
    drive.set_position(TURNED_BY_HAND)
    with served_on_pty(simulator, 115200) as bridge_end:
        yield simulator, drive, bridge_end


def run(end: str, tmp_path: Path, script: Script, *options: str) -> tuple[int, dict[str, Any]]:
    argv = [
        "motec",
        "--samples",
        str(SAMPLES),
        "--report",
        str(tmp_path / "motec.md"),
        "--json",
        str(tmp_path / "motec.json"),
        "--params",
        str(tmp_path / "motec.yaml"),
        *options,
        "--ros-args",
        "--params-file",
        str(ROOT / "config" / "motec.yaml"),
        "-p",
        f"serial_port:={end}",
        "-p",
        f"unit_ids:={list(UNITS)}",
        "-p",
        f"timeout_s:={PTY_REPLY_TIMEOUT_S}",  # a pty may stall: not what this tests
    ]
    try:
        code = main(argv, read_line=script.read_line, say=script.say)
    finally:
        script.close()
    return code, json.loads((tmp_path / "motec.json").read_text())


def writes(drive: MotecSimDrive, address: int) -> list[int]:
    """The values written to one register, in order."""
    return [r.values[0] for r in drive.write_log if r.address == address]


def stopped_after_start(drive: MotecSimDrive) -> bool:
    """A move's 0x29 = 1 went out, and 0x29 = 0 after it."""
    started = writes(drive, START)
    return 1 in started and 0 in started[started.index(1) :]


def test_the_default_drive_confirms_every_check(
    bus: tuple[MotecSimulator, MotecSimDrive, str], tmp_path: Path
) -> None:
    """Read-only checks first (said in the first line), then the six steps after
    ``yes``, each judged by what the drive reads back; each step's stop is in the write
    log (0x29 = 0 after each move's start, 0x112 = 0 after each lifeguard arming); the
    params file reaches every node (``/**/*``) and recommends lifeguard_ms."""
    _, drive, end = bus
    script = answers(*("yes",) * len(GUIDED))
    code, report = run(end, tmp_path, script)
    assert code == 0
    assert script.said[0] == FIRST_LINE
    found = verdicts(report)
    assert all(found[key] == "confirmed" for key in (*READ_CHECKS, *GUIDED)), report["checks"]
    assert found["move_time_limit"] == "not run"  # a manual check
    assert writes(drive, START).count(0) >= 4 and stopped_after_start(drive)
    # lifeguard_off: armed, disarmed, its stop; fault_halves: armed, its stop
    assert writes(drive, LIFEGUARD_TIME) == [LIFEGUARD_TEST_MS, 0, 0, LIFEGUARD_TEST_MS, 0]
    assert writes(drive, LIFEGUARD_MODE)[-1] == 0
    assert drive.fault == FAULT_PRESENT << 16 and not drive.enabled  # tripped, released
    assert report["reply_times"]["count"] == SAMPLES
    values = {"unit_ids": list(UNITS), "timeout_s": PTY_REPLY_TIMEOUT_S, "baudrate": 115200}
    assert report["recommended_parameters"]["lifeguard_ms"] == lifeguard_floor_ms(values)
    params = (tmp_path / "motec.yaml").read_text()
    assert "/**/*:\n  ros__parameters:" in params and f"serial_port: {json.dumps(end)}" in params
    assert "unit_id" not in params  # the bridge's bus node would refuse it
    assert "unit id: 1" in (tmp_path / "motec.md").read_text()


PERSONALITIES = [
    # (drive attribute, value, the check that flips, the operator's answers)
    ("low_word_first", True, "word_order", NO),
    ("unnamed_refused", True, "unnamed_rows", ("n", "", "yes please", "nope", "NO", "y")),
    ("answer_past_table", True, "table_end", (None,)),
]


@pytest.mark.parametrize(
    ("attribute", "value", "key", "said"), PERSONALITIES, ids=[p[2] for p in PERSONALITIES]
)
def test_a_personality_contradicts_its_check_only_and_nothing_is_written_without_yes(
    bus: tuple[MotecSimulator, MotecSimDrive, str],
    tmp_path: Path,
    attribute: str,
    value: bool,
    key: str,
    said: tuple[str | None, ...],
) -> None:
    """The other reading of one decision: that check is contradicted, the others stay
    confirmed; answers other than ``yes`` (and stdin closed) leave every step not run
    and the write log empty."""
    _, drive, end = bus
    setattr(drive, attribute, value)
    code, report = run(end, tmp_path, answers(*said))
    assert code == 0
    found = verdicts(report)
    assert found[key] == "contradicted", report["checks"]
    assert all(found[other] == "confirmed" for other in READ_CHECKS if other != key), found
    assert all(found[step] == "not run" for step in GUIDED), found
    assert drive.write_log == []


def test_a_drive_armed_too_short_for_the_bus_gets_the_floor_recommended(
    bus: tuple[MotecSimulator, MotecSimDrive, str], tmp_path: Path
) -> None:
    """Decision 9: a drive armed by its own setting (flash) with a time the bus cannot
    keep fed: contradicted, lifeguard_ms the floor; one armed long enough keeps its time."""
    _, drive, end = bus
    drive.power_up_armed(100)
    code, report = run(end, tmp_path, answers(None), "--read-only")
    floor = report["recommended_parameters"]["lifeguard_ms"]
    assert code == 0 and verdicts(report)["lifeguard_settings"] == "contradicted"
    assert floor > 100
    drive.power_up_armed(floor + 500)
    code, report = run(end, tmp_path, answers(None), "--read-only")
    assert verdicts(report)["lifeguard_settings"] == "confirmed"
    assert report["recommended_parameters"]["lifeguard_ms"] == floor + 500
    assert drive.write_log == []


def test_the_other_readings_of_the_guided_steps_are_contradicted(
    bus: tuple[MotecSimulator, MotecSimDrive, str], tmp_path: Path
) -> None:
    """0x29 = 0 taken as no stop (decision 18), a servo dithering at rest (17: the
    tolerance recommended), the fault flag in 0xC9 (7); then 0xAA holding a move's target
    (22), a new target ignored while a move runs (21) and a lifeguard that watches on
    after the disarm (9): each step contradicted, the read-only checks confirmed."""
    simulator, drive, end = bus
    drive.start_is_trigger = True
    drive.rest_dither_counts = 20
    drive.lifeguard_fault_code = FAULT_PRESENT
    code, report = run(end, tmp_path, answers("yes", "no", "yes", "no", "no", "yes"))
    found = verdicts(report)
    assert code == 0
    for key in ("position_stop", "standstill", "fault_halves"):
        assert found[key] == "contradicted", report["checks"]
    assert report["recommended_parameters"]["goal_tolerance_counts"] == 40
    assert all(found[key] == "confirmed" for key in READ_CHECKS), found
    assert not drive.enabled and drive.speed == 0.0  # released by the verified stop
    simulator.power_cycle(UNITS[0])
    drive.start_is_trigger = False
    drive.rest_dither_counts = 0
    drive.setpoint_holds_target = True
    drive.lifeguard_keeps_watching = True
    drive.ignores_new_target = True
    said = answers("no", "yes", "no", "yes", "yes", "no")
    code, report = run(end, tmp_path, said, "--unit-id", "1")
    found = verdicts(report)
    for key in ("setpoint_in_a_move", "new_target", "lifeguard_off"):
        assert found[key] == "contradicted", report["checks"]
    assert found["position_stop"] == found["fault_halves"] == "not run"
    assert drive.fault != 0  # it tripped after the disarm


@pytest.mark.parametrize("stop", ["", None, "ctrl-c"], ids=["enter", "stdin-closed", "ctrl-c"])
def test_a_stop_key_closed_input_or_ctrl_c_stops_the_running_move(
    bus: tuple[MotecSimulator, MotecSimDrive, str], tmp_path: Path, stop: str | None
) -> None:
    """Enter, the end of the input, or Ctrl-C while the move runs: 0x29 = 0 goes out at
    once and the drive is released again; the step could not tell (Ctrl-C: not run, the
    run ends with exit 130 and the report written); the next step is not run."""
    _, drive, end = bus
    if stop == "ctrl-c":
        # SIGINT, as a terminal sends it: the tool's handler (main thread only) raises
        # KeyboardInterrupt in the running step.
        assert threading.current_thread() is threading.main_thread()

        def cue() -> bool:
            if drive.speed == 0.0:
                return False
            signal.raise_signal(signal.SIGINT)
            return True

        script = Script(("prompt", "yes"), (cue, None))
    else:
        moving = (lambda: drive.speed != 0.0, stop)
        script = Script(("prompt", "yes"), moving, *(("prompt", "no"),) * (len(GUIDED) - 1))
    code, report = run(end, tmp_path, script)
    assert code == (EXIT_INTERRUPTED if stop == "ctrl-c" else 0)
    found = verdicts(report)
    assert found["position_stop"] == ("not run" if stop == "ctrl-c" else "could not tell"), found
    assert found["setpoint_in_a_move"] == "not run"
    assert bool(report["interrupted"]) is (stop == "ctrl-c")
    assert stopped_after_start(drive)
    assert drive.speed == 0.0 and not drive.enabled


@pytest.mark.parametrize(
    ("given", "said"),
    [
        ("timeout_s:=99.0", "error: motec_bridge: parameter timeout_s: "),
        ("lifeguard_ms:=-5", "error: motec_bridge: parameter lifeguard_ms: "),
    ],
    ids=["bus-parameter", "drive-parameter"],
)
def test_a_bad_parameter_is_one_line_as_the_bridge_says_it(
    bus: tuple[MotecSimulator, MotecSimDrive, str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    given: str,
    said: str,
) -> None:
    _, drive, end = bus
    code = main(
        ["motec", "--ros-args", "-p", f"serial_port:={end}", "-p", given], read_line=lambda: None
    )
    err = capsys.readouterr().err
    assert code == EXIT_CONFIGURATION_ERROR
    assert err.startswith(said) and err.count("\n") == 1, err
    assert drive.write_log == []
    assert not (tmp_path / "commission-motec.json").exists()
