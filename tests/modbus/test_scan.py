"""modbus_scan against every simulator: the blocks it finds are the simulator's map.

Each simulator is a real pymodbus server in this process (TCP on a free port, or RTU on a
socat pty pair); the scanner runs in-process (``main``) with small ranges around the map
and no pause, or as its console script where its one-line exits are the point. The
expected blocks come from the map (each bridge's registers.py, or the description): the
readable registers the device serves whole, merged into contiguous ranges, within the
ranges scanned.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path

import pytest

from bridge_core.sim.serving import Simulator
from bridge_core.sim.sim_base import SimulatedDevice
from bridge_core.wire.registers import READ_FUNCTION, Table
from modbus_bridge import doc
from modbus_bridge.description import load
from modbus_bridge.scan import READ_ONLY_LINE, main
from modbus_bridge.scan_probe import Prober
from modbus_bridge.sim import make_simulator as make_described
from motec_bridge.sim import make_simulator as make_motec
from r6_bridge.sim import make_simulator as make_r6
from stepper_bridge.sim import make_simulator as make_stepper
from tests.support.serial_pair import PTY_REPLY_TIMEOUT_S, served_on_pty
from xarm_bridge.sim import make_simulator as make_xarm

ROOT = Path(__file__).resolve().parents[2]
DEVICES = ROOT / "config" / "devices"
BAUD = 115200
FAST = ["--pause-ms", "0", "--budget", "20000"]
SCRIPT = Path(sys.executable).parent / "modbus_scan"
# (first, last) ranges per table: the map's addresses and a margin past each end.
Ranges = Mapping[Table, tuple[tuple[int, int], ...]]


@contextmanager
def over_tcp(simulator: Simulator) -> Iterator[tuple[SimulatedDevice, list[str]]]:
    port = simulator.start_tcp()
    try:
        yield simulator.device, ["--host", "127.0.0.1", "--port", str(port)]
    finally:
        simulator.stop()


@contextmanager
def over_pty(simulator: Simulator, unit: int = 1) -> Iterator[tuple[SimulatedDevice, list[str]]]:
    with served_on_pty(simulator, BAUD) as bridge_end:
        link = ["--serial", bridge_end, "--baudrate", str(BAUD)]
        timing = ["--timeout-s", str(PTY_REPLY_TIMEOUT_S), "--unit-id", str(unit)]
        yield simulator.devices[unit], link + timing


def served(table: Table, device: SimulatedDevice, ranges: Ranges | None = None) -> set[int]:
    """The map's readable addresses of ``table`` that the device answers when each value
    is read whole (the R6 serves the axes and IO boards it has, §3.1.6 / §3.1.8); with
    ``ranges``, of the values wholly inside them (a value cut by a range's end cannot be
    read)."""
    spans = None if ranges is None else ranges.get(table, ())
    found: set[int] = set()
    for register in device.map:
        if register.table is not table or not register.access.readable:
            continue
        if spans is not None and not any(
            first <= register.address and register.end - 1 <= last for first, last in spans
        ):
            continue
        reply = device.read(READ_FUNCTION[table], register.address, register.count)
        if isinstance(reply, list):
            found.update(register.addresses())
    return found


def expected(
    device: SimulatedDevice, ranges: Ranges, extra: Callable[[Table, Ranges], set[int]]
) -> dict[Table, list[tuple[int, int]]]:
    """Per table: the contiguous blocks of the map (plus ``extra``) inside ``ranges``."""
    return {
        table: contiguous(served(table, device, ranges) | extra(table, ranges)) for table in ranges
    }


def contiguous(addresses: Iterable[int]) -> list[tuple[int, int]]:
    """Addresses merged into blocks (first, count), written here again so that a broken
    merge in the scanner cannot agree with itself."""
    blocks: list[tuple[int, int]] = []
    for address in sorted(set(addresses)):
        if blocks and sum(blocks[-1]) == address:
            blocks[-1] = (blocks[-1][0], blocks[-1][1] + 1)
        else:
            blocks.append((address, 1))
    return blocks


def range_args(ranges: Ranges) -> list[str]:
    args: list[str] = []
    for table, spans in ranges.items():
        args += [
            "--range",
            f"{table.value}:" + ",".join(f"{first}-{last}" for first, last in spans),
        ]
    return args


def written_blocks(path: Path) -> dict[Table, list[tuple[int, int]]]:
    """The skeleton as modbus_bridge loads it: each table's rows merged into blocks."""
    register_map = load(path).device.register_map
    blocks: dict[Table, list[tuple[int, int]]] = {}
    for table in Table:
        addresses = [a for r in register_map if r.table is table for a in r.addresses()]
        if addresses:
            blocks[table] = contiguous(addresses)
    return blocks


