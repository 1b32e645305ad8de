"""The node's read plan and the loops that issue it without ROS (bench/bridge_bench.py,
rate and cpu phases).

The plan is the device's own rate groups after one poll of the simulator, as the node
sets them (``device_plan``). Two loops issue it, each in a worker process of its own
(``bridge_bench.py --device D --worker bare|device --port N ...`` runs one loop and
prints one JSON line, ``run_worker``; the bench starts it with ``run_loop``): a bare
sync ``ModbusTcpClient`` issuing the plan's requests, and the device layer's
``poll()``; both as fast as they can or paced at a rate, CPU from ``time.process_time``
inside the loop's process.
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.bench_processes import Processes, cycle_figures, proc_cpu_s
from bench.bridge_profiles import Profile

UNIT_ID = 1
BRIDGE_BENCH = Path(__file__).resolve().with_name("bridge_bench.py")  # runs the workers

Block = tuple[str, int, int]  # (table, address, count) of one read request


@dataclass(frozen=True)
class ReadPlan:
    """What the node reads: its device's rate groups, in the order it reads them.

    ``fast`` every poll; ``slow`` first in a poll once ``slow_period_s`` has passed since
    it was last read (``bridge_core.runtime.rate_groups.PollGroups``).
    """

    fast: tuple[Block, ...]
    slow: tuple[Block, ...]
    slow_period_s: float

    def polls(self, transactions: float, slow_reads: float) -> float:
        """Polls in which the node made ``transactions``, ``slow_reads`` of them with the
        slow group."""
        return (transactions - len(self.slow) * slow_reads) / len(self.fast)

    def describe(self) -> str:
        return (
            f"fast {len(self.fast)} requests every poll, slow {len(self.slow)} every "
            f"{self.slow_period_s:g} s"
        )

    def to_json(self) -> dict[str, Any]:
        return {"fast": self.fast, "slow": self.slow, "slow_period_s": self.slow_period_s}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ReadPlan:
        def blocks(rows: list[list[Any]]) -> tuple[Block, ...]:
            return tuple((str(t), int(a), int(c)) for t, a, c in rows)

        return cls(blocks(data["fast"]), blocks(data["slow"]), float(data["slow_period_s"]))


def make_device(profile: Profile, channel: Any) -> Any:
    """The bridge's device layer on ``channel``, built as the node builds it (defaults)."""
    if profile.make_device is not None:
        return profile.make_device(channel)
    module = importlib.import_module(f"{profile.package}.device")
    return getattr(module, profile.device_class)(channel)


def device_plan(profile: Profile, port: int) -> ReadPlan:
    """The node's read plan: the device's rate groups after one poll of the simulator on
    ``port`` (the R6 plans by the axis and board counts it reads), with the node's default
    ``slow_poll_period_s``."""
    from bridge_core.runtime.rate_groups import SLOW_POLL_PERIOD_DEFAULT_S
    from bridge_core.wire.channel import DeviceChannel
    from bridge_core.wire.transport import ModbusLink, TcpSettings

    link = ModbusLink(TcpSettings("127.0.0.1", port, 1.0))
    try:
        device = make_device(profile, DeviceChannel(link, UNIT_ID))
        device.poll()
        groups = device.groups
    finally:
        link.close()

    def blocks(requests: list[Any]) -> tuple[Block, ...]:
        return tuple((r.table.value, r.address, r.count) for r in requests)

    return ReadPlan(blocks(groups.fast), blocks(groups.slow), SLOW_POLL_PERIOD_DEFAULT_S)


