"""The stepper bridge against a controller that does not obey: the simulator's
``--ignore`` personality (stepper_bridge/sim.py ``IGNORABLE``) acknowledges a motion write
as the manual says and changes nothing. A command that starts, stops or changes motion is a
success only when the controller's own state, read back, shows it; otherwise the reply says
what was written and what was read back, and a halt still sends its stop and logs "not
confirmed".

Device rows: the device layer over a real socat pty pair (no ROS), 115200 baud and no reply
delay.
"""

from __future__ import annotations

import re
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from bench.line_relay import LineRelay
from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.serving import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import NotConfirmed
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings
from msg_defs.action import StepperMoveBy
from msg_defs.msg import MotionOutcome, StepperState
from msg_defs.srv import LineMove, MoveBy, SetInteger
from stepper_bridge.device import StepperDevice
from stepper_bridge.registers import (
    MOTORS,
    STEPPER_MAP,
    SYSTEM_COILS,
    coil,
    motor_coil,
    motor_register,
)
from stepper_bridge.sim import (
    IGNORABLE_MOTOR_COILS,
    IGNORABLE_SYSTEM_COILS,
    StepperSimDevice,
    make_simulator,
)

from ..support.fixtures import client_fixture
from ..support.ros import (
    WAIT_S,
    Bridge,
    Client,
    node_process,
    start_bridge,
    unique_namespace,
    wait_for,
    wait_subscribed,
)
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, socat_pair
from ..support.sims import stepper_on_pty
from .test_stepper_ros import COMMAND_TIMEOUT_S, bridge

BAUD = 115200
TRAVEL = 1000.0  # far beyond every motion here: no limit switch ends one
UNREACHED_TRAVEL = 1e6  # beyond a jog's reach in minutes
C, H = Table.COIL, Table.HOLDING


@dataclass
class Rig:
    sim: Simulator
    fake: StepperSimDevice
    device: StepperDevice

    def coils(self, since: int = 0) -> list[tuple[int, bool]]:
        """(coil address, ignored) of every coil written since write ``since``."""
        return [(r.address, r.ignored) for r in self.fake.write_log[since:] if r.table is C]


@pytest.fixture
def rig() -> Iterator[Rig]:
    sim = make_simulator(reply_delay_s=0.0, travel=TRAVEL)
    fake = sim.device
    assert isinstance(fake, StepperSimDevice)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        device = StepperDevice(DeviceChannel(link, 1, retries=0))
        device.read_config()
        try:
            yield Rig(sim, fake, device)
        finally:
            link.close()
            sim.stop()


def system_coil(name: str) -> int:
    return coil(SYSTEM_COILS[name])


def running_line(rig: Rig) -> None:
    """A slow line of pair 1 (motors 1+2) that runs for many seconds."""
    d = rig.device
    d.pair_reading = "type_rows"
    d.line_move(1, (1.0, 1.0), (200.0, 100.0), 60)
    wait_for(
        lambda: rig.fake.interpolation is not None and rig.fake.interpolation.phase == "path",
        WAIT_S,
        "the line on its path",
    )


# ---------------------------------------------------------------- hole 7: interpolation stop


def test_an_interpolation_stop_the_controller_ignores_still_stops_its_motors(rig: Rig) -> None:
    """The interpolation stop sent only the arc and line stop coils. A
    controller that does not obey them (here: acknowledges and ignores them) kept the
    pair moving while the bridge said "stopped". The motors' own stop coils follow, and
    their running flags are read back."""
    running_line(rig)
    rig.sim.ignore({"line_stop", "arc_stop"})
    mark = len(rig.fake.write_log)
    said = rig.device.stop_interpolation()
    assert rig.fake.interpolation is None and not any(rig.fake.motion.values())
    assert rig.coils(mark) == [
        (system_coil("arc_stop"), True),
        (system_coil("line_stop"), True),
        (motor_coil(1, "stop"), False),
        (motor_coil(2, "stop"), False),
    ]
    assert "running" in said and "40168" in said, said


