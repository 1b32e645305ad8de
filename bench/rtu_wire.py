#!/usr/bin/env python3
"""RTU throughput against the wire limit, on an emulated byte-timed line
(docs/architecture.md, "Performance: how it is measured").

Prints figures and writes them to bench/results/rtu_wire.json; asserts nothing.

    .venv/bin/python bench/rtu_wire.py [--duration 5] [--quick] [--clients stock,timed]
        [--check-relay] [--json PATH]

Every case runs ``DeviceChannel.read_registers`` (FC 03) in a loop on one ``ModbusLink``
against ``Simulator.start_serial`` on the far end of ``bench/line_relay.py`` (a relay that
paces bytes at 10 bits/byte on a shared half-duplex timeline), once with pymodbus's stock
``ModbusSerialClient`` and once with ``TimedSerialClient`` (what ``ModbusLink`` uses):

- stepper: 2, 10 and 49 registers with a 35 ms reply delay, at 9600 and 115200 baud;
- no device delay: the same reads with a device that answers right after t3.5;
- multi-drop: 1, 4 and 8 units polled round-robin at 115200, 10 registers, no delay.

Wire limit of one transaction (8N1): (8 + 5 + 2N) bytes x 10 bits / baud, plus the
device's turnaround max(t3.5, reply delay) after the request, plus t3.5 after the reply
(t3.5 = 3.5 characters, fixed 1.75 ms above 19200 baud). Columns:

- ``ratio``: achieved transactions/s over the run / wire limit (mean: includes every
  scheduling hiccup of the three processes sharing this machine: client, simulator,
  relay);
- ``r_med``: wire cycle / median cycle (request start to request start on the relay);
- ``r_dev``: like ``r_med`` with the device turnaround the relay observed (``turn``, ms)
  instead of the nominal one: the simulator's asyncio sleep overshoots 35 ms by ~1.5 ms,
  which is the device's doing, not the client's;
- ``viol/req``: requests that started less than t3.5 after the previous frame ended
  (relay timestamps, which never err towards a violation) / requests on the wire;
  ``min gap``: the shortest silence before a request (ms); ``late90``: p90 of how late
  the relay released a frame's last byte (ms); ``err``: failed or wrong reads.

``--check-relay`` only checks the relay against theory (frames of known sizes).
"""

from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pymodbus.client import ModbusSerialClient  # noqa: E402

from bench.line_relay import (  # noqa: E402
    REQUEST,
    LineRelay,
    check_relay,
    print_check,
    request_gaps,
    silence_violations,
    transactions,
)
from bridge_core.sim.serving import Simulator  # noqa: E402
from bridge_core.sim.sim_base import SimulatedDevice  # noqa: E402
from bridge_core.wire.channel import DeviceChannel  # noqa: E402
from bridge_core.wire.errors import LinkError  # noqa: E402
from bridge_core.wire.registers import (  # noqa: E402
    Access,
    DeviceLimits,
    RegisterMap,
    ValueType,
    register_array,
)
from bridge_core.wire.serial_timing import silence_s  # noqa: E402
from bridge_core.wire.transport import ModbusLink, SerialSettings  # noqa: E402

BITS_PER_CHAR = 10
REQUEST_BYTES = 8  # FC 03: unit, function, address (2), count (2), CRC (2)
REPLY_OVERHEAD_BYTES = 5  # unit, function, byte count, CRC (2)
STEPPER_REPLY_DELAY_S = 0.035
WARMUP_ROUNDS = 5
REGISTERS = 64
RESULTS = ROOT / "bench" / "results" / "rtu_wire.json"

BENCH_MAP = RegisterMap(
    "bench",
    tuple(
        register_array(
            "word", 0, REGISTERS, ValueType.U16, "bench", access=Access.READ_WRITE, first_index=0
        )
    ),
    DeviceLimits(max_read_registers=125),
)


@dataclass(frozen=True)
class Case:
    group: str
    baudrate: int
    registers: int
    reply_delay_s: float
    units: int = 1


