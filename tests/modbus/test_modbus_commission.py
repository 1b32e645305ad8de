"""``bridge_commission modbus`` against modbus_sim (docs/commissioning.md).

The tool runs in-process (``bridge_core.ros.commission.main``, the operator's lines fed by
the R6 test's ``Script``) against in-process simulators shared by the module: the inverter
example (its f32 rows in both word orders) with ``read_undefined: true``, and the VFD
example over TCP with a 0.5 s watchdog (its guided steps: start, watchdog, read-back).
Against the default simulators every read-only check is confirmed and the guided steps
pass; each personality that plays the other reading of one check (docs/tools.md, "Device
personalities") makes exactly that check contradicted, with the key to change. Nothing is
written without ``yes``; every way out of a running step sends the file's stop trigger.
One RTU case on a pty: the parity check.
"""

from __future__ import annotations

import json
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge_core.ros.command_line import EXIT_CONFIGURATION_ERROR
from bridge_core.ros.commission import EXIT_INTERRUPTED, main
from bridge_core.runtime.commission_run import FIRST_LINE
from bridge_core.sim.serving import Simulator
from modbus_bridge.description import load
from modbus_bridge.sim import DescribedSimDevice, make_simulator

from ..support.commission import Script, answers, verdicts
from ..support.ros import ROOT
from ..support.serial_pair import socat_pair

DEVICES = ROOT / "config" / "devices"
READ_CHECKS = ("gaps_served", "plan_speed", "addresses", "word_order")
GUIDED = ("run_forward", "watchdog", "frame_watchdog", "read_back")
SAMPLES = 10  # the fewest the tool takes
WAIT_S = 30.0  # a bound, not a measure
WATCHDOG_S = 0.5  # the VFD copy's keepalive period (the example's 2 s, shortened)
RUN, STOP = 1, 5  # the VFD's control word: run forward, stop
KEEPALIVE = "keepalive: {register: comm_watchdog, mode: counter, period_s: 2.0}"


