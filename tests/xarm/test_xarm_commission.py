"""``bridge_commission xarm`` against the xArm simulator (docs/commissioning.md).

The tool runs in-process (``bridge_core.ros.commission.main``, its operator's lines fed
by ``Script``) against an in-process simulator on a free port, its arm off its origin (a
negative joint, two of roll/pitch/yaw off 0, a counter that has counted). Against it
every read-only check is confirmed and the guided steps pass (the start in error runs
only on an arm in error); against each personality that plays the other reading of a
decision (docs/tools.md, "Device personalities") exactly that check is contradicted (the
joint count: recommended as the arm's). Nothing is written without ``yes`` (the write
log stays empty), and every way out of a running step sends the bridge's stop (C145 and
H33 = 4, in the write log after the step's first write).
"""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from bridge_core.ros.command_line import EXIT_CONFIGURATION_ERROR
from bridge_core.ros.commission import EXIT_INTERRUPTED, main
from bridge_core.sim.serving import Simulator
from bridge_core.wire.registers import Table
from xarm_bridge import commission_guided
from xarm_bridge.registers import (
    COIL_REDUCED_MODE,
    COIL_STOPPED,
    OFFLINE_TASK_ADDRESS,
    XARM_MAP,
)
from xarm_bridge.sim import IN_MOTION, STOPPED, XArmSimDevice, make_simulator

from ..support.commission import Script, answers, verdicts
from ..support.ros import ROOT

READ_CHECKS = ("signed_values", "counter_word_order", "joints", "reserved_rows", "rotation_vector")
GUIDED = ("stop", "pause", "start_in_error", "safety_modes")
SAMPLES = 10  # reply times: the fewest the tool takes
WAIT_S = 30.0  # a bound, not a measure
SHORT_RUN_S = 0.1  # the guided steps' project runs this long (short_steps)
STATE = XARM_MAP["arm_state"].address
Rig = tuple[Simulator, XArmSimDevice, int]


def off_origin(device: XArmSimDevice) -> None:
    """An arm as a real one stands: J1 -20, J2 -15 (TCP y -30 mm), J4 40 (pitch 10)."""
    for joint, angle in ((1, -20.0), (2, -15.0), (4, 40.0)):
        device.set(f"joint_angle_{joint}", angle)
    device.set("counter", 1234)
    device.tick(0.0)  # the pose from the joints


@contextmanager
def rig(joints: int = 7) -> Iterator[Rig]:
    simulator = make_simulator(joints)
    device = simulator.device
    assert isinstance(device, XArmSimDevice)
    off_origin(device)
    port = simulator.start_tcp()
    try:
        yield simulator, device, port
    finally:
        simulator.stop()


@pytest.fixture(autouse=True)
def short_steps(monkeypatch: pytest.MonkeyPatch) -> None:
    """The guided steps' project runs 0.1 s before its stop or pause, a pause is held
    0.05 s (the steps' logic unchanged; the stop-key tests lengthen the run instead)."""
    monkeypatch.setattr(commission_guided, "RUN_BEFORE_HALT_S", SHORT_RUN_S)
    monkeypatch.setattr(commission_guided, "PAUSED_S", SHORT_RUN_S / 2)


@pytest.fixture
def sim() -> Iterator[Rig]:
    with rig() as found:
        yield found


def run(port: int, tmp_path: Path, script: Script) -> tuple[int, dict[str, Any]]:
    argv = [
        "xarm",
        "--samples",
        str(SAMPLES),
        "--report",
        str(tmp_path / "xarm.md"),
        "--json",
        str(tmp_path / "xarm.json"),
        "--params",
        str(tmp_path / "xarm.yaml"),
        "--ros-args",
        "--params-file",
        str(ROOT / "config" / "xarm.yaml"),
        "-p",
        f"port:={port}",
    ]
    try:
        code = main(argv, read_line=script.read_line, say=script.say)
    finally:
        script.close()
    return code, json.loads((tmp_path / "xarm.json").read_text())


def seen(report: dict[str, Any], key: str) -> str:
    return str(next(check["seen"] for check in report["checks"] if check["key"] == key))


STOP_WRITES = ((Table.COIL, COIL_STOPPED, (1,)), (Table.HOLDING, STATE, (STOPPED,)))


