"""``bridge_replay`` (bridge_core/sim/replay.py) without ROS: which recorded reply a
request gets, what a request never recorded gets, the write log, RTU on a real pty, and
a bag that cannot be served. The bag from a running bridge, replayed into the same
``joint_states``: tests/core/ros/test_wire_replay.py."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest

from bridge_core.sim.logs import WriteRecord, read_write_log
from bridge_core.sim.replay import (
    NOT_RECORDED_EXCEPTION,
    Replayer,
    SerialReplay,
    TcpReplay,
    frames_of,
    rtu_adu,
)
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import DeviceException, LinkTimeout
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings, TcpSettings

from ...support.ros import ROOT
from ...support.serial_pair import PTY_REPLY_TIMEOUT_S, socat_pair

UNIT = 1
OK, EXCEPTION, TIMEOUT = 0, 1, 2
READ = bytes.fromhex("0300000001")  # read holding register 0, one
WRITE = bytes.fromhex("0600050007")  # write 7 to holding register 5


def tcp(tid: int, pdu: bytes, unit: int = UNIT) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def register(value: int) -> bytes:
    return bytes.fromhex("0302") + value.to_bytes(2, "big")


# A poll, a write, a poll that sees it, and a request the device did not answer.
FRAMES = [
    (1, False, tcp(1, READ), tcp(1, register(10)), OK, 100.0),
    (2, False, tcp(2, WRITE), tcp(2, WRITE), OK, 100.1),
    (3, False, tcp(3, READ), tcp(3, register(7)), OK, 100.2),
    (4, False, tcp(4, READ), tcp(4, register(8)), OK, 100.3),
    (5, False, tcp(5, bytes.fromhex("0300010001")), b"", TIMEOUT, 100.4),
]


def test_each_request_gets_the_nearest_recorded_reply_after_the_last_one_answered() -> None:
    recording = frames_of(FRAMES)
    assert recording.answer(UNIT, READ) == register(10)
    assert recording.answer(UNIT, WRITE) == WRITE
    assert recording.answer(UNIT, READ) == register(7)  # recorded after the write
    assert recording.answer(UNIT, READ) == register(8)
    assert recording.answer(UNIT, READ) == register(8)  # past the end: the last one held
    # The write again: its only reply, and the cursor goes back with it.
    assert recording.answer(UNIT, WRITE) == WRITE
    assert recording.answer(UNIT, READ) == register(7)
    assert recording.answer(UNIT, bytes.fromhex("0300010001")) is None  # recorded: no reply
    assert "5 TCP frames of unit(s) 1, 0.4 s" in recording.summary()


def test_a_request_never_recorded_gets_exception_4_and_an_unknown_unit_nothing(
    capsys: pytest.CaptureFixture[str],
) -> None:
    recording = frames_of(FRAMES)
    unknown = bytes.fromhex("0300630001")
    assert recording.answer(UNIT, unknown) == bytes([0x83, NOT_RECORDED_EXCEPTION])
    assert "not recorded: unit 1 request 0300630001" in capsys.readouterr().err
    assert recording.answer(UNIT + 1, READ) is None
    assert recording.not_recorded == 1


def test_over_tcp_the_bridge_side_sees_the_recording_and_writes_are_logged(
    tmp_path: Path,
) -> None:
    log_path = tmp_path / "writes.jsonl"
    with log_path.open("a") as log:
        served = TcpReplay(Replayer(frames_of(FRAMES), log))
        link = ModbusLink(TcpSettings("127.0.0.1", served.port, timeout_s=0.3))
        channel = DeviceChannel(link, UNIT, retries=0)
        try:
            assert channel.read_registers(0, 1) == [10]
            channel.write_register(5, 7)
            assert channel.read_registers(0, 1) == [7]
            with pytest.raises(DeviceException) as refused:
                channel.read_registers(99, 1)
            assert refused.value.exception_code == NOT_RECORDED_EXCEPTION
            with pytest.raises(LinkTimeout):
                channel.read_registers(1, 1)  # recorded as a timeout: no reply
        finally:
            link.close()
            served.stop()
    (write,) = read_write_log(log_path)
    assert write == WriteRecord(write.time, UNIT, 0x06, Table.HOLDING, 5, (7,))


def test_an_rtu_recording_is_served_on_a_pty() -> None:
    frames = [
        (1, True, rtu_adu(UNIT, READ), rtu_adu(UNIT, register(42)), OK, 1.0),
        (2, True, rtu_adu(UNIT, WRITE), rtu_adu(UNIT, bytes([0x86, 0x02])), EXCEPTION, 1.1),
    ]
    with socat_pair() as (bridge_end, device_end, _):
        served = SerialReplay(Replayer(frames_of(frames)), device_end, 115200, "N", 1)
        link = ModbusLink(SerialSettings(bridge_end, 115200, timeout_s=PTY_REPLY_TIMEOUT_S))
        channel = DeviceChannel(link, UNIT)
        try:
            assert channel.read_registers(0, 1) == [42]
            with pytest.raises(DeviceException) as refused:
                channel.write_register(5, 7)  # the device refused it in the recording
            assert refused.value.exception_code == 0x02
        finally:
            link.close()
            served.stop()


@pytest.mark.parametrize("kind", ["missing", "malformed", "no frames"])
def test_a_bag_that_cannot_be_served_is_one_line_and_exit_2(tmp_path: Path, kind: str) -> None:
    bag = tmp_path / "bag"
    if kind != "missing":
        bag.mkdir()
        (bag / "metadata.yaml").write_text(
            "garbage: [" if kind == "malformed" else _EMPTY_BAG_METADATA
        )
    result = subprocess.run(
        [sys.executable, "-m", "bridge_core.sim.replay", str(bag), "--port", "0"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr and lines[0].startswith("bridge_replay: ")
    assert str(bag) in lines[0]


# A rosbag2 bag's metadata with no topics (what a recorder writes that never saw one).
_EMPTY_BAG_METADATA = """rosbag2_bagfile_information:
  version: 9
  storage_identifier: mcap
  relative_file_paths: []
  duration: {nanoseconds: 0}
  starting_time: {nanoseconds_since_epoch: 0}
  message_count: 0
  topics_with_message_count: []
  compression_format: ''
  compression_mode: ''
  files: []
  custom_data: {}
  ros_distro: jazzy
"""
