#!/usr/bin/env python3
"""Pipelined Modbus TCP bench: poll rate at simulated round trips, by ``max_in_flight``.

    .venv/bin/python bench/pipelining.py [--devices r6,xarm] [--round-trips-ms 0,1,5]
        [--windows 1,4,13] [--nagle off,on] [--duration 2] [--repeats 3] [--json PATH]

For each device and simulated round trip (the simulator's ``--reply-delay-ms``: half each
way, requests in flight overlap; docs/architecture.md, "Pipelined Modbus TCP") the
simulator runs in a process of its own, and this process polls it as fast as it can:

- ``bare``: a bare sync pymodbus ``ModbusTcpClient`` loop issuing the device's full poll
  plan (R6 13 reads, xArm 8), one request at a time (bench/bare_loops.py's bare loop
  reads the device's rate groups instead, as the node does);
- ``N``: the device layer (``R6Device.poll`` / ``XArmDevice.poll``: the fast group every
  poll, the slow group once a second) through a ``DeviceChannel`` with ``max_in_flight``
  N (1 = one request at a time, as before this work).

``--nagle on`` runs the simulator with its ``--nagle`` personality: a device that leaves
Nagle's algorithm on for its replies (seen: pipelined, each reply then waited
for the client's delayed ACK; ``bridge_core.wire.pipeline`` acknowledges at once).

Each figure is the median over ``--repeats`` rounds (every window measured once per
round, in turn); also printed: the median transaction time one at a time (the round trip
the simulator actually gives on this machine, its scheduling included), the CPU of this
process per poll, and the ratio N / 1. Asserts nothing (bench/README.md).

bench/read_rates.py reuses the loops: ``bare_rate`` with the device's own fast and slow
plans (``device_groups``), ``device_rate`` with an observer of its snapshots, against
``controlled_simulator`` (the same simulator, whose joint register it can set).
"""

from __future__ import annotations

import argparse
import importlib
import json
import multiprocessing
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.bridge_profiles import PROFILES  # noqa: E402
from bench.change_probe import answer_changes  # noqa: E402
from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S  # noqa: E402
from bridge_core.wire.channel import DeviceChannel  # noqa: E402
from bridge_core.wire.planner import ReadRequest  # noqa: E402
from bridge_core.wire.transport import ModbusLink, TcpSettings  # noqa: E402

UNIT_ID = 1
TIMEOUT_S = 1.0
SIM_START_S = 20.0
WARMUP_POLLS = 3
DEVICES = ("r6", "xarm")
Plan = list[tuple[str, int, int]]  # (table, address, count) per request


def make_device(name: str, channel: DeviceChannel) -> Any:
    if name == "r6":
        from r6_bridge.device import R6Device

        return R6Device(channel)
    from xarm_bridge.device import XArmDevice

    return XArmDevice(channel)


def as_plan(requests: Sequence[ReadRequest]) -> Plan:
    return [(r.table.value, r.address, r.count) for r in requests]


def full_plan(name: str) -> Plan:
    """(table, address, count) of the device's full poll plan (the bare loop's)."""
    if name == "r6":
        from r6_bridge.device import R6Device

        plan = R6Device(None).poll_plan(6, 1)  # type: ignore[arg-type]
    else:
        from xarm_bridge.device import POLL_PLAN

        plan = POLL_PLAN
    return as_plan(plan)


def device_groups(name: str, port: int) -> tuple[Plan, Plan]:
    """The device layer's fast and slow plans, in its order, as it sets them on its first
    poll (the R6 plans by the counts it reads): a bare loop of the same plan issues them."""
    link = ModbusLink(TcpSettings("127.0.0.1", port, TIMEOUT_S))
    device = make_device(name, DeviceChannel(link, UNIT_ID))
    try:
        device.poll()
    finally:
        link.close()
    return as_plan(device.groups.fast), as_plan(device.groups.slow)


@contextmanager
def simulator(name: str, round_trip_ms: float, nagle: bool = False) -> Iterator[int]:
    """The device's simulator in a process of its own; ``nagle``: its ``--nagle``
    personality (a device that leaves Nagle's algorithm on for its replies)."""
    with tempfile.TemporaryDirectory() as tmp:
        port_file = Path(tmp) / "port"
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                f"{name}_bridge.sim",
                "--port",
                "0",
                "--port-file",
                str(port_file),
                "--reply-delay-ms",
                str(round_trip_ms),
                *(["--nagle"] if nagle else []),
            ],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + SIM_START_S
            while not port_file.exists() or not port_file.read_text():
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit(f"{name}_sim did not start")
                time.sleep(0.05)
            yield int(port_file.read_text())
        finally:
            proc.terminate()
            proc.wait(10)


