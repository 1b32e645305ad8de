"""The R6 device layer against the R6 simulator over a real TCP socket (no ROS)."""

from __future__ import annotations

import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from bridge_core.runtime.goals import Outcome, Verdict
from bridge_core.sim.logs import WriteRecord
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import CommandRejected, DeviceException, NotConfirmed
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, TcpSettings
from r6_bridge.device import R6Device, R6Snapshot
from r6_bridge.motions import RunCycleMotion
from r6_bridge.registers import COMMANDS, MAX_AXES, NOT_OFFERED, R6_LIMITS, R6_MAP
from r6_bridge.sim import MANUAL_VERSION, R6SimDevice, axis_speed_deg_s, make_simulator
from r6_bridge.upload import PointUploadSteps


@pytest.fixture
def sim() -> Iterator[tuple[R6SimDevice, int]]:
    simulator = make_simulator(axis_count=6, io_board_count=2)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    yield device, port
    simulator.stop()


@pytest.fixture
def r6(sim: tuple[R6SimDevice, int]) -> Iterator[tuple[R6Device, R6SimDevice, DeviceChannel]]:
    device, port = sim
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    channel = DeviceChannel(link, 1, retries=0)
    yield R6Device(channel), device, channel
    link.close()


def raw_request(port: int, pdu: bytes, unit: int = 1) -> bytes:
    """Send one hand-built Modbus TCP request; return unit + reply PDU."""
    with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
        s.sendall(struct.pack(">HHH", 7, 0, len(pdu) + 1) + bytes([unit]) + pdu)
        header = s.recv(6)
        length = struct.unpack(">HHH", header)[2]
        data = b""
        while len(data) < length:
            data += s.recv(length - len(data))
    return data


def test_poll_decodes_the_simulator_state(r6: tuple[R6Device, R6SimDevice, DeviceChannel]) -> None:
    device, sim, _ = r6
    sim.tick = lambda dt: None  # type: ignore[method-assign]  # hold the values still
    sim.set("axis_position_3", -45.5)
    sim.set("world_z", 812.25)
    sim.set("axis_speed_2", -120)
    sim.set("axis_torque_1", 0.5)
    sim.set("io_board_input_1", 0x8000_0001)
    sim.set("current_cycle_time", 2**40 + 5)
    sim.set_alarm(0x325)
    snap = device.poll()
    assert snap.axis_count == 6 and len(snap.axis_positions_deg) == 6
    assert snap.axis_positions_deg[2] == pytest.approx(-45.5)
    assert snap.world["z"] == pytest.approx(812.25)
    assert snap.axis_speeds_rpm[1] == -120
    assert snap.axis_torques_rated[0] == pytest.approx(0.5, abs=1e-3)
    assert snap.io_board_inputs == (0, 0x8000_0001)
    assert snap.current_cycle_time_ms == 2**40 + 5
    assert snap.alarm_code == 0x325 and snap.mode_name == "auto"
    assert snap.global_speed_percent == pytest.approx(50.0)
    assert device.read_version() == MANUAL_VERSION


def test_commands_write_the_manual_registers(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    device, sim, _ = r6
    device.command("start")
    device.set_global_speed(12.5)
    device.set_output(1, 7, True)
    device.set_counter(1, 42)
    device.write_parameter(964, -7)  # the last index inside §3.3.4's 20300-22229
    log = [(r.function_code, r.address, r.values) for r in sim.write_log]
    assert log == [
        (6, 20003, (1,)),
        (6, 20200, (125,)),
        (16, 20056, (1, 7, 1)),
        (16, 20050, (0, 1, 0, 0, 0, 42)),
        (16, 2179, (0, 1)),  # the counter read back (decision 24)
        (16, 20300 + 2 * 964, (0xFFFF, 0xFFF9)),
    ]
    assert sim.running
    assert sim.get("io_board_output_1") == 1 << 7
    assert device.read_counter(1) == (1, 10, 42)
    assert device.read_parameter(964) == -7
    sim.set("parameter_999", 123)
    assert device.read_parameter(999) == 123  # read-only beyond 964, but readable


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda d: d.set_global_speed(100.5), "outside"),
        (lambda d: d.set_global_speed(-1), "outside"),
        (lambda d: d.set_output(4, 0, True, boards_in_use=2), "board 4"),
        (lambda d: d.set_output(5, 0, True), "m_boards"),  # M board 0: off by default
        (lambda d: d.set_output(8, 0, True), "eu_board"),
        (lambda d: d.set_output(9, 0, True), "board 9"),
        (lambda d: d.set_output(0, 32, True), "point 32"),
        (lambda d: d.write_parameter(1000, 1), "parameter index"),
        (lambda d: d.write_parameter(915, 1), "22130"),
        (lambda d: d.write_parameter(965, 1), "read-only"),
        (lambda d: d.write_parameters(963, [1, 2, 3]), "read-only"),
        (lambda d: d.write_parameter(0, 2**31), "outside"),
        (lambda d: d.set_counter(-1, 0), "counter id"),
        (lambda d: d.command("self_destruct"), "unknown"),
        (lambda d: d.upload_points(1, 5, 0, [1] * 10), "values_per_point"),
        (lambda d: d.upload_points(1, 6, 0x40, [1] * 6), "axis mask"),
        (lambda d: d.upload_points(1, 6, 0, [1] * 6), "axis mask 0"),  # decision 25
        (lambda d: d.upload_points(1, 4, 0x13, [1] * 4), "past the 4 values"),
        (lambda d: d.write_board_outputs(0, 1, 0), "mask 0"),  # decision 24
        (lambda d: d.write_board_outputs(0, 0b11, 0b01), "outside mask"),
        (lambda d: d.set_output(2, 0, True, boards_in_use=2), "board 2"),
        (lambda d: d.upload_points(1, 6, 1, [1] * 7), "whole"),
    ],
)
def test_out_of_range_commands_write_nothing(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel], call: Callable[[R6Device], object], match: str
) -> None:
    device, sim, channel = r6
    before = channel.stats.transactions
    with pytest.raises(CommandRejected, match=match):
        call(device)
    assert sim.write_log == []
    assert channel.stats.transactions == before


