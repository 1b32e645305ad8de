"""``bridge_commission r6`` against the R6 simulator (docs/commissioning.md).

The tool runs in-process (``bridge_core.ros.commission.main``, its operator's lines fed
by ``Script``) against an in-process simulator on a free port. Against the default
simulator every read-only check is confirmed and both guided steps pass; against each
personality that plays the other reading of a decision (docs/tools.md, "Device
personalities") exactly that check is contradicted, or its recommendation changes.
Nothing is written without ``yes`` (the write log stays empty), and every way out of a
running step sends its pause (20001, in the write log after the step's start). Ctrl-C
and SIGTERM are raised in this process, where the tool's handlers take them as they
would in its own.
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
from bridge_core.sim.serving import Simulator
from r6_bridge.registers import COMMANDS
from r6_bridge.sim import R6SimDevice, make_simulator

from ..support.commission import Script, answers, verdicts
from ..support.ros import ROOT
from .test_r6_sim import timed_program

READ_CHECKS = ("word_order", "counts", "undefined_rows", "m_boards")
GUIDED = ("cycle_time_2401", "stop_shows_in_2470")
SAMPLES = 20  # reply times: enough to exercise the statistics
PROGRAM = timed_program(0.15, 0.0)  # two steps: a cycle of about 0.3 s at 100 %
WAIT_S = 30.0  # a bound, not a measure
PAUSE = COMMANDS["pause"]


@pytest.fixture
def sim() -> Iterator[tuple[Simulator, R6SimDevice, int]]:
    simulator = make_simulator(axis_count=6, io_board_count=1)
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    device.program = PROGRAM
    device.set("global_speed", 100.0)
    port = simulator.start_tcp()
    yield simulator, device, port
    simulator.stop()


def run(port: int, tmp_path: Path, script: Script, *options: str) -> tuple[int, dict[str, Any]]:
    argv = [
        "r6",
        "--samples",
        str(SAMPLES),
        "--report",
        str(tmp_path / "r6.md"),
        "--json",
        str(tmp_path / "r6.json"),
        "--params",
        str(tmp_path / "r6.yaml"),
        *options,
        "--ros-args",
        "--params-file",
        str(ROOT / "config" / "r6.yaml"),
        "-p",
        f"port:={port}",
    ]
    try:
        code = main(argv, read_line=script.read_line, say=script.say)
    finally:
        script.close()
    return code, json.loads((tmp_path / "r6.json").read_text())


def stop_after_start(device: R6SimDevice, start: str) -> bool:
    """The step's start went out, and a pause after it."""
    addresses = [r.address for r in device.write_log]
    return COMMANDS[start] in addresses and PAUSE in addresses[addresses.index(COMMANDS[start]) :]


def test_the_default_simulator_confirms_every_check(
    sim: tuple[Simulator, R6SimDevice, int], tmp_path: Path
) -> None:
    """Read-only checks first (said in the first line), then both steps after ``yes``,
    each judged by what the controller reads back; the params file is the bridge's."""
    _, device, port = sim
    script = answers("yes", "yes")
    code, report = run(port, tmp_path, script)
    assert code == 0
    assert script.said[0] == FIRST_LINE
    found = verdicts(report)
    seen = {check["key"]: check["seen"] for check in report["checks"]}
    assert all(found[key] == "confirmed" for key in (*READ_CHECKS, *GUIDED)), {
        key: (found[key], seen[key]) for key in (*READ_CHECKS, *GUIDED)
    }
    assert found["waiting_step"] == "not run"
    assert report["recommended_parameters"]["m_boards"] is True
    assert report["reply_times"]["count"] == SAMPLES
    assert stop_after_start(device, "single_cycle") and stop_after_start(device, "start")
    assert all("then the stop: wrote 20001 = 1 (pause)" in seen[key] for key in GUIDED), seen
    params = (tmp_path / "r6.yaml").read_text()
    assert params.startswith("# Recommended") and "/**/r6_bridge:\n  ros__parameters:" in params
    assert f"port: {port}" in params and "timeout_s: " in params
    assert "**confirmed**" in (tmp_path / "r6.md").read_text()


PERSONALITIES = [
    # (device attribute, value, the check that flips, the operator's answers)
    ("low_word_first", True, "word_order", ("no", "no")),
    ("answer_past_counts", True, "counts", ("n", "")),
    ("answer_undefined", True, "undefined_rows", (None,)),
    ("m_boards_offered", False, "m_boards", ("yes please", "NO")),
]