def stop_after(device: XArmSimDevice, write: tuple[Table, int, tuple[int, ...]]) -> bool:
    """The bridge's stop (C145 = 1, then H33 = 4) in the write log after ``write``."""
    log = [(r.table, r.address, r.values) for r in device.write_log]
    after = log[log.index(write) :] if write in log else []
    coil, state = STOP_WRITES
    return coil in after and state in after[after.index(coil) :]


def stops_after_starts(device: XArmSimDevice) -> int:
    """How many project starts (FC 10 at 0x30) the bridge's stop (C145 = 1, then H33 = 4)
    followed, before the next start; asserts each start was followed by one."""
    log = [(r.table, r.address, r.values) for r in device.write_log]
    starts = [k for k, (table, address, _) in enumerate(log) if address == OFFLINE_TASK_ADDRESS]
    for k, start in enumerate(starts):
        after = log[start : starts[k + 1] if k + 1 < len(starts) else len(log)]
        coil, state = STOP_WRITES
        assert coil in after and state in after[after.index(coil) :], after
    return len(starts)


def test_the_default_simulator_confirms_every_check(sim: Rig, tmp_path: Path) -> None:
    """Read-only checks first, then the guided steps after ``yes``, each judged by what
    the arm reads back and each ended by the bridge's stop (the start in error, with no
    error shown, writes nothing); the params file is the bridge's."""
    _, device, port = sim
    code, report = run(port, tmp_path, answers("yes", "yes", "yes", "yes"))
    assert code == 0
    found = verdicts(report)
    assert all(
        found[key] == "confirmed" for key in (*READ_CHECKS, "stop", "pause", "safety_modes")
    ), found
    assert found["start_in_error"] == "not run"
    assert "no error shows" in seen(report, "start_in_error")  # after yes: nothing written
    assert report["recommended_parameters"]["joint_count"] == 7
    assert stops_after_starts(device) == 2
    assert device.arm_state == STOPPED
    assert not device.get("reduced_mode") and not device.get("fence_mode")  # as they were
    params = (tmp_path / "xarm.yaml").read_text()
    assert "/**/xarm_bridge:\n  ros__parameters:" in params and "joint_count: 7" in params


def _ai_beyond_its_range(device: XArmSimDevice) -> None:
    device.set_words(Table.INPUT, XARM_MAP["tool_ai_0"].address, [0x9000])  # -28.672 V


def _flag(name: str) -> Callable[[XArmSimDevice], None]:
    def switch(device: XArmSimDevice) -> None:
        setattr(device, name, True)
        device.tick(0.0)  # the pose again (the Euler personality)

    return switch


PERSONALITIES = [
    # (the arm's joints, the personality, the check that flips, the operator's answers)
    (7, _flag("counter_low_first"), "counter_word_order", ("no", "no", "no", "no")),
    (7, _flag("answer_reserved"), "reserved_rows", ("n", "", "nope", "no")),
    (7, _flag("euler_moving_axes"), "rotation_vector", (None,)),
    (7, _ai_beyond_its_range, "signed_values", ("yes please", "NO", None)),
    (6, lambda _device: None, "joints", ("no", None)),
]


@pytest.mark.parametrize(
    ("joints", "personality", "key", "said"), PERSONALITIES, ids=[p[2] for p in PERSONALITIES]
)
def test_a_personality_contradicts_its_check_only_and_nothing_is_written_without_yes(
    tmp_path: Path,
    joints: int,
    personality: Callable[[XArmSimDevice], None],
    key: str,
    said: tuple[str | None, ...],
) -> None:
    """The other reading of one decision: that check is contradicted (a 6-joint arm with
    joint_count 7: joint_count 6 recommended), the others stay confirmed; answers other
    than ``yes`` (and stdin closed) leave every step not run and the write log empty."""
    with rig(joints) as (_, device, port):
        personality(device)
        code, report = run(port, tmp_path, answers(*said))
        assert code == 0
        found = verdicts(report)
        assert found[key] == "contradicted", found
        assert all(found[other] == "confirmed" for other in READ_CHECKS if other != key), found
        assert all(found[step] == "not run" for step in GUIDED), found
        assert report["recommended_parameters"]["joint_count"] == joints
        assert device.write_log == []


GUIDED_READINGS = [
    # (the personality, the step it is for, its verdict, the operator's answers)
    ("ignore_stop", "stop", "contradicted", ("yes", "no", "no", "no")),
    ("coils_as_written", "pause", "contradicted", ("no", "yes", "no", "no")),
    ("error", "start_in_error", "confirmed", ("no", "no", "yes", "no")),
    ("starts_in_error", "start_in_error", "contradicted", ("no", "no", "yes", "no")),
    ("safety_modes_fixed", "safety_modes", "contradicted", ("no", "no", "no", "yes")),
]