def test_simulator_refuses_what_the_device_refuses(sim: tuple[R6SimDevice, int]) -> None:
    _, port = sim

    def exception_code(pdu: bytes) -> int | None:
        reply = raw_request(port, pdu)
        return reply[2] if reply[1] & 0x80 else None

    def read(address: int, count: int) -> bytes:
        return bytes([3]) + struct.pack(">HH", address, count)

    assert exception_code(read(2268, 12)) is None  # 6 axes, whole
    assert exception_code(read(2269, 2)) == 2  # starts inside axis 0's pair
    assert exception_code(read(2268, 3)) == 2  # cuts axis 1
    assert exception_code(read(2280, 2)) == 2  # axis 7 of 6
    assert exception_code(read(2191, 2)) == 2  # IO board 2 of 2
    assert exception_code(read(2205, 1)) == 2  # reserved
    for rows in NOT_OFFERED.values():
        assert exception_code(read(rows.start, 1)) == 2
    assert exception_code(read(20000, 1)) == 2  # command registers are write-only
    # Commands only with FC 06 (§3.2.1).
    assert exception_code(bytes([16]) + struct.pack(">HHB", 20000, 1, 2) + b"\x00\x01") == 1
    # FC 04 reads the FC 03 table (§4's title), so it refuses what FC 03 refuses.
    assert exception_code(bytes([4]) + struct.pack(">HH", 2269, 2)) == 2
    assert exception_code(bytes([4]) + struct.pack(">HH", 20000, 1)) == 2
    # Global speed above 1000 (§3.2.2).
    assert exception_code(bytes([6]) + struct.pack(">HH", 20200, 1001)) == 3


