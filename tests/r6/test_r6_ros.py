"""The R6 bridge node in its own process, driven by an rclpy client in this one.

The simulator runs in this process (a real pymodbus TCP server on a thread), so the tests
can set registers and read its write log; the fault test runs it as a separate process
to kill it for real.
"""

from __future__ import annotations

import bisect
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from std_srvs.srv import Trigger

from bridge_core.sim.serving import Simulator
from bridge_core.wire.ports import free_port
from bridge_core.wire.registers import Table
from msg_defs.msg import R6State
from msg_defs.srv import (
    ClearAlarmAndNext,
    ListCounters,
    ReadCounter,
    ReadDataSource,
    ReadParameter,
    SetCounter,
    SetOutput,
    SetOutputBoard,
    SetValue,
    UploadPoints,
    WriteParameter,
)
from r6_bridge.registers import COMMANDS, R6_MAP
from r6_bridge.sim import R6SimDevice, make_simulator

from ..support.fixtures import client_fixture
from ..support.ros import WAIT_S, Client, start_bridge, values_of, wait_for

pytestmark = pytest.mark.ros

# Far above what scheduling on a loaded machine can delay a reply by: only the faults a
# test makes may look like a dead device.
TIMEOUT_S = 1.0
# The simulated controller's extra time over the world block and over the axis positions
# (stamp test): fifty times a request's ~2 ms, far below TIMEOUT_S.
BLOCK_DELAY_S = 0.1
STAMP_POLLS = 5  # polls collected on each topic
STAMP_SLACK_S = 0.001  # clock reading and float rounding between two processes' stamps


client = client_fixture(diagnostics=True, scope="module")
# Statuses every 0.25 s: the tests wait for a level or a count in them one after another.
DIAGNOSTIC_PERIOD_S = 0.25


@pytest.fixture
def simulator() -> Iterator[tuple[Simulator, int]]:
    """The R6 simulator serving TCP on this machine, and its port."""
    simulator = make_simulator(axis_count=6, io_board_count=2)
    port = simulator.start_tcp()
    yield simulator, port
    simulator.stop()


@pytest.fixture
def sim(simulator: tuple[Simulator, int]) -> tuple[R6SimDevice, int]:
    device = simulator[0].device
    assert isinstance(device, R6SimDevice)
    return device, simulator[1]


@pytest.fixture
def bridge_factory(client: Client, tmp_path: Path):  # type: ignore[no-untyped-def]
    def start(port: int, **params: Any):  # type: ignore[no-untyped-def]
        defaults = {
            "port": port,
            "poll_rate_hz": 50.0,
            "timeout_s": TIMEOUT_S,
            "reconnect_max_s": 1.0,
            "diagnostic_period_s": DIAGNOSTIC_PERIOD_S,
        }
        defaults.update(params)
        return start_bridge(client, tmp_path, "r6_bridge.node", "r6_bridge", R6State, defaults)

    return start