def test_an_interpolation_stop_nothing_obeys_is_not_confirmed(rig: Rig) -> None:
    running_line(rig)
    rig.sim.ignore({"line_stop", "arc_stop", "stop"})
    mark = len(rig.fake.write_log)
    with pytest.raises(NotConfirmed) as err:
        rig.device.stop_interpolation()
    text = str(err.value)
    assert "wrote" in text and "00101" in text and "00103" in text and "00005" in text, text
    assert "read" in text and "40168" in text and "\n" not in text, text
    assert rig.fake.interpolation is not None  # still running: the reply says so
    assert all(ignored for _, ignored in rig.coils(mark))
    # The bridge still counts the line as running: a second line is refused meanwhile.
    assert rig.device.interpolation_run is not None


def test_every_motion_write_of_the_bridge_has_an_ignore_name() -> None:
    """stepper_sim's ``--ignore`` names: each coil and register the
    bridge starts, stops or changes motion with is one of them, on every motor."""
    fake = StepperSimDevice()

    def names(table: Table, address: int, values: tuple[int, ...] = (1,)) -> frozenset[str]:
        return fake.write_names(WriteRecord(0.0, 1, 5, table, address, values))

    for m in range(1, MOTORS + 1):
        for action, name in IGNORABLE_MOTOR_COILS.items():
            assert names(C, motor_coil(m, name)) == {action}
        for field, name in (("speed", "speed"), ("direction", "direction")):
            assert names(H, STEPPER_MAP[motor_register(m, field)].address, (1,)) == {name}
        distance = STEPPER_MAP[motor_register(m, "run_distance")].address
        assert names(H, distance, (1, 0)) == {"distance"}
    for name, system in IGNORABLE_SYSTEM_COILS.items():
        assert names(C, system_coil(system)) == {name}
    assert names(C, motor_coil(1, "stop"), (0,)) == frozenset()  # 0x0000: no command
    assert names(C, system_coil("save_parameters")) == frozenset()
    assert set(StepperSimDevice.IGNORABLE) == {
        *IGNORABLE_MOTOR_COILS,
        "speed",
        "direction",
        "distance",
        *IGNORABLE_SYSTEM_COILS,
    }


# ---------------------------------------------------------------- contract rows over ROS

MM = 0.001  # m per controller unit (units_per_meter 1000)
ROS_BAUD = 115200


client = client_fixture("stepper_personality_client", log=True)


@pytest.fixture
def sim() -> Iterator[tuple[StepperSimDevice, str]]:
    with stepper_on_pty(ROS_BAUD) as served:
        yield served


def not_confirmed(reply: Any, *texts: str) -> None:
    """Never success; the reply says what was written and what was read back."""
    assert not reply.success, reply.message
    assert "not confirmed: wrote " in reply.message and "; read " in reply.message, reply.message
    for text in texts:
        assert text in reply.message, reply.message


def ignored_coils(fake: StepperSimDevice, since: int) -> list[int]:
    return [r.address for r in fake.write_log[since:] if r.table is C and r.ignored]


def ok(b: Bridge, srv: Any, name: str, **fields: Any) -> Any:
    reply = b.call(srv, name, **fields)
    assert reply.success, f"{name}: {reply.message}"
    return reply


def runs(fake: StepperSimDevice, motor: int) -> None:
    wait_for(lambda: fake.motion[motor] is not None, WAIT_S, f"motor {motor} running")


def stands(fake: StepperSimDevice, motor: int) -> None:
    wait_for(lambda: fake.motion[motor] is None, WAIT_S, f"motor {motor} standing")