def test_device_exception_comes_back_by_name(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    _, _, channel = r6
    with pytest.raises(DeviceException, match="ILLEGAL DATA ADDRESS"):
        channel.read_registers(2205, 1)
    assert channel.connected  # an exception reply means the device is alive
    assert channel.stats.exceptions == 1


def test_axes_move_while_running_and_stop(r6: tuple[R6Device, R6SimDevice, DeviceChannel]) -> None:
    device, sim, _ = r6
    start = device.poll().axis_positions_deg
    device.command("start")
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        snap = device.poll()
        if snap.moving and abs(snap.axis_positions_deg[0] - start[0]) > 0.5:
            break
    else:
        pytest.fail("axes did not move while running")
    device.command("stop")
    deadline = time.monotonic() + 30
    while device.poll().moving:
        assert time.monotonic() < deadline
    sim.set_alarm(7)
    device.command("start")
    assert not sim.running  # an alarm blocks start until cleared
    device.command("clear_alarm_and_continue")
    # Cleared, but the alarm did not halt a running program: nothing to continue.
    assert not sim.running and sim.get("alarm_code") == 0
    device.command("start")
    assert sim.running


def test_point_upload_reaches_the_simulator(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    device, sim, _ = r6
    values = [(-1) ** k * k * 1000 for k in range(6 * 23)]
    assert device.upload_points(100, 6, 0x23, values) == 3
    assert sim.points[100] == values
    assert device.upload_points(100, 4, 0x0F, [1, 2, 3, 4]) == 1
    assert sim.points[100] == [1, 2, 3, 4]  # the first frame clears


def test_the_map_covers_the_manual_tables() -> None:
    # Spot checks of addresses and scales straight from the §4 / §5 tables.
    expect = {
        "version_length": 0,
        "counter_count": 130,
        "counter_id_0": 131,
        "counter_id_1023": 2177,
        "counter_select_id": 2179,
        "mode": 2185,
        "io_board_count": 2186,
        "io_board_input_0": 2187,
        "eu_board_input": 2203,
        "io_board_output_0": 2227,
        "m_board_output_1": 2239,
        "eu_board_output": 2243,
        "axis_count": 2267,
        "axis_position_1": 2268,
        "axis_position_8": 2282,
        "world_x": 2332,
        "world_m8": 2346,
        "alarm_code": 2396,
        "current_cycle_time": 2397,
        "last_cycle_time": 2401,
        "machine_id": 2405,
        "axis_torque_1": 2406,
        "axis_torque_8": 2413,
        "axis_speed_1": 2438,
        "axis_speed_8": 2445,
        "moving": 2470,
        "homed": 2471,
        "command_stop": 20000,
        "command_clear_alarm_and_continue": 20006,
        "counter_modify_id": 20050,
        "output_board": 20056,
        "output_state": 20058,
        "global_speed": 20200,
        "parameter_0": 20300,
        "parameter_999": 22298,
        "data_source_view_id": 30000,
        "point_source_id": 30002,
        "point_count": 30005,
        "point_clear": 30006,
        "point_data_0": 30007,
        "y_output_0": 0,
        "m_output_0": 160,
        "eu_output_31": 287,
    }
    for name, address in expect.items():
        assert R6_MAP[name].address == address, name
    assert R6_MAP["axis_position_1"].scale == 1000 and R6_MAP["axis_position_1"].value_type.signed
    assert R6_MAP["axis_torque_1"].scale == 2580
    assert R6_MAP["global_speed"].scale == 10 and R6_MAP["global_speed"].count == 1
    assert R6_MAP["current_cycle_time"].count == 4
    assert R6_MAP["y_output_0"].table is Table.COIL
    for reg in R6_MAP:
        assert reg.doc.startswith("§"), reg.name
        for rows in NOT_OFFERED.values():
            assert not (reg.table is Table.HOLDING and set(reg.addresses()) & set(rows)), reg.name


def test_simulator_refuses_reads_that_mix_block_widths(sim: tuple[R6SimDevice, int]) -> None:
    _, port = sim

    def code(address: int, count: int) -> int | None:
        reply = raw_request(port, bytes([3]) + struct.pack(">HH", address, count))
        return reply[2] if reply[1] & 0x80 else None

    assert code(2267, 13) == 2  # axis count (16-bit) merged in front of the positions
    assert code(2185, 4) == 2  # mode + board count + board 0 inputs
    assert code(2397, 8) == 2  # both cycle times: "寄存器数量固定为 4"
    assert code(2396, 5) == 2  # alarm + a cycle time
    assert code(2397, 4) is None and code(2268, 12) is None and code(2405, 9) is None


def test_poll_plan_reads_every_block_as_the_manual_does() -> None:
    plan = R6Device(None).poll_plan(6, 1)  # type: ignore[arg-type]
    for request in plan:
        widths = {reg.count for reg in request.registers}
        assert len(widths) == 1, request
        if widths == {4}:
            assert request.count == 4


@pytest.mark.parametrize(
    ("count", "fewer"),
    [("axis_count", 4), ("io_board_count", 1)],
    ids=["axes", "boards"],
)
def test_poller_recovers_when_axes_or_boards_go_away(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel], count: str, fewer: int
) -> None:
    """§3.1.8: only the axes (and boards) in use are valid; after the count drops the
    cached plan reads removed rows, the controller answers 0x02, and the poller must
    re-derive the plan from the counts instead of failing forever (issue: 0 joint_states
    while connected)."""
    from bridge_core.runtime.poller import Poller, PollOutcome

    device, sim, channel = r6
    sim.tick = lambda dt: None  # type: ignore[method-assign]
    published: list[object] = []
    poller = Poller(
        channel,
        device.poll,
        published.append,
        rate_hz=10.0,
        link_up=device.invalidate_plan,
        replan=device.invalidate_plan,
    )
    assert poller.tick() is PollOutcome.PUBLISHED
    sim.set(count, fewer)
    outcomes = [poller.tick() for _ in range(3)]
    assert outcomes[0] is PollOutcome.REFUSED  # the old plan reads a removed row
    assert outcomes[-1] is PollOutcome.PUBLISHED
    assert channel.connected
    poller.publish_pending()
    newest = published[-1]
    assert getattr(newest, count) == fewer
    if count == "axis_count":
        assert len(newest.axis_positions_deg) == fewer  # type: ignore[attr-defined]
    else:
        assert len(newest.io_board_inputs) == fewer  # type: ignore[attr-defined]


def test_a_simulator_that_cannot_listen_says_so_in_one_line(
    sim: tuple[R6SimDevice, int],
) -> None:
    """A port in use ends the simulator with exit 1 and a line naming the address."""
    _, port = sim
    result = subprocess.run(
        [sys.executable, "-m", "r6_bridge.sim", "--port", str(port)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1, result.stdout + result.stderr
    assert f"r6_sim: cannot listen on 127.0.0.1:{port}" in result.stderr
    assert "Traceback" not in result.stderr


# ---------------------------------------------------------------- R6 behaviour
WAIT_S = 30.0
# Between two polls of wait_for_poll: a bridge's 50 Hz, short beside the programs' steps.
POLL_PAUSE_S = 0.02


def wait_for_poll(
    device: R6Device,
    predicate: Callable[[R6Snapshot], bool],
    what: str,
    never: Callable[[R6Snapshot], bool] | None = None,
) -> R6Snapshot:
    """Poll over the socket every ``POLL_PAUSE_S`` until ``predicate`` holds (as a bridge
    would; back to back, the simulator and this loop took a whole core); no poll on the
    way may satisfy ``never`` (e.g. an axis moving the wrong way first)."""
    deadline = time.monotonic() + WAIT_S
    while True:
        snap = device.poll()
        if predicate(snap):
            return snap
        if never is not None and never(snap):
            pytest.fail(f"while waiting for {what}: {snap}")
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}; last poll: {snap}")
        time.sleep(POLL_PAUSE_S)


def timed_program(*seconds: float) -> tuple[tuple[float, ...], ...]:
    """One waypoint per step: where each axis is after ``seconds`` of motion at 100 % global
    speed from 0 (negative: the other way), so every axis arrives at the same time."""
    return tuple(
        tuple(round(axis_speed_deg_s(a) * t, 3) for a in range(1, MAX_AXES + 1)) for t in seconds
    )


def axis_1(snap: R6Snapshot) -> float:
    return snap.axis_positions_deg[0]


def test_two_cycles_of_the_same_program_never_tie_in_the_last_cycle_time() -> None:
    """The bridge reads an unchanged 2401 as a cycle that did not finish (R6 decision 23,
    docs/decisions/r6.md); cycles of one program at one speed tie, to the millisecond,
    whenever the ticks fall alike (here always: a fixed tick), so the simulator never
    repeats it."""
    sim = R6SimDevice()
    sim.program = timed_program(0.05, 0.0)
    sim.set("global_speed", 100.0)
    times = []
    for _ in range(3):
        sim._command(COMMANDS["single_cycle"])
        while sim.running:
            sim.tick(0.01)
        times.append(int(sim.get("last_cycle_time")))
    assert sim.cycles_completed == 3
    assert times[0] != times[1] != times[2], times


def test_single_cycle_runs_to_the_end_of_the_cycle_then_stops(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """20002 "进入单循环" (decision 16): one cycle, then the program stops at its end."""
    device, sim, _ = r6
    sim.program = timed_program(0.5, -1.0, 0.0)  # 0.5 + 1.5 + 1.0 s per cycle
    sim.set("global_speed", 100.0)
    device.command("single_cycle")
    # A poll is 13 requests, so one may read the cycle time before the end and the moving
    # flag after it: wait for a poll that saw the end in every row (the current cycle time
    # back to 0 is part of it: a simulator that never resets it times out here).
    done = wait_for_poll(
        device,
        lambda s: not s.moving and s.last_cycle_time_ms > 0 and s.current_cycle_time_ms == 0,
        "the single cycle's end",
    )
    assert done.alarm_code == 0
    assert done.axis_positions_deg == (0.0,) * 6  # the program's last waypoint
    assert not sim.running and sim.cycles_completed == 1 and sim.step == 0
    # Sent while a continuous run is under way, it ends that run with the current cycle.
    device.command("start")
    wait_for_poll(device, lambda s: s.moving and axis_1(s) > 0, "the second cycle")
    device.command("single_cycle")
    done = wait_for_poll(device, lambda s: not s.moving, "the second cycle's end")
    assert done.axis_positions_deg == (0.0,) * 6
    assert sim.cycles_completed == 2
    # 20003 runs cycle after cycle.
    sim.program = timed_program(0.1, -0.2, 0.0)
    device.command("start")
    wait_for_poll(device, lambda s: sim.cycles_completed >= 5, "three more cycles")
    assert sim.running


def test_pause_resumes_at_the_step_and_stop_starts_from_the_first(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """20001 "暂停当前动作(启动从当前步开始)" keeps the step and the cycle; 20000
    "立即停止当前动作(启动从头开始)" (and 20004, decision 17) start over."""
    device, sim, _ = r6
    sim.program = timed_program(0.2, -3.0, 0.0)  # step 1: out (+), step 2: a long way back
    sim.set("global_speed", 100.0)
    device.command("start")
    wait_for_poll(device, lambda s: axis_1(s) < -3.0, "the second step")
    device.command("pause")
    paused = wait_for_poll(device, lambda s: not s.moving, "the pause")
    assert paused.current_cycle_time_ms > 0
    device.command("start")
    # Resumed at the second step: on towards its waypoint (-), in the same cycle.
    resumed = wait_for_poll(
        device,
        lambda s: axis_1(s) < axis_1(paused) - 3.0,
        "the second step going on",
        never=lambda s: axis_1(s) > axis_1(paused) + 0.5,
    )
    assert resumed.current_cycle_time_ms > paused.current_cycle_time_ms
    for stop in ("stop", "stop_button"):
        device.command(stop)
        # The cycle is abandoned: its time back to 0 (in the predicate, as a poll may read
        # the time before the stop and the moving flag after it).
        stopped = wait_for_poll(
            device, lambda s: not s.moving and s.current_cycle_time_ms == 0, stop
        )
        assert sim.step == 0, stop
        device.command("start")
        # From the first step: back out towards its waypoint (+).
        at = axis_1(stopped)

        def back_out(s: R6Snapshot, at: float = at) -> bool:
            return axis_1(s) > at + 3.0

        def further_in(s: R6Snapshot, at: float = at) -> bool:
            return axis_1(s) < at - 0.5

        wait_for_poll(device, back_out, f"the first step after {stop}", never=further_in)
        wait_for_poll(device, lambda s: axis_1(s) < -3.0, "the second step")


def test_alarm_halts_20006_continues_the_step_20005_goes_on_with_the_next(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """20005 "清除报警后运行下一条指令", 20006 "清除报警并继续自动运行" (decision 18)."""
    device, sim, _ = r6
    sim.program = timed_program(0.2, -3.0, 0.0)
    sim.set("global_speed", 100.0)
    device.command("start")
    wait_for_poll(device, lambda s: axis_1(s) < -3.0, "the second step")
    sim.set_alarm(0x325)
    halted = wait_for_poll(device, lambda s: not s.moving, "the alarm's halt")
    assert halted.alarm_code == 0x325
    device.command("start")
    assert not sim.running  # an alarm blocks start until cleared
    device.command("clear_alarm_and_continue")
    wait_for_poll(
        device,
        lambda s: s.alarm_code == 0 and axis_1(s) < axis_1(halted) - 3.0,
        "20006: the same step going on (-)",
        never=lambda s: axis_1(s) > axis_1(halted) + 0.5,
    )
    sim.set_alarm(0x326)
    halted = wait_for_poll(device, lambda s: not s.moving, "the second alarm's halt")
    assert sim.step == 1
    device.command("clear_alarm_and_next")
    wait_for_poll(
        device,
        lambda s: s.alarm_code == 0 and s.moving and axis_1(s) > axis_1(halted) + 3.0,
        "20005: the next step (towards 0, +)",
        never=lambda s: axis_1(s) < axis_1(halted) - 0.5,
    )
    assert sim.step == 2 and sim.running
    # 20006 continues only in auto mode (its "(自动运行状态下)"); the alarm is cleared.
    sim.set_alarm(0x327)
    wait_for_poll(device, lambda s: not s.moving, "the third alarm's halt")
    sim.set("mode", 1)
    device.command("clear_alarm_and_continue")
    assert not sim.running and sim.get("alarm_code") == 0
    # An alarm that halted nothing (the program stood still) leaves nothing to run on.
    sim.set("mode", 2)
    sim.set_alarm(0x328)
    for clear in ("clear_alarm_and_next", "clear_alarm_and_continue"):
        device.command(clear)
        assert not sim.running and sim.get("alarm_code") == 0, clear
        sim.set_alarm(0x328)


def test_counter_ids_past_the_count_read_0xff(sim: tuple[R6SimDevice, int]) -> None:
    """§3.1.3: "若实际数量少于请求的数量则将剩余的使用 0xFF 填充" (decision 6)."""
    device, port = sim

    def ids(first: int, count: int) -> bytes:
        reply = raw_request(port, bytes([3]) + struct.pack(">HH", 131 + 2 * first, 2 * count))
        assert reply[1:3] == bytes([3, 4 * count]), reply.hex()
        return reply[3:]

    assert ids(0, 4) == bytes.fromhex("00000000 00000001 ffffffff ffffffff")
    assert ids(3, 2) == b"\xff" * 8  # wholly past the count: padded, not refused
    assert ids(1022, 2) == b"\xff" * 8
    device.set_counters({5: (1, 0), 9: (2, 0), 0x12345: (3, 1)})
    assert ids(0, 4) == bytes.fromhex("00000005 00000009 00012345 ffffffff")
    device.set_counters({})
    assert ids(0, 1) == b"\xff" * 4


def test_coils_and_output_rows_are_one_memory(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel], sim: tuple[R6SimDevice, int]
) -> None:
    """§5's FC 01/05 outputs (Y010…, M010…, EUY010…) and §4's output rows 2227-2244 are the
    same outputs (decision 19): coil 32·board + point is bit `point` of the board's word."""
    device, simulator, channel = r6
    _, port = sim

    def coil(address: int, on: bool) -> None:
        pdu = bytes([5]) + struct.pack(">HH", address, 0xFF00 if on else 0)
        assert raw_request(port, pdu)[1:] == pdu  # the echo

    def rows(address: int) -> list[int]:
        return channel.read_registers(address, 2)

    coil(33, True)  # board 1, point 1: the low word's bit 1
    coil(52, True)  # board 1, point 20: the high word's bit 4
    assert rows(2229) == [0x0010, 0x0002]
    assert device.poll().io_board_outputs[1] == 1 << 20 | 1 << 1
    coil(33, False)
    assert rows(2229) == [0x0010, 0x0000]
    coil(160 + 32 + 5, True)  # M board 1, point 5 (rows 2239-2240)
    coil(256 + 17, True)  # EU board, point 17 (rows 2243-2244)
    assert rows(2239) == [0, 0x0020] and rows(2243) == [0x0002, 0]
    # The other way: §3.3.1's whole-board write and §3.3.3's single point show as coils.
    device.write_board_outputs(0, 0x8000_0001, 0xFFFF_FFFF)
    bits = channel.read_bits(0, 32)
    assert [k for k, b in enumerate(bits) if b] == [0, 31]
    reply = raw_request(port, bytes([1]) + struct.pack(">HH", 0, 32))
    assert reply[1:] == bytes([1, 4, 0x01, 0, 0, 0x80])
    device.set_output(1, 7, True)
    assert [k for k, b in enumerate(channel.read_bits(32, 32)) if b] == [7, 20]
    simulator.set("io_board_output_0", 0)  # and what the controller itself changes
    assert not any(channel.read_bits(0, 32))
    # Coils of IO boards not in use are refused like their rows (§3.1.6; 2 boards here).
    reply = raw_request(port, bytes([1]) + struct.pack(">HH", 64, 1))
    assert reply[1:] == bytes([0x81, 2])
    assert raw_request(port, bytes([1]) + struct.pack(">HH", 160, 128))[1] == 1  # M, EU


def test_fc04_reads_the_fc03_table(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel], sim: tuple[R6SimDevice, int]
) -> None:
    """§4 "功能码 0x03、0x04、0x06、0x10 地址表定义": FC 04 serves the same rows."""
    assert 4 in R6_LIMITS.function_codes
    _, simulator, channel = r6
    _, port = sim
    simulator.tick = lambda dt: None  # type: ignore[method-assign]  # hold the values still
    simulator.set("axis_position_2", -12.5)
    simulator.log_reads = True
    for address, count in ((2185, 1), (2268, 12), (2397, 4), (1, 21), (131, 4), (20300, 2)):
        holding = raw_request(port, bytes([3]) + struct.pack(">HH", address, count))
        inputs = raw_request(port, bytes([4]) + struct.pack(">HH", address, count))
        assert inputs[1] == 4 and inputs[2:] == holding[2:], (address, inputs.hex())
    assert channel.read_registers(2270, 2, table=Table.INPUT) == [0xFFFF, 0xCF2C]
    # The same refusals: a cut 32-bit value, a write-only row, an axis not in use.
    for address, count in ((2269, 2), (20000, 1), (2280, 2)):
        reply = raw_request(port, bytes([4]) + struct.pack(">HH", address, count))
        assert reply[1:] == bytes([0x84, 2]), address
    fc04 = [r for r in simulator.read_log if r.function_code == 4]
    assert fc04 and all(r.table is Table.HOLDING for r in fc04)


def test_the_counter_list_leaves_out_padding_ids(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """A count read before the program dropped counters: the ids past the new end read
    0xFFFFFFFF (§3.1.3) and are not counters."""
    device, sim, _ = r6
    sim.set_counters({5: (1, 0)})
    sim.set("counter_count", 3)  # as read a moment before the list shrank
    assert device.read_counter_ids() == [5]


# ---------------------------------------------------------------- decisions 23-25


@pytest.mark.parametrize(
    ("setup", "name", "match"),
    [
        (lambda sim: sim.set("mode", 1), "start", "manual mode"),
        (lambda sim: sim.set("mode", 1), "single_cycle", "manual mode"),
        (lambda sim: sim.set("homed", 0), "start", "not homed"),
        (lambda sim: sim.set_alarm(0x325), "single_cycle", "alarm 805"),
        (lambda sim: None, "clear_alarm_and_continue", "no alarm"),
        (lambda sim: sim.set_alarm(0x325), "clear_alarm_and_next", "skip_failed_step"),
        (
            lambda sim: (sim.set_alarm(0x325), sim.set("mode", 1)),
            "clear_alarm_and_continue",
            "manual",
        ),
    ],
)
def test_commands_that_start_the_program_are_checked_first(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
    setup: Callable[[R6SimDevice], object],
    name: str,
    match: str,
) -> None:
    """Decision 23: refused with the reason, nothing written."""
    device, sim, _ = r6
    setup(sim)
    with pytest.raises(CommandRejected, match=match):
        device.run_program(name)
    assert sim.write_log == []


def test_clear_alarm_and_next_runs_only_with_skip_failed_step(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    device, sim, _ = r6
    sim.set_alarm(0x325)
    device.run_program("clear_alarm_and_next", skip_failed_step=True)
    assert [r.address for r in sim.write_log] == [20005]
    assert sim.get("alarm_code") == 0


def judge_until(device: R6Device, motion: RunCycleMotion) -> Verdict:
    """Start ``motion`` and judge every poll after it until it has a verdict."""
    motion.start()
    started = time.monotonic()
    deadline = started + WAIT_S
    while time.monotonic() < deadline:
        verdict = motion.judge(device.poll(), time.monotonic() - started)
        if verdict is not None:
            return verdict
    pytest.fail("no verdict")


def test_a_single_cycle_is_reached_only_when_it_ran_and_ended(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 23: moving rose and fell and the last cycle time changed."""
    device, sim, channel = r6
    sim.program = timed_program(0.3, 0.0)
    sim.set("global_speed", 100.0)
    verdict = judge_until(device, RunCycleMotion(device, device.poll(), single_cycle=True))
    assert verdict.outcome is Outcome.REACHED, verdict.message
    assert sim.cycles_completed == 1
    # The same cycle stopped by another client half-way: moving falls, no new cycle time.
    sim.program = timed_program(1.0, 0.0)
    other = R6Device(channel)
    motion = RunCycleMotion(device, device.poll(), single_cycle=True)
    motion.start()
    wait_for_poll(
        device,
        lambda s: motion.judge(s) is None and s.moving and axis_1(s) > 5.0,
        "the cycle under way",
    )
    other.command("stop")
    verdict = judge_until_after_start(device, motion)
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "could not prove the cycle finished" in verdict.message
    assert sim.cycles_completed == 1


def judge_until_after_start(device: R6Device, motion: RunCycleMotion) -> Verdict:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        verdict = motion.judge(device.poll())
        if verdict is not None:
            return verdict
    pytest.fail("no verdict")


def test_a_cycle_that_ends_between_two_polls_is_reached(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 23: on a controller seen (by an earlier goal) to write the last cycle time
    only when a cycle finishes, a cycle that began and ended before any poll saw it
    moving still ran. Before any goal saw that: not proved (test_r6_personalities)."""
    device, sim, _ = r6
    sim.set("global_speed", 100.0)
    sim.program = timed_program(0.3, 0.0)
    seen = judge_until(device, RunCycleMotion(device, device.poll(), single_cycle=True))
    assert seen.outcome is Outcome.REACHED, seen.message
    assert device.cycle_time_written_at == "end"
    sim.program = timed_program(0.05)
    cycles = sim.cycles_completed
    motion = RunCycleMotion(device, device.poll(), single_cycle=True)
    motion.start()
    started = time.monotonic()
    deadline = started + WAIT_S
    while sim.cycles_completed < cycles + 1:  # the whole cycle before the first poll
        assert time.monotonic() < deadline, "the cycle did not end"
        time.sleep(0.01)
    while (verdict := motion.judge(device.poll(), time.monotonic() - started)) is None:
        assert time.monotonic() < deadline, "no verdict"
    assert verdict.outcome is Outcome.REACHED, verdict.message
    assert "no poll saw it moving" in verdict.message


class EndBeforeTheLastCycleTime(DeviceChannel):
    """Once ``armed``, the next read of 2401 waits until the simulator's cycle has ended: a
    poll that read 2397 while the cycle counted reads the new 2401 (the cycle's end falls
    between the two reads, as it may on a real controller)."""

    sim: R6SimDevice
    armed = False

    def read_registers(self, address: int, *args: Any, **kwargs: Any) -> list[int]:
        if self.armed and address == R6_MAP["last_cycle_time"].address:
            self.armed = False
            ended = self.sim.cycles_completed + 1
            deadline = time.monotonic() + WAIT_S
            while self.sim.cycles_completed < ended:
                assert time.monotonic() < deadline, "the cycle did not end"
                time.sleep(0.005)
        return super().read_registers(address, *args, **kwargs)


def test_a_cycle_ending_inside_a_poll_is_not_taken_for_a_start_writer(
    sim: tuple[R6SimDevice, int],
) -> None:
    """Decision 23: a poll reads 2397, 2401, then 2470. A cycle that ends between the first
    two reads leaves 2397 counting and the new 2401 in one poll; on this controller
    (2401 written at the end) that is the cycle's end, not a 2401 written while it ran:
    REACHED, and the bridge learns "end", not "start" (which would end every later
    goal STOPPED)."""
    simulated, port = sim
    link = ModbusLink(TcpSettings("127.0.0.1", port, timeout_s=1.0))
    channel = EndBeforeTheLastCycleTime(link, 1, retries=0)
    channel.sim = simulated
    try:
        device = R6Device(channel)
        plan = device.poll_plan(MAX_AXES, 0)
        order = [
            next(i for i, r in enumerate(plan) if name in r.names)
            for name in ("current_cycle_time", "last_cycle_time", "moving")
        ]
        assert order == sorted(order), order  # what RunCycleMotion.running relies on
        simulated.program = timed_program(0.6, 0.0)
        simulated.set("global_speed", 100.0)
        motion = RunCycleMotion(device, device.poll(), single_cycle=True)
        motion.start()
        wait_for_poll(
            device,
            lambda s: motion.judge(s) is None and s.current_cycle_time_ms > 0,
            "the cycle counting",
        )
        channel.armed = True
        torn = device.poll()
        assert not torn.moving and torn.current_cycle_time_ms > 0, torn
        assert torn.last_cycle_time_ms > 0, torn  # read after the end: the new time
        assert motion.judge(torn) is None  # counting: still running, as far as it knows
        verdict = judge_until_after_start(device, motion)
    finally:
        link.close()
    assert verdict.outcome is Outcome.REACHED, verdict.message
    assert device.cycle_time_written_at == "end"


def test_a_start_the_controller_ignores_is_not_reached(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    device, sim, _ = r6
    sim.program = timed_program(0.3, 0.0)

    def ignore_starts(record: WriteRecord) -> None:
        sim.running = False  # acknowledged, not obeyed

    sim.write_hooks.append(ignore_starts)
    verdict = judge_until(device, RunCycleMotion(device, device.poll(), single_cycle=True))
    assert verdict.outcome is Outcome.STOPPED, verdict.message
    assert "never showed moving" in verdict.message


def test_run_cycle_is_refused_in_manual_mode_and_its_stop_is_a_pause(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 23 and the goal's own ends: pause (20001) keeps the program's step."""
    device, sim, _ = r6
    sim.set("mode", 1)
    with pytest.raises(CommandRejected, match="manual"):
        RunCycleMotion(device, device.poll(), single_cycle=True)
    motion = RunCycleMotion(device, None, single_cycle=True)
    with pytest.raises(CommandRejected, match="manual"):
        motion.start()  # the rows read just before the write
    assert sim.write_log == []
    sim.set("mode", 2)
    sim.program = timed_program(1.0, 0.0)
    motion.start()
    wait_for_poll(device, lambda s: s.moving, "the cycle under way")
    assert "pause (20001)" in motion.stop()
    assert [r.address for r in sim.write_log] == [20002, 20001]
    wait_for_poll(device, lambda s: not s.moving, "the pause")
    assert sim.step == 0 and int(sim.get("current_cycle_time")) > 0  # kept, not reset


def test_board_outputs_change_only_the_masked_outputs(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 24: a read-modify-write keeps what the program drives."""
    device, sim, _ = r6
    sim.set("io_board_output_1", 0x8000_0001)  # the program's gripper and vacuum
    said = device.write_board_outputs(1, 0b100, 0b110, boards_in_use=2)
    assert sim.get("io_board_output_1") == 0x8000_0005
    assert "read 0x80000001, wrote 0x80000005" in said and "not atomic" in said
    device.write_board_outputs(1, 0x10, 0xFFFF_FFFF, boards_in_use=2)  # the whole board
    assert sim.get("io_board_output_1") == 0x10
    assert [(r.function_code, r.address) for r in sim.write_log] == [(16, 2229), (16, 2229)]


def test_counters_and_parameters_are_read_back(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 24: an unknown counter id is refused; a write the controller drops says so."""
    device, sim, _ = r6
    with pytest.raises(CommandRejected, match="counter 7 is not one the controller lists"):
        device.set_counter(7, 1)
    assert sim.write_log == []
    assert "reads 5" in device.set_counter(0, 5)

    def drop_parameter_writes(record: WriteRecord) -> None:
        if record.address == 20300:
            sim.set("parameter_0", 0)  # acknowledged, not applied

    sim.write_hooks.append(drop_parameter_writes)
    with pytest.raises(NotConfirmed, match="wrote 9, reads 0"):
        device.write_parameter(0, 9)
    assert "reads 4" in device.write_parameter(1, 4)


def test_an_abandoned_upload_clears_its_source(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 25: the source does not keep a path cut short."""
    device, sim, _ = r6
    upload = PointUploadSteps(device, 3, 6, 0x3F, list(range(6 * 25)))  # 3 frames
    upload.step()
    assert sim.points[3] == list(range(60)) and upload.result()["points_held"] == 10
    assert "cleared" in upload.abandon()
    assert sim.points[3] == [] and sim.point_counts[3] == 0
    assert upload.result()["points_held"] == 0
    assert device.read_data_source_length(3) == 0


def test_pose_and_state_carry_the_read_time_of_their_own_rows(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 26: the world block is read just before the axis positions, and each
    message's stamp is the time its rows were read."""
    device, _, _ = r6
    plan = device.poll_plan(6, 2)
    assert "world_x" in plan[-2].names and "axis_position_1" in plan[-1].names
    snap = device.poll()
    assert 0 < snap.state_read_time < snap.world_read_time < snap.read_time


def test_an_upload_service_whose_frame_fails_clears_its_source(
    r6: tuple[R6Device, R6SimDevice, DeviceChannel],
) -> None:
    """Decision 25: the service has no cancel, but a frame refused half-way leaves no
    path cut short either."""
    device, sim, _ = r6
    frames = 0

    def refuse_the_second_frame(record: WriteRecord) -> int | None:
        nonlocal frames
        if record.address == R6_MAP["point_count"].address and record.values[0]:
            frames += 1
            if frames == 2:
                return 0x04  # SERVER DEVICE FAILURE
        return None

    sim.write_guards.append(refuse_the_second_frame)
    with pytest.raises(NotConfirmed, match=r"frame 2 of 3 failed .*; source 4 cleared"):
        device.upload_points(4, 6, 0x3F, list(range(6 * 25)))
    assert sim.points[4] == []