def cases() -> list[Case]:
    out: list[Case] = []
    for baud in (9600, 115200):
        for regs in (49, 10, 2):
            out.append(Case("stepper", baud, regs, STEPPER_REPLY_DELAY_S))
    for baud in (9600, 115200):
        for regs in (49, 10, 2):
            out.append(Case("no-delay", baud, regs, 0.0))
    for units in (1, 4, 8):
        out.append(Case("multi-drop", 115200, 10, 0.0, units))
    return out


def transaction_wire_s(
    baudrate: int, request_bytes: int, reply_bytes: int, turnaround_s: float
) -> float:
    """One transaction on an ideal line: both frames, the device's turnaround (at least
    t3.5 after the request), and t3.5 of silence after the reply."""
    t35 = silence_s(baudrate)
    char_s = BITS_PER_CHAR / baudrate
    return (request_bytes + reply_bytes) * char_s + max(t35, turnaround_s) + t35


def wire_cycle_s(baudrate: int, registers: int, turnaround_s: float) -> float:
    """One FC 03 transaction on the wire, silence after the reply included."""
    reply_bytes = REPLY_OVERHEAD_BYTES + 2 * registers
    return transaction_wire_s(baudrate, REQUEST_BYTES, reply_bytes, turnaround_s)


def serve_devices(
    port: str, case: Case, ready: Any, stop: Any
) -> None:  # runs in a process of its own
    """The simulated devices of ``case`` on ``port`` until ``stop`` is set."""
    limits = DeviceLimits(max_read_registers=125, reply_delay_s=case.reply_delay_s)
    devices = [SimulatedDevice(BENCH_MAP, u, limits=limits) for u in range(1, case.units + 1)]
    for device in devices:
        device.set_words(BENCH_MAP["word_0"].table, 0, [device.unit_id] * REGISTERS)
    with Simulator(devices) as sim:
        sim.start_serial(port, baudrate=case.baudrate)
        ready.set()
        stop.wait()


def run_case(case: Case, client: str, duration_s: float) -> dict[str, Any]:
    t35 = silence_s(case.baudrate)
    units = list(range(1, case.units + 1))
    mp = multiprocessing.get_context("spawn")
    ready, stop = mp.Event(), mp.Event()
    # A real RTU device cannot see a request's end before t3.5 of silence; the pymodbus
    # simulator answers at once, so the line holds its reply until then.
    with LineRelay(case.baudrate, device_turnaround_s=t35) as relay:
        # The simulator runs in a process of its own, as a real device would: sharing the
        # client's GIL would put its work on the client's clock.
        sim = mp.Process(target=serve_devices, args=(relay.device_path, case, ready, stop))
        sim.start()
        try:
            if not ready.wait(20):
                raise RuntimeError("simulator did not start")
            settings = SerialSettings(relay.client_path, case.baudrate, timeout_s=1.0)
            link = ModbusLink(settings)
            if client == "stock":
                link._client = ModbusSerialClient(  # the comparison: pymodbus as shipped
                    settings.port,
                    baudrate=settings.baudrate,
                    parity=settings.parity,
                    stopbits=settings.stopbits,
                    bytesize=settings.bytesize,
                    timeout=settings.timeout_s,
                    retries=0,
                )
            channels = [DeviceChannel(link, u, retries=0) for u in units]
            for _ in range(WARMUP_ROUNDS):
                for ch in channels:
                    ch.read_registers(0, case.registers)
            relay.clear()
            done = errors = wrong = 0
            started = time.monotonic()
            while time.monotonic() - started < duration_s:
                for ch in channels:
                    try:
                        values = ch.read_registers(0, case.registers)
                    except LinkError:
                        errors += 1
                        continue
                    done += 1
                    wrong += values != [ch.unit_id] * case.registers
            elapsed = time.monotonic() - started
            frames = relay.frames()
            link.close()
        finally:
            stop.set()
            sim.join(10)
            if sim.is_alive():
                sim.kill()
    rate = done / elapsed
    wire_cycle = wire_cycle_s(case.baudrate, case.registers, case.reply_delay_s)
    pairs = transactions(frames)
    turnaround = statistics.median(rep.start - req.end for req, rep in pairs) if pairs else 0.0
    starts = [f.start for f in frames if f.direction == REQUEST]
    cycle = statistics.median(b - a for a, b in pairwise(starts)) if len(starts) > 1 else 0.0
    gaps = [g.silence_s for g in request_gaps(frames)]
    late = sorted(f.end - f.due_end for f in frames)
    return {
        **asdict(case),
        "client": client,
        "transactions": done,
        "errors": errors,
        "wrong_values": wrong,
        "elapsed_s": elapsed,
        "rate_hz": rate,
        "wire_rate_hz": 1.0 / wire_cycle,
        "ratio": rate * wire_cycle,
        "median_cycle_ms": cycle * 1e3,
        "ratio_med": wire_cycle / cycle if cycle else 0.0,
        "device_turnaround_ms": turnaround * 1e3,
        "ratio_dev": (
            wire_cycle_s(case.baudrate, case.registers, turnaround) / cycle if cycle else 0.0
        ),
        "requests_on_wire": len(starts),
        "violations": len(silence_violations(frames, relay.silence_s)),
        "min_gap_ms": min(gaps) * 1e3 if gaps else None,
        "median_gap_ms": statistics.median(gaps) * 1e3 if gaps else None,
        "relay_late_p90_ms": late[int(0.9 * (len(late) - 1))] * 1e3 if late else None,
        "t35_ms": t35 * 1e3,
    }


