#!/usr/bin/env python3
"""Pipelined Modbus TCP bench: poll rate at simulated round trips, by ``max_in_flight``.

    .venv/bin/python bench/pipelining.py [--devices r6,xarm] [--round-trips-ms 0,1,5]
        [--windows 1,4,13] [--duration 2] [--repeats 3] [--json PATH]

For each device and simulated round trip (the simulator's ``--reply-delay-ms``: half each
way, requests in flight overlap; docs/architecture.md, "Pipelined Modbus TCP") the
simulator runs in a process of its own, and this process polls it as fast as it can:

- ``bare``: a bare sync pymodbus ``ModbusTcpClient`` loop issuing the device's full poll
  plan (R6 13 reads, xArm 8), one request at a time, as in bench/bridge_bench.py;
- ``N``: the device layer (``R6Device.poll`` / ``XArmDevice.poll``: the fast group every
  poll, the slow group once a second) through a ``DeviceChannel`` with ``max_in_flight``
  N (1 = one request at a time, as before this work).

Each figure is the median over ``--repeats`` rounds (every window measured once per
round, in turn); also printed: the median transaction time one at a time (the round trip
the simulator actually gives on this machine, its scheduling included), the CPU of this
process per poll, and the ratio N / 1. Asserts nothing (bench/README.md).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bridge_core.wire.channel import DeviceChannel  # noqa: E402
from bridge_core.wire.transport import ModbusLink, TcpSettings  # noqa: E402

UNIT_ID = 1
TIMEOUT_S = 1.0
SIM_START_S = 20.0
WARMUP_POLLS = 3
DEVICES = ("r6", "xarm")


def make_device(name: str, channel: DeviceChannel) -> Any:
    if name == "r6":
        from r6_bridge.device import R6Device

        return R6Device(channel)
    from xarm_bridge.device import XArmDevice

    return XArmDevice(channel)


def full_plan(name: str) -> list[tuple[str, int, int]]:
    """(table, address, count) of the device's full poll plan (the bare loop's)."""
    if name == "r6":
        from r6_bridge.device import R6Device

        plan = R6Device(None).poll_plan(6, 1)  # type: ignore[arg-type]
    else:
        from xarm_bridge.device import POLL_PLAN

        plan = POLL_PLAN
    return [(r.table.value, r.address, r.count) for r in plan]


@contextmanager
def simulator(name: str, round_trip_ms: float) -> Iterator[int]:
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


def bare_rate(name: str, port: int, duration_s: float) -> tuple[float, float]:
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
    requests = [(read[table], address, count) for table, address, count in full_plan(name)]

    def cycle() -> None:
        for method, address, count in requests:
            if method(address, count=count, device_id=UNIT_ID).isError():
                raise RuntimeError(f"bare loop: exception reply at {address}")

    try:
        return measure(cycle, duration_s)
    finally:
        client.close()  # type: ignore[no-untyped-call]


def device_rate(
    name: str, port: int, window: int, duration_s: float
) -> tuple[float, float, float, int]:
    """Polls/s, CPU per poll, median transaction time (s), fallbacks."""
    link = ModbusLink(TcpSettings("127.0.0.1", port, TIMEOUT_S))
    channel = DeviceChannel(link, UNIT_ID, max_in_flight=window)
    device = make_device(name, channel)
    try:
        rate, cpu = measure(device.poll, duration_s)
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
        for rtt in (float(x) for x in args.round_trips_ms.split(",")):
            with simulator(name, rtt) as port:
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
            row: dict[str, Any] = {"device": name, "round_trip_ms": rtt}
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
        f"{row['device']:5} rtt {row['round_trip_ms']:g} ms "
        f"(measured one at a time {row['1']['transaction_ms']:.2f} ms): " + "; ".join(cells),
        flush=True,
    )


if __name__ == "__main__":
    main()
