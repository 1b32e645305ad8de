"""Device personalities (bridge_core/sim/personality.py): a simulator can play a device
that answers late (a delay drawn per reply), one that acknowledges a motion write and
changes nothing, and one that leaves Nagle on. Raw frames on a real TCP socket and a pty."""

from __future__ import annotations

import argparse
import struct
import time
from collections.abc import Iterator, Mapping
from typing import ClassVar

import pytest
import serial
from pymodbus.framer import FramerRTU

from bridge_core.sim.logs import WriteRecord
from bridge_core.sim.personality import DelayRange, add_ignore_argument, delay_range_ms
from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.registers import Access, DeviceLimits, Register, RegisterMap, Table, ValueType

from ...support.serial_pair import socat_pair
from .test_sim_strict import tcp_request

UNIT = 1
MAP = RegisterMap(
    "personality",
    (
        Register("speed", 0, ValueType.U16, "test", access=Access.READ_WRITE),
        Register("setpoint", 1, ValueType.U16, "test", access=Access.READ_WRITE),
        Register("run", 0, ValueType.BOOL, "test", table=Table.COIL, access=Access.READ_WRITE),
    ),
    DeviceLimits(function_codes=frozenset({1, 3, 5, 6, 16})),
)


class Obedient(SimulatedDevice):
    """A device whose ``run`` coil and ``speed`` register are motion writes; a write of
    ``run`` starts a counter the behaviour hook keeps (what an ignored write must not do)."""

    IGNORABLE: ClassVar[Mapping[str, str]] = {"run": "coil 0", "speed": "register 0"}

    def __init__(self) -> None:
        super().__init__(MAP, UNIT)
        self.hooked: list[WriteRecord] = []
        self.write_hooks.append(self.hooked.append)

    def write_names(self, record: WriteRecord) -> frozenset[str]:
        if record.table is Table.COIL and record.address == 0:
            return frozenset({"run"})
        if record.table is Table.HOLDING and record.address == 0:
            return frozenset({"speed"})
        return frozenset()


@pytest.mark.parametrize(
    ("text", "low", "high"),
    [("35", 0.035, 0.035), ("35:300", 0.035, 0.3), ("0", 0.0, 0.0), ("0.5:0.5", 0.0005, 0.0005)],
)
def test_delay_range_known_vectors(text: str, low: float, high: float) -> None:
    assert delay_range_ms(text) == DelayRange(pytest.approx(low), pytest.approx(high))  # type: ignore[arg-type]


@pytest.mark.parametrize("text", ["", "a", "300:35", "-1", "1:2:3", "1:", "20000"])
def test_delay_range_refuses_in_one_line(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError) as err:
        delay_range_ms(text)
    assert "\n" not in str(err.value)


def test_ignore_argument_names_the_simulators_writes(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    add_ignore_argument(parser, Obedient.IGNORABLE)
    assert parser.parse_args(["--ignore", "run,speed"]).ignore == {"run", "speed"}
    assert parser.parse_args([]).ignore == frozenset()
    with pytest.raises(SystemExit):
        parser.parse_args(["--ignore", "jog"])
    err = capsys.readouterr().err
    assert "unknown motion write jog; this simulator's names: run, speed" in err


def test_ignore_in_process_refuses_an_unknown_name() -> None:
    sim = Simulator([Obedient()])
    with pytest.raises(ValueError, match="unknown motion write jog"):
        sim.ignore(["jog"])


@pytest.fixture
def obedient() -> Iterator[tuple[Simulator, Obedient, int]]:
    device = Obedient()
    sim = Simulator([device])
    port = sim.start_tcp()
    try:
        yield sim, device, port
    finally:
        sim.stop()


def test_an_ignored_write_is_acknowledged_as_the_manual_says_and_changes_nothing(
    obedient: tuple[Simulator, Obedient, int],
) -> None:
    sim, device, port = obedient
    sim.ignore(["run", "speed"])
    # FC 05 and FC 06 echo the request; FC 16 answers address and count.
    assert tcp_request(port, bytes.fromhex("05 0000 FF00")) == bytes.fromhex("05 0000 FF00")
    assert tcp_request(port, bytes.fromhex("06 0000 0123")) == bytes.fromhex("06 0000 0123")
    assert tcp_request(port, bytes.fromhex("10 0000 0002 04 0007 0009")) == bytes.fromhex(
        "10 0000 0002"
    )
    # Nothing stored, no behaviour; each one logged as ignored.
    assert device.get("run") is False
    assert device.get("speed") == 0
    assert device.hooked == []
    assert [(r.function_code, r.ignored) for r in device.write_log] == [
        (5, True),
        (6, True),
        (16, True),
    ]
    # A write that is not a named motion write goes through.
    assert tcp_request(port, bytes.fromhex("06 0001 0042")) == bytes.fromhex("06 0001 0042")
    assert device.get("setpoint") == 0x42
    assert device.write_log[-1].ignored is False
    # The same writes obeyed once the personality is off.
    sim.ignore([])
    assert tcp_request(port, bytes.fromhex("05 0000 FF00")) == bytes.fromhex("05 0000 FF00")
    assert device.get("run") is True
    assert len(device.hooked) == 2


def test_an_echo_is_the_request_even_when_the_device_changes_the_value_at_once(
    obedient: tuple[Simulator, Obedient, int],
) -> None:
    _, device, port = obedient
    # A command register the device clears as soon as it takes the command.
    device.write_hooks.append(lambda record: device.set("speed", 0))
    assert tcp_request(port, bytes.fromhex("06 0000 0005")) == bytes.fromhex("06 0000 0005")
    assert device.get("speed") == 0


def _timed_tcp_reads(port: int, n: int) -> list[float]:
    times = []
    for _ in range(n):
        start = time.monotonic()
        assert tcp_request(port, bytes.fromhex("03 0000 0001")) is not None
        times.append(time.monotonic() - start)
    return times


def test_a_tcp_round_trip_is_drawn_in_its_range(obedient: tuple[Simulator, Obedient, int]) -> None:
    sim, _, port = obedient
    sim.set_round_trip(0.02, 0.06)
    times = _timed_tcp_reads(port, 12)
    assert min(times) >= 0.02
    # Drawn, not fixed: the replies do not all take the same time (a fixed 20 ms would
    # put them all within a few ms of each other; drawn in 20-60 ms they spread).
    draws = [sim.round_trip() for _ in range(200)]
    assert min(draws) >= 0.02 and max(draws) <= 0.06 and max(draws) - min(draws) > 0.02


def test_nagle_is_left_on_only_when_asked(obedient: tuple[Simulator, Obedient, int]) -> None:
    sim, _, port = obedient
    assert tcp_request(port, bytes.fromhex("03 0000 0001")) is not None
    sim.nagle = True
    assert tcp_request(port, bytes.fromhex("03 0000 0001")) is not None
    assert sim.connections_nodelay == [True, False]


def test_an_rtu_reply_waits_its_drawn_delay_after_the_request() -> None:
    device = Obedient()
    sim = Simulator([device])
    sim.set_reply_delay(0.05, 0.12)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, 19200)
        try:
            frame = bytes.fromhex("01 03 0000 0001")
            frame += struct.pack(">H", FramerRTU.compute_CRC(frame))
            times = []
            with serial.Serial(bridge_end, 19200, timeout=1.0) as port:
                for _ in range(6):
                    port.reset_input_buffer()
                    start = time.monotonic()
                    port.write(frame)
                    reply = port.read(7)
                    times.append(time.monotonic() - start)
                    assert reply[:3] == bytes.fromhex("01 03 02")
            assert min(times) >= 0.05
        finally:
            sim.stop()