@pytest.mark.parametrize(
    ("attribute", "value", "key", "said"), PERSONALITIES, ids=[p[2] for p in PERSONALITIES]
)
def test_a_personality_contradicts_its_check_only_and_nothing_is_written_without_yes(
    sim: tuple[Simulator, R6SimDevice, int],
    tmp_path: Path,
    attribute: str,
    value: bool,
    key: str,
    said: tuple[str | None, ...],
) -> None:
    """The other reading of one decision: that check is contradicted (the M boards: the
    recommendation turns to false), the others stay confirmed; answers other than ``yes``
    (and stdin closed) leave both steps not run and the write log empty."""
    _, device, port = sim
    setattr(device, attribute, value)
    code, report = run(port, tmp_path, answers(*said))
    assert code == 0
    found = verdicts(report)
    flipped = "confirmed" if key == "m_boards" else "contradicted"
    assert found[key] == flipped, found
    assert all(found[other] == "confirmed" for other in READ_CHECKS if other != key), found
    assert all(found[step] == "not run" for step in GUIDED), found
    assert report["recommended_parameters"]["m_boards"] is (key != "m_boards")
    assert device.write_log == []


def test_the_other_readings_of_the_guided_steps_are_contradicted(
    sim: tuple[Simulator, R6SimDevice, int], tmp_path: Path
) -> None:
    """2401 written at a cycle's start (decision 23) and a pause the controller ignores
    (decision 29): both steps contradicted, the read-only checks still confirmed."""
    simulator, device, port = sim
    device.set_cycle_time_at("start")
    simulator.ignore({"pause"})
    code, report = run(port, tmp_path, answers("yes", "yes"))
    assert code == 0
    found = verdicts(report)
    assert found["cycle_time_2401"] == "contradicted", found
    assert found["stop_shows_in_2470"] == "contradicted", found
    assert all(found[key] == "confirmed" for key in READ_CHECKS), found


STOPS = {"enter": "", "stdin-closed": None, "ctrl-c": signal.SIGINT, "sigterm": signal.SIGTERM}


@pytest.mark.parametrize("how", list(STOPS))
def test_a_stop_key_closed_input_or_a_signal_stops_the_running_step(
    sim: tuple[Simulator, R6SimDevice, int], tmp_path: Path, how: str
) -> None:
    """Enter, the end of the input, Ctrl-C or SIGTERM while the cycle runs: pause goes
    out at once and the step could not tell; after the end of the input or a signal the
    next step is not run, and a signal ends the run (exit 130) with the report written."""
    _, device, port = sim
    device.program = timed_program(5.0, 0.0)  # a cycle the stop must cut short
    stop = STOPS[how]
    if isinstance(stop, signal.Signals):
        # The signal as a terminal or a service manager sends it, to this process: the
        # tool's handler (main thread only) raises KeyboardInterrupt in the running step.
        assert threading.current_thread() is threading.main_thread()

        def cue() -> bool:
            if not device.running:
                return False
            signal.raise_signal(stop)
            return True

        script = Script(("prompt", "yes"), (cue, None))
    else:
        script = Script(("prompt", "yes"), (lambda: device.running, stop), ("prompt", "no"))
    code, report = run(port, tmp_path, script)
    signalled = isinstance(stop, signal.Signals)
    assert code == (EXIT_INTERRUPTED if signalled else 0)
    found = verdicts(report)
    assert found["cycle_time_2401"] == ("not run" if signalled else "could not tell"), found
    assert found["stop_shows_in_2470"] == "not run"
    assert bool(report["interrupted"]) is signalled
    assert stop_after_start(device, "single_cycle")
    assert not device.running


@pytest.mark.parametrize(
    ("given", "said"),
    [
        ("timeout_s:=99.0", "error: r6_bridge: parameter timeout_s: "),
        ("tiemout_s:=0.2", "error: parameter tiemout_s:=0.2 is not one of this process's"),
    ],
    ids=["out-of-range", "unknown"],
)
def test_a_bad_parameter_is_one_line_as_the_bridge_says_it(
    sim: tuple[Simulator, R6SimDevice, int],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    given: str,
    said: str,
) -> None:
    _, device, port = sim
    code = main(["r6", "--ros-args", "-p", f"port:={port}", "-p", given], read_line=lambda: None)
    err = capsys.readouterr().err
    assert code == EXIT_CONFIGURATION_ERROR
    assert err.startswith(said) and err.count("\n") == 1, err
    assert device.write_log == []
    assert not (tmp_path / "commission-r6.json").exists()


def test_a_step_the_bridge_refuses_starts_nothing(
    sim: tuple[Simulator, R6SimDevice, int], tmp_path: Path
) -> None:
    """The controller in manual mode: both steps are refused by the bridge's own checks
    (R6 decision 23) after ``yes``, not run; no start goes out, only their stops."""
    _, device, port = sim
    device.set("mode", 1)
    code, report = run(port, tmp_path, answers("yes", "yes"))
    assert code == 0
    checks = {check["key"]: check for check in report["checks"]}
    for key in GUIDED:
        assert checks[key]["verdict"] == "not run", checks[key]
        assert "manual mode" in checks[key]["seen"]
    assert {r.address for r in device.write_log} == {PAUSE}