def test_topics_carry_si_values(sim, bridge_factory, client: Client) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    device.set("axis_position_1", 90.0)
    device.set("axis_position_2", -45.0)
    device.set("axis_speed_1", 60)
    device.set("axis_torque_1", 0.5)
    device.set("io_board_input_1", 0x0001_0002)
    device.set_alarm(0x325)
    device.tick = lambda dt: None  # freeze the world pose the sim would derive from the axes
    device.set("world_x", 1000.0)
    device.set("world_y", -250.5)
    device.set("world_z", 300.0)
    device.set("world_w", 90.0)
    device.set("world_m7", 12.5)
    device.set("world_m8", -3.25)
    started = time.monotonic()
    with bridge_factory(
        port,
        gear_ratios=[2.0] * 8,
        rated_torques=[10.0] * 8,
        frame_id="r6_base",
        extra_world_axes=2,
    ) as (bridge, _):
        js = client.wait_message(bridge.joint_states)
        assert js.name == [f"joint_{i}" for i in range(1, 7)]
        assert js.position[0] == pytest.approx(math.pi / 2) and js.position[1] == pytest.approx(
            -math.pi / 4
        )
        assert js.velocity[0] == pytest.approx(60 * 2 * math.pi / 60 / 2.0)
        assert js.effort[0] == pytest.approx(0.5 * 10.0, abs=0.01)
        stamp = js.header.stamp.sec + js.header.stamp.nanosec * 1e-9
        assert abs(stamp - time.time()) < 5.0
        state = client.wait_message(bridge.state)
        assert (state.mode, state.mode_name, state.alarm_code) == (2, "auto", 0x325)
        assert state.global_speed_percent == pytest.approx(50.0)
        assert state.axis_count == 6 and state.io_board_count == 2
        assert list(state.io_board_inputs) == [0, 0x0001_0002] and len(state.io_board_outputs) == 2
        assert state.homed and not state.moving and state.machine_id == 1
        assert list(state.world_extra) == pytest.approx([12.5, -3.25])  # M7, M8
        pose = client.wait_message(bridge.pose)
        assert pose.header.frame_id == "r6_base"
        assert (pose.pose.position.x, pose.pose.position.y, pose.pose.position.z) == pytest.approx(
            (1.0, -0.2505, 0.3)
        )
        q = pose.pose.orientation
        assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
        bridge.wait_connected(True)
        status = bridge.wait_diagnostic(1, started, port)  # WARN: the alarm
        info = values_of(status)
        assert status.hardware_id == f"Huacheng R6@tcp://127.0.0.1:{port} unit 1"
        assert info["firmware version"] == "AM8-QC-RXE-7.8.02-bate7_FAKE_TGF_ENCODER"
        assert info["link state"] == "connected" and "805" in info["alarm code"]
        assert float(info["achieved poll rate (Hz)"]) > 0
        device.set_alarm(0)
        bridge.wait_diagnostic(0, time.monotonic(), port)


def test_every_service_writes_its_registers(sim, bridge_factory) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge_factory(port) as (bridge, _):
        bridge.wait_connected(True)
        for name, address in COMMANDS.items():
            if name.startswith("clear_alarm"):
                device.set_alarm(0x325)  # decision 23: only with an alarm to clear
            before = len(device.write_log)
            if name == "clear_alarm_and_next":
                reply = bridge.call(ClearAlarmAndNext, name, skip_failed_step=True)
            else:
                reply = bridge.call(Trigger, name)
            assert reply.success, reply.message
            new = device.write_log[before:]
            assert [(r.function_code, r.address, r.values) for r in new] == [(6, address, (1,))], (
                name
            )
        device.write_log.clear()
        assert bridge.call(SetValue, "set_global_speed", value=25.5).success
        assert bridge.call(SetOutput, "set_output", board=0, index=5, state=True).success
        reply = bridge.call(
            SetOutputBoard, "set_board_outputs", board=1, bits=0x8000_0001, mask=0xFFFF_FFFF
        )
        assert reply.success, reply.message
        reply = bridge.call(SetCounter, "set_counter", id=1, value=99)
        assert reply.success and "counter 1 reads 99" in reply.message, reply.message
        reply = bridge.call(WriteParameter, "write_parameter", index=3, value=-2)
        assert reply.success and "parameter 3 reads -2" in reply.message, reply.message
        reply = bridge.call(
            UploadPoints,
            "upload_points",
            data_source_id=100,
            values_per_point=6,
            axis_mask=0x23,
            values=list(range(1, 13)),
        )
        assert reply.success and reply.frames_sent == 1
        assert [(r.function_code, r.address, r.values) for r in device.write_log] == [
            (6, 20200, (255,)),
            (16, 20056, (0, 5, 1)),
            (16, 2229, (0x8000, 0x0001)),  # §3.3.1: board 1's word, high word first
            (16, 20050, (0, 1, 0, 0, 0, 99)),
            (16, 2179, (0, 1)),  # the counter read back (decision 24)
            (16, 20306, (0xFFFF, 0xFFFE)),
            (16, 30002, (100, 6, 0x23)),
            (16, 30005, (2, 1, *(w for v in range(1, 13) for w in (0, v)))),
        ]
        reply = bridge.call(ReadParameter, "read_parameter", index=3)
        assert reply.success and reply.value == -2
        assert device.points[100] == list(range(1, 13))
        # The upload can be checked: source 100 holds 2 points, source 7 none.
        reply = bridge.call(ReadDataSource, "read_data_source", source_id=100)
        assert reply.success and reply.points == 2, reply.message
        assert device.write_log[-1].address == 30000 and device.write_log[-1].values == (100,)
        reply = bridge.call(ReadDataSource, "read_data_source", source_id=7)
        assert reply.success and reply.points == 0, reply.message
        assert device.get("io_board_output_0") == 1 << 5
        assert device.get("io_board_output_1") == 0x8000_0001
        # A masked write changes only its outputs (decision 24).
        reply = bridge.call(SetOutputBoard, "set_board_outputs", board=1, bits=0b10, mask=0b11)
        assert reply.success and "read 0x80000001, wrote 0x80000002" in reply.message
        assert device.get("io_board_output_1") == 0x8000_0002


