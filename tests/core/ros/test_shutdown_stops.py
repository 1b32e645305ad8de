"""Every motion the bridge starts, the bridge stops: also when it is told to exit.

The stepper has no watchdog of its own: a jogging motor runs until a stop coil or a limit
switch; a MOTEC drive without its lifeguard keeps the last speed. The bridge process gets
SIGINT (Ctrl-C) or SIGTERM while a motor moves under a stream whose deadman is far longer
than the test; the writes after the signal must be exactly the stop (the stepper: then
the motor's configured speed written back over the jog's, a plain register write).
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path

import pytest
from std_msgs.msg import Float64
from std_srvs.srv import SetBool

from bridge_core.wire.registers import Table
from motec_bridge.sim import make_simulator as make_motec_simulator
from msg_defs.action import StepperMoveBy
from msg_defs.msg import MotecState, StepperState
from msg_defs.srv import SetControlMode
from stepper_bridge.registers import STEPPER_MAP, motor_coil
from stepper_bridge.sim import StepperSimDevice

from ...support.fixtures import client_fixture
from ...support.ros import Bridge, Client, node_process, wait_for
from ...support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty
from ...support.sims import stepper_on_pty

pytestmark = pytest.mark.ros

BAUD = 115200
EXIT_TIMEOUT_S = 20.0


client = client_fixture("shutdown_client", scope="module")


@pytest.fixture
def sim() -> Iterator[tuple[StepperSimDevice, str]]:
    with stepper_on_pty(BAUD) as served:
        yield served


def stepper_params(port: str) -> dict[str, object]:
    return {
        "serial_port": port,
        "baudrate": BAUD,
        "poll_rate_hz": 20.0,
        "timeout_s": PTY_REPLY_TIMEOUT_S,  # a stalled pty must not cost the stop
        "command_timeout_s": 60.0,  # the deadman must not be what stops it
    }


@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM], ids=["int", "term"])
def test_exit_stops_a_jogging_motor(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path, signal_number: int
) -> None:
    device, port = sim
    params = stepper_params(port)
    b = Bridge(client, f"/shutdown_{signal_number}", "stepper_bridge", StepperState)
    extra = ["-r", f"__ns:={b.ns}"]
    with node_process("stepper_bridge.node", params, tmp_path, extra) as proc:
        b.wait_connected(True, timeout=30)
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_1/jog", 10)
        wait_for(lambda: jog.get_subscription_count() > 0, 30, "the jog subscription")
        jog.publish(Float64(data=300.0))
        client.wait_message(b.state, lambda m: m.running[0], timeout=30)
        writes_before = len(device.write_log)
        proc.send_signal(signal_number)
        assert proc.wait(EXIT_TIMEOUT_S) == 0
        stop_coil = motor_coil(1, "stop")
        late = [(r.table, r.address, r.values) for r in device.write_log[writes_before:]]
        speed_register = STEPPER_MAP["motor1_speed"].address
        assert late == [(Table.COIL, stop_coil, (1,)), (Table.HOLDING, speed_register, (60,))]
        assert device.motion[1] is None  # the simulated motor stands still


@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM], ids=["int", "term"])
def test_exit_stops_an_action_goals_motion(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path, signal_number: int
) -> None:
    """Ctrl-C or SIGTERM while a move_by goal runs: the motor's stop coil is the last
    write, the process ends at once (a goal's thread never holds the exit up)."""
    device, port = sim
    b = Bridge(client, f"/shutdown_goal_{signal_number}", "stepper_bridge", StepperState)
    with node_process(
        "stepper_bridge.node", stepper_params(port), tmp_path, ["-r", f"__ns:={b.ns}"]
    ) as proc:
        b.wait_connected(True, timeout=30)
        goal = StepperMoveBy.Goal()
        goal.distance = 0.4  # 400 mm at 5 mm/s: far longer than the test
        sent = client.send_goal(StepperMoveBy, f"{b.ns}/stepper_bridge/motor_1/move_by", goal)
        assert sent.accepted
        sent.wait_feedback(lambda f: f.running[0], timeout=30)
        writes_before = len(device.write_log)
        proc.send_signal(signal_number)
        assert proc.wait(EXIT_TIMEOUT_S) == 0
        late = [(r.table, r.address, r.values) for r in device.write_log[writes_before:]]
        assert late == [(Table.COIL, motor_coil(1, "stop"), (1,))]
        assert device.motion[1] is None
        sent.close()


@pytest.mark.parametrize("signal_number", [signal.SIGINT, signal.SIGTERM], ids=["int", "term"])
def test_exit_zeroes_a_motec_velocity_stream(
    client: Client, tmp_path: Path, signal_number: int
) -> None:
    """MOTEC in velocity control with no lifeguard (the default): the drive would keep
    turning at the last speed; the bridge writes 0xAE = 0 on its way out."""
    simulator = make_motec_simulator([1])
    drive = simulator.drive(1)
    with served_on_pty(simulator, BAUD) as bridge_end:
        namespace = f"/shutdown_motec_{signal_number}"
        params = {
            "serial_port": bridge_end,
            "baudrate": BAUD,
            "unit_ids": [1],
            "poll_rate_hz": 20.0,
            "timeout_s": PTY_REPLY_TIMEOUT_S,
            "command_timeout_s": 60.0,
        }
        state = f"{namespace}/motec_1/state"
        client.subscribe(MotecState, state)
        with node_process(
            "motec_bridge.node", params, tmp_path, ["-r", f"__ns:={namespace}"]
        ) as proc:
            client.wait_message(state, timeout=30)
            for name, srv, fields in (
                ("set_control_mode", SetControlMode, {"mode": SetControlMode.Request.VELOCITY}),
                ("enable", SetBool, {"data": True}),
            ):
                request = srv.Request()
                for key, value in fields.items():
                    setattr(request, key, value)
                reply = client.call(srv, f"{namespace}/motec_1/{name}", request, timeout=30)
                assert reply.success, reply.message
            pub = client.node.create_publisher(Float64, f"{namespace}/motec_1/cmd_velocity", 10)
            wait_for(lambda: pub.get_subscription_count() > 0, 30, "cmd_velocity")
            pub.publish(Float64(data=10.0))  # rad/s: ~95 rpm
            client.wait_message(state, lambda m: m.speed_actual_rpm > 50, timeout=30)
            writes_before = len(drive.write_log)
            proc.send_signal(signal_number)
            assert proc.wait(EXIT_TIMEOUT_S) == 0
            late = [(r.address, r.values) for r in drive.write_log[writes_before:]]
            assert late == [(0xAE, (0,))]
            client.node.destroy_publisher(pub)


def test_a_fatal_error_stops_the_motion_before_the_process_ends(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path
) -> None:
    """An error no callback handles (a bug) ends spin: the jog it left running is stopped
    on the wire, the process says so and exits 1 (tests/support/fatal_bridge.py)."""
    device, port = sim
    params = stepper_params(port)
    b = Bridge(client, "/shutdown_fatal", "stepper_bridge", StepperState)
    extra = ["-r", f"__ns:={b.ns}"]
    with node_process("tests.support.fatal_bridge", params, tmp_path, extra) as proc:
        b.wait_connected(True, timeout=30)
        jog = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_1/jog", 10)
        wait_for(lambda: jog.get_subscription_count() > 0, 30, "the jog subscription")
        jog.publish(Float64(data=300.0))
        assert proc.wait(EXIT_TIMEOUT_S) == 1
        client.node.destroy_publisher(jog)
    forward, stop = motor_coil(1, "forward"), motor_coil(1, "stop")
    coils = [r.address for r in device.write_log if r.table == Table.COIL]
    assert forward in coils and coils[-1] == stop, coils  # it ran, and the stop came last
    assert device.motion[1] is None
    log = (tmp_path / "tests_support_fatal_bridge.log").read_text()
    assert "fatal error: injected" in log and "stream 1: stopped" in log, log
