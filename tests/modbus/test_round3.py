"""modbus_bridge, round 3: a description can never make the
bridge harm the device. The malformed-file variants of these items (one line, its line
number, in all three commands) are in malformed_cases.py; these are the rest: what a
loaded file does in the device layer, the simulator and the poll loop.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge_core.runtime.poller import REPEAT_REPORT_S, Poller, PollOutcome
from bridge_core.wire.errors import CommandRejected
from modbus_bridge import sim as sim_command
from modbus_bridge.description import DescriptionError, load
from modbus_bridge.sim import DescribedSimDevice

from ..support.fakes import FakeChannel, FakeClock, FakeDevice
from .test_modbus_sim import over_tcp, wait_for
from .test_round2 import INVERTER, MULTIDROP, VFD

XARM = VFD.parent / "xarm.yaml"

DRIVE = """\
device:
  name: drive
  manual: t
  link: {tcp: {port: 1502}}
  require_keepalive: true
registers:
  - {name: lifeguard_time, table: holding, address: 0x112, type: u16, unit: ms, access: RW, manual: t}
  - {name: speed, table: holding, address: 0xAE, type: i16, unit: rpm, access: RW, manual: t}
  - {name: enable, table: holding, address: 0x28, type: u16, access: RW, manual: t}
commands:
  triggers:
    - {name: go, writes: [{register: enable, value: 1}], starts_motion: true}
    - {name: stop, writes: [{register: speed, value: 0}], stop: true}