def no_extra(table: Table, ranges: Ranges) -> set[int]:
    return set()


def _r6() -> AbstractContextManager[tuple[SimulatedDevice, list[str]]]:
    return over_tcp(make_r6())


def _r6_extra(device: SimulatedDevice) -> Callable[[Table, Ranges], set[int]]:
    # R6 §4: FC 04 reads the FC 03 rows, so the input table answers as the holding one.
    def extra(table: Table, ranges: Ranges) -> set[int]:
        if table is not Table.INPUT:
            return set()
        return served(Table.HOLDING, device, {Table.HOLDING: ranges[Table.INPUT]})

    return extra


def _motec_extra(device: SimulatedDevice) -> Callable[[Table, Ranges], set[int]]:
    # The drive answers every address up to its last parameter, 0 where the manual
    # defines nothing (motec_bridge/registers.py, read_undefined_ok): the simulator's
    # extra addresses, beyond the map's rows.
    def extra(table: Table, ranges: Ranges) -> set[int]:
        spans = ranges[table]
        return {
            a
            for t, a in device.readable
            if t is table and any(first <= a <= last for first, last in spans)
        }

    return extra


# name -> (the simulator served, its ranges, what it answers beyond its map)
CASES: dict[
    str,
    tuple[
        Callable[[], AbstractContextManager[tuple[SimulatedDevice, list[str]]]],
        Ranges,
        Callable[[SimulatedDevice], Callable[[Table, Ranges], set[int]]],
    ],
] = {
    "r6": (
        _r6,
        {
            # Odd-address u32 counters from 131, the axes' rows at 2187 / 2227 (six of
            # eight axes: 2189-2196 refused), the running rows, and the last block.
            Table.HOLDING: ((0, 300), (2150, 2300), (22230, 22310), (29990, 30010)),
            Table.INPUT: ((0, 70),),
            Table.COIL: ((0, 300),),
            Table.DISCRETE_INPUT: ((0, 20),),
        },
        _r6_extra,
    ),
    "xarm": (
        lambda: over_tcp(make_xarm()),
        {
            Table.HOLDING: ((0, 40),),
            Table.INPUT: ((0, 120),),
            Table.COIL: ((0, 520),),
            Table.DISCRETE_INPUT: ((0, 50),),
        },
        lambda device: no_extra,
    ),
    "stepper": (
        lambda: over_pty(make_stepper(reply_delay_s=0.0)),
        {Table.HOLDING: ((0, 220), (295, 310)), Table.INPUT: ((0, 10),), Table.COIL: ((0, 20),)},
        lambda device: no_extra,
    ),
    "motec": (
        lambda: over_pty(make_motec([3]), unit=3),
        {Table.HOLDING: ((0, 290),), Table.COIL: ((0, 30),), Table.DISCRETE_INPUT: ((0, 30),)},
        _motec_extra,
    ),
    "inverter_tcp_f32": (
        lambda: over_tcp(make_described(load(DEVICES / "inverter_tcp_f32.yaml"))),
        {Table.HOLDING: ((180, 220),), Table.INPUT: ((90, 120),), Table.COIL: ((0, 10),)},
        lambda device: no_extra,
    ),
    "xarm_yaml": (
        lambda: over_tcp(make_described(load(DEVICES / "xarm.yaml"))),
        {
            Table.HOLDING: ((0, 40),),
            Table.INPUT: ((0, 120),),
            Table.COIL: ((0, 170),),
            Table.DISCRETE_INPUT: ((0, 50),),
        },
        lambda device: no_extra,
    ),
    "vfd_rtu": (
        lambda: over_pty(make_described(load(DEVICES / "vfd_rtu.yaml"))),
        {Table.HOLDING: ((250, 270), (8180, 8200), (8440, 8460)), Table.INPUT: ((0, 10),)},
        lambda device: no_extra,
    ),
    "rtu_multidrop": (
        lambda: over_pty(make_described(load(DEVICES / "rtu_multidrop.yaml")), unit=2),
        {Table.HOLDING: ((35, 45), (165, 180), (270, 280)), Table.INPUT: ((0, 10),)},
        lambda device: no_extra,
    ),
}