def observed(
    poll: Callable[[], object], observer: Callable[[object, float], None]
) -> Callable[[], object]:
    """``poll``, telling ``observer`` of each snapshot and the time it returned."""

    def cycle() -> object:
        snapshot = poll()
        observer(snapshot, time.monotonic())
        return snapshot

    return cycle


def serve_controlled(
    name: str, round_trip_ms: float, control: Connection[Any, Any], stop: Any
) -> None:
    """The device's simulator on a free port with the simulated round trip, until ``stop``
    is set (a process of its own): sends the port, then sets joint 1 (the register of
    bridge_profiles.py's profile) to each value ``control`` brings
    (``change_probe.answer_changes``). Built as latency_phase.py (bridge_bench.py) builds it
    (``make_simulator``: R6 not running, xArm sleeping, so its tick leaves the joints
    alone), not through its command line (``simulator``), so its registers can be set."""
    profile = PROFILES[name]
    sim = importlib.import_module(f"{profile.simulator}.sim").make_simulator(*profile.sim_args)
    sim.round_trip_s = round_trip_ms / 1000.0
    with sim:
        control.send(sim.start_tcp("127.0.0.1", 0))
        register = profile.joint_register
        answer_changes(control, stop, lambda value: sim.device.set(register, value))


@contextmanager
def controlled_simulator(
    name: str, round_trip_ms: float
) -> Iterator[tuple[int, Connection[Any, Any]]]:
    """(port, control) of ``serve_controlled`` in a process of its own, for the block."""
    mp = multiprocessing.get_context("spawn")
    mine, theirs = mp.Pipe()
    stop = mp.Event()
    proc = mp.Process(target=serve_controlled, args=(name, round_trip_ms, theirs, stop))
    proc.start()
    try:
        if not mine.poll(SIM_START_S):
            raise SystemExit(f"{name} simulator did not start")
        yield int(mine.recv()), mine
    finally:
        stop.set()
        proc.join(10)
        if proc.is_alive():
            proc.kill()
            proc.join(5)


def measure(cycle: Callable[[], object], duration_s: float) -> tuple[float, float]:
    """Polls per second and CPU (this process) per poll in ``duration_s``."""
    for _ in range(WARMUP_POLLS):
        cycle()
    polls = 0
    cpu = time.process_time()
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < duration_s:
        cycle()
        polls += 1
    return polls / elapsed, (time.process_time() - cpu) / max(polls, 1)


def bare_rate(
    name: str,
    port: int,
    duration_s: float,
    fast: Plan | None = None,
    slow: Plan | None = None,
    slow_period_s: float = SLOW_POLL_PERIOD_DEFAULT_S,
) -> tuple[float, float]:
    """Polls/s and CPU per poll of a bare pymodbus loop: ``fast`` (default: the device's
    full plan) every poll, ``slow`` first in a poll once ``slow_period_s`` has passed since
    it was last read (as ``PollGroups`` does)."""
    from pymodbus.client import ModbusTcpClient

    client = ModbusTcpClient("127.0.0.1", port=port, timeout=TIMEOUT_S, retries=0)
    if not client.connect():  # type: ignore[no-untyped-call]  # untyped in pymodbus 3.16
        raise SystemExit(f"bare loop: cannot connect to port {port}")
    read = {
        "coil": client.read_coils,
        "discrete_input": client.read_discrete_inputs,
        "holding": client.read_holding_registers,
        "input": client.read_input_registers,
    }
    every_poll = [
        (read[table], address, count)
        for table, address, count in (full_plan(name) if fast is None else fast)
    ]
    slow_requests = [(read[table], address, count) for table, address, count in slow or []]
    slow_due = 0.0  # read in the first poll

    def cycle() -> None:
        nonlocal slow_due
        requests = every_poll
        if slow_requests and time.monotonic() >= slow_due:
            requests = slow_requests + every_poll
        for method, address, count in requests:
            if method(address, count=count, device_id=UNIT_ID).isError():
                raise RuntimeError(f"bare loop: exception reply at {address}")
        if requests is not every_poll:
            slow_due = time.monotonic() + slow_period_s

    try:
        return measure(cycle, duration_s)
    finally:
        client.close()  # type: ignore[no-untyped-call]


def device_rate(
    name: str,
    port: int,
    window: int,
    duration_s: float,
    observer: Callable[[object, float], None] | None = None,
) -> tuple[float, float, float, int]:
    """Polls/s, CPU per poll, median transaction time (s), fallbacks. ``observer``: told of
    every snapshot and the time its poll returned (``change_probe.ChangeProbe.observe``)."""
    link = ModbusLink(TcpSettings("127.0.0.1", port, TIMEOUT_S))
    channel = DeviceChannel(link, UNIT_ID, max_in_flight=window)
    device = make_device(name, channel)
    cycle: Callable[[], object] = device.poll
    if observer is not None:
        cycle = observed(device.poll, observer)
    try:
        rate, cpu = measure(cycle, duration_s)
    finally:
        link.close()
    latencies = list(channel.stats.latencies_s)
    return rate, cpu, statistics.median(latencies), channel.pipelining.fallbacks