def test_counters_are_listed_and_read(sim, bridge_factory) -> None:  # type: ignore[no-untyped-def]
    """§3.1.3 ids, §3.1.4 one counter's target and current (its id written to 2179)."""
    device, port = sim
    device.set_counters({3: (100, 7), 12: (50, 40)})
    with bridge_factory(port) as (bridge, _):
        bridge.wait_connected(True)
        reply = bridge.call(ListCounters, "list_counters")
        assert reply.success, reply.message
        assert list(reply.ids) == [3, 12]
        reply = bridge.call(ReadCounter, "read_counter", id=12)
        assert reply.success, reply.message
        assert (reply.target, reply.current) == (50, 40)
        assert [(r.address, r.values) for r in device.write_log] == [(2179, (0, 12))]
        assert bridge.call(SetCounter, "set_counter", id=3, value=9).success
        reply = bridge.call(ReadCounter, "read_counter", id=3)
        assert reply.success and (reply.target, reply.current) == (100, 9), reply.message
        # A counter the program does not have: the controller refuses the selection.
        reply = bridge.call(ReadCounter, "read_counter", id=4)
        assert not reply.success and "read_counter 4" in reply.message, reply.message


def test_m_and_eu_boards_behind_their_parameters(sim, bridge_factory, client: Client) -> None:  # type: ignore[no-untyped-def]
    """Decision 21: the M and EU boards' IO is polled and switched (FC 05, coil 32 * board
    + point) only when the parameter says the controller has them."""
    device, port = sim
    device.set("m_board_input_1", 0x10)
    device.set("eu_board_input", 0x3)
    with bridge_factory(port) as (bridge, _):  # default: neither
        bridge.wait_connected(True)
        state = client.wait_message(bridge.state)
        assert list(state.m_board_inputs) == [] and list(state.eu_board_inputs) == []
        for board, parameter in ((5, "m_boards"), (8, "eu_board")):
            reply = bridge.call(SetOutput, "set_output", board=board, index=1, state=True)
            assert not reply.success and parameter in reply.message, reply.message
        assert device.write_log == []
    with bridge_factory(port, m_boards=True, eu_board=True) as (bridge, _):
        bridge.wait_connected(True)
        state = client.wait_message(bridge.state)
        assert list(state.m_board_inputs) == [0, 0x10, 0]
        assert list(state.eu_board_inputs) == [3]
        assert list(state.m_board_outputs) == [0, 0, 0] and list(state.eu_board_outputs) == [0]
        assert bridge.call(SetOutput, "set_output", board=6, index=2, state=True).success
        assert bridge.call(SetOutput, "set_output", board=8, index=31, state=True).success
        reply = bridge.call(SetOutput, "set_output", board=9, index=0, state=True)
        assert not reply.success and "outside" in reply.message, reply.message
        assert [(r.function_code, r.address, r.values) for r in device.write_log] == [
            (5, 32 * 6 + 2, (1,)),  # M board 1 (board 6), point 2
            (5, 32 * 8 + 31, (1,)),  # EU board, point 31
        ]
        assert device.get("m_board_output_1") == 1 << 2  # the same memory (decision 19)
        since = time.monotonic()
        client.wait_message(
            bridge.state,
            lambda m: list(m.eu_board_outputs) == [1 << 31] and m.m_board_outputs[1] == 1 << 2,
            since=since,
        )