def _written(tmp: Path, name: str, text: str) -> Path:
    path = tmp / name
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The inverter example reading through its gap (read_undefined: true, the torque limit
    polled fast: one request over 200-205, 203 undefined) and the VFD example over TCP with
    a short watchdog."""
    tmp = tmp_path_factory.mktemp("commission")
    inverter = (DEVICES / "inverter_tcp_f32.yaml").read_text()
    vfd = (DEVICES / "vfd_rtu.yaml").read_text()
    old_link = "    rtu: {serial_port: /dev/ttyUSB0, baudrate: 19200, parity: E, stopbits: 1}"
    assert old_link in vfd and "period_s: 2.0}" in vfd and "  poll_rate_hz: 20\n" in inverter
    assert "range: [0, 200], poll: slow," in inverter
    assert KEEPALIVE in vfd
    vfd_tcp = vfd.replace(old_link, "    tcp: {host: 127.0.0.1, port: 502}")
    return {
        "inverter": _written(
            tmp,
            "inverter.yaml",
            inverter.replace(
                "  poll_rate_hz: 20\n", "  poll_rate_hz: 20\n  read_undefined: true\n"
            ).replace("range: [0, 200], poll: slow,", "range: [0, 200],"),
        ),
        "vfd": _written(
            tmp, "vfd.yaml", vfd_tcp.replace("period_s: 2.0}", f"period_s: {WATCHDOG_S}}}")
        ),
        "any_frame": _written(
            tmp,
            "any_frame.yaml",
            vfd_tcp.replace(KEEPALIVE, f"keepalive: {{mode: any_frame, period_s: {WATCHDOG_S}}}"),
        ),
    }


def _serve(path: Path) -> Iterator[tuple[DescribedSimDevice, int]]:
    simulator: Simulator = make_simulator(load(path))
    device = simulator.device
    assert isinstance(device, DescribedSimDevice)
    port = simulator.start_tcp()
    try:
        yield device, port
    finally:
        simulator.stop()


@pytest.fixture(scope="module")
def inverter_sim(files: dict[str, Path]) -> Iterator[tuple[DescribedSimDevice, int]]:
    yield from _serve(files["inverter"])


@pytest.fixture(scope="module")
def vfd_sim(files: dict[str, Path]) -> Iterator[tuple[DescribedSimDevice, int]]:
    yield from _serve(files["vfd"])


@pytest.fixture
def inverter(inverter_sim: tuple[DescribedSimDevice, int]) -> tuple[DescribedSimDevice, int]:
    """The shared inverter, as the manual has it, reading a DC bus and a torque limit
    (nonzero f32 rows, one per word order)."""
    device, port = inverter_sim
    _plain(device)
    device.set("dc_bus_voltage", 540.0)  # CDAB
    device.set("speed_setpoint", 1500.0)  # ABCD
    return device, port


@pytest.fixture
def vfd(vfd_sim: tuple[DescribedSimDevice, int]) -> tuple[DescribedSimDevice, int]:
    """The shared VFD, stopped, with a setpoint of 10 Hz (the motor turns when run)."""
    device, port = vfd_sim
    _plain(device)
    with device.lock:  # standing at once (its ramp down would take seconds)
        device.set("control_word", STOP)
        device.set("frequency_setpoint", 10.0)
        device.velocities_si["motor"] = 0.0
        device.set("output_frequency", 0.0)
    return device, port


def _plain(device: DescribedSimDevice) -> None:
    device.swap_word_order = device.refuse_undefined = device.watchdog_off = False
    device.address_shift = 0
    device.ignore = frozenset()
    device.keepalive_fed_at = None
    device.write_log.clear()


def run(
    file: Path, port: int, tmp_path: Path, script: Script, *options: str, ros: tuple[str, ...] = ()
) -> tuple[int, dict[str, Any]]:
    argv = [
        "modbus",
        "--samples",
        str(SAMPLES),
        "--report",
        str(tmp_path / "modbus.md"),
        "--json",
        str(tmp_path / "modbus.json"),
        "--params",
        str(tmp_path / "modbus.yaml"),
        *options,
        "--ros-args",
        "-p",
        f"device_file:={file}",
        "-p",
        f"port:={port}",
        *ros,
    ]
    try:
        code = main(argv, read_line=script.read_line, say=script.say)
    finally:
        script.close()
    return code, json.loads((tmp_path / "modbus.json").read_text())


def seen(report: dict[str, Any], key: str) -> str:
    return next(str(c["seen"]) for c in report["checks"] if c["key"] == key)


def control_words(device: DescribedSimDevice) -> list[int]:
    """The control word values written, in order (the keepalive's feeds left out)."""
    address = device.map["control_word"].address
    return [r.values[0] for r in device.write_log if r.address == address]


def test_the_inverter_confirms_every_read_check_and_nothing_is_written_without_yes(
    inverter: tuple[DescribedSimDevice, int], files: dict[str, Path], tmp_path: Path
) -> None:
    """Read-only first (said in the first line); answers other than ``yes`` leave the
    guided steps not run and the write log empty; the params file names the file."""
    device, port = inverter
    script = answers("no", "n", "", "yes please")
    code, report = run(files["inverter"], port, tmp_path, script)
    assert code == 0
    assert script.said[0] == FIRST_LINE
    found = verdicts(report)
    assert all(found[key] == "confirmed" for key in READ_CHECKS), found
    assert found["parity"] == "not run"  # TCP
    assert found["keepalive_settings"] == "not run"  # the file names none
    assert all(found[key] == "not run" for key in GUIDED), found
    assert "dc_bus_voltage 540" in seen(report, "word_order")
    assert "speed_setpoint 1500" in seen(report, "word_order")
    assert device.write_log == []
    params = (tmp_path / "modbus.yaml").read_text()
    assert "/**/modbus_bridge:\n  ros__parameters:\n" in params
    assert f'device_file: "{files["inverter"]}"' in params and f"port: {port}" in params


PERSONALITIES = [
    # (device attribute, value, the check contradicted, what its finding says to do)
    ("swap_word_order", True, "word_order", "set `word_order: high_first`"),
    ("refuse_undefined", True, "gaps_served", "set `read_undefined: false` under `device`"),
    ("address_shift", 1, "addresses", "subtract 1 from every address"),
]


@pytest.mark.parametrize(
    ("attribute", "value", "key", "advice"), PERSONALITIES, ids=[p[2] for p in PERSONALITIES]
)
def test_a_personality_contradicts_its_check_only(
    inverter: tuple[DescribedSimDevice, int],
    files: dict[str, Path],
    tmp_path: Path,
    attribute: str,
    value: object,
    key: str,
    advice: str,
) -> None:
    """The other reading of one decision: that check is contradicted and says which key
    of the file to change; no other check is contradicted (with every row off by one the
    word order and the gaps cannot tell); stdin closed: no step runs, nothing written."""
    device, port = inverter
    setattr(device, attribute, value)
    code, report = run(files["inverter"], port, tmp_path, answers(None))
    assert code == 0
    found = verdicts(report)
    assert found[key] == "contradicted", found
    assert advice in seen(report, key)
    others = [k for k in READ_CHECKS if k != key]
    if attribute == "address_shift":
        assert all(found[k] != "contradicted" for k in others), found
    else:
        assert all(found[k] == "confirmed" for k in others), found
    assert all(found[step] == "not run" for step in GUIDED), found
    assert device.write_log == []


def test_the_vfd_runs_stops_and_trips_its_watchdog(
    vfd: tuple[DescribedSimDevice, int], files: dict[str, Path], tmp_path: Path
) -> None:
    """``yes`` to each step: the start reads back and the motor turns, the watchdog stops
    it once the feeds pause, start and stop read back; each step's stop went out after
    its start (the control word's writes: run, then stop, per step)."""
    device, port = vfd
    code, report = run(files["vfd"], port, tmp_path, answers("yes", "yes", "no", "yes"))
    assert code == 0
    found = verdicts(report)
    assert found["run_forward"] == "confirmed", found
    assert found["watchdog"] == "confirmed", found
    assert found["frame_watchdog"] == "not run"  # a register keepalive
    assert found["read_back"] == "confirmed", found
    assert found["keepalive_settings"] == "confirmed", found
    assert device.keepalive_trips >= 1
    assert control_words(device) == [RUN, STOP, RUN, STOP, RUN, STOP, STOP], control_words(device)


def test_a_watchdog_any_frame_resets_trips_in_the_silence(
    files: dict[str, Path], tmp_path: Path
) -> None:
    """The VFD with ``keepalive: {mode: any_frame}`` (decision 22): the drive runs while
    read, then no frame for the watchdog time and the grace: it trips and slows."""
    iterator = _serve(files["any_frame"])
    device, port = next(iterator)
    try:
        device.set("frequency_setpoint", 10.0)
        code, report = run(files["any_frame"], port, tmp_path, answers("no", "no", "yes", "no"))
        # The silence tripped it. Any other gap of 0.5 s without a frame trips it too (a
        # prompt, the next run's start on a loaded machine): counted here, at least one.
        tripped = device.keepalive_trips
        # At 2 Hz one poll per watchdog time, not three: the rate that feeds it recommended.
        slow_code, slow = run(
            files["any_frame"],
            port,
            tmp_path,
            answers(),
            "--read-only",
            ros=("-p", "poll_rate_hz:=2.0"),
        )
    finally:
        next(iterator, None)  # the simulator stops
    assert code == 0 and slow_code == 0
    found = verdicts(report)
    assert found["frame_watchdog"] == "confirmed", found
    assert found["keepalive_settings"] == "confirmed", found
    assert verdicts(slow)["keepalive_settings"] == "contradicted", verdicts(slow)
    assert slow["recommended_parameters"]["poll_rate_hz"] == 3 / WATCHDOG_S
    assert tripped >= 1
    assert control_words(device) == [RUN, STOP], control_words(device)


@pytest.mark.parametrize(
    ("attribute", "value", "said", "flipped"),
    [
        (
            "ignore",
            frozenset({"run_forward"}),
            ("yes", "no", "no", "yes"),
            ("run_forward", "read_back"),
        ),
        ("watchdog_off", True, ("no", "yes"), ("watchdog",)),
    ],
    ids=["ignores-the-start", "no-watchdog"],
)
def test_the_other_readings_of_the_guided_steps_are_contradicted(
    vfd: tuple[DescribedSimDevice, int],
    files: dict[str, Path],
    tmp_path: Path,
    attribute: str,
    value: object,
    said: tuple[str, ...],
    flipped: tuple[str, ...],
) -> None:
    """A drive that acknowledges the start and ignores it (decision 19): the start and
    the read-back are contradicted; one whose watchdog never trips: the watchdog step.
    The stop goes out after each step run."""
    device, port = vfd
    setattr(device, attribute, value)
    code, report = run(files["vfd"], port, tmp_path, answers(*said, None))
    assert code == 0
    found = verdicts(report)
    assert all(found[key] == "contradicted" for key in flipped), found
    assert all(found[key] != "contradicted" for key in GUIDED if key not in flipped), found
    assert control_words(device)[-1] == STOP
    assert control_words(device).count(STOP) >= said.count("yes")


@pytest.mark.parametrize("stop", ["", None, "ctrl-c"], ids=["enter", "stdin-closed", "ctrl-c"])
def test_a_stop_key_closed_input_or_ctrl_c_sends_the_stop(
    vfd: tuple[DescribedSimDevice, int], files: dict[str, Path], tmp_path: Path, stop: str | None
) -> None:
    """At a setpoint of 0 the start step waits for motion that never comes; Enter, the
    end of the input or Ctrl-C ends it: the stop trigger goes out at once, the step could
    not tell; after the end of the input or Ctrl-C no other step runs."""
    device, port = vfd
    device.set("frequency_setpoint", 0.0)

    def running() -> bool:
        return RUN in control_words(device)

    def interrupt() -> bool:  # SIGINT as a terminal sends it, once the drive runs
        if not running():
            return False
        signal.raise_signal(signal.SIGINT)
        return True

    if stop == "ctrl-c":
        assert threading.current_thread() is threading.main_thread()
        cue: Callable[[], bool] = interrupt
        script = Script(("prompt", "yes"), (cue, None))
    else:
        script = Script(("prompt", "yes"), (running, stop), *[("prompt", "no")] * 3)
    code, report = run(files["vfd"], port, tmp_path, script)
    assert code == (EXIT_INTERRUPTED if stop == "ctrl-c" else 0)
    found = verdicts(report)
    assert found["run_forward"] == ("not run" if stop == "ctrl-c" else "could not tell"), found
    assert all(found[key] == "not run" for key in GUIDED[1:]), found
    assert bool(report["interrupted"]) is (stop == "ctrl-c")
    assert control_words(device) == [RUN, STOP], control_words(device)


@pytest.mark.parametrize(
    ("given", "said"),
    [
        (("-p", "timeout_s:=99.0"), "error: modbus_bridge: parameter timeout_s: "),
        ((), "error: no device description: give -p device_file:=FILE"),
    ],
    ids=["out-of-range", "no-file"],
)
def test_a_bad_parameter_is_one_line_as_the_bridge_says_it(
    files: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    given: tuple[str, ...],
    said: str,
) -> None:
    file = ("-p", f"device_file:={files['inverter']}") if given else ()
    code = main(["modbus", "--ros-args", *file, *given], read_line=lambda: None)
    err = capsys.readouterr().err
    assert code == EXIT_CONFIGURATION_ERROR
    assert err.startswith(said) and err.count("\n") == 1, err
    assert not (tmp_path / "commission-modbus.json").exists()


def test_the_vfd_on_rtu_answers_at_its_parity(tmp_path: Path) -> None:
    """The example as shipped, 8E1 on a pty (which keeps no parity bit, decision 15):
    the tool takes the file's serial settings and the parity check is confirmed."""
    vfd = DEVICES / "vfd_rtu.yaml"
    simulator = make_simulator(load(vfd))
    with socat_pair() as (bridge_end, device_end, _):
        simulator.start_serial(device_end, 19200, "E", 1)
        try:
            argv = ["modbus", "--samples", str(SAMPLES), "--read-only", "--json"]
            argv += [str(tmp_path / "m.json"), "--report", str(tmp_path / "m.md")]
            argv += ["--params", str(tmp_path / "m.yaml"), "--ros-args"]
            argv += ["-p", f"device_file:={vfd}", "-p", f"serial_port:={bridge_end}"]
            code = main(argv, read_line=lambda: None, say=lambda _line: None)
        finally:
            simulator.stop()
    assert code == 0
    report = json.loads((tmp_path / "m.json").read_text())
    found = verdicts(report)
    assert found["parity"] == "confirmed", found
    assert "19200 8E1" in seen(report, "parity")
    assert found["word_order"] == "not run", found  # the VFD has no 32-bit row
    assert all(found[key] == "not run" for key in GUIDED), found