@pytest.mark.ros
def test_contract_services_against_ignored_writes(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path
) -> None:
    """Every service that starts, stops or changes motion, against a controller that
    acknowledges that write and ignores it: never success, and the reply says what was
    written and read back (stepper decision 23). Each once said "done"."""
    fake, port = sim
    fake.set("homing_order_1", 2)  # home_all homes motor 2
    with bridge(client, tmp_path, port) as (b, _proc):
        client.wait_message(b.state)

        def row(ignore: set[str], srv: Any, name: str, *texts: str, **fields: Any) -> None:
            fake.ignore = frozenset(ignore)
            mark = len(fake.write_log)
            try:
                not_confirmed(b.call(srv, name, **fields), *texts)
            finally:
                fake.ignore = frozenset()
            assert any(r.ignored for r in fake.write_log[mark:]), name

        for action, name, number in (
            ("forward", "forward", "00002"),
            ("reverse", "reverse", "00003"),
            ("run_once", "run", "00001"),
            ("home", "home", "00004"),
        ):
            row({name}, Trigger, f"motor_1/{action}", f"(coil {number} = ON)", "(40168) = 0")
        assert not any(fake.motion.values())
        row({"run"}, MoveBy, "motor_1/move_by", "(coil 00001 = ON)", distance=5 * MM)
        row(
            {"direction"},
            MoveBy,
            "motor_1/move_by",
            "= 1, motor 1 run distance (40009) = 5; read motor 1 direction (40005) = 0",
            distance=-5 * MM,
        )
        row({"distance"}, MoveBy, "motor_1/move_by", "run distance (40009) = 7", distance=7 * MM)
        assert not any(fake.motion.values())  # nothing ran on a direction or distance not held
        row(
            {"speed"},
            SetInteger,
            "motor_1/set_speed",
            "wrote motor 1 speed (40006) = 120; read motor 1 speed (40006) = 60",
            value=120,
        )

        # Stops of a running motor: its stop coil, the e-stop.
        ok(b, Trigger, "motor_2/forward")
        runs(fake, 2)
        row({"stop"}, Trigger, "motor_2/stop", "(coil 00010 = ON)", "(40169) = 1")
        row({"estop"}, Trigger, "emergency_stop", "(coil 00042 = ON)", "(40169) = 1")
        assert fake.motion[2] is not None
        ok(b, Trigger, "motor_2/stop")
        stands(fake, 2)
        # All-motor starts: motor 2 stands off 0 (return to zero) and off home (home_all).
        row({"to_zero"}, Trigger, "return_to_zero", "(coil 00045 = ON)")
        row({"home_all"}, Trigger, "home_all", "(coil 00046 = ON)")
        # Interpolation: its start, and a stop whose coils are all ignored.
        line = {"pair": 1, "start": [0.0, 0.0], "end": [0.2, 0.1], "speed_rpm": 60}
        row({"line_start"}, LineMove, "line_move", "line start (coil 00102 = ON)", **line)
        ok(b, LineMove, "line_move", **line)
        wait_for(lambda: fake.interpolation is not None, WAIT_S, "the line running")
        row(
            {"line_stop", "arc_stop", "stop"},
            Trigger,
            "stop_interpolation",
            "(coil 00101 = ON)",
            "(coil 00103 = ON)",
            "(coil 00005 = ON)",
            "(40168) = 1",
        )
        assert fake.interpolation is not None
        ok(b, Trigger, "stop_interpolation")
        assert fake.interpolation is None


@pytest.mark.ros
def test_contract_goals_against_ignored_writes(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path
) -> None:
    """Goals: a move_by whose single run is ignored is never REACHED and its result says
    what was written and read; a cancel whose stop is ignored ends CANCELLED with "not
    confirmed" and what was written and read (it once said "stop coil ... sent")."""
    fake, port = sim
    with bridge(client, tmp_path, port) as (b, _proc):
        client.wait_message(b.state)
        fake.ignore = frozenset({"run"})
        goal = b.send_goal(StepperMoveBy, "motor_1/move_by", distance=5 * MM)
        _status, result = goal.result()
        outcome = result.outcome
        assert outcome.code != MotionOutcome.REACHED, outcome.message
        assert "not confirmed: wrote " in outcome.message, outcome.message
        assert "(coil 00001 = ON)" in outcome.message and "(40168) = 0" in outcome.message
        fake.ignore = frozenset({"stop"})
        goal = b.send_goal(StepperMoveBy, "motor_1/move_by", distance=200 * MM)  # 40 s
        goal.wait_feedback(lambda f: f.running[0])
        mark = len(fake.write_log)
        goal.cancel()
        _status, result = goal.result()
        outcome = result.outcome
        assert outcome.code == MotionOutcome.CANCELLED, outcome.message
        assert not outcome.stop_sent, outcome.message
        assert "not confirmed: wrote motor 1 stop (coil 00005 = ON); read motor 1 running" in (
            outcome.message
        )
        assert ignored_coils(fake, mark) == [motor_coil(1, "stop")]
        assert fake.motion[1] is not None
        fake.ignore = frozenset()
        ok(b, Trigger, "motor_1/stop")