def print_table(rows: list[dict[str, Any]], header: bool = True) -> None:
    head = (
        f"{'case':<10} {'baud':>6} {'regs':>4} {'units':>5} {'delay':>5} {'wire/s':>7} "
        f"{'client':>6} {'tx/s':>7} {'ratio':>6} {'r_med':>6} {'r_dev':>6} {'turn':>6} "
        f"{'viol/req':>9} {'min gap':>7} {'late90':>6} {'err':>3}"
    )
    if header:
        print(head)
        print("-" * len(head))
    for r in rows:
        min_gap = f"{r['min_gap_ms']:.2f}" if r["min_gap_ms"] is not None else "-"
        late = f"{r['relay_late_p90_ms']:.2f}" if r["relay_late_p90_ms"] is not None else "-"
        print(
            f"{r['group']:<10} {r['baudrate']:>6} {r['registers']:>4} {r['units']:>5} "
            f"{r['reply_delay_s'] * 1e3:>5.0f} {r['wire_rate_hz']:>7.1f} {r['client']:>6} "
            f"{r['rate_hz']:>7.1f} {r['ratio']:>6.3f} {r['ratio_med']:>6.3f} "
            f"{r['ratio_dev']:>6.3f} {r['device_turnaround_ms']:>6.2f} "
            f"{r['violations']:>4}/{r['requests_on_wire']:<4} {min_gap:>7} {late:>6} "
            f"{r['errors'] + r['wrong_values']:>3}",
            flush=True,
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=5.0, help="seconds per case")
    parser.add_argument("--quick", action="store_true", help="1 s per case")
    parser.add_argument("--clients", default="stock,timed", help="stock,timed")
    parser.add_argument("--groups", default="stepper,no-delay,multi-drop")
    parser.add_argument("--check-relay", action="store_true", help="only check the relay")
    parser.add_argument("--json", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.check_relay:
        print("relay vs theory (transfer time of frames of known size, medians):")
        print_check(check_relay())
        return 0
    duration = 1.0 if args.quick else args.duration
    clients = [c for c in args.clients.split(",") if c]
    groups = set(args.groups.split(","))
    print("relay check (medians, quick):")
    relay = check_relay(sizes=(8, 103), repeats=7)
    print_check(relay)
    print()
    rows: list[dict[str, Any]] = []
    printed = 0
    for case in cases():
        if case.group not in groups:
            continue
        for client in clients:
            rows.append(run_case(case, client, duration))
        print_table(rows[printed:], header=printed == 0)
        printed = len(rows)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "when": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                "machine": platform.platform(),
                "duration_s": duration,
                "relay_check": [{**asdict(r), "error_s": r.error_s} for r in relay],
                "cases": rows,
            },
            indent=1,
        )
    )
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