keepalive: {register: lifeguard_time, period_from: lifeguard_time}
"""  # noqa: E501
DRIVE_KEEPALIVE = "keepalive: {register: lifeguard_time, period_from: lifeguard_time}"


def refused(tmp_path: Path, text: str) -> list[str]:
    path = tmp_path / "device.yaml"
    path.write_text(text)
    with pytest.raises(DescriptionError) as caught:
        load(path)
    return caught.value.lines()


def loaded(tmp_path: Path, text: str) -> DescribedSimDevice:
    path = tmp_path / "device.yaml"
    path.write_text(text)
    return DescribedSimDevice(load(path).device)


# ------------------------------------------------------------------ item 1
@pytest.mark.parametrize(
    ("keepalive", "words"),
    [
        ("{register: enable, mode: toggle, period_s: 1.0}", "mode toggle writes 0 would be"),
        ("{register: speed, mode: counter, period_s: 1.0}", "mode counter writes 32767"),
        ("{register: enable, value: 3, period_s: 1.0}", "enable takes one of 1, 2, not 3"),
    ],
)
def test_every_feed_is_checked_as_a_write_at_load(
    tmp_path: Path, keepalive: str, words: str
) -> None:
    """A toggle's 0 and 1 and a counter's whole span are feeds too: a register whose
    ``values`` or ``range`` refuse one of them is refused at load, at the keepalive."""
    text = (
        DRIVE.replace(
            "type: u16, access: RW, manual", "type: u16, access: RW, values: [1, 2], manual"
        )
        .replace("unit: rpm, access: RW,", "unit: rpm, access: RW, range: [-3000, 3000],")
        .replace(DRIVE_KEEPALIVE, f"keepalive: {keepalive}")
    )
    lines = refused(tmp_path, text)
    assert len(lines) == 1 and ":14: keepalive." in lines[0] and words in lines[0], lines


# ------------------------------------------------------------------ item 2
def test_each_trigger_that_does_not_say_whether_it_starts_motion_is_named(
    tmp_path: Path,
) -> None:
    text = DRIVE.replace(", starts_motion: true}", "}").replace(
        "    - {name: stop,",
        "    - {name: jog, writes: [{register: speed, value: 10}]}\n    - {name: stop,",
    )
    lines = refused(tmp_path, text)
    assert len(lines) == 2, lines
    assert ":12: commands.triggers[0]: trigger 'go' does not say" in lines[0]
    assert ":13: commands.triggers[1]: trigger 'jog' does not say" in lines[1]
    # a service cannot answer yes: only a trigger's start is stopped on the way out
    text = DRIVE.replace(
        "\nkeepalive:",
        "\n  values:\n    - {name: set_speed, register: speed, starts_motion: true}\nkeepalive:",
    )
    (line,) = refused(tmp_path, text)
    assert "commands.values[0].starts_motion" in line and "as a trigger" in line


def test_the_shipped_files_answer_every_trigger() -> None:
    for path in (VFD, INVERTER, MULTIDROP, XARM):
        for device in load(path).devices:
            for trigger in device.commands.triggers:
                assert trigger.stop or trigger.starts_motion is not None, (path, trigger.name)


# ------------------------------------------------------------------ item 3
def test_a_poll_failure_prints_its_traceback_once() -> None:
    """The same failure every cycle: its traceback the first time, then one line at most
    every REPEAT_REPORT_S with how often it came again (was: a traceback every 0.1 s)."""
    channel = FakeChannel()
    device = FakeDevice(channel)
    clock = FakeClock(1000.0)
    reports: list[str] = []
    poller: Poller[int] = Poller(
        channel,
        device.poll,
        lambda _snapshot: None,
        rate_hz=10.0,
        report=lambda outcome, text: reports.append(f"{outcome.value}: {text}"),
        clock=clock,
    )
    channel.connected = True
    for _ in range(45):
        device.errors.append(RuntimeError("lifeguard_time is write-only"))
        assert poller.tick() is PollOutcome.FAILED
        clock.now += 0.1
    tracebacks = [text for text in reports if "Traceback" in text]
    assert len(tracebacks) == 1 and reports[0] == tracebacks[0]
    assert len(reports) <= 1 + 4.5 / REPEAT_REPORT_S + 1
    assert all("\n" not in text and "again" in text for text in reports[1:]), reports
    device.errors.append(ValueError("another fault"))
    poller.tick()
    assert "Traceback" in reports[-1]  # a new failure: its own traceback, once


# ------------------------------------------------------------------ item 4
def test_a_watchdog_time_of_0_says_which_register_and_what_to_write(tmp_path: Path) -> None:
    path = tmp_path / "drive.yaml"
    path.write_text(DRIVE)
    with over_tcp(load(path)) as (device, _sim, _):
        feeder = device.keepalive
        assert feeder is not None
        feeder.arm()  # lifeguard_time reads 0: the device's watchdog is off
        with pytest.raises(CommandRejected) as caught:
            device.trigger("go")
        message = str(caught.value)
        assert "lifeguard_time reads 0" in message and "~/write name: lifeguard_time" in message
        assert "ms" in message, message
        device.write("lifeguard_time", 600)
        feeder.due()
        assert feeder.armed
        device.trigger("go")


def test_a_watchdog_any_frame_resets_is_fed_by_the_polls(tmp_path: Path) -> None:
    """keepalive mode any_frame: no register fed; every request to the unit resets the
    simulated watchdog, which trips (the device stops) when the frames stop; motion
    under require_keepalive needs only the link up."""
    text = DRIVE.replace(DRIVE_KEEPALIVE, "keepalive: {mode: any_frame, period_s: 0.3}")
    path = tmp_path / "drive.yaml"
    path.write_text(text)
    description = load(path)
    assert description.device.keepalive is None and description.device.frame_watchdog_s == 0.3
    with over_tcp(description) as (device, sim, channel):
        assert device.keepalive is None  # nothing for the node to feed
        device.poll()
        fed_at = sim.keepalive_fed_at
        assert fed_at is not None
        device.trigger("go")  # connected: allowed under require_keepalive
        assert sim.write_log == [sim.write_log[0]]  # the start alone: no feed written
        device.poll()
        assert sim.keepalive_fed_at is not None and sim.keepalive_fed_at > fed_at
        sim.set("speed", 100)
        wait_for(lambda: sim.keepalive_trips == 1, "the watchdog (0.3 s without a frame)")
        assert sim.get("speed") == 0  # the stop trigger's value
        channel.link.close()
        channel.link_state.went_down("closed")
        with pytest.raises(CommandRejected, match="link is down"):
            device.trigger("go")


# ------------------------------------------------------------------ item 7
def test_the_vfd_simulator_says_running_and_draws_current_while_it_turns(tmp_path: Path) -> None:
    """``sim.follows``: the status word's running bit and the current follow the motion;
    a ``command`` follower (a frequency reference) shows the command that counts."""
    text = VFD.read_text().replace(
        "  - {name: accel_time,",
        "  - {name: frequency_reference, table: holding, address: 0x2103, type: u16, "
        'scale: 100, unit: Hz, manual: "monitor: frequency command"}\n'
        "  - {name: accel_time,",
    )
    text = text.replace(
        "        output_current: {speed: 0.08}\n",
        "        output_current: {speed: 0.08}\n        frequency_reference: {command: 1}\n",
    )
    sim = loaded(tmp_path, text)
    sim.set("frequency_setpoint", 25.0)
    sim.tick(0.01)
    assert (sim.get("status_word"), sim.get("output_current")) == (0, 0.0)
    assert sim.get("frequency_reference") == 0.0  # not running: no command counts
    sim.set("control_word", 1)  # run forward
    sim.tick(0.01)
    assert sim.get("status_word") == 1 and sim.get("frequency_reference") == 25.0
    sim.tick(10.0)  # the ramp (0.3 s) is done
    assert sim.get("output_frequency") == pytest.approx(25.0)
    assert sim.get("output_current") == pytest.approx(2.0)  # 0.08 A per Hz
    sim.set("control_word", 5)  # stop: ramps down
    sim.tick(0.01)
    assert sim.get("status_word") == 1  # still turning
    sim.tick(100.0)
    assert (sim.get("status_word"), sim.get("output_current")) == (0, 0.0)
    assert sim.get("frequency_reference") == 0.0


@pytest.mark.parametrize(
    ("follows", "words"),
    [
        ("{status: {running: 1}}", "no register named 'status'"),
        ("{accel_time: {speed: 1}}", "not a read-only number"),
        ("{output_frequency: {speed: 1}}", "the joint's own"),
        ("{status_word: {speed: 1, command: 2}}", "give one rule"),
        ("{status_word: {running: -1}}", "cannot hold it"),
    ],
)
def test_followers_are_checked(tmp_path: Path, follows: str, words: str) -> None:
    text = VFD.read_text()
    old = (
        "      follows:\n        status_word: {running: 1, stopped: 0}\n"
        "        output_current: {speed: 0.08}\n"
    )
    assert old in text
    lines = refused(tmp_path, text.replace(old, f"      follows: {follows}\n"))
    assert len(lines) == 1 and "joints[0].sim.follows" in lines[0] and words in lines[0], lines


# ------------------------------------------------------------------ item 9
def test_a_pty_in_a_missing_directory_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = tmp_path / "no_such_dir" / "vfd"
    assert sim_command.main(["--device-file", str(VFD), "--pty", str(where)]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"error: --pty {where}: no directory {where.parent}\n"


def test_a_file_default_poll_group(tmp_path: Path) -> None:
    """``device.poll: slow``: every register without its own ``poll`` is slow, but a
    joint's registers stay fast and a register's own ``poll`` wins."""
    text = VFD.read_text().replace("  poll_rate_hz: 10\n", "  poll_rate_hz: 10\n  poll: slow\n")
    text = text.replace('manual: "drive status: bit 0', 'poll: fast, manual: "drive status: bit 0')
    path = tmp_path / "vfd.yaml"
    path.write_text(text)
    device = load(path).device
    assert set(device.slow_names) == {
        "control_word", "frequency_setpoint", "comm_watchdog", "output_current", "accel_time"
    }  # fmt: skip
    assert device.polls["output_frequency"] == "fast"  # the joint's velocity
    assert device.polls["status_word"] == "fast"  # its own poll
