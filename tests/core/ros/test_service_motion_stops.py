"""Every motion the bridge starts, the bridge stops: also one a service started.

A fire-and-forget service (the R6's ``~/start``, the xArm's ``~/run_offline_task``, a
MOTEC drive's ``~/move``, a stepper motor's ``~/motor_<n>/forward``) sets the device
moving; then the node is deactivated or gets SIGINT. The halt must stop that motion on
the wire (the node's motion ledger, ``bridge_core/runtime/motion_ledger.py``), and the simulated
device must stand still. A stop service in between means nothing is left to stop.

Every SIGINT exit here is also a clean one: no ERROR line, no callback error
left uncollected ("The following exception was never retrieved"), no traceback. With
nothing left to stop, the TCP simulators close their end with the same Ctrl-C, as the
demo cell's do (launch/cell.launch.py): a link the exit closes is not an error.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from std_srvs.srv import SetBool, Trigger

from bridge_core.sim.logs import WriteRecord
from bridge_core.wire.registers import Table
from motec_bridge.sim import MotecSimDrive
from msg_defs.msg import MotecState, R6State, StepperState, XArmState
from msg_defs.srv import PositionMove, RunOfflineTask, SetControlMode
from r6_bridge.registers import COMMANDS
from r6_bridge.sim import R6SimDevice
from r6_bridge.sim import make_simulator as make_r6
from stepper_bridge.registers import motor_coil
from stepper_bridge.sim import StepperSimDevice
from xarm_bridge.registers import COIL_STOPPED
from xarm_bridge.sim import IN_MOTION, XArmSimDevice
from xarm_bridge.sim import make_simulator as make_xarm

from ...support.fixtures import client_fixture
from ...support.ros import (
    WAIT_S,
    Bridge,
    Client,
    exit_complaints,
    node_log,
    node_process,
    unique_namespace,
    wait_for,
)
from ...support.serial_pair import PTY_REPLY_TIMEOUT_S
from ...support.sims import motec_on_pty, stepper_on_pty

pytestmark = pytest.mark.ros

BAUD = 115200
EXIT_TIMEOUT_S = 20.0
# Replies delayed this long until the start's write: the R6 start is on the wire for a
# while (its readiness reads, about seven of them: ~3 s in all).
IN_FLIGHT_DELAY_S = 0.4
# The start's guards pass at once; its readiness read then waits the reply delay: the
# deactivate is sent this long after the start, inside that window.
IN_FLIGHT_LEAD_S = 0.3


client = client_fixture("service_motion_client", scope="module")


@dataclass
class Rig:
    """One bridge against its simulator: how to start a motion and what shows it."""

    bridge: Bridge
    proc: Any
    start: Callable[[], None]  # the service call that sets the device moving
    stop_service: Callable[[], None]  # the stop service
    moving: Callable[[], bool]
    writes: Callable[[], list[WriteRecord]]
    is_stop: Callable[[WriteRecord], bool]
    log: Path  # the node process's output
    # The simulator closes its end at once (TCP), as the cell's simulators do on Ctrl-C.
    device_exits: Callable[[], None] | None = None


def halt(client: Client, rig: Rig, how: str, *, device_exits: bool = False) -> None:
    """Deactivate, or SIGINT (then, with ``device_exits``, the simulator goes too): a
    SIGINT exit ends with code 0 and prints no ERROR, traceback or uncollected error."""
    if how == "sigint":
        since = rig.log.stat().st_size
        rig.proc.send_signal(signal.SIGINT)
        if device_exits and rig.device_exits is not None:
            rig.device_exits()
        assert rig.proc.wait(EXIT_TIMEOUT_S) == 0
        assert exit_complaints(rig.log, since) == []
        return
    request = ChangeState.Request()
    request.transition.id = Transition.TRANSITION_DEACTIVATE
    reply = client.call(ChangeState, rig.bridge.service("change_state"), request)
    assert reply.success


@contextmanager
def r6_rig(client: Client, tmp_path: Path) -> Iterator[Rig]:
    simulator = make_r6(axis_count=6)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    ns = unique_namespace("service_motion_r6")
    bridge = Bridge(client, ns, "r6_bridge", R6State)
    try:
        with node_process(
            "r6_bridge.node", {"port": port, "poll_rate_hz": 20.0}, tmp_path, ["-r", f"__ns:={ns}"]
        ) as proc:
            bridge.wait_connected(True, timeout=30)
            yield Rig(
                bridge,
                proc,
                start=lambda: _ok(bridge.call(Trigger, "start")),
                stop_service=lambda: _ok(bridge.call(Trigger, "stop")),
                moving=lambda: device.running,
                writes=lambda: list(device.write_log),
                is_stop=lambda r: r.address == COMMANDS["pause"],
                log=node_log(tmp_path, "r6_bridge.node"),
                device_exits=simulator.stop,
            )
    finally:
        simulator.stop()


@contextmanager
def xarm_rig(client: Client, tmp_path: Path) -> Iterator[Rig]:
    simulator = make_xarm(7)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, XArmSimDevice)
    ns = unique_namespace("service_motion_xarm")
    bridge = Bridge(client, ns, "xarm_bridge", XArmState)
    try:
        with node_process(
            "xarm_bridge.node",
            {"port": port, "poll_rate_hz": 20.0, "timeout_s": 1.0},
            tmp_path,
            ["-r", f"__ns:={ns}"],
        ) as proc:
            bridge.wait_connected(True, timeout=30)
            yield Rig(
                bridge,
                proc,
                start=lambda: _ok(bridge.call(RunOfflineTask, "run_offline_task", projects=[1])),
                stop_service=lambda: _ok(bridge.call(Trigger, "stop")),
                moving=lambda: device.arm_state == IN_MOTION,
                writes=lambda: list(device.write_log),
                is_stop=lambda r: r.table == Table.COIL and r.address == COIL_STOPPED,
                log=node_log(tmp_path, "xarm_bridge.node"),
                device_exits=simulator.stop,
            )
    finally:
        simulator.stop()


@contextmanager
def motec_rig(client: Client, tmp_path: Path) -> Iterator[Rig]:
    with motec_on_pty([1], BAUD) as (simulator, port):
        drive: MotecSimDrive = simulator.drive(1)
        ns = unique_namespace("service_motion_motec")
        bridge = Bridge(client, ns, "motec_1", MotecState)
        params = {
            "serial_port": port,
            "baudrate": BAUD,
            "unit_ids": [1],
            "poll_rate_hz": 20.0,
            "timeout_s": PTY_REPLY_TIMEOUT_S,  # a stalled pty must not cost a stop
        }
        with node_process("motec_bridge.node", params, tmp_path, ["-r", f"__ns:={ns}"]) as proc:
            client.wait_message(bridge.state, timeout=30)
            mode = SetControlMode.Request.POSITION
            _ok(bridge.call(SetControlMode, "set_control_mode", mode=mode))
            _ok(bridge.call(SetBool, "enable", data=True))
            yield Rig(
                bridge,
                proc,
                start=lambda: _ok(
                    bridge.call(
                        PositionMove, "move", position=500.0, relative=True, max_velocity=20.0
                    )
                ),
                stop_service=lambda: _ok(bridge.call(Trigger, "stop")),
                moving=lambda: drive.move is not None,
                writes=lambda: list(drive.write_log),
                is_stop=lambda r: r.address == 0x29 and r.values == (0,),
                log=node_log(tmp_path, "motec_bridge.node"),
            )


@contextmanager
def stepper_rig(client: Client, tmp_path: Path) -> Iterator[Rig]:
    with stepper_on_pty(BAUD) as (device, port):
        assert isinstance(device, StepperSimDevice)
        ns = unique_namespace("service_motion_stepper")
        bridge = Bridge(client, ns, "stepper_bridge", StepperState)
        params = {
            "serial_port": port,
            "baudrate": BAUD,
            "poll_rate_hz": 20.0,
            "timeout_s": PTY_REPLY_TIMEOUT_S,
        }
        with node_process("stepper_bridge.node", params, tmp_path, ["-r", f"__ns:={ns}"]) as proc:
            bridge.wait_connected(True, timeout=30)
            yield Rig(
                bridge,
                proc,
                start=lambda: _ok(bridge.call(Trigger, "motor_3/forward")),
                stop_service=lambda: _ok(bridge.call(Trigger, "motor_3/stop")),
                moving=lambda: device.motion[3] is not None,
                writes=lambda: list(device.write_log),
                is_stop=lambda r: r.table == Table.COIL and r.address == motor_coil(3, "stop"),
                log=node_log(tmp_path, "stepper_bridge.node"),
            )


RIGS = {"r6": r6_rig, "xarm": xarm_rig, "motec": motec_rig, "stepper": stepper_rig}


def _ok(reply: Any) -> None:
    assert reply.success, reply.message


@pytest.mark.parametrize("how", ["sigint", "deactivate"])
@pytest.mark.parametrize("kind", sorted(RIGS))
def test_a_halt_stops_what_a_service_started(
    client: Client, tmp_path: Path, kind: str, how: str
) -> None:
    with RIGS[kind](client, tmp_path) as rig:
        rig.start()
        wait_for(rig.moving, WAIT_S, f"the {kind} moving")
        before = len(rig.writes())
        halt(client, rig, how)
        late = rig.writes()[before:]
        assert any(rig.is_stop(r) for r in late), f"no stop written by the {how}: {late}"
        wait_for(lambda: not rig.moving(), WAIT_S, f"the {kind} standing still")


@pytest.mark.parametrize("kind", sorted(RIGS))
def test_a_motion_its_stop_service_ended_is_not_stopped_again(
    client: Client, tmp_path: Path, kind: str
) -> None:
    with RIGS[kind](client, tmp_path) as rig:
        rig.start()
        wait_for(rig.moving, WAIT_S, f"the {kind} moving")
        rig.stop_service()
        wait_for(lambda: not rig.moving(), WAIT_S, f"the {kind} standing still")
        before = len(rig.writes())
        # A stop sent again to a simulator already gone would be an ERROR ("its stop
        # failed"), which halt() refuses as well.
        halt(client, rig, "sigint", device_exits=True)
        late = rig.writes()[before:]
        assert not any(rig.is_stop(r) for r in late), f"a stop sent again: {late}"


def test_a_start_on_the_wire_when_the_node_deactivates_is_stopped(
    client: Client, tmp_path: Path
) -> None:
    """The R6's ``~/start`` reads its readiness rows, then writes 20003. A deactivate that
    comes while it runs (replies delayed 1 s) has nothing to stop yet; the start's write
    goes out after the halt's stops. The command sees the halt when it ends and stops what
    it started (pause 20001 after the 20003), and its reply says so."""
    simulator = make_r6(axis_count=6)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    ns = unique_namespace("service_motion_inflight")
    bridge = Bridge(client, ns, "r6_bridge", R6State)
    try:
        with node_process(
            "r6_bridge.node",
            {"port": port, "poll_rate_hz": 20.0, "timeout_s": 2.0},
            tmp_path,
            ["-r", f"__ns:={ns}"],
        ):
            bridge.wait_connected(True, timeout=30)
            start = client.node.create_client(Trigger, bridge.service("start"))
            change = client.node.create_client(ChangeState, bridge.service("change_state"))
            for service in (start, change):
                wait_for(service.service_is_ready, WAIT_S, "the node's services")
            simulator.reply_delay_s = IN_FLIGHT_DELAY_S
            started = start.call_async(Trigger.Request())
            time.sleep(IN_FLIGHT_LEAD_S)  # orders the two requests; nothing is judged by it
            request = ChangeState.Request()
            request.transition.id = Transition.TRANSITION_DEACTIVATE
            changed = change.call_async(request)
            # Once the start's write is on the wire the race is run: what follows (its
            # read-back, the halt's stop of it) needs no slow device, only time.
            wait_for(
                lambda: (
                    started.done() or COMMANDS["start"] in [r.address for r in device.write_log]
                ),
                WAIT_S * 2,
                "the start's write",
            )
            simulator.reply_delay_s = 0.0
            wait_for(lambda: started.done() and changed.done(), WAIT_S * 2, "both replies")
            assert changed.result().success
            reply = started.result()
            if "not active" in reply.message:
                pytest.skip("the deactivate came before the start's turn: no race this time")
            addresses = [r.address for r in device.write_log]
            assert COMMANDS["start"] in addresses, addresses
            after = addresses[addresses.index(COMMANDS["start"]) :]
            assert COMMANDS["pause"] in after, f"the start was not stopped: {addresses}"
            assert not reply.success and "went out while the node halted" in reply.message
            wait_for(lambda: not device.running, WAIT_S, "the program paused")
    finally:
        simulator.stop()