REFUSALS: list[tuple[Any, str, dict[str, Any], str]] = [
    (SetValue, "set_global_speed", {"value": 100.5}, "outside"),
    (SetValue, "set_global_speed", {"value": -0.5}, "outside"),
    (SetValue, "set_global_speed", {"value": math.nan}, "outside"),
    (SetOutput, "set_output", {"board": 4, "index": 0, "state": True}, "board 4"),
    (SetOutput, "set_output", {"board": 0, "index": 32, "state": True}, "point 32"),
    (SetOutput, "set_output", {"board": 2, "index": 0, "state": True}, "board 2 is not in use"),
    (SetOutputBoard, "set_board_outputs", {"board": 5, "bits": 1, "mask": 1}, "outside"),
    (SetOutputBoard, "set_board_outputs", {"board": 2, "bits": 1, "mask": 1}, "not in use"),
    (SetOutputBoard, "set_board_outputs", {"board": 0, "bits": 1}, "mask 0"),
    (SetCounter, "set_counter", {"id": 7, "value": 1}, "not one the controller lists"),
    (ClearAlarmAndNext, "clear_alarm_and_next", {"skip_failed_step": False}, "skip_failed_step"),
    (ClearAlarmAndNext, "clear_alarm_and_next", {"skip_failed_step": True}, "no alarm"),
    (Trigger, "clear_alarm_and_continue", {}, "no alarm"),
    (WriteParameter, "write_parameter", {"index": 1000, "value": 1}, "index"),
    (WriteParameter, "write_parameter", {"index": 0, "value": 2**31}, "outside"),
    (
        UploadPoints,
        "upload_points",
        {"data_source_id": 1, "values_per_point": 6, "axis_mask": 0x23, "values": [1, 2, 3]},
        "whole",
    ),
    (
        UploadPoints,
        "upload_points",
        {"data_source_id": 1, "values_per_point": 6, "axis_mask": 0x40, "values": [1] * 6},
        "axis mask",
    ),
]


def test_out_of_range_requests_are_refused_and_write_nothing(sim, bridge_factory) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge_factory(port) as (bridge, _):
        bridge.wait_connected(True)
        for srv_type, name, fields, reason in REFUSALS:
            reply = bridge.call(srv_type, name, **fields)
            assert not reply.success, (name, fields)
            assert "refused" in reply.message and reason in reply.message, reply.message
        assert device.write_log == []


def test_a_refused_huge_upload_does_not_echo_its_values(sim, bridge_factory) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge_factory(port) as (bridge, _):
        bridge.wait_connected(True)
        values = [7] * 100_000
        for fields in (
            {"values_per_point": 6, "axis_mask": 0x0F, "values": values[:-2]},  # not whole
            {"values_per_point": 4, "axis_mask": 0x40, "values": values},  # no axis 7
        ):
            reply = bridge.call(UploadPoints, "upload_points", data_source_id=1, **fields)
            assert not reply.success and len(reply.message) < 300, reply.message[:300]
        assert device.write_log == []


def test_read_only_refuses_every_write(sim, bridge_factory) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    with bridge_factory(port, read_only=True) as (bridge, _):
        bridge.wait_connected(True)
        for name in COMMANDS:
            srv = ClearAlarmAndNext if name == "clear_alarm_and_next" else Trigger
            reply = bridge.call(srv, name)
            assert not reply.success and "read_only" in reply.message
        for reply in (
            bridge.call(SetValue, "set_global_speed", value=10.0),
            bridge.call(SetOutput, "set_output", board=0, index=1, state=True),
            bridge.call(SetCounter, "set_counter", id=1, value=1),
            bridge.call(ReadCounter, "read_counter", id=1),  # selects it: a write
            bridge.call(SetOutputBoard, "set_board_outputs", board=0, bits=1, mask=1),
            bridge.call(ReadDataSource, "read_data_source", source_id=100),  # selects: a write
            bridge.call(WriteParameter, "write_parameter", index=0, value=1),
            bridge.call(
                UploadPoints,
                "upload_points",
                data_source_id=1,
                values_per_point=4,
                axis_mask=1,
                values=[1, 2, 3, 4],
            ),
        ):
            assert not reply.success and "read_only" in reply.message
        assert bridge.call(ReadParameter, "read_parameter", index=0).success  # reads still work
        assert bridge.call(ListCounters, "list_counters").success
        assert device.write_log == []