# The device loop of another checkout (``--base-tree``: the tree before this work, one
# request at a time), run against the same simulator in a process of its own.
BASE_LOOP = """
import json, sys, time
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.transport import ModbusLink, TcpSettings
name, port, duration = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
if name == "r6":
    from r6_bridge.device import R6Device as Device
else:
    from xarm_bridge.device import XArmDevice as Device
link = ModbusLink(TcpSettings("127.0.0.1", port, 1.0))
device = Device(DeviceChannel(link, 1))
for _ in range(3):
    device.poll()
polls, cpu, start = 0, time.process_time(), time.perf_counter()
while (elapsed := time.perf_counter() - start) < duration:
    device.poll()
    polls += 1
print(json.dumps([polls / elapsed, (time.process_time() - cpu) / max(polls, 1)]))
"""


def base_rate(tree: Path, name: str, port: int, duration_s: float) -> tuple[float, float]:
    out = subprocess.run(
        [sys.executable, "-c", BASE_LOOP, name, str(port), str(duration_s)],
        cwd=tree,
        env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    rate, cpu = json.loads(out.strip().splitlines()[-1])
    return float(rate), float(cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--devices", default=",".join(DEVICES))
    parser.add_argument("--round-trips-ms", default="0,1,5")
    parser.add_argument("--windows", default="1,4,13")
    parser.add_argument(
        "--nagle", default="off,on", help="off, on or off,on: the device leaves Nagle on"
    )
    parser.add_argument("--duration", type=float, default=2.0, help="seconds per measurement")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--base-tree",
        type=Path,
        help="also the device loop of this checkout (e.g. `git archive 62499ac | tar -x -C DIR`)",
    )
    parser.add_argument("--json", type=Path, default=ROOT / "bench" / "results" / "pipelining.json")
    args = parser.parse_args()
    windows = [int(w) for w in args.windows.split(",")]
    rows: list[dict[str, Any]] = []
    for name in args.devices.split(","):
        for nagle, rtt in (
            (n == "on", float(x))
            for n in args.nagle.split(",")
            for x in args.round_trips_ms.split(",")
        ):
            with simulator(name, rtt, nagle) as port:
                runs: dict[str, list[tuple[float, ...]]] = {"bare": []}
                if args.base_tree is not None:
                    runs["base"] = []
                runs.update({str(w): [] for w in windows})
                for _ in range(args.repeats):
                    runs["bare"].append(bare_rate(name, port, args.duration))
                    if args.base_tree is not None:
                        runs["base"].append(base_rate(args.base_tree, name, port, args.duration))
                    for w in windows:
                        runs[str(w)].append(device_rate(name, port, w, args.duration))
            row: dict[str, Any] = {"device": name, "round_trip_ms": rtt, "nagle": nagle}
            for key, samples in runs.items():
                row[key] = {
                    "polls_per_s": statistics.median(s[0] for s in samples),
                    "cpu_us_per_poll": statistics.median(s[1] for s in samples) * 1e6,
                }
                if key not in ("bare", "base"):
                    row[key]["transaction_ms"] = statistics.median(s[2] for s in samples) * 1e3
                    row[key]["fallbacks"] = max(int(s[3]) for s in samples)
            rows.append(row)
            print_row(row, windows)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"time": time.time(), "rows": rows}, indent=1))
    print(f"figures in {args.json}")


def print_row(row: dict[str, Any], windows: list[int]) -> None:
    one = row["1"]["polls_per_s"]
    cells = [f"bare {row['bare']['polls_per_s']:.1f}"]
    if "base" in row:
        cells.append(f"base tree {row['base']['polls_per_s']:.1f}")
    for w in windows:
        r = row[str(w)]
        cells.append(
            f"N={w} {r['polls_per_s']:.1f}/s (x{r['polls_per_s'] / one:.2f}, "
            f"{r['cpu_us_per_poll']:.0f} us CPU, fallbacks {r['fallbacks']})"
        )
    print(
        f"{row['device']:5} rtt {row['round_trip_ms']:g} ms"
        f"{', Nagle on' if row.get('nagle') else ''} "
        f"(measured one at a time {row['1']['transaction_ms']:.2f} ms): " + "; ".join(cells),
        flush=True,
    )


if __name__ == "__main__":
    main()
