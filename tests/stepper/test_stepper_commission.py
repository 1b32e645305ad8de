"""``bridge_commission stepper`` against the stepper simulator on a pty (docs/commissioning.md).

The tool runs in-process (``bridge_core.ros.commission.main``, its operator's lines fed by
``Script``, as in tests/r6/test_r6_commission.py) against one in-process simulator served
on a socat pty pair, shared by the module (each test resets what it changed). Against the
default simulator every read-only check is confirmed and the three guided steps pass
(each with the other steps' personalities on); against each personality that plays the
other reading of a decision (docs/tools.md, "Device personalities") exactly that check is
contradicted and its parameter recommended (the guided ones in one run).
Nothing is written without ``yes`` (the write log stays empty), and every way out of a
running step sends its stop (in the write log after the step's start).
"""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from bridge_core.ros.command_line import EXIT_CONFIGURATION_ERROR
from bridge_core.ros.commission import EXIT_INTERRUPTED, main
from bridge_core.runtime.commission import Probe, Verdict
from bridge_core.runtime.commission_run import FIRST_LINE, run_step
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings
from stepper_bridge import commission_guided, commission_steps
from stepper_bridge.commission import CHECKS
from stepper_bridge.registers import (
    MOTORS,
    SYSTEM_COILS,
    coil,
    motor_coil,
    motor_register,
    reply_timeout_floor_s,
)
from stepper_bridge.sim import StepperSimDevice, make_simulator

from ..support.commission import Script, answers, verdicts
from ..support.ros import ROOT
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty

READ_CHECKS = ("word_order", "reply_rule", "undefined_rows")
GUIDED = ("pair_reading", "zero_at_home", "stop_and_start")
SAMPLES = 10  # the tool's least: reply times are not the point here
BAUD = 115200  # the simulator's end of the pty (a pty keeps no baud rate)
# The bridge's baudrate parameter: the reply floor the check uses (0.07 s), far above a
# pty's replies (a few ms), and a line the link times quickly.
LINE_BAUD = 38400
FLOOR_S = reply_timeout_floor_s(SerialSettings("", LINE_BAUD))
LEAD = 50.0  # every motor: 60 rpm moves 50 units/s, so each guided step takes ~0.2 s
SLOW_LEAD = 5.0  # motor 1 in the stop test: the pair-2 line at 30 rpm takes ~1.8 s
SLOW_REPLY_S = 0.1  # above that floor
CUE_UNITS = 2.0  # the Ctrl-C test: motor 1 this far on (40 ms at 50 units/s) when it signals
POLL_RATE_HZ = 20.0  # the guided steps follow their motions at this rate
WAIT_S = 30.0  # a bound, not a measure


@dataclass
class Rig:
    sim: Simulator
    fake: StepperSimDevice
    port: str

    def reset(self) -> None:
        """The simulator as the default test expects it: every motor stands 1 unit off its
        home switch at coordinate 0, fast, obeying, with the bridge's readings."""
        fake = self.fake
        self.sim.ignore(())
        self.sim.set_reply_delay(0.0)
        with fake.lock:
            fake.pair_reading = "type_rows"
            fake.zero_at_home = True
            fake.answer_undefined = False
            fake.high_word_first = False
            fake.set("baud_rate", LINE_BAUD)  # the rate the tool is told the line runs at
            fake.interpolation = None
            for m in range(1, MOTORS + 1):
                fake.motion[m] = None
                fake.position[m] = fake.offset[m] = 1.0
                fake.set(motor_register(m, "lead"), LEAD)
            fake.write_log.clear()


@pytest.fixture(scope="module")
def shared_rig() -> Iterator[Rig]:
    sim = make_simulator(reply_delay_s=0.0)
    fake = sim.device
    assert isinstance(fake, StepperSimDevice)
    with served_on_pty(sim, BAUD) as port:
        yield Rig(sim, fake, port)


@pytest.fixture
def rig(shared_rig: Rig) -> Iterator[Rig]:
    shared_rig.reset()
    yield shared_rig
    shared_rig.reset()


def run(rig: Rig, tmp_path: Path, script: Script, *options: str) -> tuple[int, dict[str, Any]]:
    argv = [
        "stepper",
        "--samples",
        str(SAMPLES),
        "--report",
        str(tmp_path / "stepper.md"),
        "--json",
        str(tmp_path / "stepper.json"),
        "--params",
        str(tmp_path / "stepper.yaml"),
        *options,
        "--ros-args",
        "--params-file",
        str(ROOT / "config" / "stepper.yaml"),
        "-p",
        f"serial_port:={rig.port}",
        "-p",
        f"baudrate:={LINE_BAUD}",
        "-p",
        f"poll_rate_hz:={POLL_RATE_HZ}",
        # A stalled pty on a loaded machine must not lose a reply (a step would end
        # "could not tell"; seen in a full run at config/stepper.yaml's 0.5 s).
        "-p",
        f"timeout_s:={PTY_REPLY_TIMEOUT_S}",
    ]
    try:
        code = main(argv, read_line=script.read_line, say=script.say)
    finally:
        script.close()
    return code, json.loads((tmp_path / "stepper.json").read_text())


