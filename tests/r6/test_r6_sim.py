"""The R6 device layer against the R6 simulator over a real TCP socket (no ROS)."""

from __future__ import annotations

import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator

import pytest

from bridge_core.channel import DeviceChannel
from bridge_core.errors import CommandRejected, DeviceException
from bridge_core.registers import Table
from bridge_core.transport import ModbusLink, TcpSettings
from r6_bridge.device import R6Device
from r6_bridge.registers import NOT_OFFERED, R6_MAP
from r6_bridge.sim import MANUAL_VERSION, R6SimDevice, make_simulator


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
        (lambda d: d.set_output(4, 0, True), "board 4"),
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
    # FC 04 is not used by the bridge and not served.
    assert exception_code(bytes([4]) + struct.pack(">HH", 2185, 1)) == 1
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
    assert sim.running and sim.get("alarm_code") == 0


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
    from bridge_core.poller import Poller, PollOutcome

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