HELD_JOG_TIMEOUT_S = 30.0


def jog_publisher(client: Client, b: Bridge, motor: int) -> Any:
    pub = client.node.create_publisher(Float64, f"{b.ns}/stepper_bridge/motor_{motor}/jog", 10)
    wait_subscribed(pub)
    return pub


@pytest.mark.ros
def test_contract_stream_stops_against_an_ignored_stop(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path
) -> None:
    """A jog's 0, the jog deadman and the position stream's deadman against a controller
    that ignores the stop coil: each stop goes out (ignored in the write log), is logged
    "not confirmed", and is sent again until it shows (here: once the controller obeys)."""
    fake, port = sim
    with bridge(client, tmp_path, port) as (b, _proc):
        logger = f"{b.ns[1:]}.stepper_bridge"
        client.wait_message(b.state)
        jog = jog_publisher(client, b, 1)
        jog.publish(Float64(data=600.0))
        runs(fake, 1)
        fake.ignore = frozenset({"stop"})
        t = time.monotonic()
        jog.publish(Float64(data=0.0))
        client.wait_log(logger, "motor 1 jog 0.0 rpm: not confirmed: wrote motor 1 stop", t)
        # Silence: the stop is still pending, the deadman sends it again.
        client.wait_log(logger, "motor 1 jog 0.0 rpm (deadman): not confirmed: wrote", t)
        assert fake.motion[1] is not None
        fake.ignore = frozenset()
        stands(fake, 1)  # the deadman's next try is obeyed

        # The jog deadman of a jog never stopped by a 0.
        jog3 = jog_publisher(client, b, 3)
        jog3.publish(Float64(data=600.0))
        runs(fake, 3)
        fake.ignore = frozenset({"stop"})
        t = time.monotonic()
        client.wait_log(logger, "motor 3 jog 0.0 rpm (deadman): not confirmed: wrote motor 3", t)
        assert fake.motion[3] is not None
        fake.ignore = frozenset()
        stands(fake, 3)

        # ~/joint_commands: a position target whose run distance is ignored is refused
        # "not confirmed" (nothing runs); the position stream's deadman against an
        # ignored stop says "not confirmed" too.
        pub = client.node.create_publisher(JointState, f"{b.ns}/stepper_bridge/joint_commands", 10)
        wait_subscribed(pub)
        fake.ignore = frozenset({"distance"})
        t = time.monotonic()
        pub.publish(JointState(name=["motor_4"], position=[0.007]))
        client.wait_log(
            logger, "; read motor 4 direction (40035) = 0, motor 4 run distance (40039) = 10", t
        )
        assert fake.motion[4] is None
        fake.ignore = frozenset({"stop"})
        t = time.monotonic()
        pub.publish(JointState(name=["motor_4"], position=[0.09]))  # 18 s away
        runs(fake, 4)
        client.wait_log(logger, "motor 4 position stream (deadman): not confirmed: wrote", t)
        fake.ignore = frozenset()
        stands(fake, 4)
        for publisher in (jog, jog3, pub):
            client.node.destroy_publisher(publisher)


def transition(client: Client, b: Bridge, transition_id: int) -> None:
    request = ChangeState.Request()
    request.transition.id = transition_id
    reply = client.call(ChangeState, f"{b.ns}/stepper_bridge/change_state", request)
    assert reply.success


def set_read_only(client: Client, b: Bridge, value: bool) -> None:
    request = SetParameters.Request()
    request.parameters = [Parameter("read_only", value=value).to_parameter_msg()]
    reply = client.call(SetParameters, f"{b.ns}/stepper_bridge/set_parameters", request)
    assert reply.results[0].successful, reply.results[0].reason