def test_disconnected_bridge_refuses_and_connects_later(bridge_factory, client: Client) -> None:  # type: ignore[no-untyped-def]
    port = free_port()
    started = time.monotonic()
    with bridge_factory(port) as (bridge, proc):
        bridge.wait_connected(False)
        bridge.wait_diagnostic(2, started, port)
        reply = bridge.call(Trigger, "start")
        assert not reply.success and "not connected" in reply.message
        assert not bridge.call(SetValue, "set_global_speed", value=10.0).success
        assert client.received(bridge.joint_states) == []
        simulator = make_simulator()
        up = time.monotonic()
        simulator.start_tcp(port=port)
        try:
            bridge.wait_connected(True, since=up)
            client.wait_message(bridge.joint_states)
            assert simulator.device.write_log == []  # nothing queued across the reconnect
            assert proc.poll() is None
        finally:
            simulator.stop()


def test_a_stop_goes_out_while_the_link_is_marked_down(bridge_factory, client: Client) -> None:  # type: ignore[no-untyped-def]
    """A stop does not wait for the reconnect backoff: with the next probe seconds
    away, ``~/start`` is refused as not connected and ``~/stop`` right after reaches the
    controller; the poller then does its link-up work and publishes at once."""
    port = free_port()
    started = time.monotonic()
    with bridge_factory(port, reconnect_max_s=60.0) as (bridge, proc):
        # Nothing listens: let the backoff grow until the next probe is >= 4 s away.
        bridge.wait_diagnostic(
            2, started, port, where=lambda v: float(v["reconnect backoff (s)"]) >= 4.0
        )
        simulator = make_simulator()
        simulator.start_tcp(port=port)
        try:
            device = simulator.device
            assert isinstance(device, R6SimDevice)
            reply = bridge.call(Trigger, "start")
            assert not reply.success and "not connected" in reply.message
            stopped = time.monotonic()
            reply = bridge.call(Trigger, "stop")
            assert reply.success, reply.message
            assert [(w.address, w.table) for w in device.write_log] == [
                (COMMANDS["stop"], Table.HOLDING)
            ]
            # The stop reconnected the link: polls resume without waiting for the backoff.
            bridge.wait_connected(True, since=stopped)
            client.wait_message(bridge.joint_states, since=stopped)
            assert proc.poll() is None
        finally:
            simulator.stop()


def test_a_stop_while_the_device_is_gone_says_it_failed(bridge_factory, client: Client) -> None:  # type: ignore[no-untyped-def]
    port = free_port()
    with bridge_factory(port) as (bridge, _):
        bridge.wait_connected(False)
        reply = bridge.call(Trigger, "stop")
        # Tried on the wire (not "refused: not connected"), and the answer says it failed.
        assert not reply.success
        assert reply.message.startswith("stop failed: cannot open")
        assert reply.message.endswith("nothing was sent")


def test_withheld_replies_and_exception_replies(  # type: ignore[no-untyped-def]
    sim, simulator: tuple[Simulator, int], bridge_factory, client: Client
) -> None:
    device, port = sim
    with bridge_factory(port, retries=0) as (bridge, node):
        client.wait_message(bridge.joint_states)
        simulator[0].withhold_replies = True
        withheld = time.monotonic()
        status = bridge.wait_diagnostic(2, withheld, port, where=lambda v: int(v["timeouts"]) > 0)
        back = time.monotonic()
        simulator[0].withhold_replies = False
        client.wait_message(bridge.joint_states, since=back)
        # Exception replies to a polled block: node alive, reported by name, nothing published.
        refused = time.monotonic()
        device.forced_exceptions.append((Table.HOLDING, range(2470, 2472), 4))
        status = bridge.wait_diagnostic(2, refused, port)
        assert "SERVER DEVICE FAILURE" in status.message
        # Polls go on and are refused (the count grows), and publish nothing.
        quiet = time.monotonic()
        count = int(values_of(status)["exception responses"])
        bridge.wait_diagnostic(
            2, quiet, port, where=lambda v: int(v["exception responses"]) >= count + 5
        )
        assert client.received(bridge.joint_states, since=quiet) == []
        device.forced_exceptions.clear()
        client.wait_message(bridge.joint_states, since=time.monotonic())
        assert node.poll() is None


def test_controller_without_version_rows_still_polls(sim, bridge_factory, client: Client) -> None:  # type: ignore[no-untyped-def]
    device, port = sim
    device.forced_exceptions.append((Table.HOLDING, range(0, 65), 2))
    started = time.monotonic()
    with bridge_factory(port) as (bridge, _):
        client.wait_message(bridge.joint_states)
        status = bridge.wait_diagnostic(0, started, port, where=lambda v: "mode" in v)
        assert values_of(status)["firmware version"].startswith("unavailable (ILLEGAL DATA ADDRESS")