@pytest.mark.parametrize(
    ("personality", "key", "verdict", "said"),
    GUIDED_READINGS,
    ids=[f"{p[0]}-{p[2]}" for p in GUIDED_READINGS],
)
def test_the_other_readings_of_the_guided_steps_are_contradicted(
    sim: Rig, tmp_path: Path, personality: str, key: str, verdict: str, said: tuple[str, ...]
) -> None:
    """A firmware that ignores both stop writes (decisions 6, 19): the stop step is
    contradicted, its stop still sent; one that keeps C144 as written: the pause step,
    whose resume leaves C144 reading 1 while H33 reads 1 (in motion). An arm in error
    (decision 20): the resume and the project are not confirmed, H33 stays 4; one that
    takes a start in error: contradicted (its stop follows the start it took)."""
    simulator, device, port = sim
    if personality == "ignore_stop":
        simulator.ignore({"stop"})
    elif personality == "coils_as_written":
        device.coils_as_written = True
    elif personality == "safety_modes_fixed":
        device.safety_modes_fixed = True
    else:
        device.set_error(1)
        device.starts_in_error = personality == "starts_in_error"
    code, report = run(port, tmp_path, answers(*said))
    assert code == 0
    found = verdicts(report)
    assert found[key] == verdict, found
    assert all(found[other] == "not run" for other in GUIDED if other != key), found
    assert all(found[check] == "confirmed" for check in READ_CHECKS), found
    if key == "start_in_error":  # the resume goes first, the stop after it
        assert stop_after(device, (Table.HOLDING, STATE, (0,)))
    elif key == "safety_modes":  # reduced mode on first, the stop after it
        assert stop_after(device, (Table.COIL, COIL_REDUCED_MODE, (1,)))
    else:
        assert stops_after_starts(device) == 1


def test_enter_and_closed_input_stop_the_running_step(
    sim: Rig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Enter while the first step's project runs, then ``yes`` and the end of the input
    while the second's runs: each step could not tell, and each sent the bridge's stop
    at once (the project would run 30 s before the step's own stop)."""
    _, device, port = sim
    monkeypatch.setattr(commission_guided, "RUN_BEFORE_HALT_S", WAIT_S)

    def moving() -> bool:
        return device.arm_state == IN_MOTION

    script = Script(("prompt", "yes"), (moving, ""), ("prompt", "yes"), (moving, None))
    code, report = run(port, tmp_path, script)
    assert code == 0
    found = verdicts(report)
    assert found["stop"] == found["pause"] == "could not tell", found
    assert stops_after_starts(device) == 2
    assert device.arm_state == STOPPED


def test_ctrl_c_during_a_step_sends_the_stop_and_ends_the_run(
    sim: Rig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGINT, as a terminal sends it, while the project runs: the tool's handler raises
    KeyboardInterrupt in the step, the stop goes out, the report says interrupted and
    the run ends (exit 130), the next step not run."""
    _, device, port = sim
    monkeypatch.setattr(commission_guided, "RUN_BEFORE_HALT_S", WAIT_S)
    assert threading.current_thread() is threading.main_thread()

    def cue() -> bool:
        if device.arm_state != IN_MOTION:
            return False
        signal.raise_signal(signal.SIGINT)
        return True

    code, report = run(port, tmp_path, Script(("prompt", "yes"), (cue, None)))
    assert code == EXIT_INTERRUPTED
    assert report["interrupted"]
    found = verdicts(report)
    assert found["stop"] == found["pause"] == "not run", found
    assert stops_after_starts(device) == 1
    assert device.arm_state == STOPPED


def test_a_bad_parameter_is_one_line_as_the_bridge_says_it(
    sim: Rig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, device, port = sim
    code = main(
        ["xarm", "--ros-args", "-p", f"port:={port}", "-p", "joint_count:=9"],
        read_line=lambda: None,
    )
    err = capsys.readouterr().err
    assert code == EXIT_CONFIGURATION_ERROR
    assert err.startswith("error: xarm_bridge: parameter joint_count: ") and err.count("\n") == 1
    assert device.write_log == []
    assert not (tmp_path / "commission-xarm.json").exists()