@pytest.mark.ros
def test_contract_halts_against_an_ignored_stop(
    sim: tuple[StepperSimDevice, str], client: Client, tmp_path: Path
) -> None:
    """Deactivate, read_only and exit with a motor a service set running, one a jog set
    running and a move_by goal running, against a controller that ignores the stop coil:
    every stop still goes out (the write log: ignored) and each is logged "not
    confirmed" (it once said "stopped")."""
    fake, port = sim
    # Motor 2 jogs at 50 units/s in each of three rounds: on a loaded machine it once ran
    # into the 500-unit limit switch before the last round's stops went out.
    fake.travel = UNREACHED_TRAVEL

    def start_all(b: Bridge) -> tuple[Any, Any]:
        ok(b, Trigger, "motor_1/forward")
        jog = jog_publisher(client, b, 2)
        # The halt and stop before locked the jog: a 0 unlocks it (silence never does);
        # taken before the next message (a depth-1 subscription).
        jog.publish(Float64(data=0.0))
        time.sleep(0.3)
        jog.publish(Float64(data=600.0))
        goal = b.send_goal(StepperMoveBy, "motor_3/move_by", distance=200 * MM)
        for motor in (1, 2, 3):
            runs(fake, motor)
        goal.wait_feedback(lambda f: f.running[2])
        fake.ignore = frozenset({"stop"})
        return jog, goal

    def all_stops_ignored(mark: int) -> None:
        stops = {motor_coil(m, "stop") for m in (1, 2, 3)}
        wait_for(
            lambda: stops <= set(ignored_coils(fake, mark)), WAIT_S, "the three stops, ignored"
        )
        ended = [m for m in (1, 2, 3) if fake.motion[m] is None]
        assert not ended, f"motors {ended} stopped: positions {fake.position}"

    def obey_and_stop(b: Bridge, jog: Any) -> None:
        fake.ignore = frozenset()
        for motor in (1, 2, 3):
            ok(b, Trigger, f"motor_{motor}/stop")
        client.node.destroy_publisher(jog)

    namespace = unique_namespace("stepper_personality")
    b = Bridge(client, namespace, "stepper_bridge", StepperState)
    params = {
        "serial_port": port,
        "baudrate": ROS_BAUD,
        "poll_rate_hz": 20.0,
        "timeout_s": PTY_REPLY_TIMEOUT_S,  # a stalled pty must not cost a stop the link
        "reconnect_max_s": 1.0,
        # The jog is published once: its deadman must not stop motor 2 before the stops are
        # ignored (a loaded machine took longer than COMMAND_TIMEOUT_S to get there).
        "command_timeout_s": HELD_JOG_TIMEOUT_S,
    }
    with node_process(
        "stepper_bridge.node", params, tmp_path, ["-r", f"__ns:={namespace}"]
    ) as proc:
        logger = f"{b.ns[1:]}.stepper_bridge"
        client.wait_message(b.state)
        for halt in ("deactivate", "read_only"):
            jog, goal = start_all(b)
            mark, t = len(fake.write_log), time.monotonic()
            if halt == "deactivate":
                transition(client, b, Transition.TRANSITION_DEACTIVATE)
            else:
                set_read_only(client, b, True)
            all_stops_ignored(mark)
            client.wait_log(logger, "motor 1 forward: its stop went out, not confirmed", t)
            client.wait_log(logger, "stream 2: its stop went out, not confirmed: wrote", t)
            _status, result = goal.result()
            assert result.outcome.code == MotionOutcome.HALTED, result.outcome.message
            assert "not confirmed: wrote motor 3 stop" in result.outcome.message
            if halt == "deactivate":
                transition(client, b, Transition.TRANSITION_ACTIVATE)
            else:
                set_read_only(client, b, False)
            obey_and_stop(b, jog)

        jog, goal = start_all(b)
        mark = len(fake.write_log)
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
        all_stops_ignored(mark)
    log = (tmp_path / "stepper_bridge_node.log").read_text(errors="replace")
    exiting = [line for line in log.splitlines() if "not confirmed" in line]
    assert any(
        "motor 1 forward: its stop went out, not confirmed (the node is exiting)" in line
        for line in exiting
    ), log[-3000:]
    assert any("stream 2: its stop went out, not confirmed" in line for line in exiting), log


# ---------------------------------------------------------------- delay rows