@pytest.mark.parametrize("name", CASES)
def test_the_scan_finds_the_map(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    serve, ranges, extra = CASES[name]
    out = tmp_path / "scan.yaml"
    with serve() as (device, args):
        want = expected(device, ranges, extra(device))
        code = main([*args, *range_args(ranges), *FAST, "-o", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert printed.out.splitlines()[0] == READ_ONLY_LINE
    got = written_blocks(out)
    assert got == {table: blocks for table, blocks in want.items() if blocks}, printed.out
    link = load(out).device.spec.device.link  # the link scanned, as the file's default
    assert link is not None
    if link.rtu is not None:
        assert link.rtu.serial_port == args[args.index("--serial") + 1]
    else:
        assert link.tcp is not None and link.tcp.port == int(args[args.index("--port") + 1])
    # The summary names each block (table, first, last).
    for blocks in got.values():
        for first, count in blocks:
            assert f"{first:>6} {first + count - 1:>6} {count:>6}" in printed.out


def test_the_skeleton_loads_and_renders(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The file loads as modbus_bridge loads a description and modbus_doc renders it; a
    value a block edge cut (xArm input 34-35, edges every 4 from 31) is one u32 row."""
    out = tmp_path / "xarm.yaml"
    with over_tcp(make_xarm()) as (_, link):
        ranges = {Table.HOLDING: ((0, 40),), Table.INPUT: ((31, 40),), Table.COIL: ((0, 5),)}
        args = [*link, *range_args(ranges), *FAST, "--max-registers", "4", "--name", "arm"]
        assert main([*args, "-o", str(out)]) == 0
    device = load(out).device
    assert device.name == "arm" and device.unit_id == 1
    assert device.spec.device.link is not None and device.spec.device.link.tcp is not None
    assert device.spec.device.function_codes == [1, 3, 4]
    assert device.spec.device.max_read_registers == 4
    registers = device.register_map
    assert registers["input_34"].value_type.label == "u32"
    assert registers["input_33"].value_type.label == "u16"
    assert registers["coil_5"].value_type.label == "bool"
    assert all(not r.access.writable for r in registers)
    text = out.read_text()
    assert "#     holding 11-31: ILLEGAL DATA ADDRESS (0x02)" in text
    capsys.readouterr()
    assert doc.main([str(out)]) == 0
    markdown = capsys.readouterr().out
    assert "`holding_0`" in markdown and "`coil_5`" in markdown and "`input_34`" in markdown


def test_a_scan_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Every request the device saw was a read (FC 01-04), and it logged no write."""
    with over_tcp(make_xarm()) as (device, link):
        device.log_reads = True
        ranges = {t: ((0, 140),) for t in Table}
        assert main([*link, *range_args(ranges), *FAST, "-o", str(tmp_path / "x.yaml")]) == 0
    out = capsys.readouterr().out
    assert device.write_log == []
    codes = {record.function_code for record in device.read_log}
    assert codes == {1, 2, 3, 4}
    assert f"wrote {tmp_path / 'x.yaml'} ({len(device.read_log)} requests" in out


def test_a_device_that_stops_answering_ends_the_scan_in_one_line(tmp_path: Path) -> None:
    simulator = make_xarm()
    device = simulator.device
    read = device.read

    def read_then_fall_silent(function_code: int, address: int, count: int) -> list[int] | int:
        if function_code == 4:  # the holding table answered; the input table goes silent
            simulator.withhold_replies = True
        return read(function_code, address, count)

    device.read = read_then_fall_silent  # type: ignore[method-assign]
    out = tmp_path / "x.yaml"
    with over_tcp(simulator) as (_, link):
        ranges = ["--range", "holding:0-40", "--range", "input:0-40"]
        result = subprocess.run(
            [str(SCRIPT), *link, *ranges, "--timeout-s", "0.3", "--pause-ms", "0", "-o", str(out)],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert result.returncode == 1, result.stdout + result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert "stopped answering" in lines[0] and "holding" in lines[0], lines[0]
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--range", "holding:9-3"], "FIRST <= LAST"),
        (["--range", "registers:0-9"], "TABLE one of"),
        (["--max-registers", "126"], "outside 1 .. 125"),
        (["--baudrate", "19201"], "invalid choice"),
        (["--range", "coil:0-9", "--range", "coil:20-29"], "one per table"),
    ],
)
def test_a_bad_option_is_one_line(
    args: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exited:
        sys.exit(main(["--host", "127.0.0.1", *args, "-o", str(tmp_path / "x.yaml")]))
    assert exited.value.code == 2
    printed = capsys.readouterr()
    assert printed.out == ""
    lines = printed.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("modbus_scan: error:"), printed.err
    assert says in lines[0]


def test_the_console_script_says_a_bad_option_in_one_line(tmp_path: Path) -> None:
    result = subprocess.run(
        [str(SCRIPT), "--serial", "/dev/null", "--unit-id", "0", "-o", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and result.stdout == "", result.stdout + result.stderr
    assert result.stderr.splitlines() == [
        "modbus_scan: error: --unit-id 0 is the broadcast on a serial line: no device answers it"
    ]


def test_a_device_that_never_answers_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No reply at all (another unit id, a wrong line setting): three requests, one line."""
    simulator = make_xarm()
    simulator.withhold_replies = True
    with over_tcp(simulator) as (_, link):
        args = [*link, "--range", "holding:0-40", "--timeout-s", "0.2", "--pause-ms", "0"]
        assert main([*args, "-o", str(tmp_path / "x.yaml")]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "no reply to 3 requests in a row" in err[0], err
    assert "(after 3 requests; nothing written" in err[0]
    assert not (tmp_path / "x.yaml").exists()


def test_the_budget_ends_the_scan_with_what_was_read(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.yaml"
    with over_tcp(make_xarm()) as (device, link):
        device.log_reads = True
        ranges = ["--range", "holding:0-40", "--range", "coil:0-50"]
        assert main([*link, *ranges, "--pause-ms", "0", "--budget", "30", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert len(device.read_log) == 30
    assert "the request budget (30) ran out at holding" in printed
    text = out.read_text()
    assert "incomplete: the request budget ran out at holding" in text
    assert "incomplete: the request budget ran out at coil 0" in text
    assert "holding_0" in {r.name for r in load(out).device.register_map}


def test_requests_are_paced() -> None:
    """Each request waits the pause after the previous reply (a fake clock)."""
    now = [0.0]
    slept: list[float] = []

    class Reader:
        def read_registers(
            self, address: int, count: int, table: Table = Table.HOLDING
        ) -> list[int]:
            now[0] += 0.01  # the reply takes 10 ms
            return [0] * count

        def read_bits(self, address: int, count: int, table: Table = Table.COIL) -> list[bool]:
            return [False] * count

    def sleep(seconds: float) -> None:
        slept.append(round(seconds, 9))
        now[0] += seconds

    prober = Prober(Reader(), budget=3, pause_s=0.05, clock=lambda: now[0], sleep=sleep)
    for address in range(3):
        assert prober.read(Table.HOLDING, address, 1) is None
    assert slept == [0.05, 0.05]