def coils(fake: StepperSimDevice) -> list[int]:
    return [r.address for r in fake.write_log if r.table is Table.COIL and r.values[0]]


def stop_after(fake: StepperSimDevice, start: int, stop: int) -> bool:
    """The step's start coil went out, and the stop coil after it."""
    sent = coils(fake)
    return start in sent and stop in sent[sent.index(start) :]


FORWARD_1, STOP_1, HOME_1 = (motor_coil(1, action) for action in ("forward", "stop", "home"))
LINE_START, LINE_STOP = (coil(SYSTEM_COILS[name]) for name in ("line_start", "line_stop"))


def header(key: str) -> str:
    """How the tool's lines about a check begin: "[N] title" (N its place in the rows;
    then " (decision ...)" before a guided step, ": verdict" after a check)."""
    number = [check.key for check in CHECKS].index(key) + 1
    return f"[{number}] {CHECKS[number - 1].title}"


def others_on(rig: Rig, step: str) -> None:
    """The guided personalities of every step but ``step`` (a step's own reading stays
    the default's)."""
    fake = rig.fake
    fake.pair_reading = "type_rows" if step == "pair_reading" else "point_rows"
    fake.zero_at_home = step == "zero_at_home"
    rig.sim.ignore(() if step == "stop_and_start" else ("stop",))


def test_the_default_simulator_confirms_every_check(rig: Rig, tmp_path: Path) -> None:
    """Read-only checks first (said in the first line) against the default simulator,
    then the three steps after ``yes``, each judged by what the controller reads back,
    and each run with the OTHER steps' personalities on (the next test turns each on for
    its own step): a personality flips its own step only. The params file is the
    bridge's, with the readings the steps showed."""
    script = answers("yes", "yes", "yes")

    def personalities_of_the_others(line: str) -> None:
        for key in GUIDED:
            if line.startswith(f"{header(key)} ("):
                others_on(rig, key)

    script.on_say = personalities_of_the_others
    code, report = run(rig, tmp_path, script)
    assert code == 0
    assert script.said[0] == FIRST_LINE
    assert report["facts"]["baud rate (40213)"] == str(LINE_BAUD)
    found = verdicts(report)
    assert all(found[key] == "confirmed" for key in (*READ_CHECKS, *GUIDED)), report["checks"]
    assert found["unit_ids"] == found["shared_line_stop"] == "not run"
    recommended = report["recommended_parameters"]
    assert recommended["interpolation_pair_reading"] == "type_rows"
    assert recommended["zero_after_home"] is False
    assert recommended["timeout_s"] >= FLOOR_S  # never below the floor
    assert stop_after(rig.fake, FORWARD_1, STOP_1)
    params = (tmp_path / "stepper.yaml").read_text()
    assert "/**/stepper_bridge:\n  ros__parameters:" in params
    assert f'serial_port: "{rig.port}"' in params and "zero_after_home: false" in params


@pytest.mark.parametrize("key", READ_CHECKS)
def test_a_read_only_personality_contradicts_its_check_only_and_nothing_is_written(
    rig: Rig, tmp_path: Path, key: str
) -> None:
    """32-bit values high word first, replies later than the floor (during that check
    only: the rest stays fast) or undefined rows that answer: that check is contradicted,
    the others confirmed, the timeout recommended from the late replies only; answers
    other than 'yes' and a closed input leave every step not run and the write log
    empty."""
    if key == "word_order":
        rig.fake.high_word_first = True
        script = answers("", "yes please", "NO")
    elif key == "undefined_rows":
        rig.fake.answer_undefined = True
        script = answers("no", "n", None)
    else:
        script = answers(None)

        def slow_during_the_check(line: str) -> None:
            if line.startswith("rows read:"):
                rig.sim.set_reply_delay(SLOW_REPLY_S)
            elif line.startswith(f"{header(key)}:"):  # its verdict: the next checks fast
                rig.sim.set_reply_delay(0.0)

        script.on_say = slow_during_the_check
    code, report = run(rig, tmp_path, script)
    assert code == 0
    found = verdicts(report)
    assert found[key] == "contradicted", report["checks"]
    assert all(found[other] == "confirmed" for other in READ_CHECKS if other != key), found
    assert all(found[step] == "not run" for step in GUIDED), found
    timeout = report["recommended_parameters"]["timeout_s"]
    assert (timeout >= 3 * SLOW_REPLY_S) is (key == "reply_rule"), timeout
    assert rig.fake.write_log == []


