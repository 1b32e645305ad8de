"""Every example frame of the R6 manual, byte-exact, over a real TCP socket.

The bridge's device layer (through the real pymodbus client of ``bridge_core.wire.transport``) talks
to a replay peer that checks each request PDU against the manual and answers with the
manual's reply; the decoded values must be the ones the manual states. Frames are copied
as printed (MBAP header included) and the header is dropped: our transaction ids differ,
and several of the manual's MBAP length fields are wrong (noted per case).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.transport import ModbusLink, TcpSettings
from r6_bridge.device import R6Device

from ..support.replay import ReplayServer, Step, pdu_of

VERSION_REPLY = (
    "0x00 0x00 0x00 0x00 0x00 0x2c 0x01 0x03 0x2a "
    "0x41 0x4d 0x38 0x2d 0x51 0x43 0x2d 0x52 0x58 0x45 0x2d 0x37 0x2e 0x38 0x2e 0x30 0x32 0x2d "
    "0x62 0x61 0x74 0x65 0x37 0x5f 0x46 0x41 0x4b 0x45 0x5f 0x54 0x47 0x46 0x5f 0x45 0x4e 0x43 "
    "0x4f 0x44 0x45 0x52 0x00 0x00"
)
# The printed reply is one byte short: its byte count (0x2a = 42, i.e. the 0x15 registers
# asked for) and the 41 data bytes shown disagree. The 41 bytes are the 40-character string
# plus its NUL terminator (length register 0x29 = 41 counts the NUL); the 42nd byte is the
# low-byte padding of §3.1.2, appended here.


def run(steps: list[tuple[str, str, str]], action: Callable[[R6Device], Any]) -> Any:
    server = ReplayServer([Step(pdu_of(req), pdu_of(rep), meaning) for req, rep, meaning in steps])
    link = ModbusLink(TcpSettings("127.0.0.1", server.port, timeout_s=2.0))
    channel = DeviceChannel(link, 1, retries=0)
    try:
        result = action(R6Device(channel))
    finally:
        link.close()
        server.close()
    assert server.mismatches == []
    assert len(server.received) == len(steps)
    return result


def test_version_length_and_string() -> None:  # §3.1.1, §3.1.2
    version = run(
        [
            (
                "00 00 00 00 00 06 01 03 00 00 00 01",
                "00 00 00 00 00 05 01 03 02 00 29",
                "version length",
            ),
            (
                "00 00 00 00 00 06 01 03 00 01 00 15",
                VERSION_REPLY,
                "version string, (0x29+1)/2 registers",
            ),
        ],
        lambda d: d.read_version(),
    )
    assert version == "AM8-QC-RXE-7.8.02-bate7_FAKE_TGF_ENCODER"
    assert len(version) + 1 == 0x29  # the length counts the NUL terminator


def test_counter_list() -> None:  # §3.1.3
    ids = run(
        [
            (
                "00 00 00 00 00 06 01 03 00 82 00 01",
                "00 00 00 00 00 05 01 03 02 00 02",
                "counter count",
            ),
            (
                "00 00 00 00 00 06 01 03 00 83 00 04",
                "00 00 00 00 00 0b 01 03 08 00 00 00 00 00 00 00 01",
                "ids of counters 0 and 1",
            ),
        ],
        lambda d: d.read_counter_ids(),
    )
    # High word first: "00000000 00000001" are ids 0 and 1 (low-first would make 65536).
    assert ids == [0, 1]


def test_counter_status() -> None:  # §3.1.4
    result = run(
        [
            (
                "00 00 00 00 00 0B 01 10 08 83 00 02 04 00 00 00 01",
                "00 00 00 00 00 06 01 10 08 83 00 02",
                "select counter id 1",
            ),
            (
                "00 00 00 00 00 06 01 03 08 83 00 06",
                "00 00 00 00 00 0f 01 03 0c 00 00 00 01 00 00 00 0a 00 00 00 05",
                "id, target, current",
            ),
        ],
        lambda d: d.read_counter(1),
    )
    assert result == (1, 0x0A, 0x05)


@pytest.mark.parametrize(
    ("names", "request_frame", "reply_frame", "expected"),
    [
        # §3.1.5: the example calls 3 "configuration mode" (the table knows only 1 and 2).
        (
            ["mode"],
            "00 00 00 00 00 06 01 03 08 89 00 01",
            "00 00 00 00 00 05 01 03 02 00 03",
            {"mode": 3},
        ),
        # §3.1.6
        (
            ["io_board_count"],
            "00 00 00 00 00 06 01 03 08 8a 00 01",
            "00 00 00 00 00 05 01 03 02 00 01",
            {"io_board_count": 1},
        ),
        # §3.1.6 board 0 inputs. The manual's first example asks for 00 01 register but
        # answers 4 bytes; a 32-bit board needs 2 (its own text and examples 2-3 say so).
        (
            ["io_board_input_0"],
            "00 00 00 00 00 06 01 03 08 8b 00 02",
            "00 00 00 00 00 07 01 03 04 00 00 00 00",
            {"io_board_input_0": 0},
        ),
        (
            ["io_board_input_0", "io_board_input_1"],
            "00 00 00 00 00 06 01 03 08 8b 00 04",
            "00 00 00 00 00 0b 01 03 08 00 00 00 00 00 00 00 00",
            {"io_board_input_0": 0, "io_board_input_1": 0},
        ),
        (
            ["io_board_input_1"],
            "00 00 00 00 00 06 01 03 08 8d 00 02",
            "00 00 00 00 00 07 01 03 04 00 00 00 00",
            {"io_board_input_1": 0},
        ),
        # §3.1.6 board 0 outputs
        (
            ["io_board_output_0"],
            "00 00 00 00 00 06 01 03 08 b3 00 02",
            "00 00 00 00 00 07 01 03 04 00 00 00 00",
            {"io_board_output_0": 0},
        ),
        # §3.1.7
        (
            ["axis_count"],
            "00 00 00 00 00 06 01 03 08 db 00 01",
            "00 00 00 00 00 05 01 03 02 00 06",
            {"axis_count": 6},
        ),
        # §3.1.8 (examples 1-3)
        (
            ["axis_position_1"],
            "00 00 00 00 00 06 01 03 08 dc 00 02",
            "00 00 00 00 00 07 01 03 04 00 00 00 00",
            {"axis_position_1": 0.0},
        ),
        (
            ["axis_position_1", "axis_position_2"],
            "00 00 00 00 00 06 01 03 08 dc 00 04",
            "00 00 00 00 00 0b 01 03 08 00 00 00 00 00 00 00 00",
            {"axis_position_1": 0.0, "axis_position_2": 0.0},
        ),
        (
            ["axis_position_2"],
            "00 00 00 00 00 06 01 03 08 de 00 02",
            "00 00 00 00 00 07 01 03 04 00 00 00 00",
            {"axis_position_2": 0.0},
        ),
        # §3.1.9 (examples 1-3)
        (
            ["world_x"],
            "00 00 00 00 00 06 01 03 09 1c 00 02",
            "00 00 00 00 00 07 01 03 04 00 00 00 00",
            {"world_x": 0.0},
        ),
        (
            ["world_x", "world_y"],
            "00 00 00 00 00 06 01 03 09 1c 00 04",
            "00 00 00 00 00 0b 01 03 08 00 00 00 00 00 00 00 00",
            {"world_x": 0.0, "world_y": 0.0},
        ),
        (
            ["world_y"],
            "00 00 00 00 00 06 01 03 09 1e 00 02",
            "00 00 00 00 00 07 01 03 04 00 00 00 00",
            {"world_y": 0.0},
        ),
        # §3.1.10
        (
            ["alarm_code"],
            "00 00 00 00 00 06 01 03 09 5c 00 01",
            "00 00 00 00 00 05 01 03 02 03 25",
            {"alarm_code": 0x0325},
        ),
        # §3.1.11
        (
            ["current_cycle_time"],
            "00 00 00 00 00 06 01 03 09 5d 00 04",
            "00 00 00 00 00 0b 01 03 08 00 00 00 00 00 00 00 00",
            {"current_cycle_time": 0},
        ),
        (
            ["last_cycle_time"],
            "00 00 00 00 00 06 01 03 09 61 00 04",
            "00 00 00 00 00 0b 01 03 08 00 00 00 00 00 00 00 00",
            {"last_cycle_time": 0},
        ),
        # §3.1.12
        (
            ["machine_id"],
            "00 00 00 00 00 06 01 03 09 65 00 01",
            "00 00 00 00 00 05 01 03 02 00 01",
            {"machine_id": 1},
        ),
        # §3.1.13
        (
            ["axis_torque_1"],
            "00 00 00 00 00 06 01 03 09 66 00 01",
            "00 00 00 00 00 05 01 03 02 00 00",
            {"axis_torque_1": 0.0},
        ),
        # §3.1.14
        (
            ["axis_speed_1"],
            "00 00 00 00 00 06 01 03 09 86 00 01",
            "00 00 00 00 00 05 01 03 02 00 00",
            {"axis_speed_1": 0},
        ),
        # §3.1.15
        (
            ["moving"],
            "00 00 00 00 00 06 01 03 09 a6 00 01",
            "00 00 00 00 00 05 01 03 02 00 01",
            {"moving": 1},
        ),
    ],
)
def test_read_examples(
    names: list[str], request_frame: str, reply_frame: str, expected: dict[str, Any]
) -> None:
    values = run([(request_frame, reply_frame, ", ".join(names))], lambda d: d.read_named(*names))
    assert values == expected


def test_nonzero_values_decode_as_the_table_says() -> None:
    # Not in the manual's examples (all zero): a position of -12.345 deg and a 64-bit cycle
    # time, high word first, so a word-order mistake cannot hide behind zeros.
    values = run(
        [
            (
                "00 00 00 00 00 06 01 03 08 dc 00 02",
                "00 00 00 00 00 07 01 03 04 ff ff cf c7",
                "axis 0",
            ),
            (
                "00 00 00 00 00 06 01 03 09 5d 00 04",
                "00 00 00 00 00 0b 01 03 08 00 00 00 01 00 00 00 02",
                "cycle",
            ),
        ],
        lambda d: {**d.read_named("axis_position_1"), **d.read_named("current_cycle_time")},
    )
    assert values["axis_position_1"] == pytest.approx(-12.345)
    assert values["current_cycle_time"] == (1 << 32) + 2


def test_stop_command() -> None:  # §3.2.1
    run(
        [("00 00 00 00 00 06 01 06 4e 20 00 01", "00 00 00 00 00 06 01 06 4e 20 00 01", "stop")],
        lambda d: d.command("stop"),
    )


def test_global_speed() -> None:  # §3.2.2: 0x64 = 10.0 %
    run(
        [("00 00 00 00 00 06 01 06 4e e8 00 64", "00 00 00 00 00 06 01 06 4e e8 00 64", "10.0 %")],
        lambda d: d.set_global_speed(10.0),
    )


def test_io_board_write() -> None:  # §3.3.1
    run(
        [
            (
                "00 00 00 00 00 0B 01 10 08 b3 00 02 04 00 00 00 01",
                "00 00 00 00 00 06 01 10 08 b3 00 02",
                "board 0 output 0 on",
            )
        ],
        lambda d: d.write_board_outputs(0, 1, 0xFFFF_FFFF, boards_in_use=1),
    )


def test_counter_modify() -> None:  # §3.3.2
    run(
        [
            (
                "00 00 00 00 00 13 01 10 4e 52 00 06 0c 00 00 00 01 00 00 00 00 00 00 00 08",
                "00 00 00 00 00 06 01 10 4e 52 00 06",
                "counter 1 current = 8",
            )
        ],
        lambda d: d.write_counter(1, 8),  # set_counter: this frame between checks
    )


def test_output_point() -> None:  # §3.3.3
    run(
        [
            (
                "00 00 00 00 00 0d 01 10 4e 58 00 03 06 00 00 00 01 00 01",
                "00 00 00 00 00 06 01 10 4e 58 00 03",
                "board 0 point 1 on",
            )
        ],
        lambda d: d.set_output(0, 1, True, boards_in_use=1),
    )


@pytest.mark.parametrize(
    ("first", "values", "request_frame", "reply_frame"),
    [
        (
            0,
            [100],
            "00 00 00 00 00 0b 01 10 4f 4c 00 02 04 00 00 00 64",
            "00 00 00 00 00 06 01 10 4f 4c 00 02",
        ),
        (
            1,
            [100],
            "00 00 00 00 00 0b 01 10 4f 4e 00 02 04 00 00 00 64",
            "00 00 00 00 00 06 01 10 4f 4e 00 02",
        ),
        (
            0,
            [100, 200],
            "00 00 00 00 00 0f 01 10 4f 4c 00 04 08 00 00 00 64 00 00 00 C8",
            "00 00 00 00 00 06 01 10 4f 4c 00 04",
        ),
    ],
)
def test_parameter_writes(
    first: int, values: list[int], request_frame: str, reply_frame: str
) -> None:  # §3.3.4
    run(
        [(request_frame, reply_frame, f"parameters {first}..")],
        lambda d: d.write_parameters(first, values),
    )


def test_point_upload() -> None:  # §3.3.5
    # The manual's MBAP lengths here (0b / 0d) and its first reply (4f 4c 00 02) are copy
    # errors; the request PDUs and the table's reply (75 32 00 03) are what we check.
    frames = run(
        [
            (
                "00 00 00 00 00 0d 01 10 75 32 00 03 06 00 64 00 06 00 23",
                "00 00 00 00 00 06 01 10 75 32 00 03",
                "source 100, 6 values, axes 1,2,6",
            ),
            (
                "00 00 00 00 00 3b 01 10 75 35 00 1A 34 00 02 00 01 "
                "00 00 00 01 00 00 00 02 00 00 00 03 00 00 00 04 00 00 00 05 00 00 00 06 "
                "00 00 00 07 00 00 00 08 00 00 00 09 00 00 00 0A 00 00 00 0B 00 00 00 0C",
                "00 00 00 00 00 06 01 10 75 35 00 1a",
                "clear and add 2 points",
            ),
        ],
        lambda d: d.upload_points(100, 6, 0x23, list(range(1, 13))),
    )
    assert frames == 1


def test_large_upload_is_split_into_frames_of_at_most_256_bytes() -> None:
    # 25 points x 6 values: 10 points per frame (2 + 120 registers = 244 bytes of data).
    from r6_bridge.upload import POINT_FRAME_MAX_REGISTERS

    values = list(range(150))
    server_steps = [
        (
            "00 00 00 00 00 0d 01 10 75 32 00 03 06 00 07 00 06 00 3f",
            "00 00 00 00 00 06 01 10 75 32 00 03",
            "config",
        )
    ]
    expected_frames = []
    for first, count, clear in ((0, 10, 1), (10, 10, 0), (20, 5, 0)):
        words = [count, clear]
        for v in values[first * 6 : (first + count) * 6]:
            words += [0, v]
        regs = len(words)
        assert regs <= POINT_FRAME_MAX_REGISTERS and 2 * regs <= 256
        pdu = bytes([1, 0x10, 0x75, 0x35, 0, regs, 2 * regs]) + b"".join(
            w.to_bytes(2, "big") for w in words
        )
        expected_frames.append(pdu)
        server_steps.append(
            (
                "00 00 00 00 00 00 " + pdu.hex(" "),
                f"00 00 00 00 00 06 01 10 75 35 00 {regs:02x}",
                f"points {first}+{count}",
            )
        )
    frames = run(server_steps, lambda d: d.upload_points(7, 6, 0x3F, values))
    assert frames == 3


@pytest.mark.parametrize(
    ("u", "v", "w", "expected"),
    [
        (0.0, 0.0, 0.0, (0.0, 0.0, 0.0, 1.0)),
        (90.0, 0.0, 0.0, (0.7071067811865476, 0.0, 0.0, 0.7071067811865476)),
        (0.0, 90.0, 0.0, (0.0, 0.7071067811865476, 0.0, 0.7071067811865476)),
        (0.0, 0.0, 90.0, (0.0, 0.0, 0.7071067811865476, 0.7071067811865476)),
        # Rz(90) Ry(90): x, y, z, w = (-0.5, 0.5, 0.5, 0.5)
        (0.0, 90.0, 90.0, (-0.5, 0.5, 0.5, 0.5)),
    ],
)
def test_tcp_pose_euler_convention(
    u: float, v: float, w: float, expected: tuple[float, ...]
) -> None:
    from bridge_core.runtime.units import euler_xyz_deg_to_quaternion

    assert euler_xyz_deg_to_quaternion(u, v, w) == pytest.approx(expected, abs=1e-12)
