"""MOTEC against drives that do not obey or answer late: the simulator's
personalities (``--ignore`` names, ``setpoint_holds_target``), the holes of the verified
stop (4), ``start_all`` (6) and ``~/set_control_mode`` (9), driven by the device layer
over a real pty pair; then the contract rows over ROS (the bridge in its own process):
against a drive that ignores a motion write, never success or REACHED, the reply says
what was written and read, and a halt still sends its stop and logs "not confirmed"."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from bench.line_relay import LineRelay
from bridge_core.wire.channel import DeviceChannel, Priority
from bridge_core.wire.errors import CommandRejected, LinkTimeout, NotConfirmed
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings
from motec_bridge.broadcast import disable_all, start_all
from motec_bridge.device import MotecDevice
from motec_bridge.registers import CONTROL_MODE_POSITION, CONTROL_MODE_VELOCITY, MOTEC_MAP
from motec_bridge.sim import MotecSimDrive, MotecSimulator, make_simulator
from motec_bridge.sim_cli import main
from motec_bridge.snapshots import STANDSTILL_SPEED_RPM
from msg_defs.msg import MotionOutcome
from msg_defs.srv import PositionMove, SetControlMode

from ..support.fixtures import client_fixture
from ..support.ros import Client, wait_for, wait_subscribed
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty
from ..support.sims import motec_on_pty
from .test_motec_ros import MotecBridge, bridge_params, motec

BAUD = 115200
UNITS = (1, 2, 3)
WAIT_S = 30.0


@dataclass
class Bus:
    sim: MotecSimulator
    devices: dict[int, MotecDevice]
    channels: dict[int, DeviceChannel]
    link: ModbusLink


@pytest.fixture
def bus() -> Iterator[Bus]:
    sim = make_simulator(UNITS)
    with served_on_pty(sim, BAUD) as bridge_end:
        # A pty may stall for seconds beside CPU burners: not what these tests are about.
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        channels = {u: DeviceChannel(link, u, retries=0) for u in UNITS}
        try:
            yield Bus(sim, {u: MotecDevice(channels[u]) for u in UNITS}, channels, link)
        finally:
            link.close()


def wait_until(what: str, condition: Any) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.01)


def cruising(d: MotecDevice, drive: MotecSimDrive, counts: int = 10_000_000) -> None:
    """Position control, enabled, a long move at 600 rpm under way."""
    d.set_control_mode(CONTROL_MODE_POSITION)
    d.enable(True)
    d.move(counts, relative=True, speed_rpm=600)
    wait_until("the move cruises", lambda: drive.speed >= 600)


def ignored(drive: MotecSimDrive, name: str) -> list[tuple[int, tuple[int, ...]]]:
    """(address, values) of the writes of register ``name`` the drive ignored."""
    address = MOTEC_MAP[name].address
    return [(r.address, r.values) for r in drive.write_log if r.ignored and r.address == address]


# ---------------------------------------------------------------- the personalities


def test_every_motion_write_of_the_bridge_has_an_ignore_name(bus: Bus) -> None:
    """Item 1: each motion write the device layer sends is one of ``IGNORABLE`` (by its
    register and value), and an ignored one is acknowledged and changes nothing."""
    d, drive = bus.devices[1], bus.sim.drive(1)
    d.set_control_mode(CONTROL_MODE_VELOCITY)
    d.enable(True)
    d.velocity(100)
    d.velocity_stop()
    d.enable(False)
    d.set_control_mode(CONTROL_MODE_POSITION)
    d.enable(True)
    d.move(1000, relative=True, speed_rpm=300)
    wait_until("the move ends", lambda: drive.move is None)
    d.stop()
    names = [sorted(drive.write_names(r)) for r in drive.write_log if r.table is Table.HOLDING]
    assert names == [
        ["control_mode"],  # 0x24 network
        ["speed_zero"],  # 0xAE = 0 before velocity control
        ["control_mode"],  # 0x25
        ["speed_zero"],  # 0xAE = 0 before enabling in velocity control
        ["enable"],
        ["speed"],  # 100 rpm
        ["speed_zero"],  # the stream's stop
        ["disable"],
        ["control_mode"],
        ["control_mode"],
        ["enable"],
        ["speed"],  # the move's speed limit
        ["target"],  # 0x2D
        ["target"],  # 0x26-0x27
        ["start"],
        ["stop"],
    ]
    assert set(MotecSimDrive.IGNORABLE) == {n for group in names for n in group}
    # Ignored: acknowledged (no exception), logged ignored, nothing stored.
    bus.sim.ignore(["enable", "control_mode"])
    d.enable(False)
    with pytest.raises(NotConfirmed, match=r"wrote 0x28 = 1, read 0x28 = 0"):
        d.enable(True)
    assert not drive.enabled and ignored(drive, "enable") == [(0x28, (1,))]
    with pytest.raises(NotConfirmed, match=r"wrote 0x24 = 0, 0x25 = 1, 0xAE = 0, read 0x24 = 0, "):
        d.set_control_mode(CONTROL_MODE_VELOCITY)
    assert drive.value("control_mode") == CONTROL_MODE_POSITION


def test_an_unknown_ignore_name_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--pty", "/tmp/motec-unused", "--ignore", "stop,brake"])
    err = capsys.readouterr().err.strip().splitlines()
    assert "unknown motion write brake" in err[-1] and "speed_zero" in err[-1], err
    assert not any("Traceback" in line for line in err)


# ---------------------------------------------------------------- hole 4: the verified stop


def test_hole4_an_unchanged_setpoint_at_full_speed_is_not_stopped(bus: Bus) -> None:
    """A drive whose 0xAA holds the move's target (decision 22) and that ignores 0x29 = 0:
    0xAA does not change while 0xAF reads full speed. The stop is not taken as done: the
    drive is released, and the release is read back."""
    d, drive = bus.devices[1], bus.sim.drive(1)
    drive.setpoint_holds_target = True
    cruising(d, drive)
    bus.sim.ignore(["stop"])
    said = d.stop()
    assert said.startswith("0x29 = 0 did not stop the move ("), said
    assert "drive released (0x28 = 0, reads 0; " in said, said
    assert not drive.enabled and drive.speed == 0
    assert ignored(drive, "start") == [(0x29, (0,))]


def test_hole4_a_stop_and_a_release_both_ignored_are_not_confirmed(bus: Bus) -> None:
    d, drive = bus.devices[1], bus.sim.drive(1)
    cruising(d, drive)
    bus.sim.ignore(["stop", "disable"])
    with pytest.raises(NotConfirmed, match=r"sent, not confirmed: wrote 0x28 = 0 \(release\), "):
        d.stop()
    assert drive.enabled and drive.speed >= 600
    assert ignored(drive, "start") == [(0x29, (0,))]
    assert ignored(drive, "enable") == [(0x28, (0,))]


def test_hole4_a_velocity_stop_that_is_ignored_releases_the_drive(bus: Bus) -> None:
    d, drive = bus.devices[1], bus.sim.drive(1)
    d.set_control_mode(CONTROL_MODE_VELOCITY)
    d.enable(True)
    d.velocity(600)
    wait_until("the motor turns", lambda: drive.speed >= 600)
    bus.sim.ignore(["speed_zero"])
    said = d.stop()
    assert said.startswith("0xAE = 0 did not stop the motor (0xAE reads 600, "), said
    assert "drive released (0x28 = 0, reads 0; " in said
    bus.sim.ignore(["speed_zero", "disable"])
    d.enable(True)
    d.velocity(0)
    d.velocity(300)
    wait_until("the motor turns", lambda: drive.speed >= 300)
    with pytest.raises(NotConfirmed, match="read 0x28 = 1"):
        d.stop()
    assert drive.speed >= 300


# ---------------------------------------------------------------- hole 6: start_all


class LosesAReadAfterTheBroadcast:
    """A drive's channel whose first read after the broadcast start gets no reply (noise
    on its stub, a reply lost): the drive took the start, the bridge cannot see it."""

    def __init__(self, channel: DeviceChannel) -> None:
        self.channel = channel
        self.armed = False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.channel, name)

    def read_registers(self, *args: Any, **kwargs: Any) -> list[int]:
        if self.armed:
            self.armed = False
            raise LinkTimeout("unit 2: no reply (lost by the test)")
        return self.channel.read_registers(*args, **kwargs)


class ArmsOnWrite:
    def __init__(self, channel: DeviceChannel, lossy: LosesAReadAfterTheBroadcast) -> None:
        self.channel, self.lossy = channel, lossy

    def __getattr__(self, name: str) -> Any:
        return getattr(self.channel, name)

    def write_register(
        self, address: int, value: int, priority: Priority = Priority.COMMAND
    ) -> None:
        self.channel.write_register(address, value, priority)
        self.lossy.armed = True


def test_hole6_a_drive_whose_read_back_is_lost_is_stopped(bus: Bus) -> None:
    """``start_all``: drive 2 took the start but its read-back was lost: its state is
    unknown, so it is stopped with the others, and the answer is failure."""
    for u in UNITS:
        bus.devices[u].set_control_mode(CONTROL_MODE_POSITION)
        bus.devices[u].enable(True)
        bus.devices[u].write_parameter(0x26, 10_000_000)
    lossy = LosesAReadAfterTheBroadcast(bus.channels[2])
    broadcast = ArmsOnWrite(DeviceChannel(bus.link, 0, retries=0), lossy)
    drives: dict[int, Any] = {1: bus.channels[1], 2: lossy, 3: bus.channels[3]}
    ok, seen = start_all(broadcast, drives)
    assert not ok, seen
    assert "drives [2] were not read back (they may be running)" in seen, seen
    assert "drive 2: not read back (unit 2: no reply (lost by the test))" in seen, seen
    for u in UNITS:
        assert f"drive {u}: move stopped (0x29 = 0; " in seen, seen
    wait_until("every drive stands", lambda: all(bus.sim.drive(u).speed == 0 for u in UNITS))
    stops = [r for r in bus.sim.drive(2).write_log if (r.address, r.values) == (0x29, (0,))]
    assert len(stops) == 1


# ---------------------------------------------------------------- hole 9: set_control_mode


def test_hole9_a_mode_change_is_judged_on_a_fresh_read(bus: Bus) -> None:
    """The motor started turning after the last poll: the mode change is refused (the
    speed is read at command priority), and nothing is written."""
    d, drive = bus.devices[1], bus.sim.drive(1)
    d.set_control_mode(CONTROL_MODE_POSITION)
    d.enable(True)
    assert not d.poll().turning
    d.move(10_000_000, relative=True, speed_rpm=600)
    wait_until("the motor turns", lambda: drive.speed > STANDSTILL_SPEED_RPM)
    before = len(drive.write_log)
    with pytest.raises(CommandRejected, match=r"the motor turns at \d+ rpm: ~/stop it"):
        d.set_control_mode(CONTROL_MODE_VELOCITY)
    assert len(drive.write_log) == before
    assert drive.value("control_mode") == CONTROL_MODE_POSITION


# ---------------------------------------------------------------- item 6: starts read back


def test_a_move_whose_start_or_target_is_ignored_is_not_confirmed_and_stopped(bus: Bus) -> None:
    """``~/move`` (and so ``~/move_to`` and a position stream's first target): against a
    drive that ignores 0x29 = 1 the move is "not confirmed" with what was written and
    read; against one that ignores the target it would run to an older one: not
    confirmed, and stopped."""
    d, drive = bus.devices[1], bus.sim.drive(1)
    d.set_control_mode(CONTROL_MODE_POSITION)
    d.enable(True)
    bus.sim.ignore(["start"])
    with pytest.raises(
        NotConfirmed, match=r"sent, not confirmed: wrote 0x26 = 20000, 0x29 = 1, read 0x26 = "
    ):
        d.move(20_000, relative=True, speed_rpm=600)
    assert drive.speed == 0 and ignored(drive, "start") == [(0x29, (1,))]
    bus.sim.ignore([])
    d.move(5_000_000, relative=False, speed_rpm=600)  # an older target, under way
    wait_until("the move runs", lambda: drive.speed > STANDSTILL_SPEED_RPM)
    bus.sim.ignore(["target"])
    with pytest.raises(NotConfirmed, match=r"wrote 0x26 = 1000, 0x29 = 1, read 0x26 = 5000000"):
        d.move(1000, relative=False, speed_rpm=600)
    wait_until("the drive stands", lambda: drive.speed == 0)


def test_a_retarget_the_drive_ignores_is_not_confirmed_and_stopped(bus: Bus) -> None:
    """A position stream's newer target (``retarget``, MOTEC decision 21): a drive that
    does not take it would run on to the older one: not confirmed, and stopped."""
    d, drive = bus.devices[1], bus.sim.drive(1)
    d.set_control_mode(CONTROL_MODE_POSITION)
    d.enable(True)
    d.move(5_000_000, relative=False, speed_rpm=600)
    wait_until("the move runs", lambda: drive.speed > STANDSTILL_SPEED_RPM)
    d.retarget(6_000_000)  # taken: nothing said
    bus.sim.ignore(["target"])
    with pytest.raises(
        NotConfirmed, match=r"wrote 0x26 = 1000, 0x29 = 1, read 0x26 = 6000000, 0x29 = 1; stopped"
    ):
        d.retarget(1000)
    wait_until("the drive stands", lambda: drive.speed == 0)


def test_broadcasts_against_drives_that_ignore_them(bus: Bus) -> None:
    """``start_all`` and ``disable_all`` (no drive answers a broadcast): a drive that
    ignores 0x29 = 1 did not take the start (failure, the others stopped); one that
    ignores 0x28 = 0 reads 0x28 = 1 after its own write too (failure, said)."""
    broadcast = DeviceChannel(bus.link, 0, retries=0)
    drives = {u: bus.channels[u] for u in UNITS}
    for u in UNITS:
        bus.devices[u].set_control_mode(CONTROL_MODE_POSITION)
        bus.devices[u].enable(True)
        bus.devices[u].write_parameter(0x26, 10_000_000)
    bus.sim.drive(2).ignore = frozenset({"start"})
    ok, seen = start_all(broadcast, drives)
    assert not ok and "drives [2] did not take the start" in seen, seen
    assert "drive 1: move stopped" in seen and "drive 3: move stopped" in seen, seen
    wait_until("every drive stands", lambda: all(bus.sim.drive(u).speed == 0 for u in UNITS))
    bus.sim.drive(2).ignore = frozenset({"disable"})
    ok, seen = disable_all(broadcast, drives)
    assert not ok and "drive 2: 0x28 = 1" in seen and "STILL ENABLED" in seen, seen
    ignored_2 = [(r.address, r.values) for r in bus.sim.drive(2).write_log if r.ignored]
    assert ignored_2 == [(0x29, (1,)), (0x28, (0,)), (0x28, (0,))]  # broadcast, broadcast, own


# ---------------------------------------------------------------- contract rows over ROS

TURN = 2 * 3.141592653589793  # rad of one motor turn (gear 1)
SLOW = TURN  # rad/s: 60 rpm


client = client_fixture("motec_personality_client", log=True)


@pytest.fixture
def one_drive() -> Iterator[tuple[MotecSimulator, str]]:
    with motec_on_pty([1], BAUD) as served:
        yield served


def position_ready(b: MotecBridge) -> None:
    b.wait_connected(1, True)
    b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.POSITION)
    b.ok(1, SetBool, "enable", data=True)


def long_move(b: MotecBridge, drive: MotecSimDrive) -> None:
    b.ok(1, PositionMove, "move", position=100 * TURN, relative=True, max_velocity=SLOW)
    wait_for(lambda: drive.speed >= 59, 20.0, "the move cruises")


def not_confirmed(reply: Any, *texts: str) -> None:
    assert not reply.success, reply.message
    assert "not confirmed" in reply.message, reply.message
    for text in texts:
        assert text in reply.message, reply.message


def command_velocity(client: Client, b: MotecBridge, rad_s: float) -> None:
    """One ``~/cmd_velocity`` message (then silence: the deadman's)."""
    pub = client.node.create_publisher(Float64, f"{b.ns}/motec_1/cmd_velocity", 10)
    wait_subscribed(pub)
    pub.publish(Float64(data=rad_s))


def drive_transition(client: Client, b: MotecBridge, transition: int) -> bool:
    request = ChangeState.Request()
    request.transition.id = transition
    reply = client.call(ChangeState, f"{b.ns}/motec_1/change_state", request)
    return bool(reply.success)


@pytest.mark.ros
def test_contract_services_against_ignored_writes(
    one_drive: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """``~/set_control_mode``, ``~/enable`` (both ways), ``~/move`` and ``~/stop`` (each
    mode) against a drive that ignores that write: never success; the reply says what was
    written and what was read back."""
    sim, port = one_drive
    drive = sim.drive(1)
    with motec(client, tmp_path, bridge_params(port, unit_ids=[1])) as (b, _proc):
        b.wait_connected(1, True)
        sim.ignore(["control_mode"])
        not_confirmed(
            b.call(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.POSITION),
            "wrote 0x24 = 0, 0x25 = 2, read 0x24 = 1",
        )
        sim.ignore(["enable"])
        b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.POSITION)
        not_confirmed(b.call(1, SetBool, "enable", data=True), "wrote 0x28 = 1, read 0x28 = 0")
        sim.ignore(["start"])
        b.ok(1, SetBool, "enable", data=True)
        not_confirmed(
            b.call(1, PositionMove, "move", position=TURN, relative=True, max_velocity=SLOW),
            "wrote 0x26 = 10000, 0x29 = 1, read 0x26 = 10000, 0x29 = 0",
        )
        assert drive.speed == 0
        sim.ignore(["stop", "disable"])
        long_move(b, drive)
        not_confirmed(b.call(1, Trigger, "stop"), "wrote 0x28 = 0 (release), read 0x28 = 1")
        assert drive.speed >= 59
        assert ignored(drive, "start")[-1] == (0x29, (0,))
        not_confirmed(b.call(1, SetBool, "enable", data=False), "wrote 0x28 = 0, read 0x28 = 1")
        sim.ignore(["disable"])
        b.ok(1, Trigger, "stop")  # 0x29 = 0 obeyed: the drive stands
        wait_for(lambda: drive.speed == 0, 20.0, "the drive stands")
        b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY)
        sim.ignore(["speed_zero", "disable"])
        command_velocity(client, b, SLOW)
        wait_for(lambda: drive.speed >= 59, 20.0, "the motor turns")
        not_confirmed(b.call(1, Trigger, "stop"), "0xAE = 0 did not stop the motor (0xAE reads 60")
        assert drive.speed >= 59


@pytest.mark.ros
def test_contract_goals_against_ignored_writes(
    one_drive: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """``~/move_to``: a start the drive ignores is never REACHED (REFUSED, what was written
    and read); a cancel whose stop and release are ignored ends CANCELLED, its result
    saying "not confirmed"."""
    from msg_defs.action import MoveTo

    sim, port = one_drive
    drive = sim.drive(1)

    def goal(position: float) -> Any:
        g = MoveTo.Goal()
        g.position, g.relative, g.max_velocity = float(position), True, SLOW
        return client.send_goal(MoveTo, f"{b.ns}/motec_1/move_to", g)

    with motec(client, tmp_path, bridge_params(port, unit_ids=[1])) as (b, _proc):
        position_ready(b)
        sim.ignore(["start"])
        _status, result = goal(TURN).result()
        assert result.outcome.code == MotionOutcome.REFUSED, result.outcome.message
        assert "not confirmed: wrote 0x26 = " in result.outcome.message, result.outcome.message
        sim.ignore(["stop", "disable"])
        running = goal(100 * TURN)
        running.wait_feedback(lambda f: abs(f.velocity) > 0.5 * SLOW)
        running.cancel()
        _status, result = running.result()
        assert result.outcome.code == MotionOutcome.CANCELLED, result.outcome.message
        assert "not confirmed" in result.outcome.message, result.outcome.message
        assert "wrote 0x28 = 0 (release), read 0x28 = 1" in result.outcome.message
        assert drive.speed >= 59 and ignored(drive, "start")[-1] == (0x29, (0,))


@pytest.mark.ros
def test_contract_deadman_and_halts_against_ignored_stops(
    one_drive: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """The deadman of ``~/cmd_velocity``, and the halts (deactivate, read_only, exit) of a
    ``~/move``: against a drive that ignores the stop and the release, each still sends
    its stop (the write log: ignored) and logs "not confirmed"."""
    sim, port = one_drive
    drive = sim.drive(1)
    logger = None
    with motec(client, tmp_path, bridge_params(port, unit_ids=[1])) as (b, proc):
        logger = f"{b.ns[1:]}.motec_1"
        b.wait_connected(1, True)
        b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.VELOCITY)
        b.ok(1, SetBool, "enable", data=True)
        sim.ignore(["speed_zero", "disable"])
        t = time.monotonic()
        command_velocity(client, b, SLOW)
        wait_for(lambda: drive.speed >= 59, 20.0, "the motor turns")
        client.wait_log(logger, "(deadman): not confirmed", t)  # silence: the deadman
        assert ignored(drive, "speed_setpoint")[0] == (0xAE, (0,))
        sim.ignore([])
        b.ok(1, Trigger, "stop")
        b.ok(1, SetControlMode, "set_control_mode", mode=SetControlMode.Request.POSITION)
        b.ok(1, SetBool, "enable", data=True)

        # Deactivate: the move's stop goes out, is ignored, and is said "not confirmed".
        sim.ignore(["stop", "disable"])
        long_move(b, drive)
        before = len(ignored(drive, "start"))
        t = time.monotonic()
        assert drive_transition(client, b, Transition.TRANSITION_DEACTIVATE)
        client.wait_log(logger, "not confirmed", t)
        assert ignored(drive, "start")[before:] == [(0x29, (0,))]
        assert drive.speed >= 59
        sim.ignore([])
        assert drive_transition(client, b, Transition.TRANSITION_ACTIVATE)
        b.ok(1, Trigger, "stop")

        # read_only.
        sim.ignore(["stop", "disable"])
        long_move(b, drive)
        before = len(ignored(drive, "start"))
        t = time.monotonic()
        assert b.set_param(1, "read_only", True).successful
        client.wait_log(logger, "not confirmed", t)
        assert ignored(drive, "start")[before:] == [(0x29, (0,))]
        sim.ignore([])
        assert b.set_param(1, "read_only", False).successful
        b.ok(1, Trigger, "stop")

        # Exit (SIGINT).
        sim.ignore(["stop", "disable"])
        long_move(b, drive)
        before = len(ignored(drive, "start"))
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
        assert ignored(drive, "start")[before:] == [(0x29, (0,))]
    log = (tmp_path / "motec_bridge_node.log").read_text(errors="replace").splitlines()
    said = [line for line in log if "not confirmed" in line and "the node is exiting" in line]
    assert said, "\n".join(log[-30:])


@pytest.mark.ros
def test_contract_joint_commands_position_target_against_an_ignored_start(
    one_drive: tuple[MotecSimulator, str], client: Client, tmp_path: Path
) -> None:
    """``~/joint_commands``: a position stream's first target against a drive that
    ignores 0x29 = 1 is refused "not confirmed" (what was written and read, logged by the
    drive's node), and its move stopped."""
    sim, port = one_drive
    drive = sim.drive(1)
    with motec(client, tmp_path, bridge_params(port, unit_ids=[1])) as (b, _proc):
        position_ready(b)
        sim.ignore(["start"])
        pub = client.node.create_publisher(JointState, f"{b.ns}/motec_bridge/joint_commands", 10)
        wait_subscribed(pub)
        t = time.monotonic()
        msg = JointState()
        msg.name, msg.position = ["drive_1"], [0.05]
        pub.publish(msg)
        client.wait_log(f"{b.ns[1:]}.motec_1", "not confirmed: wrote 0x26 = 80, 0x29 = 1", t)
        assert ignored(drive, "start") == [(0x29, (1,))]
        assert drive.speed == 0
        client.node.destroy_publisher(pub)


# ---------------------------------------------------------------- delay rows

# Replies after 50-80 ms, drawn per reply: all later than the short wait a request to a
# drive marked down used to get (down_write_timeout_s, 50 ms), all within the link's
# timeout_s 0.1 with the frames at 115200 baud.
# Past the short wait of a stop to a drive marked down (STOP_TIMEOUT_S, 0.05 s), which
# the probes waited before hole 1's fix; the link's timeout_s (DELAY_TIMEOUT_S) leaves a
# loaded host 0.4 s over the longest reply (at 0.1 s with 50-80 ms replies a
# set_control_mode timed out beside a CI run; at 0.25 s, a move's readiness read beside two
# CPU burners: this simulator runs in the test's process, beside its rclpy client).
DELAY_S = (0.06, 0.1)
DELAY_TIMEOUT_S = 0.5


@pytest.mark.ros
def test_delay_drives_answering_late_connect_poll_reconnect_and_stop_at_once(
    client: Client, tmp_path: Path
) -> None:
    """A drive answering 60-100 ms after each request, on a byte-timed line (the bench's
    relay): the node connects at start, polls, reconnects after an outage, and a stop
    goes out at once (at most the read on the line and the stop's own mode read, or its
    retry, before its write). Before hole 1's fix the probes waited 50 ms and it never connected."""
    sim = make_simulator([1])
    sim.set_reply_delay(*DELAY_S)
    drive = sim.drive(1)
    with LineRelay(BAUD) as line:
        sim.start_serial(line.device_path, BAUD)
        try:
            params = bridge_params(
                line.client_path, unit_ids=[1], timeout_s=DELAY_TIMEOUT_S, poll_rate_hz=10.0
            )
            with motec(client, tmp_path, params) as (b, proc):
                b.wait_connected(1, True)  # at start
                b.wait_joints(1, 5, time.monotonic())  # polls
                sim.unplug(1)
                b.wait_connected(1, False)
                sim.plug(1)
                b.wait_connected(1, True)  # reconnected
                b.wait_joints(1, 3, time.monotonic())
                position_ready(b)
                long_move(b, drive)
                drive.log_reads = True
                called = time.time()
                said = b.ok(1, Trigger, "stop").message
                assert "move stopped" in said, said
                (stop,) = [r for r in drive.write_log if (r.address, r.values) == (0x29, (0,))]
                ahead = [r.address for r in drive.read_log if called <= r.time <= stop.time]
                # The stop's own mode reads last (0x24; one more if a late reply cost
                # the first its try). Before them only what the poll had begun before
                # the request reached the node (the client's clock runs ahead of the
                # node's receipt under load): each poll block at most once, never a
                # second poll cycle ([36, 265, 36] beside two CPU burners).
                assert ahead and ahead[-1] == 0x24, ahead
                own = 2 if ahead[-2:] == [0x24, 0x24] else 1
                polled = ahead[:-own]
                assert len(polled) == len(set(polled)) <= 2, ahead
                assert proc.poll() is None
        finally:
            sim.stop()