def run_worker(args: argparse.Namespace) -> None:
    profile: Profile = args.profile
    if args.worker == "bare":
        from pymodbus.client import ModbusTcpClient

        client = ModbusTcpClient("127.0.0.1", port=args.port, timeout=1.0, retries=0)
        if not client.connect():  # type: ignore[no-untyped-call]  # untyped in pymodbus
            raise SystemExit(f"bare loop: cannot connect to 127.0.0.1:{args.port}")
        read = {  # FC 01 / 02 / 03 / 04, as the node's link issues them
            "coil": (client.read_coils, True),
            "discrete_input": (client.read_discrete_inputs, True),
            "holding": (client.read_holding_registers, False),
            "input": (client.read_input_registers, False),
        }
        plan = ReadPlan.from_json(json.loads(args.plan))
        fast = [(*read[table], address, count) for table, address, count in plan.fast]
        slow = [(*read[table], address, count) for table, address, count in plan.slow]
        slow_due = -math.inf  # read in the first poll, as PollGroups does

        def cycle() -> None:
            nonlocal slow_due
            due = bool(slow) and time.monotonic() >= slow_due
            for method, bits, address, count in [*slow, *fast] if due else fast:
                reply = method(address, count=count, device_id=UNIT_ID)
                # Bit replies come padded to whole bytes.
                if reply.isError() or len(reply.bits if bits else reply.registers) < count:
                    raise RuntimeError(f"bare loop: bad reply at {address}: {reply}")
            if due:  # due again one period after this poll's reads
                slow_due = time.monotonic() + plan.slow_period_s

        close: Callable[[], None] = client.close
    else:
        from bridge_core.wire.channel import DeviceChannel
        from bridge_core.wire.transport import ModbusLink, TcpSettings

        link = ModbusLink(TcpSettings("127.0.0.1", args.port, 1.0))
        device = make_device(profile, DeviceChannel(link, UNIT_ID))
        cycle = device.poll
        close = link.close

    period = 1.0 / args.rate if args.rate > 0 else 0.0
    slices = max(1, args.slices)
    slice_s = args.duration / slices
    clock = time.perf_counter
    next_due = clock()

    def pace() -> None:
        nonlocal next_due
        if period:
            next_due += period
            delay = next_due - clock()
            if delay > 0:
                time.sleep(delay)
            else:
                next_due = clock()  # late: do not burst to catch up

    warm_end = clock() + args.warmup
    while clock() < warm_end:
        cycle()
        pace()

    def sim_cpu() -> float:
        return proc_cpu_s(args.sim_pid) if args.sim_pid else float("nan")

    samples = []  # (wall, cpu, cycles, simulator cpu) at slice boundaries
    cycles = 0
    start = clock()
    samples.append((start, time.process_time(), 0, sim_cpu()))
    for k in range(1, slices + 1):
        boundary = start + k * slice_s
        while clock() < boundary:
            cycle()
            cycles += 1
            pace()
        samples.append((clock(), time.process_time(), cycles, sim_cpu()))
    close()
    print(json.dumps({"samples": samples}), flush=True)


def loop_figures(samples: list[list[float]]) -> dict[str, Any]:
    (w0, c0, n0, s0), (w1, c1, n1, s1) = samples[0], samples[-1]
    cycles = n1 - n0
    per_slice = []
    for (wa, _, na, _), (wb, _, nb, _) in itertools.pairwise(samples):
        if wb > wa:
            per_slice.append((nb - na) / (wb - wa))
    return {
        **cycle_figures(cycles, c1 - c0, w1 - w0),
        "slice_rates_hz": per_slice,
        "sim_cpu_percent": 100.0 * (s1 - s0) / (w1 - w0),
        "cpu_source": "time.process_time in the loop process",
    }


def run_loop(
    procs: Processes,
    profile: Profile,
    kind: str,
    port: int,
    *,
    duration: float,
    warmup: float,
    rate: float,
    slices: int,
    plan: ReadPlan,
    sim_pid: int = 0,
) -> dict[str, Any]:
    """Run one loop (``kind`` bare or device) in a worker process; its figures."""
    argv = [
        sys.executable,
        str(BRIDGE_BENCH),
        "--device",
        profile.name,
        "--worker",
        kind,
        "--port",
        str(port),
        "--duration",
        str(duration),
        "--warmup",
        str(warmup),
        "--rate",
        str(rate),
        "--slices",
        str(slices),
        "--sim-pid",
        str(sim_pid),
        "--plan",
        json.dumps(plan.to_json()),
    ]
    proc = procs.start(f"worker_{profile.name}_{kind}_{int(rate)}", argv, capture=True)
    try:
        out, _ = proc.communicate(timeout=duration + warmup + 60)
    finally:
        procs.stop(proc)
    if proc.returncode != 0:
        raise RuntimeError(f"worker {kind} failed (rc {proc.returncode}); see {procs.log_dir}")
    return loop_figures(json.loads(out.decode().strip().splitlines()[-1])["samples"])