def test_the_other_readings_of_the_guided_steps_are_contradicted(rig: Rig, tmp_path: Path) -> None:
    """Pairs by the point rows (decision 19), homing that keeps the coordinate (20) and a
    stop coil the controller ignores (23), in one run (each step reads only its own
    reading; the default test shows each confirmed without them): each step contradicted
    with the other reading's parameter, the read-only checks still confirmed. The
    ignored stop's own send is in the write log after the forward coil."""
    fake = rig.fake
    fake.pair_reading = "point_rows"
    fake.zero_at_home = False
    rig.sim.ignore({"stop"})
    code, report = run(rig, tmp_path, answers("yes", "yes", "yes"))
    assert code == 0
    found = verdicts(report)
    assert all(found[key] == "contradicted" for key in GUIDED), report["checks"]
    assert all(found[key] == "confirmed" for key in READ_CHECKS), found
    recommended = report["recommended_parameters"]
    assert recommended["interpolation_pair_reading"] == "point_rows"
    assert recommended["zero_after_home"] is True
    assert stop_after(fake, FORWARD_1, STOP_1)


def test_a_stop_key_or_closed_input_stops_the_running_step(rig: Rig, tmp_path: Path) -> None:
    """Enter while the line runs: the interpolation stops go out at once and the line
    ends short (could not tell); 'no' skips the homing with nothing written; the end of
    the input while motor 1 runs forward: its stop coil at once. The motors stand."""
    fake = rig.fake
    fake.set(motor_register(1, "lead"), SLOW_LEAD)  # a line of ~1.8 s, a stop cuts short
    script = Script(
        ("prompt", "yes"),
        (lambda: fake.interpolation is not None, ""),
        ("prompt", "no"),
        ("prompt", "yes"),
        (lambda: fake.motion[1] is not None, None),
    )
    code, report = run(rig, tmp_path, script)
    assert code == 0
    found = verdicts(report)
    assert found["pair_reading"] == found["stop_and_start"] == "could not tell", found
    assert found["zero_at_home"] == "not run", found
    assert stop_after(fake, LINE_START, LINE_STOP)
    assert stop_after(fake, FORWARD_1, STOP_1)
    assert HOME_1 not in coils(fake)
    assert fake.interpolation is None and fake.motion[1] is None


def test_ctrl_c_stops_the_running_step_and_writes_the_report(rig: Rig, tmp_path: Path) -> None:
    """SIGINT (as a terminal sends it) while motor 1 runs forward: its stop coil goes out,
    the run ends (exit 130) with the report written, the step not run."""
    fake = rig.fake
    assert threading.current_thread() is threading.main_thread()

    def cue() -> bool:
        # Motor 1 a little way on: its start's read-back is over and the step waits (a
        # signal then lands in the wait, not in the middle of a transaction).
        if fake.motion[1] is None or fake.coordinate(1) < CUE_UNITS:
            return False
        signal.raise_signal(signal.SIGINT)  # the tool's handler (main thread only) raises
        return True

    script = Script(("prompt", "no"), ("prompt", "no"), ("prompt", "yes"), (cue, None))
    code, report = run(rig, tmp_path, script)
    assert code == EXIT_INTERRUPTED
    assert report["interrupted"]
    assert verdicts(report)["stop_and_start"] == "not run"
    assert coils(fake) == [FORWARD_1, STOP_1]
    assert fake.motion[1] is None


def test_a_motor_without_a_home_input_is_refused_before_it_moves(rig: Rig) -> None:
    """The homing step checks both goals before its first write (the bridge's own check:
    homing without a home input runs until a stop): refused, nothing run; only the
    step's stop goes out, as on every way out of a step. The step called directly, on
    the tool's own channel (no read phase: only this step is the point)."""
    fake = rig.fake
    fake.set(motor_register(1, "home_input"), 0)
    link = ModbusLink(SerialSettings(rig.port, LINE_BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
    try:
        probe = Probe(DeviceChannel(link, 1, retries=0), {"poll_rate_hz": POLL_RATE_HZ})
        commission_steps.setup(probe)
        finding = run_step(commission_guided.zero_at_home, commission_guided.stop_motor_1, probe)
    finally:
        link.close()
        fake.set(motor_register(1, "home_input"), 2)
    assert finding.verdict is Verdict.NOT_RUN, finding
    assert finding.seen.startswith("refused, nothing written: motor 1 has no home input")
    assert coils(fake) == [STOP_1]


def test_a_bad_parameter_is_one_line_as_the_bridge_says_it(
    rig: Rig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        ["stepper", "--ros-args", "-p", f"serial_port:={rig.port}", "-p", "timeout_s:=99.0"],
        read_line=lambda: None,
    )
    err = capsys.readouterr().err
    assert code == EXIT_CONFIGURATION_ERROR
    assert err.startswith("error: stepper_bridge: parameter timeout_s: "), err
    assert err.count("\n") == 1, err
    assert rig.fake.write_log == []
    assert not (tmp_path / "commission-stepper.json").exists()
