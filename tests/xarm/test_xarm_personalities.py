"""The xArm bridge against an arm that does not obey, keeps its coils as written, or
answers late (docs/tools.md "Device personalities"): no command that starts,
stops or changes motion reports success the arm's own state, read back, does not show.

First the device layer against the simulator over a real socket (xArm decisions 19, 20),
then the contract rows: the node in its own process, an rclpy client in this one.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import LinkTimeout, NotConfirmed
from bridge_core.wire.ports import free_port
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, TcpSettings
from msg_defs.msg import XArmState
from msg_defs.srv import RunOfflineTask, SetInteger, SetJointEnable
from xarm_bridge.device import XArmDevice
from xarm_bridge.registers import COIL_PAUSED, COIL_STOPPED, ENABLE_FIRST
from xarm_bridge.sim import IN_MOTION, PAUSED, SLEEPING, STOPPED, XArmSimDevice, make_simulator

from ..core.sim.test_sim_strict import tcp_request
from ..support.fixtures import client_fixture
from ..support.ros import (
    WAIT_S,
    Bridge,
    Client,
    node_process,
    unique_namespace,
    values_of,
    wait_for,
)

ROOT = Path(__file__).resolve().parents[2]


@contextmanager
def arm() -> Iterator[tuple[XArmDevice, XArmSimDevice, Simulator]]:
    simulator = make_simulator()
    port = simulator.start_tcp()
    sim = simulator.device
    assert isinstance(sim, XArmSimDevice)
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    try:
        yield XArmDevice(DeviceChannel(link, 1, retries=0)), sim, simulator
    finally:
        link.close()
        simulator.stop()


def moving(sim: XArmSimDevice) -> None:
    """The arm runs a long offline task (state 1)."""
    with sim.lock:
        sim.task_seconds_left = 1000.0
        sim.set_state(IN_MOTION)


def is_halt_write(record: WriteRecord, coil: int, state: int) -> bool:
    if record.table is Table.COIL:
        return record.address == coil and record.values == (1,)
    return record.table is Table.HOLDING and record.address == 33 and record.values == (state,)


# ---------------------------------------------------------------- hole 2 (decision 19)
@pytest.mark.parametrize(
    ("kind", "coil", "state"), [("stop", COIL_STOPPED, 4), ("pause", COIL_PAUSED, 3)]
)
def test_a_halt_is_not_confirmed_by_the_coil_kept_as_written(
    kind: str, coil: int, state: int
) -> None:
    """A firmware that stores C145 / C144 and leaves the arm moving: the coil reads 1,
    H33 reads 1 (in motion). The old code took the coil for proof."""
    with arm() as (device, sim, simulator):
        sim.coils_as_written = True
        simulator.ignore([kind])
        moving(sim)
        with pytest.raises(NotConfirmed) as err:
            device.halt(kind)
        said = str(err.value)
        assert f"wrote C{coil} = 1 and H33 = {state}; reads " in said, said
        assert "state 1 (in motion)" in said and f"C{coil} " in said
        assert (sim.get("stopped") if kind == "stop" else sim.get("paused")) is True
        assert sim.arm_state == IN_MOTION
        assert [r.ignored for r in sim.write_log] == [True, True]


def test_a_pause_is_not_confirmed_by_state_2() -> None:
    """A task waiting on an input stands in state 2 and moves again when the input
    comes: a pause the arm ignored is not done because it reads 2."""
    with arm() as (device, sim, simulator):
        simulator.ignore(["pause"])
        with sim.lock:
            sim.task_seconds_left = 1000.0
            sim.set_state(SLEEPING)
        with pytest.raises(NotConfirmed, match=r"state 2 \(sleeping\)"):
            device.pause()


@pytest.mark.parametrize(
    ("kind", "coil", "state", "shown"),
    [("stop", COIL_STOPPED, 4, "state 4 (stopped)"), ("pause", COIL_PAUSED, 3, "state 3 (paused)")],
)
def test_on_firmware_that_ignores_the_coil_h33_goes_out_at_once(
    kind: str, coil: int, state: int, shown: str
) -> None:
    """The old code read the state back for 0.5 s before it sent H33 (13 cm at 250
    mm/s): now H33 follows the coil with no read in between."""
    with arm() as (device, sim, simulator):
        simulator.ignore([f"{kind}_coil"])
        sim.log_reads = True
        moving(sim)
        said = device.halt(kind)
        assert shown in said, said
        assert sim.arm_state == (STOPPED if kind == "stop" else PAUSED)
        first, second = sim.write_log[-2:]
        assert is_halt_write(first, coil, state) and first.ignored
        assert is_halt_write(second, coil, state) and not second.ignored
        between = [r for r in sim.read_log if first.time <= r.time <= second.time]
        assert between == [], between


def test_a_refused_stop_coil_does_not_hold_back_h33() -> None:
    with arm() as (device, sim, _):
        # A firmware that answers a write of C145 with exception 0x02.
        sim.write_guards.append(
            lambda r: 2 if r.table is Table.COIL and r.address == COIL_STOPPED else None
        )
        moving(sim)
        said = device.stop()
        assert "C145 = 1 (refused: " in said and "state 4 (stopped)" in said, said
        assert sim.arm_state == STOPPED


class _CoilReplyLost:
    """The arm's channel, but the reply to a coil write is lost after the write landed
    (a cable glitch on the way back): ``write_coil`` raises ``LinkTimeout``."""

    def __init__(self, io: DeviceChannel) -> None:
        self._io = io

    def write_coil(self, address: int, value: bool, **kwargs: object) -> None:
        self._io.write_coil(address, value, **kwargs)  # type: ignore[arg-type]
        raise LinkTimeout("no reply within 1.0 s")

    def __getattr__(self, name: str) -> object:
        return getattr(self._io, name)


@pytest.mark.parametrize("kind", ["stop", "pause"])
def test_a_lost_coil_reply_does_not_hold_back_h33(kind: str) -> None:
    with arm() as (device, sim, simulator):
        moving(sim)
        simulator.ignore([f"{kind}_coil"])  # the coil alone would not halt this arm
        device.io = _CoilReplyLost(device.io)  # type: ignore[assignment,arg-type]
        said = device.halt(kind)
        assert "(no reply: " in said and "H33 = " in said, said
        assert sim.arm_state == (STOPPED if kind == "stop" else PAUSED)


# ---------------------------------------------------------------- hole 5 (decision 20)
STARTS: list[tuple[str, Callable[[XArmDevice], object]]] = [
    ("resume", lambda d: d.resume()),
    ("set_state 0", lambda d: d.command_state(0)),
    ("run_offline_task", lambda d: d.run_offline_task([1])),
]


@pytest.mark.parametrize(("name", "start"), STARTS, ids=[name for name, _ in STARTS])
def test_a_start_on_an_arm_in_error_is_not_confirmed(
    name: str, start: Callable[[XArmDevice], object]
) -> None:
    with arm() as (device, sim, _):
        sim.set_error(22)
        with pytest.raises(NotConfirmed) as err:
            start(device)
        said = str(err.value)
        assert said.startswith("wrote ") and "state 4 (stopped), error 22 (collision error)" in said
        assert sim.arm_state == STOPPED


def test_starts_and_enables_the_arm_ignores_are_not_confirmed() -> None:
    with arm() as (device, sim, simulator):
        simulator.ignore(["start", "run_offline_task", "enable", "stop", "pause"])
        with pytest.raises(NotConfirmed, match=r"wrote projects 4 at H48; reads .*state 2"):
            device.run_offline_task([4])
        with sim.lock:
            sim.task_seconds_left = 1000.0
            sim.set_state(PAUSED)
        with pytest.raises(NotConfirmed, match=r"wrote H33 = 0; reads .*state 3 \(paused\)"):
            device.resume()
        moving(sim)
        with pytest.raises(NotConfirmed, match=r"wrote H33 = 4; reads .*state 1"):
            device.command_state(4)
        with pytest.raises(NotConfirmed, match=r"wrote H33 = 3; reads .*state 1"):
            device.command_state(3)
        with pytest.raises(NotConfirmed, match=rf"wrote C{ENABLE_FIRST}-141 = 0, reads 1 1 1"):
            device.set_joint_enable(0, False)
        assert all(r.ignored for r in sim.write_log) and sim.arm_state == IN_MOTION


# ---------------------------------------------------------------- item 1: the simulator
def test_every_motion_write_of_the_bridge_has_its_names() -> None:
    """The names xarm_sim --ignore takes, for each motion write xarm_bridge sends."""
    with arm() as (device, sim, _):
        device.stop()
        device.pause()
        device.resume()
        device.set_mode(1)
        device.set_joint_enable(2, False)
        device.set_joint_enable(2, True)
        device.run_offline_task([1])
        names = [sorted(sim.write_names(r)) for r in sim.write_log]
    assert names == [
        ["stop", "stop_coil"],
        ["stop", "stop_state"],
        ["pause", "pause_coil"],
        ["pause", "pause_state"],
        ["start"],
        ["mode"],
        ["enable"],
        ["enable"],
        ["run_offline_task"],
    ]
    assert set(XArmSimDevice.IGNORABLE) == {n for row in names for n in row}


def _sim_process(*args: str) -> tuple[subprocess.Popen[bytes], int, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "xarm_bridge.sim", "--port", "0", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline().decode()
    found = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
    assert found, line
    return proc, int(found.group(1)), line


def test_xarm_sim_ignores_and_keeps_coils_as_written_from_its_command_line() -> None:
    proc, port, banner = _sim_process("--ignore", "stop", "--coils-as-written")
    try:
        assert "ignores stop" in banner
        # C145 = 1 acknowledged (the echo), stored as written, the arm as it was.
        assert tcp_request(port, bytes.fromhex("05 0091 FF00")) == bytes.fromhex("05 0091 FF00")
        assert tcp_request(port, bytes.fromhex("01 0090 0002")) == bytes.fromhex("01 01 02")
        assert tcp_request(port, bytes.fromhex("03 0021 0001")) == bytes.fromhex("03 02 0002")
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(10)


def test_xarm_sim_refuses_an_unknown_name_in_one_line() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "xarm_bridge.sim", "--port", "0", "--ignore", "jog"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "unknown motion write jog; this simulator's names: " in lines[-1]
    assert "run_offline_task" in lines[-1]


# ---------------------------------------------------------------- item 4 (hole 12)
def test_fc06_reply_is_the_echo_of_the_request() -> None:
    """The manual's FC 06 example: "请求: 向地址位0x0020的寄存器写入0x0006", the reply
    repeats it. H32 takes the mode but reads the mode in force until set_state 0
    (decision 15): the old base built the reply by reading H32 back (mode 0)."""
    simulator = make_simulator()
    port = simulator.start_tcp()
    try:
        assert tcp_request(port, bytes.fromhex("06 0020 0006")) == bytes.fromhex("06 0020 0006")
        assert tcp_request(port, bytes.fromhex("03 0020 0001")) == bytes.fromhex("03 02 0000")
    finally:
        simulator.stop()


# ---------------------------------------------------------------- contract rows (ROS)
client = client_fixture("xarm_personality_client", diagnostics=True, log=True, scope="module")


@contextmanager
def node(client: Client, tmp_path: Path, port: int, **params: Any) -> Iterator[tuple[Bridge, Any]]:
    ns = unique_namespace("xarm_personality")
    bridge = Bridge(client, ns, "xarm_bridge", XArmState)
    values = {"port": port, "poll_rate_hz": 20.0, "timeout_s": 1.0, "reconnect_max_s": 1.0}
    values.update(params)
    with node_process("xarm_bridge.node", values, tmp_path, ["-r", f"__ns:={ns}"]) as proc:
        yield bridge, proc


@pytest.fixture
def rig(client: Client, tmp_path: Path) -> Iterator[tuple[Bridge, Any, XArmSimDevice, Simulator]]:
    simulator = make_simulator()
    port = simulator.start_tcp()
    sim = simulator.device
    assert isinstance(sim, XArmSimDevice)
    try:
        with node(client, tmp_path, port) as (bridge, proc):
            bridge.wait_connected(True, timeout=30)
            yield bridge, proc, sim, simulator
    finally:
        simulator.stop()


def _paused(sim: XArmSimDevice) -> None:
    with sim.lock:
        sim.task_seconds_left = 1000.0
        sim.set_state(PAUSED)


def _stopped(sim: XArmSimDevice) -> None:
    sim.set_state(STOPPED)


def _disabled_j1(sim: XArmSimDevice) -> None:
    with sim.lock:
        sim.set("enable_1", False)
        sim.set("brake_1", False)
        sim.enabled[0] = False


@dataclass(frozen=True)
class Row:
    """A service call against an arm that ignores ``ignored`` (and keeps C144 / C145
    as written with ``as_written``), standing as ``before`` leaves it; ``said`` is in
    the reply."""

    srv_type: Any
    name: str
    fields: dict[str, Any]
    ignored: list[str]
    as_written: bool
    before: Callable[[XArmSimDevice], None]
    said: str


ENABLE_ALL_OFF = {"joint": 0, "enable": False}
ROWS = [
    Row(Trigger, "stop", {}, ["stop"], False, moving, "wrote C145 = 1 and H33 = 4; reads"),
    Row(Trigger, "stop", {}, ["stop"], True, moving, "C145 stopped 1"),
    Row(Trigger, "pause", {}, ["pause"], False, moving, "wrote C144 = 1 and H33 = 3; reads"),
    Row(Trigger, "pause", {}, ["pause"], True, moving, "C144 paused 1"),
    Row(Trigger, "resume", {}, ["start"], False, _paused, "wrote H33 = 0; reads"),
    Row(SetInteger, "set_state", {"value": 0}, ["start"], False, _stopped, "state 4 (stopped)"),
    Row(SetInteger, "set_state", {"value": 3}, ["pause"], True, moving, "wrote H33 = 3; reads"),
    Row(SetInteger, "set_state", {"value": 4}, ["stop"], True, moving, "wrote H33 = 4; reads"),
    Row(RunOfflineTask, "run_offline_task", {"projects": [2]}, ["run_offline_task"], False,
        _stopped, "state 4"),
    Row(SetJointEnable, "set_joint_enable", ENABLE_ALL_OFF, ["enable"], False, moving,
        "reads 1 1 1 1 1 1 1"),
    Row(SetJointEnable, "set_joint_enable", {"joint": 1, "enable": True}, ["enable"], False,
        _disabled_j1, "wrote C135 = 1, reads 0"),
]  # fmt: skip


def test_no_success_for_a_motion_command_the_arm_does_not_show(
    rig: tuple[Bridge, Any, XArmSimDevice, Simulator],
) -> None:
    """Each way a service starts, stops or changes motion, against an arm that ignores
    that write (and keeps C144 / C145 as written): never success; the reply says what
    was written and what was read back."""
    bridge, _, sim, simulator = rig
    for row in ROWS:
        simulator.ignore([])
        sim.set_error(0)
        sim.set("stopped", False)
        sim.set("paused", False)
        sim.set_state(SLEEPING)
        sim.coils_as_written = row.as_written
        row.before(sim)
        simulator.ignore(row.ignored)
        written = len(sim.write_log)
        reply = bridge.call(row.srv_type, row.name, **row.fields)
        said = f"{row.name} {row.fields} ignoring {row.ignored}: {reply.message}"
        assert not reply.success, said
        assert "not confirmed: wrote " in reply.message and "reads " in reply.message, said
        assert row.said in reply.message, said
        late = sim.write_log[written:]
        assert late and all(r.ignored for r in late), (said, late)


def test_a_start_on_an_arm_in_error_is_not_done(
    rig: tuple[Bridge, Any, XArmSimDevice, Simulator],
) -> None:
    bridge, _, sim, _ = rig
    sim.set_error(22)
    starts: list[tuple[Any, str, dict[str, Any]]] = [
        (Trigger, "resume", {}),
        (SetInteger, "set_state", {"value": 0}),
        (RunOfflineTask, "run_offline_task", {"projects": [1]}),
    ]
    for srv_type, name, fields in starts:
        reply = bridge.call(srv_type, name, **fields)
        assert not reply.success, reply.message
        assert "error 22 (collision error)" in reply.message and "wrote " in reply.message


def _set_read_only(client: Client, bridge: Bridge) -> None:
    request = SetParameters.Request()
    request.parameters = [Parameter("read_only", value=True).to_parameter_msg()]
    reply = client.call(SetParameters, bridge.service("set_parameters"), request)
    assert reply.results[0].successful, reply.results[0].reason


def _deactivate(client: Client, bridge: Bridge) -> None:
    request = ChangeState.Request()
    request.transition.id = Transition.TRANSITION_DEACTIVATE
    assert client.call(ChangeState, bridge.service("change_state"), request).success


@pytest.mark.parametrize("how", ["deactivate", "sigint", "read_only"])
def test_a_halt_tries_its_stop_and_says_not_confirmed(
    client: Client, tmp_path: Path, how: str
) -> None:
    """An offline task started through the bridge; then the arm ignores every stop (and
    keeps C145 as written) and the node halts: the stop goes out (C145 and H33 = 4,
    logged ignored) and the node logs it "not confirmed"."""
    simulator = make_simulator()
    port = simulator.start_tcp()
    sim = simulator.device
    assert isinstance(sim, XArmSimDevice)
    try:
        with node(client, tmp_path, port) as (bridge, proc):
            bridge.wait_connected(True, timeout=30)
            reply = bridge.call(RunOfflineTask, "run_offline_task", projects=[1, 2, 3])
            assert reply.success, reply.message
            sim.coils_as_written = True
            simulator.ignore(["stop"])
            before = len(sim.write_log)
            halted = time.monotonic()
            if how == "sigint":
                proc.send_signal(signal.SIGINT)
                assert proc.wait(20) == 0
            elif how == "deactivate":
                _deactivate(client, bridge)
            else:
                _set_read_only(client, bridge)
            line = client.wait_log("xarm_bridge", "not confirmed", since=halted)
            assert "run_offline_task" in line.msg and "wrote C145 = 1 and H33 = 4" in line.msg
            late = [(r.table, r.address, r.values, r.ignored) for r in sim.write_log[before:]]
            assert late[:2] == [
                (Table.COIL, COIL_STOPPED, (1,), True),
                (Table.HOLDING, 33, (4,), True),
            ], late
            assert sim.arm_state == IN_MOTION
    finally:
        simulator.stop()


def test_a_round_trip_up_to_50_ms(client: Client, tmp_path: Path) -> None:
    """``--reply-delay-ms 0:50`` (TCP: the round trip drawn per request): the node
    connects at start, polls, reconnects after an outage, and a stop goes out at once:
    while the link is still marked down, and H33 = 4 right after C145."""
    port = free_port()
    simulator = make_simulator()
    simulator.set_round_trip(0.0, 0.05)
    simulator.start_tcp(port=port)
    sim = simulator.device
    assert isinstance(sim, XArmSimDevice)
    sim.log_reads = True
    started = time.monotonic()
    try:
        with node(client, tmp_path, port, timeout_s=0.5, reconnect_max_s=60.0) as (bridge, _):
            bridge.wait_connected(True, since=started, timeout=30)
            polled = time.monotonic()
            wait_for(
                lambda: len(client.received(bridge.joint_states, since=polled)) >= 5,
                WAIT_S,
                "five joint_states over the late link",
            )
            down = time.monotonic()
            simulator.stop()
            bridge.wait_connected(False, since=down)
            # The next probe seconds away: the stop must not wait for it.
            bridge.wait_diagnostic(
                2, down, port, where=lambda v: float(v["reconnect backoff (s)"]) >= 4.0
            )
            moving(sim)
            simulator.start_tcp(port=port)
            reply = bridge.call(Trigger, "stop")
            assert reply.success and "state 4 (stopped)" in reply.message, reply.message
            first, second = sim.write_log[-2:]
            assert is_halt_write(first, COIL_STOPPED, 4) and is_halt_write(second, COIL_STOPPED, 4)
            assert [r for r in sim.read_log if first.time <= r.time <= second.time] == []
            up = time.monotonic()
            bridge.wait_connected(True, since=down, timeout=90)
            client.wait_message(bridge.joint_states, since=up, timeout=90)
            status = bridge.wait_diagnostic(0, up, port, timeout=90)
            assert int(values_of(status)["reconnects"]) >= 1
    finally:
        simulator.stop()