@pytest.mark.parametrize(
    ("setup", "name", "reason"),
    [
        (lambda sim: sim.set("mode", 1), "start", "manual mode"),
        (lambda sim: sim.set("homed", 0), "single_cycle", "not homed"),
        (lambda sim: sim.set_alarm(0x325), "start", "alarm 805"),
    ],
)
def test_program_starts_are_checked_and_write_nothing(  # type: ignore[no-untyped-def]
    sim, bridge_factory, setup, name: str, reason: str
) -> None:
    """Decision 23: ~/start and ~/single_cycle read mode, alarm and homed first."""
    device, port = sim
    setup(device)
    with bridge_factory(port) as (bridge, _):
        bridge.wait_connected(True)
        reply = bridge.call(Trigger, name)
        assert not reply.success and reason in reply.message, reply.message
        assert device.write_log == [] and not device.running


def _seconds(msg: Any) -> float:
    """A message's header stamp as wall-clock seconds."""
    return float(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)


def test_pose_and_state_carry_the_read_time_of_their_own_rows(  # type: ignore[no-untyped-def]
    sim, bridge_factory, client: Client
) -> None:
    """Decision 26, through the node: ~/tcp_pose carries the time the
    world block was read, joint_states that of the axis positions, ~/state that of the
    other rows. The simulated controller takes BLOCK_DELAY_S over the world block and
    over the positions, so the three reads of a poll are far apart; each stamp must then
    fall after the device took its block's values and before it took the next block's
    (the simulator's read log), whatever the machine's speed."""
    device, port = sim
    assert isinstance(device, R6SimDevice)
    world, positions = R6_MAP["world_x"], R6_MAP["axis_position_1"]
    serve = device.read

    def slow_blocks(function_code: int, address: int, count: int) -> list[int] | int:
        if any(address <= reg.address < address + count for reg in (world, positions)):
            time.sleep(BLOCK_DELAY_S)  # before the values are taken (and the read logged)
        return serve(function_code, address, count)

    device.read = slow_blocks  # type: ignore[method-assign]
    device.log_reads = True
    with bridge_factory(port) as (bridge, _):
        topics = (bridge.pose, bridge.joint_states, bridge.state)
        wait_for(
            lambda: all(len(client.received(t)) >= STAMP_POLLS for t in topics),
            WAIT_S,
            f"{STAMP_POLLS} polls on {topics}",
        )
        poses, joints, states = ([_seconds(m) for m in client.received(t)] for t in topics)
    with device.lock:
        reads = list(device.read_log)
    times = [r.time for r in reads]
    assert times == sorted(times)

    def newest_read(stamp: float) -> int:
        """The index of the last read the device had served when ``stamp`` was taken."""
        return bisect.bisect_right(times, stamp) - 1

    joint_polls = {newest_read(s): s for s in joints}
    state_polls = {newest_read(s): s for s in states}
    # Only the polls all three subscriptions heard: each matched at its own time, and a
    # poll's last messages may still be on their way (each topic keeps its order).
    first, last = max(min(joints), min(states)), min(max(joints), max(states))
    checked = [p for p in poses if first < p < last]
    assert len(checked) >= 2, (poses, joints, states)
    for pose in checked:
        i = newest_read(pose)
        assert reads[i].covers(world.table, world.address), (pose, reads[i - 1 : i + 2])
        after = reads[i + 1]
        assert after.covers(positions.table, positions.address), (pose, after)
        assert after.time - pose >= BLOCK_DELAY_S - STAMP_SLACK_S
        # joint_states of the same poll: stamped after the positions were taken, a block
        # delay after the pose.
        assert i + 1 in joint_polls, (pose, sorted(joint_polls))
        assert joint_polls[i + 1] - pose >= BLOCK_DELAY_S - STAMP_SLACK_S
        # ~/state of the same poll: its rows are the read just before the world block.
        head = reads[i - 1]
        assert not head.covers(world.table, world.address), head
        assert not head.covers(positions.table, positions.address), head
        assert i - 1 in state_polls, (pose, sorted(state_polls), sorted(joint_polls))
        assert reads[i].time - state_polls[i - 1] >= BLOCK_DELAY_S - STAMP_SLACK_S