LINE_BAUD = 9600  # the manual's (§3), on the byte-timed line: a 49-register reply ~107 ms
# Replies 35-300 ms after each request, drawn per reply: all within timeout_s 0.5 with the
# frames at 9600 baud (8 bytes out, at most 103 back: 0.3 + 0.11 s), most of them later
# than the short wait (0.15 s, the reply timeout floor) a request to a controller marked
# down used to get.
DELAY_S = (0.035, 0.3)
DELAY_TIMEOUT_S = 0.5
# Every wait on this line is long: a poll is three requests of up to ~0.4 s each, the
# configuration read whole (several more) comes first after every (re)connect.
SLOW_WAIT_S = 3 * WAIT_S


@pytest.mark.ros
def test_delay_a_controller_answering_late_connects_polls_reconnects_and_stops_at_once(
    client: Client, tmp_path: Path
) -> None:
    """A controller answering 35-300 ms after each request on a byte-timed line at 9600
    baud (the bench's relay: a pty hands over a 103-byte reply at once, the wire takes
    ~107 ms), timeout_s 0.5: the node connects at start, polls, reconnects after an
    outage, and a stop goes out at once (at most the reads on the line ahead of it).
    Before hole 1's fix every request while the link was down waited 0.15 s: the node
    connected only when a whole start-up read happened to answer within it."""
    sim = make_simulator(1)
    sim.set_reply_delay(*DELAY_S)
    fake = sim.device
    assert isinstance(fake, StepperSimDevice)
    units = dict(sim.devices)
    with LineRelay(LINE_BAUD) as line:
        sim.start_serial(line.device_path, LINE_BAUD)
        try:
            params = {
                "serial_port": line.client_path,
                "baudrate": LINE_BAUD,
                "poll_rate_hz": 2.0,
                "timeout_s": DELAY_TIMEOUT_S,
                "reconnect_max_s": 1.0,
                "command_timeout_s": COMMAND_TIMEOUT_S,
            }
            with start_bridge(
                client, tmp_path, "stepper_bridge.node", "stepper_bridge", StepperState, params
            ) as (b, proc):
                b.wait_connected(True, timeout=SLOW_WAIT_S)  # at start
                t = time.monotonic()
                wait_for(
                    lambda: len(client.received(b.state, t)) >= 3, SLOW_WAIT_S, "3 polls"
                )  # polls
                sim.devices = {}  # the controller goes silent
                b.wait_connected(False, timeout=SLOW_WAIT_S)
                sim.devices = units
                b.wait_connected(True, timeout=SLOW_WAIT_S)  # reconnected
                t = time.monotonic()
                wait_for(lambda: len(client.received(b.state, t)) >= 3, SLOW_WAIT_S, "3 polls")
                ok(b, Trigger, "motor_1/forward")
                runs(fake, 1)
                with client.service_client(Trigger, b.service("motor_1/stop")) as stop:
                    fake.log_reads = True
                    called = time.time()
                    future = stop.call_async(Trigger.Request())
                    wait_for(future.done, SLOW_WAIT_S, "the stop's reply")
                reply = future.result()
                assert reply.success, reply.message
                (coil_write,) = [r for r in fake.write_log if r.table is C and r.time >= called][:1]
                assert coil_write.address == motor_coil(1, "stop")
                ahead = [r for r in fake.read_log if called <= r.time <= coil_write.time]
                # The read on the line when the call came, and one begun before the node
                # had the request; the polls queued meanwhile go after the stop.
                assert len(ahead) <= 2, ahead
                assert proc.poll() is None
        finally:
            sim.stop()
    # No request to the late controller was given less than timeout_s: before hole 1's fix
    # the start-up reads and the probes after the outage waited 0.15 s ("cannot reach
    # ...: no reply within 0.15 s; retrying") and a connection came only by chance.
    log = (tmp_path / "stepper_bridge_node.log").read_text(errors="replace")
    waits = [float(w) for w in re.findall(r"no reply within ([\d.]+) s", log)]
    assert all(w >= DELAY_TIMEOUT_S for w in waits), [
        line for line in log.splitlines() if "no reply within" in line
    ][:5]
